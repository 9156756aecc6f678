"""Stacks of grid images: the frames of one static state, averaged into one measurement.

- ``_methods``: methods A (average, then transform), B (transform, then average) and
  C (realign each frame's carriers, then transform), prefix stacks and the phase
  offset correction;
- :mod:`~gridstrain.stacks.accumulate`: one streamed pass over a series gathering every
  sum a measurement needs (``SeriesPass``);
- :mod:`~gridstrain.stacks.vibration`: the rigid shift of every frame (the carrier probe);
- :mod:`~gridstrain.stacks.screening`: what is measured on every frame, and the verdict.
"""

from __future__ import annotations

# shared with gridstrain's other folders, not part of the public API
from ._accumulators import FrameOrder as FrameOrder
from ._accumulators import MeanImage as MeanImage
from ._accumulators import MethodC as MethodC
from ._accumulators import PhaseMean as PhaseMean
from ._accumulators import StackResult
from ._accumulators import with_screening as with_screening
from ._methods import (
    circular_offset_std,
    correct_phases,
    mean_image,
    method_a,
    method_b,
    method_c,
    prefix_stacks,
)
from ._methods import phase_offsets as phase_offsets
from .accumulate import MOTION_TERMS as MOTION_TERMS
from .accumulate import PassPlan, SeriesPass, SeriesStatistics
from .accumulate import motion_regressors as motion_regressors
from .accumulate import nested_motion_fits as nested_motion_fits
from .accumulate import pick_motion_fit as pick_motion_fit
from .screening import FrameScreen, Trend, screen_frames
from .vibration import VibrationReport, frame_shifts, vibration_report

__all__ = [
    "FrameScreen",
    "PassPlan",
    "SeriesPass",
    "SeriesStatistics",
    "StackResult",
    "Trend",
    "VibrationReport",
    "circular_offset_std",
    "correct_phases",
    "frame_shifts",
    "mean_image",
    "method_a",
    "method_b",
    "method_c",
    "prefix_stacks",
    "screen_frames",
    "vibration_report",
]
