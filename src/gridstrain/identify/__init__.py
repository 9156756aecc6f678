"""Material parameters from the measured fields: the stress gauge of an image-based
inertial impact test (:func:`stress_gauge`, :func:`stress_gauge_of`).

Lengths in the result's unit, density in kg/m^3, times in s, stresses and moduli in
MPa; coordinates follow :mod:`gridstrain.conventions`.
"""

from ._stress_gauge import StressGauge, stress_gauge, stress_gauge_of

__all__ = ["StressGauge", "stress_gauge", "stress_gauge_of"]
