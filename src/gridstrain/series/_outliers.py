"""The frames the screening flags, excluded, refused or kept with a warning (``outliers``), and
the advice each flag comes with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..stacks.accumulate import SeriesPass
from ..stacks.screening import CHECKS, FrameScreen, NoGridError

#: What ``outliers`` may say to do with the frames the screening flags.
OUTLIER_POLICIES = ("exclude", "refuse", "warn")


# A screened series keeps the mean image's contrast above this fraction
# (|mean c_t| / mean |c_t|): 0.8 is a vibration of 0.25 pitch / 2 pi ~ 0.2 px std at
# pitch 5, past the second-order theory of the noise floor (Prop. 2.2).
_MIN_COHERENCE = 0.8


@dataclass(frozen=True, eq=False)
class _Screened:
    screen: FrameScreen
    series: object  # the frames kept
    shifts: np.ndarray  # (T_kept, 2) px, centred
    excluded: tuple[int, ...]  # frame numbers
    kept_flagged: bool  # frames flagged but kept (outliers="warn")
    saturation: float  # largest clipped fraction of a kept frame
    clip_level: float  # the level of that frame, NaN when none is clipped
    warnings: tuple[str, ...]


def outlier_verdict(s, sc: FrameScreen, outliers: str) -> tuple[list[int], list[str]]:
    """The frames of series ``s`` to keep after its screening ``sc``, and the warnings
    naming the flagged ones, as ``outliers`` says ("exclude", "refuse" or "warn"; see
    :func:`measure_series`). A strict minority is excluded; when half the frames or
    more are flagged the series is refused whatever the policy but "warn": the good
    frames cannot be told from the bad."""
    n, bad = s.n_frames, sc.flagged
    if not bad:
        return list(range(n)), []
    listed = sc.listing(s.describe_frame)
    if outliers != "warn" and (outliers == "refuse" or 2 * len(bad) >= n):
        why = "" if outliers == "refuse" or len(bad) == n else " (half or more: the " \
            "good frames cannot be told from the bad)"
        raise ValueError(f"{s.name}: {listed} -- {len(bad)} of {n} frame(s) flagged{why}; "
                         f"{_advice(sc, bad)}, or pass outliers='warn' (--outliers warn) "
                         "to measure anyway")
    if outliers == "exclude":
        return ([t for t in range(n) if t not in set(bad)],
                [f"{s.name}: excluded {len(bad)} of {n} frames: {listed}"])
    return list(range(n)), [f"{s.name}: kept {len(bad)} flagged frame(s) of {n} (outliers="
                            f"'warn'): {listed}; the noise floor and uncertainty maps of the "
                            "states measured with them are not stated (NaN)"]


def _screen_pass(s, acc: SeriesPass, max_saturation: float, outliers: str):
    """The screening of the frames of ``s`` from its pass (:meth:`SeriesPass.screen`),
    and the pass once the flagged frames are excluded, refused or kept as ``outliers``
    says: ``(_Screened, pass)``. A strict minority is excluded (read a second time
    to take them out of the sums); when half the frames or more are flagged the
    series is refused whatever the policy but "warn": the good frames cannot be told
    from the bad."""
    n = s.n_frames
    try:
        sc = acc.screen(max_saturation=max_saturation)
    except NoGridError as exc:
        raise ValueError(f"{s.name}: {exc}; a state whose grid turned by more than 17 "
                         "degrees or stretched by more than 30 % from the reference's is "
                         "not followed (gridstrain.phase.follow_lattice): measure it "
                         "against an intermediate state") from None
    except ValueError as exc:
        raise ValueError(f"{s.name}: {exc}") from None
    sequence = []
    if sc.trend is not None and sc.trend.sequence:
        what = (f"{s.name}: its {n} frames are a sequence, not one static state "
                f"({sc.trend.describe()})")
        if outliers != "warn":
            raise ValueError(f"{what}: averaging them would mix states; measure each frame "
                             "as a state of its own with --each-frame (each_frame=True)")
        sequence.append(f"{what}; averaged all the same (outliers='warn'): the maps mix "
                        "the states (--each-frame measures each frame)")
    bad = sc.flagged
    keep, warnings = outlier_verdict(s, sc, outliers)
    warnings = sequence + warnings
    if outliers == "exclude":
        for t in bad:  # the second read of a frame: only for the excluded ones
            # as stored, as the pass read it: taken out exactly as it was added
            acc.remove(t, next(iter(s.frames(dtype=None, start=t, stop=t + 1))))
    kept = s if len(keep) == n else s.subset(keep)
    coh = sc.coherence(keep)
    if len(keep) > 1 and coh.min() < _MIN_COHERENCE:
        warnings.append(f"{s.name}: the frames' rigid shifts leave only {coh.min():.0%} of "
                        "the grid's contrast in their mean (vibrations of a large fraction "
                        "of a pitch): the noise floor's theory does not hold")
    sat = sc.saturated[keep]
    worst = int(np.argmax(sat))
    level = float(sc.clip_level[keep][worst]) if sat[worst] > 0 else math.nan
    return _Screened(screen=sc, series=kept, shifts=sc.shifts(keep),
                     excluded=tuple(s._number(t) for t in bad if outliers == "exclude"),
                     kept_flagged=bool(bad) and outliers == "warn",
                     saturation=float(sat[worst]), clip_level=level,
                     warnings=tuple(warnings)), acc


def _advice(sc, bad) -> str:
    """What to do about the frames ``bad``: the advice of each check they fail."""
    out = []
    for t in bad:
        for flag in sc.flags[t]:
            what = CHECKS[flag].advice
            if what not in out:
                out.append(what)
    return "; ".join(out) or "remove or re-take them"


def _saturation_warning(s, sc: _Screened, saturation: float) -> list[str]:
    if saturation <= 0:
        return []
    lvl = sc.clip_level
    at = "" if not math.isfinite(lvl) else f" (clipped at {lvl:g}" + (
        ")" if s.saturation_level is None or lvl >= s.saturation_level else
        ", a level 2^n - 1 below the files' range: a camera of fewer bits? pass its "
        "bit depth)")
    return [f"{s.name}: up to {saturation:.2%} of a frame's pixels are saturated{at}"]
