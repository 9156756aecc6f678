"""The accumulators of a stack, frame by frame: the mean image, method B's sums of unit
phasors, moduli and derivatives (``PhaseMean``), method C's compensated sums, and the
:class:`StackResult` they end in.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import blas

from .._progress import Finding
from .._validation import (
    as_image,
    as_shifts,
    exact_in_float32,
    float_dtype,
    image_array,
)
from ..phase import (
    Lattice,
    PhaseMaps,
    Window,
    Workspace,
    compiled_loops,
    transform,
    wft,
    wft_complex,
)
from .screening import FrameProbe, FrameScreen, decide
from .vibration import RigidProbe

# Method C sums the frames by batches, one matrix product each (see
# _CompensatedMean): the batch buffer holds at most this many bytes (and 16 frames).
_BATCH_BYTES = 2**26


# Method C warns when the weights miss the frames' carriers by more than this RMS
# phase (rad): the quadrants of a frame move apart (motion not a translation), or
# given shifts disagree with the carriers. The part it misses averages as under
# method A: 0.05 rad lowers the modulus by 0.1 % (eq. 14) and leaves phase offsets
# of up to 0.05 / sqrt(T) rad that vary across the field.
_MAX_WEIGHT_PHASE_ERROR = 0.05


# Method C warns when the vibrations widen the effective window (the phase maps,
# which move with the frames, are averaged over the vibrations' spread: variance
# sigma^2 + Var(a)) by more than 1 %, i.e. Std(a) > 0.14 sigma (0.7 px at sigma = 5).
_MAX_WINDOW_WIDENING = 0.01


@dataclass(frozen=True, eq=False)
class StackResult:
    """Phases and phase derivatives of a stack of ``n_frames`` grid images.

    Attributes
    ----------
    maps : PhaseMaps
        Method A: the transform of the averaged image. Method B: ``psi`` is the
        mean modulus times the unit circular mean of the frames' ``psi``, ``dphi``
        the arithmetic mean of their derivatives (rad/px), ``valid`` the AND of
        their ``valid`` maps. Either way it feeds the kinematics unchanged.
    n_frames : int
        Number of images averaged, ``T``.
    method : {"A", "B", "C"}
        How they were averaged.
    mean_image : (H, W) float64 ndarray or None
        The averaged image, grey levels (method A only).
    resultant : (2, H, W) float64 ndarray or None
        Method B only: length of the mean unit phasor ``|mean_t psi_t / |psi_t||``
        for each wave vector, in [0, 1]. ``1 - resultant`` is about half the
        variance of the frames' phases (rad^2), a measure of how much they scatter.
    shifts : (T, 2) float64 ndarray or None
        Method C only: the rigid shifts ``(alpha_t, beta_t)`` the frames were
        realigned by, px (frame ``t`` is ``s(x + alpha_t, y + beta_t)``, eq. 2).
        Measured ones are known modulo a period along each wave vector (all the
        weights need): beyond half a period from the first frame they wrap.
    motion_residual : float or None
        Method C only: RMS departure of the frames' motion from a rigid translation,
        px (spread of the shifts of the frame's quadrants about its shift, see
        :func:`method_c`); None when not measured (frames under 64 px, one frame).
    warnings : tuple of Finding
        What the caller must know about this result, each a finding
        (:class:`gridstrain.Finding`, its sentence the ``str``): frames the screening
        flagged, which are in the average (code ``screening.flagged``); method C's
        motion that is not rigid, vibrations that widen the window, or given shifts
        that disagree with the frames (code ``vibration``).
    screening : FrameScreen or None
        What :func:`gridstrain.stacks.screening.decide` found on each frame (no grid, low
        contrast, slipped, of another state, clipped), None when not screened.
    """

    maps: PhaseMaps
    n_frames: int
    method: str
    mean_image: np.ndarray | None = None
    resultant: np.ndarray | None = None
    shifts: np.ndarray | None = None
    motion_residual: float | None = None
    warnings: tuple[Finding, ...] = ()
    screening: FrameScreen | None = None

    def __post_init__(self):
        for name in ("mean_image", "resultant", "shifts"):
            arr = getattr(self, name)
            if arr is not None:
                arr.flags.writeable = False

    def __repr__(self) -> str:
        H, W = self.maps.shape
        return (f"StackResult(method {self.method}, {self.n_frames} frames of {H}x{W}, "
                f"sigma={self.maps.sigma:.4g} px, {self.maps.valid.mean():.1%} valid)")


def with_screening(res: StackResult, records, probe: FrameProbe) -> StackResult:
    """``res`` with the screening of its frames' ``records`` (in frame order, made by
    ``probe``) and a warning naming the flagged frames, which it averaged."""
    try:
        sc = decide(records, probe)
    except ValueError as exc:  # no frame shows a grid at the lattice's wave vectors
        return replace(res, warnings=(*res.warnings,
                                      Finding("screening.flagged", f"frames: {exc}")))
    bad = sc.flagged
    if not bad:
        return replace(res, screening=sc)
    warning = (f"{len(bad)} of {sc.n_frames} frame(s) flagged by the screening and "
               f"averaged all the same: {sc.listing()}; leave them out of frames, or "
               "measure with gridstrain.measure_series (gridstrain measure), which "
               "excludes them")
    return replace(res, screening=sc,
                   warnings=(*res.warnings, Finding("screening.flagged", warning,
                                                    flagged=list(bad))))


class MeanImage:
    """Running float64 sum of frames, and the precision of their maps."""

    def __init__(self):
        self.total = None
        self.n = 0
        self.dtype = None  # float32 while every frame is float32 (conventions)

    def add(self, img: np.ndarray) -> None:
        if self.total is None:
            self.total = np.zeros(img.shape, dtype=np.float64)
            self.dtype = img.dtype
        self.total += img  # float64 accumulation whatever the frame dtype
        self.dtype = np.promote_types(self.dtype, img.dtype)
        self.n += 1

    def mean(self) -> np.ndarray:
        return self.total / self.n

    def transform(self, lattice: Lattice, **kwargs) -> tuple[PhaseMaps, np.ndarray]:
        """Method A: the WFT of the float64 mean, taken in the frames' precision."""
        avg = self.mean()
        return wft(avg.astype(self.dtype, copy=False), lattice, **kwargs), avg


class FrameOrder:
    """Makes the frames of a stack add each block of rows in frame order.

    Frame ``i`` may add its block ``key`` once frame ``i - 1`` has added it, so the
    sums come out bit for bit as one thread would make them, however many threads
    transform frames at once. Two threads rarely wait: each adds a block while the
    other computes.
    """

    def __init__(self):
        self._cond = threading.Condition()
        self._done: dict = {}
        self._failed = math.inf  # index of the first frame that failed

    def wait(self, key, i: int) -> None:
        with self._cond:
            self._cond.wait_for(lambda: self._failed < i or self._done.get(key, 0) == i)
            if self._done.get(key, 0) != i:
                raise RuntimeError(f"frame {self._failed} of the stack failed")

    def release(self, key, i: int) -> None:
        with self._cond:
            self._done[key] = i + 1
            self._cond.notify_all()

    def fail(self, i: int) -> None:
        """Frame ``i`` failed: wake the frames after it, with an error."""
        with self._cond:
            self._failed = min(self._failed, i)
            self._cond.notify_all()


def _transform_input(frame, name: str = "frame") -> tuple[np.ndarray, np.dtype]:
    """``(image to transform, precision of the maps)`` for one of method B's frames.

    Integer frames of at most 16 bits are exact in float32 and are transformed in
    float32, at half the cost; their maps stay float64, averaged from float64 sums
    (:mod:`gridstrain.conventions`, precision). Anything else is transformed in its
    precision (:func:`gridstrain._validation.as_image`).
    """
    raw = image_array(frame, name)
    if exact_in_float32(raw.dtype):
        return as_image(raw, name, dtype=np.float32), np.dtype(np.float64)
    img = as_image(raw, name)
    return img, img.dtype


class PhaseMean:
    """Running sums of the frames' WFTs for method B.

    Each frame is transformed block of rows by block of rows and its contributions
    (unit phasors, moduli, derivatives) are added while the block is in cache, so a
    frame's maps are never whole in memory. Several threads may add frames at once
    (``index`` and ``order``); each keeps its own scratch arrays from one frame to
    the next.
    """

    def __init__(self):
        self.n = 0
        self._lock = threading.Lock()
        self._local = threading.local()

    def __getstate__(self):
        # sent between Dask workers: the sums travel, the scratch arrays stay behind
        state = self.__dict__.copy()
        del state["_lock"], state["_local"]
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._lock = threading.Lock()
        self._local = threading.local()

    def _start(self, shape, lattice: Lattice, window: Window, dtype) -> None:
        H, W = shape
        self.unit = np.zeros((2, H, W), dtype=np.complex128)
        self.mod = np.zeros((2, H, W), dtype=np.float64)
        self.dphi = np.zeros((2, 2, H, W), dtype=np.float64)
        # frames in which each pixel is invalid: a count, so that a frame taken out
        # again (remove=True) takes its invalid pixels with it
        self.invalid = np.zeros((H, W), dtype=np.int32)
        self.lattice = lattice
        self.sigma = window.sigma
        self.dtype = np.dtype(dtype)

    def add_frame(self, img, lattice: Lattice, window: Window, *, mask=None,
                  index: int = 0, order: FrameOrder | None = None,
                  remove: bool = False) -> None:
        """Add the WFT of ``img`` through ``window`` (as :func:`~gridstrain.phase.wft`
        computes it).

        With ``order``, ``index`` is the frame's rank in the stack (from 0), and its
        blocks are added after those of frame ``index - 1``. ``remove=True`` takes
        out a frame added before (its contributions are subtracted).
        """
        img, precision = _transform_input(img, f"frames[{index}]")
        H, W = img.shape
        with self._lock:
            if not hasattr(self, "unit"):
                self._start((H, W), lattice, window, precision)
            elif self.unit.shape[1:] != (H, W):
                raise ValueError(f"frames must all have the shape {self.unit.shape[1:]}, "
                                 f"got {(H, W)}")
            # float32 maps only if every frame is float32 (gridstrain.conventions)
            self.dtype = np.promote_types(self.dtype, precision)
        work = getattr(self._local, "work", None)
        if work is None:
            work = self._local.work = Workspace()
        # float64 views (..., 2) of the complex sums: real arithmetic on them avoids
        # numpy's slow mixed complex-by-real loops
        unit = self.unit.view(np.float64).reshape(2, H, W, 2)
        accumulate = np.subtract if remove else np.add  # a frame taken out, or added
        kern = compiled_loops()

        def sink(j, r0, r1, psi, dphi, mod):
            h = r1 - r0
            if kern is not None:  # one compiled pass, the same sums bit for bit
                if order is not None:
                    order.wait((j, r0), index)
                kern.add_unit_sums(psi.view(psi.real.dtype), mod, dphi,
                                   unit[j, r0:r1].reshape(h, 2 * W), self.mod[j, r0:r1],
                                   self.dphi[j, :, r0:r1], mod.dtype.type(1),
                                   -1.0 if remove else 1.0)
                if order is not None:
                    order.release((j, r0), index)
                return
            # unit phasor psi / |psi|, 0 where psi = 0 (no signal: no direction)
            inv = work.get("inv", (h, W), np.float64)
            inv.fill(0.0)
            np.divide(1.0, mod, out=inv, where=mod > 0)
            u = work.get("u", (h, W, 2), np.float64)
            np.multiply(psi.view(psi.real.dtype).reshape(h, W, 2), inv[..., None], out=u)
            if not mod.all():  # derivatives 0/0 where psi = 0: they add nothing
                dphi[:, mod == 0] = 0
            if order is not None:
                order.wait((j, r0), index)
            for total, part in ((unit[j, r0:r1], u), (self.mod[j, r0:r1], mod),
                                (self.dphi[j, :, r0:r1], dphi)):
                accumulate(total, part, out=total)
            if order is not None:
                order.release((j, r0), index)

        valid = transform(img, lattice, window, mask=mask, sink=sink, work=work, checked=True)
        with self._lock:
            accumulate(self.invalid, ~valid, out=self.invalid, casting="unsafe")
            self.n += -1 if remove else 1

    def merge(self, other: PhaseMean) -> PhaseMean:
        """A new accumulator holding the sums of ``self`` and ``other`` (both
        non-empty, unchanged)."""
        return self._combined(other)

    def _combined(self, other: PhaseMean | None = None) -> PhaseMean:
        """A new accumulator with the sums of ``self`` (copied) plus ``other``'s."""
        out = PhaseMean()
        out.n = self.n + (0 if other is None else other.n)
        for name in ("unit", "mod", "dphi", "invalid"):
            mine = getattr(self, name)
            setattr(out, name, mine.copy() if other is None else mine + getattr(other, name))
        out.lattice, out.sigma = self.lattice, self.sigma
        out.dtype = self.dtype if other is None else np.promote_types(self.dtype, other.dtype)
        return out

    def result(self, *, consume: bool = False) -> StackResult:
        """Method B's maps from the sums. ``consume``: computed in the sums' own
        buffers, which the accumulator gives up (it holds no sums afterwards);
        otherwise in a copy of them, the sums kept."""
        return (self if consume else self._combined())._consume()

    def _consume(self) -> StackResult:
        # in place: the maps take the sums' buffers
        n, unit, mod, dphi = self.n, self.unit, self.mod, self.dphi
        invalid = self.invalid
        del self.unit, self.mod, self.dphi, self.invalid
        self.n = 0
        np.divide(unit, n, out=unit)
        r = np.abs(unit)
        with np.errstate(invalid="ignore", divide="ignore"):
            np.divide(unit, r, out=unit)
        unit[~(r > 0)] = 0
        np.multiply(unit, np.divide(mod, n, out=mod), out=unit)
        del mod
        psi = unit.astype(np.result_type(self.dtype, np.complex64), copy=False)
        dphi = np.divide(dphi, n, out=dphi).astype(self.dtype, copy=False)
        valid = (invalid == 0) & np.all(r > 0, axis=0)
        maps = PhaseMaps(psi=psi, dphi=dphi, valid=valid, lattice=self.lattice,
                         sigma=self.sigma)
        return StackResult(maps=maps, n_frames=n, method="B", resultant=r)


class _CompensatedMean:
    """Running float64 sums ``sum_t exp(-i theta_tj) v_t`` for method C.

    ``theta_tj = 2 pi k_j . a_t`` is the phase by which frame ``t``'s rigid shift
    ``a_t`` advances carrier ``j`` (:mod:`gridstrain.stacks.vibration`). The frames are
    copied into a buffer of ``B`` rows and added by one matrix product per batch,
    ``S (4, HW) += W (4, B) @ F (B, HW)`` with the rows of ``W`` the real and
    imaginary parts of the two weights: each frame is read once, and the sums are
    read and written once per ``B`` frames instead of four times per frame.
    """

    def __init__(self, lattice: Lattice):
        self.lattice = lattice
        self.n = 0
        self.thetas: list[np.ndarray] = []

    def _start(self, img: np.ndarray) -> None:
        H, W = img.shape
        self.shape = (H, W)
        self.dtype = float_dtype(img.dtype)
        self.sums = np.zeros((4, H * W), dtype=np.float64)
        batch = max(1, min(16, _BATCH_BYTES // (8 * H * W)))
        self.buf = np.empty((batch, H * W), dtype=np.float64)
        self.pending = 0

    def load(self, img: np.ndarray, name: str) -> np.ndarray:
        """Copy frame ``img`` (H, W), any real dtype, into the batch as float64 (the
        conversion is the copy) and return that copy, (H, W); :meth:`add` commits it."""
        if self.n == 0:
            self._start(img)
        elif img.shape != self.shape:
            raise ValueError(f"frames must all have the shape {self.shape}, got {img.shape}")
        row = self.buf[self.pending].reshape(self.shape)
        np.copyto(row, img, casting="unsafe")
        if img.dtype.kind == "f" and not np.isfinite(row).all():
            bad = int(np.count_nonzero(~np.isfinite(row)))
            raise ValueError(f"{name} must be finite, got {bad} NaN or infinite pixel(s)")
        return row

    def add(self, shift) -> None:
        """Add the frame just loaded, whose rigid shift is ``shift`` (2,) px."""
        self.pending += 1
        self.thetas.append(2 * math.pi * self.lattice.K @ np.asarray(shift, dtype=float))
        self.n += 1
        if self.pending == self.buf.shape[0]:
            self._flush()

    def _flush(self) -> None:
        b = self.pending
        if b == 0:
            return
        theta = np.array(self.thetas[self.n - b:self.n])  # (b, 2)
        w = np.empty((4, b))
        # exp(-i theta) undoes the carrier's advance exp(+i theta) (eq. 2)
        w[0], w[1] = np.cos(theta[:, 0]), -np.sin(theta[:, 0])
        w[2], w[3] = np.cos(theta[:, 1]), -np.sin(theta[:, 1])
        # S^T (HW, 4) += F^T (HW, b) @ W^T (b, 4), in place (Fortran views of C arrays)
        blas.dgemm(1.0, self.buf[:b].T, w.T, beta=1.0, c=self.sums.T, overwrite_c=True)
        self.pending = 0

    def averages(self, centre: np.ndarray) -> np.ndarray:
        """The two weighted means (2, H, W) complex, each turned by ``exp(+i centre_j)``."""
        self._flush()
        H, W = self.shape
        z = (self.sums[0::2] + 1j * self.sums[1::2]) / self.n
        z *= np.exp(1j * np.asarray(centre))[:, None]
        return z.reshape(2, H, W)


class MethodC:
    """Method C over a stream: shifts (measured or given), rigidity, sums, result."""

    def __init__(self, lattice: Lattice, shifts=None):
        self.acc = _CompensatedMean(lattice)
        self.lattice = lattice
        self.given = None if shifts is None else _check_shifts(shifts)
        self.probe = None
        self.measured: list[np.ndarray] = []
        self.parts: list[np.ndarray] = []

    def add(self, img: np.ndarray, name: str = "frame") -> None:
        """Add a frame (H, W) of any real dtype (checked with
        :func:`~gridstrain._validation.image_array`; finiteness is checked here)."""
        t = self.acc.n
        row = self.acc.load(img, name)
        if self.probe is None:
            self.probe = RigidProbe(self.lattice, img.shape)
        shift, parts = self.probe(row)
        self.measured.append(shift)
        if parts is not None:
            self.parts.append(parts)
        if self.given is not None:
            if t >= len(self.given):
                raise ValueError(f"shifts must have one row per frame: got {len(self.given)} "
                                 f"rows for more frames")
            shift = self.given[t]
        self.acc.add(shift)

    def result(self, window: Window, *, mask=None) -> StackResult:
        n = self.acc.n
        K = self.lattice.K
        measured = np.array(self.measured)
        warnings = []
        if self.given is None:
            # measured relative to the first frame: centre them, so that the phase is
            # that of the grid at the stack's mean position (the only position the
            # frames define), by turning the sums rather than re-weighting
            mean = measured.mean(axis=0)
            used = measured - mean
            centre = 2 * math.pi * K @ mean
        else:
            used = self.given[:n]
            centre = np.zeros(2)
            # the weights only need 2 pi k.a modulo 2 pi: compare on the circle
            d = 2 * math.pi * (used - measured) @ K.T  # (n, 2)
            d = np.angle(np.exp(1j * d) * np.conj(np.mean(np.exp(1j * d), axis=0)))
            miss = float(np.sqrt(np.mean(d**2)))
            if n > 1 and miss > _MAX_WEIGHT_PHASE_ERROR:
                warnings.append(Finding(
                    "vibration",
                    f"method C: the given shifts disagree with the frames' carrier phases "
                    f"by {miss:.3g} rad RMS (beyond {_MAX_WEIGHT_PHASE_ERROR} rad); the "
                    f"frames are realigned with the wrong phases. Check that the shifts "
                    f"follow eq. (2) (frame t is s(x + a_t)) and are in px, or let "
                    f"method C measure them", disagreement_rad=miss))
        return compensated_result(lambda c: self.acc.averages(c), centre, n, self.acc.dtype,
                                   used, self.parts, self.lattice, window, mask=mask,
                                   warnings=warnings)


def compensated_result(averages, centre, n: int, dtype, used: np.ndarray, parts: list,
                        lattice: Lattice, window: Window, *, mask,
                        warnings: list) -> StackResult:
    """Method C's maps from its realigned sums, transformed through ``window``:
    ``averages(centre)`` gives the two weighted means (2, H, W) turned by
    ``exp(+i centre)``; ``used`` (n, 2) are the
    shifts the weights used, ``parts`` the frames' quadrant shifts (n, 4, 2) for
    the rigidity check (or fewer than ``n``: not checked)."""
    K = lattice.K
    warnings = list(warnings)
    residual = None
    if n > 1 and len(parts) == n:
        P = np.array(parts)  # (n, 4, 2)
        R = P - P.mean(axis=1, keepdims=True)  # departure from the frame's shift
        R -= R.mean(axis=0)  # static differences: the grid's own modulation
        residual = float(np.sqrt(np.mean(np.sum(R**2, axis=2))))
        miss = 2 * math.pi * float(np.max(np.hypot(K[:, 0], K[:, 1]))) * residual
        if miss > _MAX_WEIGHT_PHASE_ERROR:
            worst = int(np.argmax(np.sum(R**2, axis=(1, 2))))
            warnings.append(Finding(
                "vibration",
                f"method C: the frames' motion is not a rigid translation: the "
                f"quadrants of a frame move apart by {residual:.3g} px RMS (worst: "
                f"frame {worst}), i.e. {miss:.3g} rad on the carrier. Only the "
                f"translation is compensated; the rest (rotation, non-rigid "
                f"vibration) averages as under method A, with its contrast loss "
                f"and phase offsets that now vary across the field",
                residual_px=residual, worst_frame=worst))
    s = window.sigma
    spread = float(np.sqrt(np.mean(np.sum((used - used.mean(axis=0)) ** 2, axis=1)) / 2))
    widening = math.sqrt(1 + spread**2 / s**2) - 1
    if widening > _MAX_WINDOW_WIDENING:
        warnings.append(Finding(
            "vibration",
            f"method C: vibrations of {spread:.3g} px RMS move the phase maps under the "
            f"window: the maps are those of a window {widening:.1%} wider than sigma = "
            f"{s:.3g} px (variance sigma^2 + Var(a)); the spatial resolution is "
            f"that much coarser (as for methods A and B)", spread_px=spread,
            widening=widening))
    maps = wft_complex(averages(centre), lattice, mask=mask, dtype=dtype, **window.options())
    return StackResult(maps=maps, n_frames=n, method="C",
                       shifts=np.array(used, dtype=np.float64), motion_residual=residual,
                       warnings=tuple(warnings))


def _check_shifts(shifts) -> np.ndarray:
    return as_shifts(shifts, "shifts")
