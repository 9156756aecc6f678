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

from ._accumulators import StackResult
from ._methods import (
    circular_offset_std,
    correct_phases,
    mean_image,
    method_a,
    method_b,
    method_c,
    prefix_stacks,
)

__all__ = [
    "StackResult",
    "circular_offset_std",
    "correct_phases",
    "mean_image",
    "method_a",
    "method_b",
    "method_c",
    "prefix_stacks",
]
