"""What a series measurement keeps of each series: its kept frames' statistics, its phase
maps and screening (``_Measured``), and what the result keeps once the maps are dropped
(``_Summary``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .._stats import median
from ..phase import PhaseMaps, filled_box
from ..stacks.screening import FrameScreen
from ..stacks.vibration import VibrationReport
from ._outliers import _saturation_warning, _Screened


def _median_modulus(pm: PhaseMaps, valid: np.ndarray) -> np.ndarray:
    sel = valid if valid.any() else pm.valid
    if not sel.any():
        return np.full(2, np.nan)
    # the moduli of the selected pixels only (|Psi| value by value, the same numbers):
    # the box they fill sliced, else gathered
    box = filled_box(sel)
    at = sel if box is None else np.s_[box[0]:box[1], box[2]:box[3]]
    return np.array([median(np.abs(pm.psi[j][at]), overwrite_input=True)
                     for j in range(2)])


@dataclass(frozen=True)
class _Stats:
    mean: np.ndarray
    variance: np.ndarray | None  # per-pixel noise variance of one frame, grey levels^2
    variance_method: str
    saturation: float


@dataclass(frozen=True, eq=False)
class _Summary:
    """What the result keeps of a series once its maps are dropped."""

    name: str
    sources: tuple
    T: int
    bit_depth: int | None
    scale: int
    saturation: float
    excluded: tuple
    screening: FrameScreen
    vib: VibrationReport
    variance: float  # mean per-frame noise variance over the valid pixels
    variance_method: str
    modulus: np.ndarray  # (2,) median |Psi|
    kept_flagged: bool
    saturation_warnings: tuple
    offset: dict | None = None  # the vibration offset removed (methods A and B)


@dataclass(frozen=True, eq=False)
class _Measured:
    """One series measured: its kept frames, screening, statistics and phase maps."""

    series: object
    screen: _Screened
    vib: VibrationReport
    stats: _Stats
    maps: PhaseMaps
    mask: np.ndarray  # the pixels the maps were computed on
    warnings: tuple
    offset: dict | None = None  # the vibration offset removed (methods A and B)

    @property
    def name(self) -> str:
        return self.series.name

    def dropping(self, *names: str) -> _Measured:
        """This series without the statistics maps ``names`` ("mean", "variance"),
        once nothing needs them (each is a float64 image)."""
        return dataclasses.replace(self, stats=dataclasses.replace(
            self.stats, **dict.fromkeys(names)))

    def without_derivatives(self) -> _Measured:
        """This series with its maps' phase derivatives dropped (an unstored NaN view
        in their place), once its kinematics are done: the rest needs only Psi."""
        pm = self.maps
        nan = np.broadcast_to(np.array(np.nan, dtype=pm.dphi.dtype), pm.dphi.shape)
        return dataclasses.replace(self, maps=dataclasses.replace(pm, dphi=nan))

    def summary(self) -> _Summary:
        s, sc, st, pm = self.series, self.screen, self.stats, self.maps
        var = float(np.mean(st.variance[pm.valid])) if st.variance is not None \
            and pm.valid.any() else math.nan
        sat = max(st.saturation, sc.saturation)
        return _Summary(name=s.name, sources=tuple(str(p) for p in s.paths), T=s.n_frames,
                        bit_depth=s.bit_depth, scale=int(s.scale), saturation=sat,
                        excluded=sc.excluded, screening=sc.screen, vib=self.vib,
                        variance=var, variance_method=st.variance_method,
                        modulus=_median_modulus(pm, pm.valid),
                        kept_flagged=sc.kept_flagged,
                        saturation_warnings=tuple(_saturation_warning(s, sc, sat)),
                        offset=self.offset)
