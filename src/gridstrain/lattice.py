"""The lattice of a grid image: its two wave vectors, detected or followed.

Public path of :mod:`gridstrain.phase.lattice`, where the lattice is implemented.
"""

from __future__ import annotations

from .phase import Lattice, detect_lattice, follow_lattice

__all__ = ["Lattice", "detect_lattice", "follow_lattice"]
