"""Material parameters from measured fields: the virtual fields method.

A heterogeneous test (an open hole, a notch, a beam in bending) gives both elastic
constants from one measurement when the principle of virtual work is written with
virtual fields over the measured strains (:func:`virtual_fields` on arrays,
:func:`identify` on a result). The special virtual fields of least noise sensitivity
(Avril & Pierron 2004) are computed from the data, so that the result does not depend on
a user's choice of fields; the intervals come from the strain maps' std through those
fields.

Conventions: :mod:`gridstrain.conventions` (x the column, y the row downward); a
state's load is the component along +x or +y of the resultant force that acts on the
specimen through the loaded edge (a tensile test loaded on the right is positive); with
loads in N and lengths in mm the moduli are in MPa.

Modules
    ``_models`` the stiffness models (isotropic plane stress; an orthotropic one is the
    same shape); ``_mesh`` the piecewise bilinear virtual fields and their kinematic
    conditions; ``_vfm`` the optimal special fields; ``_identify`` the states combined,
    the intervals and the refusals; ``_result`` a measured result's maps and loads.
"""

from ._identify import VirtualFields, virtual_fields
from ._result import identify
from ._vfm import NotIdentifiable

__all__ = ["NotIdentifiable", "VirtualFields", "identify", "virtual_fields"]
