"""gridstrain: displacement and strain maps from images of periodic grids.

The conventions (axes, signs, window, Lagrangian description) are written once, in
:mod:`gridstrain.conventions`.
"""

from .kinematics import Measurement, coarse_displacement, deformation, measure
from .lattice import Lattice, detect_lattice
from .wft import PhaseMaps, wft

__version__ = "0.1.0"

__all__ = [
    "Lattice",
    "Measurement",
    "PhaseMaps",
    "__version__",
    "coarse_displacement",
    "deformation",
    "detect_lattice",
    "measure",
    "wft",
]
