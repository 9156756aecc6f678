"""The founding paper's synthetic experiment (Sur & Grédiac 2015, §3.2).

- :mod:`gridstrain.paper.dataset`: the paper's data set, its phase maps, the
  vibration cases and the frames they give (re-exported here).
- :mod:`gridstrain.paper.experiment`: :func:`reproduce`, the experiment itself
  (methods A, B and C against T in every vibration case, with the theory beside the
  measurements), its figures and summary (``gridstrain reproduce``).
"""

# shared with gridstrain's other folders, not part of the public API
from ._summary import fixed_figure as fixed_figure
from .dataset import (
    clean_frame,
    draw_shifts,
    iter_frames,
    mean_image_bias,
    paper_phases,
    vibrated_frame,
    vibration_cases,
)
from .experiment import reproduce

__all__ = [
    "clean_frame",
    "draw_shifts",
    "iter_frames",
    "mean_image_bias",
    "paper_phases",
    "reproduce",
    "vibrated_frame",
    "vibration_cases",
]
