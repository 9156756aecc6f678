"""Material parameters from measured fields.

- **The virtual fields method** (``_models``, ``_mesh``, ``_vfm``, ``_identify``,
  ``_result``): a heterogeneous test (an open hole, a notch, a beam in bending) gives
  both elastic constants from one measurement when the principle of virtual work is
  written with virtual fields over the measured strains (:func:`virtual_fields` on
  arrays, :func:`identify` on a result). The special virtual fields of least noise
  sensitivity (Avril & Pierron 2004) are computed from the data, so that the result
  does not depend on a user's choice of fields; the intervals come from the strain
  maps' std through those fields.
- **The stress gauge** of an image-based inertial impact test (``_stress_gauge``,
  :func:`stress_gauge`, :func:`stress_gauge_of`): the mean stress of every
  cross-section from the accelerations, and Young's modulus at the record's strain rate.

Conventions: :mod:`gridstrain.conventions` (x the column, y the row downward); a
state's load is the component along +x or +y of the resultant force that acts on the
specimen through the loaded edge (a tensile test loaded on the right is positive);
lengths in the result's unit, loads in N, density in kg/m^3, times in s; with loads in
N and lengths in mm the moduli and stresses are in MPa.
"""

from ._identify import VirtualFields, virtual_fields
from ._result import identify
from ._stress_gauge import StressGauge, stress_gauge, stress_gauge_of
from ._vfm import NotIdentifiable

__all__ = ["NotIdentifiable", "StressGauge", "VirtualFields", "identify", "stress_gauge",
           "stress_gauge_of", "virtual_fields"]
