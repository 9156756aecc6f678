"""Where a transform's maps are valid: away from the borders and the mask's edges by the
margin, and where the grid's modulus shows.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import ndimage

from .._stats import median


def _region(m: np.ndarray, full: bool, radius: float):
    """Pixels farther than ``radius`` px from the border and the mask's edges, and
    the box they fill when the mask is full (None otherwise)."""
    if full:
        valid, box = _valid_rectangle(*m.shape, radius)
        return valid, (np.s_[:, :] if box is None else box)
    return _valid_region(m, radius), None


# Fewest values whose median is bounded by a subsample (_median_at_most) rather than
# taken, and the subsample's rank above its middle, in its standard deviations (half
# the square root of its size): the bound then holds but for one map in millions.
_BOUND_MIN = 2**14
_BOUND_SPREAD = 8


def _median_at_most(values: np.ndarray) -> float:
    """A value of ``values`` (a map, a box of it, or a gathered 1-D array) that is
    proved at least their median, or NaN where none is found (few values, a NaN, a
    subsample that misses).

    A subsample's value some standard deviations of rank above its middle is taken,
    and the values at or below it counted: where they are more than half, both middle
    values, and so the median (their mean, rounded), are at most it. One partition of
    a sixteenth of the values and three passes, against the median's selection: where
    every modulus reaches a fraction of this bound, none is below that fraction of
    the median, and the median is not needed (:func:`_shows_grid`, :func:`no_grid`).
    """
    n = values.size
    if n < _BOUND_MIN:
        return math.nan
    sample = np.ravel(values[::4, ::4] if values.ndim == 2 else values[::16])
    k = min(sample.size - 1, sample.size // 2 + int(_BOUND_SPREAD * math.sqrt(sample.size) / 2))
    bound = np.partition(sample, k)[k]
    if not np.isfinite(values.max()) or np.count_nonzero(values <= bound) <= n // 2:
        return math.nan
    return float(bound)


def _shows_grid(mods, valid: np.ndarray, box, m: np.ndarray, min_modulus: float) -> np.ndarray:
    """Where both moduli reach ``min_modulus`` times their median over the region
    valid by its distance to the edges (sliced while it is a box, rather than
    gathered through a mask; the mask when no pixel is far enough from an edge)."""
    any_valid = bool(valid.any())
    keep = np.ones(valid.shape, dtype=bool)
    for mod in mods:
        values = mod[box] if box is not None else mod[valid] if any_valid else mod[m]
        if min_modulus * _median_at_most(values) <= mod.min():
            continue  # every pixel reaches the fraction of a bound of the median
        keep &= mod >= min_modulus * median(values)
    return keep


def no_grid(modulus, valid, mask, min_modulus: float, *, away: float = 0.0) -> np.ndarray:
    """Pixels of ``mask`` whose grid does not show: either modulus below ``min_modulus``
    times its median over ``valid`` (over ``mask`` where no pixel is valid).

    A hole, a gap or the background beside a coupon, left unmasked: its pixels are
    then masked and the image transformed again, so that the band of ``margin``
    sigmas around them is invalid as around a mask's edge (a window straddling the
    hole takes its uniform background into the phase: strain errors of 1e-3 to 5e-3
    within 4 sigmas of a hole's edge, tests/test_small_defects.py).

    Parameters
    ----------
    modulus : (2, H, W) float ndarray
        ``|Psi_k1|`` and ``|Psi_k2|`` (:attr:`PhaseMaps.modulus`).
    valid : (H, W) bool ndarray
        The transform's valid pixels, where the median is taken.
    mask : (H, W) bool ndarray
        The specimen (:mod:`gridstrain.conventions`, Masks).
    min_modulus : float
        Fraction of the median below which no grid shows
        (:data:`~gridstrain.phase.MIN_MODULUS`).
    away : float
        Count only the pixels farther than ``away`` px from the image's border and the
        mask's edge. A window cut by a straight border keeps half the grid's modulus,
        but one cut by a corner a quarter: ``away = sigma`` keeps the corners of a
        grid that shows everywhere from reading as holes.

    Returns
    -------
    (H, W) bool ndarray
        True where ``mask`` holds a pixel without a grid.
    """
    ref = valid if valid.any() else mask
    full = bool(mask.all())
    # a full mask's valid pixels are a box (the band along the border): its values
    # sliced rather than gathered (the same values, so the same median)
    box = filled_box(ref) if full else None
    out = np.zeros(mask.shape, dtype=bool)
    for j in range(2):
        values = (modulus[j][ref] if box is None
                  else modulus[j][box[0]:box[1], box[2]:box[3]])
        least = modulus[j].min() if full else np.min(modulus[j], where=mask, initial=np.inf)
        if min_modulus * _median_at_most(values) <= least:
            continue  # every pixel of the mask reaches the fraction of a bound of the median
        out |= modulus[j] < min_modulus * median(values, overwrite_input=box is None)
    out &= mask
    if away > 0 and out.any():
        out &= _region(mask, full, away)[0]
    return out


def filled_box(valid: np.ndarray) -> tuple[int, int, int, int] | None:
    """``(r0, r1, c0, c1)``, rows ``r0:r1`` and columns ``c0:c1``, of the rectangle the
    ``True`` pixels of ``valid`` fill (a frame's valid band without a mask), or None
    if they fill none (none at all, a mask's hole)."""
    rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    if not rows.size:
        return None
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    return (r0, r1, c0, c1) if (r1 - r0) * (c1 - c0) == np.count_nonzero(valid) else None


def _gaps(runs, n: int) -> list[slice]:
    """Slices of ``range(n)`` that no ``dst`` run of :func:`_axis_band` covers."""
    covered = sorted((d.start, d.stop) for d, _ in runs)
    gaps, pos = [], 0
    for start, stop in covered:
        if start > pos:
            gaps.append(slice(pos, start))
        pos = max(pos, stop)
    if pos < n:
        gaps.append(slice(pos, n))
    return gaps


def _valid_rectangle(H: int, W: int, radius: float):
    """:func:`_valid_region` of a full mask (a new array), and the box of rows x cols
    it covers.

    The distance to the nearest pixel outside the image is the distance to the
    nearest border, so the region is a box; no distance transform is needed.
    """
    valid, box = _rectangle(H, W, float(radius))
    return valid.copy(), box


@functools.lru_cache(maxsize=8)
def _rectangle(H: int, W: int, radius: float):
    # the same for every frame of a stack: made once (the caller copies it)
    oky = np.minimum(np.arange(H) + 1, H - np.arange(H)) > radius
    okx = np.minimum(np.arange(W) + 1, W - np.arange(W)) > radius
    valid = oky[:, None] & okx[None, :]
    if not valid.any():
        return valid, None
    ys, xs = np.flatnonzero(oky), np.flatnonzero(okx)
    return valid, np.s_[ys[0]:ys[-1] + 1, xs[0]:xs[-1] + 1]


def _valid_region(mask: np.ndarray, radius: float) -> np.ndarray:
    """Pixels farther than ``radius`` from the border and from any masked pixel."""
    padded = np.pad(mask, 1, constant_values=False)
    dist = ndimage.distance_transform_edt(padded)[1:-1, 1:-1]
    return dist > radius
