"""Kinematics: displacement and strain maps from the phases of two states.

- ``_deformation``: the displacement (eq. 34, with the large-displacement correction of
  the Lagrangian description) and the small-strain tensor (eq. 35), :func:`deformation`
  and :func:`measure`;
- ``_fringe_order``: how the whole number of periods of a displacement is fixed
  (:class:`FringeOrder`) and the image-feature estimate (:func:`coarse_displacement`);
- :mod:`~gridstrain.kinematics.tracking`: the fringe order followed from state to state
  along a series;
- ``_pair_match``: whether the deformed image shows the reference's specimen, its
  content compared once warped back (:func:`pair_match`);
- ``_derived``: what the strain tensor gives besides its components: the principal,
  equivalent and maximum shear strains with their std (:func:`principal_strains`) and
  the finite strains rebuilt from the displacement gradient (:func:`finite_strains`);
- ``_spline_kernels``: the compiled cubic splines (numba), loaded on first use.
"""

from __future__ import annotations

from ._deformation import Measurement, deformation, measure
from ._derived import (
    DERIVED_STRAINS,
    FiniteStrains,
    PrincipalStrains,
    finite_strains,
    principal_strains,
)
from ._fringe_order import (
    FRINGE_ORDER_SOURCES,
    CoarseEstimate,
    FringeOrder,
    coarse_displacement,
)
from ._pair_match import PairMatch, pair_match

__all__ = [
    "DERIVED_STRAINS",
    "FRINGE_ORDER_SOURCES",
    "CoarseEstimate",
    "FiniteStrains",
    "FringeOrder",
    "Measurement",
    "PairMatch",
    "PrincipalStrains",
    "coarse_displacement",
    "deformation",
    "finite_strains",
    "measure",
    "pair_match",
    "principal_strains",
]
