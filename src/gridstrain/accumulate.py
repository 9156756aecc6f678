"""One streamed pass over a series: every sum the measurement needs from one read.

Public path of :mod:`gridstrain.stacks.accumulate`, where the pass is implemented.
"""

from __future__ import annotations

from .stacks.accumulate import (
    PassPlan as PassPlan,
)
from .stacks.accumulate import (
    SeriesPass as SeriesPass,
)
from .stacks.accumulate import (
    SeriesStatistics as SeriesStatistics,
)

__all__ = ['PassPlan', 'SeriesPass', 'SeriesStatistics']
