"""gridstrain: displacement and strain maps from images of periodic grids.

The conventions (axes, signs, window, Lagrangian description) are written once, in
:mod:`gridstrain.conventions`.
"""

from .kinematics import (
    CoarseEstimate,
    FringeOrder,
    Measurement,
    coarse_displacement,
    deformation,
    measure,
)
from .lattice import Lattice, detect_lattice
from .noise import NoiseModel, anscombe, estimate_noise, inverse_anscombe
from .uncertainty import Uncertainty, predict_uncertainty
from .vibration import VibrationReport, frame_shifts, vibration_report
from .wft import PhaseMaps, wft

__version__ = "0.1.0"

__all__ = [
    "CoarseEstimate",
    "FringeOrder",
    "Lattice",
    "Measurement",
    "NoiseModel",
    "PhaseMaps",
    "Uncertainty",
    "VibrationReport",
    "__version__",
    "anscombe",
    "coarse_displacement",
    "deformation",
    "detect_lattice",
    "estimate_noise",
    "frame_shifts",
    "inverse_anscombe",
    "measure",
    "predict_uncertainty",
    "vibration_report",
    "wft",
]
