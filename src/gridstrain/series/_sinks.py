"""Where a series measurement puts each state's maps: kept in memory for the result, or
written to the result file as measured.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..kinematics import FringeOrder, Measurement
from ..results import SeriesResult


def empty_state_message(name: str, margin: float, sigma: float, guess, source: str) -> str:
    """Why a state without a single valid pixel is refused (never a written result)."""
    return (f"{name}: no valid pixel, nothing written: the mask, the band of margin = "
            f"{margin:g} sigmas (sigma {sigma:.4g} px), the grid's modulus and the "
            f"displacement (guess {guess[0]:.4g}, {guess[1]:.4g} px, {source}) leave no "
            "pixel to measure")


def _streamed(output, n_states: int):
    from ..results import StreamedResult

    return StreamedResult(output, n_states)


def _as_dtype(res: Measurement, unc, dtype):
    """The maps of a state in ``dtype`` (None: as they are)."""
    if dtype is None or res.u.dtype == dtype:
        return res, unc
    res = dataclasses.replace(res, u=res.u.astype(dtype), strain=res.strain.astype(dtype),
                              rotation=res.rotation.astype(dtype))
    return res, None if unc is None else {k: v.astype(dtype) for k, v in unc.items()}


class _InMemory:
    """Collects the states' maps for a :class:`SeriesResult` held in memory."""

    def __init__(self, n_states: int, dtype=None):
        self.n, self.dtype = n_states, dtype
        self.measurements, self.orders, self.unc = [], [], []
        self.floors, self.smoothing = [], []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def add(self, i: int, res: Measurement, rec: FringeOrder, unc, floors: dict,
            smooth: dict) -> None:
        res, unc = _as_dtype(res, unc, self.dtype)
        self.measurements.append(res)
        self.orders.append(rec)
        self.unc.append(unc)
        self.floors.append(floors)
        self.smoothing.append(smooth)

    def reader(self, i: int):
        """None: the maps of state ``i`` are held here already."""
        return None

    def result(self, **fields) -> SeriesResult:
        ms = self.measurements
        uncertainty = None
        have = [a for a in self.unc if a is not None]
        if have:
            uncertainty = {k: np.stack([a[k] if a is not None else
                                        np.full_like(have[0][k], np.nan) for a in self.unc])
                           for k in have[0]}
        return SeriesResult(
            u=np.stack([r.u for r in ms]), strain=np.stack([r.strain for r in ms]),
            valid=np.stack([r.valid for r in ms]), measurements=tuple(ms),
            guesses=tuple(tuple(float(v) for v in r.guess) for r in self.orders),
            guess_sources=tuple(r.source for r in self.orders),
            fringe_orders=tuple(self.orders), uncertainty=uncertainty, **fields)
