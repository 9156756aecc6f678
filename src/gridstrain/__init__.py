"""gridstrain: displacement and strain maps from images of periodic grids.

The conventions (axes, signs, window, Lagrangian description) are written once, in
:mod:`gridstrain.conventions`.
"""

from .kinematics import Measurement, coarse_displacement, deformation, measure
from .lattice import Lattice, detect_lattice
from .noise import NoiseModel, anscombe, estimate_noise, estimate_noise_image, inverse_anscombe
from .uncertainty import Uncertainty, predict_uncertainty
from .vibration import VibrationReport, frame_shifts, vibration_report
from .wft import PhaseMaps, wft

__version__ = "0.1.0"

# The series workflow and the result files, imported on first use: they pull in
# the pipeline, h5py and matplotlib, which ``import gridstrain`` need not load.
_LAZY = {
    "measure_series": "gridstrain.pipeline",
    "SeriesResult": "gridstrain.pipeline",
    "method_a": "gridstrain.stacks",
    "method_b": "gridstrain.stacks",
    "load": "gridstrain.results",
    "save_result": "gridstrain.results",
    "progress_bar": "gridstrain._progress",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'gridstrain' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))

__all__ = [
    "Lattice",
    "Measurement",
    "NoiseModel",
    "PhaseMaps",
    "SeriesResult",
    "Uncertainty",
    "VibrationReport",
    "__version__",
    "anscombe",
    "coarse_displacement",
    "deformation",
    "detect_lattice",
    "estimate_noise",
    "estimate_noise_image",
    "frame_shifts",
    "inverse_anscombe",
    "load",
    "measure",
    "measure_series",
    "method_a",
    "method_b",
    "predict_uncertainty",
    "progress_bar",
    "save_result",
    "vibration_report",
    "wft",
]
