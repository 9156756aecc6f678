"""Discontinuities of the displacement: a crack, an edge, a torn grid.

The windowed Fourier transform sees a displacement jump ``delta`` across a line as
the jump smoothed by the window: the measured displacement is off by ``delta/2
erfc(d / (sqrt(2) sigma))`` at a distance ``d`` from the line (0.25 px at the line,
still 5 times the noise of a good grid at ``2 sigma`` for ``delta = 0.5`` px), and
the strain shows a ridge of exactly the window's profile, ``delta / (sqrt(2 pi)
sigma)`` high (0.04 for ``delta = 0.5`` px at ``sigma = 5`` px). Across an opening of
more than half a pitch the phases may also be unwrapped across the line with the
wrong whole period on one side. :func:`find_discontinuities` finds the ridges,
:func:`without_discontinuities` measures again with the pixels whose window
straddles one left out, so that the unwrapping goes round the crack's tip.

Conventions: :mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._validation import check_positive, check_type
from .kinematics import Measurement, deformation
from .stacks.screening import MAD_TO_STD
from .uncertainty._biases import local_departure, nearest_index

__all__ = ["Discontinuities", "find_discontinuities", "without_discontinuities"]

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
        displacement jump its ridge's height gives, ``sqrt(2 pi) sigma`` times the
        height; modulo a pitch where the opening exceeds half a pitch).
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
                         f"{r['cols'][1]} (a jump of about {r['jump_px']:.2g} px, known "
                         "modulo a pitch)" for r in self.regions)


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
    Each strain component's departure from its median over ``8 sigma`` around is
    compared with ``min_jump / (sqrt(2 pi) sigma)``, the height of the ridge a jump
    of ``min_jump`` leaves, and with 10 robust standard deviations of that
    departure over the valid pixels. A jump of a whole number of pitches leaves no
    trace in the phases (the grid is the same on both sides): only the stretches of
    a crack whose opening differs from it are seen.
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
    height = np.zeros(valid.shape)
    seeds = np.zeros(valid.shape, dtype=bool)
    low = np.zeros(valid.shape, dtype=bool)
    nearest = None if valid.all() else nearest_index(valid)
    for c in range(strain.shape[0]):
        # the surroundings: a median over 8 sigma, wider than a ridge (about 3 sigma)
        d = np.abs(local_departure(strain[c], valid, sigma, nearest))
        spread = MAD_TO_STD * float(np.median(d[valid]))
        seeds |= d > max(threshold, _MIN_SIGMAS * spread)
        low |= d > _FOLLOW_SIGMAS * spread
        np.maximum(height, d, out=height)
    seeds &= valid
    low &= valid
    if not seeds.any():
        return Discontinuities(core=empty, band=empty.copy(), regions=(),
                               threshold=threshold)
    lab, _ = ndimage.label(low, structure=np.ones((3, 3)))
    core = np.isin(lab, np.unique(lab[seeds]))
    if not core.any():
        return Discontinuities(core=empty, band=empty.copy(), regions=(),
                               threshold=threshold)
    r = math.ceil(_BAND_SIGMAS * sigma)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    band = ndimage.binary_dilation(core, structure=yy**2 + xx**2 <= r * r) & valid
    labels, _ = ndimage.label(band)
    regions = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        sel = labels[sl] == k
        h = float(np.max(height[sl][sel & core[sl]]))
        regions.append({"rows": (int(sl[0].start), int(sl[0].stop - 1)),
                        "cols": (int(sl[1].start), int(sl[1].stop - 1)),
                        "pixels": int(sel.sum()),
                        "jump_px": h * math.sqrt(2 * math.pi) * sigma})
    return Discontinuities(core=core, band=band, regions=tuple(regions),
                           threshold=threshold)


def _no_seed_possible(strain: np.ndarray, valid: np.ndarray, threshold: float) -> bool:
    """Whether no strain component spreads over ``threshold`` on the valid pixels.

    A departure from the local median is at most the component's range over the
    valid pixels: the median, and its linear interpolation back to every pixel, are
    of values taken there (invalid pixels take a valid neighbour's). Below the
    threshold no pixel can seed a ridge, and the search would find none; the
    factor 0.999 leaves room for the interpolation's rounding.
    """
    for comp in strain:
        vals = comp[valid]
        span = float(np.max(vals)) - float(np.min(vals))
        if not span < 0.999 * threshold:  # NaN included: the search decides
            return False
    return True


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
        Default: the median displacement ``m`` was fixed with (``m.guess``).
    """
    check_type(m, "m", Measurement)
    check_type(disc, "disc", Discontinuities)
    if m.reference is None or m.deformed is None:
        raise ValueError("m must keep its phase maps (reference and deformed) to be "
                         "measured again")
    if not disc:
        return m
    ref = m.reference
    kept = type(ref)(psi=ref.psi, dphi=ref.dphi, valid=ref.valid & ~disc.band,
                     lattice=ref.lattice, sigma=ref.sigma)
    g = np.array(m.guess, dtype=float) if guess is None else guess
    again = deformation(kept, m.deformed, lagrangian=m.lagrangian, guess=g)
    # fragments the band cuts off (slivers between it and a border, smaller than a
    # window's core, pi sigma^2) have their whole periods from a few pixels: left out
    labels, n = ndimage.label(again.valid)
    if n > 1:
        sizes = np.bincount(labels.ravel(), minlength=n + 1)
        small = np.nonzero(sizes < math.pi * m.sigma**2)[0]
        small = small[small > 0]
        if small.size:
            drop = np.isin(labels, small)
            valid = again.valid & ~drop
            u, strain, rotation = (np.where(valid, a, np.nan) for a in
                                   (again.u, again.strain, again.rotation))
            again = dataclasses.replace(again, u=u, strain=strain, rotation=rotation,
                                        valid=valid)
    # the fringe order's record stays that of the whole field
    return dataclasses.replace(again, reference=ref, fringe_order=m.fringe_order,
                               guess_source=m.guess_source)
