"""Kinematics: displacement and strain maps from the phases of two states.

- ``_deformation``: the displacement (eq. 34, with the large-displacement correction of
  the Lagrangian description) and the small-strain tensor (eq. 35), :func:`deformation`
  and :func:`measure`;
- ``_fringe_order``: how the whole number of periods of a displacement is fixed
  (:class:`FringeOrder`), the image-feature estimate (:func:`coarse_displacement`) and
  whether the grid's own modulus shows a whole-period shift (:func:`grid_shows`);
- :mod:`~gridstrain.kinematics.tracking`: the fringe order followed from state to state
  along a series;
- ``_pair_match``: whether the deformed image shows the reference's specimen, its
  content compared once warped back (:func:`pair_match`);
- ``_spline_kernels``: the compiled cubic splines (numba), loaded on first use.
"""

from __future__ import annotations

from ._deformation import Measurement, deformation, measure
from ._fringe_order import (
    FRINGE_ORDER_SOURCES,
    CoarseEstimate,
    FringeOrder,
    coarse_displacement,
    grid_shows,
)
from ._pair_match import PairMatch, pair_match

__all__ = [
    "FRINGE_ORDER_SOURCES",
    "CoarseEstimate",
    "FringeOrder",
    "Measurement",
    "PairMatch",
    "coarse_displacement",
    "deformation",
    "grid_shows",
    "measure",
    "pair_match",
]
