"""Figures of displacement and strain maps and of vibrations, drawn off-screen.

Figures are built on :class:`matplotlib.figure.Figure` with the Agg canvas, never
through ``pyplot``: no window, no global state, no backend to configure, safe in
scripts and on servers. Maps follow :mod:`gridstrain.conventions`: ``x`` is the
column (to the right), ``y`` the row (downwards), as in the image, with no flip.

Map style (one for ``--figures``, ``gridstrain plot`` and the report: :func:`map_norm`)
    A diverging colormap (``RdBu_r``) centred on zero (white) with symmetric
    limits only when both signs matter: each holds more than 5 % of the range
    drawn. Otherwise a sequential colormap (``viridis``) spans the values, so that
    a tensile strain with a few slightly negative noise pixels is not drawn as if
    those pixels were as strong as the tension. The colour bar is linear, so both
    halves of a diverging bar carry ticks. Strains are drawn in µε, rotations in
    mrad, displacements in px or, with a pixel size, in its unit; displacement
    maps of :func:`save_figures` have their mean over the valid pixels removed
    (and stated on the colour bar): a rigid translation would otherwise fill the
    map with one colour. The states of a series share one norm per quantity.
    Invalid pixels are transparent over the grid image in grey.

Colour limits (the same default in every figure, animation and the report)
    ``"robust"`` (default): the 0.5th and 99.5th percentiles of the valid values of
    every state (:data:`ROBUST_PERCENTILES`), so that a few edge pixels do not wash
    a 100-2000 µε field out to ±3500 µε; ``"common"``: their full range; or two
    numbers ``(low, high)`` in the unit drawn. A diverging map spans the larger
    side of either. ``cmap`` replaces the colormap chosen.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import CenteredNorm, Normalize
from matplotlib.figure import Figure

from .._stats import streamed_percentiles
from .._validation import check_choice, check_finite, check_pixel_size, check_positive, check_type
from ..io import OutputDirectory, write_atomic
from ..results import FINITE_FIELDS, SeriesResult

__all__ = [
    "ROBUST_PERCENTILES",
    "capped_dpi",
    "check_cmap",
    "check_limits",
    "chosen_states",
    "figure_names",
    "map_norm",
    "plot_gauge",
    "plot_load_strain",
    "plot_map",
    "plot_shifts",
    "plot_stress_strain",
    "save_figure",
    "save_figures",
]

# Grey-level percentiles mapped to black and white in the background image.
_GREY_PERCENTILES = (1.0, 99.0)
_DPI = 100
#: The colour limits a map may take by name; a pair ``(low, high)`` gives them
#: explicitly (:func:`check_limits`).
LIMITS = ("common", "robust")
#: Robust limits: these percentiles of the valid values of all states.
ROBUST_PERCENTILES = (0.5, 99.5)
_ROBUST = ROBUST_PERCENTILES


def check_limits(limits, *, name: str = "limits"):
    """``limits`` checked: ``"common"``, ``"robust"`` or ``(low, high)`` floats.

    Returns the name, or the pair as a tuple of two finite floats with
    ``low < high`` (the values drawn at the two ends of the colour bar, in the unit
    the map is drawn in: µε for strains by default).
    """
    if isinstance(limits, str):
        return check_choice(limits, name, tuple(LIMITS))
    try:
        lo, hi = (float(v) for v in limits)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 'common', 'robust' or a pair (low, high) of "
                         f"numbers, got {limits!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"{name} must be a pair (low, high) of finite numbers with low < "
                         f"high, got ({lo:g}, {hi:g})")
    return lo, hi


def check_cmap(cmap, *, name: str = "cmap"):
    """``cmap`` checked: None (gridstrain's choice, :func:`colormap`) or the name of a
    matplotlib colormap."""
    if cmap is None:
        return None
    if not isinstance(cmap, str) or cmap not in colormaps:
        raise ValueError(f"{name} must name a matplotlib colormap (viridis, RdBu_r, "
                         f"coolwarm, cividis...), got {cmap!r}")
    return cmap

#: Symbol and kind of each map of :data:`gridstrain.results.MAP_FIELDS`.
_FIELDS = {
    "ux": (r"$u_x$", "displacement"),
    "uy": (r"$u_y$", "displacement"),
    "exx": (r"$\varepsilon_{xx}$", "strain"),
    "eyy": (r"$\varepsilon_{yy}$", "strain"),
    "exy": (r"$\varepsilon_{xy}$", "strain"),
}


def _new_figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=_DPI)
    FigureCanvasAgg(fig)
    return fig


#: Both signs "matter" (diverging map) when each holds more than this fraction of
#: the range drawn.
_BOTH_SIGNS = 0.05


def map_norm(values, *, valid=None, limits="robust") -> Normalize:
    """The colour norm of a map (or of all the states of a series) in gridstrain's style.

    Parameters
    ----------
    values : array_like
        The values drawn (any shape; NaN ignored).
    valid : bool array_like, optional
        The pixels that count (default: the finite ones).
    limits : {"robust", "common"} or (float, float)
        The 0.5th to 99.5th percentiles of the valid values (the default: a few
        outliers then do not wash the maps out), their full range, or the two ends
        given, in the unit of ``values``.

    Returns
    -------
    matplotlib.colors.Normalize
        A :class:`~matplotlib.colors.CenteredNorm` about 0 spanning the larger
        side when each sign holds more than 5 % of the range between the 0.5th
        and 99.5th percentiles (drawn with the
        diverging ``RdBu_r``); else a linear
        :class:`~matplotlib.colors.Normalize` over the range (drawn with the
        sequential ``viridis``). :func:`colormap` gives the colormap of a norm.
        Explicit limits: centred on 0 when ``low == -high``, else linear over them.
    """
    limits = check_limits(limits)
    if not isinstance(limits, str):
        return _norm(*limits, *limits, limits)
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(v) if valid is None else np.asarray(valid, dtype=bool) & np.isfinite(v)
    v = v[ok]
    if v.size == 0:
        return CenteredNorm(0.0, 1.0)
    r_lo, r_hi = (float(x) for x in np.percentile(v, _ROBUST))
    return _norm(float(v.min()), float(v.max()), r_lo, r_hi, limits)


def states_norm(values_of: Callable, n: int, *, limits="robust") -> Normalize:
    """:func:`map_norm` of the valid values of ``n`` states, ``values_of(i)`` giving
    state ``i``'s ``(values, valid)``: read one state at a time (a record of
    thousands of states is never in memory at once), the same norm."""
    limits = check_limits(limits)
    if not isinstance(limits, str):
        return _norm(*limits, *limits, limits)

    def chunks():
        for i in range(n):
            values, valid = values_of(i)
            v = np.asarray(values, dtype=np.float64)
            yield v[np.asarray(valid, dtype=bool) & np.isfinite(v)]

    count, lo, hi, (r_lo, r_hi) = streamed_percentiles(chunks, _ROBUST)
    if count == 0:
        return CenteredNorm(0.0, 1.0)
    return _norm(lo, hi, float(r_lo), float(r_hi), limits)


def _norm(v_min: float, v_max: float, r_lo: float, r_hi: float, limits) -> Normalize:
    """:func:`map_norm` from the extremes and the robust percentiles of the values."""
    if not isinstance(limits, str):  # given: drawn as asked
        lo, hi = limits
        return CenteredNorm(0.0, hi) if lo == -hi else Normalize(lo, hi)
    # the signs that matter are judged without the outliers: a few noise pixels of
    # the other sign do not make a one-signed field diverging
    lo, hi = (v_min, v_max) if limits == "common" else (r_lo, r_hi)
    if r_lo < 0 < r_hi and min(-r_lo, r_hi) > _BOTH_SIGNS * (r_hi - r_lo):
        return CenteredNorm(0.0, max(-lo, hi))
    if hi <= lo:
        pad = abs(hi) * 1e-6 or 1.0
        lo, hi = lo - pad, hi + pad
    return Normalize(lo, hi)


def colormap(norm, cmap: str | None = None):
    """``cmap``, else ``RdBu_r`` for a norm centred on 0 and ``viridis`` otherwise;
    invalid pixels transparent."""
    name = check_cmap(cmap) or ("RdBu_r" if isinstance(norm, CenteredNorm) else "viridis")
    return colormaps[name].with_extremes(bad=(0.0, 0.0, 0.0, 0.0))


def plot_map(values, *, valid=None, background=None, label: str = "", unit: str = "",
             title: str = "", pixel_size: float | None = None, length_unit: str = "px",
             limit: float | None = None, offset: float = 0.0, norm=None,
             cmap: str | None = None) -> Figure:
    """A map over the grid image, in the style of :func:`map_norm`.

    Parameters
    ----------
    values : (H, W) array_like
        The field (NaN where undefined).
    valid : (H, W) bool array_like, optional
        Pixels to colour; the others are transparent. Default: finite values.
    background : (H, W) array_like, optional
        Grey image drawn under the map (the reference grid image).
    label : str
        Name of the quantity, for the colour bar (mathtext allowed).
    unit : str
        Unit of the values, for the colour bar (``"px"``, ``"mm"``, ``""`` for a
        dimensionless quantity).
    title : str
        Figure title.
    pixel_size : float, optional
        Pixel size in ``length_unit``: the axes are then in that unit.
    length_unit : str
        Unit of the axes (``"px"`` without ``pixel_size``).
    limit : float, optional
        A diverging map over ``[-limit, limit]``, centred on 0.
    offset : float
        Subtracted from the values before drawing (stated on the colour bar).
    norm : matplotlib.colors.Normalize, optional
        The norm (from :func:`map_norm`, shared by the states of a series).
        Default (neither ``limit`` nor ``norm``): :func:`map_norm` of the valid
        values, robust limits.
    cmap : str, optional
        A matplotlib colormap; default :func:`colormap`'s choice.

    Returns
    -------
    matplotlib.figure.Figure
    """
    offset = check_finite(offset, "offset")
    v = np.asarray(values, dtype=np.float64) - offset
    if v.ndim != 2:
        raise ValueError(f"values must be a 2-D map (H, W), got shape {v.shape}")
    ok = np.isfinite(v)
    if valid is not None:
        ok &= _same_shape(np.asarray(valid, dtype=bool), v.shape, "valid")
    limit = check_positive(limit, "limit", allow_none=True)
    if norm is None:
        norm = CenteredNorm(0.0, limit) if limit is not None else \
            map_norm(v, valid=ok, limits="robust")
    H, W = v.shape
    s = 1.0 if pixel_size is None else float(pixel_size)
    axis_unit = "px" if pixel_size is None else length_unit
    extent = map_extent((H, W), s)
    aspect = H / W
    fig = _new_figure(6.4, max(3.0, 5.2 * aspect + 1.0))
    ax = fig.add_subplot()
    if background is not None:
        bg = _same_shape(np.asarray(background, dtype=np.float64), v.shape, "background")
        lo, hi = np.percentile(bg[np.isfinite(bg)], _GREY_PERCENTILES)
        ax.imshow(bg, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1, extent=extent,
                  interpolation="nearest")
    data = np.ma.masked_array(v, mask=~ok)
    im = ax.imshow(data, cmap=colormap(norm, cmap), norm=norm, extent=extent,
                   interpolation="nearest")
    ax.set_xlabel(f"x ({axis_unit})")
    ax.set_ylabel(f"y ({axis_unit})")
    if title:
        ax.set_title(title, fontsize=10)
    _colour_bar(fig.colorbar(im, ax=ax, shrink=0.9), label, unit, offset)
    return fig


def map_extent(shape, scale: float = 1.0) -> tuple[float, float, float, float]:
    """``imshow``'s extent of an ``(H, W)`` map whose pixel ``(col, row)`` is centred on
    ``(col * scale, row * scale)`` (:mod:`gridstrain.conventions`), y downwards: the
    axes of every map figure are in the unit places are named in."""
    H, W = shape
    return (-0.5 * scale, (W - 0.5) * scale, (H - 0.5) * scale, -0.5 * scale)


def _same_shape(arr: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``arr``, refused unless it has the shape of the values drawn."""
    if arr.shape != shape:
        raise ValueError(f"{name} must have the shape of values {shape}, got {arr.shape}")
    return arr


def _colour_bar(cbar, label: str, unit: str, offset: float) -> None:
    """Label a map's colour bar with the quantity, its unit and the offset removed."""
    text = f"{label} ({unit})" if unit else f"{label} (dimensionless)"
    if offset != 0:
        text += f", mean {offset:.4g}{' ' + unit if unit else ''} removed"
    cbar.set_label(text)
    cbar.formatter.set_powerlimits((-2, 3))
    cbar.update_ticks()


def plot_shifts(shifts, *, title: str = "") -> Figure:
    """Per-frame rigid translations against the frame index (cf. paper Fig. 2).

    Parameters
    ----------
    shifts : (T, 2) array_like
        ``(alpha_t, beta_t)``, px.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Two panels, ``alpha_t`` and ``beta_t``, with their ``+-1`` standard
        deviation as dashed lines.
    """
    a = np.asarray(shifts, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2 or a.shape[0] < 1:
        raise ValueError(f"shifts must have shape (T, 2), got {a.shape}")
    T = a.shape[0]
    t = np.arange(T)
    fig = _new_figure(6.4, 4.8)
    axes = fig.subplots(2, 1, sharex=True)
    for ax, col, name in zip(axes, a.T, (r"$\alpha_t$", r"$\beta_t$"), strict=True):
        std = float(np.std(col, ddof=1)) if T > 1 else 0.0
        ax.plot(t, col, marker="o", markersize=3, linewidth=1)
        ax.axhline(0.0, color="0.5", linewidth=0.8)
        for sgn in (-1, 1):
            ax.axhline(sgn * std, color="0.3", linestyle="--", linewidth=0.8)
        ax.set_ylabel(f"{name} (px)")
        ax.set_title(f"{name}: std {std:.3g} px", fontsize=9, loc="left")
    axes[-1].set_xlabel("frame index t")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def save_figure(fig: Figure, path, *, overwrite: bool = False) -> Path:
    """Write ``fig`` as a PNG, atomically (see :func:`gridstrain.io.write_atomic`).

    The PNG is drawn in memory and then written, so that a full disk is one
    ``OSError`` naming the file and leaves nothing behind. ``path`` must end in
    ``.png``.
    """
    dest = Path(os.fspath(path))
    if dest.suffix.lower() != ".png":
        raise ValueError(f"path must end in .png (the figure is written as a PNG), got "
                         f"{dest.name!r}")
    return write_atomic(dest, _png(fig), overwrite=overwrite)


def _png(fig: Figure):
    return lambda fh: fig.savefig(fh, format="png", dpi=_DPI)


def figure_names(n_states: int) -> list[str]:
    """File names :func:`save_figures` writes for ``n_states`` loaded states."""
    names = [f"{f}_state{i}.png" for i in range(n_states) for f in _FIELDS]
    names.append("vibration_reference.png")
    names += [f"vibration_state{i}.png" for i in range(n_states)]
    return names


def save_figures(result, directory, *, pixel_size: float | None = None,
                 unit: str | None = None, overwrite: bool = False,
                 progress: Callable[[float, str], None] | None = None) -> tuple[Path, ...]:
    """Write every figure of a :class:`gridstrain.results.SeriesResult`.

    Parameters
    ----------
    result : SeriesResult
    directory : str or os.PathLike
        Created if missing (its parent must exist). The figures are listed in
        its marker file (:class:`gridstrain.io.OutputDirectory`).
    pixel_size : float, optional
        Pixel size in ``unit``: displacements and axes in that unit.
    unit : str, optional
        Length unit, required with ``pixel_size``.
    overwrite : bool
        Replace the figures an earlier call wrote in ``directory`` (and only
        those: a file of the same name that gridstrain did not write, or that
        changed since, is refused).
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    tuple of pathlib.Path
        One PNG per map and state (``exx_state0.png``...) and one per series for
        the vibrations (``vibration_reference.png``, ``vibration_state0.png``...),
        in the order of :func:`figure_names`.
    """
    check_type(result, "result", SeriesResult)
    ps, unit = check_pixel_size(pixel_size, unit)
    names = figure_names(result.n_states)
    out = OutputDirectory(directory, names, overwrite=overwrite, what="figures directory")
    out.prepare()
    report = progress or (lambda f, m: None)
    total = len(names)
    written = []
    T = result.n_frames
    n = result.n_states
    from ..results import state_loads

    loads = state_loads(result)

    def values_of(name, kind, i):
        # one state at a time: the maps of a record may stay in its file
        values, valid = np.asarray(result.get_map(name)[i]), np.asarray(result.valid[i])
        if kind == "displacement" and ps is not None:
            values = values * ps
        elif kind == "strain":
            values = values * 1e6
        return values, valid

    # one colour limit per quantity, common to every state, so that the states
    # compare by eye (displacements about each state's mean)
    offsets, norms = {}, {}
    for name, (_symbol, kind) in _FIELDS.items():
        off = np.zeros(n)
        if kind == "displacement":
            for i in range(n):
                values, valid = values_of(name, kind, i)
                off[i] = float(np.mean(values[valid])) if valid.any() else 0.0

        def centred(i, name=name, kind=kind, off=off):
            values, valid = values_of(name, kind, i)
            return values - off[i], valid

        offsets[name] = off
        norms[name] = states_norm(centred, n, limits="robust")
    for i in range(n):
        for name, (symbol, kind) in _FIELDS.items():
            values, valid = values_of(name, kind, i)
            offset, norm = float(offsets[name][i]), norms[name]
            u = (unit if ps is not None else "px") if kind == "displacement" else _MICRO
            title = (f"{symbol}, {state_title(result.names[i + 1], i, *loads)}\n"
                     f"method {result.method}, $\\sigma$ = {result.sigma:.3g} px, "
                     f"T = {T[0]}/{T[i + 1]}")
            fig = plot_map(values, valid=valid, background=result.reference_image,
                           label=symbol, unit=u, title=title, pixel_size=ps,
                           length_unit=unit or "px", offset=offset, norm=norm)
            written.append(out.write(f"{name}_state{i}.png", _png(fig)))
            report(len(written) / total, f"figure {len(written)}/{total}")
    for v, fname in zip(result.vibration, names[5 * result.n_states:], strict=True):
        fig = plot_shifts(v.shifts, title=f"vibrations of the {v.name} series "
                                          f"({v.n_frames} frames)")
        written.append(out.write(fname, _png(fig)))
        report(len(written) / total, f"figure {len(written)}/{total}")
    return tuple(written)


# --------------------------------------------------------------------------- every state

#: What each quantity of a result is drawn as: (symbol, unit in the file). Strains read
#: best in microstrain (1e-6; ``microstrain=`` takes "%" and "1" too), rotations in mrad,
#: the principal direction in degrees.
QUANTITIES = {
    "ux": (r"$u_x$", "px"), "uy": (r"$u_y$", "px"),
    "exx": (r"$\varepsilon_{xx}$", "1"), "eyy": (r"$\varepsilon_{yy}$", "1"),
    "exy": (r"$\varepsilon_{xy}$", "1"), "rotation": (r"$\omega$", "rad"),
    "ux_std": (r"std $u_x$", "px"), "uy_std": (r"std $u_y$", "px"),
    "exx_std": (r"std $\varepsilon_{xx}$", "1"), "eyy_std": (r"std $\varepsilon_{yy}$", "1"),
    "exy_std": (r"std $\varepsilon_{xy}$", "1"),
    # derived from the strain tensor (SeriesResult.principal_strains)
    "e1": (r"$\varepsilon_1$", "1"), "e2": (r"$\varepsilon_2$", "1"),
    "principal_angle": (r"$\theta_1$", "rad"),
    "equivalent": (r"$\varepsilon_{eq}$", "1"),
    "max_shear": (r"$(\varepsilon_1 - \varepsilon_2)/2$", "1"),
    "e1_std": (r"std $\varepsilon_1$", "1"), "e2_std": (r"std $\varepsilon_2$", "1"),
    "principal_angle_std": (r"std $\theta_1$", "rad"),
    "equivalent_std": (r"std $\varepsilon_{eq}$", "1"),
    "max_shear_std": (r"std $(\varepsilon_1 - \varepsilon_2)/2$", "1"),
    "rotation_std": (r"std $\omega$", "rad"),
    # finite strains (SeriesResult.finite_strains): Green-Lagrange E and logarithmic
    **{f"{kind}_{c}{s}": (("std " if s else "") + f"${sym}_{{{c}}}$", "1")
       for kind, sym in (("gl", "E"), ("log", r"\ln U")) for c in ("xx", "yy", "xy")
       for s in ("", "_std")},
}
_MICRO = "µε"
# the quantities derived from the strain tensor, and their std
_DERIVED = ("e1", "e2", "principal_angle", "equivalent", "max_shear")
_FINITE = tuple(f"{k}_{c}" for k in ("gl", "log") for c in ("xx", "yy", "xy"))


def quantity(result, name: str, *, pixel_size: float | None = None,
             unit: str | None = None, microstrain=True) -> tuple[np.ndarray, str]:
    """``(values (n_states, H, W), unit drawn)`` of one quantity of a result.

    Strains (and their std) in µε with ``microstrain`` (True or ``"microstrain"``), in
    percent with ``"%"``, dimensionless with False or ``"1"``; rotations in mrad, the
    principal direction in degrees, displacements in ``unit`` with a pixel size, else
    px.
    """
    return np.stack([state_quantity(result, name, i, pixel_size=pixel_size, unit=unit,
                                    microstrain=microstrain)[0]
                     for i in range(result.n_states)]), \
        _drawn_unit(name, pixel_size, unit, microstrain)


def state_quantity(result, name: str, i: int, *, pixel_size: float | None = None,
                   unit: str | None = None, microstrain=True
                   ) -> tuple[np.ndarray, str]:
    """``(values (H, W), unit drawn)`` of one quantity of state ``i`` (read alone from
    a result whose maps stay in its file), as :func:`quantity`."""
    from ._units import strain_scale

    check_choice(name, "name", tuple(QUANTITIES))
    drawn = _drawn_unit(name, pixel_size, unit, microstrain)
    if name == "rotation":
        return np.asarray(result.measurements[i].rotation) * 1e3, drawn
    if name.removesuffix("_std") in (*_DERIVED, *_FINITE, "rotation"):
        # the finite strains asked for: refused, saying why, on an Eulerian result
        maps = result.derived_maps(i, finite=name.removesuffix("_std") in _FINITE)
        if name not in maps:
            raise ValueError(f"this result has no {name} map (a single frame per series "
                             "gives no uncertainty map)")
        if name == "rotation_std":
            return maps[name] * 1e3, drawn
        if name.startswith("principal_angle"):
            return np.degrees(maps[name]), drawn
        values = maps[name]
    elif name.endswith("_std"):
        if result.uncertainty is None or name not in result.uncertainty:
            raise ValueError(f"this result has no {name} map (a single frame per series "
                             "gives no uncertainty map)")
        values = np.asarray(result.uncertainty[name][i])
    else:
        values = np.asarray(result.get_map(name)[i])
    if QUANTITIES[name][1] == "1":
        return values * strain_scale(microstrain)[0], drawn
    if pixel_size is not None:
        return values * pixel_size, drawn
    return values, drawn


def _drawn_unit(name: str, pixel_size, unit, microstrain) -> str:
    from ._units import strain_scale

    check_choice(name, "name", tuple(QUANTITIES))
    if name in ("rotation", "rotation_std"):
        return "mrad"
    if name.startswith("principal_angle"):
        return "deg"
    if QUANTITIES[name][1] == "1":
        return strain_scale(microstrain)[1]
    return unit if pixel_size is not None else "px"


def state_norm(values, valid, *, limits="robust"):
    """``(norm, diverging)``: :func:`map_norm` of the valid values of every state."""
    norm = map_norm(values, valid=valid, limits=limits)
    return norm, isinstance(norm, CenteredNorm)


#: The tallest figure gridstrain draws, px: a page or a screen, not a scroll.
MAX_HEIGHT_PX = 4000
#: States drawn by :func:`plot_states` at most (the first, evenly spaced ones, the last).
MAX_PANELS = 12


def capped_dpi(fig: Figure, dpi: float) -> float:
    """``dpi``, lowered so that ``fig`` saved at it is at most :data:`MAX_HEIGHT_PX` tall.

    The layout (fonts, panels) stays as drawn; only the resolution drops.
    """
    return min(float(dpi), MAX_HEIGHT_PX / float(fig.get_size_inches()[1]))


def chosen_states(n: int, *, k: int = MAX_PANELS) -> np.ndarray:
    """Indices of at most ``k`` of ``n`` states: the first, evenly spaced ones, the last."""
    if n <= k:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


def _nice_length(span: float) -> float:
    """1, 2 or 5 times a power of ten, near a fifth of ``span``."""
    target = span / 5
    p = 10 ** math.floor(math.log10(target))
    return max((m * p for m in (1, 2, 5) if m * p <= target), default=p)


def plot_states(result, name: str, *, limits="robust", cmap: str | None = None,
                microstrain=True, pixel_size: float | None = None,
                unit: str | None = None, px: bool = False, columns: int = 3,
                states=None) -> Figure:
    """Maps of one quantity for a chosen set of states, on common colour limits.

    Parameters
    ----------
    result : SeriesResult
    name : str
        One of :data:`QUANTITIES` (``"exx"``, ``"ux"``, ``"rotation"``,
        ``"exx_std"``...).
    limits : {"robust", "common"} or (float, float)
        See :func:`map_norm` (over every state, drawn or not): the 0.5th to 99.5th
        percentiles of the valid values (default), their full range, or the two
        ends given in the unit drawn (µε for strains by default).
    cmap : str, optional
        A matplotlib colormap; default :func:`colormap`'s choice.
    microstrain : bool or {"microstrain", "%", "1"}
        Strains in µε (True, the default), in percent, or dimensionless (False).
    pixel_size, unit : float, str, optional
        Displacements, the axes and a scale bar in ``unit``; default the result's own
        (:attr:`SeriesResult.pixel_size`), px for a result without one.
    px : bool
        In px, even for a result with a pixel size.
    columns : int
        Panels per row.
    states : sequence of int, optional
        The states drawn; default :func:`chosen_states` (all of them up to 12).
        Save it at :func:`capped_dpi` to keep it at most 4000 px tall.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per state over the grey reference image: pixels outside the
        valid region show the image, so the region measured is visible; one colour
        bar with the unit. Each panel is titled with the state's name, its time and
        load when the result has them, and its valid fraction.
    """
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    from ..results import state_loads
    from ._places import drawn_in

    ps, unit = drawn_in(result, pixel_size=pixel_size, unit=unit, px=px)
    limits = check_limits(limits)
    cmap = check_cmap(cmap)
    n_all = result.n_states
    shown = chosen_states(n_all) if states is None else np.asarray(states, dtype=int)
    if shown.size == 0 or shown.min() < 0 or shown.max() >= n_all:
        raise ValueError(f"states must be indices of the {n_all} states, got {states!r}")

    def values_of(i):
        # state by state: the maps of a record may stay in its file
        values, _ = state_quantity(result, name, i, pixel_size=ps, unit=unit,
                                   microstrain=microstrain)
        return values, np.asarray(result.valid[i]) & np.isfinite(values)

    drawn = _drawn_unit(name, ps, unit, microstrain)
    norm = states_norm(values_of, n_all, limits=limits)
    n = shown.size
    cols = max(1, min(int(columns), n))
    rows = math.ceil(n / cols)
    H, W = result.shape
    fig = _new_figure(3.4 * cols + 1.0, (3.4 * H / W + 0.6) * rows + 0.4)
    # room between the panels for two-line titles and the tick labels: an inner
    # panel carries no axis label (below), so nothing runs into its neighbour
    fig.subplots_adjust(hspace=0.35, wspace=0.25)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    bg = result.reference_image
    lo_g, hi_g = np.percentile(bg, _GREY_PERCENTILES)
    cmap = colormap(norm, cmap)
    load, load_unit, time = state_loads(result)
    # the axes in the unit places are named in (px without a pixel size)
    s, axis_unit = (1.0, "px") if ps is None else (ps, unit)
    extent = map_extent((H, W), s)
    im = None
    for k, ax in enumerate(axes):
        if k >= n:
            ax.set_axis_off()
            continue
        i = int(shown[k])
        values, valid = values_of(i)
        ax.imshow(bg, cmap="gray", vmin=lo_g, vmax=hi_g if hi_g > lo_g else lo_g + 1,
                  interpolation="nearest", extent=extent)
        im = ax.imshow(np.ma.masked_array(values, mask=~valid), cmap=cmap, norm=norm,
                       interpolation="nearest", extent=extent)
        ax.set_title(state_title(result.names[i + 1], i, load, load_unit, time)
                     + f"\n{valid.mean():.0%} valid", fontsize=8)
        # axis labels on the outer panels only: an inner one would run into its
        # neighbour's image
        if k + cols >= n:
            ax.set_xlabel(f"x ({axis_unit})", fontsize=8)
        if k % cols == 0:
            ax.set_ylabel(f"y ({axis_unit})", fontsize=8)
        ax.tick_params(labelsize=7)
        if ps is not None:
            length = _nice_length(W * ps)
            ax.add_artist(AnchoredSizeBar(ax.transData, length, f"{length:g} {unit}",
                                          "lower right", pad=0.4, color="black",
                                          frameon=True, size_vertical=max(1, H / 100) * ps))
    symbol = QUANTITIES[name][0]
    cbar = fig.colorbar(im, ax=list(axes[:n]), shrink=0.85)
    cbar.set_label(f"{symbol} ({drawn})" if drawn != "1" else f"{symbol} (dimensionless)")
    which = f"{n_all} state(s)" if n == n_all else f"{n} of {n_all} states"
    how = f"{limits} colour limits" if isinstance(limits, str) else \
        f"colour limits {limits[0]:g} to {limits[1]:g} {drawn}"
    fig.suptitle(f"{symbol}, {how} over all states; {which} shown", fontsize=10)
    return fig


def state_title(name: str, i: int, load, load_unit: str | None, time) -> str:
    """A state's name with its time and load where known: ``"step3, t = 6 s, 1 kN"``."""
    parts = [str(name)]
    if time is not None and math.isfinite(time[i]):
        parts.append(f"t = {time[i]:.4g} s")
    if load is not None and math.isfinite(load[i]):
        parts.append(f"{load[i]:.4g} {load_unit or ''}".rstrip())
    return ", ".join(parts)


def _probe(values_of: Callable, result, mask):
    """Per-state mean of the valid pixels of ``mask``, state ``i``'s values from
    ``values_of(i)``; NaN in a state where none is valid."""
    out = []
    for i in range(result.n_states):
        ok = mask & np.asarray(result.valid[i])
        vals = values_of(i)
        out.append(float(np.mean(vals[ok])) if ok.any() else math.nan)
    return np.array(out)


def plot_history(result, *, point=None, region=None, names=("exx", "eyy", "exy"),
                 microstrain=True, against: str = "auto", load=None,
                 load_unit: str | None = None, time=None, unit: str | None = None,
                 px: bool = False, pixel_size: float | None = None) -> Figure:
    """Strain (or any quantity) of all states at a point or averaged over a region.

    Parameters
    ----------
    result : SeriesResult
    point : (x, y) floats, optional
        The pixel nearest to the point.
    region : (x0, y0, x1, y1) floats, optional
        The pixels whose centre lies in ``x0 <= x < x1``, ``y0 <= y < y1``; the mean
        of the valid pixels. Default (neither given): the whole field.
    names : sequence of str
        Quantities of :data:`QUANTITIES`, drawn on one axis.
    microstrain : bool or {"microstrain", "%", "1"}
        Strains in µε (True, the default), in percent, or dimensionless (False).
    against : {"auto", "time", "load", "state"}
        The horizontal axis: "auto" takes the time, else the load, else the state.
    load, load_unit, time : optional
        The states' loads and times (default: the result's own, if any).
    unit, px, pixel_size : optional
        ``point``, ``region`` and the displacements in ``unit`` or px: the rule of
        :func:`gridstrain.post.gauge` (a place on a result with a pixel size says its
        unit).

    Returns
    -------
    matplotlib.figure.Figure
        One curve per quantity, with error bars of one standard deviation: the
        gauge's (:func:`gridstrain.post.gauge`) for strains and displacements.
        State names label the axis up to 15 states.

    Raises
    ------
    ValueError
        A point or region outside the measured field, or with no valid pixel in any
        state (never an empty figure): the message names the field's extent in the
        unit given.
    """
    from ..results import state_loads
    from . import gauge
    from ._places import place_mask, refuse_empty, result_frame

    check_choice(against, "against", ("auto", "time", "load", "state"))
    if point is not None and region is not None:
        raise ValueError("give point or region, not both")
    frame = result_frame(result, pixel_size=pixel_size, unit=unit, px=px,
                         places=(("point", point), ("region", region)))
    mask, where = place_mask(frame, region=region, point=point)
    where = f"at {where}" if point is not None else f"mean over {where} (valid pixels)"
    load, load_unit, time = state_loads(result, load=load, load_unit=load_unit, time=time)
    if against == "auto":
        against = "time" if time is not None else "load" if load is not None else "state"
    xs = {"time": time, "load": load}.get(against, np.arange(result.n_states))
    if xs is None:
        raise ValueError(f"against={against!r}, but the states have no {against}")
    reading = None
    fig = _new_figure(6.4, 4.0)
    ax = fig.add_subplot()
    unit_drawn = None
    from ._units import strain_scale

    ps, unit = (None, None) if frame.unit == "px" else (frame.scale, frame.unit)
    names = tuple(names)
    if not names:
        raise ValueError("names must hold at least one quantity, got none")
    # one axis, one unit: a strain in % and a displacement in mm on one axis would be
    # read against a label true for one of them only
    drawn = {name: _drawn_unit(name, ps, unit, microstrain) for name in names}
    if len(set(drawn.values())) > 1:
        raise ValueError("names must share one unit to be drawn on one axis, got "
                         + ", ".join(f"{n} ({u})" for n, u in drawn.items())
                         + ": draw them in separate figures")
    for name in names:
        # displacements in the unit the place is named in, as the maps draw them
        unit_drawn = drawn[name]
        kind = QUANTITIES[name][1]
        scale = strain_scale(microstrain)[0] if kind == "1" else \
            math.degrees(1.0) if name == "principal_angle" else \
            (ps or 1.0) if kind == "px" else 1.0
        if name in ("exx", "eyy", "exy", "ux", "uy", *_DERIVED, *_FINITE):
            if reading is None:
                reading = gauge(result, point=point, region=region, px=px,
                                pixel_size=pixel_size, unit=unit,
                                finite=any(n in _FINITE for n in names))
            # the derived strains of the gauge's mean tensor, as a rosette reads them
            attr = name
            if name in _DERIVED:
                source = reading.principal_strains()
            elif name in _FINITE:  # of the gauge's mean gradient
                source, attr = reading.finite_strains(), FINITE_FIELDS[name]
            else:
                source = reading
            curve = getattr(source, attr) * scale
            err = getattr(source, f"{attr}_std") * scale
            err = err if np.all(np.isfinite(err)) else None
        else:
            curve, err = _probe(lambda i, name=name: state_quantity(
                result, name, i, pixel_size=ps, unit=unit, microstrain=microstrain)[0],
                result, mask), None
            if not np.isfinite(curve).any():
                refuse_empty(frame, where, lambda i: result.valid[i], result.n_states)
        ax.errorbar(xs, curve, yerr=err, marker="o", markersize=3, capsize=2,
                    label=QUANTITIES[name][0])
    ax.axhline(0.0, color="0.6", linewidth=0.8)
    if against == "state" and result.n_states <= 15:
        ax.set_xticks(xs, list(result.names[1:]), rotation=30, fontsize=8)
    else:
        ax.set_xlabel({"time": "time (s)", "load": f"load ({load_unit or '-'})",
                       "state": "state"}[against])
    # the names share one unit (checked above); their kind names the axis
    kind = QUANTITIES[names[0]][1]
    what = "angle" if any(n.startswith("principal_angle") for n in names) else \
        {"1": "strain", "px": "displacement", "rad": "rotation"}[kind]
    ax.set_ylabel(f"{what} ({unit_drawn})")
    ax.set_title(where, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_stress_strain(constants) -> Figure:
    """Stress against the axial and transverse strains, with the fitted lines.

    Parameters
    ----------
    constants : gridstrain.post.ElasticConstants

    Returns
    -------
    matplotlib.figure.Figure
        Strains in µε with error bars of one stated std; the lines of slope
        ``1 / E`` and ``-nu / E`` fitted to them, E and nu with their 95 % intervals
        in the legend.
    """
    c = constants
    fig = _new_figure(6.4, 4.4)
    ax = fig.add_subplot()
    axial, trans = ("xx", "yy") if c.axis == "x" else ("yy", "xx")
    s = np.linspace(0.0, float(np.max(c.stress)) * 1.05, 50)
    for strain, std, name, slope in (
            (c.axial, c.axial_std, axial, 1 / c.E),
            (c.transverse, c.transverse_std, trans, -c.nu / c.E)):
        line = ax.errorbar(strain * 1e6, c.stress, xerr=std * 1e6, marker="o", ls="none",
                           capsize=2, label=rf"$\varepsilon_{{{name}}}$")
        off = float(np.average(strain - slope * c.stress, weights=1 / std**2))
        ax.plot((slope * s + off) * 1e6, s, color=line[0].get_color(), lw=1)
    ax.set_xlabel(r"strain (µε)")
    ax.set_ylabel(f"stress ({c.stress_unit})")
    from ._constants import modulus_unit

    k, unit = modulus_unit(c.E, c.stress_unit)
    ax.set_title(f"E = {c.E * k:.4g} [{c.E_ci[0] * k:.4g}, {c.E_ci[1] * k:.4g}] {unit}, "
                 f"ν = {c.nu:.3f} [{c.nu_ci[0]:.3f}, {c.nu_ci[1]:.3f}] (95 %)", fontsize=9)
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_gauge(reading, *, against: str = "auto", microstrain=True) -> Figure:
    """A gauge's mean strains of every state, with error bars of one std.

    Parameters
    ----------
    reading : gridstrain.post.GaugeReading
    against : {"auto", "time", "load", "state"}
        The horizontal axis: "auto" takes the time, else the load, else the state.
    microstrain : bool or {"microstrain", "%", "1"}
        Strains in µε (True, the default), in percent, or dimensionless (False).

    Returns
    -------
    matplotlib.figure.Figure
        ``exx``, ``eyy`` and ``exy`` of the reading, titled with the gauge's place
        (:attr:`GaugeReading.where`); no error bar where the std is unknown.
    """
    from ._units import strain_scale

    check_choice(against, "against", ("auto", "time", "load", "state"))
    if against == "auto":
        against = "time" if reading.time is not None else \
            "load" if reading.load is not None else "state"
    xs = {"time": reading.time, "load": reading.load}.get(
        against, np.arange(len(reading.states)))
    if xs is None:
        raise ValueError(f"against={against!r}, but the gauge has no {against}")
    scale, drawn = strain_scale(microstrain)
    fig = _new_figure(6.4, 4.0)
    ax = fig.add_subplot()
    for name in ("exx", "eyy", "exy"):
        err = getattr(reading, f"{name}_std") * scale
        ax.errorbar(xs, getattr(reading, name) * scale,
                    yerr=err if np.all(np.isfinite(err)) else None, marker="o",
                    markersize=3, capsize=2, label=QUANTITIES[name][0])
    ax.axhline(0.0, color="0.6", linewidth=0.8)
    ax.set_xlabel({"time": "time (s)", "load": f"load ({reading.load_unit or '-'})",
                   "state": "state index"}[against])
    ax.set_ylabel(f"strain ({drawn})" if drawn != "1" else "strain (dimensionless)")
    ax.set_title(reading.where, fontsize=8, wrap=True)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_load_strain(reading, *, axis: str = "x") -> Figure:
    """The load against a gauge's axial and transverse strains, where no
    cross-section turns it into a stress (:func:`plot_stress_strain` does then).

    Parameters
    ----------
    reading : gridstrain.post.GaugeReading
        With loads.
    axis : {"x", "y"}
        The loading direction: ``exx`` (``eyy``) is the axial strain.

    Returns
    -------
    matplotlib.figure.Figure
        Strains in µε with error bars of one std (none where unknown).
    """
    check_choice(axis, "axis", ("x", "y"))
    if reading.load is None:
        raise ValueError("reading has no loads: a load-strain plot needs them")
    fig = _new_figure(6.4, 4.4)
    ax = fig.add_subplot()
    for name in ("exx", "eyy") if axis == "x" else ("eyy", "exx"):
        std = getattr(reading, f"{name}_std") * 1e6
        ax.errorbar(getattr(reading, name) * 1e6, reading.load,
                    xerr=std if np.all(np.isfinite(std)) else None, marker="o", ls="-",
                    lw=0.8, capsize=2, label=QUANTITIES[name][0])
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.set_xlabel(f"strain ({_MICRO})")
    ax.set_ylabel(f"load ({reading.load_unit or '-'})")
    ax.set_title(reading.where, fontsize=8, wrap=True)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
