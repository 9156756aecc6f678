"""The vibrations of a series: the rigid shift of every frame and what they do to the maps.

Public path of :mod:`gridstrain.stacks.vibration`, where they are implemented.
"""

from __future__ import annotations

from .stacks.vibration import (
    VibrationReport as VibrationReport,
)
from .stacks.vibration import (
    frame_shifts as frame_shifts,
)
from .stacks.vibration import (
    vibration_report as vibration_report,
)

__all__ = ['VibrationReport', 'frame_shifts', 'vibration_report']
