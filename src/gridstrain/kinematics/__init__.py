"""Kinematics: displacement and strain maps from the phases of two states.

- ``_deformation``: the displacement (eq. 34, with the large-displacement correction of
  the Lagrangian description) and the small-strain tensor (eq. 35), :func:`deformation`;
- ``_measure``: the pair's measurement from two images, :func:`measure`;
- ``_fringe_order``: how the whole number of periods of a displacement is fixed
  (:class:`FringeOrder`), the image-feature estimate (:func:`coarse_displacement`) and
  whether the grid's own modulus shows a whole-period shift (:func:`grid_shows`);
- :mod:`~gridstrain.kinematics.tracking`: the fringe order followed from state to state
  along a series;
- ``_pair_match``: whether the deformed image shows the reference's specimen, its
  content compared once warped back (:func:`pair_match`);
- ``_derived``: what the strain tensor gives besides its components: the principal,
  equivalent and maximum shear strains with their std (:func:`principal_strains`) and
  the finite strains rebuilt from the displacement gradient (:func:`finite_strains`);
- ``_spline_kernels``: the compiled cubic splines (numba), loaded on first use;
- ``_bilinear_kernels``: the compiled bilinear reads of the images' content compared
  at whole-period offsets (numba), loaded on first use.
"""

from __future__ import annotations

from ._deformation import Measurement, deformation

# shared with gridstrain's other folders, not part of the public API
from ._deformation import eulerian_gradient as eulerian_gradient
from ._deformation import small_strain as small_strain
from ._derived import (
    DERIVED_STRAINS,
    FINITE_COMPONENTS,
    FiniteStrains,
    PrincipalStrains,
    finite_strains,
    principal_strains,
)
from ._discontinuities import (
    Discontinuities,
    Part,
    check_parted,
    check_parts,
    find_discontinuities,
    without_discontinuities,
)
from ._fringe_order import (
    FRINGE_ORDER_SOURCES,
    CoarseEstimate,
    FringeOrder,
    coarse_displacement,
    grid_shows,
)
from ._fringe_order import cut_into_parts as cut_into_parts
from ._fringe_order import phase_products as phase_products
from ._fringe_order import solve_k as solve_k
from ._measure import measure
from ._pair_match import PairMatch, pair_match

__all__ = [
    "DERIVED_STRAINS",
    "FINITE_COMPONENTS",
    "FRINGE_ORDER_SOURCES",
    "CoarseEstimate",
    "Discontinuities",
    "FiniteStrains",
    "FringeOrder",
    "Measurement",
    "PairMatch",
    "Part",
    "PrincipalStrains",
    "check_parted",
    "check_parts",
    "coarse_displacement",
    "deformation",
    "find_discontinuities",
    "finite_strains",
    "grid_shows",
    "measure",
    "pair_match",
    "principal_strains",
    "without_discontinuities",
]
