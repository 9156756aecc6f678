"""gridstrain: displacement and strain maps from images of periodic grids.

The conventions (axes, signs, window, Lagrangian description) are written once, in
:mod:`gridstrain.conventions`.

The public names below are imported on first use (PEP 562), so that ``import
gridstrain`` and ``gridstrain --help`` do not pay for scipy, scikit-image, h5py or
matplotlib before anything is computed.
"""

from __future__ import annotations

import importlib
import sys
import types

__version__ = "0.1.0"

# public name -> submodule that defines it
_LAZY = {
    "CoarseEstimate": "kinematics",
    "FringeOrder": "kinematics",
    "Lattice": "phase",
    "Measurement": "kinematics",
    "NoiseModel": "noise",
    "PhaseMaps": "phase",
    "Uncertainty": "uncertainty",
    "VibrationReport": "vibration",
    "anscombe": "noise",
    "coarse_displacement": "kinematics",
    "deformation": "kinematics",
    "detect_lattice": "phase",
    "estimate_noise": "noise",
    "estimate_noise_image": "noise",
    "frame_shifts": "vibration",
    "inverse_anscombe": "noise",
    "measure": "kinematics",
    "predict_uncertainty": "uncertainty",
    "vibration_report": "vibration",
    "wft": "phase",
    # the series workflow and the result files (they pull in h5py and matplotlib)
    "SeriesResult": "pipeline",
    "load": "results",
    "measure_series": "pipeline",
    "method_a": "stacks",
    "method_b": "stacks",
    "progress_bar": "_progress",
    "save_result": "results",
}

__all__ = ["__version__", *sorted(_LAZY)]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'gridstrain' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    # once resolved, the name is a plain attribute of the package
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


class _Package(types.ModuleType):
    """The package module: a public name stays what it is when a submodule of that name loads.

    The import system binds every submodule it loads to the package under the
    submodule's name. :func:`wft` is implemented in ``gridstrain.phase._transform`` and also
    exported by the public module :mod:`gridstrain.wft`, named after it: the
    function, not that module, is the package's ``wft`` (as with an eager ``from
    .wft import wft``), whichever of the two is imported first.
    """

    def __setattr__(self, name, value):
        if isinstance(value, types.ModuleType) and name in _LAZY:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
