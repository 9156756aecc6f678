"""The exact phase derivatives of the transform (the analytic derivative of the window),
one wave vector at a time.
"""

from __future__ import annotations

import math

import numpy as np

from .._runtime import fft as _fft
from ._spectrum import _axis_band, spectrum_block, transfer_function
from ._validity import _gaps


def _ifft(x: np.ndarray, axis: int) -> np.ndarray:
    """In-place-allowed 1-D inverse FFT along ``axis``, on the chosen implementation."""
    return _fft.call("ifft", x, axis=axis, overwrite_x=True, workers=1)


def _one_wave_vector(V, k, sigma, H, W, nx, psi, dphi, mod, work, *, chunk: int,
                     sink=None):
    """Fill ``psi`` (H, W), ``dphi`` (2, H, W) and ``mod`` (H, W) for the wave vector ``k``.

    With ``sink``, ``psi`` and ``dphi`` hold one block of ``chunk`` rows: each block
    is computed there, then handed to ``sink(r0, r1, psi, dphi, mod)`` (``mod`` is
    still filled whole: the validity test needs its median).

    The filtered spectrum is non-zero only on a band of rows x cols around ``k``, and
    the window is separable: one inverse FFT along y of the band's columns for the
    window and one for its y-derivative, then inverse FFTs along x of the image's
    rows for ``Psi``, ``dPsi/dx`` and ``dPsi/dy``. Shifting the band down to the bins
    nearest ``k`` demodulates by the carrier up to a residual of less than half a
    bin, applied to the y-transform and to ``Psi``.
    """
    ny = V.shape[0]
    cdtype = V.dtype
    rows, yruns, nuy, sy, gy = _axis_band(ny, k[1], sigma)
    cols, xruns, nux, sx, gx = _axis_band(nx, k[0], sigma)
    # a complex image's full spectrum (wft_complex), or a real one's half spectrum
    block = V[np.ix_(rows, cols)] if V.shape[1] == nx else spectrum_block(V, rows, cols, nx)
    # complex transfer values: a complex times real product would go through a
    # slow mixed-type loop
    gy = gy.astype(cdtype)
    dgy = transfer_function(nuy, sigma, derivative=True).astype(cdtype)
    gx = gx.astype(cdtype)
    dgx = transfer_function(nux, sigma, derivative=True).astype(cdtype)

    # along y: window and its derivative, for the band's columns only. The x-window
    # is applied here too, on the small band, so that the blocks along x below are
    # mostly copies; dPsi/dx then needs dgx / gx (~ 2 i pi nu, finite on the band).
    block *= gx
    Y = work.get("Y", (2, ny, cols.size), cdtype)
    for gap in _gaps(yruns, ny):
        Y[:, gap] = 0
    for dst, src in yruns:
        np.multiply(block[src], gy[src, None], out=Y[0, dst])
        np.multiply(block[src], dgy[src, None], out=Y[1, dst])
    ratio = (dgx / gx).astype(cdtype)
    A = _ifft(Y, 1)[:, :H]
    ry = sy / ny - k[1]
    if ry != 0:
        A *= np.exp(2j * math.pi * ry * np.arange(H)).astype(cdtype)[:, None]
    rx = sx / nx - k[0]
    ex = np.exp(2j * math.pi * rx * np.arange(W)).astype(cdtype) if rx != 0 else None

    # along x, by blocks of rows: Psi, dPsi/dx, dPsi/dy. One buffer serves every block
    # (the in-place FFT overwrites it, so the columns outside the band are re-zeroed).
    X = work.get("X", (3, min(chunk, H), nx), cdtype)
    gaps = _gaps(xruns, nx)
    cc = work.get("cc", (min(chunk, H), W), cdtype)
    prod = work.get("prod", (2, min(chunk, H), W), cdtype)
    rinv = work.get("rinv", (min(chunk, H), W), mod.dtype)
    for r0 in range(0, H, chunk):
        r1 = min(r0 + chunk, H)
        h = r1 - r0
        Xh = X[:, :h]
        for gap in gaps:
            Xh[:, :, gap] = 0
        for dst, src in xruns:
            Xh[0, :, dst] = A[0, r0:r1, src]
            np.multiply(A[0, r0:r1, src], ratio[src], out=Xh[1, :, dst])
            Xh[2, :, dst] = A[1, r0:r1, src]
        out = _ifft(Xh, 2)
        c = out[0, :, :W]
        ps, dp = (psi[r0:r1], dphi[:, r0:r1]) if sink is None else (psi[:h], dphi[:, :h])
        if ex is None:
            ps[...] = c
        else:
            np.multiply(c, ex, out=ps)
        np.abs(c, out=mod[r0:r1])
        # d phi = Im(conj(c) dc) / |c|^2: exact for the sampled window, no unwrapping
        ch = cc[:h]
        np.conjugate(c, out=ch)
        ph = prod[:, :h]
        np.multiply(out[1:, :, :W], ch, out=ph)
        # in the maps' own precision: a float32 frame runs float32 loops throughout
        inv = np.square(mod[r0:r1], out=rinv[:h])
        np.reciprocal(inv, out=inv)  # inf where Psi = 0: d phi is NaN there, as 0/0
        np.multiply(ph.imag, inv, out=dp)
        if sink is not None:
            sink(r0, r1, ps, dp, mod[r0:r1])

