"""Screening the frames of a series: what is measured on every frame and what is decided.

Public path of :mod:`gridstrain.stacks.screening`, where the screening is implemented.
"""

from __future__ import annotations

from .stacks.screening import (
    FrameProbe as FrameProbe,
)
from .stacks.screening import (
    FrameRecord as FrameRecord,
)
from .stacks.screening import (
    FrameScreen as FrameScreen,
)
from .stacks.screening import (
    Trend as Trend,
)
from .stacks.screening import (
    decide as decide,
)
from .stacks.screening import (
    screen_frames as screen_frames,
)

__all__ = ['FrameScreen', 'Trend', 'screen_frames']
