"""A result as one self-contained HTML page, to open in any browser and send on.

:func:`write_report` reads a result file (:mod:`gridstrain.results`) and writes a
single HTML file: no script, no style sheet or font fetched, every figure a PNG
embedded as a ``data:`` URI, so the page shows the same offline, attached to an
e-mail or archived with the data. It holds the run's provenance (version, date,
input files, the configuration that replays the run), the lattice, the
vibrations of every series, the noise floor, the maps of every state on common
colour limits (strains in µε), the rotation and uncertainty maps, the strain of
the states averaged over the valid region, and the warnings.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import math
from pathlib import Path

import numpy as np

from ._validation import as_path, check_type
from .io import write_atomic
from .pipeline import MAP_FIELDS, SeriesResult
from .plotting import plot_history, plot_shifts, plot_states
from .results import load, read_attrs

__all__ = ["render_report", "write_report"]

_DPI = 90
_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 2px 8px; text-align: right; }
th { background: #f0f0f0; } td.l, th.l { text-align: left; }
img { max-width: 100%; } pre { background: #f6f6f6; padding: 0.5em; overflow-x: auto; }
.warn { background: #fff4e0; border-left: 4px solid #e69500; padding: 0.3em 0.6em; }
figure { margin: 0.5em 0; } figcaption { font-size: 0.85em; color: #555; }
"""


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(fig, alt: str, caption: str = "") -> str:
    cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return (f'<figure><img class="figure" alt="{html.escape(alt)}" '
            f'src="data:image/png;base64,{_png(fig)}">{cap}</figure>')


def _num(x, spec: str = ".3g") -> str:
    if x is None:
        return "–"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return html.escape(str(x))
    return "–" if not math.isfinite(v) else format(v, spec)


def _table(header, rows, left=(0,)) -> str:
    """A table; cells are HTML already escaped; the columns ``left`` hold text."""
    def cell(tag, i, c):
        return f'<{tag} class="l">{c}</{tag}>' if i in left else f"<{tag}>{c}</{tag}>"

    head = "".join(cell("th", i, html.escape(h)) for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell("td", i, c) for i, c in enumerate(r)) + "</tr>"
                   for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


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
    out = _head(result, a, ps, unit, title)
    if result.warnings:
        out.append("<h2>Warnings</h2>")
        out += [f'<p class="warn">{html.escape(w)}</p>' for w in result.warnings]
    out += _inputs_section(result)
    out += _lattice_section(result)
    out += _vibration_section(result)
    out += _noise_section(result)
    out += _maps_section(result, ps, unit)
    if result.uncertainty:
        out.append("<h2>Uncertainty maps</h2><p>Predicted standard deviation of each map "
                   "at each pixel, from the noise measured in the frames.</p>")
        for name in result.uncertainty:
            if name in ("ux_std", "uy_std", "exx_std", "eyy_std", "exy_std"):
                out.append(_figure(plot_states(result, name, pixel_size=ps, unit=unit),
                                   f"uncertainty map of {name}"))
    extra = _extra_fields(result)
    if extra:
        out.append("<h2>Other results</h2>")
        out += [f"<h3>{html.escape(k)}</h3><pre>{html.escape(v)}</pre>" for k, v in extra]
    out += _provenance_section(result, a)
    out.append("</body></html>\n")
    return "\n".join(out)


def _head(result, a: dict, ps, unit, title: str) -> list[str]:
    """The page's head, title and the one-paragraph description of the run."""
    H, W = result.shape
    return [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
            f"<h1>{html.escape(title)}</h1>",
            f"<p>{result.n_states} loaded state(s) against the reference, {H} × {W} px, "
            f"method {result.method}, σ = {result.sigma:.4g} px (spatial resolution "
            f"{result.noise.spatial_resolution:.3g} px"
            + (f" = {result.noise.spatial_resolution * ps:.3g} {html.escape(unit)}"
               if ps else "")
            + f", the period damped by 10 %; window FWHM "
            f"{result.noise.window_fwhm:.3g} px), large-displacement correction "
            f"{'on' if result.lagrangian else 'off'}. "
            f"Written by gridstrain {html.escape(str(a.get('gridstrain_version', '?')))} "
            f"on {html.escape(str(a.get('created', '?')))}.</p>"]


def _inputs_section(result) -> list[str]:
    """Every image series: frames, bit depth, saturation and files."""
    rows = []
    for name, files, T, bits, scale, sat in zip(
            result.names, result.sources, result.n_frames, result.bit_depth, result.scale,
            result.saturation, strict=True):
        where = html.escape(files[0]) + (f" … ({len(files)} files)" if len(files) > 1
                                         else "") if files else "array in memory"
        depth = "float" if bits is None else f"{bits}-bit" + (f" ×{scale}" if scale != 1
                                                               else "")
        rows.append([html.escape(name), str(T), depth, f"{sat:.2%}", where])
    return ["<h2>Inputs</h2>",
            _table(["series", "frames", "data", "saturated", "files"], rows, left=(0, 4))]


def _lattice_section(result) -> list[str]:
    """The wave vectors, pitches and angles, and whether they were detected."""
    lat = result.lattice
    how = "Detected on the mean reference image" if result.lattice_detected else "Given"
    return ["<h2>Lattice</h2>",
            _table(["wave vector", "kx (cycles/px)", "ky (cycles/px)", "pitch (px)",
                    "angle (deg)"],
                   [[k, _num(v[0], ".6g"), _num(v[1], ".6g"), _num(p, ".5f"),
                     _num(ang, ".3f")] for k, v, p, ang in
                    zip(("k1", "k2"), (lat.k1, lat.k2), lat.pitches, lat.angles,
                        strict=True)]),
            f"<p>{how}; validity margin {result.margin:g} σ.</p>"]


def _vibration_section(result) -> list[str]:
    """The vibrations of every series: a table, and the shifts of each stack."""
    out = ["<h2>Vibrations</h2>",
           _table(["series", "std α (px)", "std β (px)", "contrast k1", "contrast k2",
                   "phase offset std k1 (rad)", "k2 (rad)"],
                  [[html.escape(v.name), _num(v.std[0]), _num(v.std[1]),
                    _num(v.contrast_factor[0], ".5f"), _num(v.contrast_factor[1], ".5f"),
                    _num(v.phase_offset_std[0]), _num(v.phase_offset_std[1])]
                   for v in result.vibration])]
    for v in result.vibration:
        if v.n_frames > 1:
            out.append(_figure(plot_shifts(v.shifts, title=f"{v.name}: rigid shift of each "
                                           "frame"), f"vibrations of {v.name}"))
    return out


def _noise_section(result) -> list[str]:
    """The noise floor of every state, and the sensor noise of every series."""
    nf = result.noise
    out = ["<h2>Noise floor</h2><p>One standard deviation of the random error at a "
           "pixel. Theory: windowed-Fourier noise with the sensor variance measured in "
           "the frames; halves: the reference split in two, scaled.</p>"]
    rows = []
    for i in range(result.n_states):
        for label, u, e in (("theory", nf.theory_u[i], nf.theory_strain[i]),
                            ("reference halves", nf.split_u[i], nf.split_strain[i])):
            rows.append([f"{html.escape(result.names[i + 1])}, {label}",
                         _num(u[0]), _num(u[1]),
                         *(_num(x * 1e6) for x in e)])
        rows.append([f"{html.escape(result.names[i + 1])}, vibration offset (rigid)",
                     _num(nf.vibration_u[i][0]), _num(nf.vibration_u[i][1]), "–", "–", "–"])
    out.append(_table(["", "u_x (px)", "u_y (px)", "ε_xx (µε)", "ε_yy (µε)", "ε_xy (µε)"],
                      rows))
    out.append(_table(["series", "sensor variance (grey levels²)", "how", "|Ψ| k1", "|Ψ| k2"],
                      left=(0, 2), rows=
                      [[html.escape(n), _num(v), html.escape(m), _num(mod[0]), _num(mod[1])]
                       for n, v, m, mod in zip(result.names, nf.sensor_variance,
                                               nf.variance_method, nf.modulus, strict=True)]))
    return out


def _maps_section(result, ps, unit) -> list[str]:
    """The maps of every state, their means over the valid region, and the strain
    history."""
    out = ["<h2>Maps</h2><p>Every state on the same colour limits; strains in µε "
           "(10⁻⁶), displacements in "
           + (html.escape(unit) if ps else "px")
           + "; outside the valid region the reference image shows through.</p>"]
    for name in (*MAP_FIELDS, "rotation"):
        out.append(_figure(plot_states(result, name, pixel_size=ps, unit=unit),
                           f"map of {name}"))
    rows = []
    for i, m in enumerate(result.measurements):
        v = result.valid[i]
        means = [float(np.mean(result.get_map(k)[i][v])) if v.any() else math.nan
                 for k in MAP_FIELDS]
        rows.append([html.escape(result.names[i + 1]), f"{v.mean():.1%}",
                     _num(means[0], ".4f"), _num(means[1], ".4f"),
                     *(_num(x * 1e6, ".1f") for x in means[2:]), str(m.iterations),
                     html.escape(_fringe_order(result, i))])
    out.append(_table(["state", "valid", "mean u_x (px)", "mean u_y (px)", "mean ε_xx (µε)",
                       "mean ε_yy (µε)", "mean ε_xy (µε)", "iterations", "fringe order"],
                      rows, left=(0, 8)))
    if result.n_states > 1:
        out.append(_figure(plot_history(result), "strain of the states",
                           "Strain of every state, mean over the valid pixels."))
    return out


def _provenance_section(result, a: dict) -> list[str]:
    """Every parameter of the run, the configuration that replays it, the conventions."""
    params = [[html.escape(str(k)), html.escape(repr(v))]
              for k, v in result.parameters.items()]
    out = ["<h2>Provenance</h2>", _table(["parameter", "value"], params, left=(0, 1))]
    if a.get("config"):
        out.append("<p>The configuration of this run (replay it with <code>gridstrain "
                   "measure --config RESULT.h5 -o OUT.h5</code>):</p>"
                   f"<pre>{html.escape(str(a['config']), quote=False)}</pre>")
    out.append(f"<p>Conventions: {html.escape(str(a.get('conventions', '')))}</p>")
    return out


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
    result = load(src)
    text = render_report(result, attrs=read_attrs(src), title=f"gridstrain: {src.name}")
    dest = as_path(html_path, "html_path")
    return write_atomic(dest, text.encode("utf-8"), overwrite=overwrite)
