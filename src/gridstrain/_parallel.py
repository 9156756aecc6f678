"""Method B on a series of frames: the windowed Fourier transform of every frame, averaged.

The paper's method B (section 2.3) estimates the phases and phase derivatives of each
of the T frames separately and averages them, at the cost of T transforms instead of
one (method A transforms the averaged image). This module maps :func:`gridstrain.wft`
over the frames on a pool of threads (scipy.fft and numpy's large array operations
release the GIL) and accumulates the results in float64, with memory bounded by a
few frames whatever T.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .lattice import Lattice
from .wft import DEFAULT_MARGIN, PhaseMaps, wft

__all__ = ["mean_wft"]


def _check_workers(workers) -> int:
    if workers is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
            os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
    return workers


def mean_wft(frames: Iterable, lattice: Lattice, *, sigma: float | None = None, mask=None,
             margin: float = DEFAULT_MARGIN, workers: int | None = None,
             progress: Callable[[float, str], None] | None = None,
             n_frames: int | None = None) -> PhaseMaps:
    """Method B: windowed Fourier transform of each frame, phasors and derivatives averaged.

    Parameters
    ----------
    frames : iterable of (H, W) array_like
        The frames, grey levels, consumed one at a time (a generator such as
        ``FrameSeries.frames()`` keeps memory bounded). float32 frames are
        transformed in float32; every frame must have the same shape.
    lattice : Lattice
        Wave vectors, as for :func:`gridstrain.wft`.
    sigma, mask, margin
        As for :func:`gridstrain.wft`, the same for every frame.
    workers : int, optional
        Threads transforming frames at once (default: the usable cores). At most
        ``2 * workers`` frames and their results are held at a time.
    progress : callable, optional
        ``progress(fraction, message)``, called after each frame; ``fraction`` is
        known only when ``n_frames`` is given or ``frames`` has a length.
    n_frames : int, optional
        Number of frames, for the progress fraction.

    Returns
    -------
    PhaseMaps
        ``psi`` (2, H, W): mean of the frames' ``Psi`` (demodulated phasors), grey
        levels, so that ``phase`` is the argument of the mean phasor; ``dphi``
        (2, 2, H, W): mean of the frames' phase derivatives, rad/px; ``valid``:
        pixels valid in every frame. Sums are float64 and the frames' order fixes
        the order of the additions, so the result does not depend on ``workers``;
        it is returned in the frames' precision.

    Raises
    ------
    ValueError
        If ``frames`` is empty, the frames differ in shape, or ``workers`` is not
        a positive integer.
    """
    n_workers = _check_workers(workers)
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be callable or None, got {progress!r}")
    total = n_frames if n_frames is not None else (
        len(frames) if hasattr(frames, "__len__") else None)

    def one(frame):
        return wft(frame, lattice, sigma=sigma, mask=mask, margin=margin)

    acc = {}
    count = 0

    def add(res: PhaseMaps) -> None:
        nonlocal count
        if not acc:
            acc["psi"] = res.psi.astype(np.complex128)
            acc["dphi"] = res.dphi.astype(np.float64)
            acc["valid"] = res.valid.copy()
            acc["first"] = res
        else:
            if res.shape != acc["first"].shape:
                raise ValueError(f"frames must all have the shape of the first, "
                                 f"{acc['first'].shape}; frame {count} has {res.shape}")
            np.add(acc["psi"], res.psi, out=acc["psi"])
            np.add(acc["dphi"], res.dphi, out=acc["dphi"])
            acc["valid"] &= res.valid
        count += 1
        if progress is not None:
            frac = count / total if total else 0.0
            progress(min(frac, 1.0), f"method B: transformed frame {count}"
                     + (f"/{total}" if total else ""))

    if n_workers == 1:
        for frame in frames:
            add(one(frame))
    else:
        with ThreadPoolExecutor(max_workers=n_workers) as pool:
            pending: deque = deque()
            for frame in frames:
                pending.append(pool.submit(one, frame))
                while len(pending) >= 2 * n_workers:
                    add(pending.popleft().result())
            while pending:
                add(pending.popleft().result())
    if count == 0:
        raise ValueError("frames must hold at least one frame, got none")
    first = acc["first"]
    acc["psi"] /= count
    acc["dphi"] /= count
    return PhaseMaps(psi=acc["psi"].astype(first.psi.dtype, copy=False),
                     dphi=acc["dphi"].astype(first.dphi.dtype, copy=False),
                     valid=acc["valid"], lattice=lattice, sigma=first.sigma)
