"""gridstrain: displacement and strain maps from images of periodic grids.

The conventions (axes, signs, window, Lagrangian description) are written once, in
:mod:`gridstrain.conventions`.
"""

from .lattice import Lattice, detect_lattice
from .wft import PhaseMaps, wft

__version__ = "0.1.0"

__all__ = ["Lattice", "PhaseMaps", "__version__", "detect_lattice", "wft"]
