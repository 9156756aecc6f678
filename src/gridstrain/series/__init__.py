"""The measurement of a series of grid images: the loop that orchestrates the others.

- ``_loop``: :func:`measure_series`, its options checked once at the door and the loop
  over the series and the states;
- ``_inputs``: the frames, guesses, names, mask, loads and times, checked together;
- ``_passes``: the lattice, one streamed pass per series and its phase maps;
- ``_outliers``: the frames the screening flags, and what is done with them;
- ``_records``: what is kept of each series measured;
- ``_floors``: the noise floors of the maps;
- ``_sinks``: the states' maps kept in memory or written as measured.

The public path of :func:`measure_series` is :mod:`gridstrain.pipeline`.
"""

from __future__ import annotations

from ._inputs import state_names
from ._loop import ORDERS, MeasureOptions, measure_series
from ._outliers import OUTLIER_POLICIES
from ._passes import reference_lattice
from ._sinks import empty_state_message

__all__ = ["ORDERS", "OUTLIER_POLICIES", "MeasureOptions", "empty_state_message", "measure_series",
           "reference_lattice", "state_names"]
