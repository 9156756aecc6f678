"""Displacement and strain from phase maps (paper eqs. 34-35, any two wave vectors).

Signs, axes and the Lagrangian description are those of
:mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from skimage.registration import phase_cross_correlation
from skimage.restoration import unwrap_phase

from ._validation import as_image, check_mask, check_positive
from .lattice import Lattice, detect_lattice
from .wft import DEFAULT_MARGIN, PhaseMaps, wft

__all__ = ["Measurement", "coarse_displacement", "deformation", "measure"]

# Spline order used to evaluate the deformed maps at x + u. The demodulated maps are
# band-limited by the window (their spectrum falls as exp(-2 pi^2 sigma^2 nu^2)), so
# cubic splines suffice: against the direct sum at off-grid points the phase error is
# 3e-7 rad at sigma = pitch = 5 px (tests/test_lagrangian_interpolation.py), and on a noisy
# 1040 x 1376 pair they change u by less than 1e-7 px from quintic splines, with 16
# coefficients per point instead of 36.
_SPLINE_ORDER = 3
# Rows and columns of edge values added around a map before its spline prefilter, as
# scipy's map_coordinates(mode="nearest") does: the prefilter's boundary then matches
# the clamped evaluation outside the image.
_SPLINE_PAD = 12
# A coarse cross-correlation estimate is trusted only if the low-passed images,
# aligned, correlate at least this well (Pearson); below it the pattern has no
# features beyond the periodic grid and the displacement is ambiguous to a period.
_MIN_COARSE_CORRELATION = 0.5


@dataclass(frozen=True, eq=False)
class Measurement:
    """Displacement and strain maps between a reference and a deformed state.

    Attributes
    ----------
    u : (2, H, W) float ndarray
        Displacement ``(u_x, u_y)`` in px, Lagrangian (at reference pixels), NaN
        where not ``valid``. Computed in float64; float32 (as are ``strain`` and
        ``rotation``) when both sets of phase maps are (:mod:`gridstrain.conventions`).
    strain : (3, H, W) float ndarray
        ``(eps_xx, eps_yy, eps_xy)``, dimensionless small-strain tensor (tensor
        shear), NaN where not ``valid``.
    rotation : (H, W) float ndarray
        Infinitesimal rotation ``omega = (du_y/dx - du_x/dy)/2``, rad.
    valid : (H, W) bool ndarray
        Pixels where both states were measured.
    lattice : Lattice
    sigma : float
        Window standard deviation, px.
    lagrangian : bool
        Whether the large-displacement (Lagrangian) correction was applied.
    iterations : int
        Fixed-point iterations of the correction (0 without it).
    step_rms : float
        RMS change of ``u`` over the valid pixels at the last iteration, px.
    guess : (2,) tuple of float
        Median of the initial guess that fixed the fringe order, px.
    guess_source : str
        ``"auto"`` (cross-correlation), ``"zero"``, or ``"user"``.
    reference, deformed : PhaseMaps
        The phase maps the measurement was made from.
    """

    u: np.ndarray
    strain: np.ndarray
    rotation: np.ndarray
    valid: np.ndarray
    lattice: Lattice
    sigma: float
    lagrangian: bool
    iterations: int
    step_rms: float
    guess: tuple[float, float]
    guess_source: str
    reference: PhaseMaps = field(repr=False)
    deformed: PhaseMaps = field(repr=False)

    def __post_init__(self):
        for name in ("u", "strain", "rotation", "valid"):
            getattr(self, name).flags.writeable = False

    @property
    def ux(self) -> np.ndarray:
        """(H, W) displacement along x, px."""
        return self.u[0]

    @property
    def uy(self) -> np.ndarray:
        """(H, W) displacement along y, px."""
        return self.u[1]

    @property
    def exx(self) -> np.ndarray:
        """(H, W) normal strain along x."""
        return self.strain[0]

    @property
    def eyy(self) -> np.ndarray:
        """(H, W) normal strain along y."""
        return self.strain[1]

    @property
    def exy(self) -> np.ndarray:
        """(H, W) shear strain (tensor component, half the engineering shear)."""
        return self.strain[2]

    def __repr__(self) -> str:
        H, W = self.valid.shape
        v = self.valid
        mu = [float(np.mean(c[v])) if v.any() else math.nan for c in self.u]
        return (f"Measurement({H}x{W}, {v.mean():.1%} valid, mean u = ({mu[0]:.4g}, "
                f"{mu[1]:.4g}) px, sigma={self.sigma:.4g} px, lagrangian={self.lagrangian}, "
                f"iterations={self.iterations})")


def coarse_displacement(reference, deformed, lattice: Lattice, *, mask=None):
    """Coarse rigid displacement from the images' non-periodic content.

    The images are low-passed with a Gaussian of one pitch, which removes the grid
    (its carrier is attenuated by ``exp(-2 pi^2)`` ~ 3e-9) and keeps what is not
    periodic: printing defects, reflectance, specimen edges, holes. Their masked
    normalised cross-correlation (scikit-image's ``phase_cross_correlation`` with
    masks, which is not biased towards zero by the image borders) gives the
    translation to the nearest pixel (to the nearest ``q`` pixels on images larger
    than 1024 px, decimated by ``q``), enough to fix the fringe order.

    Parameters
    ----------
    reference, deformed : (H, W) array_like
    lattice : Lattice
    mask : (H, W) bool array_like, optional
        True on the specimen in the reference image.

    Returns
    -------
    shift : (2,) ndarray
        ``(u_x, u_y)`` in px (Lagrangian sign: a specimen moved right gives
        ``u_x > 0``).
    correlation : float
        Pearson correlation of the low-passed images once aligned; below 0.5 the
        estimate is not trustworthy (no feature besides the periodic grid).
    """
    ref = as_image(reference, "reference").astype(np.float64)
    cur = as_image(deformed, "deformed").astype(np.float64)
    if ref.shape != cur.shape:
        raise ValueError(f"deformed must have the shape of reference {ref.shape}, "
                         f"got {cur.shape}")
    m = check_mask(mask, ref.shape)
    if not isinstance(lattice, Lattice):
        raise TypeError(f"lattice must be a Lattice, got {type(lattice).__name__}")
    best = _correlate(ref, cur, lattice, m)
    if not m.all():
        # The mask often hides the best features (the hole, the specimen's edges) and
        # a featureless masked pair can correlate falsely, so the whole images are
        # tried too and the better-correlated estimate wins.
        whole = _correlate(ref, cur, lattice, np.ones_like(m))
        if whole[1] > best[1]:
            best = whole
    return best


def _correlate(ref, cur, lattice, m):
    q = max(1, math.ceil(max(ref.shape) / 1024))
    low = []
    for img in (ref, cur):
        mean = img[m].mean()
        low.append(ndimage.gaussian_filter(np.where(m, img, mean) - mean, lattice.pitch,
                                           truncate=6.0)[::q, ::q])
    a, b = low
    ma = m[::q, ::q]
    if not (np.any(a) and np.any(b)):
        return np.zeros(2), 0.0
    shift, _, _ = phase_cross_correlation(a, b, reference_mask=ma,
                                          moving_mask=np.ones_like(ma), overlap_ratio=0.5)
    dy, dx = (int(np.rint(v)) for v in shift)
    # Pearson correlation over the overlap of a(x) and b(x - shift)
    H, W = a.shape
    ys = slice(max(0, dy), min(H, H + dy))
    xs = slice(max(0, dx), min(W, W + dx))
    yb = slice(max(0, -dy), min(H, H - dy))
    xb = slice(max(0, -dx), min(W, W - dx))
    aa, bb, mm = a[ys, xs], b[yb, xb], ma[ys, xs]
    aa, bb = aa[mm] - aa[mm].mean(), bb[mm] - bb[mm].mean()
    den = math.sqrt(float(np.sum(aa * aa)) * float(np.sum(bb * bb)))
    corr = float(np.sum(aa * bb)) / den if den > 0 else 0.0
    return np.array([-dx * q, -dy * q], dtype=float), corr


class _Spline:
    """A (possibly complex) 2-D map, prefiltered once, evaluated at many point sets.

    ``map_coordinates`` with ``prefilter=True`` would filter the whole map again at
    every call, as costly as the evaluation itself; the fixed-point iterations of
    :func:`deformation` evaluate the same deformed map several times.
    """

    def __init__(self, arr: np.ndarray, order: int | None = None):
        self.order = order = _SPLINE_ORDER if order is None else order
        padded = np.pad(arr, _SPLINE_PAD, mode="edge")
        self.coef = ndimage.spline_filter(padded, order, mode="nearest",
                                          output=padded.dtype)

    def __call__(self, coords: np.ndarray) -> np.ndarray:
        """Values at ``coords`` (2, H, W) = (rows, columns) of the unpadded map."""
        return ndimage.map_coordinates(self.coef, coords + _SPLINE_PAD, order=self.order,
                                       mode="nearest", prefilter=False)


def _unwrap(wrapped: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """scikit-image's ``unwrap_phase`` of ``wrapped`` over ``valid`` (0 elsewhere).

    Like scikit-image's, the result is defined up to one multiple of 2 pi per
    connected region (4-connected), which the fringe order chosen from the guess
    absorbs. Turned by a constant ``c`` (its circular mean), the map becomes
    ``s = wrap(wrapped - c)``; if no two valid neighbours of ``s`` (along a row or a
    column) differ by pi or more, scikit-image's reliability-guided unwrapping would
    join every pair of groups with the offset that makes them continuous in ``s``
    (each merge rounds the difference of two neighbours), so its result is ``s + c``
    up to those multiples. That is checked by two differences instead of sorting
    every edge: the common case of a displacement field spread over less than a
    fringe, whatever its mean. Otherwise scikit-image runs.
    """
    # any constant would do for the proof; the circular mean of a subsample centres
    # the map so that a field spread over less than 2 pi shows no jump
    sub = wrapped[::4, ::4][valid[::4, ::4]]
    c = float(np.angle(np.sum(np.exp(1j * sub)))) if sub.size else 0.0
    s = np.mod(wrapped - c + np.pi, 2 * np.pi) - np.pi
    jumps = (np.any((np.abs(np.diff(s, axis=1)) >= np.pi) & valid[:, 1:] & valid[:, :-1])
             or np.any((np.abs(np.diff(s, axis=0)) >= np.pi) & valid[1:] & valid[:-1]))
    if not jumps:
        # wrapped plus whole turns, as scikit-image adds them
        turns = np.rint((s + c - wrapped) / (2 * np.pi))
        return np.where(valid, wrapped + 2 * np.pi * turns, 0.0)
    ma = np.ma.masked_array(wrapped, mask=~valid)
    return np.ma.filled(unwrap_phase(ma, rng=0), 0.0)


def _solve(K: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``K^-1 r`` for a 2x2 ``K`` and ``r`` of shape (2, ...)."""
    return np.tensordot(np.linalg.inv(K), r, axes=1)


def _guess_field(guess, shape, ref_img, cur_img, lattice, mask):
    if isinstance(guess, str):
        if guess != "auto":
            raise ValueError(f"guess must be 'auto', None, a (u_x, u_y) pair or a (2, H, W) "
                             f"field, got {guess!r}")
        if ref_img is None:
            raise ValueError("guess='auto' needs the images; pass a guess with phase maps")
        shift, corr = coarse_displacement(ref_img, cur_img, lattice, mask=mask)
        if corr >= _MIN_COARSE_CORRELATION:
            return np.broadcast_to(shift[:, None, None], (2, *shape)), "auto"
        return np.zeros((2, *shape)), "zero"
    if guess is None:
        return np.zeros((2, *shape)), "zero"
    g = np.asarray(guess, dtype=float)
    if g.shape == (2,):
        g = np.broadcast_to(g[:, None, None], (2, *shape))
    elif g.shape != (2, *shape):
        raise ValueError(f"guess must be a (u_x, u_y) pair or a field of shape "
                         f"{(2, *shape)}, got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError("guess must be finite")
    return g, "user"


def deformation(reference: PhaseMaps, deformed: PhaseMaps, *, lagrangian: bool = True,
                guess=None, tol: float = 1e-6, max_iter: int = 50,
                _images=None) -> Measurement:
    """Displacement and strain between two phase-map sets of the same lattice.

    Parameters
    ----------
    reference, deformed : PhaseMaps
        From :func:`gridstrain.wft` (or a stack average) with the same lattice and
        window.
    lagrangian : bool
        Apply the large-displacement correction: solve
        ``u(X) = -(1/2pi) K^-1 (phi_def(X + u(X)) - phi_ref(X))`` by fixed point,
        and take the deformed-state derivatives at ``X + u``. Without it, eq. (34)
        as printed (``phi_def`` at ``X``), exact only to first order.
    guess : None, (2,) array_like or (2, H, W) array_like
        Initial displacement, px, that fixes the fringe order (a displacement is
        known from phases only up to a lattice period). Default: zero.
    tol : float
        Stop when the RMS change of ``u`` over the valid pixels falls below
        ``tol`` px.
    max_iter : int
        Largest number of fixed-point iterations.

    Returns
    -------
    Measurement

    Notes
    -----
    The wrapped phase difference is unwrapped in space by scikit-image's
    ``unwrap_phase`` over the valid pixels (each connected region on its own; not
    called where the map, turned by its mean, shows no jump between valid
    neighbours, since its result is then known); each region's fringe order is the
    one closest to the guess. With the correction on,
    the residual ``phi_def(X + u) - phi_ref(X) + 2 pi K u`` is wrapped at every
    iteration, so any displacement is followed once the start is within half a
    period. The strain then comes from the exact Lagrangian gradient
    ``G = (2 pi K + D_def(X + u))^-1 (D_ref - D_def(X + u))``, with ``D`` the 2x2
    phase-derivative matrices; to first order this is eq. (35),
    ``G = -(1/2pi) K^-1 (D_def - D_ref)``, which is what is used without the
    correction.
    """
    for name, pm in (("reference", reference), ("deformed", deformed)):
        if not isinstance(pm, PhaseMaps):
            raise TypeError(f"{name} must be PhaseMaps, got {type(pm).__name__}")
    if reference.shape != deformed.shape:
        raise ValueError(f"deformed maps must have the shape of the reference "
                         f"{reference.shape}, got {deformed.shape}")
    if reference.lattice != deformed.lattice:
        raise ValueError("reference and deformed maps must use the same lattice")
    tol = check_positive(tol, "tol")
    if not isinstance(max_iter, int) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")

    lattice = reference.lattice
    K = lattice.K
    shape = reference.shape
    ref_img, cur_img, img_mask = _images if _images is not None else (None, None, None)
    g, source = _guess_field(guess, shape, ref_img, cur_img, lattice, img_mask)

    # eq. (34): wrapped phase difference, unwrapped over the valid region
    valid = reference.valid & deformed.valid & np.all(np.isfinite(reference.dphi), axis=(0, 1))
    dphase = np.angle(deformed.psi * np.conj(reference.psi)).astype(np.float64)
    labels, n_regions = ndimage.label(valid)
    if n_regions == 0:
        raise ValueError("no valid pixel: the image is smaller than the window and its "
                         "margin, or the mask leaves nothing")
    unwrapped = np.stack([_unwrap(dphase[j], valid) for j in range(2)])
    u = -_solve(K, unwrapped) / (2 * np.pi)
    # fringe order per connected region, closest to the guess: u -> u - K^-1 n
    for lab in range(1, n_regions + 1):
        sel = labels == lab
        n = np.rint(np.median((K @ (u[:, sel] - g[:, sel])), axis=1))
        if np.any(n):
            u[:, sel] -= np.linalg.solve(K, n)[:, None]

    iterations, step = 0, 0.0
    D_ref = reference.dphi.astype(np.float64, copy=False)
    if lagrangian:
        yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
        conj_ref = np.conj(reference.psi.astype(np.complex128, copy=False))
        psi_cur = [_Spline(p.astype(np.complex128, copy=False)) for p in deformed.psi]
        two_pi_K = 2 * np.pi * K
        nv = max(int(valid.sum()), 1)
        for iterations in range(1, max_iter + 1):  # noqa: B007
            coords = np.stack([yy + u[1], xx + u[0]])
            r = np.empty_like(u)
            for j in range(2):
                # residual phi_def(X + u) - phi_ref(X) + 2 pi k.u, wrapped to (-pi, pi]:
                # the carrier's phase added as a real number rather than as exp(i .)
                r[j] = np.angle(psi_cur[j](coords) * conj_ref[j])
                r[j] += two_pi_K[j, 0] * u[0] + two_pi_K[j, 1] * u[1]
                r[j] = np.pi - np.mod(np.pi - r[j], 2 * np.pi)
            du = -_solve(K, r) / (2 * np.pi)
            u = u + np.where(valid, du, 0.0)
            step = math.sqrt(float(np.sum(du[:, valid] ** 2)) / nv)
            if step < tol:
                break
        coords = np.stack([yy + u[1], xx + u[0]])
        inside = ((coords[0] >= 0) & (coords[0] <= shape[0] - 1)
                  & (coords[1] >= 0) & (coords[1] <= shape[1] - 1))
        cur_valid = ndimage.map_coordinates(deformed.valid.astype(np.float64), coords,
                                            order=1, mode="constant", cval=0.0)
        valid = reference.valid & inside & (cur_valid > 0.999)
        D_cur = np.empty((2, 2, *shape))
        # Where Psi is exactly 0 (deep in a masked area) its derivatives are undefined;
        # a spline's prefilter would spread one NaN over whole rows, so zero them (the
        # pixels are invalid anyway).
        dphi_cur = np.nan_to_num(deformed.dphi.astype(np.float64), nan=0.0, posinf=0.0,
                                 neginf=0.0)
        for j in range(2):
            for m in range(2):
                D_cur[j, m] = _Spline(dphi_cur[j, m])(coords)
        # exact Lagrangian gradient: (2 pi K + D_cur) G = D_ref - D_cur, by Cramer's
        # rule map by map rather than through (2, 2, H, W) temporaries
        a00 = 2 * np.pi * K[0, 0] + D_cur[0, 0]
        a01 = 2 * np.pi * K[0, 1] + D_cur[0, 1]
        a10 = 2 * np.pi * K[1, 0] + D_cur[1, 0]
        a11 = 2 * np.pi * K[1, 1] + D_cur[1, 1]
        B = np.subtract(D_ref, D_cur, out=D_cur)
        rdet = 1.0 / (a00 * a11 - a01 * a10)
        G = np.empty((2, 2, *shape))
        G[0, 0] = (a11 * B[0, 0] - a01 * B[1, 0]) * rdet
        G[0, 1] = (a11 * B[0, 1] - a01 * B[1, 1]) * rdet
        G[1, 0] = (a00 * B[1, 0] - a10 * B[0, 0]) * rdet
        G[1, 1] = (a00 * B[1, 1] - a10 * B[0, 1]) * rdet
    else:
        D_cur = deformed.dphi.astype(np.float64)
        G = -np.tensordot(np.linalg.inv(K), D_cur - D_ref, axes=1) / (2 * np.pi)  # eq. (35)

    strain = np.stack([G[0, 0], G[1, 1], 0.5 * (G[0, 1] + G[1, 0])])
    rotation = 0.5 * (G[1, 0] - G[0, 1])
    # computed in float64, returned in the maps' precision (gridstrain.conventions)
    dt = np.result_type(reference.dphi.dtype, deformed.dphi.dtype)
    u = np.where(valid, u, np.nan).astype(dt, copy=False)
    strain = np.where(valid, strain, np.nan).astype(dt, copy=False)
    rotation = np.where(valid, rotation, np.nan).astype(dt, copy=False)
    gmed = tuple(float(np.median(c)) for c in g) if source != "zero" else (0.0, 0.0)
    return Measurement(u=u, strain=strain, rotation=rotation, valid=valid, lattice=lattice,
                       sigma=reference.sigma, lagrangian=bool(lagrangian),
                       iterations=iterations, step_rms=step, guess=gmed,
                       guess_source=source, reference=reference, deformed=deformed)


def measure(reference, deformed, *, lattice: Lattice | None = None,
            sigma: float | None = None, mask=None, lagrangian: bool = True,
            guess="auto", margin: float = DEFAULT_MARGIN) -> Measurement:
    """Displacement and strain maps between a reference and a deformed grid image.

    Parameters
    ----------
    reference, deformed : (H, W) array_like
        Grid images of the specimen before and after loading (grey levels).
    lattice : Lattice, optional
        The grid's wave vectors; detected on the reference image by default.
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen, in the reference configuration.
    lagrangian : bool
        Large-displacement correction (default on); see :func:`deformation`.
    guess : "auto", None, (2,) or (2, H, W) array_like
        Initial displacement fixing the fringe order. ``"auto"`` cross-correlates
        the low-passed images (:func:`coarse_displacement`) and falls back to zero
        when they hold nothing but the periodic grid.
    margin : float
        Invalid band along borders and mask edges, in units of ``sigma``.

    Returns
    -------
    Measurement

    Examples
    --------
    >>> import numpy as np
    >>> from gridstrain import Lattice, measure, synthetic
    >>> lat = Lattice.from_pitch(5.0)
    >>> ref = synthetic.grid_image((96, 96), lat)
    >>> cur = synthetic.grid_image((96, 96), lat,
    ...                            displacement=lambda X, Y: (0.3 + 0 * X, -0.2 + 0 * Y))
    >>> res = measure(ref, cur, lattice=lat, guess=None)
    >>> [round(float(np.nanmean(c)), 5) for c in res.u]
    [0.3, -0.2]
    """
    ref = as_image(reference, "reference")
    cur = as_image(deformed, "deformed")
    if ref.shape != cur.shape:
        raise ValueError(f"deformed must have the shape of reference {ref.shape}, "
                         f"got {cur.shape}")
    m = check_mask(mask, ref.shape)
    if lattice is None:
        lattice = detect_lattice(ref, mask=m)
    elif not isinstance(lattice, Lattice):
        raise TypeError(f"lattice must be a Lattice or None, got {type(lattice).__name__}")
    pm_ref = wft(ref, lattice, sigma=sigma, mask=m, margin=margin, workers=None)
    # the deformed specimen has moved: its mask is not the reference's, so the
    # deformed image is transformed whole and validity comes from its own moduli
    pm_cur = wft(cur, lattice, sigma=sigma, margin=margin, workers=None)
    return deformation(pm_ref, pm_cur, lagrangian=lagrangian, guess=guess,
                       _images=(ref, cur, m))
