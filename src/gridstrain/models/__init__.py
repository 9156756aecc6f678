"""Models of what a camera sees and of what a specimen does, for tests, examples and
the paper's experiment.

- :mod:`gridstrain.models.synthetic`: the grid image model (the paper's eq. 1), a
  deformed grid rendered at the positions a displacement field gives, and the
  camera's noise;
- :mod:`gridstrain.models.kirsch`: the analytic field of an infinite plate with a
  circular hole in uniaxial tension (Kirsch), a measurement's oracle.
"""

from __future__ import annotations

from . import kirsch, synthetic
from .synthetic import PROFILES, add_noise, deformed_positions, grid_image, line_profile

__all__ = ["PROFILES", "add_noise", "deformed_positions", "grid_image", "kirsch",
           "line_profile", "synthetic"]
