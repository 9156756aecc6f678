"""Stacks of grid images: averaging before (method A) or after (method B) the WFT,
or after realigning the frames' carriers (method C).

A stack is ``T`` images of the same, static specimen, each translated by an unknown
vibration (the founding paper's eq. 2). The paper proves (§2.2) that the windowed
Fourier transform of the *averaged* image (method A) gives phase derivatives whose
noise falls as ``1/sqrt(T)`` whatever the vibrations, and phases offset by a
spatially constant ``delta`` (eqs. 26-30); averaging the phases and derivatives of
every image instead (method B, §2.3) gives the same precision at ``T`` times the
cost. Method C (not in the paper) weights each frame by the phasor that undoes its
measured rigid shift on each carrier before averaging, and transforms that complex
average: method B's precision without vibration offset or contrast loss, at about
twice method A's cost. Frames are consumed one at a time: a stack is never held in
memory. The conventions are those of :mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import itertools
import math
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import blas

from .._progress import Progress, null_progress
from .._threads import map_bounded, one_blas_thread
from .._validation import (
    as_image,
    as_int_tuple,
    as_shifts,
    check_choice,
    check_type,
    check_workers,
    float_dtype,
    image_array,
)
from ..phase._transform import Workspace, _kernels, transform
from ..phase.lattice import Lattice
from ..phase.window import Window
from ..wft import DEFAULT_MARGIN, PhaseMaps, wft, wft_complex
from .screening import FrameProbe, FrameScreen, decide
from .vibration import RigidProbe

__all__ = [
    "StackResult",
    "correct_phases",
    "mean_image",
    "method_a",
    "method_b",
    "method_c",
    "prefix_stacks",
]

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
    warnings : tuple of str
        What the caller must know about this result: frames the screening flagged
        (they are in the average), method C's motion that is not rigid or given
        shifts that disagree with the frames.
    screening : FrameScreen or None
        What :func:`gridstrain.screening.decide` found on each frame (no grid, low
        contrast, slipped, of another state, clipped), None when not screened.
    """

    maps: PhaseMaps
    n_frames: int
    method: str
    mean_image: np.ndarray | None = None
    resultant: np.ndarray | None = None
    shifts: np.ndarray | None = None
    motion_residual: float | None = None
    warnings: tuple[str, ...] = ()
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


def _frames(frames, *, convert: bool = True) -> Iterator[tuple[int, np.ndarray, int | None]]:
    """Validate frames lazily: yields ``(index, frame, total or None)``; with
    ``convert=False`` the frames keep their dtype and their finiteness is the
    caller's to check (see :func:`~gridstrain._validation.image_array`)."""
    if isinstance(frames, np.ndarray):
        if frames.ndim != 3:
            raise ValueError(f"frames must be a (T, H, W) array or an iterable of (H, W) "
                             f"images, got an array of shape {frames.shape}")
    elif not isinstance(frames, Iterable):
        raise TypeError(f"frames must be an iterable of 2-D images, got "
                        f"{type(frames).__name__}")
    try:
        total = len(frames)  # type: ignore[arg-type]
    except TypeError:
        total = None
    shape = None
    for i, frame in enumerate(frames):
        if convert:
            img = as_image(frame, f"frames[{i}]", allow_uniform=True)
        else:
            img = image_array(frame, f"frames[{i}]")
        if shape is None:
            shape = img.shape
        elif img.shape != shape:
            raise ValueError(f"frames[{i}] must have the shape of frames[0], {shape}, got "
                             f"{img.shape}")
        yield i, img, total


def _report(progress: Progress, i: int, total: int | None, what: str) -> None:
    if total:
        progress((i + 1) / total, f"{what}: frame {i + 1}/{total}")
    else:
        progress(0.0, f"{what}: frame {i + 1}")


def _check_counts(counts) -> list[int]:
    values = list(as_int_tuple(counts, "counts", minimum=1))
    if any(b <= a for a, b in itertools.pairwise(values)):
        raise ValueError(f"counts must be strictly increasing, got {counts!r}")
    return values


class _Screener:
    """Probes each frame of a stack as it is read, in frame order, and says at the end
    which frames :func:`gridstrain.screening.decide` flags.

    The bare methods cannot leave a flagged frame out (their frames may be a stream
    read once): they name it in the result's warnings instead, so that no average
    of a foreign, slipped, black or clipped frame comes back unannounced.
    """

    def __init__(self, lattice: Lattice, enabled: bool):
        self.lattice, self.enabled = lattice, bool(enabled)
        self.probe: FrameProbe | None = None
        self.records: list = []

    def frames(self, items: Iterator) -> Iterator:
        """``items`` of :func:`_frames`, each probed before it is handed on."""
        for item in items:
            if self.enabled:
                img = item[1]
                if self.probe is None:
                    self.probe = FrameProbe(self.lattice, img.shape)
                self.records.append(self.probe(img))
            yield item

    def result(self, res: StackResult) -> StackResult:
        """``res`` with the screening and a warning naming the flagged frames."""
        if not self.enabled or self.probe is None:
            return res
        return with_screening(res, self.records, self.probe)


def with_screening(res: StackResult, records, probe: FrameProbe) -> StackResult:
    """``res`` with the screening of its frames' ``records`` (in frame order, made by
    ``probe``) and a warning naming the flagged frames, which it averaged."""
    try:
        sc = decide(records, probe)
    except ValueError as exc:  # no frame shows a grid at the lattice's wave vectors
        return replace(res, warnings=(*res.warnings, f"frames: {exc}"))
    bad = sc.flagged
    if not bad:
        return replace(res, screening=sc)
    warning = (f"{len(bad)} of {sc.n_frames} frame(s) flagged by the screening and "
               f"averaged all the same: {sc.listing()}; leave them out of frames, or "
               "measure with gridstrain.measure_series (gridstrain measure), which "
               "excludes them")
    return replace(res, screening=sc, warnings=(*res.warnings, warning))


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
    if raw.dtype.kind in "ui" and raw.dtype.itemsize <= 2:
        return as_image(raw, name, dtype=np.float32), np.dtype(np.float64)
    img = as_image(raw, name)
    return img, img.dtype


class _PhaseMean:
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

    def _start(self, shape, lattice: Lattice, sigma, dtype) -> None:
        H, W = shape
        self.unit = np.zeros((2, H, W), dtype=np.complex128)
        self.mod = np.zeros((2, H, W), dtype=np.float64)
        self.dphi = np.zeros((2, 2, H, W), dtype=np.float64)
        # frames in which each pixel is invalid: a count, so that a frame taken out
        # again (remove=True) takes its invalid pixels with it
        self.invalid = np.zeros((H, W), dtype=np.int32)
        self.lattice = lattice
        self.sigma = float(lattice.pitch if sigma is None else sigma)
        self.dtype = np.dtype(dtype)

    def add_frame(self, img, lattice: Lattice, *, sigma=None, mask=None,
                  margin: float = DEFAULT_MARGIN, index: int = 0,
                  order: FrameOrder | None = None, remove: bool = False) -> None:
        """Add the WFT of ``img`` (as :func:`~gridstrain.wft.wft` computes it).

        With ``order``, ``index`` is the frame's rank in the stack (from 0), and its
        blocks are added after those of frame ``index - 1``. ``remove=True`` takes
        out a frame added before (its contributions are subtracted).
        """
        img, precision = _transform_input(img, f"frames[{index}]")
        H, W = img.shape
        with self._lock:
            if not hasattr(self, "unit"):
                self._start((H, W), lattice, sigma, precision)
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
        kern = _kernels()

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

        window = Window.for_lattice(lattice, sigma=sigma, margin=margin)
        valid = transform(img, lattice, window, mask=mask, sink=sink, work=work, checked=True)
        with self._lock:
            accumulate(self.invalid, ~valid, out=self.invalid, casting="unsafe")
            self.n += -1 if remove else 1

    def merge(self, other: _PhaseMean) -> _PhaseMean:
        """A new accumulator holding the sums of ``self`` and ``other`` (both
        non-empty, unchanged)."""
        return self._combined(other)

    def _combined(self, other: _PhaseMean | None = None) -> _PhaseMean:
        """A new accumulator with the sums of ``self`` (copied) plus ``other``'s."""
        out = _PhaseMean()
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


def mean_image(frames, *, progress: Progress | None = None) -> np.ndarray:
    """Average a stack of images, one frame at a time, in float64.

    Parameters
    ----------
    frames : iterable of (H, W) array_like, or (T, H, W) array
        The images, grey levels; any iterable (a generator, a list, a memory-mapped
        stack) is consumed once and never held whole. Not modified.
    progress : callable, optional
        ``progress(fraction, message)``; the fraction is known only when ``frames``
        has a length.

    Returns
    -------
    (H, W) float64 ndarray
        ``v_bar = (1/T) sum_t v_t``, grey levels.
    """
    return _average(frames, progress or null_progress, "averaging").mean()


def _average(frames, progress: Progress, what: str,
             screener: _Screener | None = None) -> MeanImage:
    """The streamed float64 sum of ``frames`` (each probed by ``screener``)."""
    acc = MeanImage()
    items = _frames(frames)
    with one_blas_thread():  # the screening's small products (gridstrain._threads)
        for i, img, total in (items if screener is None else screener.frames(items)):
            acc.add(img)
            _report(progress, i, total, what)
    if acc.n == 0:
        raise ValueError("frames must hold at least one image, got none")
    return acc


def method_a(frames, lattice: Lattice, *, sigma: float | None = None, mask=None,
             workers: int | None = None, screen: bool = True,
             progress: Progress | None = None) -> StackResult:
    """Method A: the windowed Fourier transform of the averaged image (paper §2.2).

    Parameters
    ----------
    frames : iterable of (H, W) array_like, or (T, H, W) array
        The stack, consumed one frame at a time (see :func:`mean_image`).
    lattice : Lattice
        Wave vectors of the grid.
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen.
    workers : int, optional
        Threads of the transform (default: the usable cores; see :func:`wft`).
    screen : bool
        Screen every frame as it is read (:mod:`gridstrain.screening`: no grid, low
        contrast, a slip, a frame of another state, clipping) and name the flagged
        ones in the result's ``warnings``; they stay in the average (about 2 ms a
        megapixel frame).
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    StackResult
        ``maps = wft(v_bar)``, with ``mean_image = v_bar`` (float64, the sum's
        precision); the transform is taken in float32 when every frame is float32
        (precision in :mod:`gridstrain.conventions`).

    Notes
    -----
    Under vibrations the averaged image is a biased estimate of the reference
    image (Proposition 2.1), yet its phase derivatives are unbiased with a noise
    falling as ``1/sqrt(T)`` (eq. 27), and its phases are offset by the constant
    ``delta`` of eqs. (29)-(30), removable with :func:`correct_phases` when the
    vibrations are known. One transform whatever ``T``.
    """
    check_type(lattice, "lattice", Lattice)
    n_workers = check_workers(workers)
    screener = _Screener(lattice, screen)
    acc = _average(frames, progress or null_progress, "method A", screener)
    maps, avg = acc.transform(lattice, sigma=sigma, mask=mask, workers=n_workers)
    (progress or null_progress)(1.0, "method A: done")
    return screener.result(StackResult(maps=maps, n_frames=acc.n, method="A",
                                       mean_image=avg))


def method_b(frames, lattice: Lattice, *, sigma: float | None = None, mask=None,
             margin: float = DEFAULT_MARGIN, workers: int | None = None,
             screen: bool = True, progress: Progress | None = None) -> StackResult:
    """Method B: average the phases and phase derivatives of every frame (paper §2.3).

    Parameters
    ----------
    frames : iterable of (H, W) array_like, or (T, H, W) array
        The stack, consumed one frame at a time; one WFT per frame.
    lattice : Lattice
        Wave vectors of the grid.
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen.
    margin : float
        Invalid band at borders and mask edges, in sigmas (see :func:`wft`).
    workers : int, optional
        Threads transforming frames at once (default: the usable cores). The
        frames add their contributions to one set of float64 sums (80 bytes a
        pixel), block of rows by block of rows, in frame order: the result does not
        depend on ``workers``, bit for bit. Integer frames of at most 16 bits are
        transformed in float32, where their grey levels are exact, and the maps are
        float64 (:mod:`gridstrain.conventions`, precision). Memory: the sums, and per thread one
        frame and the scratch arrays of one transform (about 100 bytes a pixel in
        float64).
    screen : bool
        Screen every frame as it is read (:mod:`gridstrain.screening`: no grid, low
        contrast, a slip, a frame of another state, clipping) and name the flagged
        ones in the result's ``warnings``; they stay in the average (about 2 ms a
        megapixel frame).
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    StackResult
        See :class:`StackResult` for how ``maps`` is formed; ``resultant`` gives
        the spread of the frames' phases.

    Notes
    -----
    The phases are averaged on the circle: the phase of the stack is
    ``arg mean_t (psi_t / |psi_t|)``. It needs no unwrapping and no reference frame,
    is right when the frames' phases straddle ``+-pi`` (where an arithmetic mean of
    wrapped phases is off by up to ``pi``), and agrees with the arithmetic mean of
    the unwrapped phases (eq. 32) up to third-order terms in their spread. Its
    vibration offset is ``arg mean_t exp(2 i pi k . (alpha_t, beta_t))``, which
    eqs. (29)-(30) approximate to second order, so :func:`correct_phases` applies
    to both methods. Derivatives are already unwrapped quantities (rad/px) and are
    averaged arithmetically (eq. 33).
    """
    check_type(lattice, "lattice", Lattice)
    progress = progress or null_progress
    n_workers = check_workers(workers)
    acc = _PhaseMean()
    order = FrameOrder() if n_workers > 1 else None

    def transform(item):
        i, img, total = item
        try:
            acc.add_frame(img, lattice, sigma=sigma, mask=mask, margin=margin, index=i,
                          order=order)
        except BaseException:
            if order is not None:
                order.fail(i)  # the frames after this one must not wait for it
            raise
        return i, total

    screener = _Screener(lattice, screen)
    # frames probed here, in frame order, while the threads transform the ones before
    with one_blas_thread():  # BLAS's idle threads would spin on the transforms' cores
        # integer frames as they are: their transforms run in float32 (_transform_input)
        items = screener.frames(_frames(frames, convert=False))
        for i, total in map_bounded(transform, items, n_workers):
            _report(progress, i, total, "method B")
    if acc.n == 0:
        raise ValueError("frames must hold at least one image, got none")
    progress(1.0, "method B: done")
    return screener.result(acc.result(consume=True))  # the maps take the sums' place


class _CompensatedMean:
    """Running float64 sums ``sum_t exp(-i theta_tj) v_t`` for method C.

    ``theta_tj = 2 pi k_j . a_t`` is the phase by which frame ``t``'s rigid shift
    ``a_t`` advances carrier ``j`` (:mod:`gridstrain.vibration`). The frames are
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

    def result(self, *, sigma=None, mask=None, margin=DEFAULT_MARGIN) -> StackResult:
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
                warnings.append(
                    f"method C: the given shifts disagree with the frames' carrier phases "
                    f"by {miss:.3g} rad RMS (beyond {_MAX_WEIGHT_PHASE_ERROR} rad); the "
                    f"frames are realigned with the wrong phases. Check that the shifts "
                    f"follow eq. (2) (frame t is s(x + a_t)) and are in px, or let "
                    f"method C measure them")
        return compensated_result(lambda c: self.acc.averages(c), centre, n, self.acc.dtype,
                                   used, self.parts, self.lattice, sigma=sigma, mask=mask,
                                   margin=margin, warnings=warnings)


def compensated_result(averages, centre, n: int, dtype, used: np.ndarray, parts: list,
                        lattice: Lattice, *, sigma, mask, margin, warnings: list) -> StackResult:
    """Method C's maps from its realigned sums: ``averages(centre)`` gives the two
    weighted means (2, H, W) turned by ``exp(+i centre)``; ``used`` (n, 2) are the
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
            warnings.append(
                f"method C: the frames' motion is not a rigid translation: the "
                f"quadrants of a frame move apart by {residual:.3g} px RMS (worst: "
                f"frame {worst}), i.e. {miss:.3g} rad on the carrier. Only the "
                f"translation is compensated; the rest (rotation, non-rigid "
                f"vibration) averages as under method A, with its contrast loss "
                f"and phase offsets that now vary across the field")
    s = float(lattice.pitch if sigma is None else sigma)
    spread = float(np.sqrt(np.mean(np.sum((used - used.mean(axis=0)) ** 2, axis=1)) / 2))
    widening = math.sqrt(1 + spread**2 / s**2) - 1
    if widening > _MAX_WINDOW_WIDENING:
        warnings.append(
            f"method C: vibrations of {spread:.3g} px RMS move the phase maps under the "
            f"window: the maps are those of a window {widening:.1%} wider than sigma = "
            f"{s:.3g} px (variance sigma^2 + Var(a)); the spatial resolution is "
            f"that much coarser (as for methods A and B)")
    maps = wft_complex(averages(centre), lattice, sigma=sigma, mask=mask, margin=margin,
                       dtype=dtype)
    return StackResult(maps=maps, n_frames=n, method="C",
                       shifts=np.array(used, dtype=np.float64), motion_residual=residual,
                       warnings=tuple(warnings))


def _check_shifts(shifts) -> np.ndarray:
    return as_shifts(shifts, "shifts")


def method_c(frames, lattice: Lattice, *, shifts=None, sigma: float | None = None,
             mask=None, margin: float = DEFAULT_MARGIN, screen: bool = True,
             progress: Progress | None = None) -> StackResult:
    """Method C: average the frames with their carriers realigned, then one WFT.

    Not in the paper: it uses the frames' rigid shifts, which the carrier phases
    give (:func:`gridstrain.vibration.frame_shifts`), to remove what the
    vibrations do to method A while keeping its single transform per wave vector.

    Parameters
    ----------
    frames : iterable of (H, W) array_like, or (T, H, W) array
        The stack, consumed once, one frame at a time.
    lattice : Lattice
        Wave vectors of the grid.
    shifts : (T, 2) array_like, optional
        ``(alpha_t, beta_t)`` of each frame, px, frame ``t`` being
        ``s(x + alpha_t, y + beta_t)`` (eq. 2), e.g. from
        :func:`~gridstrain.vibration.frame_shifts`. Default: measured here, in the
        same pass, from each frame's carrier phases relative to the first frame,
        then centred (see Notes).
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen.
    margin : float
        Invalid band at borders and mask edges, in sigmas (see :func:`wft`).
    screen : bool
        Screen every frame as it is read (:mod:`gridstrain.screening`: no grid, low
        contrast, a slip, a frame of another state, clipping) and name the flagged
        ones in the result's ``warnings``; they stay in the average (about 2 ms a
        megapixel frame).
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    StackResult
        ``maps`` the transforms of the weighted means, ``shifts`` the shifts used,
        ``motion_residual`` and ``warnings``
        (motion not rigid; given shifts that disagree with the frames).

    Notes
    -----
    **Principle.** A frame shifted by ``a_t`` has its carrier ``k_j`` advanced by
    ``theta_tj = 2 pi k_j . a_t`` (:mod:`gridstrain.vibration`). The transform is
    linear, so weighting the frames by ``exp(-i theta_tj)`` before averaging,
    ``z_j = (1/T) sum_t exp(-i theta_tj) v_t``, realigns every frame's carrier
    and ``Psi_kj(z_j)`` is the transform of the un-vibrated grid. The weight is a
    constant per frame: it changes no frequency in ``z_j``, only amplitudes. The
    mean grey level, the conjugate carrier ``-k_j``, the other family ``k_(3-j)``
    and the harmonics stay where they are in a single frame, multiplied by the
    phasors ``mean_t exp(i (m theta_tj' - theta_tj))`` of modulus at most 1, so the
    window rejects them as it does for one frame (their distance to ``k_j`` is at
    least ``|k_j|``, where the window's transfer is ``exp(-2 pi^2 sigma^2
    |k|^2)``, 3e-9 at ``sigma = p``). Only the wanted component adds coherently.

    **Analogue of Props. 2.2-2.4.** With the measured shifts centred, the weights'
    phases are ``2 pi k_j . (a_t - a_bar + e_t - e_bar)`` with ``e_t`` the shift
    estimates' errors. The carrier of ``z_j`` is that of the grid at the stack's
    mean position ``a_bar`` times ``mean_t exp(-2 i pi k_j . (e_t - e_bar))``:
    the contrast factor is ``1 - 1/2 (2 pi)^2 k_j^T Var(e) k_j`` (1 - 2e-7 for
    the 5e-4 px of :func:`~gridstrain.vibration.frame_shifts`) instead of eq. (14)'s
    ``1 - 1/2 (2 pi)^2 k_j^T Var(a) k_j``, and the phase offset about the mean
    position is third order in the errors (eqs. 28-31 have no first- or
    second-order term left). What remains relative to ``s`` is the mean position
    itself, ``2 pi k_j . a_bar``, exactly linear (no eq. 29 truncation): a
    rigid-body translation of the specimen that no frame of the stack can tell
    from the vibrations, with ``Std = 2 pi |k_j| Std(alpha) / sqrt(T)``, the
    offset of method B (:func:`gridstrain.theory.compensated_noise_std`). The
    phase derivatives carry the sensor noise of an average of ``T`` frames at full
    contrast: method B's precision, by eqs. (25)-(27).

    **Limits.** (i) The frames' phase modulation moves with them,
    ``phi(x + a_t)``; method C realigns the carrier, not the modulation, so the
    result is the modulation averaged over the vibration's law, a window of
    variance ``sigma^2 + Var(a)`` instead of ``sigma^2`` (a 0.5 % wider window at
    0.5 px of vibration and ``sigma = 5``; a warning beyond 1 %): negligible while
    ``Std(a)`` is small against ``sigma``, whatever it is against the pitch (the weights need the
    shift only modulo a period, so shifts past half a period do no harm). (ii) A
    rotation or a non-rigid vibration moves the quadrants of a frame apart; only
    the translation is compensated and the rest averages as under method A.
    ``motion_residual`` measures it and a warning is given beyond
    0.05 rad on the carrier (the shifts of the 2 x 2 quadrants, each
    measured like :func:`~gridstrain.vibration.frame_shifts`). Method A would
    not do better: it compensates nothing.

    Cost: per frame, its carrier coefficients in four quadrants (one product
    with a (W, 5) matrix) and its share of a matrix product that adds a batch of
    frames to the four sums (32 bytes per pixel plus a batch buffer of at most
    64 MiB); then one complex FFT and the band-limited inverse transforms per
    wave vector (:func:`~gridstrain.wft.wft_complex`). See
    ``benchmarks/bench_method_c.py``.
    """
    check_type(lattice, "lattice", Lattice)
    progress = progress or null_progress
    run = MethodC(lattice, shifts)
    screener = _Screener(lattice, screen)
    # frames converted while copied into the batch: one pass instead of three
    with one_blas_thread():  # small per-frame products (gridstrain._threads)
        for i, img, total in screener.frames(_frames(frames, convert=False)):
            run.add(img, f"frames[{i}]")
            _report(progress, i, total, "method C")
    if run.acc.n == 0:
        raise ValueError("frames must hold at least one image, got none")
    if run.given is not None and len(run.given) != run.acc.n:
        raise ValueError(f"shifts must have one row per frame: got {len(run.given)} rows "
                         f"for {run.acc.n} frames")
    res = screener.result(run.result(sigma=sigma, mask=mask, margin=margin))
    progress(1.0, "method C: done")
    return res


def prefix_stacks(frames, lattice: Lattice, counts, *, method: str = "A",
                  sigma: float | None = None, mask=None,
                  progress: Progress | None = None) -> Iterator[StackResult]:
    """Results for the first ``T`` frames, for every ``T`` in ``counts``, in one pass.

    The stacks are nested (the one of ``T = 1000`` holds the one of ``T = 200``),
    which is how a growing acquisition behaves and costs one pass over the frames:
    a running sum for method A, running sums of the WFTs for method B.

    Parameters
    ----------
    frames : iterable of (H, W) array_like
        At least ``max(counts)`` frames (extra ones are not read).
    lattice : Lattice
        Wave vectors.
    counts : iterable of int
        Strictly increasing stack sizes ``T``.
    method : {"A", "B", "C"}
        Averaging method (see :func:`method_a`, :func:`method_b`,
        :func:`method_c`; C with its shifts measured in the same pass, centred on
        each prefix).
    sigma, mask
        As in :func:`gridstrain.wft.wft`.
    progress : callable, optional
        ``progress(fraction, message)``.

    Yields
    ------
    StackResult
        One per count, in order, as soon as that many frames have been read.
    """
    check_type(lattice, "lattice", Lattice)
    check_choice(method, "method", ("A", "B", "C"))
    wanted = _check_counts(counts)
    progress = progress or null_progress
    acc = {"A": MeanImage, "B": _PhaseMean, "C": lambda: MethodC(lattice)}[method]()
    k = 0
    last = wanted[-1]
    n = 0
    for i, img, _ in _frames(frames):
        if method == "B":
            acc.add_frame(img, lattice, sigma=sigma, mask=mask)
        else:
            acc.add(img)
        n = i + 1
        progress(n / last, f"method {method}: frame {n}/{last}")
        if n == wanted[k]:
            if method == "A":
                maps, avg = acc.transform(lattice, sigma=sigma, mask=mask)
                yield StackResult(maps=maps, n_frames=n, method="A", mean_image=avg)
            elif method == "C":
                yield acc.result(sigma=sigma, mask=mask)
            else:
                yield acc.result()
            k += 1
            if k == len(wanted):
                return
    raise ValueError(f"frames must hold at least {last} images (the largest count), got {n}")


def phase_offsets(shifts, lattice: Lattice, *, exact: bool) -> np.ndarray:
    """Phase offsets ``(delta_1, delta_2)`` of a vibrated stack, rad (eqs. 28-30)."""
    sh = np.asarray(shifts, dtype=float)
    if sh.ndim != 2 or sh.shape[1] != 2 or sh.shape[0] < 1:
        raise ValueError(f"shifts must be a (T, 2) array of (alpha, beta) in px, got shape "
                         f"{sh.shape}")
    if not np.all(np.isfinite(sh)):
        raise ValueError("shifts must be finite")
    # phase advance of each frame for each wave vector: arg Psi_k of s(x + shift) is
    # arg Psi_k(s) + 2 pi k . shift (checked in tests/test_stacks.py)
    u = 2 * math.pi * sh @ lattice.K.T  # (T, 2)
    if exact:
        return np.angle(np.mean(np.exp(1j * u), axis=0))
    # eq. (28) expanded to second order, i.e. eqs. (29)-(30) written with atan2 so
    # that the branch is that of the argument in eq. (28)
    return np.arctan2(u.mean(axis=0), 1 - 0.5 * np.mean(u**2, axis=0))


def correct_phases(maps, shifts, *, exact: bool = False):
    """Remove the vibration phase offset ``delta`` of a stack (paper eqs. 29-30).

    Parameters
    ----------
    maps : PhaseMaps or StackResult
        Phases of a stack (method A or B).
    shifts : (T, 2) array_like
        The vibrations ``(alpha_t, beta_t)`` of its frames, px (known only for
        synthetic data, or measured by other means).
    exact : bool
        False: ``delta_j = arctan(2 pi m1 / (1 - (2 pi)^2 m2 / 2))`` with ``m1``,
        ``m2`` the sample mean and mean square of ``k_j . shift_t``, the paper's
        eqs. (29)-(30) for any lattice. True: ``delta_j = arg mean_t
        exp(2 i pi k_j . shift_t)``, the offset these approximate to second order
        (the paper's eq. 28 before truncating the Taylor series of eq. 3).

    Returns
    -------
    PhaseMaps or StackResult
        Same type as ``maps``, with ``psi_j`` multiplied by ``exp(-i delta_j)``;
        moduli and derivatives unchanged (``delta`` is uniform).
    """
    if isinstance(maps, StackResult):
        return replace(maps, maps=correct_phases(maps.maps, shifts, exact=exact))
    if not isinstance(maps, PhaseMaps):
        raise TypeError(f"maps must be a PhaseMaps or StackResult, got "
                        f"{type(maps).__name__}")
    delta = phase_offsets(shifts, maps.lattice, exact=bool(exact))
    rot = np.exp(-1j * delta).astype(maps.psi.dtype)[:, None, None]
    # dphi and valid are read-only arrays: sharing them cannot alter the input
    return PhaseMaps(psi=maps.psi * rot, dphi=maps.dphi, valid=maps.valid,
                     lattice=maps.lattice, sigma=maps.sigma)
