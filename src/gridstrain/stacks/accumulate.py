"""One pass over a series of frames, in sums that merge.

A series holds ``T`` frames of one static state. Everything the measurement needs
from its frames is gathered in one read of each frame by :class:`SeriesPass`:

- the screening's per-frame record (:class:`gridstrain.stacks.screening.FrameProbe`):
  carrier coefficients, hence the rigid shifts ``a_t`` (eq. 2), contrast, tiles,
  clipping;
- the sums giving the mean image, the temporal variance with the frames' rigid
  motion regressed out, and the means of the two halves of the series (the noise
  floor measured half against half);
- with method B, the sums of the frames' windowed Fourier transforms
  (:func:`gridstrain.stacks.method_b`);
- with method C, the frames summed with their carriers realigned by their shifts,
  per half (:func:`gridstrain.stacks.method_c`).

Passes over parts of a series (chunks of frames, on threads or Dask workers) merge
exactly (:meth:`SeriesPass.merge`), provided they start from the same *origin*,
the frame every sum is taken against: the pixel sums are over ``d_t = v_t -
origin`` (noise-sized numbers, not grey levels squared) and the shifts are phase
advances of the carrier against the origin's, so that every part measures them on
the same basis. A frame the screening rejects is taken out again by
:meth:`SeriesPass.remove` (the only frames read twice).

The regression of the variance. A frame of a static stack is ``s(x + a_t)`` plus the
sensor noise (eq. 2): at one pixel, the frames' values are a function of the rigid shift
``a_t``, which the temporal variance would count as noise. Where the grid is periodic
that function is periodic in the carrier phases ``theta_t = 2 pi K a_t`` the pass
measures, a sum of harmonics ``exp(i (m theta_1 + n theta_2))``; what is not periodic
(lighting, stains, the print's defects) varies slowly and moves with ``a_t`` to first
order. So each pixel's series is fitted on the regressors ``g_t`` (:data:`MOTION_TERMS`):
the two shift components, then the cosine and sine of the carriers' harmonics ``(m,
n)`` of order ``|m| + |n|`` 1, 2 and 3, by order. A first-order fit on the shifts
alone (eq. 3's linear term, the paper's ref. [22]) leaves the second-order term ``a^T
H a / 2`` in the residual: with 0.3 px of vibration on sharp grids of pitch 5 it
passes for 2 to 10 times the sensor's variance, and the std maps state the noise up
to 3 times too large. The harmonics follow a grid's own response to a shift at any
amplitude. On a sharp-edged checkerboard of pitch 5 (T = 50), what the harmonics up
to order 2 leave adds 0.4 % to the noise variance at 0.3 px and 7 % at 0.5 px; on
``sin^3`` lines crossed as a checkerboard, 2 % and 17 to 44 %; up to order 3, 0.4 %
at most on both.

The fit is nested: the regressors are added by groups (none, the shifts, each order
of harmonics) and each group is kept only if it lowers the image's mean residual
variance by more than :data:`_TERM_GAIN`: a still stack keeps the fit on the shifts
(``T - 3`` dof, as a first-order fit), and every group costs degrees of freedom, not
bias. A group is tried only while ``T - 1`` exceeds the regressors fitted (``T >= 28``
for all: 0.5 px needs them, 0.1 px the first order). With ``c_t = g_t -
mean(g)`` over the kept frames, the fit leaves the residual sum of squares ``S_dd -
S_d^2 / T - s^T S_cc^-1 s`` with ``s = sum_t c_t d_t = sum_t g_t d_t - mean(g) S_d``:
the sums over ``g_t d_t`` and ``d_t`` are additive whatever the frames kept, so the
centring is done once, at the end, where ``S_cc`` is factored once by Gram-Schmidt
(its groups in order) for every nested fit.

Conventions: :mod:`gridstrain.conventions`. Sums are float64 whatever the frames.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from scipy import linalg
from scipy.linalg import blas

from .._validation import check_type, exact_in_float32
from ..phase import Lattice, Window, compiled_loops
from ._accumulators import FrameOrder, PhaseMean, StackResult, compensated_result
from .screening import _RESIDUAL_FRAMES, FrameProbe, FrameScreen, decide
from .vibration import RigidProbe, shift_matrix

__all__ = ["MOTION_TERMS", "PassPlan", "SeriesPass", "SeriesStatistics", "motion_regressors",
           "motion_sums_bytes", "nested_motion_fits", "pick_motion_fit"]

# Frames batched per matrix product of the linear sums: the batch costs this many
# bytes at most (as for method C's sums).
_BATCH_BYTES = 2**26
_METHODS = ("A", "B", "C")

#: The regressors of a frame's rigid motion fitted out of each pixel's series, by
#: group, in the order the groups are tried (module docstring): the shift ``(x, y)``,
#: px, then the cosine and sine of the carrier harmonics ``m theta_1 + n theta_2``.
MOTION_TERMS = (("x", "y"),
                ("cos(theta1)", "sin(theta1)", "cos(theta2)", "sin(theta2)"),
                ("cos(2 theta1)", "sin(2 theta1)", "cos(2 theta2)", "sin(2 theta2)",
                 "cos(theta1 + theta2)", "sin(theta1 + theta2)",
                 "cos(theta1 - theta2)", "sin(theta1 - theta2)"),
                ("cos(3 theta1)", "sin(3 theta1)", "cos(3 theta2)", "sin(3 theta2)",
                 "cos(2 theta1 + theta2)", "sin(2 theta1 + theta2)",
                 "cos(2 theta1 - theta2)", "sin(2 theta1 - theta2)",
                 "cos(theta1 + 2 theta2)", "sin(theta1 + 2 theta2)",
                 "cos(theta1 - 2 theta2)", "sin(theta1 - 2 theta2)"))
# the harmonics (m, n) of the groups after the shifts, in MOTION_TERMS' order: those of
# order |m| + |n| = 1, 2 and 3
_HARMONICS = ((1, 0), (0, 1), (2, 0), (0, 2), (1, 1), (1, -1),
              (3, 0), (0, 3), (2, 1), (2, -1), (1, 2), (1, -2))

# A group of regressors is fitted when it lowers the image's mean residual variance
# by more than this fraction: 1 % of a variance is 0.5 % of a std, below the maps'
# own calibration (1.0-1.06); on a still stack the next group's gain is noise, under
# 0.1 % for 10,000 pixels and 40 degrees of freedom.
_TERM_GAIN = 0.01
# A centred regressor whose part independent of those before it is below this
# fraction of the uncentred regressor's norm is left out (a still stack: the
# harmonics' columns are then the shifts' and their squares to 1e-9): the fit stays
# well conditioned, and what it would explain is below the rounding of the sums.
_COLLINEAR = 1e-7
# Pixels per band of the fit's per-pixel algebra (its temporaries: 0.5 MiB a regressor).
_FIT_BAND = 2**16


def _motion_rows(n_frames: int) -> int:
    """The motion regressors a series of ``n_frames`` frames can fit, whole groups of
    :data:`MOTION_TERMS` leaving a degree of freedom at least (``T >= 4`` for the
    shifts, 8, 16 and 28 for the harmonics of order 1, 2 and 3): only their sums are
    kept."""
    k = 0
    for grp in MOTION_TERMS:
        if n_frames - 1 - (k + len(grp)) < 1:
            break
        k += len(grp)
    return k


def motion_sums_bytes(shape, n_frames: int) -> int:
    """Memory a :class:`SeriesPass` over ``n_frames`` frames of ``shape`` (H, W) holds
    for its variance's fit beyond the fit on the shifts alone: 8 bytes a pixel for each
    harmonic term ``n_frames`` allows (``_motion_rows``), 0 below 8 frames; for the
    memory budget, whose calibrated figures include the shifts' two sums."""
    H, W = (int(v) for v in shape)
    return 8 * H * W * max(_motion_rows(int(n_frames)) - len(MOTION_TERMS[0]), 0)


def _orthonormal(g: np.ndarray, gbar: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """The centred regressors ``c = g - gbar`` (T, p) made orthonormal in their order
    (modified Gram-Schmidt, twice): ``(B, cols)`` with ``c[:, cols] @ B`` orthonormal,
    ``B`` upper triangular. A column is left out where its part independent of those
    before it is below :data:`_COLLINEAR` of the uncentred column's norm: the sums
    ``sum_t g_t d_t`` are uncentred, and a smaller part would be their rounding."""
    c = g - gbar
    q, cols = [], []
    for j in range(c.shape[1]):
        v = c[:, j].copy()
        for _ in range(2):
            for qi in q:
                v -= (qi @ v) * qi
        nv = float(np.linalg.norm(v))
        if not nv > _COLLINEAR * float(np.linalg.norm(g[:, j])):
            continue
        q.append(v / nv)
        cols.append(j)
    if not cols:
        return np.zeros((0, 0)), []
    Q = np.column_stack(q)
    R = Q.T @ c[:, cols]  # upper triangular: c[:, cols] = Q R
    B = linalg.solve_triangular(np.triu(R), np.eye(len(cols)))
    return B, cols


def nested_motion_fits(g: np.ndarray, gbar: np.ndarray, *, min_dof: int):
    """The nested fits of the motion regressors ``g`` (T, p), a prefix of
    :data:`MOTION_TERMS`' columns: ``(B, cols, stops)``. The regressors made
    orthonormal over the frames in their order (``(g - gbar)[:, cols] @ B``,
    :func:`_orthonormal`), and ``stops``, the numbers ``k`` of orthonormal regressors
    of the nested fits, one at each group's end (a group wholly collinear with those
    before it adds no fit), those that leave ``min_dof`` degrees of freedom at least
    after the mean and the ``k`` regressors. A pixel's residual sum of squares in the
    fit of the first ``k`` is its centred sum of squares less ``sum_{i<k} z_i^2``,
    ``z = B^T sum_t (g_t - gbar) d_t``."""
    T, p = g.shape
    B, cols = _orthonormal(g, gbar)
    ends = [e for e in np.cumsum([len(grp) for grp in MOTION_TERMS]) if e <= p]
    stops = [0] + [sum(1 for c in cols if c < e) for e in ends]
    return B, cols, list(dict.fromkeys(k for k in stops if T - 1 - k >= min_dof))


def pick_motion_fit(means, stops: list[int], cols: list[int]) -> int:
    """Index into ``stops`` (:func:`nested_motion_fits`) of the fit to keep, given the
    images' mean residual variance ``means`` of each: the fewest groups whose mean is
    within :data:`_TERM_GAIN` of the lowest; a still stack keeps the fit on its
    shifts where it has them."""
    means = np.asarray(means, dtype=np.float64)
    best = float(means.min())
    k_shift = sum(1 for c in cols if c < len(MOTION_TERMS[0]))
    low = stops.index(k_shift) if k_shift in stops else 0
    return next((i for i in range(low, len(stops)) if means[i] <= (1 + _TERM_GAIN) * best),
                int(np.argmin(means)))


def motion_regressors(theta: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """The regressors of :data:`MOTION_TERMS` for frames of carrier phase advances
    ``theta`` (T, 2), rad, and shifts ``shift`` (T, 2), px: (T, 26) float64."""
    theta = np.asarray(theta, dtype=np.float64).reshape(-1, 2)
    cols = [np.asarray(shift, dtype=np.float64).reshape(-1, 2)]
    for m, n in _HARMONICS:
        arg = m * theta[:, 0] + n * theta[:, 1]
        cols.append(np.column_stack([np.cos(arg), np.sin(arg)]))
    return np.concatenate(cols, axis=1)


@dataclass(frozen=True, eq=False)
class PassPlan:
    """What a pass over one series gathers (picklable: sent to Dask workers).

    Attributes
    ----------
    lattice : Lattice
        The grid's wave vectors.
    n_frames : int
        Frames in the series; frame ``t`` is in the first half when ``t <
        n_frames // 2``.
    method : {"A", "B", "C"}
        "B" adds the frames' transforms, "C" their realigned sums.
    window : Window, optional
        The transforms' window: method B's frames, method C's result (default: the
        lattice's pitch and the default margin).
    transform_mask : (H, W) bool ndarray, optional
        Method B's mask (the windows' support).
    saturation_level : float, optional
        The files' ceiling, raw grey levels (None for float data).
    scale : int
        Raw value of one sensor grey level.
    count_mask : (H, W) bool ndarray, optional
        Where clipped pixels are counted.
    """

    lattice: Lattice
    n_frames: int
    method: str = "A"
    window: Window | None = None
    transform_mask: np.ndarray | None = None
    saturation_level: float | None = None
    scale: int = 1
    count_mask: np.ndarray | None = None

    def __post_init__(self):
        if self.method not in _METHODS:
            raise ValueError(f"method must be one of {', '.join(_METHODS)}, got "
                             f"{self.method!r}")
        if self.n_frames < 1:
            raise ValueError(f"n_frames must be at least 1, got {self.n_frames!r}")
        if self.window is None:
            object.__setattr__(self, "window", Window.for_lattice(self.lattice))
        check_type(self.window, "window", Window)


@dataclass(frozen=True, eq=False)
class SeriesStatistics:
    """Per-pixel statistics of the kept frames of a series.

    Attributes
    ----------
    mean : (H, W) float64 ndarray
        Mean image, grey levels.
    variance : (H, W) float64 ndarray or None
        Noise variance of one frame, grey levels^2: the temporal variance with the
        frames' rigid motion regressed out of each pixel's series (``regressors``,
        module docstring; ``T - 1 - len(regressors)`` degrees of freedom), plain
        (``T - 1``) when there is nothing to regress on; None for one frame.
    method : str
        How the variance was obtained.
    n_frames : int
        Frames kept.
    regressors : tuple of str
        The terms of :data:`MOTION_TERMS` fitted out (those left out as collinear
        with the ones before them excepted); empty for a plain variance.
    dof : int
        Degrees of freedom of the variance (0 for one frame).
    """

    mean: np.ndarray
    variance: np.ndarray | None
    method: str
    n_frames: int
    regressors: tuple = ()
    dof: int = 0


class _Zeros:
    """float64 zeros of ``shape``, allocated where first read."""

    __slots__ = ("shape",)

    def __init__(self, shape: tuple):
        self.shape = shape

    def __getstate__(self):
        return self.shape

    def __setstate__(self, state):
        self.shape = state


class _ZerosOnRead:
    """An attribute of sums: an array, a :class:`_Zeros` that becomes float64 zeros of
    its shape where first read (in ``_<name>``), or None once released."""

    def __set_name__(self, owner, name: str):
        self.private = f"_{name}"

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        value = getattr(obj, self.private)
        if isinstance(value, _Zeros):
            value = np.zeros(value.shape)
            setattr(obj, self.private, value)
        return value

    def __set__(self, obj, value) -> None:
        setattr(obj, self.private, value)


class SeriesPass:
    """The mergeable sums of one pass over (part of) a series.

    Parameters
    ----------
    plan : PassPlan
        What to gather.
    origin : (H, W) array_like
        The frame the sums are taken against (the series' first frame): every part
        of a series that is to be merged must use the same.

    Notes
    -----
    Memory: four float64 images (the halves' sums, the sum of squares, the origin) and
    one per motion regressor of the variance's fit that ``n_frames`` allows (2 from 4
    frames, 6 from 8, 14 from 16, 26 from 28: module docstring), a batch of frames of at
    most 64 MiB; method B adds its transform sums (80 bytes a pixel), method C
    eight float64 images. The per-frame records are a few hundred bytes a frame.
    The motion's sums are freed by :meth:`release`.
    """

    #: The linear sums (rows: module docstring, by pixel); None once released.
    lin = _ZerosOnRead()
    #: The sum of the squared differences to the origin, by pixel; None once released.
    sq = _ZerosOnRead()

    def __init__(self, plan: PassPlan, origin):
        if not isinstance(plan, PassPlan):
            raise TypeError(f"plan must be a PassPlan, got {type(plan).__name__}")
        self.plan = plan
        self.origin = np.array(origin, dtype=np.float64)
        H, W = self.shape = self.origin.shape
        lat = plan.lattice
        self.probe = FrameProbe(lat, self.shape, saturation_level=plan.saturation_level,
                                scale=plan.scale, mask=plan.count_mask,
                                residual=plan.n_frames >= _RESIDUAL_FRAMES)
        self._M = shift_matrix(lat)
        self.records: dict = {}  # t -> FrameRecord
        self.theta: dict = {}  # t -> (2,) carrier phase advance against the origin, rad
        self.parts: dict = {}  # t -> (4, 2) quadrant shifts (method C), px
        self.removed: set = set()
        self.dtype = None  # float32 while every frame is float32 (gridstrain.conventions)
        # linear sums, rows: d over each half, then (method C) per half the real and
        # imaginary parts of exp(-i theta_j) d for j = 1, 2, then g_t d for the motion
        # regressors g_t (MOTION_TERMS): what release() keeps is a prefix
        self._m0 = 2 + (8 if plan.method == "C" else 0)
        self._n_motion = _motion_rows(plan.n_frames)
        # the carriers' phase advances weigh method C's sums and the motion's
        # regressors; a series too short for them (fewer than 4 frames, method A or B:
        # every one-frame state of a record) measures none, nor the origin's carrier
        self._advances = plan.method == "C" or self._n_motion > 0
        self._c0 = self.probe.carrier(self.origin) if self._advances else None
        rows = self._m0 + self._n_motion
        # zeros until a frame other than the origin comes: a one-frame series (every
        # state of a record) never writes them, nor reads them (statistics), and their
        # 24 bytes a pixel cost 0.2 to 0.5 ms to clear on 250 x 400 px
        self.lin = _Zeros((rows, H * W))
        self.sq = _Zeros((H * W,))  # sum d^2
        # method C's weights sum: sum_t exp(-i theta_tj) per half, (2 halves, 2)
        self.wsum = np.zeros((2, 2), dtype=np.complex128)
        # the batch: the frames' differences to the origin (float64), or, when the
        # compiled loops are there, integer frames as read (set by the first frame)
        self._buf = np.empty((0, H * W), dtype=np.float64)
        self._w: list = []  # pending weight rows
        self._signs: list = []  # their frames' signs (+1 added, -1 taken out)
        self._tmp = None  # scratch image
        self._rigid = None
        if plan.method == "C":
            self._rigid = RigidProbe(lat, self.shape)
            self._rigid(self.origin)  # quadrant shifts against the origin
        self.transforms = PhaseMean() if plan.method == "B" else None

    # ------------------------------------------------------------------ adding

    def _half(self, t: int) -> int:
        return 0 if t < self.plan.n_frames // 2 else 1

    def add(self, t: int, frame, *, order: FrameOrder | None = None,
            transform: bool = True) -> None:
        """Add frame ``t`` (its index in the series, from 0), (H, W) array of grey
        levels: float, or integers as read from the files (summed by the compiled
        loops without a float64 copy of the batch, when they are installed).

        ``transform=False`` leaves method B's transform to :meth:`add_transform`
        (on another thread, in frame order with ``order``).
        """
        if t in self.records:
            raise ValueError(f"frame {t} was added twice")
        arr = np.asarray(frame)
        if arr.shape != self.shape:
            raise ValueError(f"frames must have the shape {self.shape}, got {arr.shape}")
        fd = arr.dtype if arr.dtype.kind == "f" else np.dtype(np.float64)
        self.dtype = fd if self.dtype is None else np.promote_types(self.dtype, fd)
        raw = arr
        if self._rigid is not None:  # method C: one float64 copy for both probes
            arr = arr.astype(np.float64, copy=False)
        # the probe converts an integer frame itself, its extrema taken as stored
        rec = self.probe(arr)
        self.records[t] = rec
        if self._advances:
            self.theta[t] = np.angle(rec.coefficients * np.conj(self._c0))  # eq. (2)
        if self._rigid is not None:
            _, parts = self._rigid(arr)
            if parts is not None:
                self.parts[t] = parts
        self._sums(t, raw, 1.0)
        if transform and self.transforms is not None:
            self.add_transform(t, raw, order=order)

    def add_transform(self, t: int, frame, *, order: FrameOrder | None = None,
                      remove: bool = False) -> None:
        """Add (or take out) method B's transform of frame ``t``; thread-safe."""
        p = self.plan
        self.transforms.add_frame(frame, p.lattice, p.window, mask=p.transform_mask,
                                  index=t, order=order, remove=remove)

    def remove(self, t: int, frame) -> None:
        """Take frame ``t`` (added before, read again) out of every sum."""
        if t not in self.records or t in self.removed:
            raise ValueError(f"frame {t} is not in the sums")
        arr = np.asarray(frame)
        self._sums(t, arr, -1.0)
        if self.transforms is not None:
            self.add_transform(t, arr, remove=True)
        self.removed.add(t)

    def _sums(self, t: int, arr: np.ndarray, sign: float) -> None:
        h = self._half(t)
        w = np.zeros(self._lin.shape[0])
        w[h] = sign
        if self._n_motion:
            a = self._M @ self.theta[t]  # px
            w[self._m0:] = sign * motion_regressors(self.theta[t], a)[0, :self._n_motion]
        if self.plan.method == "C":
            e = np.exp(-1j * self.theta[t])  # undoes the carrier's advance (eq. 2)
            w[2 + 4 * h:6 + 4 * h] = sign * np.array([e[0].real, e[0].imag, e[1].real,
                                                      e[1].imag])
            self.wsum[h] += sign * e
        if t == 0 and np.array_equal(arr, self.origin):
            return  # the origin itself: d = 0 adds nothing to the pixel sums
        raw = self._raw_dtype(arr)
        if raw != self._buf.dtype or self._buf.shape[0] == 0:
            self._flush()
            self._buf = self._batch(raw)
        b = len(self._w)
        row = self._buf[b].reshape(self.shape)
        if raw == np.float64:
            np.subtract(arr, self.origin, out=row)
        else:
            np.copyto(row, arr)  # the compiled loop takes the difference (_flush)
        self._signs.append(sign)  # the squares are summed by batch (_flush)
        self._w.append(w)
        if len(self._w) == self._buf.shape[0]:
            self._flush()

    @staticmethod
    def _raw_dtype(arr: np.ndarray) -> np.dtype:
        """How a frame waits in the batch: as read (integers of at most 16 bits, the
        compiled loop there to sum them), else as its float64 difference."""
        if exact_in_float32(arr.dtype) and compiled_loops() is not None:
            return arr.dtype
        return np.dtype(np.float64)

    def _batch(self, dtype) -> np.ndarray:
        """An empty batch of frames of ``dtype``: at most 16 frames and
        ``_BATCH_BYTES``. Method B's transforms dominate its pass, and its batch
        must add little to their memory: 4 raw integer frames (a quarter of one
        float64 frame each), else one frame."""
        H, W = self.shape
        dtype = np.dtype(dtype)
        most = 16 if self.plan.method != "B" else 4 if dtype.itemsize <= 2 else 1
        n = max(1, min(most, _BATCH_BYTES // (dtype.itemsize * H * W)))
        return np.empty((n, H * W), dtype=dtype)

    def _flush(self) -> None:
        b = len(self._w)
        if b == 0:
            return
        W = np.array(self._w)  # (b, rows)
        signs = np.array(self._signs)
        self._w.clear()
        self._signs.clear()
        D = self._buf[:b]
        if D.dtype != np.float64:  # raw frames: the compiled loop (gridstrain.phase._kernels)
            kern = compiled_loops()
            if kern is not None:
                kern.add_differences(self._buf, b, self.origin.reshape(-1), W, signs,
                                     self.lin, self.sq)
                return
            # the compiled loops switched off since the frames came: their differences
            D = np.subtract(D, self.origin.reshape(-1))
        # lin^T (HW, rows) += D^T (HW, b) @ W (b, rows), in place (Fortran views)
        blas.dgemm(1.0, D.T, W, beta=1.0, c=self.lin.T, overwrite_c=True)
        # sum_t sign_t d_t^2: the batch read once more, one temporary
        if b == 1:  # the frame's row is free once in lin: squared in place
            np.multiply(D[0], D[0], out=D[0])
            (np.add if signs[0] > 0 else np.subtract)(self.sq, D[0], out=self.sq)
            return
        if self._tmp is None:
            self._tmp = np.empty(D.shape[1])
        if np.all(signs > 0):  # frames added, none taken out: no weights
            np.einsum("bi,bi->i", D, D, out=self._tmp)
        else:
            np.einsum("bi,bi,b->i", D, D, signs, out=self._tmp)
        self.sq += self._tmp

    def __getstate__(self):
        # sent between Dask workers: the sums travel, not the batch buffer
        self._flush()
        state = self.__dict__.copy()
        state["_buf"] = (self._buf.shape, self._buf.dtype.str)
        state["_tmp"] = None
        return state

    def __setstate__(self, state):
        shape, dtype = state["_buf"]
        self.__dict__.update(state)
        self._buf = np.empty(shape, dtype=dtype)

    def merge(self, other: SeriesPass) -> SeriesPass:
        """A new pass holding the sums of ``self`` and ``other`` (another part of the
        same series, with the same origin); both are left unchanged."""
        if not np.array_equal(self.origin, other.origin):
            raise ValueError("passes over parts of a series must share their origin frame")
        common = self.records.keys() & other.records.keys()
        if common:
            raise ValueError(f"frames {sorted(common)[:5]} are in both parts")
        self._flush()
        other._flush()
        out = copy.copy(self)
        out._w, out._signs = [], []
        out._tmp = None
        out._buf = np.empty(self._buf.shape, dtype=self._buf.dtype)
        out.lin = self.lin + other.lin
        out.sq = self.sq + other.sq
        out.wsum = self.wsum + other.wsum
        out.records = {**self.records, **other.records}
        out.theta = {**self.theta, **other.theta}
        out.parts = {**self.parts, **other.parts}
        out.removed = self.removed | other.removed
        if other.dtype is not None:
            out.dtype = other.dtype if self.dtype is None else np.promote_types(
                self.dtype, other.dtype)
        if self.transforms is not None:
            if self.transforms.n == 0:
                out.transforms = other.transforms
            elif other.transforms.n:
                out.transforms = self.transforms.merge(other.transforms)
        return out

    # ------------------------------------------------------------------ results

    @property
    def kept(self) -> list[int]:
        """Indices of the frames in the sums, in order."""
        return sorted(set(self.records) - self.removed)

    def screen(self, *, max_saturation: float = 0.01) -> FrameScreen:
        """The screening of every frame added (:func:`gridstrain.stacks.screening.decide`);
        the pass must hold frames ``0 .. T-1``."""
        T = self.plan.n_frames
        if sorted(self.records) != list(range(T)):
            missing = sorted(set(range(T)) - set(self.records))
            raise ValueError(f"the pass lacks frames {missing[:5]} of {T}")
        return decide([self.records[t] for t in range(T)], self.probe,
                      max_saturation=max_saturation)

    def statistics(self) -> SeriesStatistics:
        """Mean image and noise variance of the kept frames (the variance's fit: module
        docstring)."""
        if self._sq is None or self._lin.shape[0] < self._m0 + self._n_motion:
            raise ValueError("the pixel sums were released")
        self._flush()
        kept = self.kept
        T = len(kept)
        if T == 0:
            raise ValueError("no frame left in the sums")
        if T < 2 and isinstance(self._lin, _Zeros):
            # the origin alone (a one-frame state): no frame entered its sums (they are
            # still zeros to come), which are not read
            return SeriesStatistics(self.origin + 0.0, None, "unavailable (a single frame)",
                                    1)
        H, W = self.shape
        s1 = self.lin[0] + self.lin[1]  # (HW,)
        mean = self.origin + s1.reshape(H, W) / T
        if T < 2:
            return SeriesStatistics(mean, None, "unavailable (a single frame)", 1)
        if self._n_motion:
            theta = np.array([self.theta[t] for t in kept]).reshape(T, 2)
            g = motion_regressors(theta, theta @ self._M.T)[:, :self._n_motion]
        else:  # nothing to regress on: a plain temporal variance
            g = np.zeros((T, 0))
        gbar = g.mean(axis=0)
        B, cols, stops = nested_motion_fits(g, gbar, min_dof=1)
        names = [n for grp in MOTION_TERMS for n in grp]
        # per pixel, the residual sum of squares of the nested fit of the first k
        # orthonormal regressors is svv - sum_{i<k} z_i^2, z = B^T s (module docstring)
        motion = self.lin[self._m0:]
        n = H * W
        # the choice from _FIT_BAND pixels drawn at random (a fixed draw) where the
        # image has more: their mean is the image's within 0.1 % (40 dof), and a
        # regular stride could fall on one phase of the grid
        pick_px = (slice(None) if n <= _FIT_BAND else
                   np.sort(np.random.default_rng(0).choice(n, _FIT_BAND, replace=False)))
        svv, z2 = self._band(pick_px, s1, gbar, B, cols, motion, T)
        z2 = np.concatenate([[0.0], np.cumsum(z2)])
        means = (svv.sum() - z2[stops]) / np.array([T - 1 - k for k in stops])
        k = stops[pick_motion_fit(means, stops, cols)]
        var = np.empty(n)
        for i0 in range(0, n, _FIT_BAND):
            i1 = min(i0 + _FIT_BAND, n)
            svv, z2 = self._band(slice(i0, i1), s1, gbar, B[:k, :k], cols[:k], motion, T,
                                 per_pixel=True)
            var[i0:i1] = svv - z2.sum(axis=0) if k else svv
        dof = T - 1 - k
        terms = tuple(names[c] for c in cols[:k])
        n_harm = sum(1 for c in cols[:k] if c >= len(MOTION_TERMS[0]))
        if k == 0:
            how = f"temporal variance, vibrations not removed ({dof} dof)"
        elif n_harm == 0:
            how = f"temporal variance, shifts regressed out ({dof} dof)"
        else:
            how = (f"temporal variance, shifts and {n_harm} terms of the carriers' "
                   f"harmonics regressed out ({dof} dof)")
        return SeriesStatistics(mean, np.maximum(var, 0.0).reshape(H, W) / dof, how, T,
                                regressors=terms, dof=dof)

    def _band(self, px, s1, gbar, B, cols, motion, T, *, per_pixel=False):
        """Pixels ``px`` (a slice or indices of the flat image): the centred sum of
        squares ``svv`` and the squared coordinates ``z^2`` of the series on the
        orthonormal regressors ``B`` (per pixel with ``per_pixel``, else summed)."""
        s1b = s1[px]
        svv = self.sq[px] - s1b * s1b / T
        if not cols:
            return svv, np.zeros((0, svv.size)) if per_pixel else np.zeros(0)
        # s = sum_t (g_t - gbar) d_t = sum_t g_t d_t - gbar S_d, on the kept columns
        sc = motion[cols, px] if isinstance(px, slice) else motion[np.ix_(cols, px)]
        sc = sc - gbar[cols, None] * s1b
        z = B.T @ sc
        z *= z
        return svv, z if per_pixel else z.sum(axis=1)

    def release(self, *, keep_halves: bool = False, keep_method: bool = True) -> None:
        """Free the pixel sums once :meth:`statistics` is taken, keeping what the
        results still to come need: with ``keep_method`` method B's transforms and
        method C's realigned sums, with ``keep_halves`` the halves' sums
        (:meth:`half_means`; method C's halves are in its realigned sums). May be
        called again to free more. Afterwards only what was kept can be asked for."""
        self._flush()
        self.sq = self._tmp = None
        self._buf = np.empty((1, 0))
        if not keep_method:
            self.transforms = None
        if self._lin is None:
            return
        if self.plan.method == "C" and (keep_method or keep_halves):
            keep = self._m0  # its rows follow the halves' sums in the same array
        elif keep_halves:
            keep = 2
        else:
            self.lin = self.origin = None  # the origin only completes the sums
            return
        if self._lin.shape[0] > keep:  # the motion's sums: only the variance needs them
            self.lin = (_Zeros((keep, self._lin.shape[1])) if isinstance(self._lin, _Zeros)
                        else np.array(self._lin[:keep]))

    def half_counts(self) -> tuple[int, int]:
        """Frames kept in each half."""
        kept = self.kept
        n1 = sum(1 for t in kept if self._half(t) == 0)
        return n1, len(kept) - n1

    def half_means(self, halves: tuple = (0, 1)) -> list[np.ndarray]:
        """The mean images (H, W) of the kept frames of each half of ``halves``."""
        if self.lin is None:
            raise ValueError("the halves' sums were released (release(keep_halves=True) "
                             "keeps them)")
        self._flush()
        counts = self.half_counts()
        return [self.origin + self.lin[h].reshape(self.shape) / counts[h] for h in halves]

    def method_b(self, *, release: bool = False) -> StackResult:
        """Method B's result over the kept frames (:func:`gridstrain.stacks.method_b`);
        with ``release`` it is computed in the sums' buffers, which the pass gives up
        (no second method-B result can be asked for)."""
        if self.plan.method != "B":
            raise ValueError("the pass was not planned for method B")
        if self.transforms is None:
            raise ValueError("method B's sums were released")
        if self.transforms.n == 0:
            raise ValueError("no frame left in the sums")
        if release:  # the maps take the place of the sums (half the memory)
            transforms, self.transforms = self.transforms, None
            return transforms.result(consume=True)
        return self.transforms.result()

    def method_c(self, *, mask=None, halves: tuple = (0, 1)) -> StackResult:
        """Method C's result over the kept frames of ``halves``
        (:func:`gridstrain.stacks.method_c`) through the plan's window, the frames
        realigned by their shifts centred on the mean position of all the kept
        frames."""
        if self.plan.method != "C":
            raise ValueError("the pass was not planned for method C")
        if self.lin is None:
            raise ValueError("method C's sums were released")
        self._flush()
        kept = self.kept
        sel = [t for t in kept if self._half(t) in halves]
        if not sel:
            raise ValueError("no frame left in the sums")
        H, W = self.shape
        # the phase of the grid at the kept frames' mean position (eq. 2): the weights
        # are turned by it rather than recomputed
        c = np.array([self.records[t].coefficients for t in kept])
        cbar = c.mean(axis=0)
        phi = np.angle(c * np.conj(cbar))  # (T, 2), as gridstrain.stacks.vibration centres them
        centre = np.angle(cbar * np.conj(self._c0)) + phi.mean(axis=0)
        lin = sum(self.lin[2 + 4 * h:6 + 4 * h] for h in halves)  # (4, HW)
        wsum = sum(self.wsum[h] for h in halves)  # (2,)
        n = len(sel)

        def averages(turn):
            z = np.empty((2, H * W), dtype=np.complex128)
            for j in range(2):
                # sum_t e_t v_t = sum_t e_t d_t + origin sum_t e_t
                z[j] = lin[2 * j] + 1j * lin[2 * j + 1]
                z[j] += wsum[j] * self.origin.ravel()
                z[j] *= np.exp(1j * turn[j]) / n
            return z.reshape(2, H, W)

        # the shifts the weights realign, centred on the kept frames' mean position
        used_all = (phi - phi.mean(axis=0)) @ self._M.T
        used = used_all[[self._half(t) in halves for t in kept]]  # sel's rows, in order
        parts = [self.parts[t] for t in sel if t in self.parts]
        dtype = np.float64 if self.dtype is None else self.dtype
        if dtype.kind != "f":
            dtype = np.dtype(np.float64)
        return compensated_result(averages, centre, n, dtype, used, parts,
                                   self.plan.lattice, self.plan.window, mask=mask,
                                   warnings=())

    def __repr__(self) -> str:
        return (f"SeriesPass(frames={len(self.records)}, removed={len(self.removed)}, "
                f"method={self.plan.method!r}, shape={self.shape})")

