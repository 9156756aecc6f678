"""What a test is run for, from the maps of a result: virtual gauges and
extensometers with their standard deviations, elastic constants, histories over
time, animations and ParaView time series.

Coordinates follow :mod:`gridstrain.conventions` (x the column, y the row, from
0); strains are dimensionless, loads in the unit the user gives, times in s.
"""

from ._animate import animate
from ._constants import ElasticConstants, elastic_constants
from ._correlation import strain_noise_correlation
from ._gauges import GaugeReading, gauge
from ._history import History, history
from ._loads import read_loads
from ._paraview import export_pvd

__all__ = ["ElasticConstants", "GaugeReading", "History", "animate", "elastic_constants",
           "export_pvd", "gauge", "history", "read_loads", "strain_noise_correlation"]
