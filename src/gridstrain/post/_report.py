"""A result as one self-contained HTML page, to open in any browser and send on.

:func:`write_report` reads a result file (:mod:`gridstrain.results`) and writes a
single HTML file: no script, no style sheet or font fetched, every figure a PNG
embedded as a ``data:`` URI, so the page shows the same offline, attached to an
e-mail or archived with the data. It holds the run's provenance (version, date,
input files, the configuration that replays the run), the lattice, the
vibrations of every series, the noise floor, the maps on common colour limits
(strains in µε), the rotation and uncertainty maps, the strain of the states
averaged over the valid region, and the warnings.

A result file may come from anyone: the page is rendered from a template
(``templates/report.html.j2``) with autoescaping, so every text and number read
from the file reaches the page escaped, and the page forbids scripts
(Content-Security-Policy). A long sequence stays one readable page: beyond
:data:`ALL_STATES_UP_TO` states, the maps are those of a few states (the first,
evenly spaced ones, the last), the histories show every state, and each state is
one row of the tables.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import math
import warnings
from importlib import resources
from pathlib import Path

import numpy as np

from .._validation import as_path, check_type
from ..io import write_atomic
from ..results import MAP_FIELDS, SeriesResult, load, read_attrs
from ._plotting import plot_history, plot_shifts, plot_states

__all__ = ["render_report", "write_report"]

#: Up to this many states the report draws the maps of every state; beyond, those
#: of :data:`SHOWN_STATES` states spread over the sequence.
ALL_STATES_UP_TO = 12
SHOWN_STATES = 6
_DPI = 90
# An embedded figure is drawn at most this tall (px): a browser scrolls a page, not
# one image of a tall specimen's maps.
_MAX_HEIGHT_PX = 4000
_TICKS = 12  # state labels on a history's axis, at most
_UNC = ("ux_std", "uy_std", "exx_std", "eyy_std", "exy_std")


def _template():
    import jinja2

    text = resources.files(__package__).joinpath("templates/report.html.j2").read_text(
        encoding="utf-8")
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined,
                             keep_trailing_newline=True)
    env.filters["content"] = _content
    return env.from_string(text)


def _content(text) -> str:
    """Text escaped for an element's content (``&``, ``<``, ``>``), its quotes kept
    as they are, so that a configuration reads as written; never for an attribute."""
    import markupsafe

    return markupsafe.Markup(html.escape(str(text), quote=False))


def _figure(fig, alt: str, caption: str = "") -> dict:
    """A figure as the template draws it: a PNG no taller than the limit, base64."""
    dpi = min(_DPI, _MAX_HEIGHT_PX / fig.get_figheight())
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return {"alt": alt, "caption": caption,
            "png": base64.b64encode(buf.getvalue()).decode("ascii")}


def _num(x, spec: str = ".3g") -> str:
    if x is None:
        return "–"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return "–" if not math.isfinite(v) else format(v, spec)


def _table(header, rows, left=(0,)) -> dict:
    """A table for the template; the columns ``left`` hold text."""
    return {"header": list(header), "rows": [[str(c) for c in r] for r in rows],
            "left": set(left)}


def _shown_states(n: int) -> list[int]:
    """The states whose maps the report draws: all of them up to
    :data:`ALL_STATES_UP_TO`, else the first, the last and evenly spaced ones."""
    if n <= ALL_STATES_UP_TO:
        return list(range(n))
    return _spread(n, SHOWN_STATES)


def _spread(n: int, k: int) -> list[int]:
    """``k`` indices (fewer if ``n`` is small) from 0 to ``n - 1``, evenly spaced."""
    return np.unique(np.linspace(0, n - 1, k).round().astype(int)).tolist()


def _subset(result, states: list[int]):
    """The result restricted to some states, for the figures of their maps (those
    states alone read from a result whose maps stay in its file)."""
    if states == list(range(result.n_states)):
        return result
    idx = np.array(states)
    return dataclasses.replace(
        result, u=np.asarray(result.u[idx]), strain=np.asarray(result.strain[idx]),
        valid=np.asarray(result.valid[idx]),
        measurements=tuple(result.measurements[i] for i in states),
        names=(result.names[0], *(result.names[i + 1] for i in states)),
        uncertainty=None if result.uncertainty is None else
        {k: np.asarray(v[idx]) for k, v in result.uncertainty.items()})


def render_report(result: SeriesResult, *, attrs: dict | None = None,
                  title: str = "gridstrain result") -> str:
    """The HTML text of the report of ``result`` (see :func:`write_report`).

    ``attrs`` are the result file's root attributes (:func:`gridstrain.results.
    read_attrs`): pixel size, unit, creation date, the stored configuration.
    """
    check_type(result, "result", SeriesResult)
    a = dict(attrs or {})
    ps, unit = a.get("pixel_size"), a.get("unit")
    if ps is None or unit is None:
        ps = unit = None
    with warnings.catch_warnings():
        # long state names squeeze a figure's margins; it is drawn all the same
        warnings.filterwarnings("ignore", "Tight layout not applied", UserWarning)
        context = _context(result, a, ps, unit, title)
    return _template().render(context)


def _context(result, a: dict, ps, unit, title: str) -> dict:
    """The values the template shows: texts, tables and figures."""
    states = _shown_states(result.n_states)
    shown = _subset(result, states)
    return {
        "title": title, "summary": _summary(result, a, ps, unit),
        "warnings": list(result.warnings),
        **_inputs_section(result), **_lattice_section(result),
        **_vibration_section(result, states), **_noise_section(result),
        **_maps_section(result, shown, ps, unit), **_states_section(result),
        **_checks_section(result),
        "uncertainty": [_figure(plot_states(shown, name, pixel_size=ps, unit=unit),
                                f"uncertainty map of {name}")
                        for name in (shown.uncertainty or {}) if name in _UNC],
        "extra": _extra_fields(result),
        "parameters": _table(["parameter", "value"],
                             [[str(k), repr(v)] for k, v in result.parameters.items()],
                             left=(0, 1)),
        "config": str(a.get("config") or ""),
        "conventions": str(a.get("conventions", "")),
    }


def _summary(result, a: dict, ps, unit) -> str:
    """The one-paragraph description of the run."""
    H, W = result.shape
    d = result.noise.spatial_resolution
    phys = f" = {d * ps:.3g} {unit}" if ps else ""
    return (f"{result.n_states} loaded state(s) against the reference, {H} × {W} px, "
            f"method {result.method}, σ = {result.sigma:.4g} px (spatial resolution "
            f"{d:.3g} px{phys}, the period damped by 10 %; window FWHM "
            f"{result.noise.window_fwhm:.3g} px), large-displacement correction "
            f"{'on' if result.lagrangian else 'off'}. Written by gridstrain "
            f"{a.get('gridstrain_version', '?')} on {a.get('created', '?')}.")


def _inputs_section(result) -> dict:
    """Every image series: frames, bit depth, saturation and files."""
    rows = []
    for name, files, T, bits, scale, sat in zip(
            result.names, result.sources, result.n_frames, result.bit_depth, result.scale,
            result.saturation, strict=True):
        where = files[0] + (f" … ({len(files)} files)" if len(files) > 1 else "") \
            if files else "array in memory"
        depth = "float" if bits is None else f"{bits}-bit" + (f" ×{scale}" if scale != 1
                                                               else "")
        rows.append([name, T, depth, _num(sat, ".2%"), where])
    return {"inputs": _table(["series", "frames", "data", "saturated", "files"], rows,
                             left=(0, 4))}


def _lattice_section(result) -> dict:
    """The wave vectors, pitches and angles, and whether they were detected."""
    lat = result.lattice
    how = "Detected on the mean reference image" if result.lattice_detected else "Given"
    return {"lattice": _table(
                ["wave vector", "kx (cycles/px)", "ky (cycles/px)", "pitch (px)",
                 "angle (deg)"],
                [[k, _num(v[0], ".6g"), _num(v[1], ".6g"), _num(p, ".5f"), _num(ang, ".3f")]
                 for k, v, p, ang in zip(("k1", "k2"), (lat.k1, lat.k2), lat.pitches,
                                         lat.angles, strict=True)]),
            "lattice_note": f"{how}; validity margin {result.margin:g} σ."}


def _vibration_section(result, states: list[int]) -> dict:
    """The vibrations of every series: a table, and the shifts of the reference's and
    the shown states' stacks."""
    series = [0, *(i + 1 for i in states)]
    table = _table(["series", "std α (px)", "std β (px)", "contrast k1", "contrast k2",
                    "phase offset std k1 (rad)", "k2 (rad)"],
                   [[v.name, _num(v.std[0]), _num(v.std[1]), _num(v.contrast_factor[0], ".5f"),
                     _num(v.contrast_factor[1], ".5f"), _num(v.phase_offset_std[0]),
                     _num(v.phase_offset_std[1])] for v in result.vibration])
    figures = [_figure(plot_shifts(v.shifts, title=f"{v.name}: rigid shift of each frame"),
                       f"vibrations of {v.name}")
               for v in (result.vibration[j] for j in series) if v.n_frames > 1]
    note = "" if len(series) == len(result.vibration) else (
        f"Shifts drawn for the reference and the {len(states)} states whose maps are "
        "shown; the table lists every series.")
    return {"vibration": table, "vibration_figures": figures, "vibration_note": note}


def _noise_section(result) -> dict:
    """The noise floor of every state (one row each), and the sensor noise of every
    series."""
    nf = result.noise
    rows = [[result.names[i + 1], _num(nf.theory_u[i][0]), _num(nf.theory_u[i][1]),
             *(_num(x * 1e6) for x in nf.theory_strain[i]),
             *(_num(x * 1e6) for x in nf.split_strain[i]),
             _num(nf.vibration_u[i][0]), _num(nf.vibration_u[i][1])]
            for i in range(result.n_states)]
    noise = _table(["state", "theory u_x (px)", "u_y (px)", "theory ε_xx (µε)", "ε_yy (µε)",
                    "ε_xy (µε)", "halves ε_xx (µε)", "ε_yy (µε)", "ε_xy (µε)",
                    "vibration u_x (px)", "u_y (px)"], rows)
    sensor = _table(["series", "sensor variance (grey levels²)", "how", "|Ψ| k1", "|Ψ| k2"],
                    [[n, _num(v), m, _num(mod[0]), _num(mod[1])]
                     for n, v, m, mod in zip(result.names, nf.sensor_variance,
                                             nf.variance_method, nf.modulus, strict=True)],
                    left=(0, 2))
    return {"noise": noise, "sensor": sensor}


def _maps_section(result, shown, ps, unit) -> dict:
    """The maps of the shown states on colour limits common to them."""
    n, k = result.n_states, shown.n_states
    which = "Every state" if k == n else (
        f"{k} of the {n} states (the first, the last and evenly spaced ones; the "
        "histories and the table below hold every state)")
    note = (f"{which} on the same colour limits; strains in µε (10⁻⁶), displacements in "
            f"{unit if ps else 'px'}; outside the valid region the reference image shows "
            "through.")
    maps = [_figure(plot_states(shown, name, pixel_size=ps, unit=unit), f"map of {name}")
            for name in (*MAP_FIELDS, "rotation")]
    return {"maps_note": note, "maps": maps}


def _states_section(result) -> dict:
    """One row per state (valid fraction, mean of each map over its valid pixels,
    iterations, fringe order), and the histories of the means."""
    rows = []
    for i, m in enumerate(result.measurements):
        v = np.asarray(result.valid[i])
        means = [float(np.mean(np.asarray(result.get_map(k)[i])[v])) if v.any()
                 else math.nan for k in MAP_FIELDS]
        rows.append([result.names[i + 1], f"{v.mean():.1%}", _num(means[0], ".4f"),
                     _num(means[1], ".4f"), *(_num(x * 1e6, ".1f") for x in means[2:]),
                     m.iterations, _fringe_order(result, i)])
    table = _table(["state", "valid", "mean u_x (px)", "mean u_y (px)", "mean ε_xx (µε)",
                    "mean ε_yy (µε)", "mean ε_xy (µε)", "iterations", "fringe order"],
                   rows, left=(0, 8))
    histories = []
    if result.n_states > 1:
        for names, what in ((("exx", "eyy", "exy"), "Strain"), (("ux", "uy"), "Displacement")):
            fig = plot_history(result, names=names)
            _thin_ticks(fig, result.n_states)
            histories.append(_figure(fig, f"{what.lower()} of the states",
                                     f"{what} of every state, mean over the valid pixels."))
    return {"states": table, "histories": histories}


def _checks_section(result) -> dict:
    """The pair check of each state (its content against the reference's once warped
    back) and the vibration offset removed from each series' phases (methods A, B)."""
    sy = result.systematic or {}
    pairs = [[r["state"], r["verdict"], _num(r["match"], ".2f"), _num(r["rho"], ".3f"),
              _num(r["rho_match"], ".3f"), _num(r["rho_sd"], ".3f")]
             for r in sy.get("pair_match", ())]
    offsets = [[r["series"], r["method"], *(_num(v, ".2e") for v in r["removed_rad"]),
                *(_num(v, ".2e") for v in r["predicted_std_rad"])]
               for r in sy.get("vibration_offset", ()) if r is not None]
    return {
        "pair_checks": _table(["state", "verdict", "match", "correlation", "expected",
                               "spread"], pairs, left=(0, 1)) if pairs else None,
        "offsets": _table(["series", "method", "removed k1 (rad)", "removed k2 (rad)",
                           "predicted std k1 (rad)", "predicted std k2 (rad)"], offsets,
                          left=(0, 1)) if offsets else None}


def _thin_ticks(fig, n: int) -> None:
    """At most :data:`_TICKS` state labels on a history's axis, by state index."""
    if n <= _TICKS:
        return
    ax = fig.axes[0]
    ticks = _spread(n, _TICKS)
    ax.set_xticks(ticks, [str(t) for t in ticks], rotation=0, fontsize=8)
    ax.set_xlabel("state index")


def _fringe_order(result, i: int) -> str:
    """Where state ``i``'s fringe order came from, and whether it is confirmed."""
    if not result.fringe_orders:
        return result.guess_sources[i]
    r = result.fringe_orders[i]
    return f"{r.source}, {'confirmed' if r.confirmed else 'NOT CONFIRMED'}"


# The fields every report shows in its own section; any other field a result
# class gains is listed under "Other results" by its repr.
_SHOWN = {
    "u", "strain", "valid", "lattice", "lattice_detected", "sigma", "method", "lagrangian",
    "margin", "mask", "reference_image", "names", "sources", "n_frames", "bit_depth",
    "scale", "saturation", "measurements", "guesses", "guess_sources", "vibration", "noise",
    "parameters", "warnings", "uncertainty", "fringe_orders"}


def _extra_fields(result) -> list[tuple[str, str]]:
    return [(f.name, repr(getattr(result, f.name))) for f in dataclasses.fields(result)
            if f.name not in _SHOWN and getattr(result, f.name) is not None]


def write_report(result_path, html_path, *, overwrite: bool = False) -> Path:
    """Write the HTML report of a result file, atomically.

    Parameters
    ----------
    result_path : str or os.PathLike
        A file written by :func:`gridstrain.results.save_result`.
    html_path : str or os.PathLike
        Destination (``.html``).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
    """
    src = as_path(result_path, "result_path")
    result = load(src, in_memory=False)
    text = render_report(result, attrs=read_attrs(src), title=f"gridstrain: {src.name}")
    dest = as_path(html_path, "html_path")
    return write_atomic(dest, text.encode("utf-8"), overwrite=overwrite)
