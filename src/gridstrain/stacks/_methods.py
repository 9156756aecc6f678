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
from collections.abc import Iterable, Iterator
from dataclasses import replace

import numpy as np

from .._progress import Progress, null_progress
from .._runtime.threads import map_bounded, one_blas_thread
from .._validation import (
    as_image,
    as_int_tuple,
    check_choice,
    check_type,
    check_workers,
    image_array,
)
from ..phase import DEFAULT_MARGIN, Lattice, PhaseMaps, Window
from ._accumulators import FrameOrder, MeanImage, MethodC, PhaseMean, StackResult, with_screening
from .screening import FrameProbe

__all__ = [
    "StackResult",
    "circular_offset_std",
    "correct_phases",
    "mean_image",
    "method_a",
    "method_b",
    "method_c",
    "prefix_stacks",
]


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
    which frames :func:`gridstrain.stacks.screening.decide` flags.

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
    with one_blas_thread():  # the screening's small products (gridstrain._runtime.threads)
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
        Screen every frame as it is read (:mod:`gridstrain.stacks.screening`: no grid, low
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
        Screen every frame as it is read (:mod:`gridstrain.stacks.screening`: no grid, low
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
    wrapped phases is off by up to ``pi``), and differs from the arithmetic mean of
    the unwrapped phases (eq. 32) by third-order terms in their spread. Its
    vibration offset is ``arg mean_t exp(2 i pi k . (alpha_t, beta_t))``, method A's,
    which eqs. (29)-(30) approximate to second order, so :func:`correct_phases`
    applies to both methods. About the frames' mean position the offset is third
    order but about 40 times the phase noise at 0.5 px of vibration
    (:func:`circular_offset_std`): ``correct_phases(res, res.screening.shifts(),
    about="mean")`` removes it with the shifts the screening measured. Derivatives
    are already unwrapped quantities (rad/px) and are averaged arithmetically
    (eq. 33).
    """
    check_type(lattice, "lattice", Lattice)
    progress = progress or null_progress
    n_workers = check_workers(workers)
    window = Window.for_lattice(lattice, sigma=sigma, margin=margin)
    acc = PhaseMean()
    order = FrameOrder() if n_workers > 1 else None

    def transform(item):
        i, img, total = item
        try:
            acc.add_frame(img, lattice, window, mask=mask, index=i, order=order)
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



def method_c(frames, lattice: Lattice, *, shifts=None, sigma: float | None = None,
             mask=None, margin: float = DEFAULT_MARGIN, screen: bool = True,
             progress: Progress | None = None) -> StackResult:
    """Method C: average the frames with their carriers realigned, then one WFT.

    Not in the paper: it uses the frames' rigid shifts, which the carrier phases
    give (:func:`gridstrain.stacks.vibration.frame_shifts`), to remove what the
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
        :func:`~gridstrain.stacks.vibration.frame_shifts`. Default: measured here, in the
        same pass, from each frame's carrier phases relative to the first frame,
        then centred (see Notes).
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen.
    margin : float
        Invalid band at borders and mask edges, in sigmas (see :func:`wft`).
    screen : bool
        Screen every frame as it is read (:mod:`gridstrain.stacks.screening`: no grid, low
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
    ``theta_tj = 2 pi k_j . a_t`` (:mod:`gridstrain.stacks.vibration`). The transform is
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
    the 5e-4 px of :func:`~gridstrain.stacks.vibration.frame_shifts`) instead of eq. (14)'s
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
    measured like :func:`~gridstrain.stacks.vibration.frame_shifts`). Method A would
    not do better: it compensates nothing.

    Cost: per frame, its carrier coefficients in four quadrants (one product
    with a (W, 5) matrix) and its share of a matrix product that adds a batch of
    frames to the four sums (32 bytes per pixel plus a batch buffer of at most
    64 MiB); then one complex FFT and the band-limited inverse transforms per
    wave vector (:func:`~gridstrain.phase.wft_complex`). See
    ``benchmarks/bench_method_c.py``.
    """
    check_type(lattice, "lattice", Lattice)
    window = Window.for_lattice(lattice, sigma=sigma, margin=margin)
    progress = progress or null_progress
    run = MethodC(lattice, shifts)
    screener = _Screener(lattice, screen)
    # frames converted while copied into the batch: one pass instead of three
    with one_blas_thread():  # small per-frame products (gridstrain._runtime.threads)
        for i, img, total in screener.frames(_frames(frames, convert=False)):
            run.add(img, f"frames[{i}]")
            _report(progress, i, total, "method C")
    if run.acc.n == 0:
        raise ValueError("frames must hold at least one image, got none")
    if run.given is not None and len(run.given) != run.acc.n:
        raise ValueError(f"shifts must have one row per frame: got {len(run.given)} rows "
                         f"for {run.acc.n} frames")
    res = screener.result(run.result(window, mask=mask))
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
        As in :func:`gridstrain.phase.wft`.
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
    window = Window.for_lattice(lattice, sigma=sigma)
    acc = {"A": MeanImage, "B": PhaseMean, "C": lambda: MethodC(lattice)}[method]()
    k = 0
    last = wanted[-1]
    n = 0
    for i, img, _ in _frames(frames):
        if method == "B":
            acc.add_frame(img, lattice, window, mask=mask)
        else:
            acc.add(img)
        n = i + 1
        progress(n / last, f"method {method}: frame {n}/{last}")
        if n == wanted[k]:
            if method == "A":
                maps, avg = acc.transform(lattice, mask=mask, **window.options())
                yield StackResult(maps=maps, n_frames=n, method="A", mean_image=avg)
            elif method == "C":
                yield acc.result(window, mask=mask)
            else:
                yield acc.result()
            k += 1
            if k == len(wanted):
                return
    raise ValueError(f"frames must hold at least {last} images (the largest count), got {n}")


def phase_offsets(shifts, lattice: Lattice, *, exact: bool,
                  about_mean: bool = False) -> np.ndarray:
    """Phase offsets ``(delta_1, delta_2)`` of a vibrated stack, rad (eqs. 28-30);
    ``about_mean``: the exact offset about the frames' mean position
    (:func:`correct_phases`, ``about="mean"``)."""
    sh = np.asarray(shifts, dtype=float)
    if sh.ndim != 2 or sh.shape[1] != 2 or sh.shape[0] < 1:
        raise ValueError(f"shifts must be a (T, 2) array of (alpha, beta) in px, got shape "
                         f"{sh.shape}")
    if not np.all(np.isfinite(sh)):
        raise ValueError("shifts must be finite")
    # phase advance of each frame for each wave vector: arg Psi_k of s(x + shift) is
    # arg Psi_k(s) + 2 pi k . shift (checked in tests/test_stacks.py)
    u = 2 * math.pi * sh @ lattice.K.T  # (T, 2)
    if about_mean:
        u = u - u.mean(axis=0)
        return np.angle(np.mean(np.exp(1j * u), axis=0))
    if exact:
        return np.angle(np.mean(np.exp(1j * u), axis=0))
    # eq. (28) expanded to second order, i.e. eqs. (29)-(30) written with atan2 so
    # that the branch is that of the argument in eq. (28)
    return np.arctan2(u.mean(axis=0), 1 - 0.5 * np.mean(u**2, axis=0))


def circular_offset_std(shifts, lattice: Lattice) -> np.ndarray:
    """The spread of the offset about the mean position that :func:`correct_phases`
    (``about="mean"``) removes, predicted from the vibrations' amplitude, rad.

    For Gaussian vibrations the frames' phase advances ``x_t`` have the std ``s_j``
    (``2 pi k_j . a_t``); about their mean, ``d_t = x_t - x_bar``, the offset is
    ``arg mean_t exp(i d_t) = atan(mean_t sin d_t / mean_t cos d_t)``. The centring
    removes the part of ``sin x`` along ``x``: ``mean_t sin d_t = mean_t (sin x_t -
    exp(-s^2/2) x_t)`` to first order in ``x_bar``, of variance ``((1 - exp(-2 s^2)) / 2
    - s^2 exp(-s^2)) / T``, and ``mean_t cos d_t = exp(-s^2 / 2)``, so

    ``std = sqrt(((1 - exp(-2 s^2)) / 2 - s^2 exp(-s^2)) / T) exp(s^2 / 2)``,

    ``s^3 / sqrt(6 T)`` to leading order (third order: the sample skewness). Its mean
    is zero: the offset is a draw of the stack, not a bias of the method.

    Parameters
    ----------
    shifts : (T, 2) array_like
        The frames' rigid shifts, px.
    lattice : Lattice

    Returns
    -------
    (2,) float64 ndarray
        Per wave vector, rad.
    """
    sh = np.asarray(shifts, dtype=float)
    T = sh.shape[0]
    if T < 2:
        return np.zeros(2)
    s2 = (2 * math.pi * sh @ lattice.K.T).var(axis=0)
    # the difference cancels to s^6 / 6: its series where the closed form loses digits
    series = s2**3 / 6 - s2**4 / 6 + 11 * s2**5 / 120
    closed = (1 - np.exp(-2 * s2)) / 2 - s2 * np.exp(-s2)
    var = np.where(s2 < 0.05, series, np.maximum(closed, 0.0)) / T
    return np.sqrt(var) * np.exp(s2 / 2)


def correct_phases(maps, shifts, *, exact: bool = False, about: str = "origin"):
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
    about : {"origin", "mean"}
        ``"origin"``: the phases are brought to the frame of zero shift (the whole
        ``delta``, which needs the shifts against that frame). ``"mean"``: only the
        offset about the frames' mean position, ``arg mean_t exp(i (theta_tj -
        mean_t theta_tj))`` with ``theta_tj = 2 pi k_j . shift_t`` (exact; ``exact``
        is ignored), which centred measured shifts give
        (:meth:`~gridstrain.stacks.screening.FrameScreen.shifts`): the phases of the grid
        at its mean position, the mean of the unwrapped phases of eq. (32), which
        is what a stack without a frame of reference can give. That offset is
        third order in the vibrations (:func:`circular_offset_std`) but not
        negligible: 0.0125 rad (std) at 0.5 px std, pitch 5 and 64 frames, some 40 times
        the phase noise of the stack. :func:`gridstrain.measure_series` removes it
        for methods A and B.

    Returns
    -------
    PhaseMaps or StackResult
        Same type as ``maps``, with ``psi_j`` multiplied by ``exp(-i delta_j)``;
        moduli and derivatives unchanged (``delta`` is uniform).
    """
    if isinstance(maps, StackResult):
        return replace(maps, maps=correct_phases(maps.maps, shifts, exact=exact, about=about))
    if not isinstance(maps, PhaseMaps):
        raise TypeError(f"maps must be a PhaseMaps or StackResult, got "
                        f"{type(maps).__name__}")
    check_choice(about, "about", ("origin", "mean"))
    delta = phase_offsets(shifts, maps.lattice, exact=bool(exact), about_mean=about == "mean")
    rot = np.exp(-1j * delta).astype(maps.psi.dtype)[:, None, None]
    # dphi and valid are read-only arrays: sharing them cannot alter the input
    return PhaseMaps(psi=maps.psi * rot, dphi=maps.dphi, valid=maps.valid,
                     lattice=maps.lattice, sigma=maps.sigma)
