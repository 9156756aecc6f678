"""Discontinuities of the displacement: a crack, an edge, a torn grid.

The windowed Fourier transform sees a displacement jump ``delta`` across a line as
the jump smoothed by the window: the measured displacement is off by ``delta/2
erfc(d / (sqrt(2) sigma))`` at a distance ``d`` from the line (0.25 px at the line,
still 5 times the noise of a good grid at ``2 sigma`` for ``delta = 0.5`` px), and
the strain shows a ridge of the window's profile, ``delta / (sqrt(2 pi) sigma)``
high (0.04 for ``delta = 0.5`` px at ``sigma = 5`` px) and integrating to ``delta``
across, where a smooth strain concentration of width ``w`` shows one ``sqrt(w^2 +
sigma^2)`` wide: the width tells them apart. Across an opening of
more than half a pitch the phases may also be unwrapped across the line with the
wrong whole period on one side. :func:`find_discontinuities` finds the ridges,
:func:`without_discontinuities` measures again with the pixels whose window
straddles one left out, so that the unwrapping goes round the crack's tip. A crack
that cuts the field into parts leaves no way round: nothing in the phases joins
one side's whole periods to the other's, and :func:`check_parts` fixes each part's
from its own image content, or says it cannot.

Conventions: :mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._validation import as_image, check_mask, check_positive, check_same_shape, check_type
from ..stacks.screening import MAD_TO_STD
from ..uncertainty import nearest_filled, nearest_index
from ._deformation import Measurement, deformation
from ._fringe_order import FringeOrder, coarse_displacement, cut_into_parts, grid_shows

__all__ = ["Discontinuities", "Part", "check_parts", "find_discontinuities",
           "without_discontinuities"]

# The smallest displacement jump taken as a discontinuity, px: its ridge, ``delta /
# (sqrt(2 pi) sigma)``, stands 50 times above the strain noise of a 12-bit grid at
# sigma = 5 px (4e-4), and a smooth strain field reaches it only with a strain
# concentration of 2 % over less than the window's width, itself biased by the
# window (gridstrain.uncertainty.smoothing_bias).
_MIN_JUMP = 0.25
# ... and the ridge must also stand this many robust standard deviations of the
# strain's departure from its surroundings above them.
_MIN_SIGMAS = 10.0
# A ridge found is followed (hysteresis) wherever it stands this many robust
# standard deviations above its surroundings: towards a crack's tip the opening
# falls below min_jump, and a jump of 0.03 px still leaves an error of 5 times the
# noise of a good grid at the line (4 standard deviations occur at 6e-5 of the
# pixels of a noise map, and only those touching a ridge are taken).
_FOLLOW_SIGMAS = 4.0
# A candidate ridge is a jump's if its cross-section, its baseline taken off, is
# at most this many sigmas wide (its equivalent width: the integral of its absolute
# value over +-4 sigma, over sqrt(2 pi) times its height). A small jump's is the
# window's profile, sigma wide; larger ones' are narrower or wider as the phases of
# the two sides' phasors mix (measured: 0.2 to 1.46 sigma for jumps of 0.5 to 7 px
# and 11 px at pitches 5 and 6.4 px, the widest for true openings past a pitch; one
# of 9 px at a pitch of 5 px, 1.52 sigma, is taken for smooth). A smooth strain
# concentration of width w is seen sqrt(w^2 + sigma^2) wide: 1.6 sigma and more for
# bumps and bands of 1.5 to 3 sigma and 3 to 20 %, 1.51 to 1.55 sigma through the
# shear lobes of bumps of 10 to 20 % (whose negative lobe the absolute value
# counts). A ridge's sections, 10 strain noise deviations high at least, scatter by
# 2 % about their median: the limit lies between the widest jump and the narrowest
# smooth concentration measured, 1.46 and 1.51 sigma.
_MAX_WIDTH = 1.485
# The jump is the strain integrated over +-3 sigma from the crest (holding 0.9973
# of the window's profile), the width over +-4 sigma, the baseline the line
# through the means at 4.5 to 5.5 sigma on each side.
_SECTION_SIGMAS = (3.0, 4.0, 4.5, 5.5)
# A displacement jump is seen by the phases modulo the lattice: across a torn grid the
# window mixes the two sides' phasors, whose phase runs the short way round, so the
# jump a ridge integrates to is within half a period of zero along each wave vector.
# A ridge that integrates to more than this many periods is a continuous gradient the
# phases followed (a steep but intact grid), not a tear: 0.5 plus 0.1 for the noise
# and the baseline of the sections (a jump of 5.5 px at a pitch of 5 reads 0.1
# period, a tanh step of one period over three pitches 0.9).
_MAX_TEAR_PERIODS = 0.6
# ... unless the grid's modulus collapses along it: the deformed state's modulus at
# ``X + u`` over the reference's at ``X`` (the same material point: the lighting and
# the print cancel), relative to its median over the valid pixels, below this along
# the ridge's core (the median over the core, the smaller of the two wave vectors).
# Half a period of opening cancels the two sides' phasors (0); an intact grid whose
# local period changes by 20 % within the window keeps 0.6 and more.
_TORN_MODULUS = 0.5
# ... and a ridge that integrates to more than this many periods (and at most to
# _MAX_TEAR_PERIODS) is a tear only where the grid shows one, as a steep continuous
# gradient of an intact grid integrating to a third to half a period, narrower than
# the window, leaves as narrow a ridge (a rise of half a period along a family over
# three periods). Below it neither the width nor the modulus tells them apart (jumps
# of 0.1 to 0.25 period measured 0.9 to 1.46 sigma wide and dips of 0.8 to 0.95; a
# steep gradient of 0.33 period 1.41 and 0.92): a small jump is a tear as its narrow
# ridge says, and a whole period cannot hide in it.
_SMALL_TEAR_PERIODS = 0.35
# The grid shows the tear where the ridge's sections are at most this many sigmas wide
# (the median): two sides' phasors mixing by the window narrow a jump's ridge as they
# near half a period (0.16 to 0.76 sigma measured for openings of 0.35 to 0.5 period
# at lattice periods of 5 to 7 px), where a continuous rise over three periods is
# seen 1.36 to 1.37 sigma wide.
_TEAR_WIDTH = 1.1
# ... or where the grid's modulus at its crest (the deformed state's at ``X + u`` over
# the reference's at ``X``, the smallest within sigma of the crest, over its level 3 to
# 4 sigma away on each side; the median over the sections) falls below this: two
# phasors near half a period apart, or a gap without grid, empty the window's centre
# (0.34 to 0.54 measured for openings of 0.35 to 0.5 period; 0.59 for a gap of 7 px),
# where an intact checkerboard rising by half a period along a family over three
# periods keeps 0.83 to 0.86. A dark gap of half a period in a grid of dark lines
# looks like one more line and keeps 0.89: the width then tells.
_TORN_DIP = 0.75
# Pixels within this many sigmas of a ridge's core are left out: the window's
# error there, delta/2 erfc(d / sqrt(2) sigma), reaches the noise beyond it only for
# jumps of several pixels (1e-3 of delta/2 at the core's edge plus 2 sigma).
_BAND_SIGMAS = 2.0


@dataclass(frozen=True, eq=False)
class Discontinuities:
    """Where a state's displacement jumps, and the pixels it spoils.

    Attributes
    ----------
    core : (H, W) bool ndarray
        Pixels on a ridge of the strain's departure from its surroundings.
    band : (H, W) bool ndarray
        Pixels whose window straddles a ridge (the core widened by
        ``2 sigma``), within the measurement's valid pixels.
    regions : tuple of dict
        Per connected ridge: ``rows`` and ``cols`` (first, last; px, the
        bounding box of its band), ``pixels`` (of its band), ``jump_px`` (the
        displacement jump, px: the strain integrated across the ridge, the
        median over its sections, signed as the opening), ``opening_px`` and
        ``sliding_px`` (its components across and along the ridge), ``pitch_px``
        (the lattice's period along the jump). The phases know a jump only
        modulo a period: one of 6 px at a pitch of 6.4 px reads -0.4 px, one of a
        whole period leaves no trace. NaN where no section of the ridge lies
        within the valid pixels (along a hole, for example).
    threshold : float
        The strain departure taken as a ridge (dimensionless).
    """

    core: np.ndarray
    band: np.ndarray
    regions: tuple
    threshold: float

    def __post_init__(self):
        for name in ("core", "band"):
            getattr(self, name).flags.writeable = False

    def __bool__(self) -> bool:
        return bool(self.regions)

    def describe(self) -> str:
        """One line per region, for a warning."""
        return "; ".join(f"rows {r['rows'][0]}-{r['rows'][1]}, columns {r['cols'][0]}-"
                         f"{r['cols'][1]} ({_jump_words(r)})" for r in self.regions)


def _jump_words(r: dict) -> str:
    """A region's jump, in words: known only modulo the period along it."""
    if not math.isfinite(r["jump_px"]):
        return "a jump its sections cannot measure"
    return (f"a jump of {r['jump_px']:.2g} px modulo the period {r['pitch_px']:.3g} px "
            "along it")


def find_discontinuities(m: Measurement, *, min_jump: float = _MIN_JUMP) -> Discontinuities:
    """The ridges of a measurement's strain that a displacement jump leaves.

    Parameters
    ----------
    m : Measurement
    min_jump : float
        Smallest jump looked for, px (default 0.25).

    Returns
    -------
    Discontinuities
        Empty (false) when no ridge stands out.

    Notes
    -----
    Each strain component's departure from the median of the valid pixels over
    ``8 sigma`` around is compared with ``min_jump / (sqrt(2 pi) sigma)``, the
    height of the ridge a jump of ``min_jump`` leaves, and with 10 robust standard
    deviations of that departure over the valid pixels. A ridge is followed from
    there wherever its departure exceeds 4 of them, across gaps of up to ``2
    sigma`` and across the holes of pixels the reference measures and the deformed
    state does not (where the deformed grid vanishes along an opening near half a
    pitch). A ridge is kept only if its cross-sections, one through a seed
    every ``sigma``, are no wider than a jump's (``_MAX_WIDTH``, 1.485 sigma, their
    median), a smooth strain concentration being seen wider than the window. Its
    jump is the strain integrated across it (over +-3 sigma, the median over its
    sections). A ridge is a tear only where the phases can be discontinuous: seen
    through the window, a jump integrates to less than half a period along each wave
    vector (the two sides' phasors mix the short way round), so a ridge that
    integrates to more than 0.6 period is a steep gradient of an intact grid,
    followed and not cut, unless the grid's modulus collapses along it (the
    deformed state's at ``X + u`` over the reference's at ``X`` below half its
    median). One that integrates to 0.35 to 0.6 period is a tear only where the grid
    shows it: its sections at most 1.1 sigma wide (the phasors' mixing narrows a
    jump's ridge as they near half a period), or the modulus at its crest below 0.75
    of its sides' (the window's centre emptied by the mixing or by a gap); a steep
    gradient narrower than the window keeps both (1.36 sigma, 0.85). A jump of a
    whole number of pitches leaves no trace in the phases
    (the grid is the same on both sides): only the stretches of a crack whose
    opening differs from it are seen, and the jump is known modulo the period.
    """
    check_type(m, "m", Measurement)
    min_jump = check_positive(min_jump, "min_jump")
    valid = np.asarray(m.valid, dtype=bool)
    sigma = float(m.sigma)
    empty = np.zeros(valid.shape, dtype=bool)
    threshold = min_jump / (math.sqrt(2 * math.pi) * sigma)
    if valid.sum() < 16:
        return Discontinuities(core=empty, band=empty.copy(), regions=(),
                               threshold=threshold)
    strain = np.asarray(m.strain)
    if _no_seed_possible(strain, valid, threshold):
        return Discontinuities(core=empty, band=empty.copy(), regions=(),
                               threshold=threshold)
    dep = np.zeros(strain.shape)
    seeds = np.zeros(valid.shape, dtype=bool)
    low = np.zeros(valid.shape, dtype=bool)
    for c in range(strain.shape[0]):
        # the surroundings: a median over 8 sigma, wider than a ridge (about 3 sigma)
        dep[c] = _departure(strain[c], valid, sigma)
        d = np.abs(dep[c])
        spread = MAD_TO_STD * float(np.median(d[valid]))
        seeds |= d > max(threshold, _MIN_SIGMAS * spread)
        low |= d > _FOLLOW_SIGMAS * spread
    seeds &= valid
    low &= valid
    if not seeds.any():
        return Discontinuities(core=empty, band=empty.copy(), regions=(),
                               threshold=threshold)
    # followed across the pixels the reference measures and the deformed state does
    # not as well: where the opening nears half a pitch the deformed grid's modulus
    # vanishes along the crack, and the hole that leaves (widened by the transform's
    # margin) may part a ridge from its tip or from a strip along a border. Opened by
    # a disc of radius sigma: the strips a few pixels wide along the borders, where
    # the displacement carries the deformed point out of its maps, join nothing
    inside = ndimage.binary_fill_holes(valid) if m.reference is None else m.reference.valid
    holes = ndimage.binary_opening(inside & ~valid, structure=_disc(math.ceil(sigma)))
    # ... and across gaps of up to 2 sigma along it: where the opening passes through
    # a whole pitch the ridge vanishes over a few pixels, and the stretch beyond it,
    # too low for a seed, still spoils the pixels beside it and joins the faces
    joined = ndimage.binary_dilation(low | holes, structure=_disc(math.ceil(sigma)))
    lab, _ = ndimage.label(joined, structure=np.ones((3, 3)))
    sections = _sections(strain, valid, sigma, dep, seeds, lab)
    sections["periods"] = _phase_jumps(sections, m.lattice)
    modulus = _ModulusRatio(m)
    jumps = [k for k in np.unique(lab[seeds])
             if _is_jump(sections, k, sigma)
             and _is_tear(sections, k, (lab == k) & low, modulus, m.lattice, sigma)]
    core = np.isin(lab, jumps) & low
    if not core.any():
        return Discontinuities(core=empty, band=empty.copy(), regions=(),
                               threshold=threshold)
    band = ndimage.binary_dilation(core, structure=_disc(math.ceil(_BAND_SIGMAS * sigma)))
    band &= valid
    # one region per ridge: the parts of its band that a hole along it, or a gap
    # where its opening passes a whole period, parts are one crack's
    labels, _ = ndimage.label(band | (joined & np.isin(lab, jumps)), structure=np.ones((3, 3)))
    regions = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        sel = (labels[sl] == k) & band[sl]
        if not sel.any():
            continue
        rows, cols = np.nonzero(sel)
        inside_k = labels[sections["rows"], sections["cols"]] == k
        regions.append({"rows": (int(sl[0].start + rows.min()), int(sl[0].start + rows.max())),
                        "cols": (int(sl[1].start + cols.min()), int(sl[1].start + cols.max())),
                        "pixels": int(sel.sum()),
                        **_jump(sections, inside_k, m.lattice)})
    return Discontinuities(core=core, band=band, regions=tuple(regions),
                           threshold=threshold)


def _sections(strain, valid, sigma, dep, seeds, lab) -> dict:
    """The strain's cross-sections through seeds of the ridges, one every sigma.

    Each is read along the ridge's normal (the leading eigenvector of the
    strain's structure tensor, its gradients' products over sigma: across a
    ridge, whatever the sign or the component), centred on the crest within 2
    sigma of the seed, its baseline (the line through its means at 4.5 to 5.5
    sigma on each side) taken off. Returns the seeds' ``rows``, ``cols`` and
    ridge ``label``, the section's equivalent ``width`` (px; the integral of the
    seed's strongest component's absolute value over +-4 sigma, over ``sqrt(2
    pi)`` times its height), the
    ``opening`` and ``sliding`` jumps (px; the integral of the strain tensor across,
    ``n.E.n`` and ``2 t.E.n``), the normal ``n`` (x, y), and ``ok``: the section
    lies on valid pixels, and ``crest``: where along the normal the crest lies from
    the seed, px.
    """
    step = max(1, int(sigma))
    pick = np.zeros_like(seeds)
    pick[::step, ::step] = seeds[::step, ::step]
    missing = np.setdiff1d(np.unique(lab[seeds]), np.unique(lab[pick]))
    pick |= seeds & np.isin(lab, missing)  # a ridge too short to hold a grid point
    rows, cols = np.nonzero(pick)
    nearest = nearest_index(valid)
    filled = np.stack([nearest_filled(np.asarray(c, dtype=np.float64), valid, nearest)
                       for c in strain])
    grads = [np.gradient(c) for c in filled]
    tensor = [ndimage.gaussian_filter(sum(g[i] * g[j] for g in grads), sigma)[rows, cols]
              for i, j in ((1, 1), (0, 0), (1, 0))]  # xx, yy, xy
    theta = 0.5 * np.arctan2(2 * tensor[2], tensor[0] - tensor[1])
    n = np.stack([np.cos(theta), np.sin(theta)])  # (x, y)
    inner, wide, near, far = _SECTION_SIGMAS
    reach = math.ceil((far + 2.0) * sigma) + 1  # a crest 2 sigma off, its span beyond
    t = np.arange(-reach, reach + 1, dtype=np.float64)
    yy = rows[:, None] + t[None, :] * n[1][:, None]
    xx = cols[:, None] + t[None, :] * n[0][:, None]
    prof = np.stack([ndimage.map_coordinates(c, [yy, xx], order=1, mode="nearest")
                     for c in filled])  # (3, points, samples)
    on = ndimage.map_coordinates(valid.astype(np.float64), [yy, xx], order=0, cval=0.0) > 0
    comp = np.argmax(np.abs(dep[:, rows, cols]), axis=0)  # the seed's strongest component
    sign = np.sign(dep[comp, rows, cols])
    idx = np.arange(rows.size)
    centre = np.abs(t) <= 2.0 * sigma
    crest = np.flatnonzero(centre)[0] + np.argmax((prof[comp, idx] * sign[:, None])[:, centre],
                                                  axis=1)
    span = np.arange(-round(far * sigma), round(far * sigma) + 1)
    take = crest[:, None] + span[None, :]  # (points, span)
    sec = np.take_along_axis(prof, np.broadcast_to(take, (prof.shape[0], *take.shape)),
                             axis=2)
    on = np.take_along_axis(on, take, axis=1)
    # the baseline: the line through the means of the valid samples of each side
    ends = []
    for side in (span <= -near * sigma, span >= near * sigma):
        w = on & side
        ends.append((sec * w).sum(axis=-1) / np.maximum(w.sum(axis=-1), 1))
    ok = on[:, np.abs(span) <= wide * sigma].all(axis=1)
    ok &= (on & (span <= -near * sigma)).any(axis=1) & (on & (span >= near * sigma)).any(axis=1)
    mid = 0.5 * (near + far) * sigma
    sec = sec - ends[0][..., None] - (ends[1] - ends[0])[..., None] * (span + mid) / (2 * mid)
    # the window's profile holds erf(a / sqrt 2) of a jump within +-a sigma
    integral = (sec[..., np.abs(span) <= inner * sigma].sum(axis=-1)
                / math.erf(inner / math.sqrt(2)))
    height = sec[comp, idx, span.size // 2] * sign
    main = sec[comp, idx] * sign[:, None]
    inside = np.abs(span) <= wide * sigma
    with np.errstate(divide="ignore", invalid="ignore"):
        width = (np.abs(main[:, inside]).sum(axis=-1)
                 / (math.erf(wide / math.sqrt(2)) * math.sqrt(2 * math.pi) * height))
    ok &= height > 0
    nx, ny = n
    exx, eyy, exy = integral
    opening = exx * nx * nx + eyy * ny * ny + 2 * exy * nx * ny
    sliding = 2 * ((eyy - exx) * nx * ny + exy * (nx * nx - ny * ny))
    return {"rows": rows, "cols": cols, "label": lab[rows, cols], "width": width,
            "opening": opening, "sliding": sliding, "n": n, "ok": ok,
            "crest": t[crest]}


def _is_jump(sections: dict, k: int, sigma: float) -> bool:
    """Whether the ridge labelled ``k`` has a jump's cross-section (at most
    ``_MAX_WIDTH`` sigmas wide, the median over its sections); one without a
    section on valid pixels (along a hole) is kept: nothing says it is smooth."""
    mine = (sections["label"] == k) & sections["ok"]
    if not mine.any():
        return True
    return float(np.median(sections["width"][mine])) <= _MAX_WIDTH * sigma


def _phase_jumps(sections: dict, lattice) -> np.ndarray:
    """Per section, the jump it integrates to in periods: the largest over the two
    wave vectors of ``|K b|``, ``b`` the jump vector (opening along the normal,
    sliding along the ridge), px."""
    nx, ny = sections["n"]
    b = np.stack([sections["opening"] * nx - sections["sliding"] * ny,
                  sections["opening"] * ny + sections["sliding"] * nx])
    return np.max(np.abs(lattice.K @ b), axis=0)


class _ModulusRatio:
    """The deformed grid's modulus at ``X + u`` over the reference's at ``X``, per wave
    vector, relative to its median over the valid pixels (made on first use: only a
    ridge the width and the integral leave in doubt needs it). The same material
    point is compared: the lighting and the print cancel, and what is left is the
    grid's own change (torn, or its period changed within the window)."""

    def __init__(self, m: Measurement):
        self.m = m
        self._ratio = None

    def maps(self) -> np.ndarray | None:
        """(2, H, W) ratio maps; None without the phase maps."""
        m = self.m
        if m.reference is None or m.deformed is None:
            return None
        if self._ratio is None:
            v = np.asarray(m.valid, dtype=bool)
            H, W = v.shape
            yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
            u = np.stack([nearest_filled(np.asarray(c, dtype=np.float64), v)
                          for c in m.u])
            out = np.empty((2, H, W))
            for j in range(2):
                ref = np.abs(m.reference.psi[j])
                cur = ndimage.map_coordinates(np.abs(m.deformed.psi[j]),
                                              [yy + u[1], xx + u[0]], order=1,
                                              mode="nearest")
                r = cur / np.maximum(ref, 1e-12 * float(np.max(ref[v])))
                out[j] = r / max(float(np.median(r[v])), 1e-300)
            self._ratio = out
        return self._ratio

    def along(self, core: np.ndarray) -> float:
        """The median over ``core`` of the smaller wave vector's ratio; NaN without
        the phase maps."""
        ratio = self.maps()
        if ratio is None or not core.any():
            return math.nan
        return float(np.median(np.min(ratio[:, core], axis=0)))


def _crest_dips(sections: dict, modulus: _ModulusRatio, lattice, sigma: float):
    """Per section, the grid's modulus at the crest relative to the sides' (NaN where
    it cannot be read): the smallest ratio within ``sigma`` of the crest over the mean
    of its medians 3 to 4 sigma away on each side, along the wave vector that the
    section's jump ``b`` turns most (``|K b|`` nearest to half a period, the one two
    torn sides' phasors, mixed by the window, would cancel most).

    Read on every section, valid or not: where the deformed grid vanished along an
    opening the ratio there (computed from the transforms, not their validity) is
    the tear's own evidence.
    """
    ratio = modulus.maps()
    n_sec = sections["rows"].size
    if ratio is None or n_sec == 0:
        return np.full(n_sec, np.nan)
    nx, ny = sections["n"]
    b = np.stack([sections["opening"] * nx - sections["sliding"] * ny,
                  sections["opening"] * ny + sections["sliding"] * nx])
    j = np.argmin(np.abs(np.cos(np.pi * (lattice.K @ b))), axis=0)
    reach = math.ceil(4.0 * sigma)
    t = np.arange(-reach, reach + 1, dtype=np.float64)
    cy = sections["rows"] + sections["crest"] * ny
    cx = sections["cols"] + sections["crest"] * nx
    yy = cy[:, None] + t[None, :] * ny[:, None]
    xx = cx[:, None] + t[None, :] * nx[:, None]
    prof = np.stack([ndimage.map_coordinates(r, [yy, xx], order=1, mode="nearest")
                     for r in ratio])[j, np.arange(n_sec)]  # (sections, samples)
    dip = np.min(prof[:, np.abs(t) <= sigma], axis=1)
    far = np.abs(t) >= 3.0 * sigma
    sides = 0.5 * (np.median(prof[:, far & (t < 0)], axis=1)
                   + np.median(prof[:, far & (t > 0)], axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return dip / sides


def _is_tear(sections: dict, k: int, core: np.ndarray, modulus: _ModulusRatio,
             lattice, sigma: float) -> bool:
    """Whether the ridge ``k`` (its ``core`` pixels) is a torn grid.

    By what its sections integrate to (the median over those on valid pixels): up to
    ``_SMALL_TEAR_PERIODS``, a small jump, a tear; up to ``_MAX_TEAR_PERIODS``, as a
    jump seen modulo the lattice does, a tear only where the grid shows it: the
    sections are at most ``_TEAR_WIDTH`` sigmas wide, or the grid's modulus at the
    crest falls below ``_TORN_DIP`` of the sides' (the medians over the sections);
    past it, only where the grid's modulus collapses along it (``_TORN_MODULUS``): a
    steep gradient integrates to what it is, a period or more. A ridge without a
    section on valid pixels is judged by the dip alone (a tear where none can be
    read). What is not a tear is a steep gradient of an intact grid: the phases are
    continuous across it, and it is followed, not cut."""
    mine = (sections["label"] == k) & sections["ok"]

    def emptied() -> bool:
        if "dip" not in sections:  # the ratio maps made once, for the first that asks
            sections["dip"] = _crest_dips(sections, modulus, lattice, sigma)
        dips = sections["dip"][sections["label"] == k]
        dips = dips[np.isfinite(dips)]
        return not dips.size or float(np.median(dips)) < _TORN_DIP

    if not mine.any():
        # its sections run off the valid pixels (a ridge near a border, or the image
        # a few windows wide): their integrals, over the filled strain, still tell a
        # rise past _MAX_TEAR_PERIODS, a period or more, from a jump seen modulo the
        # lattice; along a hole where the deformed grid vanished they read nothing
        # (NaN) and the dip decides
        rough = sections["periods"][sections["label"] == k]
        rough = rough[np.isfinite(rough)]
        if rough.size and float(np.median(rough)) > _MAX_TEAR_PERIODS:
            return not modulus.along(core) >= _TORN_MODULUS
        return emptied()
    periods = float(np.median(sections["periods"][mine]))
    if periods <= _SMALL_TEAR_PERIODS:
        return True
    if periods <= _MAX_TEAR_PERIODS:
        return (float(np.median(sections["width"][mine])) <= _TEAR_WIDTH * sigma
                or emptied())
    return not modulus.along(core) >= _TORN_MODULUS


def _jump(sections: dict, inside: np.ndarray, lattice) -> dict:
    """A region's jump from the sections through its seeds (the median of those
    on valid pixels): ``jump_px``, ``opening_px``, ``sliding_px``, ``pitch_px``."""
    mine = inside & sections["ok"]
    if not mine.any():
        nan = float("nan")
        return {"jump_px": nan, "opening_px": nan, "sliding_px": nan,
                "pitch_px": float(lattice.pitch)}
    opening = float(np.median(sections["opening"][mine]))
    sliding = float(np.median(sections["sliding"][mine]))
    size = math.hypot(opening, sliding)
    # the period along the jump: its phase in each family is K b, known modulo 1
    n = np.median(sections["n"][:, mine] * np.sign(sections["n"][1, mine] + 1e-12), axis=1)
    t = np.array([-n[1], n[0]])
    b = (opening * n + sliding * t) / max(size, 1e-12)
    along = float(np.max(np.abs(lattice.K @ b))) if size > 0 else 0.0
    pitch = 1.0 / along if along > 0 else float(lattice.pitch)
    return {"jump_px": math.copysign(size, opening), "opening_px": opening,
            "sliding_px": sliding, "pitch_px": pitch}


def _no_seed_possible(strain: np.ndarray, valid: np.ndarray, threshold: float) -> bool:
    """Whether no strain component spreads over ``threshold`` on the valid pixels.

    A departure from the local median is at most the component's range over the
    valid pixels: the median, and its linear interpolation back to every pixel, are
    of values taken there (invalid pixels take a valid neighbour's). Below the
    threshold no pixel can seed a ridge, and the search would find none; the
    factor 0.999 leaves room for the interpolation's rounding.
    """
    for comp in strain:
        # reduced where valid, without gathering them (the same values)
        span = float(np.max(comp, where=valid, initial=-np.inf)) \
            - float(np.min(comp, where=valid, initial=np.inf))
        if not span < 0.999 * threshold:  # NaN included: the search decides
            return False
    return True


def _disc(r: int) -> np.ndarray:
    """A disc of radius ``r`` px, a structuring element."""
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return yy**2 + xx**2 <= r * r


# A strain taken for a missing sample by the median of _departure: far beyond any
# strain, so that it only ranks below or above every sample present.
_ABSENT = 1e30


def _departure(e: np.ndarray, valid: np.ndarray, sigma: float) -> np.ndarray:
    """``e`` less its median over the valid pixels within 8 sigma around, taken on a
    grid of step ``sigma`` (a ridge 2 to 3 sigmas wide holds 3 of the 9 columns of
    the median's window, which keeps it out of its background).

    The invalid samples of a window count alternately (a checkerboard) as far below
    and far above every strain, so that they shift the median by at most a rank or
    two of the valid ones instead of pulling it: given their nearest valid value,
    the samples of a hole beside a narrow strip of a ridge (between the hole and a
    border) would all take the ridge's value and hide it from its own background.
    """
    step = max(1, int(sigma))
    f = np.asarray(e, dtype=np.float64)[::step, ::step].copy()
    ok = valid[::step, ::step]
    if not ok.any():
        return np.zeros(e.shape)
    yy, xx = np.indices(f.shape)
    f[~ok] = np.where((yy + xx) % 2 == 0, -_ABSENT, _ABSENT)[~ok]
    size = max(3, round(8.0 * sigma / step) | 1)
    bg = ndimage.median_filter(f, size=size, mode="nearest")
    known = np.abs(bg) < 0.5 * _ABSENT  # a window short of valid samples: the nearest
    bg = nearest_filled(bg, known)
    zoom = (e.shape[0] / bg.shape[0], e.shape[1] / bg.shape[1])
    full = ndimage.zoom(bg, zoom, order=1, mode="nearest", grid_mode=True)
    return np.where(valid, e - full[:e.shape[0], :e.shape[1]], 0.0)


def without_discontinuities(m: Measurement, disc: Discontinuities, *,
                            guess=None) -> Measurement:
    """``m`` measured again without the pixels whose window straddles a
    discontinuity: the phases are unwrapped round the crack's tip instead of
    across it (where an opening of more than half a pitch would put one side a
    whole period off), and those pixels are invalid.

    Parameters
    ----------
    m : Measurement
        With its phase maps (``m.reference`` and ``m.deformed``).
    disc : Discontinuities
        From :func:`find_discontinuities`.
    guess : as for :func:`gridstrain.kinematics.deformation`
        Default: the median displacement ``m`` was fixed with (``m.guess``). Where
        the band cuts the field into parts, each part's whole periods are the ones
        closest to it (to a field given here, for example the previous state's
        displacement, pixel by pixel): :func:`check_parts` checks each part on its
        own image content.
    """
    check_type(m, "m", Measurement)
    check_type(disc, "disc", Discontinuities)
    if m.reference is None or m.deformed is None:
        raise ValueError("m must keep its phase maps (reference and deformed) to be "
                         "measured again")
    if not disc:
        return m
    ref = m.reference
    # within m's valid pixels: a strip valid in both phase maps but not in m (where
    # the deformed state's point X + u falls outside its maps) would join the parts
    # the band cuts apart, and the phases would be unwrapped across the crack there
    kept = type(ref)(psi=ref.psi, dphi=ref.dphi, valid=ref.valid & m.valid & ~disc.band,
                     lattice=ref.lattice, sigma=ref.sigma)
    g = np.array(m.guess, dtype=float) if guess is None else guess
    again = deformation(kept, m.deformed, lagrangian=m.lagrangian, guess=g)
    del g
    # fragments the band cuts off (slivers between it and a border, smaller than a
    # window's core, pi sigma^2) have their whole periods from a few pixels: left out
    labels, n = ndimage.label(again.valid)
    if n > 1:
        sizes = np.bincount(labels.ravel(), minlength=n + 1)
        small = np.nonzero(sizes < math.pi * m.sigma**2)[0]
        small = small[small > 0]
        if small.size:
            again = _left_out(again, np.isin(labels, small))
    # the fringe order's record stays that of the whole field
    return dataclasses.replace(again, reference=ref, fringe_order=m.fringe_order,
                               guess=m.guess, guess_source=m.guess_source)


def _own_field(m: Measurement) -> np.ndarray:
    """(2, H, W) ``m.u`` with each invalid pixel given its nearest valid pixel's value."""
    nearest = nearest_index(m.valid)
    return np.stack([nearest_filled(np.asarray(c, dtype=np.float64), m.valid, nearest)
                     for c in m.u])


def _left_out(m: Measurement, drop: np.ndarray) -> Measurement:
    """``m`` with the pixels of ``drop`` invalid (NaN in its maps)."""
    valid = m.valid & ~drop
    u, strain, rotation = (np.where(valid, a, np.nan) for a in (m.u, m.strain, m.rotation))
    return dataclasses.replace(m, u=u, strain=strain, rotation=rotation, valid=valid)


@dataclass(frozen=True)
class Part:
    """A part of the field that a crack cuts off, and how its whole periods were fixed.

    Attributes
    ----------
    rows, cols : (2,) tuple of int
        First and last row and column of the part (its bounding box), px.
    pixels : int
        Its valid pixels before the check.
    confirmed : bool
        Whether its own image content, the deformed image warped back by its
        measured field, matches the reference's (:func:`coarse_displacement`
        restricted to the part): its fringe order is then known.
    shift_px : (2,) tuple of float
        The whole periods its content showed the measured field to be off by
        (added to it), px; zero when confirmed as measured or not confirmed.
    left_out : bool
        Whether its pixels were made invalid: not confirmed while another part is.
    detail : str
        Why, in words.
    """

    rows: tuple[int, int]
    cols: tuple[int, int]
    pixels: int
    confirmed: bool
    shift_px: tuple[float, float] = (0.0, 0.0)
    left_out: bool = False
    detail: str = ""

    def describe(self) -> str:
        """Where the part lies, in words."""
        return (f"rows {self.rows[0]}-{self.rows[1]}, columns {self.cols[0]}-"
                f"{self.cols[1]}")


def check_parted(m: Measurement, reference_image, deformed_image, *, mask=None
                 ) -> tuple[Measurement, tuple[Part, ...]]:
    """``m`` with each part's whole periods from its own content where invalid bands
    part its field without a jump (a gradient too steep for the window dims the grid
    along it) and its fringe order is not confirmed (:func:`check_parts`, the parts it
    cannot decide left out), when one part is confirmed so; else ``m`` as it is and no
    part. The rule the pair API and measure_series share."""
    order = m.fringe_order
    if order is None or order.confirmed or m.reference is None or \
            not cut_into_parts(m.valid):
        return m, ()
    checked, parts = check_parts(m, m.reference.valid, reference_image, deformed_image,
                                 mask=mask, cause="invalid bands (no jump found) part")
    if not any(p.confirmed for p in parts):
        return m, ()
    return checked, parts


def check_parts(m: Measurement, before, reference_image, deformed_image, *,
                mask=None, cause: str = "the crack cuts") -> tuple[Measurement, tuple[Part, ...]]:
    """Each part a crack cuts the field into, its fringe order fixed by its own content.

    No continuity joins the two sides of an open crack: the whole periods of
    each side come from that side's own evidence. For each connected region of
    ``m.valid`` (when there are more than in ``before``), the deformed image is
    warped back by the part's measured field and correlated with the reference
    over that part alone (:func:`gridstrain.kinematics.coarse_displacement`
    with ``region``). Where the content lies whole periods away and the grid's own
    modulus shows them too (:func:`gridstrain.kinematics.grid_shows`: not light
    that moved), the part is measured again with those periods added; where it
    cannot tell (a grid
    without printed features, a part too small to hold any), the part is not
    confirmed. Unconfirmed parts are left out (invalid) when another part is
    confirmed, so that every valid pixel shares the record of the state; when
    none is, all are kept and the record says the order is not confirmed.

    Parameters
    ----------
    m : Measurement
        From :func:`without_discontinuities`, with its phase maps.
    before : (H, W) bool array_like
        The valid pixels before the crack was cut out (``m``'s parts are counted
        against its connected regions).
    reference_image, deformed_image : (H, W) array_like
        The states' images (mean images of their stacks), grey levels.
    mask : (H, W) bool array_like, optional
        True on the specimen in the reference image.
    cause : str
        What parted the field and how, as the record says it (``"the crack cuts"``;
        ``"invalid bands part"`` where no jump was found: a gradient too steep for
        the window).

    Returns
    -------
    (Measurement, tuple of Part)
        ``m`` with its parts' whole periods fixed, its unconfirmed parts left out
        where another is confirmed, and its ``fringe_order`` saying so; the parts
        (empty when the crack cuts nothing off).
    """
    check_type(m, "m", Measurement)
    shape = m.valid.shape
    before = check_mask(before, shape, "before")
    labels, n = ndimage.label(m.valid)
    if n <= 1 or n <= ndimage.label(before)[1]:
        return m, ()
    if m.reference is None or m.deformed is None:
        raise ValueError("m must keep its phase maps (reference and deformed) to be "
                         "measured again")
    ref = as_image(reference_image, "reference_image").astype(np.float64)
    cur = as_image(deformed_image, "deformed_image").astype(np.float64)
    check_same_shape(ref.shape, shape, "reference_image", "the maps")
    check_same_shape(cur.shape, shape, "deformed_image", "the maps")
    mask = check_mask(mask, shape)
    K = m.lattice.K
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    # each part's territory: the pixels nearer to it than to any other part (a hole's
    # edge, the strongest feature, lies in the invalid margin round the hole), less
    # the crack's band, where the other side's content shows once warped back
    nearest = nearest_index(m.valid)
    territories = labels[nearest] * ~(before & ~m.valid)
    del nearest
    found = []  # per part: (its pixels, the whole periods off or None, the estimate)
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        part = labels == k
        u = [nearest_filled(np.asarray(c, dtype=np.float64), part) for c in m.u]
        warped = ndimage.map_coordinates(cur, [yy + u[1], xx + u[0]], order=1,
                                         mode="nearest")
        del u
        est = _part_estimate(ref, warped, m.lattice, mask, territories == k)
        off = np.rint(K @ np.array(est.shift)) if est.confident else None
        if off is not None and np.any(off):
            # whole periods on one side of a cut: only where the grid's own modulus shows
            # them too, not the part's light alone (a highlight, a hot spot)
            shown, seen = grid_shows(m.reference, m.deformed, m.u, part, off,
                                     within=territories == k)
            if not shown:
                off, est = None, dataclasses.replace(
                    est, reason=f"its light lay whole periods away ({est.reason}) but {seen}")
        found.append((part, sl, off, est))
    shifts = [np.zeros(2) if off is None else np.linalg.solve(K, off)
              for _, _, off, _ in found]
    again = m
    if any(np.any(s) for s in shifts):
        g = _own_field(m)
        for (part, _, _, _), s in zip(found, shifts, strict=True):
            g[:, part] += s[:, None]
        ref = m.reference  # without the crack's band: m's valid pixels, its parts
        kept = type(ref)(psi=ref.psi, dphi=ref.dphi, valid=ref.valid & m.valid,
                         lattice=ref.lattice, sigma=ref.sigma)
        again = deformation(kept, m.deformed, lagrangian=m.lagrangian, guess=g)
        del g
        again = dataclasses.replace(again, guess=m.guess, guess_source=m.guess_source)
    any_confirmed = any(off is not None for _, _, off, _ in found)
    parts, drop = [], np.zeros(shape, dtype=bool)
    for (part, sl, off, est), s in zip(found, shifts, strict=True):
        left_out = any_confirmed and off is None
        if left_out:
            drop |= part
        if off is None:
            detail = f"not confirmed by its own image features ({est.reason})"
        elif np.any(s):
            detail = (f"its content, warped back, lay {s[0]:.2f}, {s[1]:.2f} px away: "
                      f"whole periods added ({est.reason})")
        else:
            detail = f"confirmed by its own image features ({est.reason})"
        parts.append(Part(rows=(int(sl[0].start), int(sl[0].stop - 1)),
                          cols=(int(sl[1].start), int(sl[1].stop - 1)),
                          pixels=int(part.sum()), confirmed=off is not None,
                          shift_px=(float(s[0]), float(s[1])), left_out=left_out,
                          detail=detail))
    if drop.any():
        again = _left_out(again, drop)
    again = dataclasses.replace(again, fringe_order=_parts_record(m.fringe_order, parts,
                                                                  cause),
                                reference=m.reference)
    return again, tuple(parts)


def _part_estimate(ref, warped, lattice, mask, territory):
    """:func:`coarse_displacement` of ``warped`` over ``territory`` (phases: zero),
    within ``mask``, and over the whole territory when that is not confident: the
    mask often hides a part's best features (a hole, the specimen's edges)."""
    est = coarse_displacement(ref, warped, lattice, mask=mask, phase_shift=(0.0, 0.0),
                              region=territory)
    if est.confident or mask.all():
        return est
    whole = coarse_displacement(ref, warped, lattice, phase_shift=(0.0, 0.0),
                                region=territory)
    return whole if whole.confident or whole.peak_to_alias > est.peak_to_alias else est


def _parts_record(rec: FringeOrder | None, parts: list[Part],
                  cause: str = "the crack cuts") -> FringeOrder:
    """The state's fringe-order record once each part was checked on its own."""
    said = "; ".join(f"{p.describe()}: {p.detail}" + (", left out" if p.left_out else "")
                     for p in parts)
    head = f"{cause} the field into {len(parts)} parts: {said}"
    if rec is None:
        rec = FringeOrder("smallest displacement", False)
    if any(p.confirmed for p in parts):
        return dataclasses.replace(rec, source="image features", confirmed=True,
                                   detail=f"{head}; before: {rec.detail}")
    return dataclasses.replace(rec, confirmed=False,
                               detail=f"{head}: their whole periods assume an opening "
                                      f"below half a pitch across it; {rec.detail}")
