"""The fringe order of a displacement (the whole number of periods the phases cannot see):
how it was fixed (:class:`FringeOrder`) and the image-feature estimate that can fix it
(:func:`coarse_displacement`: band-passed normalised cross-correlation of the two images
against the aliases one or two periods away; where it cannot decide, the content below
the grid's frequency compared at whole-period offsets, :mod:`._grid_free`).
"""

from __future__ import annotations

import dataclasses
import math
import weakref
from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft
from scipy import ndimage

from .._validation import (
    as_image,
    as_pair,
    check_mask,
    check_same_shape,
    check_type,
)
from ..phase import Lattice, PhaseMaps, filled_box
from ..uncertainty import nearest_index
from ._grid_free import (
    ContentOrder,
    _gaussian_at,
    decimation,
    field_from_phases,
    gradient,
    grid_free,
    order_from_content,
    smooth_decimate,
)

__all__ = ["FRINGE_ORDER_SOURCES", "CoarseEstimate", "FringeOrder", "coarse_displacement",
           "grid_shows"]

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


# ... and on its band-passed images decimated by the largest integer q <= pitch / 2
# that leaves at least this many samples per side. The band stops at about
# 0.8 / pitch (the difference of Gaussians keeps 9 % of its peak there) and the
# narrow Gaussian, applied before decimating, leaves 4e-4 of what lies at the new
# Nyquist frequency 1 / (2 q) >= 1 / pitch: the grid's fundamental is not folded
# back into the band, nothing the band holds is lost, and the correlation costs q^2
# times less (a record's small frames included). The verdicts and their figures are
# those of full resolution from 128 px images up (tests/test_fringe_order.py).
_COARSE_MIN_SAMPLES = 64


# The best candidate must correlate this many times better than any alias a lattice
# period or two away. Measured (160-px images, 0.1 % noise, 40 % vignette): grids and
# sharp rotated checkerboards with nothing else, moved by 0 to 13 px, 1.00 to 1.18;
# sixty printed spots moving with the specimen 2.2 to 3.2, a hole's edge 2.0.
_MIN_PEAK_TO_ALIAS = 1.5


# Features that correlate at the pitch this many times better than their aliases are
# sharper than a lamp's light. A smooth bump of light of std s, band-passed between
# half a pitch and a pitch, correlates with itself a period p away by about
# exp(-p^2 / (4 s^2)): 2.5 times less only for s <= 0.52 p, a hot spot half a pitch
# wide (a focused beam, not a lamp's). Measured: hot spots of std 4 to 25 px moved by
# a lattice vector at pitches 5 and 6.4, 1.0 to 2.3; printed spots of 1 to 2.5 px,
# 2.7 to 3.8.
_SHARP_PEAK_TO_ALIAS = 2.5


def sharp(est: CoarseEstimate) -> bool:
    """Whether the image features ``est`` are too sharp at the pitch to be light
    (:data:`_SHARP_PEAK_TO_ALIAS`): content printed on or lying on the specimen."""
    return est.confident and not math.isnan(est.disagreement) and \
        est.peak_to_alias >= _SHARP_PEAK_TO_ALIAS and not est.tiles[1]


# The correlation peak must lie within this fraction of a period (along each wave
# vector) of the candidate the phases allow: the peak is good to a pixel, a quarter
# of a 4-px pitch.
_MAX_DISAGREEMENT = 0.25


#: How a fringe order can be fixed (:attr:`FringeOrder.source`).
FRINGE_ORDER_SOURCES = ("previous state", "image features", "user", "smallest displacement")


# A small step, or image features compared as one rigid shift, tie the whole periods of
# the pixels they are taken on only as far as continuity reaches: where the invalid pixels
# cut the valid ones into parts (a band where the grid's modulus fell: a gradient too
# steep for the window, a tear not declared), each part may be whole periods from the
# others (a rise of a period across the band reads as none on either side, and the
# features' shift is the larger part's). The order is confirmed only when one part
# (8-connected) holds this share of the valid pixels: specks cut off by the noise, a
# hundredth of them at most, cannot make a state wrong on more than that.
_TIED = 0.99


def cut_into_parts(valid: np.ndarray) -> str:
    """Why one whole number of periods found for ``valid``'s pixels does not hold for all
    of them (no part holds :data:`_TIED` of them), or "" when it does."""
    if filled_box(valid) is not None:  # a rectangle is one part: no labels needed
        return ""
    labels, n = ndimage.label(valid, structure=np.ones((3, 3), dtype=bool))
    if n <= 1:
        return ""
    sizes = np.bincount(labels.ravel())[1:]
    largest = int(sizes.max())
    if largest >= _TIED * int(sizes.sum()):
        return ""
    return (f"the valid pixels fall into {n} parts (the largest holds "
            f"{largest / sizes.sum():.0%} of them), parted by invalid bands where the "
            "grid's modulus fell (a gradient too steep for the window or a tear): what "
            "fixes the whole periods of one part does not tie the others to it")


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
        phases (a candidate whole periods from the phases' smallest displacement
        shown by the grid's own modulus as well: a highlight or hot spot that moved
        imitates the specimen in the image's light); or tracking from a confirmed
        previous state with an increment below ``_MAX_STEP`` periods everywhere (a
        step that is plausibly less than half a period; the first state of a series
        from the reference within ``SMALL_STEP``), not contradicted by image
        features, and over valid pixels that hold together (a field that bands of
        invalid pixels part, where a gradient too steep for the window or a tear
        dimmed the grid, may have each part whole periods from the others: not
        confirmed). Where two kinds of evidence disagree the state is not confirmed.
        A state not confirmed may be one or more periods off.
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
    residual_ratio : float
        Of the image content below the grid's frequency compared at whole-period
        offsets (:class:`CoarseEstimate`), NaN when not made.
    tiles_agreeing, tiles_informative : int
        Of that comparison: the tiles whose content decides, and those of them that
        pick the order taken.
    strain_if_off : float
        For a state not confirmed, how far its strain may be off as well: with the
        large-displacement correction, a displacement a period ``a`` off reads the
        deformed phases a period away, and the strain reported at ``X`` is, to first
        order, the strain at ``X + a``; this is the 95th percentile over the valid
        pixels of ``max |(a . grad) e|`` over the two lattice periods and the three
        components (dimensionless; 0 without the correction; NaN when confirmed).
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
    residual_ratio: float = math.nan
    tiles_agreeing: int = 0
    tiles_informative: int = 0
    strain_if_off: float = math.nan

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
                "step_periods": num(self.step),
                "residual_ratio": num(self.residual_ratio),
                "tiles_agreeing": int(self.tiles_agreeing),
                "tiles_informative": int(self.tiles_informative),
                "strain_if_off_by_a_period": num(self.strain_if_off)}


def _from_estimate(est, source, confirmed, guess, detail, step=math.nan) -> FringeOrder:
    """A :class:`FringeOrder` carrying the figures of a coarse estimate (or none)."""
    if est is None:
        return FringeOrder(source, confirmed, guess, detail, step=step)
    return FringeOrder(source, confirmed, guess, detail, correlation=est.correlation,
                       peak_to_alias=est.peak_to_alias, disagreement=est.disagreement,
                       features_shift=est.shift, step=step,
                       residual_ratio=est.residual_ratio, tiles_agreeing=est.tiles[0],
                       tiles_informative=est.tiles[1])


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
    residual_ratio : float
        When the correlation at the pitch could not decide and the phases were
        given: the content below the grid's frequency compared at whole-period
        offsets (:mod:`gridstrain.kinematics._grid_free`), the residual of the
        second-best offset over the best's; NaN when not made.
    tiles : (2,) tuple of int
        Of that comparison: tiles agreeing with the order taken, informative tiles.
    light_doubt : str
        Where the estimate puts the displacement whole periods from the phases' and
        the grid's modulus shows them but its harmonics' ratio cannot tell (a hot spot of the
        lamp that moved imitates a stain): why the order it gives is not confirmed;
        empty otherwise.
    """

    shift: tuple[float, float]
    peak: tuple[float, float]
    correlation: float
    alias_correlation: float
    peak_to_alias: float
    disagreement: float
    confident: bool
    reason: str
    residual_ratio: float = math.nan
    tiles: tuple[int, int] = (0, 0)
    light_doubt: str = ""


def coarse_displacement(reference, deformed, lattice: Lattice, *, mask=None,
                        phase_shift=None, region=None) -> CoarseEstimate:
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
    region : (H, W) bool array_like, optional
        A part of the reference that moves on its own (one side of a crack): its
        content alone is correlated (within ``mask``), and the whole images are
        never tried in its stead, so that the estimate is this part's evidence.

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
    if region is not None:
        part = _CoarseReference(ref, lattice, m & check_mask(region, ref.shape, "region"))
        return _correlate(part.side(False), cur, lattice, phase_shift)
    return _CoarseReference(ref, lattice, m).estimate(cur, phase_shift)


# A record's states whose content decided nothing before the comparison is made only
# every _RECHECK states: a reference holding nothing but the grid never decides, and
# the comparison is most of a small state's cost.
_FUTILE = 3
_RECHECK = 8


class _Contents:
    """What a function makes of an image or a state's transforms (a content map at the
    samples), kept while the same object is asked for again: a state's image features
    and its check once warped back compare the same two images and transforms, and the
    reference's stay for every state. Two objects a function (the reference's and the
    latest state's), each held by a weak reference: an object freed is never taken for
    another one at its address, and nothing is kept alive for the memo's sake."""

    def __init__(self):
        self._kept: dict = {}

    def __call__(self, make, obj, *args):
        kept = self._kept.setdefault(make, [])
        for ref, given, out in kept:
            if ref() is obj and given == args:
                return out
        out = make(obj, *args)
        kept.insert(0, (weakref.ref(obj), args, out))
        del kept[2:]
        return out


def _made(memo, make, obj, *args):
    """``make(obj, *args)``, from ``memo`` (:class:`_Contents`) when one is given."""
    return make(obj, *args) if memo is None else memo(make, obj, *args)


class _CoarseReference:
    """The reference's side of :func:`coarse_displacement` (its band-passed image,
    masks and transforms), computed once and used for every deformed image of a
    run: what depends on the reference alone is not recomputed per state."""

    def __init__(self, reference: np.ndarray, lattice: Lattice, mask: np.ndarray):
        self.reference = np.asarray(reference, dtype=np.float64)
        self.lattice, self.mask = lattice, mask
        self._sides: dict[bool, _Side] = {}
        self._gf = None
        # states in a row whose content below the grid's frequency decided nothing
        # (no tile informative), and the states decided since the last comparison
        self._futile = self._since = 0
        self._contents = _Contents()

    def side(self, whole: bool) -> _Side:
        if whole not in self._sides:
            m = np.ones_like(self.mask) if whole else self.mask
            self._sides[whole] = _reference_side(self.reference, self.lattice, m)
        return self._sides[whole]

    def grid_free(self):
        """The reference's image below the grid's frequency and its sampling, px."""
        if self._gf is None:
            q = decimation(self.lattice)
            self._gf = (grid_free(self.reference, self.lattice, q), q)
        return self._gf

    def content(self, deformed: np.ndarray, u: np.ndarray, ok: np.ndarray,
                gradient=None) -> ContentOrder:
        """:func:`order_from_content` of ``deformed`` with the field ``u`` (2, h, w)
        and ``ok`` at the reference's grid-free samples."""
        ref, q = self.grid_free()
        return order_from_content(ref, self._contents(grid_free, deformed, self.lattice, q),
                                  u, ok, self.lattice, q, gradient=gradient)

    def decide(self, deformed: np.ndarray, reference: PhaseMaps,
               current: PhaseMaps) -> CoarseEstimate:
        """The image-feature estimate of ``deformed`` against the reference, with the
        phases' maps of both: the correlation at the pitch (:meth:`estimate`) and,
        where it cannot decide, the content below the grid's frequency compared at
        whole-period offsets of the phases' field."""
        # the phases are smooth over the window (about a pitch): sampled every q px,
        # their products hold what the rigid shift and the field need
        q = decimation(self.lattice)
        ok = reference.valid[::q, ::q] & current.valid[::q, ::q]
        if not ok.any():
            return self.estimate(deformed, None)
        ref_psi = reference.psi[:, ::q, ::q].astype(np.complex128)
        z = current.psi[:, ::q, ::q] * np.conj(ref_psi)
        mean = (z / np.maximum(np.abs(z), 1e-300))[:, ok].sum(axis=1)
        phases = -solve_k(self.lattice.K, np.angle(mean)) / (2 * np.pi)
        est = self.estimate(deformed, phases)
        field = None
        if est.confident:
            if not np.any(np.rint(self.lattice.K @ (np.array(est.shift) - phases))):
                return est  # the order the phases give: nothing moved by whole periods
            field = field_from_phases(z, ok, self.lattice)
            return self._corroborated(est, reference, current, field, ok, est.shift,
                                      None if sharp(est) else deformed)
        if self._futile >= _FUTILE and self._since < _RECHECK:
            # a record on a reference with nothing but the grid: its content has
            # decided nothing state after state, and compared again every _RECHECK
            # states (content may come into the compared region as the specimen moves)
            self._since += 1
            return dataclasses.replace(
                est, reason=f"{est.reason}; below the grid's frequency: nothing decided "
                            f"in the last {self._futile} states compared")
        u = field_from_phases(z, ok, self.lattice) if field is None else field
        c = self.content(deformed, u, ok, gradient=gradient(u, q))
        self._futile = self._futile + 1 if c.tiles_informative == 0 else 0
        self._since = 0
        tiles = (c.tiles_agreeing, c.tiles_informative)
        if c.confident:
            found = dataclasses.replace(
                est, shift=c.shift, confident=True, residual_ratio=c.residual_ratio,
                tiles=tiles, reason=f"{c.reason} (at the pitch: {est.reason})")
            if not any(c.offset):
                return found
            return self._corroborated(found, reference, current, u, ok, c.shift, deformed)
        return dataclasses.replace(est, residual_ratio=c.residual_ratio, tiles=tiles,
                                   reason=f"{est.reason}; below the grid's frequency: "
                                          f"{c.reason}")

    def evidence(self, reference: PhaseMaps, current: PhaseMaps, u: np.ndarray,
                 ok: np.ndarray, periods, *, material: bool = False,
                 image=None) -> tuple[bool, str, str]:
        """:func:`_grid_evidence` with ``u`` and ``ok`` at this reference's samples, and
        the ratio of the grid's harmonics in this reference and the deformed ``image``
        when given: ``(shown, said, doubt)``, whether the grid's modulus shows the whole
        ``periods`` (and nothing the light cannot imitate puts them elsewhere), what it
        says, and why that is no confirmation where only the light's evidence shows
        them (empty otherwise)."""
        return _grid_evidence(reference, current, u, ok, periods, material=material,
                              images=None if image is None else (self.reference, image),
                              memo=self._contents)

    def _corroborated(self, est: CoarseEstimate, reference: PhaseMaps, current: PhaseMaps,
                      u: np.ndarray, ok: np.ndarray, shift, deformed=None) -> CoarseEstimate:
        """``est``, which puts the displacement whole periods from the order the phases
        give (``shift``, px), kept confident only when the grids' own moduli show the
        same whole periods and the ratio of their harmonics in the images
        (``deformed`` the current one, None for features too sharp to be light:
        :func:`sharp`) does not put them elsewhere (:func:`grid_shows`); where that
        ratio cannot tell, ``light_doubt`` says so: the order may be used, not
        confirmed.

        The image's light is the specimen's reflectance times the lighting, plus what
        its surface reflects: a lamp's hot spot or a specular highlight that moved by
        about a lattice vector is read as the specimen moving by whole periods. The
        grid's modulus, demodulated at the grid's frequency, does not carry what the
        surface reflects (smooth, it adds nothing at that frequency) and carries what is
        printed or lies on the specimen (it multiplies the grid): a whole-period shift
        that is the specimen's shows in it too. A lamp's hot spot multiplies the grid as
        well, as a stain would, and its highlight comes with it: only the ratio of the
        grid's second harmonic to its first, which no light changes
        (:func:`_light_free`), tells the specimen's content from the light's."""
        # the whole periods ``shift`` adds to the field ``u``, at its median
        v = u[:, ok]
        med = np.array([np.median(c) for c in v])
        same, seen, doubt = _grid_evidence(
            reference, current, u, ok, self.lattice.K @ (np.array(shift) - med),
            images=None if deformed is None else (self.reference, deformed),
            memo=self._contents)
        if same:
            return dataclasses.replace(est, reason=f"{est.reason}; {seen}",
                                       light_doubt=doubt)
        return dataclasses.replace(
            est, confident=False,
            reason=f"the image's light puts the displacement whole periods from the "
                   f"phases' smallest ({shift[0]:.2f}, {shift[1]:.2f} px: {est.reason}) but "
                   f"{seen}: it may be light that moved (a hot spot, a highlight), not the "
                   f"specimen")

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


def grid_shows(reference: PhaseMaps, deformed: PhaseMaps, u, valid, periods, *,
               within=None, images=None) -> tuple[bool, str]:
    """Whether the grid's own modulus shows a displacement whole periods from ``u``.

    Image features that put a displacement whole periods away may follow the light
    rather than the specimen: a lamp's hot spot or a specular highlight that moved by
    about a lattice vector. The grid's modulus, demodulated at the grid's frequency,
    carries what multiplies the grid (what is printed on or lies on the specimen, a
    hole's or an edge's collapse of the grid) and not what the surface reflects (a
    smooth highlight adds nothing at the grid's frequency). The moduli of the two
    states are compared as the image's content is below the grid's frequency
    (:mod:`gridstrain.kinematics._grid_free`), the deformed one read at ``X + u(X) +
    m a1 + n a2``.

    Parameters
    ----------
    reference, deformed : PhaseMaps
        The two states' maps (their ``psi``).
    u : (2, H, W) array_like
        The measured displacement, px, Lagrangian (at the material point).
    valid : (H, W) bool array_like
        Where ``u`` holds; elsewhere it is carried from the nearest valid pixel to
        first order (its value plus its gradient times the way there).
    periods : (2,) array_like
        The whole periods ``(m, n)`` to test, added to ``u``.
    within : (H, W) bool array_like, optional
        The pixels whose content is compared (default: every pixel).
    images : ((H, W), (H, W)) array_like, optional
        The two states' images. Given, the ratio of the grid's second harmonic to its
        first in them (which a smooth light multiplying the grid, such as a lamp's
        hot spot, or adding to it, such as a highlight, leaves as it is) must pick
        ``periods`` too: a hot spot multiplies the modulus as a stain would.

    Returns
    -------
    (bool, str)
        Whether the moduli (and the harmonics' ratios) pick ``periods`` among the
        whole-period offsets (by the rule of the sum over the tiles, ``favoured``, or
        every rule), and what they say, in words.
    """
    check_type(reference, "reference", PhaseMaps)
    check_type(deformed, "deformed", PhaseMaps)
    q = decimation(reference.lattice)
    v = check_mask(valid, reference.shape, "valid")[::q, ::q]
    uq = np.asarray(u, dtype=np.float64)[:, ::q, ::q]
    w = None if within is None else check_mask(within, reference.shape, "within")[::q, ::q]
    if images is not None:
        images = tuple(as_image(im, name).astype(np.float64)
                       for im, name in zip(images, ("images[0]", "images[1]"), strict=True))
        for im, name in zip(images, ("images[0]", "images[1]"), strict=True):
            check_same_shape(im.shape, reference.shape, name, "the maps")
    return _grid_shows(reference, deformed, uq, v, periods, material=True, within=w,
                       images=images)


def _grid_content(reference: PhaseMaps, current: PhaseMaps, u: np.ndarray, ok: np.ndarray,
                  *, material: bool = False, within=None, around=(0, 0),
                  contents=None, memo=None) -> ContentOrder:
    """:func:`order_from_content` of the grids' own moduli (the logarithm of the mean
    modulus of the two wave vectors, sampled every ``q`` px) with the field ``u`` (2,
    h, w) and ``ok`` at those samples, over the samples ``within`` (default all), the
    field carried to the others from the nearest of ``ok`` (:func:`_extended`), the
    search centred on the whole periods ``around``. ``material``: ``u`` is the
    displacement at the material point (a measurement's, Lagrangian), not the phases'
    at the camera's point. ``contents``: the two states' content maps at those samples
    to compare instead of the moduli (:func:`_light_free`); ``memo``: a
    :class:`_Contents` the moduli's maps are kept in."""
    lattice = reference.lattice
    q = decimation(lattice)
    pitch = max(lattice.pitches)
    a, b = (_made(memo, _modulus_content, pm, pitch, q) for pm in (reference, current)) \
        if contents is None else contents
    if not ok.any():
        return order_from_content(a, b, u, ok, lattice, q, around=around)
    # every sample, the field carried to the invalid ones from their nearest valid
    # one, to first order: a hole's edge or the specimen's, where the modulus
    # collapses, lies in the invalid margin round them and is the strongest content
    # the grid carries
    u = _extended(np.asarray(u, dtype=np.float64), ok, q)
    use = np.ones_like(ok) if within is None else within
    return order_from_content(a, b, u, use, lattice, q,
                              around=around, gradient=None if material else gradient(u, q))


def _modulus_content(pm: PhaseMaps, pitch: float, q: int) -> np.ndarray:
    """The logarithm of the mean modulus of ``pm``'s two wave vectors, low-passed by a
    Gaussian of std ``pitch`` px and sampled every ``q`` px (:func:`_grid_content`)."""
    # low-passed by a Gaussian of a pitch as the image's content is (the moire of the
    # grid's harmonics with the pixels ripples the modulus by a few 1e-3), over the
    # window's weights within the frame: near a border the transform sums a truncated
    # window, its modulus falling as they do
    m = np.mean(np.abs(pm.psi), axis=0, dtype=np.float64)
    m = smooth_decimate(m, pitch, q) / np.maximum(_window_weights(m.shape, pm.sigma,
                                                                  pitch, q), 1e-6)
    return np.log(np.maximum(m, 1e-3 * max(float(np.max(m)), 1e-300)))


def _window_weights(shape, sigma: float, s: float, q: int) -> np.ndarray:
    """The window's weights within a frame of ``shape`` (a Gaussian of std ``sigma``
    over ones, zero beyond the border) smoothed and sampled as
    :func:`smooth_decimate` does with ``s`` and ``q``: separable, the product of two
    profiles (the same values as the filtered whole frame to within rounding)."""
    return np.outer(*(_gaussian_at(ndimage.gaussian_filter1d(
        np.ones(n), sigma, mode="constant", truncate=4.0), s, q, 0) for n in shape))


def _extended(u: np.ndarray, ok: np.ndarray, q: int) -> np.ndarray:
    """The field ``u`` (2, h, w) at samples ``q`` px apart carried from ``ok`` to every
    other sample to first order: its nearest valid sample's value plus that sample's
    gradient times the way to it.

    Carried as a constant, a rotated or strained field is wrong by the gradient times
    the way: 10 degrees of rotation, 0.17 px a px, put the hole's edge, the strongest
    content the modulus has, 0.35 period from where it lies two pitches into the
    invalid margin round it, and the comparison favours half periods.
    The gradient is that of the valid samples (central differences within them),
    taken at the nearest sample where it is known."""
    rows, cols = (np.broadcast_to(i, ok.shape) for i in nearest_index(ok))
    out = u[:, rows, cols]
    if ok.all() or min(ok.shape) < 2:
        return out
    g = gradient(np.where(ok, u, np.nan), q)  # NaN next to an invalid sample
    known = ok & np.all(np.isfinite(g), axis=(0, 1))
    if not known.any():
        return out
    gr, gc = (np.broadcast_to(i, ok.shape) for i in nearest_index(known))
    G = g[:, :, gr[rows, cols], gc[rows, cols]]  # (2, 2, h, w) as du_i/d(x, y)
    yy, xx = np.indices(ok.shape)
    dx, dy = (xx - cols) * float(q), (yy - rows) * float(q)
    return out + G[:, 0] * dx + G[:, 1] * dy


def _grid_shows(reference: PhaseMaps, current: PhaseMaps, u: np.ndarray, ok: np.ndarray,
                periods, *, material: bool = False, within=None,
                images=None) -> tuple[bool, str]:
    """:func:`grid_shows` with ``u`` and ``ok`` at the samples: the modulus, and the
    harmonics' ratio as well when ``images`` are given, must show ``periods``."""
    shown, said, doubt = _grid_evidence(reference, current, u, ok, periods,
                                        material=material, within=within, images=images)
    return (shown and not doubt), (doubt or said)


def _grid_evidence(reference: PhaseMaps, current: PhaseMaps, u: np.ndarray, ok: np.ndarray,
                   periods, *, material: bool = False, within=None,
                   images=None, memo=None) -> tuple[bool, str, str]:
    """``(shown, said, doubt)``: whether the grid's modulus shows the whole periods
    ``periods`` and the ratio of the grid's harmonics in ``images`` (when given,
    :func:`_light_free`) does not put them elsewhere, what they say, and, where the
    modulus shows them but that ratio cannot tell, why that is no confirmation (empty
    otherwise). ``memo``: a :class:`_Contents` the content maps are kept in."""
    # the search centred on the periods tested: they are then never at its edge, and
    # the phases' own order lies within its reach for shifts of a few periods
    want = tuple(int(v) for v in np.rint(periods))
    g = _grid_content(reference, current, u, ok, material=material, within=within,
                      around=want, memo=memo)
    shown, said = _says(g, want, "the grid's own modulus")
    if not shown and want == tuple(g.offset) and g.tiles_agreeing == g.tiles_informative > 0:
        # too little of the modulus's content to decide over the whole frame (stains
        # covering a tile or two of a large one), but where it decides it shows these
        # periods and nowhere others: corroboration enough to use them, never to confirm
        return True, said, (f"not confirmed: the image content that moved could be the "
                            f"light, and {said}, though each of its informative tiles "
                            f"shows them")
    if not shown or images is None:
        return shown, said, ""
    q = decimation(reference.lattice)
    lat = reference.lattice
    told = []
    # what no light imitates: the ratio of the grid's harmonics, and where it vanishes
    for what, make in (("its second harmonic over its first", _light_free),
                       ("the places where it vanishes", _vanishing)):
        contents = tuple(_made(memo, make, im, lat, q) for im in images)
        if contents[0] is None:
            told.append(f"{what} cannot be read at this pitch (folded onto a carrier)")
            continue
        if all(float(np.ptp(c)) == 0.0 for c in contents):
            # a grid that vanishes nowhere: its clipped contrast is one value in both
            # images, and no offset of it is better than another
            told.append(f"{what}: none in either image")
            continue
        c = _grid_content(reference, current, u, ok, material=material, within=within,
                          around=want, contents=contents)
        seen, more = _says(c, want, what)
        if seen:
            return True, f"{said}, and {more.removeprefix('its ')}", ""
        if c.confident or c.favoured:
            return False, f"{said} but {more}", ""
        told.append(more)
    return True, said, (f"not confirmed: the image content that moved could be the light "
                        f"(a lamp's hot spot multiplies the grid as a stain would): {said} "
                        f"but {'; '.join(told)}")


def _says(g: ContentOrder, want: tuple, what: str) -> tuple[bool, str]:
    """Whether the content comparison ``g`` picks the whole periods ``want``, and what
    it says, in words, of ``what`` was compared."""
    if want == tuple(g.offset) and (g.confident or g.favoured):
        return True, (f"{what} shows the same whole periods (ratio of residuals "
                      f"{g.residual_ratio:.2f})")
    if not (g.confident or g.favoured):
        return False, f"{what} does not show them ({g.reason})"
    return False, f"{what} puts them at {g.offset[0]}, {g.offset[1]} periods ({g.reason})"


def _light_free(image, lattice: Lattice, q: int) -> np.ndarray | None:
    """The logarithm of the ratio of the grid's second harmonics to its carriers in
    ``image`` (the moduli summed over the two wave vectors), both demodulated by one
    Gaussian (std the longer pitch), sampled every ``q`` px from pixel 0; None where a
    second harmonic, folded by the pixels, lies within the window's band of the mean or
    of a carrier (pitches of 4 px and less, 2 pi sigma |2 k - k'| < 3).

    The image is the specimen's reflectance times the light, plus what its surface
    reflects. A smooth light (a lamp's hot spot, vignetting) multiplies every harmonic
    of the grid alike under the one window; what the surface reflects (a highlight)
    adds to the mean alone: their ratio is the print's own, whatever the light does.
    What is printed on or lies on the specimen and is finer than the window changes
    it (a spot darkening part of a period, a line's width, an edge), and moves with
    the specimen. A print without a second harmonic (a sine, or symmetric square
    lines) has nothing here, and nothing confirms what the light could have done."""
    x = np.asarray(image, dtype=np.float64)
    pitch = max(lattice.pitches)
    K = np.asarray(lattice.K, dtype=np.float64)
    others = np.vstack([np.zeros((1, 2)), K, -K])
    for k in 2 * K:
        folded = k - np.rint(k)
        if np.min(np.hypot(*(others - folded).T)) * 2 * np.pi * pitch < 3.0:
            return None

    ratio = _moduli(x, 2 * K, pitch, q) / np.maximum(_moduli(x, K, pitch, q), 1e-300)
    return np.log(np.maximum(ratio, 1e-3 * max(float(np.max(ratio)), 1e-300)))


def _vanishing(image, lattice: Lattice, q: int) -> np.ndarray:
    """Where the grid vanishes while the image does not (a hole's or an edge's
    collapse of the grid): the logarithm of the grid's contrast (its carriers' modulus
    over the local mean, under one Gaussian of std the longer pitch) relative to its
    median, kept between 1/16 and 1/4, sampled every ``q`` px. A lamp's light
    multiplies carrier and mean alike; a highlight lowers the contrast below a
    quarter only where it outshines the grid's mean level three times over."""
    x = np.asarray(image, dtype=np.float64)
    pitch = max(lattice.pitches)
    c = _moduli(x, np.asarray(lattice.K, dtype=np.float64), pitch, q) / np.maximum(
        np.abs(smooth_decimate(x, pitch, q)), 1e-300)
    return np.log(np.clip(c / max(float(np.median(c)), 1e-300), 1 / 16, 1 / 4))


def _moduli(x: np.ndarray, ks: np.ndarray, s: float, q: int) -> np.ndarray:
    """The sum over the wave vectors ``ks`` (n, 2) of the moduli of ``x`` demodulated
    at each by a Gaussian of std ``s`` px, sampled every ``q`` px."""
    H, W = x.shape
    out = 0.0
    for kx, ky in ks:
        # separable: exp(-2 i pi (kx x + ky y))
        e = np.outer(np.exp(-2j * np.pi * ky * np.arange(H)),
                     np.exp(-2j * np.pi * kx * np.arange(W))) * x
        out = out + np.hypot(smooth_decimate(e.real, s, q), smooth_decimate(e.imag, s, q))
    return out


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
        den = smooth_decimate(w, s1, q)
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
    num = smooth_decimate(x, s1, q)
    num2 = ndimage.gaussian_filter(num, s2, mode="constant", truncate=4.0)
    return num / np.maximum(den, 1e-12) - num2 / np.maximum(den2, 1e-12)


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
    n: np.ndarray | None = None  # overlap count at every shift (1 where none)
    sf: np.ndarray | None = None  # sum of f over the overlap
    vf: np.ndarray | None = None  # and its centred sum of squares (0 where negative)
    enough: np.ndarray | None = None  # shifts with overlap enough
    weights: tuple = ()  # the deformed image's band-pass weights (its whole crop)
    # where both masks are one rectangle (no mask given): the reference's (first row,
    # last row + 1, first column, last column + 1) and the shifts' reach (ry, rx)
    box: tuple | None = None
    reach: tuple = (0, 0)


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
    mf, mg = ma.astype(np.float64), mb.astype(np.float64)
    need = 0.5 * min(mf.sum(), mg.sum())
    # the shifts with overlap enough reach (ry, rx) samples; on L samples the circular
    # correlation of two maps of h samples is their linear one over |s| <= L - h, so
    # transforms of h + ry samples hold them all (a quarter of twice h's area for
    # unmasked images), the shifts beyond left out
    big = (sfft.next_fast_len(2 * h), sfft.next_fast_len(2 * w))
    ry, rx = _reach(np.rint(_xc(_tr(mf, big), _tr(mg, big), big)) >= need)
    shape = (sfft.next_fast_len(h + ry), sfft.next_fast_len(w + rx))
    f = (a - a[mf > 0].mean()) * mf
    F, F2, MF = _tr(f, shape), _tr(f * f, shape), _tr(mf, shape)
    MG = _tr(mg, shape)
    n = np.rint(_xc(MF, MG, shape))
    within = [np.minimum(i, L - i) <= r for i, L, r in
              ((np.arange(L), L, r) for L, r in zip(shape, (ry, rx), strict=True))]
    enough = (n >= need) & within[0][:, None] & within[1][None, :]
    sf = _xc(F, MG, shape)
    n = np.maximum(n, 1.0)
    vf = np.maximum(_xc(F2, MG, shape) - sf * sf / n, 0.0)
    box = filled_box(ma) if np.array_equal(ma, mb) else None
    return dataclasses.replace(side, fft_shape=shape, MF=MF, F=F, F2=F2, n=n, sf=sf, vf=vf,
                               enough=enough, box=box, reach=(ry, rx))


def _box_sums(v: np.ndarray, box: tuple, reach: tuple, shape: tuple) -> np.ndarray:
    """``sum_{x in box} v(x + s)`` (``v`` zero beyond its array) for the shifts ``|s| <=
    reach``, placed at ``s`` modulo ``shape`` (0 elsewhere): the correlation of a
    rectangle's indicator with ``v``, from ``v``'s summed-area table."""
    h, w = v.shape
    table = np.zeros((h + 1, w + 1))
    np.cumsum(np.cumsum(v, axis=0), axis=1, out=table[1:, 1:])
    r0, r1, c0, c1 = box
    sy, sx = np.arange(-reach[0], reach[0] + 1), np.arange(-reach[1], reach[1] + 1)
    a, b = np.clip(r0 + sy, 0, h), np.clip(r1 + sy, 0, h)
    c, d = np.clip(c0 + sx, 0, w), np.clip(c1 + sx, 0, w)
    top, bottom = table[a], table[b]
    sums = bottom[:, d] - top[:, d] - bottom[:, c] + top[:, c]
    out = np.zeros(shape)
    # shifts 0 .. r first along each axis, -r .. -1 last, as a transform's map holds them
    (ry, rx), (Ly, Lx) = reach, shape
    for src_r, dst_r in ((np.s_[ry:], np.s_[:ry + 1]), (np.s_[:ry], np.s_[Ly - ry:])):
        for src_c, dst_c in ((np.s_[rx:], np.s_[:rx + 1]), (np.s_[:rx], np.s_[Lx - rx:])):
            out[dst_r, dst_c] = sums[src_r, src_c]
    return out


def _reach(enough: np.ndarray) -> tuple[int, int]:
    """The largest shift along each axis, in samples, of the ``True`` entries of a map
    indexed by shifts modulo its shape."""
    out = []
    for axis, L in enumerate(enough.shape):
        i = np.nonzero(enough.any(axis=1 - axis))[0]
        out.append(int(np.max(np.minimum(i, L - i))))
    return out[0], out[1]


def _tr(a, shape):
    return sfft.rfft2(a, s=shape)


def _xc(a, b, shape):  # sum_x a(x) b(x + s), from the transforms of a and b
    return sfft.irfft2(np.conj(a) * b, s=shape)


def _ncc_map(side: _Side, g):
    """Normalised correlation of the reference's ``f(x)`` and ``g(x + s)`` over
    ``mf(x) mg(x + s)`` (the masks of ``side``).

    Returns the map indexed by ``s`` modulo its shape.
    """
    shape, MF, nn = side.fft_shape, side.MF, side.n
    g = np.where(side.mb, g - g[side.mb].mean(), 0.0)
    G = _tr(g, shape)
    if side.box is not None:
        # the masks are one rectangle: the sums of g and g^2 over the overlap at
        # every shift come from summed-area tables rather than two more correlations
        sg = _box_sums(g, side.box, side.reach, shape)
        vg = _box_sums(g * g, side.box, side.reach, shape)
    else:
        sg, vg = _xc(MF, G, shape), _xc(MF, _tr(g * g, shape), shape)
    vg -= sg * sg / nn
    sf = side.sf
    num = _xc(side.F, G, shape) - sf * sg / nn
    den = np.sqrt(side.vf * np.maximum(vg, 0.0))
    scale = max(float(np.max(den, where=side.enough, initial=0.0)), 1e-300)
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
    vals = np.full(inside.shape, np.nan)
    if inside.any():  # read at the candidates within the correlated shifts only
        vals[inside] = at(c, cands[inside] / q)
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
    for _, _, z in phase_products(reference, deformed, valid):
        z /= np.maximum(np.abs(z), 1e-300)
        mean += z.sum(axis=1)
    return -solve_k(reference.lattice.K, np.angle(mean)) / (2 * np.pi)


# Pixels per band of rows of phase_products.
_PRODUCT_BAND = 2**14


def phase_products(reference: PhaseMaps, deformed: PhaseMaps, valid: np.ndarray):
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
        # each wave vector's map gathered on its own (a mask over the trailing axes of
        # the stack gathers several times slower) into the layout that gather gives,
        # (n, 2) transposed, so that the sums over a band add in the same order
        z = np.stack([deformed.psi[j, rows][v] for j in range(2)],
                     axis=-1).T.astype(np.complex128, copy=False)
        ref = np.stack([reference.psi[j, rows][v] for j in range(2)], axis=-1).T
        z *= np.conjugate(ref, out=ref)
        yield rows, v, z


def solve_k(K: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``K^-1 r`` for a 2x2 ``K`` and ``r`` of shape (2, ...)."""
    return np.tensordot(np.linalg.inv(K), r, axes=1)


def strain_if_off(res) -> float:
    """How far the strain of ``res`` (a :class:`Measurement`) would move if its
    displacement were one lattice period off: see :attr:`FringeOrder.strain_if_off`.

    With the large-displacement correction the gradient at ``X`` is built from the
    deformed phases' derivatives at ``X + u``; a displacement ``u + a`` reads them at
    the place of the material point ``X + a`` (to first order in the gradient), so
    the strain reported at ``X`` becomes the strain at ``X + a``: it changes by
    ``(a . grad) e``, from the measured strain maps (central differences).
    Without the correction the strain does not depend on the order: 0."""
    if not res.lagrangian:
        return 0.0
    v = res.valid
    P = res.lattice.periods
    worst = np.zeros(v.shape)
    for comp in res.strain:
        gy, gx = np.gradient(np.asarray(comp, dtype=np.float64))
        for k in range(2):
            d = np.abs(P[0, k] * gx + P[1, k] * gy)
            np.fmax(worst, d, out=worst)
    vals = worst[v & np.isfinite(worst)]
    return float(np.percentile(vals, 95)) if vals.size else math.nan
