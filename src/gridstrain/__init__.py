"""gridstrain: displacement and strain maps from images of periodic grids.

The conventions (axes, signs, window, Lagrangian description) are written once, in
:mod:`gridstrain.conventions`.

The public names below are imported on first use (PEP 562), so that ``import
gridstrain`` and ``gridstrain --help`` do not pay for scipy, scikit-image, h5py or
matplotlib before anything is computed.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings

__version__ = "0.1.0"

# public name -> submodule that defines it
_LAZY = {
    "CoarseEstimate": "kinematics",
    "FringeOrder": "kinematics",
    "Lattice": "phase",
    "Measurement": "kinematics",
    "NoiseModel": "uncertainty",
    "PhaseMaps": "phase",
    "Uncertainty": "uncertainty",
    "VibrationReport": "stacks",
    "anscombe": "uncertainty",
    "coarse_displacement": "kinematics",
    "deformation": "kinematics",
    "detect_lattice": "phase",
    "estimate_noise": "uncertainty",
    "estimate_noise_image": "uncertainty",
    "frame_shifts": "stacks",
    "inverse_anscombe": "uncertainty",
    "measure": "kinematics",
    "predict_uncertainty": "uncertainty",
    "vibration_report": "stacks",
    "wft": "phase",
    # the series workflow and the result files (they pull in h5py and matplotlib)
    "SeriesResult": "results",
    "load": "results",
    "measure_series": "series",
    "method_a": "stacks",
    "method_b": "stacks",
    "progress_bar": "_progress",
    "Finding": "_progress",
    "FINDINGS": "_progress",
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
    submodule's name. :func:`wft` is implemented in ``gridstrain.phase._transform``;
    the old module path ``gridstrain.wft`` (see :data:`_MOVED`) still imports: the
    function, not a module, stays the package's ``wft``, whichever is imported first.
    """

    def __setattr__(self, name, value):
        if isinstance(value, types.ModuleType) and name in _LAZY:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


#: Modules that moved into a folder, old name -> the folder (or public module) that holds
#: their names now. The old path still imports, for one release, with a DeprecationWarning.
_MOVED = {
    "accumulate": "stacks.accumulate",
    "discontinuities": "kinematics",
    "distributed": "series",
    "kirsch": "models.kirsch",
    "lattice": "phase",
    "noise": "uncertainty",
    "pipeline": "series",
    "plotting": "post",
    "report": "post",
    "screening": "stacks.screening",
    "sequences": "io",
    "synthetic": "models.synthetic",
    "vibration": "stacks.vibration",
    "wft": "phase",
}


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """``import gridstrain.OLD`` gives the module that holds OLD's names now, and warns."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, old = fullname.rpartition(".")
        if package == __name__ and old in _MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        old = spec.name.rpartition(".")[2]
        new = f"{__name__}.{_MOVED[old]}"
        warnings.warn(f"{spec.name} is deprecated and will be removed in the next release: "
                      f"import from {new}", DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module):
        pass  # the module it gives is already loaded


if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
    sys.meta_path.append(_MovedFinder())
