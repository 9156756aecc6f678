"""The transform up to the specimen's edges: the grid continued beyond them by its own
demodulated maps, then transformed whole (:func:`transform_to_edges`).

Near an edge the Gaussian window is cut: the mean grey level and the conjugate carrier
leak into ``Psi`` and the strain is biased by up to 4e-3 at the edge
(:mod:`gridstrain.phase.window`, ``DEFAULT_MARGIN``). Here the pixels beyond the edge
(outside the mask, and a band of ``margin`` sigmas beyond the frame) are filled, before
the window, with the grid that the specimen's own maps predict there. At each outside
pixel ``q``, from the nearest *trusted* pixel ``t`` (``depth`` sigmas inside the edge)
along ``n = (q - t) / |q - t|``, ``d = |q - t|``:

    phi_j(q) = [arg Psi_j(t) - sigma^2 / 2 lap phi_j(t)] + grad phi_j(t) . n d
               + 1/2 d^2 d2phi_j/dn2(t),
    v(q) = a(t) + sum_j 2 |Psi_j(t)| cos(2 pi k_j . q + phi_j(q)),

the phase continued to second order along the normal (its curvature from the phase
derivative at ``t`` and at the trusted pixel ``depth`` sigmas farther in), the
modulus and the mean grey level ``a`` (the window's mean of the image) held
constant. ``arg Psi`` of a curved phase is offset by ``sigma^2 / 2`` times its
Laplacian (a Gaussian window over a chirp): removed, so that the continued grid
joins the specimen's without a step. Then the extended image is transformed without
a mask. The maps the continuation is drawn from are those of the previous transform:
:data:`EDGE_PASSES` passes reach the fixed point, where the continuation is that of
the extended transform's own maps (measured: 1e-7 strain from pass 8 on).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import ndimage

from .._stats import median
from .._validation import as_image, check_mask, check_type
from ._maps import PhaseMaps, finite_derivatives
from ._transform import _wft
from ._validity import _region
from .lattice import Lattice
from .window import Window

__all__ = [
    "EDGE_DEPTH",
    "EDGE_HARMONIC_SPREAD",
    "EDGE_PASSES",
    "edge_harmonic_bias",
    "edge_noise_gain",
    "edge_pixels",
    "partly_covered",
    "transform_to_edges",
]

#: Depth, in window standard deviations, of the trusted pixels the continuation starts
#: from. Closer to the edge their maps are themselves the continuation's (the window
#: straddles it); deeper, the Taylor expansion reaches farther (its error grows as the
#: cube of the distance for a quadratic strain).
EDGE_DEPTH = 2.0
#: Passes of continuation and transform: the first starts from the masked transform,
#: whose maps at ``EDGE_DEPTH`` sigmas are biased by ~1e-2 rad; each pass divides the
#: error by the weight of the window beyond the edge seen from the trusted pixels
#: (about 6: 16 % of a Gaussian lies beyond one sigma).
EDGE_PASSES = 8
#: A run of the mask's outermost pixels whose grid shows at less than this fraction of
#: the contrast a few pixels inside (and significantly so) is taken as only partly on
#: the specimen (:func:`partly_covered`). Any such pixel left in biases the edge's strain
#: by ~1e-2 (a cosine print, pitch 5 px, sigma 5 px: the outermost row 10 % to 80 %
#: uncovered, 7e-3 to 1.2e-2); a print's own row-to-row contrast varies by under 1 %.
EDGE_COVERAGE = 0.95
#: The largest over the smallest of one image's strain bias in the edge band from the
#: print's harmonics, over the grid's position against the edge (six positions a pitch
#: apart, noise-free prints at sigma = pitch = 5 px: cos^3, sign(cos) |cos|^(1/3), a
#: square profile, cos plus 20 % of its 2nd or 3rd harmonic: 2.6 to 3.1). The bias
#: :func:`edge_harmonic_bias` sees at one position is scaled by it to bound any other.
EDGE_HARMONIC_SPREAD = 3.0
# The depths, px, of the layer the outermost pixels' contrast is compared with.
_INNER_LAYER = (4.0, 6.0)
# Runs of outermost pixels shorter than this many pitches are not judged alone.
_MIN_RUN_PITCHES = 2.0


def edge_pixels(mask, window: Window) -> np.ndarray:
    """The pixels of ``mask`` within the window's band (``margin * sigma`` px) of its
    edges or of the frame's border: those that only :func:`transform_to_edges`
    measures.

    Parameters
    ----------
    mask : (H, W) bool array_like
        The specimen (:mod:`gridstrain.conventions`, Masks).
    window : Window

    Returns
    -------
    (H, W) bool ndarray
    """
    check_type(window, "window", Window)
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask must be a 2-D boolean array, got shape {m.shape}")
    interior = _region(m, bool(m.all()), window.band)[0]
    return m & ~interior


def transform_to_edges(image, lattice: Lattice, window: Window, *, mask=None,
                       extend: int = 0, passes: int = EDGE_PASSES,
                       depth: float = EDGE_DEPTH) -> PhaseMaps:
    """The windowed Fourier transform of ``image`` valid up to the edges of ``mask``
    and of the frame, the grid continued beyond them by its own maps.

    Parameters
    ----------
    image : (H, W) array_like
        Grid image, grey levels (float64 computation; float32 kept float32).
    lattice : Lattice
    window : Window
        ``sigma``, ``margin`` (the band beyond the edges that is filled, px =
        ``margin * sigma``) and ``min_modulus``.
    mask : (H, W) bool array_like, optional
        True on the specimen. Its outermost pixels that show the grid in part (a
        mask drawn at the specimen's edge, or up to two pixels beyond it) are found
        (:func:`partly_covered`) and continued over as outside; their maps are the
        continuation's.
    extend : int
        Pixels beyond ``mask`` also valid, whose maps are partly the continuation's:
        for an image whose specimen's edge is known to a few pixels only (a state's,
        found in the image), ``mask`` is drawn that far inside it and the maps reach
        its real edge.
    passes : int
        Continuations and transforms (default :data:`EDGE_PASSES`).
    depth : float
        Depth of the trusted pixels, sigmas (default :data:`EDGE_DEPTH`).

    Returns
    -------
    PhaseMaps
        ``(H, W)`` maps; ``valid`` where ``mask`` is (and ``extend`` px beyond) and
        both moduli reach ``min_modulus`` times their median over the mask, up to the
        edges.

    Notes
    -----
    Bias. The continuation is exact for a phase quadratic along the normal over its
    reach (``depth`` sigmas inside, ``margin`` sigmas outside), that is for a strain
    uniform or linear in space: 1e-7 strain at the edge pixels on a noise-free grid
    (tests/test_edges.py), against 4e-3 for the masked transform. Its error is the
    displacement's remainder ``du(q) = u_cont(q) - u(q)``; to first order in the
    phase, the strain's error at ``x0`` is the window's derivative of it,
    ``sum_q g(q - x0) (q - x0) / sigma^2 du(q)`` (along the normal), the maps at the
    trusted pixels holding that error too (a fixed point). For a strain quadratic
    along the normal (``eps''`` its second derivative) the continuation misses the
    displacement's cubic term: with the window's own ``sigma^2 eps'' / 2`` that every
    pixel has, the bias is ``-4.1 sigma^2 eps''`` at the edge pixel,
    ``-1.1 sigma^2 eps''`` one sigma inside and ``+0.26 sigma^2 eps''`` two sigmas
    inside (sigma = pitch, ``depth`` = 2; tests/test_edges.py checks the direct sum
    against the transform to 10 %).

    Noise. Fewer of the window's pixels are measured and the continuation repeats the
    trusted pixels' noise, amplified by its derivatives: the std of the strain along
    the normal is up to 2.6 times the interior's at the edge pixel, 1.5 times one
    sigma inside, 1 beyond two; along the edge, 1.6 times; the displacement's up to
    2.2 times (:func:`edge_noise_gain` gives the factors, propagated through this
    estimator).

    The image's harmonics (a square profile, a checkerboard's cross terms) are not
    continued: a grid with strong harmonics keeps part of the cut window's bias in
    the band, which :func:`edge_harmonic_bias` measures on the image (a cos^3 print
    at pitch 5 px: one image's 2e-3). A mask's outermost pixels that show the grid
    in part would put the background into the continuation (two-thirds covered:
    1.2e-2 strain in the band, a uniform strain 1e-3); they are continued over
    (:func:`partly_covered`), up to :data:`_MAX_LAYERS` layers, and the band is then
    exact again (4e-8).
    """
    check_type(lattice, "lattice", Lattice)
    check_type(window, "window", Window)
    img = as_image(image)
    m = check_mask(mask, img.shape)
    if isinstance(passes, bool) or not isinstance(passes, int) or passes < 1:
        raise ValueError(f"passes must be an integer >= 1, got {passes!r}")
    if isinstance(extend, bool) or not isinstance(extend, int) or extend < 0:
        raise ValueError(f"extend must be an integer >= 0, got {extend!r}")
    used = m
    pm = _continued(img, lattice, window, used, passes, depth)
    # the mask's outermost pixels that only partly show the grid are continued over,
    # as outside: one layer at a time (a mask drawn a pixel or two beyond the edge)
    for _ in range(_MAX_LAYERS):
        if used.all():
            break
        part = partly_covered(img, pm, used)
        if not part.any():
            break
        used = used & ~part
        pm = _continued(img, lattice, window, used, passes, depth)
    psi, dphi, sigma = pm.psi, pm.dphi, window.sigma
    valid = ndimage.binary_dilation(m, iterations=extend) if extend and not m.all() \
        else m.copy()
    if valid.any():
        for j in range(2):
            mod = np.abs(psi[j])
            valid &= mod >= window.min_modulus * median(mod[m])
    return finite_derivatives(PhaseMaps(psi=psi, dphi=dphi, valid=valid, lattice=lattice,
                                        sigma=sigma))


# Layers of partly covered pixels taken off at most (a mask drawn up to 2 px beyond
# the specimen's edge, and the partly covered pixel inside it).
_MAX_LAYERS = 3


def _continued(img, lattice: Lattice, window: Window, m, passes: int, depth: float):
    """The padded continuation and transform of :func:`transform_to_edges`, its maps
    cut back to the frame (``valid`` not yet set)."""
    sigma = window.sigma
    H, W = img.shape
    P = math.ceil(window.band) + 1
    big = np.zeros((H + 2 * P, W + 2 * P), dtype=img.dtype)
    big[P:P + H, P:P + W] = img
    spec = np.zeros(big.shape, dtype=bool)
    spec[P:P + H, P:P + W] = m
    # the first maps: the masked transform, biased near the edges
    pm = _wft(big, lattice, mask=spec, derivatives="exact", checked=True,
              **window.options())
    trusted = ndimage.distance_transform_edt(np.pad(spec, 1))[1:-1, 1:-1] > depth * sigma
    if not trusted.any():
        raise ValueError(f"mask: no pixel lies {depth:g} sigmas ({depth * sigma:.3g} px) "
                         "inside the specimen's edges to continue the grid from")
    outside = ~spec
    # the nearest trusted pixel of every pixel, and the offset to it
    _, (ti, tj) = ndimage.distance_transform_edt(~trusted, return_indices=True)
    qi, qj = np.nonzero(outside)
    si, sj = ti[qi, qj], tj[qi, qj]
    dy = (qi - si).astype(np.float64)
    dx = (qj - sj).astype(np.float64)
    # the transform of the padded frame has its carrier at the padded coordinates
    X, Y = qj.astype(np.float64), qi.astype(np.float64)
    # the second trusted pixel, ``depth`` farther inside along the same normal: the
    # phase's curvature along the normal from the two derivatives' difference
    dist = np.hypot(dx, dy)
    nx_, ny_ = dx / np.maximum(dist, 1e-12), dy / np.maximum(dist, 1e-12)
    base = depth * sigma
    ui = np.rint(si - base * ny_).astype(np.intp)
    uj = np.rint(sj - base * nx_).astype(np.intp)
    inside = (ui >= 0) & (ui < big.shape[0]) & (uj >= 0) & (uj < big.shape[1])
    ui, uj = np.where(inside, ui, si), np.where(inside, uj, sj)
    second = inside & trusted[ui, uj] & (dist > 0)
    step = np.hypot(si - ui, sj - uj).astype(np.float64)
    step[~second] = 1.0
    K = np.array(lattice.K, dtype=np.float64)
    fill = big.astype(np.float64)
    for k in range(passes):
        # the mean grey level under the window: over the specimen at first, then over
        # the whole continued image (a cut window would let the carriers leak into it)
        mean = (_local_mean(big, spec, sigma) if k == 0 else
                ndimage.gaussian_filter(fill, sigma, mode="constant"))
        values = mean[si, sj]
        for j in range(2):
            psi = pm.psi[j]
            g = pm.dphi[j].astype(np.float64)
            lap = _laplacian(g, sigma)
            phi = (np.angle(psi[si, sj]) - 0.5 * sigma**2 * lap[si, sj]
                   + g[0][si, sj] * dx + g[1][si, sj] * dy)
            # d^2 phi / dn^2 from the derivative along n at the two trusted pixels
            curv = ((g[0][si, sj] - g[0][ui, uj]) * nx_
                    + (g[1][si, sj] - g[1][ui, uj]) * ny_) / step
            phi += np.where(second, 0.5 * curv * dist**2, 0.0)
            carrier = 2 * math.pi * (K[j, 0] * X + K[j, 1] * Y)
            values += 2 * np.abs(psi[si, sj]) * np.cos(carrier + phi)
        fill[qi, qj] = values
        pm = _wft(fill.astype(img.dtype), lattice, mask=None, derivatives="exact",
                  checked=True, **window.options())
    inner = (slice(P, P + H), slice(P, P + W))
    # Psi at the frame's own coordinates (conventions: the absolute carrier)
    shift = np.exp(2j * math.pi * P * (K[:, 0] + K[:, 1])).astype(pm.psi.dtype)
    psi = pm.psi[(slice(None), *inner)] * shift[:, None, None]
    dphi = np.ascontiguousarray(pm.dphi[(slice(None), slice(None), *inner)])
    return PhaseMaps(psi=psi, dphi=dphi, valid=m.copy(), lattice=lattice, sigma=sigma)


def partly_covered(image, maps: PhaseMaps, mask) -> np.ndarray:
    """The mask's outermost pixels that show the grid only in part: the specimen's
    edge crosses them (a mask drawn at the edge, or beyond it).

    Parameters
    ----------
    image : (H, W) array_like
        Grid image, grey levels.
    maps : PhaseMaps
        Its maps, valid up to the edges (:func:`transform_to_edges`).
    mask : (H, W) bool array_like
        The specimen.

    Returns
    -------
    (H, W) bool ndarray
        True on the runs of outermost pixels taken as partly covered.

    Notes
    -----
    The maps predict the grid at each pixel, ``sum_j 2 Re(Psi_j e^{2 pi i k_j . x})``
    about the mean grey level. A pixel a fraction ``f`` of whose area shows the grid
    (the rest the background) shows ``f`` times that grid plus a constant. The
    outermost pixels (those beside a pixel off the mask) are grouped in runs along
    each side (by the direction to the nearest pixel off the mask) and the image is
    regressed, with an intercept, on the prediction over each run: its slope is the
    run's share of the grid, compared with the slope over the pixels 4 to 6 px
    inside (:data:`EDGE_COVERAGE`; a drop within three of its standard errors, from
    the regression's residual, is not taken). Harmonics of the print along a run are
    orthogonal to the fundamental and add to the residual only; those across it are
    constant along it and go to the intercept.
    """
    img = as_image(image).astype(np.float64)
    m = check_mask(mask, img.shape)
    H, W = img.shape
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    K = np.array(maps.lattice.K, dtype=np.float64)
    pred = sum(2 * np.real(maps.psi[j] * np.exp(2j * math.pi * (K[j, 0] * x + K[j, 1] * y)))
               for j in range(2))
    dist, (oi, oj) = ndimage.distance_transform_edt(np.pad(m, 1), return_indices=True)
    dist, oi, oj = dist[1:-1, 1:-1], oi[1:-1, 1:-1] - 1, oj[1:-1, 1:-1] - 1
    out = np.zeros_like(m)
    inner = m & (dist >= _INNER_LAYER[0]) & (dist <= _INNER_LAYER[1])
    ref = _slope(img[inner], pred[inner])
    if ref is None or ref[0] <= 0:
        return out
    edge = m & (dist == 1)
    di, dj = oi - y, oj - x
    side = np.where(np.abs(dj) >= np.abs(di), np.where(dj > 0, 1, 2), np.where(di > 0, 3, 4))
    min_run = _MIN_RUN_PITCHES * maps.lattice.pitch
    for s in (1, 2, 3, 4):
        runs, n = ndimage.label(edge & (side == s), structure=np.ones((3, 3)))
        for r in range(1, n + 1):
            sel = runs == r
            if sel.sum() < min_run:
                continue
            fit = _slope(img[sel], pred[sel])
            if fit is None:
                continue
            share, se = fit[0] / ref[0], fit[1] / ref[0]
            if share < EDGE_COVERAGE and 1 - share > 3 * se:
                out |= sel
    return out


def _slope(v: np.ndarray, p: np.ndarray):
    """``(slope, its standard error)`` of ``v`` regressed on ``p`` with an intercept,
    or None where ``p`` does not vary."""
    p = p - p.mean()
    ss = float(np.sum(p * p))
    if v.size < 3 or ss <= 0:
        return None
    b = float(np.sum(p * (v - v.mean()))) / ss
    res = v - v.mean() - b * p
    return b, math.sqrt(float(np.sum(res * res)) / (v.size - 2) / ss)


def _laplacian(g: np.ndarray, sigma: float) -> np.ndarray:
    """The phase's Laplacian from its derivatives ``g`` (2, H, W), by central
    differences over ``2 round(sigma)`` px (zero where they leave the frame)."""
    k = max(1, round(sigma))
    out = np.zeros(g.shape[1:])
    out[:, k:-k] += (g[0][:, 2 * k:] - g[0][:, :-2 * k]) / (2 * k)
    out[k:-k, :] += (g[1][2 * k:, :] - g[1][:-2 * k, :]) / (2 * k)
    return out


def _local_mean(image: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """The mean grey level of the specimen under the window: the Gaussian average of
    ``image`` over ``mask`` (normalised by the window's weight on it)."""
    w = ndimage.gaussian_filter(mask.astype(np.float64), sigma, mode="constant")
    s = ndimage.gaussian_filter(np.where(mask, image, 0.0).astype(np.float64), sigma,
                                mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(w > 0, s / np.where(w > 0, w, 1.0), 0.0)


def edge_noise_gain(mask, lattice: Lattice, window: Window) -> tuple[np.ndarray, np.ndarray]:
    """How much noisier :func:`transform_to_edges`'s maps are at each pixel of ``mask``
    than in the interior: the factors on the displacement's and the strain's std.

    Parameters
    ----------
    mask : (H, W) bool array_like
        The specimen.
    lattice : Lattice
    window : Window

    Returns
    -------
    u_gain : (2, H, W) float ndarray
        Factor on the std of ``(u_x, u_y)``; 1 farther than the band from every edge.
    strain_gain : (3, H, W) float ndarray
        Factor on the std of ``(e_xx, e_yy, e_xy)``.

    Notes
    -----
    Propagated through the estimator itself, not sampled: for white noise, the
    variance of a map at a pixel is the noise variance times the sum over the image of
    the squared response of that map to a unit grey level at each pixel (the
    estimator linearised about a noise-free grid). Along a straight edge the response
    depends only on the distance to it: one perturbed transform per distance, on a
    strip of the lattice's own cosine grid whose first column is the edge, gives the
    profile (:func:`_gain_profiles`, computed once per lattice and window). A pixel
    whose row meets an edge at ``dx`` px and whose column meets one at ``dy`` px has
    the two excess variances added, ``gain^2 = 1 + (gx(dx)^2 - 1) + (gy(dy)^2 - 1)``,
    exact along one straight edge and an approximation at a corner, where the two
    continuations are not independent.
    """
    check_type(lattice, "lattice", Lattice)
    check_type(window, "window", Window)
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask must be a 2-D boolean array, got shape {m.shape}")
    prof = _gain_profiles(tuple(map(float, lattice.k1)), tuple(map(float, lattice.k2)),
                          window)
    padded = np.pad(m, 1, constant_values=False)
    # the distance to the nearest pixel off the specimen along the row, and the column
    # (a sampling that makes the other axis far away)
    far = 4.0 * (sum(m.shape) + 2)
    dx = ndimage.distance_transform_edt(padded, sampling=(far, 1.0))[1:-1, 1:-1] - 1
    dy = ndimage.distance_transform_edt(padded, sampling=(1.0, far))[1:-1, 1:-1] - 1
    n = prof.shape[-1]
    ix = np.clip(np.rint(dx), 0, n - 1).astype(np.intp)
    iy = np.clip(np.rint(dy), 0, n - 1).astype(np.intp)
    var = prof[0][:, ix] ** 2 + prof[1][:, iy] ** 2 - 1.0  # (5, H, W)
    gain = np.sqrt(np.maximum(var, 0.0))
    gain[:, ~m] = 1.0
    return gain[:2], gain[2:]


# The probes of the noise's propagation (:func:`_gain_profiles`): each gives every
# pixel's variance without bias. A strip of 60 sigmas along the edge, its two edges
# and 8 probes average about 250 independent windows per distance to the edge: the
# variance to 9 %, the std to 4-5 % (tests/test_edges.py checks it against the scatter
# over noise draws).
_PROBES = 8
_STRIP_SIGMAS = 60


@functools.lru_cache(maxsize=8)
def _gain_profiles(k1: tuple, k2: tuple, window: Window) -> np.ndarray:
    """``(2 normals, 5 maps, n)``: the std of ``(u_x, u_y, e_xx, e_yy, e_xy)`` at
    ``0 .. n - 1`` px from an edge whose normal is x (first) or y, over the
    interior's, for :func:`transform_to_edges`.

    The estimator is linearised about a noise-free cosine grid of the lattice on a
    strip (two edges ``2 x 3 band`` px apart, ``_STRIP_SIGMAS`` sigmas along them):
    its response ``(maps(grid + h z) - maps(grid)) / h`` to a probe ``z`` of random
    signs has, at each pixel, the expected square ``sum_xi r(xi)^2``, the variance
    under unit white noise (Hutchinson's estimator); averaged along the edges (the
    grid is the same there but for its phase, which the average covers), over both
    edges and over the probes (a fixed seed: the same profile every time), and
    divided by that of the strip's middle.
    """
    lattice = Lattice(k1, k2)
    sigma = window.sigma
    band = math.ceil(window.band)
    reach = band + math.ceil(2 * window.band)  # the band, the trusted pixels' windows
    n_along, n_across = math.ceil(_STRIP_SIGMAS * sigma) + 2 * reach, 2 * reach + 1
    M = np.linalg.inv(np.array(lattice.K)) / (2 * math.pi)
    rng = np.random.default_rng(20261206)
    h = 1e-4  # grey levels on a grid of amplitude 0.4: linear to 1e-4 of the response
    out = np.ones((2, 5, band + 1))
    for axis in range(2):
        shape = (n_along, n_across) if axis == 0 else (n_across, n_along)
        y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
        base = 1.0 + 0.4 * sum(np.cos(2 * math.pi * (k[0] * x + k[1] * y))
                               for k in (k1, k2))
        ref = transform_to_edges(base, lattice, window)
        sums = np.zeros((5, n_across))
        for _ in range(_PROBES):
            pm = transform_to_edges(base + h * rng.choice((-1.0, 1.0), size=shape),
                                    lattice, window)
            dphase = np.angle(pm.psi * np.conj(ref.psi)) / h  # (2, ...)
            dd = (pm.dphi - ref.dphi) / h  # (2 wave vectors, 2 axes, ...)
            du = -np.tensordot(M, dphase, axes=1)
            G = -np.einsum("ij,jm...->im...", M, dd)
            maps = np.stack([du[0], du[1], G[0, 0], G[1, 1], 0.5 * (G[0, 1] + G[1, 0])])
            # away from the strip's two ends along the edge (continued there too)
            inner = maps[:, reach:-reach] if axis == 0 else maps[:, :, reach:-reach]
            sums += np.mean(inner**2, axis=1 if axis == 0 else 2)
        sums = 0.5 * (sums + sums[:, ::-1])  # the two edges
        interior = np.mean(sums[:, reach - 3:reach + 4], axis=1)
        out[axis] = np.sqrt(sums[:, :band + 1] / interior[:, None])
    return out



def edge_harmonic_bias(image, lattice: Lattice, window: Window, *, mask=None,
                       maps: PhaseMaps | None = None) -> np.ndarray:
    """One image's strain bias from the print's harmonics, which
    :func:`transform_to_edges` does not continue beyond the edges.

    Parameters
    ----------
    image : (H, W) array_like
        Grid image, grey levels.
    lattice : Lattice
    window : Window
    mask : (H, W) bool array_like, optional
        The specimen.
    maps : PhaseMaps, optional
        ``transform_to_edges(image, lattice, window, mask=mask)``, if already made.

    Returns
    -------
    (3, H, W) float ndarray
        The bias of the image's own ``(e_xx, e_yy, e_xy)`` (dimensionless), 0 off
        ``mask``.

    Notes
    -----
    The print less its harmonics is made from the image's own maps: the mean grey
    level under the window (of the image less its fundamentals) plus the
    fundamentals ``sum_j 2 Re(Psi_j e^{2 pi i k_j . x})``, on the mask. The
    harmonics are the image less that, regressed over the interior (beyond the
    window's band from the edges; up to :data:`_HARMONIC_SAMPLES` pixels) on
    ``cos`` and ``sin`` of ``n Phi_1 + m Phi_2`` (``Phi_j`` the grid's total phase,
    every order with ``|n| + |m| <= 6`` but the fundamentals, kept where they stand
    out of the noise as a whole): a print's harmonics follow its lines, and the
    regression over the whole interior averages the noise out. The print without
    and with its harmonics are both transformed up to the edges and their strains
    compared: to first order in the harmonics, their bias
    (noise-free), in the interior their aliasing (the window's,
    :func:`gridstrain.uncertainty.aliasing_bias`) and in the edge band the cut of the
    harmonics at the edge besides. It is the bias at the grid's position against the
    edges in this image: another position (a state's, displaced) has another, up to
    :data:`EDGE_HARMONIC_SPREAD` times it, and a strain holds two images' (the
    reference's and the state's).
    """
    check_type(lattice, "lattice", Lattice)
    check_type(window, "window", Window)
    img = as_image(image).astype(np.float64)
    m = check_mask(mask, img.shape)
    if maps is None:
        maps = transform_to_edges(img, lattice, window, mask=m)
    H, W = img.shape
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    K = np.array(lattice.K, dtype=np.float64)
    total = [np.angle(maps.psi[j]) + 2 * math.pi * (K[j, 0] * x + K[j, 1] * y)
             for j in range(2)]
    pred = sum(2 * np.abs(maps.psi[j]) * np.cos(total[j]) for j in range(2))
    # the pixels that show the grid in part are left out, as the image's transform
    # left them (their light is not the grid's)
    whole = m & ~partly_covered(img, maps, m)
    # the mean grey level from the image less its fundamentals: a window cut at the
    # edge would let them leak into the mean (1e-3 strain on a cosine print)
    clean = np.where(whole, _local_mean(img - pred, whole, window.sigma) + pred, img)
    inner = np.flatnonzero(whole & ~edge_pixels(whole, window))
    if inner.size < 4 * len(_ORDERS):  # too few pixels to tell harmonics from noise
        return np.zeros((3, H, W))
    if inner.size > _HARMONIC_SAMPLES:
        inner = np.sort(np.random.default_rng(0).choice(inner, _HARMONIC_SAMPLES,
                                                        replace=False))
    amp = np.abs(maps.psi[0]) + np.abs(maps.psi[1])  # the harmonics scale with the grid's
    orders = _orders_apart(K, min(H, W))
    if not orders:
        return np.zeros((3, H, W))

    def basis(idx):
        p1, p2, a = total[0].ravel()[idx], total[1].ravel()[idx], amp.ravel()[idx]
        return np.stack([a * f(n * p1 + k * p2) for n, k in orders for f in (np.cos, np.sin)],
                        axis=1)

    X, v = basis(inner), (img - clean).ravel()[inner]
    # orders that fold onto one another on the pixels (an integer pitch: the 3rd onto
    # the conjugate of the 2nd) are one column: the least squares' cut (singular
    # values under 1e-4 of the largest) leaves them one coefficient, not two opposite
    # large ones that cancel inside and not at the edges (noise-free: a bias of 3)
    coef, _, rank, _ = np.linalg.lstsq(X, v - v.mean(), rcond=1e-4)
    fit = X @ coef
    ess, rss = float(fit @ fit), float(np.sum((v - v.mean() - fit) ** 2))
    # the harmonics as a whole stand out of the noise (an F test, 5 of its standard
    # deviations 1 + sqrt(2 / rank) under noise alone) or are the noise's
    if not ess / max(rank, 1) > (1 + 5 * math.sqrt(2 / max(rank, 1))) * rss / max(
            v.size - rank, 1):
        coef[:] = 0.0
    on = np.flatnonzero(whole)
    printed = clean.copy()
    printed.ravel()[on] += basis(on) @ coef
    pure = transform_to_edges(clean, lattice, window, mask=whole)
    full = transform_to_edges(printed, lattice, window, mask=whole)
    M = np.linalg.inv(K) / (2 * math.pi)
    G = -np.einsum("ij,jm...->im...", M,
                   full.dphi.astype(np.float64) - pure.dphi.astype(np.float64))
    out = np.stack([G[0, 0], G[1, 1], 0.5 * (G[0, 1] + G[1, 0])])
    out[:, ~m] = 0.0
    return out


# The harmonics' orders (n, m) of n k1 + m k2 regressed (one of each +-pair): all with
# |n| + |m| <= 6 but the mean and the fundamentals.
_ORDERS = tuple((n, k) for n in range(0, 7) for k in range(-6, 7)
                if abs(n) + abs(k) <= 6 and (n > 0 or k > 0) and (n, k) not in ((1, 0), (0, 1)))


def _orders_apart(K: np.ndarray, size: int) -> list:
    """The orders of :data:`_ORDERS` whose harmonic, folded by the sampling, lies two
    frequency bins (``2 / size`` cycles/px) or more from the mean and from either
    carrier and its conjugate: those closer are, on the pixels, one with the
    fundamental or the mean (an integer pitch puts the 4th, 5th and 6th orders there)
    and cannot be told from them; their bias is the aliasing's
    (:func:`gridstrain.uncertainty.aliasing_bias`)."""
    reach = 2.0 / size
    near = np.array([[0.0, 0.0], K[0], K[1], -K[0], -K[1]])
    out = []
    for n, k in _ORDERS:
        h = n * K[0] + k * K[1]
        d = (h[None, :] - near + 0.5) % 1.0 - 0.5
        if np.hypot(d[:, 0], d[:, 1]).min() > reach:
            out.append((n, k))
    return out


#: Interior pixels the harmonics are regressed on, at most (a random draw, fixed seed):
#: 200,000 against 80 columns: the noise left in the fitted harmonics is
#: sqrt(80 / 200,000) = 2 % of the image's (a cosine print, its noise 1/40 of its
#: amplitude, 960 interior pixels: 29 %, an edge bias of 4e-3 read as harmonics
#: where the F test above did not drop them).
_HARMONIC_SAMPLES = 200_000
