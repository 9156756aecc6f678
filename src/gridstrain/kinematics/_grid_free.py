"""The fringe order from what the images hold below the grid's frequency.

A printed feature as sharp as the pitch fixes the fringe order by a correlation peak
narrower than a period (:func:`~gridstrain.kinematics.coarse_displacement`). A broad
reflectance blob, a wood grain or a stain has no such peak: band-passed at the pitch
they leave nothing but the grid's residue, which correlates equally well a whole
period away. They still move with the specimen, and the phases already say where
every point went *modulo* the lattice. So the test here is a choice among whole
periods, not a search for a peak:

1. both images are low-passed by a Gaussian of one pitch (the grid's fundamental
   kept at ``exp(-2 pi^2) ~ 3e-9``), sampled every ``q ~ pitch`` px, and their
   logarithm taken (reflectance and lighting multiply: their logarithms add);
2. every sample ``X`` of the reference is compared with the deformed image at
   ``X + u(X) + t``, ``u`` the field the phases give (modulo the lattice; theirs is
   at the camera's point, taken at the material point to first order through its
   gradient) and ``t`` a candidate offset on the lattice (``m a1 + n a2``);
3. the difference's least-squares plane is removed in each of 3 x 3 tiles (lighting
   fixed to the camera, vignetting included, differs between ``X`` and ``X + u + t``
   by a plane for any quadratic profile), and what is left, summed over the tile, is
   the tile's residual ``E_t(t)``.

The right offset leaves noise; a wrong one adds the content's gradient times a
period. The decision (:func:`order_from_content`) is confident only when

- some tile is *informative*: its best offset, searched on a half-period lattice,
  is a whole-period one (content fixed to the camera, or moving otherwise than the
  grid, puts it between two) and every other whole-period offset leaves at least
  ``_MIN_RESIDUAL_RATIO`` times its residual;
- every informative tile picks the same offset, and so does the sum over the tiles,
  where the second-best whole-period offset leaves at least ``_MIN_TOTAL_RATIO``
  times the best's residual;
- that offset is not at the edge of the search.

A competitor at a lattice offset that the grid explains (its periodic residue) adds
the same residual to every offset and leaves the ratio to the content; a competitor
the content itself explains (a pattern repeating every two periods) leaves the same
residual as the best offset, and the test stays undecided. A grid with nothing else
leaves every ratio near 1: the order stays unconfirmed.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._runtime import compiled
from ..phase import Lattice

# A tile decides only if every other whole-period offset leaves this many times its
# best residual: with ~500 independent samples a tile's residual varies by ~6 % with
# the noise. On bare grids (checkerboards, lines and sines, pitch 4 to 7 px, moved up
# to 15 px, 105 pairs of 192 x 256 to 384 x 512 px) one tile in 400 reached it, and
# no pair passed the whole rule.
_MIN_RESIDUAL_RATIO = 1.5

# ... and holds this many compared samples (tiles of fewer, on small images, reached
# the ratio by chance on bare grids); the sum over all tiles must reach this ratio
# too (1.11 at most on those bare grids, 1.6 to 11 with stains or a grain).
_MIN_TILE_SAMPLES = 64
_MIN_TOTAL_RATIO = 1.25

# Tiles per side.
_TILES = 3

# Whole periods searched around the smallest displacement the phases allow (first
# stage, whole periods only), then around the best one on half periods.
_SEARCH = 5
_REFINE = 2

# Interpolated samples per call, a few megabytes of coordinates.
_CHUNK = 2**18

# Residuals within this many float64 roundings of the compared values are equal: two
# maps without content (a grid that vanishes nowhere: its clipped contrast is one
# constant in both images) leave every offset a residual of 1e-32 or exactly 0, whose
# ratios are those of rounding errors (2.6 "favoured" an offset 3 periods away on a
# rotated checkerboard). Content at the level of a 12-bit sensor's noise, low-passed by
# a pitch, leaves 1e-12 a sample and more, 1e13 times this floor.
_ROUNDING = 1e3 * np.finfo(np.float64).eps


@dataclass(frozen=True)
class ContentOrder:
    """What the content below the grid's frequency says about the fringe order.

    Attributes
    ----------
    confident : bool
    reason : str
    offset : (2,) tuple of int
        The whole periods ``(m, n)`` added to the phases' field: ``t = m a1 + n a2``.
    shift : (2,) tuple of float
        The median displacement ``(u_x, u_y)`` of the field with that offset over the
        compared samples, px: a guess that fixes the order.
    residual_ratio : float
        Over all tiles, the residual of the second-best whole-period offset over the
        best's (1 when nothing decides).
    tiles_agreeing, tiles_informative : int
        Informative tiles (see the module's notes) and those that pick ``offset``.
    favoured : bool
        Whether the sum over the tiles alone picks ``offset``: a whole-period offset,
        not at the edge of the search, whose second best leaves at least
        ``_MIN_TOTAL_RATIO`` times its residual (``confident`` asks the tiles too).
    """

    confident: bool
    reason: str
    offset: tuple[int, int]
    shift: tuple[float, float]
    residual_ratio: float
    tiles_agreeing: int = 0
    tiles_informative: int = 0
    favoured: bool = False


def grid_free(image: np.ndarray, lattice: Lattice, q: int) -> np.ndarray:
    """The logarithm of ``image`` low-passed by a Gaussian of std the longer pitch,
    sampled every ``q`` px from pixel 0 (normalised near the borders): the grid
    removed. A hole or an edge stays in it: content that moves with the specimen."""
    pitch = max(lattice.pitches)
    x = np.asarray(image, dtype=np.float64)
    low = smooth_decimate(x, pitch, q) / np.maximum(frame_weights(x.shape, pitch, q), 1e-12)
    floor = 1e-3 * max(float(np.max(low)), 1e-300)
    return np.log(np.maximum(low, floor))


def frame_weights(shape, s, q):
    """What :func:`smooth_decimate` makes of a whole frame of ones: the weights that
    normalise it near the borders, as the product of two profiles."""
    return np.outer(*(ndimage.gaussian_filter1d(np.ones(n), s, mode="constant",
                                                truncate=4.0)[::q] for n in shape))


def smooth_decimate(a, s, q):
    """``a`` smoothed by a Gaussian of std ``s`` px and sampled every ``q`` px: each
    axis filtered, then decimated, before the other.

    The same values, bit for bit, as ``scipy.ndimage.gaussian_filter1d(a, s, axis,
    mode="constant", truncate=4.0)[::q]`` along each axis, with the sums taken only
    at the samples kept (:func:`_gaussian_at`)."""
    return _gaussian_at(_gaussian_at(a, s, q, 0), s, q, 1)


def _gaussian_at(a, s, q, axis):
    """``a`` smoothed along ``axis`` by a Gaussian of std ``s`` px (zero beyond the
    border, truncated at 4 std) at every ``q``-th index from 0."""
    a = np.asarray(a)
    if q == 1 or a.dtype != np.float64:
        sl = [slice(None)] * a.ndim
        sl[axis] = slice(None, None, q)
        return ndimage.gaussian_filter1d(a, s, axis=axis, mode="constant",
                                         truncate=4.0)[tuple(sl)]
    # scipy's kernel and its order of summation for a symmetric kernel (the centre
    # tap, then each pair of taps from the outermost in), so that the sums are the
    # same bits: q times fewer of them
    r = int(4.0 * float(s) + 0.5)
    x = np.arange(-r, r + 1)
    w = np.exp(-0.5 / (s * s) * x**2)
    w = w / w.sum()
    m = -(-a.shape[axis] // q)
    pad = [(0, 0)] * a.ndim
    pad[axis] = (r, r)
    p = np.pad(a, pad)

    def tap(j):  # the padded input at j + i q, i = 0 .. m - 1
        sl = [slice(None)] * a.ndim
        sl[axis] = slice(j, j + q * (m - 1) + 1, q)
        return p[tuple(sl)]

    out = tap(r) * w[r]
    pair = np.empty_like(out)
    for t in range(r, 0, -1):
        np.add(tap(r - t), tap(r + t), out=pair)
        pair *= w[r - t]
        out += pair
    return out


# The compiled bilinear reads (gridstrain.kinematics._bilinear_kernels, the "fast"
# extra) when installed: loaded on the first comparison, never at import. False forces
# scipy's map_coordinates (what runs without numba).
_COMPILED = True


@functools.cache
def _load_kernels():
    """The module of the compiled reads (:func:`gridstrain._runtime.compiled.load`), or None."""
    return compiled.load(__package__, "._bilinear_kernels")


def bilinear(img: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.map_coordinates(img, coords, order=1, mode="nearest")`` for a
    float64 ``img`` (H, W) and ``coords`` (2, n), the same bits, by a compiled loop
    when numba is installed."""
    kern = _load_kernels() if _COMPILED else None
    if kern is None or img.dtype != np.float64:
        return ndimage.map_coordinates(img, coords, order=1, mode="nearest")
    c = np.asarray(coords, dtype=np.float64)
    out = np.empty(c.shape[1])
    kern.bilinear_at(np.ascontiguousarray(img), np.ascontiguousarray(c[0]),
                     np.ascontiguousarray(c[1]), out)
    return out


def decimation(lattice: Lattice) -> int:
    """Samples every ``q`` px: a pitch (the low-pass keeps 7e-3 at the new Nyquist
    frequency, and nothing the content holds above it)."""
    return max(1, int(min(lattice.pitches)))


def field_from_phases(z: np.ndarray, ok: np.ndarray, lattice: Lattice) -> np.ndarray:
    """The displacement (2, h, w) px at the samples, from ``z = psi_def conj(psi_ref)``
    (2, h, w) sampled there: the wrapped phase difference unwrapped over ``ok``, eq.
    (34) at the camera's point ``x`` (see :func:`order_from_content`'s ``gradient``);
    its fringe order is the one closest to zero at the median. NaN outside ``ok``."""
    from skimage.restoration import unwrap_phase

    dphase = np.stack([unwrap_phase(np.ma.masked_array(np.angle(z[j]), ~ok)).filled(0.0)
                       for j in range(2)])
    K = lattice.K
    u0 = -np.tensordot(np.linalg.inv(K), dphase, axes=1) / (2 * np.pi)
    n = np.rint(K @ np.median(u0[:, ok], axis=1))
    u0 -= np.linalg.solve(K, n)[:, None, None]
    u0[:, ~ok] = np.nan
    return u0


def gradient(u: np.ndarray, q: int) -> np.ndarray:
    """(2, 2, h, w) ``du_i/dx_j`` of a field (2, h, w) sampled every ``q`` px (central
    differences; NaN next to a NaN)."""
    return np.stack([np.stack(np.gradient(c, q)[::-1]) for c in u])


def largest_region(ok: np.ndarray) -> np.ndarray:
    """The largest connected region of ``ok``: regions apart may each be whole periods
    off the others, and the test takes one offset for all it compares."""
    labels, n = ndimage.label(ok)
    if n <= 1:
        return ok
    sizes = np.bincount(labels.ravel())[1:]
    return labels == 1 + int(np.argmax(sizes))


class _Search:
    """What :func:`order_from_content` compares: each reference sample's image in the
    deformed grid-free image (``cx``, ``cy``, samples) through ``(I + G)``, and the
    residuals of the tiles' content at offsets of whole or half periods."""

    def __init__(self, ref_gf, cur_gf, u, ok, lattice: Lattice, q: int, gradient):
        self.ref_gf, self.cur_gf, self.q = ref_gf, cur_gf, q
        self.h, self.w = h, w = ref_gf.shape
        self.P = P = lattice.periods
        self.period = float(np.max(np.hypot(*P))) / q  # samples
        self.yy, self.xx = yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        if gradient is None:
            gradient = np.zeros((2, 2, 1, 1))
        self.ok = largest_region(ok & np.all(np.isfinite(u), axis=0)
                                 & np.all(np.isfinite(gradient), axis=(0, 1)))
        self.M = M = np.eye(2)[:, :, None, None] + gradient  # (I + G) at each sample
        ux = M[0, 0] * u[0] + M[0, 1] * u[1]
        uy = M[1, 0] * u[0] + M[1, 1] * u[1]
        self.cx, self.cy = (xx + ux / q), (yy + uy / q)

    def compared(self, centre, periods, step=1):
        """The samples (every ``step``-th along each axis) whose images at every
        offset searched lie inside the deformed image, and their tiles."""
        cx, cy = self.cx, self.cy
        H2, W2 = self.cur_gf.shape
        t = self.P @ np.asarray(centre, dtype=float) / self.q
        reach = (periods + 1) * self.period
        with np.errstate(invalid="ignore"):
            s = self.ok & (cx + t[0] >= reach) & (cx + t[0] <= W2 - 1 - reach) \
                & (cy + t[1] >= reach) & (cy + t[1] <= H2 - 1 - reach)
        if step > 1:
            s &= (self.yy % step == 0) & (self.xx % step == 0)
        return s, _Tiles(self.xx[s], self.yy[s])

    def energies(self, sel, tiles, offsets):
        """The tiles' residuals (n, tiles) at the ``offsets`` (n, 2), in periods."""
        base = np.stack([self.cy[sel], self.cx[sel]])[:, tiles.order]
        ref = self.ref_gf[sel][tiles.order]
        # (I + G) at the samples, rows as (y, x) and columns as (x, y)
        m = np.broadcast_to(self.M, (2, 2, self.h, self.w))
        Ms = np.stack([[m[1, 0][sel], m[1, 1][sel]],
                       [m[0, 0][sel], m[0, 1][sel]]])[:, :, tiles.order]
        shifts = offsets @ self.P.T / self.q  # (n, 2) as (x, y), samples
        out = np.empty((len(offsets), tiles.n))
        per = max(1, _CHUNK // base.shape[1])
        for i0 in range(0, len(offsets), per):
            t = shifts[i0:i0 + per]
            coords = base[:, None, :] + np.einsum("abs,nb->ans", Ms, t)
            d = bilinear(self.cur_gf, coords.reshape(2, -1)).reshape(len(t), -1)
            d -= ref
            out[i0:i0 + per] = tiles.residuals(d)
        return out


def order_from_content(ref_gf: np.ndarray, cur_gf: np.ndarray, u: np.ndarray,
                       ok: np.ndarray, lattice: Lattice, q: int, *,
                       around=(0, 0), gradient=None) -> ContentOrder:
    """Choose the whole periods to add to the field ``u`` from the grid-free images.

    Parameters
    ----------
    ref_gf, cur_gf : (h, w) and (h', w') ndarray
        :func:`grid_free` of the reference and of the deformed image.
    u : (2, h, w) ndarray
        The displacement at the reference's samples (pixel ``(q i, q j)``), px, known
        modulo the lattice.
    ok : (h, w) bool ndarray
        Samples where ``u`` and the reference hold.
    lattice : Lattice
    q : int
        The samples' spacing, px.
    around : (2,) int
        The whole periods the search is centred on.
    gradient : (2, 2, h, w) ndarray, optional
        ``du_i/dx_j`` when ``u`` is the displacement at the camera's point ``x``
        rather than at the material point ``X`` (the phases' field): the point ``X``
        is then seen at ``x = X + t + u(x)``, to first order ``X + (I + G)(u(X) +
        t)`` (at 10 % strain and 11 px, 0.1 px from the exact point).

    Returns
    -------
    ContentOrder
    """
    search = _Search(ref_gf, cur_gf, u, ok, lattice, q, gradient)
    ok, P, compared, energies = search.ok, search.P, search.compared, search.energies
    none = ContentOrder(False, "too few samples of the images' content to compare",
                        tuple(int(v) for v in around), (math.nan, math.nan), 1.0)
    # whole periods first, around the given centre, as far as the images allow (half
    # the samples kept at least); then half periods near the best
    n_ok = int(ok.sum())
    # every second sample along each axis where the tiles stay large (the one-pitch
    # low-pass leaves neighbours correlated at 0.78, those two apart at 0.37)
    step = 2 if n_ok >= 4 * _TILES**2 * 4 * _MIN_TILE_SAMPLES else 1
    for reach in range(_SEARCH, _REFINE - 1, -1):
        sel = compared(around, reach, step)[0]
        if step**2 * sel.sum() >= n_ok / 2:
            break
    sel, tiles = compared(around, reach, step)
    if sel.sum() < 4 * _TILES**2:
        return none
    a = np.arange(-reach, reach + 1)
    whole = np.stack(np.meshgrid(a, a, indexing="ij"), -1).reshape(-1, 2) + np.asarray(around)
    e = energies(sel, tiles, whole.astype(float)).sum(axis=1)
    centre = whole[int(np.argmin(e))]
    at_edge = bool(np.any(np.abs(centre - np.asarray(around)) >= reach))
    sel, tiles = compared(centre, _REFINE, step)
    if sel.sum() < 4 * _TILES**2:
        return none
    b = np.arange(-2 * _REFINE, 2 * _REFINE + 1) / 2
    half = np.stack(np.meshgrid(b, b, indexing="ij"), -1).reshape(-1, 2) + centre
    # content that the maps do not hold decides nothing
    E = tiles.floored(energies(sel, tiles, half), np.abs(ref_gf[sel]).max(), cur_gf)
    integer = np.all(half == np.rint(half), axis=1)
    edge = np.any(np.abs(half - centre) >= _REFINE, axis=1)

    def verdict(col):
        """(best index, ratio of the second-best whole offset, best is whole)."""
        j = int(np.argmin(col))
        others = integer.copy()
        others[j] = False
        ratio = float(np.min(col[others]) / max(col[j], 1e-300))
        return j, ratio, bool(integer[j])

    j, ratio, whole_best = verdict(E.sum(axis=1))
    votes = [verdict(E[:, k]) for k in range(tiles.n)
             if tiles.size(k) >= _MIN_TILE_SAMPLES]
    informative = [v for v in votes if v[1] >= _MIN_RESIDUAL_RATIO]
    agree = sum(v[0] == j and v[2] for v in informative)
    offset = tuple(int(v) for v in np.rint(half[j]))
    field = u[:, sel] + (P @ np.rint(half[j]))[:, None]
    shift = tuple(float(np.median(c)) for c in field)
    counts = f"{agree} of {len(informative)} informative tiles of {tiles.n} agree"
    favoured = bool(whole_best and ratio >= _MIN_TOTAL_RATIO and not (edge[j] or at_edge))
    if not informative:
        why = (f"no tile's content decides (ratio of residuals {ratio:.2f} over all; "
               f"each tile's below {_MIN_RESIDUAL_RATIO}): nothing but the grid moves "
               "with the specimen")
    elif not whole_best:
        why = ("the content matches best half a period from every offset the phases "
               "allow: it is fixed to the camera or does not move with the grid")
    elif agree < len(informative):
        why = f"the tiles disagree ({counts})"
    elif ratio < _MIN_TOTAL_RATIO:
        why = (f"over all tiles the ratio of residuals is {ratio:.2f} < "
               f"{_MIN_TOTAL_RATIO} ({counts})")
    elif edge[j] or at_edge:
        why = "the best offset lies at the edge of the search"
    else:
        return ContentOrder(True, f"the content below the grid's frequency: {counts}, "
                            f"ratio of residuals {ratio:.2f}", offset, shift, ratio, agree,
                            len(informative), favoured)
    return ContentOrder(False, why, offset, shift, ratio, agree, len(informative), favoured)


class _Tiles:
    """The samples split into ``_TILES`` x ``_TILES`` tiles over their bounding box,
    each with an orthonormal basis of the planes over its samples; ``order`` sorts
    the samples tile by tile."""

    def __init__(self, x: np.ndarray, y: np.ndarray):
        def band(v):
            lo, hi = float(v.min()), float(v.max()) + 1e-9
            return np.minimum(((v - lo) / (hi - lo) * _TILES).astype(int), _TILES - 1)

        self.spans, self.basis = [], []
        self.order = np.arange(0)
        self.n = 0
        if x.size < 4:
            return
        tid = band(y) * _TILES + band(x)
        self.order = np.argsort(tid, kind="stable")
        bounds = np.searchsorted(tid[self.order], np.arange(_TILES**2 + 1))
        keep = []
        for k in range(_TILES**2):
            a, b = int(bounds[k]), int(bounds[k + 1])
            if b - a < 4:
                continue
            s = self.order[a:b]
            A = np.stack([np.ones(b - a), x[s] - x[s].mean(), y[s] - y[s].mean()], 1)
            self.spans.append((len(keep), a, b))
            self.basis.append(np.linalg.qr(A)[0])
            keep.append(s)
        self.order = np.concatenate(keep) if keep else np.arange(0)
        # the spans re-read in the kept order
        at = 0
        for i, (_, a, b) in enumerate(self.spans):
            self.spans[i] = (at, at + b - a)
            at += b - a
        self.n = len(self.spans)

    def size(self, k: int) -> int:
        """Samples in tile ``k``."""
        a, b = self.spans[k]
        return b - a

    def floored(self, E: np.ndarray, largest: float, other: np.ndarray) -> np.ndarray:
        """Residuals ``E`` (n, tiles) floored at the rounding (``_ROUNDING``) of their
        samples' values: at most ``largest`` or those of the map ``other``."""
        scale = max(float(largest), float(np.max(np.abs(other))))
        sizes = np.array([self.size(k) for k in range(self.n)], dtype=np.float64)
        return np.maximum(E, 0.0) + sizes * (_ROUNDING * scale) ** 2

    def residuals(self, d: np.ndarray) -> np.ndarray:
        """Per row of ``d`` (n, samples in ``order``) and tile, the sum of squares
        less the least-squares plane's."""
        out = np.empty((d.shape[0], self.n))
        for k, ((a, b), Q) in enumerate(zip(self.spans, self.basis, strict=True)):
            v = d[:, a:b]
            c = v @ Q
            out[:, k] = np.einsum("ij,ij->i", v, v) - np.einsum("ij,ij->i", c, c)
        return out
