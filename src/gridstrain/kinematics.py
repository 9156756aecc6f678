"""Displacement and strain from phase maps (paper eqs. 34-35, any two wave vectors).

Signs, axes and the Lagrangian description are those of
:mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import fft as sfft
from scipy import ndimage
from skimage.restoration import unwrap_phase

from ._stats import median
from ._threads import map_bounded
from ._validation import (
    as_image,
    as_pair,
    check_int,
    check_mask,
    check_positive,
    check_same_shape,
    check_type,
    check_workers,
)
from .lattice import Lattice, _reference_carrier, _state_carrier, detect_lattice
from .wft import DEFAULT_MARGIN, PhaseMaps, demodulated_at, wft

__all__ = [
    "FRINGE_ORDER_SOURCES",
    "CoarseEstimate",
    "FringeOrder",
    "Measurement",
    "coarse_displacement",
    "deformation",
    "measure",
]

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
# Band-pass of the coarse estimate, in pitches (see coarse_displacement): a narrow
# band around the pitch makes a feature's correlation peak narrower than a period.
# With a wide band (up to 2 or 4 pitches) a hole's edge beat its aliases by only 1.3
# (up to 1.05 for reflectance blobs 20 px wide), with this one by 2.0.
_BAND_LOW = 0.5
_BAND_HIGH = 1.0
# The coarse estimate works on a central crop of at most this size, px.
_MAX_COARSE_SIZE = 1024
# ... and, when the crop is large, on its band-passed images decimated by the largest
# integer q <= pitch / 2 that leaves at least this many samples per side. The band
# stops at about 0.8 / pitch (the difference of Gaussians keeps 9 % of its peak
# there) and the narrow Gaussian, applied before decimating, leaves 4e-4 of what
# lies at the new Nyquist frequency 1 / (2 q) >= 1 / pitch: the grid's fundamental
# is not folded back into the band, nothing the band holds is lost, and the
# correlation costs q^2 times less.
_COARSE_MIN_SAMPLES = 256
# The best candidate must correlate this many times better than any alias a lattice
# period or two away. Measured (160-px images, 0.1 % noise, 40 % vignette): grids and
# sharp rotated checkerboards with nothing else, moved by 0 to 13 px, 1.00 to 1.18;
# sixty printed spots moving with the specimen 2.2 to 3.2, a hole's edge 2.0.
_MIN_PEAK_TO_ALIAS = 1.5
# The correlation peak must lie within this fraction of a period (along each wave
# vector) of the candidate the phases allow: the peak is good to a pixel, a quarter
# of a 4-px pitch.
_MAX_DISAGREEMENT = 0.25


#: How a fringe order can be fixed (:attr:`FringeOrder.source`).
FRINGE_ORDER_SOURCES = ("previous state", "image features", "user", "smallest displacement")


@dataclass(frozen=True)
class FringeOrder:
    """How the whole number of periods (the fringe order) of a displacement was fixed.

    The phases give the displacement only modulo the lattice periods; the fringe
    order comes from elsewhere, and this record says from where and whether
    anything confirms it.

    Attributes
    ----------
    source : str
        One of :data:`FRINGE_ORDER_SOURCES`: ``"previous state"`` (the previous
        load step's displacement field, incremental tracking), ``"image features"``
        (a confident :func:`coarse_displacement`), ``"user"`` (a given guess) or
        ``"smallest displacement"`` (nothing else: the order closest to zero).
    confirmed : bool
        True when the order is backed by something besides the phases: the user's
        guess; image features that clearly pick one candidate and agree with the
        phases; or tracking from a confirmed previous state with an increment
        below ``_MAX_STEP`` periods everywhere (a step that is plausibly less than
        half a period). A state not confirmed may be one or more periods off.
    guess : (2,) tuple of float
        Median of the guess field that fixed the order, px.
    detail : str
        Why, in words.
    correlation, peak_to_alias, disagreement : float
        Of the image-feature estimate (:class:`CoarseEstimate`), NaN when not made.
    features_shift : (2,) tuple of float or None
        The image-feature estimate's displacement, px, when made.
    step : float
        Largest increment from the previous state along a wave vector, in periods
        (NaN when not tracked).
    """

    source: str
    confirmed: bool
    guess: tuple[float, float] = (0.0, 0.0)
    detail: str = ""
    correlation: float = math.nan
    peak_to_alias: float = math.nan
    disagreement: float = math.nan
    features_shift: tuple[float, float] | None = None
    step: float = math.nan

    def __post_init__(self):
        if self.source not in FRINGE_ORDER_SOURCES:
            raise ValueError(f"source must be one of {FRINGE_ORDER_SOURCES}, got "
                             f"{self.source!r}")

    def as_dict(self) -> dict:
        """Plain-Python record (NaN as None), for JSON and HDF5."""
        def num(x):
            return float(x) if x is not None and math.isfinite(x) else None

        return {"source": self.source, "confirmed": bool(self.confirmed),
                "guess_px": [float(v) for v in self.guess], "detail": self.detail,
                "correlation": num(self.correlation),
                "peak_to_alias": num(self.peak_to_alias),
                "disagreement_periods": num(self.disagreement),
                "features_shift_px": None if self.features_shift is None
                else [float(v) for v in self.features_shift],
                "step_periods": num(self.step)}


def _from_estimate(est, source, confirmed, guess, detail, step=math.nan) -> FringeOrder:
    """A :class:`FringeOrder` carrying the figures of a coarse estimate (or none)."""
    if est is None:
        return FringeOrder(source, confirmed, guess, detail, step=step)
    return FringeOrder(source, confirmed, guess, detail, correlation=est.correlation,
                       peak_to_alias=est.peak_to_alias, disagreement=est.disagreement,
                       features_shift=est.shift, step=step)


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
        ``"auto"`` (image features, :func:`coarse_displacement`), ``"zero"``, or
        ``"user"``.
    reference, deformed : PhaseMaps
        The phase maps the measurement was made from.
    fringe_order : FringeOrder
        How the whole number of periods was fixed, and whether it is confirmed.
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
    fringe_order: FringeOrder | None = field(default=None, repr=False)

    def __post_init__(self):
        for name in ("u", "strain", "rotation", "valid"):
            arr = getattr(self, name)
            if isinstance(arr, np.ndarray):  # maps read from a file are read-only already
                arr.flags.writeable = False

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


@dataclass(frozen=True)
class CoarseEstimate:
    """What the images' non-periodic content says about the rigid displacement.

    Attributes
    ----------
    shift : (2,) tuple of float
        ``(u_x, u_y)``, px: the best phase-consistent candidate when the phases
        were given, otherwise the correlation peak (to the pixel).
    peak : (2,) tuple of float
        The correlation peak itself, px (sub-pixel, parabolic).
    correlation : float
        Normalised correlation of the band-passed images at ``shift``.
    alias_correlation : float
        Best correlation among ``shift``'s aliases ``shift + m a1 + n a2``
        (``a1``, ``a2`` the lattice periods, ``0 < max(|m|, |n|) <= 2``).
    peak_to_alias : float
        ``correlation / max(alias_correlation, 0.01)``.
    disagreement : float
        Distance from ``peak`` to ``shift`` in periods (largest over the two wave
        vectors, ``|K (peak - shift)|``); NaN without phases.
    confident : bool
        Whether the estimate fixes the fringe order: content that moves with the
        specimen, a peak that clearly beats its aliases and agrees with the phases.
    reason : str
        Why it is (or is not) confident, in words.
    """

    shift: tuple[float, float]
    peak: tuple[float, float]
    correlation: float
    alias_correlation: float
    peak_to_alias: float
    disagreement: float
    confident: bool
    reason: str


def coarse_displacement(reference, deformed, lattice: Lattice, *, mask=None,
                        phase_shift=None) -> CoarseEstimate:
    """Rigid displacement from the images' non-periodic content, and whether to trust it.

    The images are band-passed by a difference of Gaussians of half a pitch and
    one pitch: the first removes the grid (its carrier is attenuated by
    ``exp(-pi^2 / 2)`` ~ 7e-3, and what survives is periodic, so it favours no
    alias), the second what is fixed to the camera and smooth (lighting,
    vignetting). What is left is what moves with the specimen: printing defects,
    dust on it, edges, holes. Their normalised cross-correlation is computed over
    the overlap of the two images at every shift (masked, so that the image
    borders neither pad with zeros nor pull the peak towards zero shift).

    The phases fix the displacement modulo the lattice: the candidates are
    ``phase_shift + m a1 + n a2``. The estimate is *confident* only when (a) the
    band-passed images correlate (``>= 0.5``) at the best candidate, (b) that
    candidate beats every alias within two periods by a peak-to-alias ratio of
    1.5 and (c) the correlation peak itself lies within a quarter period of it. A
    pattern with nothing but the grid, or smooth content fixed to the camera
    (lighting, vignetting), fails (a) or (b); when it cannot decide, the caller
    must not use ``shift``.

    Parameters
    ----------
    reference, deformed : (H, W) array_like
    lattice : Lattice
    mask : (H, W) bool array_like, optional
        True on the specimen in the reference image.
    phase_shift : (2,) array_like, optional
        The rigid displacement the phases give, px, known modulo the lattice
        periods (see :func:`deformation`). Without it the candidates are the
        correlation peak and its aliases, and nothing is checked against phases.

    Returns
    -------
    CoarseEstimate
        ``shift`` with the Lagrangian sign: a specimen moved right gives
        ``u_x > 0``.

    Notes
    -----
    Sharp content fixed to the camera (dust on the lens or sensor, hot pixels)
    that outweighs the specimen's own features makes the estimate say "no
    motion"; check (c) catches it unless the specimen moved by a whole number of
    periods to within a quarter period. Images larger than 1024 px are
    correlated over their central 1024 x 1024 px; from 512 px on, the
    band-passed images are decimated by ``q = floor(pitch / 2)`` (at most down
    to 256 samples a side) before they are correlated: the band holds nothing
    above about 0.8 / pitch, below the new Nyquist frequency, and the
    correlation costs ``q^2`` times less. The candidates are then read from the
    decimated map by cubic splines, the peak located to a fifth of a sample.
    """
    ref = as_image(reference, "reference").astype(np.float64)
    cur = as_image(deformed, "deformed").astype(np.float64)
    check_same_shape(cur.shape, ref.shape, "deformed", "reference")
    m = check_mask(mask, ref.shape)
    check_type(lattice, "lattice", Lattice)
    if phase_shift is not None:
        phase_shift = as_pair(phase_shift, "phase_shift", labels="(u_x, u_y)", unit="px")
    return _CoarseReference(ref, lattice, m).estimate(cur, phase_shift)


class _CoarseReference:
    """The reference's side of :func:`coarse_displacement` (its band-passed image,
    masks and transforms), computed once and used for every deformed image of a
    run: what depends on the reference alone is not recomputed per state."""

    def __init__(self, reference: np.ndarray, lattice: Lattice, mask: np.ndarray):
        self.reference = np.asarray(reference, dtype=np.float64)
        self.lattice, self.mask = lattice, mask
        self._sides: dict[bool, _Side] = {}

    def side(self, whole: bool) -> _Side:
        if whole not in self._sides:
            m = np.ones_like(self.mask) if whole else self.mask
            self._sides[whole] = _reference_side(self.reference, self.lattice, m)
        return self._sides[whole]

    def estimate(self, deformed: np.ndarray, phase_shift) -> CoarseEstimate:
        """:func:`coarse_displacement` of ``deformed`` (float64, checked)."""
        best = _correlate(self.side(False), deformed, self.lattice, phase_shift)
        if not self.mask.all() and not best.confident:
            # The mask often hides the best features (the hole, the specimen's edges),
            # so the whole images are tried too.
            whole = _correlate(self.side(True), deformed, self.lattice, phase_shift)
            if whole.confident or whole.peak_to_alias > best.peak_to_alias:
                best = whole
        return best


def _band_weights(m, pitch, q=1) -> tuple[np.ndarray, np.ndarray]:
    """The normalising weights of :func:`_band_pass` over ``m``, for its narrow and its
    wide Gaussian (they depend on the mask alone: made once for a fixed mask)."""
    w = m.astype(np.float64)
    if q == 1:
        return tuple(ndimage.gaussian_filter(w, s, mode="constant", truncate=4.0)
                     for s in (_BAND_LOW * pitch, _BAND_HIGH * pitch))
    s1 = _BAND_LOW * pitch
    s2 = math.sqrt((_BAND_HIGH * pitch) ** 2 - s1**2) / q
    if m.all():  # the weights of a whole image: the product of two profiles
        prof = [ndimage.gaussian_filter1d(np.ones(n), s1, mode="constant", truncate=4.0)[::q]
                for n in m.shape]
        den = np.outer(*prof)
        den2 = np.outer(*(ndimage.gaussian_filter1d(p, s2, mode="constant", truncate=4.0)
                          for p in prof))
    else:
        den = _smooth_decimate(w, s1, q)
        den2 = ndimage.gaussian_filter(den, s2, mode="constant", truncate=4.0)
    return den, den2


def _band_pass(img, m, pitch, q=1, weights=None):
    """Difference of Gaussians (half a pitch, one pitch), normalised over ``m``,
    sampled every ``q`` px along both axes; ``weights`` from :func:`_band_weights`."""
    den, den2 = _band_weights(m, pitch, q) if weights is None else weights
    x = np.where(m, img, 0.0)
    if q == 1:
        # normalised convolution: nothing is assumed beyond the border or the mask
        num = ndimage.gaussian_filter(x, _BAND_LOW * pitch, mode="constant", truncate=4.0)
        num2 = ndimage.gaussian_filter(x, _BAND_HIGH * pitch, mode="constant", truncate=4.0)
        return num / np.maximum(den, 1e-12) - num2 / np.maximum(den2, 1e-12)
    # the narrow Gaussian at full resolution is the anti-aliasing filter; the wide one
    # is the narrow one followed by a Gaussian of std sqrt(s_high^2 - s_low^2), applied
    # to the decimated sums (numerator and weights alike)
    s1 = _BAND_LOW * pitch
    s2 = math.sqrt((_BAND_HIGH * pitch) ** 2 - s1**2) / q
    num = _smooth_decimate(x, s1, q)
    num2 = ndimage.gaussian_filter(num, s2, mode="constant", truncate=4.0)
    return num / np.maximum(den, 1e-12) - num2 / np.maximum(den2, 1e-12)


def _smooth_decimate(a, s, q):
    """``a`` smoothed by a Gaussian of std ``s`` px and sampled every ``q`` px: each
    axis filtered, then decimated, before the other."""
    a = ndimage.gaussian_filter1d(a, s, axis=0, mode="constant", truncate=4.0)[::q]
    return ndimage.gaussian_filter1d(a, s, axis=1, mode="constant", truncate=4.0)[:, ::q]


def _decimation(shape, lattice) -> int:
    """The coarse estimate's decimation factor (see ``_COARSE_MIN_SAMPLES``)."""
    q = int(min(lattice.pitches) // 2)
    while q > 1 and min(shape) // q < _COARSE_MIN_SAMPLES:
        q -= 1
    return max(q, 1)


@dataclass(frozen=True, eq=False)
class _Side:
    """The reference's band-passed image for one mask, with what the normalised
    correlation needs of it and of the deformed image's fixed mask (see
    :func:`_ncc_map`)."""

    shape: tuple[int, int]  # (H, W) of the whole image
    win: tuple[slice, slice]  # the central crop correlated
    q: int  # decimation
    a: np.ndarray  # band-passed reference, decimated
    ma: np.ndarray  # its mask, decimated
    mb: np.ndarray  # the deformed image's mask (its inner band), decimated
    usable: bool  # enough pixels, not uniform
    fft_shape: tuple[int, int] = (0, 0)
    MF: np.ndarray | None = None  # transforms of the reference's mask, f and f^2
    F: np.ndarray | None = None
    F2: np.ndarray | None = None
    n: np.ndarray | None = None  # overlap count at every shift
    sf: np.ndarray | None = None  # sum of f over the overlap
    vf: np.ndarray | None = None  # and its centred sum of squares
    enough: np.ndarray | None = None  # shifts with overlap enough
    weights: tuple = ()  # the deformed image's band-pass weights (its whole crop)


def _reference_side(ref: np.ndarray, lattice: Lattice, m: np.ndarray) -> _Side:
    # large images: a central crop of at most _MAX_COARSE_SIZE keeps the transform
    # cheap and still holds hundreds of periods
    H, W = ref.shape
    cy, cx = max(0, (H - _MAX_COARSE_SIZE) // 2), max(0, (W - _MAX_COARSE_SIZE) // 2)
    win = (slice(cy, cy + _MAX_COARSE_SIZE), slice(cx, cx + _MAX_COARSE_SIZE))
    ref, m = ref[win], m[win]
    pitch = lattice.pitch
    q = _decimation(ref.shape, lattice)  # samples of the correlated maps, px
    a = _band_pass(ref, m, pitch, q)
    # the band-pass of a pixel within the wide Gaussian's reach of the image border
    # depends on where the border is (fixed to the camera): leave that band out
    edge = math.ceil(_BAND_HIGH * pitch)
    inner = np.zeros_like(m)
    inner[edge:-edge, edge:-edge] = True
    if m.all():
        ma = inner
    else:
        ma = ndimage.binary_erosion(m, iterations=max(1, int(_BAND_LOW * pitch) + 1)) & inner
    ma, mb = ma[::q, ::q], inner[::q, ::q]
    side = _Side((H, W), win, q, a, ma, mb, usable=bool(ma.sum() >= 16 and np.ptp(a[ma]) > 0),
                  weights=_band_weights(np.ones_like(m), pitch, q))
    if not side.usable:
        return side
    h, w = a.shape
    shape = (sfft.next_fast_len(2 * h), sfft.next_fast_len(2 * w))
    mf, mg = ma.astype(np.float64), mb.astype(np.float64)
    f = (a - a[mf > 0].mean()) * mf
    F, F2, MF = _tr(f, shape), _tr(f * f, shape), _tr(mf, shape)
    MG = _tr(mg, shape)
    n = np.rint(_xc(MF, MG, shape))
    sf = _xc(F, MG, shape)
    vf = _xc(F2, MG, shape) - sf * sf / np.maximum(n, 1.0)
    enough = n >= 0.5 * min(mf.sum(), mg.sum())
    return dataclasses.replace(side, fft_shape=shape, MF=MF, F=F, F2=F2, n=n, sf=sf, vf=vf,
                               enough=enough)


def _tr(a, shape):
    return sfft.rfft2(a, s=shape)


def _xc(a, b, shape):  # sum_x a(x) b(x + s), from the transforms of a and b
    return sfft.irfft2(np.conj(a) * b, s=shape)


def _ncc_map(side: _Side, g):
    """Normalised correlation of the reference's ``f(x)`` and ``g(x + s)`` over
    ``mf(x) mg(x + s)`` (the masks of ``side``).

    Returns the map indexed by ``s`` modulo its shape.
    """
    shape, MF = side.fft_shape, side.MF
    mg = side.mb.astype(np.float64)
    g = (g - g[mg > 0].mean()) * mg
    G, G2 = _tr(g, shape), _tr(g * g, shape)
    nn = np.maximum(side.n, 1.0)
    sf, sg = side.sf, _xc(MF, G, shape)
    vg = _xc(MF, G2, shape) - sg * sg / nn
    num = _xc(side.F, G, shape) - sf * sg / nn
    den = np.sqrt(np.maximum(side.vf, 0.0) * np.maximum(vg, 0.0))
    scale = max(float(np.max(den)), 1e-300)
    ok = side.enough & (den > 1e-9 * scale)
    c = np.full(shape, np.nan)
    return np.divide(num, den, out=c, where=ok)


def _at_cubic(c, s):
    """Cubic-spline value of the wrapped map ``c`` at shifts ``s`` (..., 2) = (x, y)
    in samples; NaN where a sample within four of ``s`` is NaN (outside the shifts
    correlated: set to 0 for the spline's prefilter, whose influence falls by 0.27
    a sample, so that it stays below 1 % of the map's values four samples away)."""
    s = np.asarray(s, dtype=float)
    ok = ndimage.minimum_filter(np.isfinite(c), size=9, mode="wrap")
    coords = np.stack([s[..., 1].ravel(), s[..., 0].ravel()])
    vals = ndimage.map_coordinates(np.nan_to_num(c, nan=0.0), coords, order=3,
                                   mode="grid-wrap").reshape(s.shape[:-1])
    near = np.rint(s).astype(int)
    inside = ok[near[..., 1] % c.shape[0], near[..., 0] % c.shape[1]]
    return np.where(inside, vals, np.nan)


def _at(c, s):
    """Bilinear value of the wrapped map ``c`` at shifts ``s`` (..., 2) = (x, y) px."""
    s = np.asarray(s, dtype=float)
    x, y = s[..., 0], s[..., 1]
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    Sy, Sx = c.shape
    out = 0.0
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            out = out + wy * wx * c[(y0.astype(int) + dy) % Sy, (x0.astype(int) + dx) % Sx]
    return out


def _correlate(side: _Side, cur, lattice, phase_shift) -> CoarseEstimate:
    H, W = side.shape
    q = side.q
    cur = cur[side.win]
    b = _band_pass(cur, np.ones(cur.shape, dtype=bool), lattice.pitch, q,
                   weights=side.weights)
    nan = math.nan
    if not (side.usable and np.ptp(b[side.mb]) > 0):
        return CoarseEstimate((0.0, 0.0), (0.0, 0.0), 0.0, nan, nan, nan, False,
                              "the images are too small or uniform once band-passed")
    c = _ncc_map(side, b)
    if not np.any(np.isfinite(c)):
        return CoarseEstimate((0.0, 0.0), (0.0, 0.0), 0.0, nan, nan, nan, False,
                              "no overlap to correlate")
    k = int(np.nanargmax(c))
    iy, ix = np.unravel_index(k, c.shape)
    Sy, Sx = c.shape
    py = iy - Sy if iy > Sy // 2 else iy
    px = ix - Sx if ix > Sx // 2 else ix
    # sub-pixel peak, one parabola per axis (NaN neighbours leave the integer peak)
    sub = []
    for d, (i, S) in enumerate(((ix, Sx), (iy, Sy))):
        lo = c[iy, (i - 1) % S] if d == 0 else c[(i - 1) % S, ix]
        hi = c[iy, (i + 1) % S] if d == 0 else c[(i + 1) % S, ix]
        den = lo - 2 * c[iy, ix] + hi
        sub.append(0.5 * (lo - hi) / den if np.isfinite(den) and den < 0 else 0.0)
    peak = q * np.array([px + sub[0], py + sub[1]])  # px
    P = lattice.periods  # columns a1, a2
    K = lattice.K
    span = np.array([W, H], dtype=float)
    M = math.ceil(float(np.max(span)) / min(lattice.pitches)) + 2
    mm, nn = np.meshgrid(np.arange(-M, M + 1), np.arange(-M, M + 1), indexing="ij")
    # with phases, the candidate nearest to the peak anchors the lattice of candidates
    base = peak if phase_shift is None else \
        phase_shift + P @ np.rint(K @ (peak - phase_shift))
    cands = base[None, None, :] + mm[..., None] * P[:, 0] + nn[..., None] * P[:, 1]
    inside = ((np.abs(cands[..., 0]) < q * (Sx // 2 - 1))
              & (np.abs(cands[..., 1]) < q * (Sy // 2 - 1)))
    at = _at if q == 1 else _at_cubic  # a decimated peak spans few samples: cubic
    vals = np.where(inside, at(c, np.where(inside[..., None], cands, 0.0) / q), np.nan)
    if not np.any(np.isfinite(vals)):
        return CoarseEstimate((0.0, 0.0), tuple(map(float, peak)), 0.0, nan, nan, nan,
                              False, "no candidate within the correlated shifts")
    j = np.unravel_index(int(np.nanargmax(vals)), vals.shape)
    best = float(vals[j])
    near = (np.abs(mm - mm[j]) <= 2) & (np.abs(nn - nn[j]) <= 2)
    near[j] = False
    aliases = vals[near & np.isfinite(vals)]
    alias = float(np.max(aliases)) if aliases.size else nan
    ratio = best / max(alias, 0.01) if aliases.size else nan
    shift = cands[j]
    off = float(np.max(np.abs(K @ (peak - shift)))) if phase_shift is not None else nan
    if best < _MIN_COARSE_CORRELATION:
        ok, why = False, (f"correlation {best:.2f} < {_MIN_COARSE_CORRELATION}: nothing "
                          "but the grid moves with the specimen")
    elif not ratio >= _MIN_PEAK_TO_ALIAS:
        ok, why = False, (f"peak-to-alias ratio {ratio:.2f} < {_MIN_PEAK_TO_ALIAS}: a "
                          "lattice period away correlates almost as well")
    elif phase_shift is not None and not off <= _MAX_DISAGREEMENT:
        ok, why = False, (f"the correlation peak lies {off:.2f} period from every "
                          "displacement the phases allow")
    else:
        ok, why = True, (f"correlation {best:.2f}, peak-to-alias ratio {ratio:.2f}"
                         + (f", {off:.2f} period from the phases"
                            if phase_shift is not None else ""))
    return CoarseEstimate(tuple(float(v) for v in shift), tuple(float(v) for v in peak),
                          best, alias, ratio, off, ok, why)


def _phase_shift(reference: PhaseMaps, deformed: PhaseMaps) -> np.ndarray | None:
    """Rigid displacement the phases give, modulo the lattice, px (None if no pixel).

    The circular mean of each wrapped phase difference over the common valid
    pixels, through eq. (34): ``u = -K^-1 dphi / 2 pi``.
    """
    valid = reference.valid & deformed.valid
    if not valid.any():
        return None
    mean = np.zeros(2, dtype=np.complex128)
    for _, _, z in _phase_products(reference, deformed, valid):
        z /= np.maximum(np.abs(z), 1e-300)
        mean += z.sum(axis=1)
    return -_solve(reference.lattice.K, np.angle(mean)) / (2 * np.pi)


# Pixels per band of rows of _phase_products.
_PRODUCT_BAND = 2**14


def _phase_products(reference: PhaseMaps, deformed: PhaseMaps, valid: np.ndarray):
    """``(rows, v, z)`` band of rows by band of rows: the rows' slice, their pixels of
    ``valid`` (bool), and ``z = Psi_def conj(Psi_ref)`` (2, n) there, complex128,
    whose angle is the wrapped phase difference of eq. (34). The bands' temporaries
    stay in cache; bands without a valid pixel are skipped."""
    H, W = valid.shape
    step = max(1, _PRODUCT_BAND // W)
    for r0 in range(0, H, step):
        rows = slice(r0, r0 + step)
        v = valid[rows]
        if not v.any():
            continue
        z = deformed.psi[:, rows][:, v].astype(np.complex128)
        z *= np.conj(reference.psi[:, rows][:, v])
        yield rows, v, z


# The cubic splines of four maps (both transforms' real and imaginary parts, or the
# four phase derivatives) evaluated at once by gridstrain._spline_kernels (numba, the
# "fast" extra) when installed: loaded on the first correction, never at import.
# False forces scipy's map_coordinates, one map at a time (what runs without numba).
_COMPILED = True


# The compiled loops run on blocks of this many rows (the prefilter's second half on
# blocks of this many columns), on the usable cores. The blocks do not depend on the
# number of cores, nor does the order in which a step's sums are added: the result is
# the same bit for bit on any number of threads.
_BLOCK_ROWS = 64
_BLOCK_COLUMNS = 128


def _by_blocks(n: int, size: int, fn) -> list:
    """``fn(i0, i1)`` for the blocks ``[i0, i1)`` of ``size`` indices that tile
    ``range(n)``, on up to the usable cores (``fn`` must release the GIL: the
    compiled loops do); their results in the blocks' order."""
    blocks = [(i, min(i + size, n)) for i in range(0, n, size)]
    return list(map_bounded(lambda b: fn(*b), blocks,
                            max(min(check_workers(None), len(blocks)), 1)))


@functools.cache
def _load_kernels():
    """The module of compiled spline loops, or None when numba cannot be imported."""
    try:
        from . import _spline_kernels
    except ImportError:
        return None
    return _spline_kernels


class _Spline:
    """Real or complex 2-D maps ``(..., H, W)``, prefiltered once, evaluated together
    at many point sets.

    ``map_coordinates`` with ``prefilter=True`` would filter the whole map again at
    every call, as costly as the evaluation itself; the fixed-point iterations of
    :func:`deformation` evaluate the same deformed maps several times. Four real
    planes (two complex maps, or four real ones) of a cubic spline are prefiltered
    and evaluated by compiled loops when numba is installed, which compute each
    point's weights once for the four (about ten times faster than four
    ``map_coordinates``, the prefilter three to four times faster than
    ``spline_filter``; the same values to rounding within the padding,
    ``tests/test_lagrangian_interpolation.py``). A value that is not finite is
    taken as 0: a NaN would spread over whole rows and columns of coefficients.
    """

    def __init__(self, arr: np.ndarray, order: int | None = None):
        self.order = order = _SPLINE_ORDER if order is None else order
        arr = np.asarray(arr)
        self.lead = arr.shape[:-2]
        self.is_complex = np.iscomplexobj(arr)
        flat = arr.reshape(-1, *arr.shape[-2:])
        planes = [p for a in flat for p in ((a.real, a.imag) if self.is_complex else (a,))]
        Hp, Wp = (n + 2 * _SPLINE_PAD for n in arr.shape[-2:])
        kern = _load_kernels() if _COMPILED and order == 3 and len(planes) == 4 else None
        self.kern = kern
        if kern is not None:
            # interleaved (Hp, Wp, 4): a neighbour's four coefficients in one cache line;
            # read from the maps themselves (a complex map as its real view), not a copy
            self.coef = np.empty((Hp, Wp, 4))
            dt = np.complex128 if self.is_complex else np.float64
            src = np.ascontiguousarray(flat, dtype=dt)
            src = src.view(np.float64) if self.is_complex else src
            coef = self.coef
            _by_blocks(Hp, _BLOCK_ROWS, lambda i0, i1: kern.prefilter_rows(
                src, self.is_complex, _SPLINE_PAD, coef, i0, i1))
            _by_blocks(Wp, _BLOCK_COLUMNS,
                       lambda j0, j1: kern.prefilter_columns(coef, j0, j1))
            return
        self.coef = []
        for p in planes:
            p = np.nan_to_num(p.astype(np.float64), copy=False, nan=0.0, posinf=0.0,
                              neginf=0.0)
            padded = np.pad(p, _SPLINE_PAD, mode="edge")
            self.coef.append(ndimage.spline_filter(padded, order, mode="nearest"))

    def __call__(self, coords: np.ndarray) -> np.ndarray:
        """Values ``(..., *points)`` at ``coords`` (2, *points) = (rows, columns) of
        the unpadded maps."""
        pts = coords.shape[1:]
        if self.kern is not None:
            c = np.asarray(coords, dtype=np.float64).reshape(2, 1, -1) if len(pts) != 2 \
                else np.asarray(coords, dtype=np.float64)
            out = np.empty((4, *c.shape[1:]))
            self.kern.cubic4_at(self.coef, float(_SPLINE_PAD), np.ascontiguousarray(c[0]),
                                np.ascontiguousarray(c[1]), out)
            out = out.reshape(4, *pts)
        else:
            shifted = coords + _SPLINE_PAD
            out = np.stack([ndimage.map_coordinates(c, shifted, order=self.order,
                                                    mode="nearest", prefilter=False)
                            for c in self.coef])
        if self.is_complex:
            out = out[0::2] + 1j * out[1::2]
        return out.reshape(*self.lead, *pts)


def _unwrap(wrapped: np.ndarray, valid: np.ndarray, pairs=None) -> np.ndarray:
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
    fringe, whatever its mean. Otherwise scikit-image runs. ``pairs``: the valid
    neighbours along rows and along columns, when the caller has them.
    """
    # any constant would do for the proof; the circular mean of a subsample centres
    # the map so that a field spread over less than 2 pi shows no jump
    sub = wrapped[::4, ::4][valid[::4, ::4]]
    c = float(np.angle(np.sum(np.exp(1j * sub)))) if sub.size else 0.0
    # s = mod(wrapped - c + pi, 2 pi) - pi, in one buffer
    s = np.subtract(wrapped, c)
    s += np.pi
    np.mod(s, 2 * np.pi, out=s)
    s -= np.pi
    rows, cols = (valid[:, 1:] & valid[:, :-1], valid[1:] & valid[:-1]) if pairs is None \
        else pairs
    jumps = _jumps(s, rows, 1) or _jumps(s, cols, 0)
    if not jumps:
        # wrapped plus whole turns, as scikit-image adds them: rint((s + c - wrapped)
        # / 2 pi) turns, the same operations in s's buffer
        s += c
        s -= wrapped
        s /= 2 * np.pi
        np.rint(s, out=s)
        s *= 2 * np.pi
        s += wrapped
        s[~valid] = 0.0
        return s
    ma = np.ma.masked_array(wrapped, mask=~valid)
    return np.ma.filled(unwrap_phase(ma, rng=0), 0.0)


def _jumps(s: np.ndarray, pairs: np.ndarray, axis: int) -> bool:
    """Whether two neighbours along ``axis`` that ``pairs`` marks differ by pi or more."""
    d = np.diff(s, axis=axis)
    np.abs(d, out=d)
    big = np.greater_equal(d, np.pi)
    del d
    big &= pairs
    return bool(big.any())


def _solve(K: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``K^-1 r`` for a 2x2 ``K`` and ``r`` of shape (2, ...)."""
    return np.tensordot(np.linalg.inv(K), r, axes=1)


class _Handover:
    """A guess field handed over to :func:`deformation`, which drops it once the
    fringe order is fixed: a field passed as a plain argument would stay referenced
    by the caller's call until :func:`deformation` returns (a whole (2, H, W) map
    through the large-displacement correction, the most memory of the kinematics)."""

    def __init__(self, field):
        self._field = field

    def take(self):
        field, self._field = self._field, None
        return field


def _guess_field(guess, reference, deformed, images):
    """The guess as a (2, H, W) field (a constant one broadcast), its source, and
    the coarse estimate (or None)."""
    shape = reference.shape
    if isinstance(guess, _Handover):
        guess = guess.take()
    zero = np.broadcast_to(np.zeros((2, 1, 1)), (2, *shape))
    if isinstance(guess, str):
        if guess != "auto":
            raise ValueError(f"guess must be 'auto', None, a (u_x, u_y) pair or a (2, H, W) "
                             f"field, got {guess!r}")
        if images is None:
            raise ValueError("guess='auto' needs the images; pass a guess with phase maps")
        ref_img, cur_img, mask = images
        est = coarse_displacement(ref_img, cur_img, reference.lattice, mask=mask,
                                  phase_shift=_phase_shift(reference, deformed))
        if est.confident:
            shift = np.array(est.shift)
            return np.broadcast_to(shift[:, None, None], (2, *shape)), "auto", est
        return zero, "zero", est
    if guess is None:
        return zero, "zero", None
    g = np.asarray(guess, dtype=float)
    if g.shape == (2,):
        g = np.broadcast_to(g[:, None, None], (2, *shape))
    elif g.shape != (2, *shape):
        raise ValueError(f"guess must be a (u_x, u_y) pair or a field of shape "
                         f"{(2, *shape)}, got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError("guess must be finite")
    return g, "user", None


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
        Stop when the RMS error left in ``u`` over the valid pixels, bounded from
        the last step (see Notes), falls below ``tol`` px.
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
    period. The iterations start from the first-order solution with the deformed
    state's derivatives at ``X``, ``(2 pi K + D_def(X)) u = 2 pi K u_0`` with ``u_0``
    eq. (34) at ``X``, and each one multiplies the error by at most ``q``, the largest
    norm of ``(2 pi K)^-1 D_def`` (about the largest displacement gradient): they stop once
    ``q / (1 - q)`` times the RMS of the last step, a bound on the error left, is
    below ``tol`` (one or two iterations at strains of 1e-3). The strain then comes
    from the exact Lagrangian gradient
    ``G = (2 pi K + D_def(X + u))^-1 (D_ref - D_def(X + u))``, with ``D`` the 2x2
    phase-derivative matrices; to first order this is eq. (35),
    ``G = -(1/2pi) K^-1 (D_def - D_ref)``, which is what is used without the
    correction.
    """
    check_type(reference, "reference", PhaseMaps)
    check_type(deformed, "deformed", PhaseMaps)
    check_same_shape(deformed.shape, reference.shape, "deformed maps", "the reference")
    if reference.lattice != deformed.lattice:
        raise ValueError("reference and deformed maps must use the same lattice")
    tol = check_positive(tol, "tol")
    max_iter = check_int(max_iter, "max_iter")

    lattice = reference.lattice
    K = lattice.K
    g, source, coarse = _guess_field(guess, reference, deformed, _images)
    del guess  # g is the caller's field when one is given: not kept past the start
    valid = reference.valid & deformed.valid & np.all(np.isfinite(reference.dphi), axis=(0, 1))
    start = [_unwrapped_displacement(reference, deformed, valid, K, g)]
    gmed, order = _fringe_order_record(g, source, coarse)
    del g  # only its median is kept: a (2, H, W) field less in memory from here on

    iterations, step = 0, 0.0
    D_ref = reference.dphi.astype(np.float64, copy=False)
    if lagrangian:
        # the starting field is handed over, not kept here: the first step frees it
        u, iterations, step = _lagrangian_fixed_point(start.pop(), reference, deformed,
                                                      valid, tol, max_iter)
        G, valid = _lagrangian_gradient(u, reference, deformed, D_ref)
    else:
        u = start.pop()
        G = _eulerian_gradient(K, deformed.dphi.astype(np.float64) - D_ref)
    del D_ref

    # computed in float64, returned in the maps' precision (gridstrain.conventions)
    dt = np.result_type(reference.dphi.dtype, deformed.dphi.dtype)
    strain, rotation = _small_strain(G), 0.5 * (G[1, 0] - G[0, 1])
    del G
    u, strain, rotation = _outside_nan(valid, dt, u, strain, rotation)
    return Measurement(u=u, strain=strain, rotation=rotation, valid=valid, lattice=lattice,
                       sigma=reference.sigma, lagrangian=bool(lagrangian),
                       iterations=iterations, step_rms=step, guess=gmed,
                       guess_source=source, reference=reference, deformed=deformed,
                       fringe_order=order)


def _eulerian_gradient(K: np.ndarray, dD: np.ndarray) -> np.ndarray:
    """Displacement gradient (2, 2, ...) from the change ``dD`` (2, 2, ...) of the
    phase derivatives, without the large-displacement correction (eq. 35)."""
    return -_solve(K, dD) / (2 * np.pi)


def _small_strain(G: np.ndarray) -> np.ndarray:
    """The small-strain tensor ``(e_xx, e_yy, e_xy)`` (3, ...) of the gradient ``G``
    (2, 2, ...), tensor shear (:mod:`gridstrain.conventions`)."""
    return np.stack([G[0, 0], G[1, 1], 0.5 * (G[0, 1] + G[1, 0])])


def _outside_nan(valid, dtype, *maps):
    """The ``maps`` (fresh float64 arrays, changed in place) NaN outside ``valid``, in
    ``dtype``."""
    invalid = ~valid
    for a in maps:
        a[..., invalid] = np.nan
    return tuple(a.astype(dtype, copy=False) for a in maps)


def _unwrapped_displacement(reference, deformed, valid, K, g) -> np.ndarray:
    """(2, H, W) displacement of eq. (34) from the unwrapped phase difference, each
    connected valid region shifted by the whole periods that bring it closest to
    the guess ``g`` ((2, H, W), px)."""
    # one wave vector at a time: a complex product of (H, W), not of (2, H, W)
    dphase = np.empty(reference.psi.shape, dtype=np.float64)
    for j in range(2):
        dphase[j] = np.angle(deformed.psi[j] * np.conj(reference.psi[j]))
    labels, n_regions = ndimage.label(valid)
    if n_regions == 0:
        raise ValueError("no valid pixel: the image is smaller than the window and its "
                         "margin, or the mask leaves nothing")
    pairs = (valid[:, 1:] & valid[:, :-1], valid[1:] & valid[:-1])  # both maps' jump checks
    for j in range(2):  # unwrapped in place
        dphase[j] = _unwrap(dphase[j], valid, pairs)
    # fringe order per connected region, closest to the guess. By eq. (34) the
    # unwrapped phase in periods is -dphase / 2 pi = K u: the whole periods n that
    # bring K (u - g) closest to 0 are taken on it, and added back as dphase + 2 pi n
    # (u -> u - K^-1 n) before the one solve
    constant = g.strides[1:] == (0, 0)  # a (u_x, u_y) pair broadcast: K g once
    kg = K @ g[:, 0, 0] if constant else None
    for lab in range(1, n_regions + 1):
        sel = valid if n_regions == 1 else labels == lab
        n = np.empty(2)
        for j in range(2):
            t = dphase[j][sel]  # a fresh gather, sorted in place by the median
            t *= -1 / (2 * np.pi)
            if constant:
                n[j] = np.rint(median(t, overwrite_input=True) - kg[j])
            else:
                t -= K[j, 0] * g[0][sel] + K[j, 1] * g[1][sel]
                n[j] = np.rint(median(t, overwrite_input=True))
            del t
        for j in range(2):
            if n[j]:
                dphase[j][sel] += 2 * np.pi * n[j]
    u = _solve(K, dphase)
    del dphase
    np.negative(u, out=u)
    u /= 2 * np.pi
    return u


def _lagrangian_fixed_point(u, reference, deformed, valid, tol, max_iter):
    """Solve ``u(X) = -(1/2pi) K^-1 (phi_def(X + u) - phi_ref(X))`` by fixed point
    from ``u`` (eq. 34 at ``X``), the residual wrapped at every step; returns ``u``,
    the number of iterations and the RMS of the last step over the valid pixels, px.

    The start is the first-order (Newton) solution with the deformed state's
    derivatives at ``X``, ``(2 pi K + D_def(X)) u = 2 pi K u_0``: pointwise, no
    interpolation, and closer than ``u_0`` by about the strain (the error left is
    the change of ``D_def`` between ``X`` and ``X + u``: 4e-3 px RMS for an 11 px
    displacement of a noisy 12-bit pair, against 3e-2 px from ``u_0``). A step
    ``du = -(2 pi K)^-1 r`` takes the error ``e`` to ``-M e``, ``M = (2 pi K)^-1
    D_def`` between the two points, so ``|e| <= q / (1 - q) |du|`` after it, with ``q``
    the largest norm of ``M`` over the deformed state's valid pixels (about the
    largest displacement gradient): the iterations stop once that bound, as an RMS,
    is below ``tol``, or, where ``q >= 1`` (no contraction is known), once the step
    is.
    """
    shape = reference.shape
    K = reference.lattice.K
    two_pi_K = 2 * np.pi * K
    psi_cur = _Spline(deformed.psi)  # both wave vectors' maps, evaluated together
    nv = max(int(valid.sum()), 1)
    if psi_cur.kern is not None:  # the start and each step in one compiled loop
        kern = psi_cur.kern
        start = np.empty((2, *shape))
        u0 = np.ascontiguousarray(u, dtype=np.float64)
        d = np.ascontiguousarray(deformed.dphi, dtype=np.float64)
        cur_valid = np.ascontiguousarray(deformed.valid)
        m_of_d = np.linalg.inv(two_pi_K)
        a_med = _median_start(deformed, two_pi_K)
        q = max(_by_blocks(shape[0], _BLOCK_ROWS, lambda i0, i1: kern.newton_start(
            u0, d, cur_valid, two_pi_K, m_of_d, a_med, start, i0, i1)))
        u = start
        # the reference's maps as they are (their real view), unless they are complex64
        ref = np.ascontiguousarray(reference.psi, dtype=np.complex128).view(np.float64)
        solve = np.ascontiguousarray(-np.linalg.inv(K) / (2 * np.pi))

        def one_step():
            # the blocks' sums added in the blocks' order, whatever the threads
            return math.fsum(_by_blocks(shape[0], _BLOCK_ROWS, lambda i0, i1:
                                        kern.fixed_point_step(psi_cur.coef, float(_SPLINE_PAD),
                                                              u, ref, two_pi_K, solve, valid,
                                                              i0, i1)))
    else:
        u = _newton_start(u, deformed, two_pi_K)
        q = _contraction(deformed, K)
        yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
        conj_ref = np.conj(reference.psi.astype(np.complex128, copy=False))
        coords = np.empty((2, *shape))
        r = np.empty_like(u)

        def one_step():
            np.add(yy, u[1], out=coords[0])
            np.add(xx, u[0], out=coords[1])
            at = psi_cur(coords)
            for j in range(2):
                # residual phi_def(X + u) - phi_ref(X) + 2 pi k.u, wrapped to (-pi, pi]:
                # the carrier's phase added as a real number rather than as exp(i .)
                r[j] = np.angle(at[j] * conj_ref[j])
                r[j] += two_pi_K[j, 0] * u[0] + two_pi_K[j, 1] * u[1]
                r[j] = np.pi - np.mod(np.pi - r[j], 2 * np.pi)
            du = -_solve(K, r) / (2 * np.pi)
            du[:, ~valid] = 0.0
            u[...] += du
            return float(np.sum(du * du))

    gain = q / (1.0 - q) if q < 1.0 else 1.0
    iterations, step = 0, 0.0
    for iterations in range(1, max_iter + 1):  # noqa: B007
        step = math.sqrt(one_step() / nv)
        if gain * step < tol:
            break
    return u, iterations, step


def _median_start(deformed, two_pi_K) -> np.ndarray:
    """``(2 pi K + D_med)^-1 2 pi K`` (2, 2), ``D_med`` the median of the deformed
    state's phase derivatives over its valid pixels: the start's linear map for the
    field's mean gradient. A rotation of 10 degrees moves ``X + u`` by 0.17 |u| from
    the Eulerian start, half a period at 15 px from the centre: the start must take
    the mean gradient in wherever the local derivatives cannot be trusted."""
    v = deformed.valid
    D = np.zeros((2, 2))
    if v.any():
        for a in range(2):
            for b in range(2):
                D[a, b] = median(deformed.dphi[a, b][v].astype(np.float64),
                                 overwrite_input=True)
    A = np.linalg.solve(two_pi_K + D, two_pi_K)
    return A if np.all(np.isfinite(A)) else np.eye(2)


def _newton_start(u0, deformed, two_pi_K):
    """``(2 pi K + D_def(X))^-1 2 pi K u0``, pointwise; where the deformed state is
    valid at ``X`` but that start differs by more than a tenth of a period from the
    one with the median derivatives (:func:`_median_start`), the latter (a
    derivative spoilt by a low modulus must not move the start towards another
    fringe order); ``u0`` where the deformed state is not valid."""
    a_med = _median_start(deformed, two_pi_K)
    m0 = a_med[0, 0] * u0[0] + a_med[0, 1] * u0[1]
    m1 = a_med[1, 0] * u0[0] + a_med[1, 1] * u0[1]
    D = deformed.dphi.astype(np.float64, copy=False)
    b0 = two_pi_K[0, 0] * u0[0] + two_pi_K[0, 1] * u0[1]
    b1 = two_pi_K[1, 0] * u0[0] + two_pi_K[1, 1] * u0[1]
    a00 = two_pi_K[0, 0] + D[0, 0]
    a01 = two_pi_K[0, 1] + D[0, 1]
    a10 = two_pi_K[1, 0] + D[1, 0]
    a11 = two_pi_K[1, 1] + D[1, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        rdet = 1.0 / (a00 * a11 - a01 * a10)
        u = np.stack([(a11 * b0 - a01 * b1) * rdet, (a00 * b1 - a10 * b0) * rdet])
        # the change along each wave vector, in periods
        c0 = (two_pi_K[0, 0] * (u[0] - m0) + two_pi_K[0, 1] * (u[1] - m1)) / (2 * np.pi)
        c1 = (two_pi_K[1, 0] * (u[0] - m0) + two_pi_K[1, 1] * (u[1] - m1)) / (2 * np.pi)
        keep = (np.abs(c0) < 0.1) & (np.abs(c1) < 0.1)
    return np.where(deformed.valid, np.where(keep, u, np.stack([m0, m1])), u0)


def _contraction(deformed, K) -> float:
    """Largest Frobenius norm (a bound on the 2-norm) of ``(2 pi K)^-1 D_def`` over
    the deformed state's valid pixels: the fixed point's contraction factor."""
    v = deformed.valid
    if not v.any():
        return 0.0
    D = deformed.dphi[:, :, v].astype(np.float64)
    M = _solve(K, D) / (2 * np.pi)
    q = float(np.sqrt(np.max(np.sum(M * M, axis=(0, 1)))))
    return q if math.isfinite(q) else math.inf


def _lagrangian_gradient(u, reference, deformed, D_ref):
    """Exact Lagrangian displacement gradient ``G`` ((2, 2, H, W)) with the deformed
    state's derivatives taken at ``X + u``, and the pixels valid in both states."""
    shape = reference.shape
    K = reference.lattice.K
    # Where Psi is exactly 0 (deep in a masked area) its derivatives are undefined;
    # a spline's prefilter would spread one NaN over whole rows: the spline takes them
    # as zeros (the pixels are invalid anyway)
    spline = _Spline(deformed.dphi)  # the four derivatives, evaluated together
    if spline.kern is not None:  # one compiled loop: validity, derivatives and G
        G = np.empty((2, 2, *shape))
        valid = np.empty(shape, dtype=bool)
        args = (spline.coef, float(_SPLINE_PAD), np.ascontiguousarray(u, dtype=np.float64),
                np.ascontiguousarray(deformed.valid), np.ascontiguousarray(reference.valid),
                np.ascontiguousarray(D_ref, dtype=np.float64), 2 * np.pi * K, G, valid)
        _by_blocks(shape[0], _BLOCK_ROWS,
                   lambda i0, i1: spline.kern.lagrangian_gradient(*args, i0, i1))
        return G, valid
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    coords = np.stack([yy + u[1], xx + u[0]])
    inside = ((coords[0] >= 0) & (coords[0] <= shape[0] - 1)
              & (coords[1] >= 0) & (coords[1] <= shape[1] - 1))
    cur_valid = ndimage.map_coordinates(deformed.valid.astype(np.float64), coords,
                                        order=1, mode="constant", cval=0.0)
    valid = reference.valid & inside & (cur_valid > 0.999)
    D_cur = spline(coords)
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
    return G, valid


def _fringe_order_record(g, source, coarse):
    """The guess's median ``(u_x, u_y)`` and the FringeOrder record of how the fringe
    order was chosen."""
    if source == "zero":
        gmed = (0.0, 0.0)
    elif g.strides[1:] == (0, 0):  # one displacement, broadcast: its value
        gmed = (float(g[0, 0, 0]), float(g[1, 0, 0]))
    else:
        gmed = tuple(float(np.median(c)) for c in g)
    if source == "user":
        order = FringeOrder("user", True, gmed, "the given guess")
    elif source == "auto":
        order = _from_estimate(coarse, "image features", True, gmed, coarse.reason)
    elif coarse is not None:
        order = _from_estimate(coarse, "smallest displacement", False, gmed,
                               f"image features undecided ({coarse.reason})")
    else:
        order = FringeOrder("smallest displacement", False, gmed, "guess=None")
    return gmed, order


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
        Initial displacement fixing the fringe order. ``"auto"`` uses the images'
        features (:func:`coarse_displacement`) when they are conclusive and falls
        back to the smallest displacement the phases allow otherwise;
        :attr:`Measurement.fringe_order` says which, and whether it is confirmed.
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
    check_same_shape(cur.shape, ref.shape, "deformed", "reference")
    m = check_mask(mask, ref.shape)
    if check_type(lattice, "lattice", Lattice, allow_none=True) is None:
        lattice = detect_lattice(ref, mask=m)
    pm_ref = wft(ref, lattice, sigma=sigma, mask=m, margin=margin, workers=None)
    # the deformed specimen has moved: its mask is not the reference's, so the
    # deformed image is transformed whole and validity comes from its own moduli; at
    # its own carrier, a window off it biases the phase where the grid's amplitude
    # varies (gridstrain.wft.demodulated_at)
    carrier = _state_carrier(cur, lattice, _reference_carrier(ref, lattice))
    pm_cur = wft(cur, carrier, sigma=pm_ref.sigma, margin=margin, workers=None)
    if carrier is not lattice:
        pm_cur = demodulated_at(pm_cur, lattice)
    return deformation(pm_ref, pm_cur, lagrangian=lagrangian, guess=guess,
                       _images=(ref, cur, m))
