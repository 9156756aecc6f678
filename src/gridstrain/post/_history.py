"""Histories over time: smoothed strain, strain rate, velocity and acceleration of a gauge."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter

from .._validation import check_int, check_pixel_size, check_type, freeze_arrays
from ._gauges import GaugeReading

#: Largest departure of a time step from the mean step, relative: the
#: Savitzky-Golay weights assume evenly spaced samples.
_UNIFORM = 1e-3


def _operator_rows(n: int, window: int, order: int, deriv: int, delta: float):
    """``(edge_first, centre, edge_last)`` weights of the filter (mode "interp").

    The filter is linear: output ``i`` is ``sum_j A[i, j] x_j``. Within half a
    window of the ends it is the fitted polynomial of the first (last) ``window``
    samples; elsewhere the centre row slides.
    """
    E = savgol_filter(np.eye(window), window, order, deriv=deriv, delta=delta, axis=0,
                      mode="interp")
    h = window // 2
    return E[:h], E[h], E[window - h:]


def _apply(x, s, window, order, deriv, delta, share=None):
    """The filtered series and its std.

    ``s``: each sample's std; ``share``: the part of its variance common to all
    samples (fully correlated, the reference's), None for independent samples.
    An output of weights ``w`` has the variance ``sum w_j^2 (1 - f_j) s_j^2 +
    (sum w_j sqrt(f_j) s_j)^2``.
    """
    n = x.size
    first, centre, last = _operator_rows(n, window, order, deriv, delta)
    h = window // 2
    f = np.zeros(n) if share is None else share
    own, common = s**2 * (1.0 - f), s * np.sqrt(f)
    y, v, c = np.empty(n), np.empty(n), np.empty(n)
    for rows, sl, out in ((first, slice(0, window), slice(0, h)),
                          (last, slice(n - window, n), slice(n - h, n))):
        y[out], v[out], c[out] = rows @ x[sl], (rows**2) @ own[sl], rows @ common[sl]
    if n > 2 * h:
        def slide(a):
            return np.lib.stride_tricks.sliding_window_view(a, window)

        mid = slice(h, n - h)
        y[mid], v[mid], c[mid] = slide(x) @ centre, slide(own) @ centre**2, \
            slide(common) @ centre
    return y, np.sqrt(v + c**2)


@dataclass(frozen=True)
class History:
    """A gauge's readings over time, smoothed and differentiated.

    Every array is ``(n_states,)``, with its std ``<name>_std`` beside it.

    Attributes
    ----------
    states : tuple of str
    time : ndarray
        s.
    window, order : int
        The Savitzky-Golay filter: a polynomial of degree ``order`` fitted by
        least squares to ``window`` consecutive states (the first and last
        ``window // 2`` states use the polynomial of the first or last window).
    exx, eyy, exy : ndarray
        Smoothed strains, dimensionless.
    exx_rate, eyy_rate, exy_rate : ndarray
        Strain rates, 1/s.
    vx, vy : ndarray
        Velocity of the gauge's mean displacement, ``unit``/s.
    ax, ay : ndarray
        Its acceleration, ``unit``/s^2.
    unit : str
        Length unit (px without a pixel size).
    """

    states: tuple[str, ...]
    time: np.ndarray
    window: int
    order: int
    unit: str
    exx: np.ndarray
    exx_std: np.ndarray
    eyy: np.ndarray
    eyy_std: np.ndarray
    exy: np.ndarray
    exy_std: np.ndarray
    exx_rate: np.ndarray
    exx_rate_std: np.ndarray
    eyy_rate: np.ndarray
    eyy_rate_std: np.ndarray
    exy_rate: np.ndarray
    exy_rate_std: np.ndarray
    vx: np.ndarray
    vx_std: np.ndarray
    vy: np.ndarray
    vy_std: np.ndarray
    ax: np.ndarray
    ax_std: np.ndarray
    ay: np.ndarray
    ay_std: np.ndarray

    def __post_init__(self):
        freeze_arrays(self)

    def columns(self) -> dict[str, np.ndarray]:
        """The table, each column name followed by its unit in brackets."""
        u = self.unit
        units = {"exx": "-", "eyy": "-", "exy": "-", "exx_rate": "1/s", "eyy_rate": "1/s",
                 "exy_rate": "1/s", "vx": f"{u}/s", "vy": f"{u}/s", "ax": f"{u}/s2",
                 "ay": f"{u}/s2"}
        cols: dict[str, np.ndarray] = {"state": np.array(self.states, dtype=str),
                                       "time [s]": self.time}
        for name, unit in units.items():
            cols[f"{name} [{unit}]"] = getattr(self, name)
            cols[f"{name}_std [{unit}]"] = getattr(self, f"{name}_std")
        return cols

    def to_csv(self, path, *, overwrite: bool = False):
        """Write :meth:`columns` to a CSV file, atomically; returns its path."""
        from ..io import write_csv

        return write_csv(path, self.columns(), overwrite=overwrite, digits=10)


def history(reading: GaugeReading, *, window: int = 5, order: int = 2,
            pixel_size: float | None = None, unit: str | None = None) -> History:
    """Smoothed strains, strain rates, velocity and acceleration of a gauge over time.

    Parameters
    ----------
    reading : GaugeReading
        With the states' times (:func:`gauge`'s ``time``), evenly spaced (within
        0.1 % of the mean step).
    window : int
        States in the Savitzky-Golay window: odd, more than ``order``, at most the
        number of states.
    order : int
        Degree of the fitted polynomial, at least 2 (for the acceleration).
    pixel_size, unit : float, str, optional
        Velocity and acceleration in ``unit`` (px without).

    Returns
    -------
    History

    Notes
    -----
    The filter (:func:`scipy.signal.savgol_filter`, mode "interp") is linear.
    Every state is measured against the same reference image, whose noise is
    common to all of them (``GaugeReading.reference_share`` of each variance):
    with weights ``w``, an output's variance is ``sum_j w_j^2 (1 - f_j) s_j^2 +
    (sum_j w_j sqrt(f_j) s_j)^2``. The common part cancels in a derivative (its
    weights sum to zero) and stays whole in the smoothed strain. Without the
    share, the states are taken as independent, which overstates the std of a
    derivative by up to sqrt(2).
    """
    check_type(reading, "reading", GaugeReading)
    window = check_int(window, "window", minimum=3)
    order = check_int(order, "order", minimum=2)
    ps, unit = check_pixel_size(pixel_size, unit)
    t = reading.time
    if t is None:
        raise ValueError("the gauge has no times: give them (--loads FILE.csv with a "
                         "'time [s]' column, or gauge(..., time=...))")
    n = t.size
    if window % 2 == 0 or window <= order or window > n:
        raise ValueError(f"window must be odd, above order ({order}) and at most the "
                         f"number of states ({n}), got {window}")
    dt = np.diff(t)
    step = float(dt.mean())
    if np.max(np.abs(dt - step)) > _UNIFORM * step:
        raise ValueError(f"time must be evenly spaced for the Savitzky-Golay filter "
                         f"(steps from {dt.min():.6g} to {dt.max():.6g} s)")
    s = 1.0 if ps is None else ps
    f = reading.reference_share
    out = {}
    for name in ("exx", "eyy", "exy"):
        x, e = getattr(reading, name), getattr(reading, f"{name}_std")
        out[name], out[f"{name}_std"] = _apply(x, e, window, order, 0, step, f)
        out[f"{name}_rate"], out[f"{name}_rate_std"] = _apply(x, e, window, order, 1, step,
                                                              f)
    for comp in ("x", "y"):
        x, e = getattr(reading, f"u{comp}") * s, getattr(reading, f"u{comp}_std") * s
        out[f"v{comp}"], out[f"v{comp}_std"] = _apply(x, e, window, order, 1, step, f)
        out[f"a{comp}"], out[f"a{comp}_std"] = _apply(x, e, window, order, 2, step, f)
    return History(states=reading.states, time=t, window=window, order=order,
                   unit=unit or "px", **out)
