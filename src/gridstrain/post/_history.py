"""Histories over time: smoothed strain, strain rate, velocity and acceleration of a gauge."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter

from .._validation import check_int, check_type, freeze_arrays
from ..results import FINITE_FIELDS, SeriesResult
from ._gauges import GaugeReading, gauge
from ._places import own_length

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
    gl_xx, gl_yy, gl_xy, log_xx, log_yy, log_xy : ndarray or None
        With ``finite``: the smoothed Green–Lagrange and logarithmic strains of the
        gauge's mean displacement gradient (:meth:`GaugeReading.finite_strains`),
        dimensionless, and their rates ``gl_xx_rate``... (1/s), each with its std;
        else None.
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
    gl_xx: np.ndarray | None = None
    gl_xx_std: np.ndarray | None = None
    gl_yy: np.ndarray | None = None
    gl_yy_std: np.ndarray | None = None
    gl_xy: np.ndarray | None = None
    gl_xy_std: np.ndarray | None = None
    log_xx: np.ndarray | None = None
    log_xx_std: np.ndarray | None = None
    log_yy: np.ndarray | None = None
    log_yy_std: np.ndarray | None = None
    log_xy: np.ndarray | None = None
    log_xy_std: np.ndarray | None = None
    gl_xx_rate: np.ndarray | None = None
    gl_xx_rate_std: np.ndarray | None = None
    gl_yy_rate: np.ndarray | None = None
    gl_yy_rate_std: np.ndarray | None = None
    gl_xy_rate: np.ndarray | None = None
    gl_xy_rate_std: np.ndarray | None = None
    log_xx_rate: np.ndarray | None = None
    log_xx_rate_std: np.ndarray | None = None
    log_yy_rate: np.ndarray | None = None
    log_yy_rate_std: np.ndarray | None = None
    log_xy_rate: np.ndarray | None = None
    log_xy_rate_std: np.ndarray | None = None

    def __post_init__(self):
        freeze_arrays(self)

    @property
    def finite(self) -> bool:
        """Whether the finite strains were smoothed (``history(..., finite=True)``)."""
        return self.gl_xx is not None

    def columns(self) -> dict[str, np.ndarray]:
        """The table, each column name followed by its unit in brackets."""
        u = self.unit
        units = {"exx": "-", "eyy": "-", "exy": "-", "exx_rate": "1/s", "eyy_rate": "1/s",
                 "exy_rate": "1/s", "vx": f"{u}/s", "vy": f"{u}/s", "ax": f"{u}/s2",
                 "ay": f"{u}/s2"}
        if self.finite:
            for name in FINITE_FIELDS:
                units |= {name: "-", f"{name}_rate": "1/s"}
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


def history(reading, *, window: int = 5, order: int = 2,
            pixel_size: float | None = None, unit: str | None = None, px: bool = False,
            finite: bool = False, **places) -> History:
    """Smoothed strains, strain rates, velocity and acceleration of a gauge over time.

    Parameters
    ----------
    reading : GaugeReading or SeriesResult
        A gauge's readings (:func:`gauge`), with the states' times, evenly spaced
        (within 0.1 % of the mean step); or a result, read here by :func:`gauge` with
        ``places`` (``region=``, ``point=``, ``polygon=``, ``load=``, ``time=``...),
        ``unit``, ``pixel_size``, ``px`` and ``finite``.
    window : int
        States in the Savitzky-Golay window: odd, more than ``order``, at most the
        number of states.
    order : int
        Degree of the fitted polynomial, at least 2 (for the acceleration).
    pixel_size, unit : float, str, optional
        The velocity and acceleration in ``unit``: the gauge's result's own length
        unit (``"mm"``, :attr:`GaugeReading.unit`), whose pixel size is used; with
        ``pixel_size`` too, for a reading whose result carries none (one that carries
        another is refused, naming both).
    px : bool
        The velocity and acceleration in px (and, for a result, the places in px).
        A reading whose result has a pixel size must say which (``unit=`` or
        ``px=True``): without either the call is refused, naming both, since it once
        gave px/s and the command line gives the file's unit. Without a pixel size,
        px.
    finite : bool
        Also smooth and differentiate the Green–Lagrange and logarithmic strains
        (:meth:`GaugeReading.finite_strains`; a reading taken with ``finite=True``).

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
    derivative by up to sqrt(2). The finite strains' std are propagated the same
    way, their first-order std (:func:`gridstrain.kinematics.finite_strains`) split
    by the same share: to first order they are linear in the displacement gradient,
    whose noise is shared alike.
    """
    finite = check_type(finite, "finite", bool)
    if isinstance(reading, SeriesResult):
        reading = gauge(reading, pixel_size=pixel_size, unit=unit, px=px, finite=finite,
                        **places)
    elif places:
        raise TypeError(f"{', '.join(sorted(places))} name a place on a result: give "
                        "them to gauge(), or give history() the result itself")
    check_type(reading, "reading", GaugeReading)
    window = check_int(window, "window", minimum=3)
    order = check_int(order, "order", minimum=2)
    ps, unit = _velocity_length(reading, pixel_size=pixel_size, unit=unit, px=px)
    t = reading.time
    if t is None:
        raise ValueError("the gauge has no times: give them (--loads FILE.csv with a "
                         "'time [s]' column, or gauge(..., time=...)), or measure the "
                         "record with the camera's --frame-rate HZ")
    n = t.size
    if window % 2 == 0 or window <= order or window > n:
        raise ValueError(f"window must be odd, above order ({order}) and at most the "
                         f"number of states ({n}), got {window}")
    dt = np.diff(t)
    step = float(dt.mean())
    if np.max(np.abs(dt - step)) > _UNIFORM * step:
        # name where it breaks: a dropped frame is one step twice the others
        k = int(np.argmax(np.abs(dt - float(np.median(dt)))))
        raise ValueError(f"time must be evenly spaced for the Savitzky-Golay filter "
                         f"(steps from {dt.min():.6g} to {dt.max():.6g} s; "
                         f"{dt[k]:.6g} s from {reading.states[k]} to "
                         f"{reading.states[k + 1]}: a frame missing, or a state of "
                         "another time, there)")
    s = 1.0 if ps is None else ps
    f = reading.reference_share
    strains = {name: (getattr(reading, name), getattr(reading, f"{name}_std"))
               for name in ("exx", "eyy", "exy")}
    if finite:
        fs = reading.finite_strains()  # refused, saying why, without the rotation
        strains |= {name: (getattr(fs, attr), _std(getattr(fs, f"{attr}_std"), n))
                    for name, attr in FINITE_FIELDS.items()}
    out = {}
    for name, (x, e) in strains.items():
        out[name], out[f"{name}_std"] = _apply(x, e, window, order, 0, step, f)
        out[f"{name}_rate"], out[f"{name}_rate_std"] = _apply(x, e, window, order, 1, step,
                                                              f)
    for comp in ("x", "y"):
        x, e = getattr(reading, f"u{comp}") * s, getattr(reading, f"u{comp}_std") * s
        out[f"v{comp}"], out[f"v{comp}_std"] = _apply(x, e, window, order, 1, step, f)
        out[f"a{comp}"], out[f"a{comp}_std"] = _apply(x, e, window, order, 2, step, f)
    return History(states=reading.states, time=t, window=window, order=order,
                   unit=unit or "px", **out)


def _std(value, n):
    """A std that may be None (no uncertainty maps) as NaN: the readings' convention."""
    return np.full(n, np.nan) if value is None else np.asarray(value, dtype=np.float64)


def _velocity_length(reading, *, pixel_size, unit, px):
    """``(pixel_size, unit)`` of the velocities, ``(None, None)`` for px: the rule of
    places (:func:`gridstrain.post._places.result_frame`) on the reading's result."""
    own_ps, own_unit = reading.pixel_size, reading.unit
    if check_type(px, "px", bool):
        if pixel_size is not None or unit is not None:
            raise ValueError(f"px=True gives the velocities in px/s: give it without "
                             f"pixel_size and unit, got pixel_size={pixel_size!r}, "
                             f"unit={unit!r}")
        return None, None
    if pixel_size is None and unit is None and own_ps is not None:
        raise ValueError(
            f"the velocities do not say their unit, and this gauge's result has a pixel "
            f"size ({own_ps:g} {own_unit}): write unit={own_unit!r} for {own_unit}/s, as "
            "the command line gives them, or px=True for px/s")
    return own_length(own_ps, own_unit, pixel_size=pixel_size, unit=unit,
                      what="this gauge's result")
