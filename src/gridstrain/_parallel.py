"""Method B on a series of frames: the windowed Fourier transform of every frame, averaged.

The paper's method B (section 2.3) estimates the phases and phase derivatives of each
of the T frames separately and averages them, at the cost of T transforms instead of
one (method A transforms the averaged image). This module maps :func:`gridstrain.wft`
over the frames on a pool of threads (scipy.fft and numpy's large array operations
release the GIL) and accumulates the results in float64, with memory bounded by a
few frames whatever T.

Averaging the phasors ``Psi`` instead of the phases gives exactly method A's ``Psi``
(the transform is linear in the image), so by default the phases themselves are
averaged, as the paper does; the derivatives are averaged in both cases.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._validation import check_choice
from .lattice import Lattice
from .wft import _MIN_MODULUS, DEFAULT_MARGIN, PhaseMaps, wft

__all__ = ["mean_wft"]


def _check_workers(workers) -> int:
    if workers is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
            os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
    return workers


def mean_wft(frames: Iterable, lattice: Lattice, *, sigma: float | None = None, mask=None,
             margin: float = DEFAULT_MARGIN, min_modulus: float = _MIN_MODULUS,
             average: str = "phase",
             workers: int | None = None,
             progress: Callable[[float, str], None] | None = None,
             n_frames: int | None = None) -> PhaseMaps:
    """Method B: windowed Fourier transform of each frame, phases and derivatives averaged.

    Parameters
    ----------
    frames : iterable of (H, W) array_like
        The frames, grey levels, consumed one at a time (a generator such as
        ``FrameSeries.frames()`` keeps memory bounded). float32 frames are
        transformed in float32; every frame must have the same shape.
    lattice : Lattice
        Wave vectors, as for :func:`gridstrain.wft`.
    sigma, mask, margin, min_modulus
        As for :func:`gridstrain.wft`, the same for every frame.
    average : {"phase", "phasor"}
        ``"phase"`` (the paper's method B): the phase is the first frame's plus the
        mean of each frame's phase relative to it, ``arg(Psi_t conj(Psi_1))``, which
        needs no unwrapping while the frames differ by less than pi (vibrations of
        a fraction of the pitch); the modulus is the mean modulus. ``"phasor"``:
        the mean of the ``Psi_t``, which equals method A's ``Psi`` and saves the
        phase computations.
    workers : int, optional
        Threads transforming frames at once (default: the usable cores). At most
        ``workers`` frames and their transforms are held at a time, besides the
        float64 sums.
    progress : callable, optional
        ``progress(fraction, message)``, called after each frame; ``fraction`` is
        known only when ``n_frames`` is given or ``frames`` has a length.
    n_frames : int, optional
        Number of frames, for the progress fraction.

    Returns
    -------
    PhaseMaps
        ``psi`` (2, H, W): grey levels, with the averaged phase as argument (see
        ``average``); ``dphi``
        (2, 2, H, W): mean of the frames' phase derivatives, rad/px; ``valid``:
        pixels valid in every frame. Sums are float64 and the frames' order fixes
        the order of the additions, so the result does not depend on ``workers``;
        it is returned in the frames' precision.

    Raises
    ------
    ValueError
        If ``frames`` is empty, the frames differ in shape, ``average`` is unknown,
        or ``workers`` is not a positive integer.
    """
    check_choice(average, "average", ("phase", "phasor"))
    n_workers = _check_workers(workers)
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be callable or None, got {progress!r}")
    total = n_frames if n_frames is not None else (
        len(frames) if hasattr(frames, "__len__") else None)

    it = iter(frames)
    first_frame = next(it, None)
    if first_frame is None:
        raise ValueError("frames must hold at least one frame, got none")
    first = wft(first_frame, lattice, sigma=sigma, mask=mask, margin=margin,
                min_modulus=min_modulus)
    del first_frame
    # keep only the sums and what the last step needs of frame 1, not its maps
    shape, sigma_used = first.shape, first.sigma
    cdtype, rdtype = first.psi.dtype, first.dphi.dtype
    dphi = first.dphi.astype(np.float64)
    valid = first.valid.copy()
    if average == "phasor":
        psi_sum = first.psi.astype(np.complex128)
    else:
        conj1 = np.conj(first.psi)
        phase_sum = np.zeros(first.psi.shape)  # frame 1's phase relative to itself
        mod_sum = np.abs(first.psi).astype(np.float64)
    del first

    def transform(frame):
        # runs in a worker thread: the phase extraction is as costly as a third of
        # the transform, so it is done here rather than in the accumulating thread;
        # only what is summed is kept
        res = wft(frame, lattice, sigma=sigma, mask=mask, margin=margin,
                  min_modulus=min_modulus)
        if res.shape != shape:
            raise ValueError(f"frames must all have the shape of the first, {shape}; "
                             f"got {res.shape}")
        if average == "phasor":
            return res.dphi, res.valid, res.psi, None
        return res.dphi, res.valid, np.angle(res.psi * conj1), np.abs(res.psi)

    count = 1

    def add(item) -> None:
        nonlocal count
        d, v, a, b = item
        np.add(dphi, d, out=dphi)
        np.logical_and(valid, v, out=valid)
        if average == "phasor":
            np.add(psi_sum, a, out=psi_sum)
        else:
            np.add(phase_sum, a, out=phase_sum)
            np.add(mod_sum, b, out=mod_sum)
        count += 1
        if progress is not None:
            progress(min(count / total, 1.0) if total else 0.0,
                     f"method B: transformed frame {count}" + (f"/{total}" if total else ""))

    if progress is not None:
        progress(1 / total if total else 0.0,
                 "method B: transformed frame 1" + (f"/{total}" if total else ""))
    if n_workers == 1:
        for frame in it:
            add(transform(frame))
    else:
        with ThreadPoolExecutor(max_workers=n_workers) as pool:
            pending: deque = deque()
            for frame in it:
                # one frame per thread at a time: memory stays at about ``workers``
                # transforms whatever the number of frames
                while len(pending) >= n_workers:
                    add(pending.popleft().result())
                pending.append(pool.submit(transform, frame))
                del frame
            while pending:
                add(pending.popleft().result())
    if average == "phasor":
        psi = psi_sum / count
    else:
        # arg Psi_1 = -arg conj(Psi_1)
        psi = mod_sum / count * np.exp(1j * (phase_sum / count - np.angle(conj1)))
    dphi /= count
    return PhaseMaps(psi=psi.astype(cdtype, copy=False), dphi=dphi.astype(rdtype, copy=False),
                     valid=valid, lattice=lattice, sigma=sigma_used)
