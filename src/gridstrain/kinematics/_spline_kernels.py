"""Compiled loops of the large-displacement correction (numba, the ``fast`` extra).

Imported only by :mod:`gridstrain.kinematics`, on the first large-displacement
correction, never when gridstrain is imported: numba's own import and the loading
of its cached machine code take about 0.4 s of CPU in a fresh process (shared with
any other compiled loop), and compiling takes seconds the first time (the machine
code is then cached on disk, ``cache=True``).

``scipy.ndimage.map_coordinates`` evaluates one map per call and computes the
spline weights of every point again for each; the correction evaluates four maps
at once (the real and imaginary parts of both transforms, or the four phase
derivatives) at the same points. Here the weights are computed once per point and
a row's points are evaluated by runs that share their neighbourhoods' rows, at unit
stride in each map's plane ``(4, H, W)``, so that LLVM vectorises them across the
points; what the correction does with the values (the products whose arguments are
the residuals; the Lagrangian gradient) follows on the same row: the four maps some
twenty times faster than four calls of ``map_coordinates``,
the same numbers to rounding (``tests/test_lagrangian_interpolation.py`` compares every
loop with the scipy and numpy path that runs without numba).

The shortcuts of the phase difference's unwrapping (:func:`unwrap_by_turns`) and the
whole periods of its fringe order (:func:`turns_range`) are here too: numpy's
operations in one or two passes that stop at the first jump, the same bits.

Every loop of the correction works on a range of rows (the prefilter's second half on a range of
columns) and releases the GIL: :mod:`gridstrain.kinematics` runs fixed blocks of
them on the usable cores, with the same result on any number of threads.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__: list[str] = []

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}
# The spline's sums with their products fused (FMA where the CPU has it): the
# evaluation of four maps at 100 000 points 3.6 -> 2.9 ms, each sum's rounding one
# step less (values within 1e-15 of their own size of the unfused ones)
_FUSED = {**_OPTIONS, "fastmath": {"contract"}}


# The B-spline's 1/6, multiplied rather than divided by 6: eight divisions a point
# took a sixth of the evaluation's time (four maps at 100 000 points 2.9 -> 2.6 ms);
# the weights differ by an ulp, the maps by about 1e-15 of their values.
_SIXTH = 1.0 / 6.0


@njit(**_FUSED)
def _weights(t):  # pragma: no cover
    """Cubic B-spline weights of the four samples floor(v) - 1 .. floor(v) + 2,
    ``t = v - floor(v)``."""
    s = 1.0 - t
    return (s * s * s * _SIXTH, (3.0 * t * t * t - 6.0 * t * t + 4.0) * _SIXTH,
            (3.0 * s * s * s - 6.0 * s * s + 4.0) * _SIXTH, t * t * t * _SIXTH)


@njit(**_FUSED)
def _at4(coef, y, x):  # pragma: no cover
    """The four maps of ``coef`` (4, Hp, Wp) at the padded point ``(y, x)``, clamped
    to the map as :func:`cubic4_at` does."""
    _, Hp, Wp = coef.shape
    y = min(max(y, 0.0), Hp - 1.0)
    x = min(max(x, 0.0), Wp - 1.0)
    fy = math.floor(y)
    fx = math.floor(x)
    wy0, wy1, wy2, wy3 = _weights(y - fy)
    wx0, wx1, wx2, wx3 = _weights(x - fx)
    y0 = int(fy) - 1
    x0 = int(fx) - 1
    c0 = max(x0, 0)
    c1 = min(max(x0 + 1, 0), Wp - 1)
    c2 = min(x0 + 2, Wp - 1)
    c3 = min(x0 + 3, Wp - 1)
    a0 = a1 = a2 = a3 = 0.0
    for a in range(4):
        r = min(max(y0 + a, 0), Hp - 1)
        wa = wy0 if a == 0 else wy1 if a == 1 else wy2 if a == 2 else wy3
        a0 += wa * (wx0 * coef[0, r, c0] + wx1 * coef[0, r, c1] + wx2 * coef[0, r, c2]
                    + wx3 * coef[0, r, c3])
        a1 += wa * (wx0 * coef[1, r, c0] + wx1 * coef[1, r, c1] + wx2 * coef[1, r, c2]
                    + wx3 * coef[1, r, c3])
        a2 += wa * (wx0 * coef[2, r, c0] + wx1 * coef[2, r, c1] + wx2 * coef[2, r, c2]
                    + wx3 * coef[2, r, c3])
        a3 += wa * (wx0 * coef[3, r, c0] + wx1 * coef[3, r, c1] + wx2 * coef[3, r, c2]
                    + wx3 * coef[3, r, c3])
    return a0, a1, a2, a3


# A row's points are evaluated by runs: consecutive points whose 4 x 4 neighbourhoods
# start at the same row and at the same column offset from the point's own (a smooth
# displacement crosses a whole pixel rarely) read four rows of each map at unit
# stride, which LLVM vectorises across the run's points; a point whose neighbourhood
# reaches past the padded map takes the clamped one-point path (:func:`_at4`). Four
# maps at 100 000 points of a smooth field: 3.0 -> 1.3 ms, one core; the same values
# to an ulp (the order of the sums is the one-point path's, their products fused
# where LLVM chooses).
_OUTSIDE = -(2**62)  # a row start that no run has: the point is not in one


@njit(**_FUSED)
def _row_weights(cy, cx, offset, ok, Hp, Wp, wy, wx, oy, ox):  # pragma: no cover
    """The weights ``wy``, ``wx`` (4, W) and the neighbourhoods' first row ``oy`` and
    column offset ``ox`` (W,) of one row's points ``(cy[j], cx[j]) + offset`` where
    ``ok[j]`` and the neighbourhood lies in the padded map; ``oy[j] = _OUTSIDE``
    elsewhere (a point off the map, not ok, or not finite)."""
    for j in range(cy.size):
        y = cy[j] + offset
        x = cx[j] + offset
        fy = math.floor(y)
        fx = math.floor(x)
        inside = ok[j] and fy >= 1.0 and fy <= Hp - 3.0 and fx >= 1.0 and fx <= Wp - 3.0
        wy[0, j], wy[1, j], wy[2, j], wy[3, j] = _weights(y - fy if inside else 0.0)
        wx[0, j], wx[1, j], wx[2, j], wx[3, j] = _weights(x - fx if inside else 0.0)
        oy[j] = int(fy) - 1 if inside else _OUTSIDE
        ox[j] = int(fx) - 1 - j if inside else 0


@njit(**_FUSED)
def _run(out, r0, r1, r2, r3, c, wy, wx, j0, j1):  # pragma: no cover
    """``out[j]`` for the points ``j0 <= j < j1`` of one run: the map's rows
    ``r0 .. r3`` (its neighbourhoods' four rows), the columns ``j + c .. j + c + 3``.
    Unsigned indices: numba then checks no negative index, which kept the loop
    scalar."""
    wy0, wy1, wy2, wy3 = wy[0], wy[1], wy[2], wy[3]
    wx0, wx1, wx2, wx3 = wx[0], wx[1], wx[2], wx[3]
    one, two, three = np.uint64(1), np.uint64(2), np.uint64(3)
    for jj in range(j0, j1):
        j = np.uint64(jj)
        k = np.uint64(jj + c)
        a = 0.0
        a += wy0[j] * (wx0[j] * r0[k] + wx1[j] * r0[k + one] + wx2[j] * r0[k + two]
                       + wx3[j] * r0[k + three])
        a += wy1[j] * (wx0[j] * r1[k] + wx1[j] * r1[k + one] + wx2[j] * r1[k + two]
                       + wx3[j] * r1[k + three])
        a += wy2[j] * (wx0[j] * r2[k] + wx1[j] * r2[k + one] + wx2[j] * r2[k + two]
                       + wx3[j] * r2[k + three])
        a += wy3[j] * (wx0[j] * r3[k] + wx1[j] * r3[k + one] + wx2[j] * r3[k + two]
                       + wx3[j] * r3[k + three])
        out[j] = a


@njit(**_OPTIONS)
def _row_scratch(W):  # pragma: no cover
    """The scratch of :func:`_row_values` for rows of ``W`` points: the weights ``wy``,
    ``wx`` (4, W), the runs' ``oy``, ``ox`` (W,) int64 and the values ``vals`` (4, W)."""
    return (np.empty((4, W)), np.empty((4, W)), np.empty(W, dtype=np.int64),
            np.empty(W, dtype=np.int64), np.empty((4, W)))


@njit(**_FUSED)
def _row_values(coef, offset, cy, cx, ok, vals, wy, wx, oy, ox):  # pragma: no cover
    """The four maps of ``coef`` (4, Hp, Wp) at one row's points ``(cy[j], cx[j]) +
    offset`` where ``ok[j]``, into ``vals`` (4, W): by runs (:func:`_row_weights`),
    the points off them by :func:`_at4`. ``wy``, ``wx`` (4, W), ``oy``, ``ox`` (W,)
    int64: scratch."""
    _, Hp, Wp = coef.shape
    W = cy.size
    _row_weights(cy, cx, offset, ok, Hp, Wp, wy, wx, oy, ox)
    j0 = 0
    while j0 < W:
        if oy[j0] == _OUTSIDE:
            if ok[j0]:
                a0, a1, a2, a3 = _at4(coef, cy[j0] + offset, cx[j0] + offset)
                vals[0, j0] = a0
                vals[1, j0] = a1
                vals[2, j0] = a2
                vals[3, j0] = a3
            j0 += 1
            continue
        j1 = j0 + 1
        while j1 < W and oy[j1] == oy[j0] and ox[j1] == ox[j0]:
            j1 += 1
        r = oy[j0]
        c = ox[j0]
        for p in range(4):
            m = coef[p]
            _run(vals[p], m[r], m[r + 1], m[r + 2], m[r + 3], c, wy, wx, j0, j1)
        j0 = j1


@njit(**_FUSED)
def cubic4_at(coef, offset, cy, cx, out):  # pragma: no cover
    """``out[:, i, j]``: the four maps of ``coef`` at ``(cy[i, j], cx[i, j]) + offset``.

    ``coef`` (4, Hp, Wp) float64: the prefiltered coefficients of four maps. ``cy``,
    ``cx`` (H, W): rows and columns of the points in the coordinates of the unpadded
    maps, ``offset`` the padding. ``out`` (4, H, W). As ``map_coordinates(order=3,
    mode="nearest", prefilter=False)`` on each map: a point is first clamped to the
    padded map, and the neighbours beyond its edge take the edge's coefficients.
    """
    H, W = cy.shape
    ok = np.ones(W, dtype=np.bool_)
    wy, wx, oy, ox, vals = _row_scratch(W)
    for i in range(H):
        _row_values(coef, offset, cy[i], cx[i], ok, vals, wy, wx, oy, ox)
        for p in range(4):
            for j in range(W):
                out[p, i, j] = vals[p, j]


@njit(**_FUSED)
def residual_products(coef, offset, u, ref, valid, prod, i0, i1):  # pragma: no cover
    """The products whose arguments are a step of the large-displacement fixed point's
    residuals (:func:`fixed_point_update`), on the rows ``i0 <= i < i1``.

    ``coef`` (4, Hp, Wp): the prefiltered deformed transforms ``Re Psi_1, Im Psi_1,
    Re Psi_2, Im Psi_2``; ``u`` (2, H, W) the displacement; ``ref`` (2, H, 2W) the
    reference transforms ``Psi_1, Psi_2`` as real views (real and imaginary parts side
    by side). Writes ``prod`` (4, i1 - i0, W): the imaginary and real parts of
    ``Psi_j,def(X + u) conj Psi_j,ref(X)`` for j = 1, 2, at the ``valid`` pixels (0
    elsewhere). Their arguments are taken over the block by :func:`arctan2`.
    """
    W = u.shape[2]
    cy = np.empty(W)
    cx = np.empty(W)
    wy, wx, oy, ox, vals = _row_scratch(W)
    for i in range(i0, i1):
        k = i - i0
        for j in range(W):
            cy[j] = i + u[1, i, j]
            cx[j] = j + u[0, i, j]
        _row_values(coef, offset, cy, cx, valid[i], vals, wy, wx, oy, ox)
        for j in range(W):
            v = valid[i, j]
            p0 = vals[0, j]
            p1 = vals[1, j]
            p2 = vals[2, j]
            p3 = vals[3, j]
            c0 = ref[0, i, 2 * j]
            d0 = ref[0, i, 2 * j + 1]
            c1 = ref[1, i, 2 * j]
            d1 = ref[1, i, 2 * j + 1]
            prod[0, k, j] = p1 * c0 - p0 * d0 if v else 0.0
            prod[1, k, j] = p0 * c0 + p1 * d0 if v else 0.0
            prod[2, k, j] = p3 * c1 - p2 * d1 if v else 0.0
            prod[3, k, j] = p2 * c1 + p3 * d1 if v else 0.0


@njit(**_OPTIONS)
def fixed_point_update(angles, u, two_pi_k, solve, valid, i0, i1):  # pragma: no cover
    """One step of the large-displacement fixed point on the rows ``i0 <= i < i1``,
    in place; returns ``sum du^2``.

    ``angles`` (2, i1 - i0, W): ``arg(Psi_j,def(X + u) conj Psi_j,ref(X))`` of the
    block (:func:`residual_products`); ``u`` (2, H, W) the displacement, updated at
    the ``valid`` pixels; ``two_pi_k`` = ``2 pi K`` and ``solve`` = ``-K^-1 / 2 pi``
    (2, 2). At ``X``: ``r_j = wrap(arg(...) + 2 pi k_j.u)`` and ``du = -K^-1 r / 2
    pi``, as :func:`gridstrain.kinematics._lagrangian_fixed_point` computes with numpy.
    """
    W = u.shape[2]
    two_pi = 2.0 * math.pi
    k00, k01, k10, k11 = two_pi_k[0, 0], two_pi_k[0, 1], two_pi_k[1, 0], two_pi_k[1, 1]
    s00, s01, s10, s11 = solve[0, 0], solve[0, 1], solve[1, 0], solve[1, 1]
    # a row's steps without a branch (selections: LLVM vectorises the loop, 0.76 ->
    # 0.52 ms at 250 x 400 px), their squares then added in the pixels' order (an
    # invalid pixel's 0 changes no sum): the same bits as one loop over the valid ones
    sq = np.empty(W)
    total = 0.0
    for i in range(i0, i1):
        k = i - i0
        for j in range(W):
            v = valid[i, j]
            ux = u[0, i, j]
            uy = u[1, i, j]
            r0 = angles[0, k, j] + (k00 * ux + k01 * uy)
            r1 = angles[1, k, j] + (k10 * ux + k11 * uy)
            # wrapped to (-pi, pi], as pi - mod(pi - r, 2 pi)
            t0 = math.pi - r0
            t1 = math.pi - r1
            r0 = math.pi - (t0 - two_pi * math.floor(t0 / two_pi))
            r1 = math.pi - (t1 - two_pi * math.floor(t1 / two_pi))
            dx = s00 * r0 + s01 * r1
            dy = s10 * r0 + s11 * r1
            u[0, i, j] = ux + dx if v else ux
            u[1, i, j] = uy + dy if v else uy
            sq[j] = dx * dx + dy * dy if v else 0.0
        for j in range(W):
            total += sq[j]
    return total


# arctan on [-tan(pi/8), tan(pi/8)] as t + t z R(z), z = t^2: R the polynomial of
# degree 10 that interpolates (arctan(sqrt z) / sqrt z - 1) / z at the 11 Chebyshev
# nodes of [0, tan^2(pi/8)] (computed in 60-digit arithmetic): its error is below
# 6e-18 of arctan's value there, far under an ulp; the result's error (at most 2 ulp
# over +-pi, tests/test_lagrangian_interpolation.py) comes from the octant's
# constants. glibc's atan2 takes about 20 ns a point and numpy calls it once a point
# where the CPU has no AVX-512; these lines take some 2 ns, vectorised by LLVM (the
# fixed point's two maps a step, and the start's phase difference: about 2 ms of CPU
# a step at 250 x 400 px).
_ATAN = (-0.3333333333333333, 0.1999999999999552, -0.14285714284666542,
         0.11111111015256361, -0.09090904578123903, 0.07692183190826087,
         -0.06664511447381948, 0.0585814891280221, -0.0508544973794026,
         0.03923165829558719, -0.01917688711906226)
_A0, _A1, _A2, _A3, _A4, _A5, _A6, _A7, _A8, _A9, _A10 = _ATAN
_TAN_EIGHTH = math.tan(math.pi / 8)
_QUARTER, _HALF = math.pi / 4, math.pi / 2


@njit(inline="always", **_OPTIONS)
def _atan2(y, x):  # pragma: no cover
    """``numpy.arctan2(y, x)`` to 2 ulp, branch-free: the signs of zeros, infinities
    and NaN as numpy has them."""
    ax, ay = abs(x), abs(y)
    swap = ay > ax  # a NaN leaves it False, and reaches t
    big, small = (ay, ax) if swap else (ax, ay)
    # past tan(pi/8) the ratio is turned by pi/4: (s - b) / (s + b), one division;
    # two infinities are turned to 0 (pi/4 and its octants)
    infinite = small == math.inf
    turn = infinite or small > _TAN_EIGHTH * big
    num = small - big if turn else small
    den = small + big if turn else big
    # where both are 0 the octant's constants give the signed zeros and pi
    t = 0.0 if den == 0.0 or infinite else num / den
    z = t * t
    r = ((((((((((_A10 * z + _A9) * z + _A8) * z + _A7) * z + _A6) * z + _A5) * z + _A4)
             * z + _A3) * z + _A2) * z + _A1) * z + _A0)
    a = t + t * z * r
    a = _QUARTER + a if turn else a
    a = _HALF - a if swap else a
    a = math.pi - a if math.copysign(1.0, x) < 0.0 else a
    return math.copysign(a, y)


@njit(**_OPTIONS)
def arctan2(y, x, out):  # pragma: no cover
    """``out = numpy.arctan2(y, x)`` to 2 ulp (:func:`_atan2`), for C-ordered arrays
    of one shape (``out`` may be ``y`` or ``x``)."""
    yf, xf, of = y.ravel(), x.ravel(), out.ravel()
    for i in range(of.size):
        of[i] = _atan2(yf[i], xf[i])


@njit(**_OPTIONS)
def phase_difference(ref, cur, out):  # pragma: no cover
    """``out[j] = arg(Psi_j,cur conj Psi_j,ref)`` (2, H, W), from the transforms'
    real views ``ref`` and ``cur`` (2, H, 2W): the product as numpy computes it, its
    argument by :func:`_atan2`."""
    n, H, W = out.shape
    for j in range(n):
        for i in range(H):
            for k in range(W):
                a = ref[j, i, 2 * k]
                b = ref[j, i, 2 * k + 1]
                c = cur[j, i, 2 * k]
                d = cur[j, i, 2 * k + 1]
                out[j, i, k] = _atan2(a * d - b * c, a * c + b * d)


@njit(**_OPTIONS)
def largest_step(u, field, v, K):  # pragma: no cover
    """The largest ``|K (u - field)|`` (periods along each wave vector) over the
    pixels ``v``; -1 where there is none, inf where one is not finite."""
    k00, k01, k10, k11 = K[0, 0], K[0, 1], K[1, 0], K[1, 1]
    _, H, W = u.shape
    best = -1.0
    for i in range(H):
        for j in range(W):
            if v[i, j]:
                d0 = u[0, i, j] - field[0, i, j]
                d1 = u[1, i, j] - field[1, i, j]
                a = max(abs(k00 * d0 + k01 * d1), abs(k10 * d0 + k11 * d1))
                if not a <= best:
                    best = a if a == a else math.inf
    return best


# The pole of the cubic B-spline's inverse filter, and the gain that makes the
# filter's DC response 1 (Unser 1999): scipy.ndimage's values.
_POLE = math.sqrt(3.0) - 2.0
_GAIN = (1.0 - _POLE) * (1.0 - 1.0 / _POLE)
# Terms of the causal initial sum beyond which z^i is below 1e-20: they do not change
# a float64 coefficient. The same horizon cuts the sum's wrapped part, whose terms
# z^(n + k) of a line of n > _HORIZON samples all lie below it: summed over the whole
# line, their products z^k z^n fell to subnormal numbers, whose arithmetic is some
# hundred times slower, for nothing (the prefilter of four 250 x 400 maps took 2.2
# times as long).
_HORIZON = math.ceil(math.log(1e-20) / math.log(-_POLE))


# The maps a prefilter holds (the first axis): always four, written as a constant in
# the recursions' loops so that LLVM unrolls them.
_PLANES = 4
# Rows whose recursions run in lockstep: along a row each step waits for the one
# before, and a row's four maps alone leave the core idle between them; eight rows
# give it 32 independent sums (the first half of the prefilter of four 250 x 400 maps
# 1.02 -> 0.71 ms, one core, the same bits).
_LOCKSTEP = 8


@njit(**_OPTIONS)
def prefilter_rows(src, complex_view, pad, out, i0, i1):  # pragma: no cover
    """First half of the cubic B-spline prefilter: the rows ``i0 <= i < i1`` of ``out``
    (n, Hp, Wp) filled from the maps ``src`` (n, H, W), edge-padded by ``pad``, and
    filtered along the columns' axis (each row on its own).

    With ``complex_view``, ``src`` (n / 2, H, 2W) is the real view of n / 2 complex
    maps, whose real and imaginary parts are the maps ``2c`` and ``2c + 1``. A value
    that is not finite is taken as 0. :func:`prefilter_columns` on every column after
    this on every row gives ``scipy.ndimage.spline_filter(np.pad(src[p], pad,
    mode="edge"), 3, mode="nearest")`` for each map, to rounding: along each axis the
    gain, then the causal and anticausal recursions of the pole ``z = sqrt(3) - 2``
    with the half-sample symmetric initial values that scipy uses for
    ``mode="nearest"``. Padded sides of at least 16 px (shorter ones differ from scipy
    by up to 1e-7). Rows are independent: blocks of rows may run on several threads.
    """
    nm, Hp, Wp = out.shape
    if nm != _PLANES:
        raise ValueError("the prefilter holds four maps")
    nm = _PLANES
    H, W = Hp - 2 * pad, Wp - 2 * pad
    g = _GAIN * _GAIN
    s = np.empty((_LOCKSTEP, nm))
    first = np.empty((_LOCKSTEP, nm))
    # the rows' recursions run on a block of rows laid out (rows, Wp, maps), a row's
    # four maps side by side, which LLVM vectorises; the block is then written to the
    # maps' planes
    block = np.empty((_LOCKSTEP, Wp, nm))
    for b0 in range(i0, i1, _LOCKSTEP):
        b1 = min(b0 + _LOCKSTEP, i1)
        for i in range(b0, b1):
            si = min(max(i - pad, 0), H - 1)
            row = block[i - b0]
            for j in range(Wp):
                sj = min(max(j - pad, 0), W - 1)
                for p in range(nm):
                    v = src[p // 2, si, 2 * sj + p % 2] if complex_view else src[p, si, sj]
                    # a NaN or an infinity would spread over whole rows and columns
                    row[j, p] = g * v if math.isfinite(v) else 0.0
        _recurse_rows(block, 0, b1 - b0, s, first)
        for i in range(b0, b1):  # unsigned indices: the loop vectorises
            flat = block[i - b0].ravel()
            r0, r1, r2, r3 = out[0, i], out[1, i], out[2, i], out[3, i]
            for jj in range(Wp):
                j = np.uint64(jj)
                k = np.uint64(4 * jj)
                r0[j] = flat[k]
                r1[j] = flat[k + np.uint64(1)]
                r2[j] = flat[k + np.uint64(2)]
                r3[j] = flat[k + np.uint64(3)]


@njit(**_OPTIONS)
def _recurse_rows(out, b0, b1, s, first):  # pragma: no cover
    """The two recursions along the second axis of ``out`` (rows, Wp, nm) on the rows
    ``b0 <= i < b1`` (at most :data:`_LOCKSTEP`), each row and map on its own, the rows
    in lockstep; ``s``, ``first`` (_LOCKSTEP, nm) scratch."""
    n = out.shape[1]
    nm = _PLANES
    nb = b1 - b0
    z = _POLE
    zn = z ** n
    for r in range(nb):
        for p in range(nm):
            first[r, p] = out[b0 + r, 0, p]
            s[r, p] = out[b0 + r, 0, p] + zn * out[b0 + r, n - 1, p]
    zi = z
    for k in range(1, min(n, _HORIZON)):
        for r in range(nb):
            for p in range(nm):
                s[r, p] += zi * out[b0 + r, k, p]
        zi *= z
    zi = z
    for k in range(1, min(n, _HORIZON - n)):  # the wrapped terms z^(n + k) (_HORIZON)
        for r in range(nb):
            for p in range(nm):
                s[r, p] += zi * zn * out[b0 + r, n - 1 - k, p]
        zi *= z
    for r in range(nb):
        for p in range(nm):
            out[b0 + r, 0, p] = s[r, p] * z / (1.0 - zn * zn) + first[r, p]
    for k in range(1, n):
        for r in range(nb):
            for p in range(nm):
                out[b0 + r, k, p] += z * out[b0 + r, k - 1, p]
    for r in range(nb):
        for p in range(nm):
            out[b0 + r, n - 1, p] *= z / (z - 1.0)
    for k in range(n - 2, -1, -1):
        for r in range(nb):
            for p in range(nm):
                out[b0 + r, k, p] = z * (out[b0 + r, k + 1, p] - out[b0 + r, k, p])


@njit(**_OPTIONS)
def prefilter_columns(out, j0, j1):  # pragma: no cover
    """Second half of the prefilter (see :func:`prefilter_rows`): the columns ``j0 <=
    j < j1`` of ``out`` (n, Hp, Wp), filtered along the rows' axis in place. Columns
    are independent: blocks of columns may run on several threads. The same
    recursions as :func:`_recurse_rows`, written out on the block of ``out`` itself:
    the rows' recursion on a strided 2-D view of the block gives the same bits in
    more time (benchmarks/README.md). Each map's
    rows are read at unit stride with unsigned indices (numba checks no negative
    index then, and LLVM vectorises the loops across the columns)."""
    n = out.shape[1]
    if out.shape[0] != _PLANES:
        raise ValueError("the prefilter holds four maps")
    nm = _PLANES
    z = _POLE
    zn = z ** n
    w = j1 - j0
    s = np.empty((nm, w))
    first = np.empty((nm, w))
    u0 = np.uint64(j0)
    for p in range(nm):
        top, bottom, f, sp = out[p, 0], out[p, n - 1], first[p], s[p]
        for jj in range(w):
            j = np.uint64(jj)
            f[j] = top[u0 + j]
            sp[j] = top[u0 + j] + zn * bottom[u0 + j]
    zi = z
    for k in range(1, min(n, _HORIZON)):
        for p in range(nm):
            r, sp = out[p, k], s[p]
            for jj in range(w):
                j = np.uint64(jj)
                sp[j] += zi * r[u0 + j]
        zi *= z
    zi = z
    for k in range(1, min(n, _HORIZON - n)):  # the wrapped terms z^(n + k) (_HORIZON)
        for p in range(nm):
            r, sp = out[p, n - 1 - k], s[p]
            for jj in range(w):
                j = np.uint64(jj)
                sp[j] += zi * zn * r[u0 + j]
        zi *= z
    for p in range(nm):
        top, f, sp = out[p, 0], first[p], s[p]
        for jj in range(w):
            j = np.uint64(jj)
            top[u0 + j] = sp[j] * z / (1.0 - zn * zn) + f[j]
    for k in range(1, n):
        for p in range(nm):
            r, q = out[p, k], out[p, k - 1]
            for jj in range(j0, j1):
                j = np.uint64(jj)
                r[j] += z * q[j]
    for p in range(nm):
        r = out[p, n - 1]
        for jj in range(j0, j1):
            j = np.uint64(jj)
            r[j] *= z / (z - 1.0)
    for k in range(n - 2, -1, -1):
        for p in range(nm):
            r, q = out[p, k], out[p, k + 1]
            for jj in range(j0, j1):
                j = np.uint64(jj)
                r[j] = z * (q[j] - r[j])


@njit(**_FUSED)
def lagrangian_gradient(coef, offset, u, cur_valid, box, ref_valid, d_ref, two_pi_k,
                        strain, rotation, valid, i0, i1):  # pragma: no cover
    """The exact Lagrangian displacement gradient and the pixels valid in both states.

    ``coef`` (4, Hp, Wp): the prefiltered deformed phase derivatives ``D_00, D_01,
    D_10, D_11``; ``u`` (2, H, W); ``cur_valid``, ``ref_valid`` (H, W) bool; ``d_ref``
    (2, 2, H, W) the reference's derivatives; ``two_pi_k`` = ``2 pi K``. Solves
    ``(2 pi K + D_def(X + u)) G = D_ref - D_def(X + u)`` by Cramer's rule and writes
    its small strain ``strain`` (3, H, W), ``(G_00, G_11, (G_01 + G_10) / 2)``, its
    rotation ``rotation`` (H, W), ``(G_10 - G_01) / 2``, and ``valid`` (H, W): valid in
    the reference, ``X + u`` inside the image and the bilinear interpolation of the
    deformed validity there above 0.999 (``box`` (4,) int64: rows ``box[0] <= r <
    box[1]`` and columns ``box[2] <= c < box[3]`` all valid in the deformed state, or
    an empty one: where the four neighbours lie in it the interpolation is 1, not
    computed; 3.2 -> 2.7 ms at 250 x 400 px), as
    :func:`gridstrain.kinematics._lagrangian_gradient` computes with scipy and numpy;
    ``strain`` and ``rotation`` are NaN where not ``valid`` (the measurement's value
    there: the spline is not evaluated). On the rows ``i0 <= i < i1`` only.
    """
    _, H, W = u.shape
    r0, r1, c0, c1 = box[0], box[1], box[2], box[3]
    cy = np.empty(W)
    cx = np.empty(W)
    ok = np.empty(W, dtype=np.bool_)
    wy, wx, oy, ox, vals = _row_scratch(W)
    for i in range(i0, i1):
        for j in range(W):
            y = i + u[1, i, j]
            x = j + u[0, i, j]
            cy[j] = y
            cx[j] = x
            good = ref_valid[i, j] and y >= 0.0 and y <= H - 1.0 and x >= 0.0 \
                and x <= W - 1.0
            fy = math.floor(y)
            fx = math.floor(x)
            y0 = int(fy) if good else 0  # (y, x) may be any number where not good
            x0 = int(fx) if good else 0
            if good and not (r0 <= y0 and y0 + 1 < r1 and c0 <= x0 and x0 + 1 < c1):
                ty = y - fy
                tx = x - fx
                w = 0.0
                for a in range(2):
                    for b in range(2):
                        r = y0 + a
                        c = x0 + b
                        if r < H and c < W and cur_valid[r, c]:
                            w += (ty if a else 1.0 - ty) * (tx if b else 1.0 - tx)
                good = w > 0.999
            ok[j] = good
            valid[i, j] = good
        _row_values(coef, offset, cy, cx, ok, vals, wy, wx, oy, ox)
        # every point computed, those not valid then NaN (as the measurement reports
        # them; their values are whatever the row's scratch held): no branch, which
        # LLVM vectorises
        for j in range(W):
            good = ok[j]
            d00 = vals[0, j]
            d01 = vals[1, j]
            d10 = vals[2, j]
            d11 = vals[3, j]
            a00 = two_pi_k[0, 0] + d00
            a01 = two_pi_k[0, 1] + d01
            a10 = two_pi_k[1, 0] + d10
            a11 = two_pi_k[1, 1] + d11
            b00 = d_ref[0, 0, i, j] - d00
            b01 = d_ref[0, 1, i, j] - d01
            b10 = d_ref[1, 0, i, j] - d10
            b11 = d_ref[1, 1, i, j] - d11
            rdet = 1.0 / (a00 * a11 - a01 * a10)
            g01 = (a11 * b01 - a01 * b11) * rdet
            g10 = (a00 * b10 - a10 * b00) * rdet
            strain[0, i, j] = (a11 * b00 - a01 * b10) * rdet if good else math.nan
            strain[1, i, j] = (a00 * b11 - a10 * b01) * rdet if good else math.nan
            strain[2, i, j] = 0.5 * (g01 + g10) if good else math.nan
            rotation[i, j] = 0.5 * (g10 - g01) if good else math.nan


@njit(**_OPTIONS)
def newton_start(u0, d, cur_valid, two_pi_k, m_of_d, a_med, u, i0, i1):  # pragma: no cover
    """The fixed point's start and contraction factor, in one pass.

    ``u = (2 pi K + D(X))^-1 2 pi K u0`` where ``cur_valid`` and the change differs
    from the change with the median derivatives (``a_med u0``, ``a_med = (2 pi K +
    D_med)^-1 2 pi K``) by less than a tenth of a period along both wave vectors,
    ``a_med u0`` elsewhere on ``cur_valid``, ``u0`` off it; returns the
    largest Frobenius norm over ``cur_valid`` of ``M = m_of_d D`` (``m_of_d`` =
    ``(2 pi K)^-1``), inf if one is not finite. ``u0``, ``u`` (2, H, W); ``d``
    (2, 2, H, W); as :func:`gridstrain.kinematics._newton_start` and
    :func:`gridstrain.kinematics._contraction` compute with numpy. On the rows ``i0 <=
    i < i1`` only.
    """
    W = u0.shape[2]
    two_pi = 2.0 * math.pi
    k00, k01, k10, k11 = two_pi_k[0, 0], two_pi_k[0, 1], two_pi_k[1, 0], two_pi_k[1, 1]
    n00, n01, n10, n11 = m_of_d[0, 0], m_of_d[0, 1], m_of_d[1, 0], m_of_d[1, 1]
    e00, e01, e10, e11 = a_med[0, 0], a_med[0, 1], a_med[1, 0], a_med[1, 1]
    # a row without a branch (selections: LLVM vectorises the loop, 1.2 -> 0.5 ms at
    # 250 x 400 px), its norms then reduced in the pixels' order: the same bits
    norms = np.empty(W)
    q = 0.0
    finite = True
    for i in range(i0, i1):
        for j in range(W):
            x0 = u0[0, i, j]
            y0 = u0[1, i, j]
            v = cur_valid[i, j]
            d00 = d[0, 0, i, j]
            d01 = d[0, 1, i, j]
            d10 = d[1, 0, i, j]
            d11 = d[1, 1, i, j]
            m00 = n00 * d00 + n01 * d10
            m01 = n00 * d01 + n01 * d11
            m10 = n10 * d00 + n11 * d10
            m11 = n10 * d01 + n11 * d11
            f = math.sqrt(m00 * m00 + m01 * m01 + m10 * m10 + m11 * m11)
            norms[j] = f if v else 0.0
            b0 = k00 * x0 + k01 * y0
            b1 = k10 * x0 + k11 * y0
            a00 = k00 + d00
            a01 = k01 + d01
            a10 = k10 + d10
            a11 = k11 + d11
            rdet = 1.0 / (a00 * a11 - a01 * a10)
            nx = (a11 * b0 - a01 * b1) * rdet
            ny = (a00 * b1 - a10 * b0) * rdet
            mx = e00 * x0 + e01 * y0
            my = e10 * x0 + e11 * y0
            c0 = (k00 * (nx - mx) + k01 * (ny - my)) / two_pi
            c1 = (k10 * (nx - mx) + k11 * (ny - my)) / two_pi
            keep = abs(c0) < 0.1 and abs(c1) < 0.1
            u[0, i, j] = (nx if keep else mx) if v else x0
            u[1, i, j] = (ny if keep else my) if v else y0
        for j in range(W):
            f = norms[j]
            if not math.isfinite(f):
                finite = False
            elif f > q:
                q = f
    return q if finite else math.inf


# ----------------------------------------------------------- the phase difference's turns


@njit(**_OPTIONS)
def _turned_row(wrapped, c, s, i):  # pragma: no cover
    """Row ``i`` of ``s = mod(wrapped - c + pi, 2 pi) - pi``, as numpy computes it;
    False where a value left ``[-2 pi, 4 pi)`` before the ``mod`` (a NaN, a
    ``c`` far from the map), whose row must then take numpy's ``fmod``.

    Within that interval ``np.mod(x, b)`` (C ``fmod``, moved into ``[0, b)``, +0.0 for
    an exact multiple) is ``x + b``, ``x`` or ``x - b`` (exact there), written as
    selections that the compiler vectorises: ``fmod``'s exact division took ten times
    as long as the rest of the pass."""
    W = wrapped.shape[1]
    b = 2.0 * math.pi
    inside = True
    for j in range(W):
        x = wrapped[i, j] - c
        x += math.pi
        lo = b if x < 0.0 else 0.0
        hi = b if x >= b else 0.0
        inside &= x >= -b and x < 2.0 * b
        s[i, j] = ((x + lo) - hi) - math.pi
    if inside:
        return True
    for j in range(W):
        x = wrapped[i, j] - c
        x += math.pi
        m = np.fmod(x, b)
        if m != 0.0:
            if m < 0.0:
                m += b
        else:
            m = 0.0
        s[i, j] = m - math.pi
    return False


@njit(**_OPTIONS)
def _row_jumps(s, valid, i):  # pragma: no cover
    """Whether two valid neighbours of ``s`` along row ``i``, or between rows ``i - 1``
    and ``i``, differ by pi or more (without a branch per pixel: vectorised)."""
    W = s.shape[1]
    jump = False
    for j in range(W - 1):
        jump |= valid[i, j] & valid[i, j + 1] & (abs(s[i, j + 1] - s[i, j]) >= math.pi)
    if i > 0:
        for j in range(W):
            jump |= valid[i, j] & valid[i - 1, j] & (abs(s[i, j] - s[i - 1, j]) >= math.pi)
    return jump


@njit(**_OPTIONS)
def _whole_turns_row(wrapped, s, c, valid, i):  # pragma: no cover
    """Row ``i`` of ``s`` replaced by ``wrapped`` plus the whole turns of ``s + c -
    wrapped`` (0 off ``valid``), as the numpy path rounds them."""
    two_pi = 2.0 * math.pi
    for j in range(s.shape[1]):
        if valid[i, j]:
            w = wrapped[i, j]
            x = s[i, j] + c
            x -= w
            x /= two_pi
            x = np.rint(x)
            x *= two_pi
            s[i, j] = x + w
        else:
            s[i, j] = 0.0


@njit(**_OPTIONS)
def unwrap_by_turns(wrapped, valid, c, around, s, turned=True):  # pragma: no cover
    """The shortcuts of :func:`gridstrain.kinematics._unwrap` in two passes at most,
    the same operations as its numpy path (the same bits); returns 0 or 1, the
    shortcut taken (``s`` (H, W) then the unwrapped map, 0 off ``valid``), or 2 where
    neither holds (scikit-image must run; ``s`` is scratch).

    0: ``s = mod(wrapped - c + pi, 2 pi) - pi`` shows no jump of pi or more between
    valid neighbours, and ``wrapped`` plus the whole turns of ``s + c - wrapped`` is
    returned. 1: ``around`` (H, W), when given (its first axis not empty), is finite,
    and ``wrapped`` plus the whole turns of ``around - wrapped`` shows no jump. Each
    pass stops at its first jump. Without ``turned``, the first shortcut is taken as
    failed (a call before found its jump).
    """
    H, W = wrapped.shape
    jump = not turned
    for i in range(H if turned else 0):
        _turned_row(wrapped, c, s, i)
        if _row_jumps(s, valid, i):
            jump = True
            break
    if not jump:
        for i in range(H):
            _whole_turns_row(wrapped, s, c, valid, i)
        return 0
    if around.shape[0] == 0:
        return 2
    for i in range(H):
        for j in range(W):
            if not math.isfinite(around[i, j]):
                return 2
    for i in range(H):
        s[i] = around[i]
        _whole_turns_row(wrapped, s, 0.0, valid, i)
        if _row_jumps(s, valid, i):
            return 2
    return 1


@njit(**_OPTIONS)
def turns_range(dphase, sel, g, k0, k1, kg, constant):  # pragma: no cover
    """The smallest and largest ``t = -dphase / 2 pi - (k0 g_x + k1 g_y)`` (``- kg``
    where ``constant``) over ``sel``, periods, and whether every one is finite:
    where all lie within one half-period either side of the same whole number, that
    number is the one the median of ``t`` rounds to, found without sorting.
    ``dphase``, ``sel`` (H, W); ``g`` (2, H, W), read only where not ``constant``."""
    H, W = dphase.shape
    lo = math.inf
    hi = -math.inf
    finite = True
    scale = -1.0 / (2.0 * math.pi)
    for i in range(H):
        for j in range(W):
            if sel[i, j]:
                t = dphase[i, j] * scale
                t -= kg if constant else k0 * g[0, i, j] + k1 * g[1, i, j]
                finite &= math.isfinite(t)
                lo = min(lo, t)
                hi = max(hi, t)
    return lo, hi, finite
