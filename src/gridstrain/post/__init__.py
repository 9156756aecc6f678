"""What a test is run for, from the maps of a result: virtual gauges and
extensometers with their standard deviations, elastic constants, histories over
time, animations and ParaView time series.

Coordinates follow :mod:`gridstrain.conventions` (x the column, y the row, from
0); strains are dimensionless, loads in the unit the user gives, times in s.
"""

from ._animate import animate
from ._constants import ElasticConstants, elastic_constants, modulus_unit, stress_unit
from ._gauges import GaugeReading, gauge
from ._history import History, history
from ._loads import read_loads
from ._paraview import export_pvd
from ._units import STRAIN_UNITS, strain_scale

__all__ = ["STRAIN_UNITS", "ElasticConstants", "GaugeReading", "History", "animate",
           "elastic_constants", "export_pvd", "gauge", "history", "modulus_unit",
           "read_loads", "strain_scale", "stress_unit"]
