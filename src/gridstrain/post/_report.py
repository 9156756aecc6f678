"""A result as one self-contained HTML page, to open in any browser and send on.

:func:`write_report` reads a result file (:mod:`gridstrain.results`) and writes a
single HTML file: no script, no style sheet or font fetched, every figure a PNG
embedded as a ``data:`` URI, so the page shows the same offline, attached to an
e-mail or archived with the data. It shows first what the test was run for: when
the states have loads or a region or an area is given, a gauge (the whole valid region, or the
region given) with its strains and their std in every state and their history; with
loads the load–strain plot,
or with the specimen's cross-section the stress–strain plot with Young's modulus
and Poisson's ratio and their 95 % intervals (:func:`gridstrain.post.
elastic_constants`). Then the maps on colour limits shared by the states (robust
percentiles by default; strains in µε), the rotation and uncertainty maps, one
table with a row per state (time, load, valid fraction, mean maps, noise floor,
pair check, fringe order) and one with a row per image series (frames, bit depth,
saturation, vibrations, sensor noise), the lattice, the warnings and the run's
provenance (version, date, input files, the configuration that replays the run).
Every value is written with its unit and a sensible number of digits, never as a
Python repr.

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
import numbers
import warnings
from importlib import resources
from pathlib import Path

import numpy as np

from .._progress import SEVERITIES
from .._validation import as_path, check_choice, check_positive, check_type
from ..io import available_memory, write_atomic
from ..results import MAP_FIELDS, SeriesResult, read_attrs, state_loads
from ..results import load as load_result
from ._constants import elastic_constants
from ._gauges import gauge
from ._plotting import (
    check_cmap,
    check_limits,
    plot_gauge,
    plot_history,
    plot_load_strain,
    plot_shifts,
    plot_states,
    plot_stress_strain,
)

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
# The report reads its maps into memory once when they take at most this share of the
# memory available (the figures, the percentiles and the matplotlib canvases take the
# rest); else state by state from the file, as often as its figures need them.
_IN_MEMORY_SHARE = 0.25
# ... of this many bytes where the system tells no available memory (neither cgroups
# nor /proc: macOS, Windows): a 4-GiB machine's, so that a long record is still read
# state by state there.
_UNKNOWN_MEMORY = 4 * 2**30


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


def _micro(x) -> str:
    """A noise floor in µε to two significant digits, without an exponent (830, not
    8.3e+02, in a column headed µε)."""
    text = _num(x * 1e6 if x is not None else None, ".2g")
    return text if text == "–" else f"{float(text):g}"


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


def _maps_read_once(result: SeriesResult) -> SeriesResult:
    """``result`` with its per-state maps read from its file in one read each, when
    they fit :data:`_IN_MEMORY_SHARE` of the memory available: the report's figures,
    table and histories then read each state's maps from memory rather than the file
    (a dozen reads of every state of a long record, most of the report's time beside
    the drawing). The same values (a lazy map reads what loading would): the same
    page. Left as it is when its maps are in memory already or do not fit."""
    stored = [a for a in (result.u, result.strain, result.valid,
                          *(result.uncertainty or {}).values(),
                          *(m.rotation for m in result.measurements))
              if not isinstance(a, np.ndarray)]
    if not stored:
        return result
    need = sum(int(np.prod(a.shape)) * np.dtype(a.dtype).itemsize for a in stored)
    free, source = available_memory()
    if source == "unknown":  # a system that says nothing: at most the known floor
        free = _UNKNOWN_MEMORY
    if need > _IN_MEMORY_SHARE * free:
        return result
    measurements = tuple(m if isinstance(m.rotation, np.ndarray) else
                         dataclasses.replace(m, rotation=np.asarray(m.rotation))
                         for m in result.measurements)
    return dataclasses.replace(
        result, u=np.asarray(result.u), strain=np.asarray(result.strain),
        valid=np.asarray(result.valid), measurements=measurements,
        uncertainty=None if result.uncertainty is None else
        {k: np.asarray(v) for k, v in result.uncertainty.items()})


def render_report(result: SeriesResult, *, attrs: dict | None = None,
                  title: str = "gridstrain result", region=None, px: bool = False,
                  area: float | None = None, area_unit: str = "mm2", axis: str = "x",
                  limits="robust", cmap: str | None = None) -> str:
    """The HTML text of the report of ``result`` (see :func:`write_report`).

    Parameters
    ----------
    result : SeriesResult
    attrs : dict, optional
        The result file's root attributes (:func:`gridstrain.results.read_attrs`):
        pixel size, unit, creation date, the stored configuration.
    title : str
        The page's title.
    region : (x0, y0, x1, y1) floats, or a sequence of them, optional
        The gauge(s) of the test's section (:func:`gridstrain.post.gauge`), in the
        file's unit when ``attrs`` (or the result) give a pixel size, else px; several
        gauges ``G1``, ``G2``... share the table (their columns side by side), each
        with its figures and constants. Default: the whole valid region. Gauged
        also when the states have no loads (no load column, plot or constants then).
    px : bool
        ``region`` in px even when the file has a pixel size.
    area : float, optional
        The specimen's cross-section, in ``area_unit``: with loads, the
        stress–strain plot and E and ν with their 95 % intervals
        (:func:`gridstrain.post.elastic_constants`); without it, the load–strain
        plot and a note that E needs the area.
    area_unit : str
        ``"mm2"`` (default), ``"cm2"``, ``"m2"``, ``"in2"``.
    axis : {"x", "y"}
        The loading direction.
    limits : {"robust", "common"} or (float, float)
        The maps' colour limits, shared by the states
        (:func:`gridstrain.post.map_norm`).
    cmap : str, optional
        A matplotlib colormap for the maps.

    Returns
    -------
    str
    """
    check_type(result, "result", SeriesResult)
    area = check_positive(area, "area", allow_none=True)
    check_choice(axis, "axis", ("x", "y"))
    limits, cmap = check_limits(limits), check_cmap(cmap)
    a = dict(attrs or {})
    ps, unit = a.get("pixel_size"), a.get("unit")
    if ps is None or unit is None:  # the result's own, when the attributes have none
        ps, unit = result.pixel_size, result.unit
    test = {"region": region, "px": bool(px), "area": area, "area_unit": area_unit,
            "axis": axis}
    result = _maps_read_once(result)
    with warnings.catch_warnings():
        # long state names squeeze a figure's margins; it is drawn all the same
        warnings.filterwarnings("ignore", "Tight layout not applied", UserWarning)
        context = _context(result, a, ps, unit, title, test, {"limits": limits,
                                                             "cmap": cmap})
    return _template().render(context)


def _context(result, a: dict, ps, unit, title: str, test: dict, colours: dict) -> dict:
    """The values the template shows: texts, tables and figures."""
    states = _shown_states(result.n_states)
    return {
        "title": title, "summary": _summary(result, a, ps, unit),
        # most serious first (their codes' severity), each with its code
        "warnings": sorted(result.warnings, key=lambda w: -SEVERITIES.index(w.severity)),
        "test": _test_section(result, ps, unit, **test),
        **_series_section(result, states), **_lattice_section(result),
        **_maps_section(result, states, ps, unit, colours),
        **_states_section(result, ps, unit), **_checks_section(result),
        "uncertainty": [_figure(plot_states(result, name, pixel_size=ps, unit=unit,
                                            px=ps is None, states=states, **colours),
                                f"uncertainty map of {name}")
                        for name in (result.uncertainty or {}) if name in _UNC],
        "extra": _extra_fields(result),
        "parameters": _table(["parameter", "value"],
                             [[str(k), _plain(v)] for k, v in result.parameters.items()],
                             left=(0, 1)),
        "config": str(a.get("config") or ""),
        "conventions": str(a.get("conventions", "")),
    }


def _with_std(value, std, scale: float = 1e6) -> str:
    """``value ± std`` times ``scale``, rounded to the std's second significant digit
    (``"1401.5 ± 11"``); the value alone to 4 digits where the std is unknown."""
    v, s = float(value) * scale, float(std) * scale
    if not math.isfinite(v):
        return "–"
    if not (math.isfinite(s) and s > 0):
        return _num(v, ".4g")
    decimals = max(0, 1 - math.floor(math.log10(s)))
    return f"{v:.{decimals}f} ± {s:.{decimals}f}"


def _regions(region) -> list:
    """``region`` as a list of gauges: None (the whole valid region), one
    ``(x0, y0, x1, y1)`` or a sequence of them."""
    if region is None:
        return [None]
    try:
        nested = len(region) > 0 and np.ndim(region[0]) == 1
    except TypeError:  # not a sequence: refused by the gauge, naming it
        nested = False
    return [tuple(r) for r in region] if nested else [region]


def _test_section(result, ps, unit, *, region, px: bool, area, area_unit: str,
                  axis: str) -> dict | None:
    """What the test was run for, when the states have loads: each gauge's strains of
    every state (one table, the gauges' columns side by side), their history, and the
    stress–strain plot with E and ν (with the area) or the load–strain plot
    (without)."""
    load, load_unit, time = state_loads(result)
    if load is None and region is None and area is None:
        return None  # nothing asked of a test; --area asks for E, and hears what is missing
    named = {} if px or ps is None else {"pixel_size": ps, "unit": unit}
    regions = _regions(region)
    readings = [gauge(result, region=r, px=px, **named) for r in regions]
    several = len(readings) > 1
    tags = [f"G{g + 1} " if several else "" for g in range(len(readings))]
    head = ["state", "time (s)", *([f"load ({load_unit or '–'})"] if load is not None
                                   else [])]
    for tag in tags:
        head += [f"{tag}pixels", f"{tag}ε_xx (µε)", f"{tag}ε_yy (µε)", f"{tag}ε_xy (µε)"]
    rows = [[name, _num(time[i], ".4g") if time is not None else "–",
             *([_num(load[i], ".4g")] if load is not None else []),
             *(cell for r in readings for cell in (
                 int(r.n_pixels[i]), *(_with_std(getattr(r, c)[i], getattr(r, f"{c}_std")[i])
                                       for c in ("exx", "eyy", "exy"))))]
            for i, name in enumerate(readings[0].states)]
    figures, constant_rows, notes = [], [], []
    for tag, reading in zip(tags, readings, strict=True):
        own = f" ({tag.strip()})" if several else ""
        figures.append(_figure(plot_gauge(reading), f"gauge history{own}",
                               f"The gauge's{own} mean strains in every state, with one "
                               "std."))
        if load is None:
            continue
        if area is None:
            figures.append(_figure(plot_load_strain(reading, axis=axis),
                                   f"load-strain plot{own}",
                                   f"Load against the gauge's{own} strains."))
            continue
        try:
            c = elastic_constants(reading, area=area, area_unit=area_unit, axis=axis)
        except ValueError as exc:  # too few states, no std, constant loads: said so
            notes.append(f"No elastic constants{own}: {exc}.")
            figures.append(_figure(plot_load_strain(reading, axis=axis),
                                   f"load-strain plot{own}",
                                   f"Load against the gauge's{own} strains."))
            continue
        figures.append(_figure(plot_stress_strain(c), f"stress-strain plot{own}",
                               f"Stress against the axial and transverse strains{own}, "
                               "with the weighted straight-line fits."))
        constant_rows += [[f"Young's modulus E{own}", *_modulus_cells(c)],
                          [f"Poisson's ratio ν{own}", f"{c.nu:.4f}",
                           f"[{c.nu_ci[0]:.4f}, {c.nu_ci[1]:.4f}]"]]
        notes.append(f"Fitted{own} on {len(c.states)} states, the stress = load / "
                     f"{area:g} {area_unit} in {c.stress_unit}, loading along {axis}; "
                     f"intervals from the {c.interval_basis} (reduced χ² "
                     f"{c.reduced_chi2[0]:.2f} axial, {c.reduced_chi2[1]:.2f} "
                     "transverse).")
        if c.unit_doubt() is not None:
            notes.append(f"{c.unit_doubt()}{own}.")
    if load is None:
        notes.append("The states have no loads: no load-strain plot, Young's modulus "
                     "or Poisson's ratio (measure --loads FILE records them; report "
                     "--loads FILE gives them to the page).")
    elif area is None:
        notes.append("Young's modulus and Poisson's ratio need the specimen's "
                     "cross-section: gridstrain report RESULT.h5 --area A (in mm² by "
                     "default).")
    constants = _table(["constant", "value", "95 % interval"], constant_rows, left=(0,)) \
        if constant_rows else None
    places = [r.where if g is not None else
              f"the whole valid region ({r.where.removeprefix('gauge ')})"
              for g, r in zip(regions, readings, strict=True)]
    where = places[0] if not several else "; ".join(
        f"{tag.strip()}, {w}" for tag, w in zip(tags, places, strict=True))
    return {"where": where,
            "loads": _loads_note(result, load_unit) if load is not None else None,
            "table": _table(head, rows), "figures": figures, "constants": constants,
            "note": " ".join(notes) or None}


def _modulus_cells(c) -> list[str]:
    from ._constants import modulus_unit

    k, unit = modulus_unit(c.E, c.stress_unit)
    return [f"{c.E * k:.4g} {unit}", f"[{c.E_ci[0] * k:.4g}, {c.E_ci[1] * k:.4g}] {unit}"]


def _loads_note(result, load_unit) -> str:
    """Where the loads came from, in words."""
    src = getattr(result, "load_source", None) or {}
    if not src:
        return f"Loads in {load_unit or 'no stated unit'}, given with the measurement."
    text = (f"Loads from {src.get('file', '?')} (column {src.get('load_column', '?')}, "
            f"in {src.get('load_unit', '?')}")
    if src.get("time_column"):
        text += (f"; times from {src['time_column']}, "
                 f"{src.get('method', 'joined by time')}, the log's clock "
                 f"{_num(src.get('offset_s', 0.0), 'g')} s ahead of the camera's")
    else:
        text += f"; {src.get('method', '')}"
    sha = str(src.get("sha256", ""))
    return text + (f"; SHA-256 {sha[:12]}…)." if sha else ").")


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


def _series_section(result, states: list[int]) -> dict:
    """One row per image series (frames, data, saturation, vibrations, sensor noise,
    files), and the shifts of the reference's and the shown states' stacks."""
    nf = result.noise
    rows = []
    for j, (name, files, T, bits, scale, sat) in enumerate(zip(
            result.names, result.sources, result.n_frames, result.bit_depth, result.scale,
            result.saturation, strict=True)):
        v = result.vibration[j]
        where = files[0] + (f" … ({len(files)} files)" if len(files) > 1 else "") \
            if files else "array in memory"
        depth = "float" if bits is None else f"{bits}-bit" + (f" ×{scale}" if scale != 1
                                                               else "")
        rows.append([name, T, depth, _num(sat, ".2%"), _num(v.std[0]), _num(v.std[1]),
                     _num(v.contrast_factor[0], ".4f"), _num(v.contrast_factor[1], ".4f"),
                     _num(nf.sensor_variance[j]), nf.variance_method[j], where])
    table = _table(["series", "frames", "data", "saturated", "vibration std α (px)",
                    "β (px)", "contrast k1", "k2", "sensor variance (grey levels²)",
                    "how", "files"], rows, left=(0, 9, 10))
    series = [0, *(i + 1 for i in states)]
    figures = [_figure(plot_shifts(v.shifts, title=f"{v.name}: rigid shift of each frame"),
                       f"vibrations of {v.name}")
               for v in (result.vibration[j] for j in series) if v.n_frames > 1]
    note = "" if len(series) == len(result.vibration) else (
        f"Shifts drawn for the reference and the {len(states)} states whose maps are "
        "shown; the table lists every series.")
    return {"series": table, "vibration_figures": figures, "vibration_note": note}


def _maps_section(result, states: list[int], ps, unit, colours: dict) -> dict:
    """The maps of the shown ``states`` on colour limits common to every state: the
    full result is drawn with its states chosen, so that each panel carries its own
    state's load and time."""
    n, k = result.n_states, len(states)
    which = "Every state" if k == n else (
        f"{k} of the {n} states (the first, the last and evenly spaced ones; the "
        "histories and the table below hold every state)")
    lim = colours["limits"]
    how = ("the 0.5th to 99.5th percentiles of the valid values of every state"
           if lim == "robust" else "the full range of the valid values of every state"
           if lim == "common" else f"{lim[0]:g} to {lim[1]:g} µε for the strains, robust "
           "for the others")
    note = (f"{which} on the same colour limits ({how}); strains in µε (10⁻⁶), "
            f"displacements in {unit if ps else 'px'}; outside the valid region the "
            "reference image shows through.")
    # limits given explicitly are in one quantity's unit: they apply to the strains
    maps = [_figure(plot_states(result, name, pixel_size=ps, unit=unit, px=ps is None,
                                states=states, cmap=colours["cmap"],
                                limits=lim if isinstance(lim, str) or name[0] == "e"
                                else "robust"), f"map of {name}")
            for name in (*MAP_FIELDS, "rotation")]
    return {"maps_note": note, "maps": maps}


def _states_section(result, ps=None, unit=None) -> dict:
    """One row per state (time, load, valid fraction, mean of each map over its valid
    pixels, noise floor, pair check, iterations, fringe order), and the histories of
    the means; displacements in ``unit`` with the pixel size ``ps``, as the maps and
    the histories draw them, else px."""
    load, load_unit, time = state_loads(result)
    nf = result.noise
    pairs = {r["state"]: r for r in (result.systematic or {}).get("pair_match", ())}
    length = unit if ps else "px"
    rows = []
    for i, m in enumerate(result.measurements):
        name = result.names[i + 1]
        v = np.asarray(result.valid[i])
        means = [float(np.mean(np.asarray(result.get_map(k)[i])[v])) if v.any()
                 else math.nan for k in MAP_FIELDS]
        noise = [_micro(t) + (f" / {_micro(h)}" if math.isfinite(float(h)) else "")
                 for t, h in zip(nf.theory_strain[i], nf.split_strain[i], strict=True)]
        pair = pairs.get(name)
        rows.append([name, "–" if time is None else _num(time[i], ".4g"),
                     "–" if load is None else _num(load[i], ".4g"), f"{v.mean():.1%}",
                     *(_num(x * (ps or 1.0), ".4g" if ps else ".4f") for x in means[:2]),
                     *(_num(x * 1e6, ".1f") for x in means[2:]), *noise,
                     "–" if pair is None else f"{pair['verdict']} ({_num(pair['match'], '.2f')})",
                     m.iterations, _fringe_order(result, i)])
    table = _table(["state", "time (s)", f"load ({load_unit or '–'})", "valid",
                    f"mean u_x ({length})", f"mean u_y ({length})", "mean ε_xx (µε)",
                    "mean ε_yy (µε)", "mean ε_xy (µε)", "noise ε_xx (µε)", "noise ε_yy (µε)",
                    "noise ε_xy (µε)", "pair check", "iterations", "fringe order"],
                   rows, left=(0, 12, 14))
    histories = []
    if result.n_states > 1:
        for names, what in ((("exx", "eyy", "exy"), "Strain"), (("ux", "uy"), "Displacement")):
            fig = plot_history(result, names=names, pixel_size=ps, unit=unit,
                               px=ps is None)
            if time is None and load is None:  # else drawn against them, not the state
                _thin_ticks(fig, result.n_states)
            histories.append(_figure(fig, f"{what.lower()} of the states",
                                     f"{what} of every state, mean over the valid pixels."))
    return {"states": table, "histories": histories}


def _checks_section(result) -> dict:
    """The vibration offset removed from each series' phases (methods A, B)."""
    sy = result.systematic or {}
    offsets = [[r["series"], r["method"], *(_num(v, ".2e") for v in r["removed_rad"]),
                *(_num(v, ".2e") for v in r["predicted_std_rad"])]
               for r in sy.get("vibration_offset", ()) if r is not None]
    return {
        "pair_checks": bool(sy.get("pair_match")),
        "offsets": _table(["series", "method", "removed k1 (rad)", "removed k2 (rad)",
                           "predicted std k1 (rad)", "predicted std k2 (rad)"], offsets,
                          left=(0, 1)) if offsets else None}


def _thin_ticks(fig, n: int) -> None:
    """At most :data:`_TICKS` state labels on a history's axis, by state index (a
    history drawn against the states: one against time or load keeps its axis)."""
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
# class gains is listed under "Other results", its values written out as text.
_SHOWN = {
    "u", "strain", "valid", "lattice", "lattice_detected", "sigma", "method", "lagrangian",
    "margin", "mask", "reference_image", "names", "sources", "n_frames", "bit_depth",
    "scale", "saturation", "measurements", "guesses", "guess_sources", "vibration", "noise",
    "parameters", "warnings", "findings", "uncertainty", "fringe_orders", "load", "load_unit",
    "time", "load_source"}
# Values listed in full up to this many; a longer array is summarised.
_LIST_UP_TO = 12
# Nested records listed down to this depth; deeper, summarised.
_DEPTH = 4


def _plain(value) -> str:
    """A value as a reader reads it, never as a Python repr: numbers to 4 significant
    digits, booleans as yes/no, sequences comma-separated (a long array by its size
    and range), records as ``key: value`` separated by semicolons."""
    if value is None:
        return "–"
    if isinstance(value, str):
        return value
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return _num(value, ".4g")
    if isinstance(value, numbers.Complex):
        return f"{_num(value.real, '.4g')} {'-' if value.imag < 0 else '+'} " \
               f"{_num(abs(value.imag), '.4g')}i"
    if not isinstance(value, dict | tuple | list | np.ndarray) and not (
            dataclasses.is_dataclass(value) and not isinstance(value, type)):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return "; ".join(f"{k}: ({_plain(v)})" if isinstance(v, dict) and v
                         else f"{k}: {_plain(v)}" for k, v in value.items()) or "none"
    a = np.asarray(value, dtype=object) if not isinstance(value, np.ndarray) else value
    if a.dtype.kind in "biuf" and a.size > _LIST_UP_TO:
        f = a[np.isfinite(a)] if a.dtype.kind == "f" else a
        rng = f"from {_plain(f.min())} to {_plain(f.max())}" if f.size else "none finite"
        return f"{a.size} values {rng}"
    items = list(value) if not isinstance(value, np.ndarray) else value.ravel().tolist()
    if not items or all(_is_empty(v) for v in items):
        return "none"
    return ", ".join(_plain(v) for v in items[:_LIST_UP_TO]) + (
        f", … ({len(items)} in all)" if len(items) > _LIST_UP_TO else "")


def _is_empty(value) -> bool:
    return isinstance(value, tuple | list | dict) and not value


def _rows(prefix: str, value, depth: int = 0) -> list[list[str]]:
    """``[name, text]`` rows of a value: a record (dict, dataclass) one row per
    entry, named by its path (``systematic / aliasing / u_px``), a sequence of records
    one row per record."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if depth < _DEPTH and isinstance(value, dict) and value:
        return [r for k, v in value.items() for r in _rows(f"{prefix} / {k}", v, depth + 1)]
    if (isinstance(value, tuple | list) and value
            and not all(_is_empty(v) for v in value)
            and any(isinstance(v, dict) or dataclasses.is_dataclass(v) for v in value)):
        # a sequence of records (one per series, per harmonic): a row each
        return [[f"{prefix} [{i}]", _plain(v)] for i, v in enumerate(value)]
    return [[prefix, _plain(value)]]


def _extra_fields(result) -> dict | None:
    """The fields no section shows, one row per value, as text."""
    rows = [r for f in dataclasses.fields(result)
            if f.name not in _SHOWN and getattr(result, f.name) is not None
            for r in _rows(f.name, getattr(result, f.name))]
    return _table(["field", "value"], rows, left=(0, 1)) if rows else None


def write_report(result_path, html_path, *, overwrite: bool = False, load=None,
                 load_unit: str | None = None, time=None, **options) -> Path:
    """Write the HTML report of a result file, atomically.

    Parameters
    ----------
    result_path : str or os.PathLike
        A file written by :func:`gridstrain.results.save_result`.
    html_path : str or os.PathLike
        Destination (``.html``).
    overwrite : bool
        Replace an existing file.
    load, load_unit, time : (S,) array_like, str, (S,) array_like, optional
        Each state's load, its unit and time, in place of the file's (those
        :func:`gridstrain.post.read_loads` reads from a testing machine's file);
        ``None`` keeps the file's.
    **options
        ``region``, ``px``, ``area``, ``area_unit``, ``axis``, ``limits``, ``cmap``
        of :func:`render_report`.

    Returns
    -------
    pathlib.Path
    """
    src = as_path(result_path, "result_path")
    result = load_result(src, in_memory=False)
    if load is not None:
        result = dataclasses.replace(result, load=load, load_unit=load_unit,
                                     time=result.time if time is None else time)
    text = render_report(result, attrs=read_attrs(src), title=f"gridstrain: {src.name}",
                         **options)
    dest = as_path(html_path, "html_path")
    return write_atomic(dest, text.encode("utf-8"), overwrite=overwrite)
