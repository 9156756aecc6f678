"""Compiled loops of the windowed Fourier transform, of its coupling correction, of the
carrier's move and of method B's sums (numba, the ``fast`` extra).

Imported only by :func:`gridstrain.phase._maps._load_kernels`, on the first
transform, correction or move that uses them, never when gridstrain is imported:
numba's own import takes a few hundred milliseconds, and compiling takes seconds the
first time (the machine code is then cached on disk, ``cache=True``, and loaded in
about a tenth of that).

The loops are written for one dtype at a time: a float32 frame runs float32
arithmetic throughout (no literal constant that would promote it to float64), and
the loops over columns are innermost on contiguous rows so that LLVM vectorises
them. ``error_model="numpy"``: a division by zero gives inf or NaN as in numpy
(``Psi = 0``, no signal: the derivative is 0/0, NaN), instead of raising.
"""

from __future__ import annotations

import numpy as np

try:
    from numba import njit
except ImportError:  # the module stays importable (its doctests are collected)
    njit = None

__all__: list[str] = []

# whether the loops below are compiled; without numba they stay plain Python
# functions, which gridstrain.phase._transform never calls (it runs its numpy paths instead)
AVAILABLE = njit is not None

# contract: a * b + c as one fused multiply-add (one rounding instead of two); no
# other fast-math licence, so that NaN and inf propagate as in numpy
_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False,
            "fastmath": {"contract"}}
_jit = njit(**_OPTIONS) if AVAILABLE else (lambda func: func)


@_jit
def demodulate_rows(X, e0, ey_re, ey_im, ex_re, ex_im, m, re, im, row0):  # pragma: no cover
    """Rows ``e0 ..`` of the demodulated map, with ``m`` columns each side, as planes.

    ``X`` (h, 2 nx) real: the real view of the inverse FFT along x of h consecutive
    rows of the periodic transform. Column ``c`` of the planes is column ``c - m`` of
    the image (read modulo nx: the columns just outside the image are those of the
    zero-extended one), multiplied by the residual carrier ``ex[c] ey[e]``.
    ``re``, ``im`` (R, W + 2m) real: rows ``row0 .. row0 + h - 1`` receive the
    extended rows ``e0 .. e0 + h - 1`` (row ``e`` is image row ``e - m``).
    """
    h = X.shape[0]
    nx = X.shape[1] // 2
    wc = ex_re.size
    for i in range(h):
        e = e0 + i
        yr = ey_re[e]
        yi = ey_im[e]
        out_r = re[row0 + i]
        out_i = im[row0 + i]
        row = X[i]
        # columns -m .. -1 (the end of the periodic row), then 0 .. W + m - 1
        _demodulate(out_r[:m], out_i[:m], row[2 * (nx - m):], ex_re[:m], ex_im[:m], yr, yi)
        _demodulate(out_r[m:wc], out_i[m:wc], row, ex_re[m:wc], ex_im[m:wc], yr, yi)


@_jit
def _demodulate(out_r, out_i, src, ex_re, ex_im, yr, yi):  # pragma: no cover
    """``out = src * ex * (yr + i yi)``, ``src`` interleaved (re, im) pairs."""
    for c in range(out_r.size):
        cr = ex_re[c] * yr - ex_im[c] * yi
        ci = ex_re[c] * yi + ex_im[c] * yr
        xr = src[2 * c]
        xi = src[2 * c + 1]
        out_r[c] = xr * cr - xi * ci
        out_i[c] = xr * ci + xi * cr


@_jit
def band_columns(V, rows, dst, cols, nx, gx, gy, m, Y):  # pragma: no cover
    """The y-transform's input: the band of the image's spectrum, windowed.

    ``V`` (ny, nx // 2 + 1) complex: rfft2 of the image. ``Y[m + dst[i], j] =
    X[rows[i], cols[j]] gx[j] gy[i]``, with the full spectrum ``X`` read from its
    half, ``X[r, c] = conj(X[-r, -c])`` for a real image. ``cols`` ascending: the
    columns held in ``V`` come first. The rows outside the band are left as they are.
    """
    ny, nh = V.shape
    ncol = cols.size
    npos = 0
    while npos < ncol and cols[npos] < nh:
        npos += 1
    for i in range(rows.size):
        r = rows[i]
        rc = (ny - r) % ny
        out = Y[m + dst[i]]
        g = gy[i]
        src = V[r]
        mirror = V[rc]
        for j in range(npos):
            out[j] = src[cols[j]] * (gx[j] * g)
        for j in range(npos, ncol):
            out[j] = np.conj(mirror[nx - cols[j]]) * (gx[j] * g)


@_jit
def spread_rows(A, e0, runs, gaps, X):  # pragma: no cover
    """``X[i]``: row ``e0 + i`` of ``A`` (the band's columns) spread over the row of the
    x spectrum, zeros elsewhere. ``runs`` (n, 3): destination, source, length of each
    run of columns; ``gaps`` (g, 2): start and stop of the zeroed columns."""
    for i in range(X.shape[0]):
        row = X[i]
        src = A[e0 + i]
        for g in range(gaps.shape[0]):
            row[gaps[g, 0]:gaps[g, 1]] = 0
        for r in range(runs.shape[0]):
            d, s, n = runs[r, 0], runs[r, 1], runs[r, 2]
            row[d:d + n] = src[s:s + n]


@_jit
def _three(a, n0):  # pragma: no cover
    """Taps ``n0 .. n0 + 2`` of ``a`` (``a[n - 1]``, zero past its end) and the last two
    offsets, clipped to ``a.size`` (read with the zero weights, never out of reach)."""
    m = a.size
    a1 = a[n0 - 1]
    a2 = a[n0] if n0 < m else a1 - a1
    a3 = a[n0 + 1] if n0 + 1 < m else a1 - a1
    return a1, a2, a3, min(n0 + 1, m), min(n0 + 2, m)


@_jit
def _sum3(out, a1, a2, a3, h1, l1, h2, l2, h3, l3, first):  # pragma: no cover
    """``out (+)= a1 (h1 - l1) + a2 (h2 - l2) + a3 (h3 - l3)`` (1-D, the same length)."""
    if first:
        for x in range(out.size):
            out[x] = a1 * (h1[x] - l1[x]) + a2 * (h2[x] - l2[x]) + a3 * (h3[x] - l3[x])
    else:
        for x in range(out.size):
            out[x] += a1 * (h1[x] - l1[x]) + a2 * (h2[x] - l2[x]) + a3 * (h3[x] - l3[x])


@_jit
def _rows_d(out, P, r, c0, a):  # pragma: no cover
    """``out[x] = sum_n a[n-1] (P[r + n, c0 + x] - P[r - n, c0 + x])``: the y filter at
    row ``r``; taps grouped as in :func:`_dx` (no tap of zero weight read)."""
    m = a.size
    W = out.size
    n = 1
    while n <= m:
        if n == 1 or n + 2 <= m:
            a1, a2, a3, n2, n3 = _three(a, n)
            _sum3(out, a1, a2, a3, P[r + n, c0:c0 + W], P[r - n, c0:c0 + W],
                  P[r + n2, c0:c0 + W], P[r - n2, c0:c0 + W],
                  P[r + n3, c0:c0 + W], P[r - n3, c0:c0 + W], n == 1)
            n += 3
        elif n + 1 == m:
            _sum2(out, a[n - 1], a[n], P[r + n, c0:c0 + W], P[r - n, c0:c0 + W],
                  P[r + n + 1, c0:c0 + W], P[r - n - 1, c0:c0 + W])
            n += 2
        else:
            _sum1(out, a[n - 1], P[r + n, c0:c0 + W], P[r - n, c0:c0 + W])
            n += 1


@_jit
def _rate(out, pr, pi, fr, fi):  # pragma: no cover
    """``out = Im(conj(p) f) / |p|^2``, the phase derivative (1-D, the same length)."""
    for x in range(out.size):
        # 0/0 where Psi = 0: NaN, as the exact path gives
        out[x] = (pr[x] * fi[x] - pi[x] * fr[x]) / (pr[x] * pr[x] + pi[x] * pi[x])


@_jit
def phase_derivatives(re, im, taps, y0, y1, base, psi, mod, dx, dy, out0,
                      tmp):  # pragma: no cover
    """Rows ``y0 .. y1 - 1`` of ``psi``, ``|psi|`` and both phase derivatives.

    ``re``, ``im`` (R, W + 2m): rows of the demodulated map with ``m = taps.size``
    columns beyond the image each side (:func:`demodulate_rows`), row ``i`` holding
    the extended row ``base + i`` (image row ``base + i - m``). The derivative
    of the phase along an axis is ``Im(conj(psi) D psi) / |psi|^2`` with the
    antisymmetric filter ``D psi[x] = sum_n taps[n-1] (psi[x+n] - psi[x-n])``.
    ``psi`` (h, 2W) real (the complex map's real view), ``mod``, ``dx``, ``dy``
    (h, W) real (the moduli and the derivatives): row y at index ``y - out0`` (the
    whole maps with ``out0 = 0``, or one block of rows). ``tmp`` (4, W) real:
    scratch for one row's filtered values.

    Each loop below runs over a contiguous row with few arrays and three taps at a
    time (the last one or two by loops of their own, no tap of zero weight read):
    LLVM vectorises those (with more arrays that might overlap in one loop it gives
    up), and the sums stay in registers over three taps.
    """
    m = taps.size
    W = mod.shape[1]
    fxr, fxi, fyr, fyi = tmp[0, :W], tmp[1, :W], tmp[2, :W], tmp[3, :W]
    for y in range(y0, y1):
        r = y + m - base
        _dx(fxr, re[r], taps)
        _dx(fxi, im[r], taps)
        _rows_d(fyr, re, r, m, taps)
        _rows_d(fyi, im, r, m, taps)
        pr = re[r, m:m + W]
        pi = im[r, m:m + W]
        o = y - out0
        _rate(dx[o], pr, pi, fxr, fxi)
        _rate(dy[o], pr, pi, fyr, fyi)
        md = mod[o]
        for x in range(W):
            md[x] = np.sqrt(pr[x] * pr[x] + pi[x] * pi[x])
        ps = psi[o]
        for x in range(W):
            ps[2 * x] = pr[x]
            ps[2 * x + 1] = pi[x]


# method B's sums add what the numpy path adds, operation for operation: no fused
# multiply-add, so that both paths give the same bits
_exact_jit = njit(**(_OPTIONS | {"fastmath": False})) if AVAILABLE else (lambda func: func)


@_jit
def carrier_moved(src, ex_re, ex_im, ey_re, ey_im, out):  # pragma: no cover
    """``out = src ex[x] ey[y]`` (the complex products taken in that order, as numpy
    takes them, to an ulp or two of their modulus), ``src`` and ``out`` (H, 2W) real views of
    one complex map (``out`` may be ``src``), ``ex`` (W,) and ``ey`` (H,) the
    carrier's change along x and y, in the map's precision."""
    H = src.shape[0]
    W = ex_re.size
    for y in range(H):
        e = ey_re[y]
        f = ey_im[y]
        for x in range(W):
            a = src[y, 2 * x]
            b = src[y, 2 * x + 1]
            c = ex_re[x]
            d = ex_im[x]
            re = a * c - b * d
            im = a * d + b * c
            out[y, 2 * x] = re * e - im * f
            out[y, 2 * x + 1] = re * f + im * e


@_exact_jit
def add_unit_sums(psi, mod, dphi, unit, msum, dsum, one, sign):  # pragma: no cover
    """Add (``sign`` 1) or take out (-1) one block of a frame's maps to method B's sums.

    ``psi`` (h, 2W) real view of the block's complex map, ``mod`` (h, W) its modulus,
    ``dphi`` (2, h, W) its derivatives, in the frame's precision; ``unit`` (h, 2W),
    ``msum`` (h, W), ``dsum`` (2, h, W) float64: the rows of the sums of the unit
    phasors ``psi / |psi|`` (real view), of the moduli and of the derivatives. Where
    ``|psi| = 0`` (no signal, no direction) the phasor and the derivatives add 0.
    As :class:`gridstrain.stacks.PhaseMean`'s numpy path: the phasor is ``psi``
    times the reciprocal of the modulus, taken in the frame's precision (``one``, 1
    in that precision) and then in float64.
    """
    h, W = mod.shape
    for y in range(h):
        for x in range(W):
            mv = mod[y, x]
            m = np.float64(mv)
            if mv > 0:
                inv = np.float64(one / mv)
                d0 = np.float64(dphi[0, y, x])
                d1 = np.float64(dphi[1, y, x])
            else:
                inv = 0.0
                d0 = 0.0
                d1 = 0.0
            ur = np.float64(psi[y, 2 * x]) * inv
            ui = np.float64(psi[y, 2 * x + 1]) * inv
            # sign is +1 or -1: each product is exact, so this adds or subtracts
            # exactly what numpy's add or subtract does
            unit[y, 2 * x] += ur * sign
            unit[y, 2 * x + 1] += ui * sign
            msum[y, x] += m * sign
            dsum[0, y, x] += d0 * sign
            dsum[1, y, x] += d1 * sign


# the series pass's pixel sums (gridstrain.stacks.accumulate): numpy's operations per pixel,
# without fused multiply-adds, so that a machine with FMA and one without agree
_SUM_TILE = 1024  # pixels per tile: the tile's sums, origin and differences stay in cache


@_exact_jit
def add_differences(frames, b, origin, w, signs, lin, sq):  # pragma: no cover
    """Add ``b`` raw frames' differences to the origin to the pass's linear sums and
    sums of squares.

    ``frames`` (B, N) raw grey levels (integers, the file's type), of which the first
    ``b`` rows are added; ``origin`` (N,) float64; ``w`` (b, R) float64 the frames'
    weights (one row per frame); ``signs`` (b,) +1 (added) or -1 (taken out);
    ``lin`` (R, N) and ``sq`` (N,) float64 sums, updated in place:
    ``lin[r] += sum_t w[t, r] d_t`` and ``sq += sum_t signs[t] d_t^2`` with ``d_t =
    frames[t] - origin`` in float64. The pixels are taken by tiles, and each tile's
    sums meet every frame of the batch while they are in cache: the sums are read
    and written once per batch, not once per frame.
    """
    N = origin.size
    R = lin.shape[0]
    d = np.empty(_SUM_TILE)
    for i0 in range(0, N, _SUM_TILE):
        i1 = min(i0 + _SUM_TILE, N)
        n = i1 - i0
        # contiguous 1-D views of the tile: what LLVM vectorises
        o = origin[i0:i1]
        q = sq[i0:i1]
        dt = d[:n]
        for t in range(b):
            row = frames[t, i0:i1]
            s = signs[t]  # +1 or -1: the product is exact, a sum or a difference
            for i in range(n):
                v = np.float64(row[i]) - o[i]
                dt[i] = v
                q[i] += (v * v) * s
            for r in range(R):
                wr = w[t, r]
                if wr != 0.0:
                    out = lin[r, i0:i1]
                    for i in range(n):
                        out[i] += wr * dt[i]


# --- the window's phase-modulus coupling (gridstrain.phase._coupling) -------------------

# tanh(x) = x P(x^2) / Q(x^2) for |x| <= _TANH_END, +-1 beyond (where float32's tanh is
# 1): a rational fit of least relative error, within 4e-7 of tanh in float32
# arithmetic, and no libm call, which would keep the loops from vectorising
_TANH_END = np.float32(9.0)
_TANH_P = np.array([1.0, 0.13383981453577715, 0.003498997457494452, 2.0661284075910284e-05,
                    1.341984900877282e-08], np.float32)
_TANH_Q = np.array([1.0, 0.4671730293595846, 0.025890211691717305, 0.00032910405820631253,
                    7.804741053616249e-07], np.float32)
# cos and sin of |b| <= 0.2 rad (the saturated bias) by their Taylor series to b^6 and
# b^7: the next terms, b^8 / 8! and b^9 / 9!, are below 1e-10
_COS = np.array([1.0, -1 / 2, 1 / 24, -1 / 720], np.float32)
_SIN = np.array([1.0, -1 / 6, 1 / 120, -1 / 5040], np.float32)
# ln z = f - s (f - R(s)) for z in [sqrt(1/2), sqrt(2)), f = z - 1, s = f / (2 + f):
# R(s) = 2 s^2 / 3 + 2 s^4 / 5 + ..., the series of 2 atanh s (|s| < 0.172: the terms
# past s^9 are below 1e-9)
_LOG_R = np.array([2 / 3, 2 / 5, 2 / 7, 2 / 9], np.float32)
_LN2 = np.float32(0.6931471805599453)
_SQRT_HALF_BITS = np.int32(0x3F3504F3)  # the bits of float32's sqrt(1/2)
_TINY = np.float32(1.17549435e-38)  # float32's smallest normal number
_HUGE = np.float32(3.4028235e38)  # and its largest finite one


@_jit
def max_norm(psi):  # pragma: no cover
    """``max |psi|^2`` of a complex map's real view ``psi`` (H, 2W), float64; NaN where a
    value is NaN, as ``np.abs(psi).max()`` is."""
    H = psi.shape[0]
    W = psi.shape[1] // 2
    top = 0.0
    nan = False
    for y in range(H):
        row = psi[y]
        for x in range(W):
            re = np.float64(row[2 * x])
            im = np.float64(row[2 * x + 1])
            s = re * re + im * im
            top = s if s > top else top
            nan |= s != s
    return np.nan if nan else top


@_jit
def _saturated(v, s):  # pragma: no cover
    """``s tanh(v / s)``, 0 where ``v`` is not finite (float32)."""
    zero = s - s
    end = _TANH_END
    p, q = _TANH_P, _TANH_Q
    v = v if v - v == zero else zero
    t = v / s
    t = t if t < end else end
    t = t if t > -end else -end
    t2 = t * t
    num = (((p[4] * t2 + p[3]) * t2 + p[2]) * t2 + p[1]) * t2 + p[0]
    den = (((q[4] * t2 + q[3]) * t2 + q[2]) * t2 + q[1]) * t2 + q[0]
    return s * (t * num / den)


@_jit
def _pad(row, m):  # pragma: no cover
    """The ``m`` values each side of a padded row: its ends repeated (``mode="nearest"``)."""
    W = row.size - 2 * m
    for x in range(m):
        row[x] = row[m]
        row[m + W + x] = row[m + W - 1]


@_jit
def _sum2(out, a1, a2, h1, l1, h2, l2):  # pragma: no cover
    """``out += a1 (h1 - l1) + a2 (h2 - l2)``."""
    for x in range(out.size):
        out[x] += a1 * (h1[x] - l1[x]) + a2 * (h2[x] - l2[x])


@_jit
def _sum1(out, a1, h1, l1):  # pragma: no cover
    """``out += a1 (h1 - l1)``."""
    for x in range(out.size):
        out[x] += a1 * (h1[x] - l1[x])


@_jit
def _dx(out, row, a):  # pragma: no cover
    """``out[x] = sum_n a[n-1] (row[m + x + n] - row[m + x - n])``: the differentiator
    along a row padded by ``m = a.size`` each side; three taps a loop, the last one or
    two by loops of their own (no tap of zero weight read)."""
    m = a.size
    W = out.size
    n = 1
    while n <= m:
        if n == 1 or n + 2 <= m:
            a1, a2, a3, n2, n3 = _three(a, n)
            _sum3(out, a1, a2, a3, row[m + n:m + n + W], row[m - n:m - n + W],
                  row[m + n2:m + n2 + W], row[m - n2:m - n2 + W],
                  row[m + n3:m + n3 + W], row[m - n3:m - n3 + W], n == 1)
            n += 3
        elif n + 1 == m:
            _sum2(out, a[n - 1], a[n], row[m + n:m + n + W], row[m - n:m - n + W],
                  row[m + n + 1:m + n + 1 + W], row[m - n - 1:m - n - 1 + W])
            n += 2
        else:
            _sum1(out, a[n - 1], row[m + n:m + n + W], row[m - n:m - n + W])
            n += 1


@_jit
def _dy(out, ring, y, H, a):  # pragma: no cover
    """The differentiator along y at row ``y`` of a map of ``H`` rows, of which ``ring``
    (R, W + 2m) holds the rows ``y - m .. y + m``, row ``r`` in ``ring[r % R]`` (its
    columns ``m .. m + W - 1``); the rows beyond the map are its first or last
    (``mode="nearest"``). Taps grouped as in :func:`_dx`."""
    m = a.size
    R = ring.shape[0]
    W = out.size
    n = 1
    while n <= m:
        if n == 1 or n + 2 <= m:
            a1, a2, a3, n2, n3 = _three(a, n)
            _sum3(out, a1, a2, a3,
                  ring[min(y + n, H - 1) % R, m:m + W], ring[max(y - n, 0) % R, m:m + W],
                  ring[min(y + n2, H - 1) % R, m:m + W], ring[max(y - n2, 0) % R, m:m + W],
                  ring[min(y + n3, H - 1) % R, m:m + W], ring[max(y - n3, 0) % R, m:m + W],
                  n == 1)
            n += 3
        elif n + 1 == m:
            _sum2(out, a[n - 1], a[n],
                  ring[min(y + n, H - 1) % R, m:m + W], ring[max(y - n, 0) % R, m:m + W],
                  ring[min(y + n + 1, H - 1) % R, m:m + W],
                  ring[max(y - n - 1, 0) % R, m:m + W])
            n += 2
        else:
            _sum1(out, a[n - 1],
                  ring[min(y + n, H - 1) % R, m:m + W], ring[max(y - n, 0) % R, m:m + W])
            n += 1


@_jit
def _log_modulus(out, psi, inv, ratio, mant):  # pragma: no cover
    """``out = ln |psi| - ln top`` of one row's real view ``psi`` (2W), as ``ln(float32(
    |psi|^2 / top^2)) / 2``, ``inv = 1 / top^2`` (an image scaled by a power of two
    gives the same bits); ``ratio``, ``mant`` (W,) float32 scratch."""
    for x in range(out.size):
        re = np.float64(psi[2 * x])
        im = np.float64(psi[2 * x + 1])
        ratio[x] = np.float32((re * re + im * im) * inv)
    _log(out, ratio, mant, np.float32(0.5))


@_jit
def _log(out, v, mant, scale):  # pragma: no cover
    """``out = scale ln(v)`` (float32 rows, ``scale`` a power of two), within an ulp, in
    loops that LLVM vectorises (no libm call) but for zeros, subnormals, inf and NaN;
    ``mant`` scratch. ``v = 2^k z``, ``z`` in [sqrt(1/2), sqrt(2)) read from the bits
    (``_LOG_R``)."""
    bits = v.view(np.int32)
    zbits = mant.view(np.int32)
    unusual = 0
    for x in range(out.size):
        k = (bits[x] - _SQRT_HALF_BITS) >> np.int32(23)
        zbits[x] = bits[x] - (k << np.int32(23))
        out[x] = np.float32(k)
        unusual += not _TINY <= v[x] <= _HUGE
    r = _LOG_R
    one, two = np.float32(1), np.float32(2)
    for x in range(out.size):
        f = mant[x] - one
        s = f / (two + f)
        s2 = s * s
        ln = out[x] * _LN2 + (f - s * (f - s2 * (((r[3] * s2 + r[2]) * s2 + r[1]) * s2 + r[0])))
        out[x] = scale * ln
    if unusual:
        for x in range(out.size):
            if not _TINY <= v[x] <= _HUGE:
                out[x] = scale * np.log(v[x])


@_jit
def _copy2(a, b, src_a, src_b):  # pragma: no cover
    """``a = src_a``, ``b = src_b`` (rows, converted to ``a``'s and ``b``'s type)."""
    for x in range(a.size):
        a[x] = src_a[x]
        b[x] = src_b[x]


@_jit
def _first_order(gx, gy, sc, b, wx, wy, sig2, cq, sat):  # pragma: no cover
    """The window's fading ``sc`` and the scaled ``gx``, ``gy`` in place (grad ln |Psi| in,
    ``sc grad ln |Psi|`` out), and the first-order bias ``b``, saturated (float32 rows)."""
    one = np.float32(1)
    for x in range(gx.size):
        q = (gx[x] * gx[x] + gy[x] * gy[x]) * cq
        q *= q
        f = sig2 / (one + q * q)
        sc[x] = f
        gx[x] *= f
        gy[x] *= f
    for x in range(gx.size):
        b[x] = _saturated(wx[x] * gx[x] + wy[x] * gy[x], sat)


@_jit
def _second_order(b, ox, oy, cxx, cxy, cyy, wx, wy, gx, gy, sc, half,
                  sat):  # pragma: no cover
    """``b = ox gx + oy gy + half sc curv``, saturated, with ``ox = wx - ox``, ``oy = wy -
    oy`` (the derivatives of the first-order bias in, omega out) and ``curv = ox^2 cxx +
    2 ox oy cxy + oy^2 cyy`` (in ``cxx``); loops of few arrays, which LLVM vectorises."""
    two = np.float32(2)
    for x in range(b.size):
        ox[x] = wx[x] - ox[x]
        oy[x] = wy[x] - oy[x]
    for x in range(b.size):
        cxx[x] = (ox[x] * ox[x] * cxx[x] + two * ox[x] * oy[x] * cxy[x]
                  + oy[x] * oy[x] * cyy[x])
    for x in range(b.size):
        b[x] = _saturated(ox[x] * gx[x] + oy[x] * gy[x] + half * sc[x] * cxx[x], sat)


@_jit
def _turned(out, psi, b):  # pragma: no cover
    """``out = psi exp(-i b)`` of one row's real views (2W), ``|b| <= 0.2``."""
    c, s = _COS, _SIN
    for x in range(b.size):
        v = b[x]
        v2 = v * v
        cb = ((c[3] * v2 + c[2]) * v2 + c[1]) * v2 + c[0]
        sb = (((s[3] * v2 + s[2]) * v2 + s[1]) * v2 + s[0]) * v
        re = psi[2 * x]
        im = psi[2 * x + 1]
        out[2 * x] = re * cb + im * sb
        out[2 * x + 1] = im * cb - re * sb


@_jit
def _minus(out, src, d):  # pragma: no cover
    """``out = src - d``, ``d`` float32 (exact in ``src``'s precision)."""
    for x in range(out.size):
        out[x] = src[x] - d[x]


@_jit
def coupling_rows(psi, dphi, inv, a, sig2, cq, half, sat, out_psi, out_dphi,
                  ring, rows, tmp):  # pragma: no cover
    """One wave vector's coupling correction (:func:`gridstrain.phase.coupling_corrected`)
    in three passes down the rows, each a few rows behind the one before.

    ``psi`` (H, 2W) real view of the complex map, ``dphi`` (2, H, W); ``inv`` the
    reciprocal of its largest ``|psi|^2`` (:func:`max_norm`); ``a`` (m,) float32 the
    differentiator's taps; ``sig2``, ``cq``, ``half``, ``sat`` float32: ``sigma^2``,
    ``(sigma / steepest)^2``, ``sigma^2 / 2``, the saturation. ``out_psi``,
    ``out_dphi`` as ``psi``, ``dphi``. Scratch, float32: ``ring`` (5, R, W + 2m) and
    ``rows`` (3, R, W), R = 2m + 1: the rows that the differentiators along y reach
    of ``ln |Psi|``, the first-order bias, ``dphi`` and the bias, and those of the
    fading and the scaled gradients; ``tmp`` (5, W).

    Row ``y`` of the first pass (ln |Psi|'s gradient, the first-order bias) needs
    ``ln |Psi|`` to row ``y + m``; the second (omega, the curvature, the bias), at row
    ``y - m``, the first pass's to row ``y``; the third (the corrected maps), at row
    ``y - 2m``, the second's to row ``y - m``. What the passes exchange stays in the
    rings, in cache.
    """
    H = psi.shape[0]
    W = psi.shape[1] // 2
    m = a.size
    R = ring.shape[1]
    lnmod, first, wx, wy, bias = ring[0], ring[1], ring[2], ring[3], ring[4]
    gx, gy, sc = rows[0], rows[1], rows[2]
    t0, t1, t2, t3, t4 = tmp[0], tmp[1], tmp[2], tmp[3], tmp[4]
    for r in range(min(m, H)):
        _log_modulus(lnmod[r % R, m:m + W], psi[r], inv, t0, t1)
        _pad(lnmod[r % R], m)
    for y in range(H + 2 * m):
        if y < H:
            r = y + m
            if r < H:
                _log_modulus(lnmod[r % R, m:m + W], psi[r], inv, t0, t1)
                _pad(lnmod[r % R], m)
            i = y % R
            _copy2(wx[i, m:m + W], wy[i, m:m + W], dphi[0, y], dphi[1, y])
            _pad(wx[i], m)
            _dx(gx[i], lnmod[i], a)
            _dy(gy[i], lnmod, y, H, a)
            _first_order(gx[i], gy[i], sc[i], first[i, m:m + W], wx[i, m:m + W],
                         wy[i, m:m + W], sig2, cq, sat)
            _pad(first[i], m)
        z = y - m
        if 0 <= z < H:
            i = z % R
            _dx(t0, first[i], a)
            _dy(t1, first, z, H, a)
            _dx(t2, wx[i], a)
            _dy(t3, wx, z, H, a)
            _dy(t4, wy, z, H, a)
            _second_order(bias[i, m:m + W], t0, t1, t2, t3, t4, wx[i, m:m + W],
                          wy[i, m:m + W], gx[i], gy[i], sc[i], half, sat)
            _pad(bias[i], m)
        t = y - 2 * m
        if 0 <= t < H:
            i = t % R
            _dx(t0, bias[i], a)
            _dy(t1, bias, t, H, a)
            _turned(out_psi[t], psi[t], bias[i, m:m + W])
            _minus(out_dphi[0, t], dphi[0, t], t0)
            _minus(out_dphi[1, t], dphi[1, t], t1)
