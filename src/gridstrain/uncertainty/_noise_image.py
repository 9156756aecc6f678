"""The sensor's noise model from one image: the grid's spectrum notched out tile by tile,
the residual's variance binned by grey level and fitted with Var = K l + L
(:func:`estimate_noise_image`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import fft as sfft
from scipy import ndimage

from .._stats import median, row_medians
from .._validation import (
    as_image,
    check_int,
    check_mask,
    check_positive,
    check_type,
)
from ..phase import Lattice, detect_lattice, spectrum_block, transfer_function
from ._noise import _Q75, NoiseModel, _intervals, _settled, _wls

# Side of the tiles whose median periodogram measures the grid's harmonic content:
# 128 px resolve 1/128 cycle/px.
_TILE = 128


# Harmonics n k1 + m k2 with |n|, |m| up to this order are candidates for a notch
# (beyond it the pixel's integration leaves less than a grey level on a sharp
# checkerboard at pitch 5).
_MAX_ORDER = 12


# A harmonic is notched when the tile spectrum near its aliased frequency exceeds
# this many times the noise floor (the median over the bins away from every
# candidate). Over ~60 tiles the 3 x 3-smoothed median of white noise spreads by
# about 0.1 relative, so 1.3 is ~3 spreads above it; a harmonic left below it adds
# a fraction of the noise density over a few bins of the kept band, under 1 %.
_PEAK_FACTOR = 1.3


# Frequency std of each Gaussian notch, cycles/px: wide enough to cover a peak
# broadened by lighting, strain or a lattice error of 1e-4 cycle/px at order 12,
# narrow enough that hundreds of notches leave most of the band.
_NOTCH_STD = 0.012


# A notch widens by this fraction per decade of its peak above the noise floor:
# a strong harmonic carries strong skirts (a print texture or the lighting
# modulating it, the strain spreading it), which a fixed width lets through. A
# 20-px texture of 5 % contrast biased the variance by +8 % with fixed notches,
# by under 0.5 % with 0.15 (the fundamental's notch is then ~2.5 times wider).
_WIDEN = 0.15


# Residuals beyond this many robust standard deviations (within an intensity bin)
# are rejected as outliers: dust, steps, texture; the truncation's effect on the
# variance of Gaussian residuals is divided out exactly.
_CLIP = 3.5


# E[X^2 | |X| <= c] / Var for a standard normal: the truncation's effect divided out
_CLIP_KAPPA = 1 - 2 * _CLIP * math.exp(-_CLIP**2 / 2) / math.sqrt(2 * math.pi) / math.erf(
    _CLIP / math.sqrt(2))


# tiles transformed at once by _tile_spectrum: 16 tiles of 128 x 128
_TILE_BATCH_BYTES = 2**21


def _blackman_harris(n: int) -> np.ndarray:
    # 4-term Blackman-Harris: sidelobes below -92 dB, so the grid's fundamental
    # (1e8 times the noise density on a 12-bit image) does not leak over the band
    t = 2 * np.pi * np.arange(n) / n
    return 0.35875 - 0.48829 * np.cos(t) + 0.14128 * np.cos(2 * t) - 0.01168 * np.cos(3 * t)


def _tile_spectrum(img: np.ndarray, usable: np.ndarray, tile: int) -> np.ndarray:
    """(tile, tile) median periodogram over half-overlapping tiles, 3 x 3 smoothed.

    The tiles (together about 4 times the image) are transformed a batch at a
    time, each batch's periodograms written straight into the (bins, tiles) table
    whose rows the median is taken along: the memory is that table, half a tile's
    bins per tile (about twice the image in float64), whatever the image's size.
    """
    win = np.outer(_blackman_harris(tile), _blackman_harris(tile))
    step = tile // 2
    blocks = sliding_window_view(img, (tile, tile))[::step, ::step]
    good = sliding_window_view(usable, (tile, tile))[::step, ::step].all(axis=(2, 3))
    # the tiles wholly usable, or all of them when fewer than 4 are (holes
    # everywhere: the median over all tiles is still robust)
    if np.count_nonzero(good) < 4:
        good = np.ones(good.shape, dtype=bool)
    where = np.argwhere(good)
    n, wr = len(where), tile // 2 + 1
    # a real tile's periodogram is even: half of it, one row of bins per frequency
    table = np.empty((tile * wr, n))
    batch = max(1, _TILE_BATCH_BYTES // (tile * tile * 8))
    for i0 in range(0, n, batch):
        idx = where[i0:i0 + batch]
        sel = blocks[idx[:, 0], idx[:, 1]]
        sel = (sel - sel.mean(axis=(1, 2), keepdims=True)) * win
        table[:, i0:i0 + len(idx)] = (np.abs(sfft.rfft2(sel)) ** 2).reshape(len(idx), -1).T
    med = row_medians(table).reshape(tile, wr)
    spec = np.empty((tile, tile))
    spec[:, :wr] = med
    spec[:, wr:] = med[(-np.arange(tile)) % tile][:, tile - wr:0:-1]
    return ndimage.uniform_filter(spec, 3, mode="wrap")


def _harmonics(lattice: Lattice, order: int) -> np.ndarray:
    """(M, 2) aliased frequencies ``(f_y, f_x)`` of ``n k1 + m k2``, in [-1/2, 1/2)."""
    n, m = np.meshgrid(np.arange(-order, order + 1), np.arange(-order, order + 1))
    k1, k2 = np.array(lattice.k1), np.array(lattice.k2)  # (k_x, k_y)
    f = n.ravel()[:, None] * k1 + m.ravel()[:, None] * k2
    f = (f + 0.5) % 1.0 - 0.5
    return f[:, ::-1]


def _residual_filter(shape, lattice: Lattice, spec: np.ndarray, s: float):
    """Transfer (H, W) of the grid-removal filter and the notched frequencies.

    ``H(f) = prod_h (1 - exp(-|f - f_h|^2 / (2 s^2)))^2`` over the significant
    harmonics (always 0 and the fundamentals): a double zero at each, so a peak
    of width ``w`` leaks ``(w^2 / 2 s^2)^4`` of its power.
    """
    H, W = shape
    tile = spec.shape[0]
    cand = _harmonics(lattice, _MAX_ORDER)
    # each candidate's tile bin (rounded half to even, as round() does), all at once
    iy, ix = (np.rint(cand[:, a] * tile).astype(np.intp) % tile for a in range(2))
    # noise floor: tile bins more than 3 bins from every candidate
    near = np.zeros((tile, tile), dtype=bool)
    d = np.arange(-3, 4)
    near[((iy[:, None] + d) % tile)[:, :, None], ((ix[:, None] + d) % tile)[:, None, :]] = True
    # each candidate's largest bin within one (3 x 3, wrapped)
    peaks = ndimage.maximum_filter(spec, size=3, mode="wrap")[iy, ix]
    far = spec[~near] if (~near).sum() >= 20 else spec.ravel()
    floor = float(np.median(far)) if (~near).sum() >= 20 else float(np.quantile(far, 0.1))
    n = np.arange(-_MAX_ORDER, _MAX_ORDER + 1)
    nn, mm = np.meshgrid(n, n)
    always = (np.abs(nn) + np.abs(mm)).ravel() <= 1
    out = np.ones((H, W))
    fy_all, fx_all = np.fft.fftfreq(H), np.fft.fftfreq(W)
    used = []
    for (fy, fx), keep, peak in zip(cand, always, peaks, strict=True):
        if not keep and peak <= _PEAK_FACTOR * floor:
            continue
        used.append((fy, fx))
        # strong peaks carry strong skirts (texture, lighting, strain): wider notches
        sh = s * (1.0 + _WIDEN * math.log10(max(float(peak) / floor, 1.0)))
        dy = (fy_all - fy + 0.5) % 1.0 - 0.5
        dx = (fx_all - fx + 0.5) % 1.0 - 0.5
        ri, ci = np.nonzero(np.abs(dy) < 8 * sh)[0], np.nonzero(np.abs(dx) < 8 * sh)[0]
        g = np.exp(-0.5 * dy[ri, None] ** 2 / sh**2) * np.exp(-0.5 * dx[None, ci] ** 2 / sh**2)
        g = (1.0 - g) ** 2
        # the notch's rows and columns are a run each, or two where it wraps round the
        # spectrum's edge: written through slices, not gathered and scattered
        for rs, ra in _runs(ri):
            for cs, ca in _runs(ci):
                out[rs, cs] *= g[ra, ca]
    return out, np.array(used)


def _runs(idx: np.ndarray) -> list[tuple[slice, slice]]:
    """The runs of consecutive values of the increasing indices ``idx``: ``(slice of
    the values, slice of their places in idx)`` each."""
    if idx.size == 0:
        return []
    cut = np.flatnonzero(np.diff(idx) != 1) + 1
    return [(slice(int(idx[a]), int(idx[b - 1]) + 1), slice(int(a), int(b)))
            for a, b in zip(np.r_[0, cut], np.r_[cut, idx.size], strict=True)]


def _clipped_variance(r: np.ndarray) -> float:
    """Variance of zero-mean Gaussian samples ``r`` with outliers rejected."""
    c, kappa = _CLIP, _CLIP_KAPPA
    s2 = (median(np.abs(r), overwrite_input=True) / _Q75) ** 2
    for _ in range(20):
        keep = r * r <= c * c * s2
        new = float(np.mean(r[keep] ** 2)) / kappa
        if abs(new - s2) <= 1e-9 * new:
            break
        s2 = new
    return s2


def estimate_noise_image(image, lattice: Lattice | None = None, *, mask=None,
                         saturation: float | None = None, scale: float = 1,
                         n_bins: int = 32) -> NoiseModel:
    """Estimate the Poisson-Gaussian noise ``Var = K l + L`` from a single grid image.

    Parameters
    ----------
    image : (H, W) array_like
        One frame of a grid or checkerboard, grey levels as stored (at least
        160 x 160 px). Not modified.
    lattice : Lattice, optional
        The grid's wave vectors, used to find the regions without a grid (holes,
        background) whose edges are left out. Default: detected.
    mask : (H, W) bool array_like, optional
        True on the pixels that may be used; the neighbourhood of the others is
        left out too.
    saturation : float, optional
        Stored grey level at which the sensor clips; pixels near a clipped one are
        left out (as are those near a zero).
    scale : float
        Stored grey levels per sensor grey level (16 for 12-bit data stored x16);
        only used to report ``K`` and ``L`` in sensor units.
    n_bins : int
        Number of intensity bins of equal counts.

    Returns
    -------
    NoiseModel
        ``method == "single image"``, ``n_frames == 1``; ``levels`` and
        ``variances`` per bin in stored units (the variance of the image noise, the
        filter's gain divided out).

    Notes
    -----
    A grid image is a locally periodic pattern times a slowly varying lighting,
    plus noise: in the spectrum the pattern lives in narrow peaks at the harmonics
    ``n k1 + m k2`` (``|n|, |m| <= 12``, folded by the sampling) and at zero, and
    the noise, white, everywhere. Which harmonics hold more than noise is read
    from the data, the median over half-overlapping 128 x 128 tiles of
    Blackman-Harris periodograms (so a hole or an edge in a few tiles does not
    matter): a harmonic is notched when the tile spectrum near it exceeds 1.3
    times the noise floor. The filter is ``H(f) = prod (1 - G(f - f_h))^2`` over
    the notched harmonics, ``G`` a Gaussian of 0.012 cycle/px (wider on images
    under 560 px, and for strong peaks): a double zero at each harmonic, so a peak broadened by the
    lighting or the strain leaks nothing measurable, and a kernel whose reach is
    about 60 px. The residual ``r = h * image`` is what the grid does not explain.

    The filter's effect is accounted for exactly, not fitted: a pixel's residual
    has variance ``sum_y h(x - y)^2 (K l(y) + L) = G (K lambda(x) + L)`` with
    ``G = sum h^2`` (Parseval: the fraction of white-noise power the filter
    passes, computed from ``h``) and ``lambda = (h^2 * image) / G`` the local level
    with the weights ``h^2`` (linear in the image, so unbiased). The pairs
    ``(lambda, r^2 / G)`` are grouped in bins of equal counts by ``lambda``; in
    each bin the variance is a clipped mean of ``r^2`` (3.5 robust standard
    deviations, the truncation divided out), and ``K``, ``L`` come from the
    weighted fit of these bin variances, as in single-image raw-data noise
    estimation (Foi et al. 2008). Pixels within the kernel's reach of the image
    border, of a pixel outside ``mask``, of a clipped pixel, or of the border of a
    region without a grid (fundamental modulus below a quarter of its median,
    evaluated from the image's spectrum near each fundamental on a grid of a few
    pixels) are left out; the inside of a hole, uniform, is noise and is kept. Confidence
    intervals come from the fit's covariance, with each
    bin's error from the chi-square law corrected for the correlation the filter
    puts between neighbouring residuals (``sum_d rho(d)^2``, from ``h``),
    inflated by the square root of the reduced chi-square when above 1.

    ``L`` is poorly pinned by one image (its levels span a narrow range far from 0:
    +-1117 around 1301 on 12-bit images stored x16, a fifth of the draws negative,
    while ``K`` stays within 1 %): its interval says so, and a negative fit, which
    no sensor gives, is refitted with ``L = 0`` (``K`` alone, the same weights),
    its interval ``[0, L + half-width]``. The variance at the image's levels, what
    the uncertainty maps use, moves by less than the fit's own error: the refit
    keeps the weighted residual least.

    Print texture (a static reflectance pattern) is not noise. A texture smooth
    over a few pixels modulates the harmonics and the zero frequency within their
    notches, which widen with the strength of their peak (15 % per decade above
    the noise floor), and is removed with the grid; what a texture holds at the
    scale of a pixel or two passes the filter and is counted as noise: the
    estimate is biased up by the texture's power in the kept band. Measured
    (``tests/test_noise_image.py``) on the variance at the mean level: +0.2 %
    for a 5 % texture smooth over 20 px (+0.6 % at 10 %), +1.6 % over 5 px,
    +7.5 % for a 2 % texture over 3 px and +37 % for 5 %. Without texture, on
    512 x 688 12-bit images stored x16 (checkerboards rotated 20 and -12 degrees
    at pitches 5.3 and 7.1, sharp lines at pitch 4, a sine grid at 6.2; a hole,
    lighting falling to 40 %): ``K`` within 1.5 % and the variance at the mean
    level within 0.8 %, in about 0.08 s (0.2 s at 1040 x 1376 px).

    References
    ----------
    A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian, "Practical
    Poissonian-Gaussian noise modeling and fitting for single-image raw-data",
    IEEE Trans. Image Process. 17 (2008) 1737-1754. doi:10.1109/TIP.2008.2001399
    """
    img = as_image(image).astype(np.float64, copy=False)  # read only, never written
    H, W = img.shape
    if min(H, W) < 160:
        raise ValueError(f"image must be at least 160 x 160 px to estimate its noise, got "
                         f"{H} x {W}")
    lattice = check_type(lattice, "lattice", Lattice, allow_none=True)
    n_bins = check_int(n_bins, "n_bins", minimum=3)
    scale = check_positive(scale, "scale")
    m = check_mask(mask, img.shape)
    saturation = check_positive(saturation, "saturation", allow_none=True)
    bad = ~m | (img <= 0)
    if saturation is not None:
        bad |= img >= saturation
    if lattice is None:
        lattice = detect_lattice(img, mask=m)
    F = sfft.rfft2(img)
    edge = _gridless_borders(F, img.shape, lattice, m)
    # the kernel of a Gaussian notch of frequency std s is a Gaussian envelope of
    # 1 / (2 pi s) px (its square, of the double notch, is narrower): beyond 4.5 of
    # them a pixel's residual no longer sees an edge, a hole or a clipped pixel
    # on small images the notches widen so that the reach stays a sixth of the side
    notch = max(_NOTCH_STD, 4.5 / (2 * math.pi * min(H, W) / 6))
    reach = math.ceil(4.5 / (2 * math.pi * notch))
    tile = min(_TILE, 1 << math.floor(math.log2(min(H, W) / 2)))
    Hf, _ = _residual_filter(img.shape, lattice, _tile_spectrum(img, ~bad & ~edge, tile), notch)
    del img  # each full-size map is dropped once used
    # correlation of neighbouring residuals: Var(mean of n r^2) = 2 V^2 R / n
    A = np.abs(Hf) ** 2
    R = float(A.size * np.sum(A * A) / np.sum(A) ** 2)
    del A
    r, lam, G = _filtered_residual(F, Hf, (H, W))
    del F, Hf
    bad |= edge
    # nothing to keep away from (no mask, no clipped pixel, no gridless region): no
    # dilation, which would cost a pass over the image for nothing
    ok = ~ndimage.binary_dilation(bad, iterations=reach) if bad.any() else \
        np.ones(bad.shape, dtype=bool)
    ok[:reach] = ok[-reach:] = False
    ok[:, :reach] = ok[:, -reach:] = False
    n_bins = min(n_bins, np.count_nonzero(ok) // 200)
    if n_bins < 8:
        raise ValueError(f"too few usable pixels ({np.count_nonzero(ok)}) to estimate the "
                         "noise from this image (borders, masked, clipped and gridless "
                         "regions are left out with a band of "
                         f"{reach} px); a larger image or a noise model from a stack "
                         "helps")
    box = [lam[ok], r[ok]]
    del lam, r
    lb, vb, nbin = _binned_variances(box, n_bins, G)
    K, L, cov, chi2, err = _fit_binned(lb, vb, nbin, R)
    red, (sK, sL) = _intervals(cov, chi2, lb.size)
    L_ci = (max(0.0, L - sL), L + sL)  # a variance is not negative
    if L < 0:
        # the read-noise variance refitted at its bound, 0: K alone, same weights
        w = 1.0 / err**2
        K = float(np.sum(w * lb * vb) / np.sum(w * lb * lb))
        L, L_ci = 0.0, (0.0, max(L + sL, 0.0))
    return NoiseModel(K=K, L=L, K_ci=(K - sK, K + sK), L_ci=L_ci, scale=scale,
                      n_frames=1, n_pixels=int(np.count_nonzero(ok)), dof=None,
                      reduced_chi2=red, levels=lb, variances=vb, variance_errors=err,
                      method="single image", filter_gain=G)


def _gridless_borders(F, shape, lattice, mask) -> np.ndarray:
    """(H, W) bool: the borders of the regions without a grid (fundamental modulus
    below a quarter of its median), steps the grid-removal filter does not remove.

    ``F`` is the real 2-D FFT (``rfft2``) of the image of ``shape``. The moduli of
    the windowed transform at the two fundamentals (window of standard deviation
    the pitch) are band-limited: they
    are evaluated on a grid of about ``sigma / 1.5`` px from the spectrum within
    ``0.68 / sigma`` of each fundamental (the window's transfer falls below 1e-4
    beyond), one small inverse FFT each instead of a windowed Fourier transform of
    the whole image. The periodic extension this assumes only changes the moduli
    within a few windows of the image border, which the estimate leaves out anyway.
    """
    H, W = shape
    sigma = lattice.pitch
    band = 0.68 / sigma  # cycles/px: exp(-2 pi^2 sigma^2 band^2) < 1e-4
    by, bx = math.ceil(band * H), math.ceil(band * W)
    h, w = sfft.next_fast_len(2 * by + 1), sfft.next_fast_len(2 * bx + 1)
    dy, dx = np.arange(-by, by + 1), np.arange(-bx, bx + 1)
    mods = []
    for kx, ky in (lattice.k1, lattice.k2):
        ny, nx = round(ky * H), round(kx * W)
        rows, cols = (ny + dy) % H, (nx + dx) % W
        gy = transfer_function((ny + dy) / H - ky, sigma)
        gx = transfer_function((nx + dx) / W - kx, sigma)
        small = np.zeros((h, w), dtype=complex)
        small[np.ix_(dy % h, dx % w)] = _spectrum_at(F, rows, cols, W) * np.outer(gy, gx)
        # |sum_d F(k + d) G(d) exp(2 i pi d.x)| at x = (i H / h, j W / w): the modulus
        mods.append(np.abs(sfft.ifft2(small)) * (h * w) / (H * W))
    # back to pixels: each pixel takes the nearest coarse sample
    iy = np.rint(np.arange(H) * h / H).astype(int) % h
    ix = np.rint(np.arange(W) * w / W).astype(int) % w
    inner = np.zeros((H, W), dtype=bool)
    e = math.ceil(3 * sigma)
    inner[e:H - e, e:W - e] = True
    sel = mask & inner
    nogrid = np.zeros((H, W), dtype=bool)
    for mod in mods:
        full = mod[np.ix_(iy, ix)]
        ref = full[sel] if sel.any() else full.ravel().copy()
        nogrid |= full < 0.25 * median(ref, overwrite_input=True)
        del full, ref
    # the modulus marks a gridless region's border to within about two pitches, and
    # the coarse grid to within half its step
    band_px = math.ceil(2 * lattice.pitch + 0.5 * max(H / h, W / w))
    return ndimage.binary_dilation(nogrid, iterations=band_px) & ndimage.binary_dilation(
        ~nogrid, iterations=band_px)


def _spectrum_at(F, rows, cols, W):
    """The full 2-D FFT at ``rows`` x ``cols`` from the real one ``F`` (``rfft2`` of a
    real image of ``W`` columns), by :func:`gridstrain.phase._transform._spectrum_block`, which
    takes its columns in increasing order."""
    order = np.argsort(cols, kind="stable")
    out = np.empty((rows.size, cols.size), dtype=F.dtype)
    out[:, order] = spectrum_block(F, rows, cols[order], W)
    return out


def _filtered_residual(F, Hf, shape):
    """Residual ``r = h * img`` of the grid-removal filter of transfer ``Hf``, the
    local level ``lambda = (h^2 * img) / G`` and the filter's white-noise gain
    ``G = sum h^2`` (Parseval), from ``F`` the image's real 2-D FFT (``rfft2``):
    ``Hf`` is even (the harmonics come in opposite pairs), so ``h`` is real and its
    half spectrum is enough."""
    half = Hf[:, :F.shape[1]]
    G = float(np.mean(Hf * Hf))  # Parseval: sum h^2, the white-noise power passed
    # one full-size map at a time beside F: h^2's transform, then each product in place
    h = sfft.irfft2(half, s=shape)
    np.multiply(h, h, out=h)
    spec = sfft.rfft2(h)
    del h
    lam = sfft.irfft2(np.multiply(spec, F, out=spec), s=shape)
    del spec
    lam /= G
    spec = np.multiply(F, half)
    r = sfft.irfft2(spec, s=shape)
    return r, lam, G


# Bins' edges up to this many are found by comparisons rather than binary searches.
_COMPARED_EDGES = 64


def _binned_variances(box: list, n_bins, G):
    """Per bin of equal counts by level ``lv``: mean level, clipped variance of the
    residuals ``rv`` divided by the filter gain ``G``, and the pixel count (bins of
    fewer than 50 pixels are dropped). ``box`` is ``[lv, rv]``, handed over: each
    is dropped once sorted by bin."""
    lv = box[0]
    # bins of about equal counts: the edges are quantiles of every 8th pixel (the
    # counts vary by about 1 %, and each bin's count weighs its variance), the two
    # outer ones the extremes of all, so that every pixel falls in a bin
    edges = np.quantile(lv[::8], np.linspace(0, 1, n_bins + 1))
    edges[0], edges[-1] = lv.min(), lv.max()
    edges = np.unique(edges)
    nb = edges.size - 1
    if nb < 3:
        raise ValueError("the image spans too narrow a range of levels to fit "
                         "Var = K l + L")
    if edges.size <= _COMPARED_EDGES:
        # the count of edges at or below each level, as np.searchsorted(edges, lv,
        # "right") gives it (NaN above every edge), one comparison an edge: 33 passes
        # over 1.2 M levels take 9 ms, the binary searches 32 ms
        count = np.zeros(lv.size, dtype=np.int16)
        for e in edges:
            count += lv >= e
        count[np.isnan(lv)] = edges.size
    else:
        count = np.searchsorted(edges, lv, side="right")
    idx = np.clip(count - 1, 0, nb - 1).astype(np.int16)
    del count
    lb, vb, nbin = [], [], []
    # a stable sort of small integers is a radix sort
    order = np.argsort(idx, kind="stable")
    splits = np.cumsum(np.bincount(idx, minlength=nb))[:-1]
    del idx
    lv = box.pop(0)[order]
    rv = box.pop(0)[order]
    del order
    for lg, rg in zip(np.split(lv, splits), np.split(rv, splits), strict=True):
        if lg.size < 50:
            continue
        lb.append(float(lg.mean()))
        vb.append(_clipped_variance(rg) / G)
        nbin.append(lg.size)
    lb, vb, nbin = np.array(lb), np.array(vb), np.array(nbin, dtype=np.float64)
    if lb.size < 3:
        raise ValueError("too few intensity bins to fit Var = K l + L")
    return lb, vb, nbin


def _fit_binned(lb, vb, nbin, R):
    """``K``, ``L``, their covariance, the chi-square and the bin errors of the
    weighted fit of ``Var = K l + L`` to the bin variances, the weights from the
    chi-square law with the residuals' correlation factor ``R``, iterated."""
    K, L = np.polyfit(lb, vb, 1)
    for _ in range(20):
        model = np.maximum(K * lb + L, 1e-6 * float(np.median(vb)))
        err = model * np.sqrt(2 * R / nbin)
        (K_new, L_new), cov, chi2 = _wls(lb, vb, err)
        done = _settled(K, L, K_new, L_new, float(np.mean(lb)), 1e-9)
        K, L = float(K_new), float(L_new)
        if done:
            break
    if not K > 0:
        raise ValueError(f"no signal-dependent noise found in the image (fitted K = {K:.3g}); "
                         "it may be processed (denoised, compressed) or hold no grid")
    return K, L, cov, chi2, err
