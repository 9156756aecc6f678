"""What a test is run for, from the maps of a result: virtual gauges and
extensometers with their standard deviations, elastic constants, histories over
time, animations, figures and the HTML report.

Coordinates follow :mod:`gridstrain.conventions` (x the column, y the row, from
0); strains are dimensionless, loads in the unit the user gives, times in s.

- ``_gauges``, ``_history``, ``_constants``, ``_animate``, ``_loads``: gauges and
  extensometers, histories, E and ν, animations, a test rig's loads;
- ``_places``: the one rule a region, point or polygon is named by (the file's unit
  with a pixel size, else px), checked against the measured field;
- ``_plotting``: the figures (maps on common colour limits, histories, rigid shifts,
  the stress–strain plot);
- ``_report``: the self-contained HTML report of a result.

The figures and the report load matplotlib; their names are imported on first use
(PEP 562), so that the gauges and the command line's other commands do not pay for it.
"""

from __future__ import annotations

import importlib

from ._animate import FORMATS as ANIMATION_FORMATS
from ._animate import animate
from ._constants import ElasticConstants, elastic_constants, modulus_unit, stress_unit
from ._correlation import strain_noise_correlation
from ._gauges import GaugeReading, gauge, reference_share
from ._history import History, history
from ._loads import read_loads
from ._places import frame_of, own_length, place_mask, refuse_empty
from ._units import STRAIN_UNITS, strain_scale

# public name -> private module that defines it, imported on first use
_LAZY = {
    **dict.fromkeys(
        ("QUANTITIES", "ROBUST_PERCENTILES", "capped_dpi", "check_cmap", "check_limits",
         "plot_gauge", "plot_load_strain",
         "chosen_states", "figure_names", "map_norm",
         "plot_history", "plot_map", "plot_shifts", "plot_states", "plot_stress_strain",
         "save_figure", "save_figures"), "_plotting"),
    **dict.fromkeys(("render_report", "write_report"), "_report"),
}

__all__ = ["ANIMATION_FORMATS", "STRAIN_UNITS", "ElasticConstants", "GaugeReading", "History",
           "animate",
           "elastic_constants", "frame_of", "gauge", "history", "modulus_unit",
           "own_length", "place_mask", "read_loads", "refuse_empty",
           "reference_share", "strain_noise_correlation", "strain_scale", "stress_unit",
           *sorted(_LAZY)]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
