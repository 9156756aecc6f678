"""The window's transfer function and the spectrum of the padded image along a wave vector:
what each transform of a grid image multiplies and reads.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy import fft as sfft

# Transfer-function values below this (relative to its peak of 1) are flushed to zero:
# they would change the result by less than 1e-16 relative, and as denormals they
# would only slow the FFT down.
_FLUSH = 1e-16


def transfer_function(nu, sigma: float, *, derivative: bool = False) -> np.ndarray:
    """1-D transfer function of the sampled, unit-sum Gaussian window.

    Parameters
    ----------
    nu : array_like
        Frequencies, cycles/px.
    sigma : float
        Standard deviation of the window, px.
    derivative : bool
        If True, the transfer function of the sampled derivative of the window
        (``2 i pi nu`` times the Gaussian's), periodised the same way.

    Returns
    -------
    ndarray
        ``sum_j G(nu + j) / sum_j G(j)`` with ``G(nu) = exp(-2 pi^2 sigma^2 nu^2)``:
        sampling the Gaussian periodises its spectrum, and dividing by its value at 0
        makes the sampled window sum to exactly 1. Values below 1e-16 are zero.
    """
    nu = np.asarray(nu, dtype=float)
    a = 2.0 * math.pi**2 * sigma**2
    out = np.zeros(nu.shape, dtype=complex if derivative else float)
    for j in (-2, -1, 0, 1, 2):  # |j| = 3 weighs exp(-2 pi^2 sigma^2 * 6.25) < 1e-200
        g = np.exp(-a * (nu + j) ** 2)
        out += 2j * math.pi * (nu + j) * g if derivative else g
    norm = sum(math.exp(-a * j * j) for j in (-2, -1, 0, 1, 2))
    out /= norm
    out[np.abs(out) < _FLUSH] = 0
    return out


def _axis_band(n: int, k: float, sigma: float):
    """One axis of the band where the window's transfer function ``G(f - k)`` is non-zero.

    Returns ``(idx, runs, nu, shift, g)``: the FFT indices of the band; the band as
    ``(dst, src)`` slice pairs placing entry ``src`` of ``idx`` at ``dst`` in a spectrum
    shifted down by ``shift`` bins (the bin nearest ``k``, so that the inverse FFT
    comes out demodulated by ``exp(-2 i pi shift x / n)``); ``nu = f - k`` on the
    band, cycles/px; and the transfer function there, ``transfer_function(nu,
    sigma)`` (the same bits: it is taken value by value).
    """
    nu_all = (sfft.fftfreq(n) - k + 0.5) % 1.0 - 0.5
    g_all = transfer_function(nu_all, sigma)
    idx = np.flatnonzero(g_all)
    shift = round(k * n)
    pos = (idx - shift) % n
    # pos is circularly contiguous (the transfer function decreases with |nu|):
    # cut it into the runs where it increases by one, to copy with slices
    cuts = np.flatnonzero(np.diff(pos) != 1) + 1
    bounds = [0, *cuts.tolist(), idx.size]
    runs = [(slice(int(pos[i]), int(pos[j - 1]) + 1), slice(i, j))
            for i, j in itertools.pairwise(bounds)]
    return idx, runs, nu_all[idx], shift, g_all[idx]


def spectrum_block(V: np.ndarray, rows: np.ndarray, cols: np.ndarray, nx: int) -> np.ndarray:
    """Block ``rows x cols`` of the full 2-D DFT of a real image, from its rfft2 ``V``.

    Copied run by run with slices: the band's indices are a few arithmetic runs, and
    fancy indexing would gather element by element.
    """
    ny, nh = V.shape
    out = np.empty((rows.size, cols.size), dtype=V.dtype)
    neg = cols >= nh
    # cols is sorted: the positive frequencies come first, the negative ones last
    n_pos = int(np.count_nonzero(~neg))
    for conj in (False, True):
        off = n_pos if conj else 0
        sel = cols[n_pos:] if conj else cols[:n_pos]
        # X[r, c] = conj(X[-r, -c]) for a real image
        r_src = (-rows) % ny if conj else rows
        c_src = nx - sel if conj else sel
        for r_out, r_in in _runs(r_src):
            for c_out, c_in in _runs(c_src):
                dst = out[r_out, off + c_out.start:off + c_out.stop]
                if conj:
                    np.conjugate(V[r_in, c_in], out=dst)
                else:
                    dst[...] = V[r_in, c_in]
    return out


def _runs(idx: np.ndarray):
    """``(position, source)`` slice pairs covering ``idx`` by runs of step +1 or -1."""
    n = idx.size
    if n == 0:
        return
    step = np.diff(idx)
    start = 0
    while start < n:
        stop = start + 1
        if stop < n and abs(step[start]) == 1:
            s = int(step[start])
            while stop < n and step[stop - 1] == s:
                stop += 1
        else:
            s = 1
        first, last = int(idx[start]), int(idx[stop - 1])
        end = last + s
        yield slice(start, stop), slice(first, None if end < 0 else end, s)
        start = stop
