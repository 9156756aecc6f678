"""What ``gridstrain measure`` says about a result: the lines it prints (the lattice, the
fringe orders, the noise floor, the metrology, the systematic errors) and the JSON summary.
"""

from __future__ import annotations

import math

import numpy as np

from .._progress import tally
from ..results import MAP_FIELDS, SeriesResult
from ..uncertainty import FWHM_PER_SIGMA, SPATIAL_RESOLUTION_PER_SIGMA


def findings_json(found) -> list[dict]:
    """A JSON summary's ``"findings"``: each of ``found`` (the summary's ``"warnings"``,
    in their order) with its code, severity, state and figures, for a reader that
    selects them by code."""
    return [{"code": w.code, "severity": w.severity, "state": w.state,
             "figures": w.record()["figures"]} for w in found]


def _fmt(x: float, spec: str = ".2e") -> str:
    return "n/a" if x is None or not math.isfinite(x) else format(x, spec)


def _angle(deg: float) -> str:
    # round first, then add 0.0 so that a tiny negative angle prints 0.000, not -0.000
    return f"{round(deg, 3) + 0.0:.3f}"


def _describe_depth(result: SeriesResult) -> str:
    bits, scale = result.bit_depth[0], result.scale[0]
    if bits is None:
        return "float data"
    return f"{bits}-bit data" + (f" stored x{scale}" if scale != 1 else "")


# States reported one by one up to this many; beyond (a record), the tables show the
# first, the last and evenly spaced ones, and any state with something wrong
_LISTED = 12
_SAMPLED = 6


def _listed(n: int, notable=()) -> tuple[list[int], list[str]]:
    """The states a table shows, and the line that says which (none: all of them)."""
    if n <= _LISTED:
        return list(range(n)), []
    shown = sorted({*np.round(np.linspace(0, n - 1, _SAMPLED)).astype(int).tolist(),
                    *notable})
    return shown, [f"  ({len(shown)} of {n} states shown: every state's figures are in the "
                   "result file, the JSON summary (--json) and the report (--report))"]


def _loads_line(result) -> list[str]:
    """How the loads file was read and joined to the states, in one line (none
    without a file)."""
    src = getattr(result, "load_source", None)
    if not src:
        return []
    sep = {"\t": "tab", " ": "spaces", "whitespace": "spaces"}.get(src["delimiter"],
                                                                 repr(src["delimiter"]))
    sep = "one column" if src["delimiter"] == "none (one column)" else \
        f"{sep} between columns"
    how = (f"at the states' times + {src['offset_s']:g} s on {src['time_column']!r}, "
           "linear interpolation" if src["method"] == "linear interpolation in time"
           else src["method"])
    return [f"loads: {src['file']} ({src['encoding']}, {sep}, decimal "
            f"{src['decimal']!r}), {src['load_column']!r} {how}; "
            f"SHA-256 {src['sha256'][:12]}..."]


def report_lines(result: SeriesResult, *, pixel_size: float | None = None,
                 unit: str | None = None) -> list[str]:
    """The human-readable report of a measurement, as lines of text. A record of many
    states is summed up: its tables show a few states (the first, the last, evenly
    spaced ones, and any with no valid pixel or a failed pair check); the warnings are
    all there."""
    H, W = result.shape
    lat = result.lattice
    p1, p2 = lat.pitches
    a1, a2 = lat.angles
    lines = [
        f"{result.n_states} loaded state(s) against the reference, {H} x {W} px, "
        f"{_describe_depth(result)}; {_ORDER_TEXT[result.state_order]}",
        f"lattice ({'detected' if result.lattice_detected else 'given'}): pitches "
        f"{p1:.4f}/{p2:.4f} px, angles {_angle(a1)}/{_angle(a2)} deg; sigma "
        f"{result.sigma:.4g} px, "
        f"method {result.method}, large-displacement correction "
        f"{'on' if result.lagrangian else 'off'}",
        *_loads_line(result),
        "",
        "vibrations (rigid shift of each frame, 1 std)  alpha px  beta px   contrast k1/k2"
        "   phase offset k1/k2 rad",
    ]
    record = result.n_states > _LISTED
    single = [v for v in result.vibration if v.n_frames == 1] if record else []
    for k, v in enumerate(result.vibration):
        if record and v.n_frames == 1:
            continue
        label = f"  {v.name}, {v.n_frames} frame(s)"
        if result.excluded and result.excluded[k]:
            label += f" ({len(result.excluded[k])} excluded)"
        contrast = f"{_fmt(v.contrast_factor[0], '.5f')}/{_fmt(v.contrast_factor[1], '.5f')}"
        lines.append(f"{label:<46} {_fmt(v.std[0], '.4f'):>8} {_fmt(v.std[1], '.4f'):>8}   "
                     f"{contrast:<16} "
                     f"{_fmt(v.phase_offset_std[0])}/{_fmt(v.phase_offset_std[1])}")
    if single:
        lines.append(f"  {len(single)} series of one frame: no vibration to measure")
    nf = result.noise
    empty = [i for i in range(result.n_states) if not result.valid[i].any()] \
        if record else []
    shown, note = _listed(result.n_states, empty)
    # the state names' column as wide as the longest shown (frame000001: 11), so that
    # the numbers stay under their heads
    w = max([9, *(len(result.names[i + 1]) for i in shown)])
    lines += ["", f"{'noise floor (1 std at a pixel)':<{w + 33}}u_x px    u_y px    e_xx"
              "      e_yy      e_xy"]
    for i in shown:
        given = (nf.model or {}).get("source", "").startswith("given")
        theory = "theory, given camera model" if given else "theory, measured sensor noise"
        rows = [(theory, nf.theory_u[i], nf.theory_strain[i]),
                ("reference halves, scaled", nf.split_u[i], nf.split_strain[i])]
        unc = result.uncertainty
        if unc is not None and result.valid[i].any():
            v = result.valid[i]
            med = [float(np.median(unc[k][i][v])) for k in
                   ("ux_std", "uy_std", "exx_std", "eyy_std", "exy_std")]
            rows.append(("uncertainty maps, median", med[:2], med[2:]))
        rows.append(("vibration offset (rigid)", nf.vibration_u[i], None))
        for k, (name, u, e) in enumerate(rows):
            head = f"  {result.names[i + 1] if k == 0 else '':<{w}} {name:<30}"
            es = "  ".join(f"{_fmt(x):<8}" for x in e) if e is not None else \
                "-         -         -"
            lines.append(f"{head} {_fmt(u[0]):<8}  {_fmt(u[1]):<8}  {es}")
    lines += note
    # the later tables show the same states: said once in full
    note = [f"  (the same {len(shown)} of {result.n_states} states)"] if note else []
    res = f"{nf.spatial_resolution:.3g} px"
    if pixel_size is not None:
        res += f" = {nf.spatial_resolution * pixel_size:.3g} {unit}"
    lines.append(f"spatial resolution: {res} (period of a sine displacement damped by "
                 f"10 %, {SPATIAL_RESOLUTION_PER_SIGMA:.2f} sigma; window FWHM "
                 f"{nf.window_fwhm:.3g} px, {FWHM_PER_SIGMA:.3f} sigma)")
    lines += _noise_source_lines(result)
    lines += _metrology_lines(result, shown, note)
    lines += _systematic_lines(result, shown, note)
    lines.append("")
    for i in shown:
        m, v = result.measurements[i], result.valid[i]
        if v.any():
            e = [float(np.mean(c[v])) for c in result.strain[i]]
            u = [float(np.mean(c[v])) for c in result.u[i]]
            lines.append(f"{result.names[i + 1]}: {v.mean():.1%} valid; mean e_xx "
                         f"{e[0]:.3e}, e_yy {e[1]:.3e}, e_xy {e[2]:.3e}; mean u "
                         f"({u[0]:.4f}, {u[1]:.4f}) px; {m.iterations} iteration(s)")
            lines.append("  " + _fringe_line(result, i))
        else:
            lines.append(f"{result.names[i + 1]}: no valid pixel")
    lines += note
    if result.warnings:  # counted by their codes' severity, then said one by one
        lines.append(f"findings: {tally(result.warnings)}")
    for w in result.warnings:
        lines.append(f"warning: {w}")
    return lines


_ORDER_TEXT = {"natural": "states in natural order",
               "reordered": "states put in natural order from the order given",
               "given": "states in the order given"}


def _fringe_line(result: SeriesResult, i: int) -> str:
    """How state ``i``'s fringe order was fixed, in one line."""
    if not result.fringe_orders:
        return (f"fringe order from the guess ({result.guesses[i][0]:.2f}, "
                f"{result.guesses[i][1]:.2f}) px: {result.guess_sources[i]}")
    r = result.fringe_orders[i]
    state = "confirmed" if r.confirmed else "NOT CONFIRMED (may be whole periods off)"
    if not r.confirmed and r.strain_if_off > 0:
        state = (f"NOT CONFIRMED (may be whole periods off, and its strain by up to "
                 f"{r.strain_if_off:.1e})")
    return (f"fringe order: {r.source}, {state}; guess ({r.guess[0]:.2f}, "
            f"{r.guess[1]:.2f}) px; {r.detail}")


def _noise_source_lines(result: SeriesResult) -> list[str]:
    model = result.noise.model or {}
    src = model.get("source", "stack")
    if "K" not in model:
        return [f"image noise: {src} (temporal variance of each series)"]
    scale = model.get("scale") or 1
    line = (f"image noise: {src}, Var = K l + L with K = {_fmt(model['K'], '.4g')}, "
            f"L = {_fmt(model['L'], '.4g')} (stored grey levels)")
    if scale != 1:
        line += (f"; sensor units (x{scale:g}): K = {_fmt(model['K_sensor'], '.4g')}, "
                 f"L = {_fmt(model['L_sensor'], '.4g')}")
    if model.get("K_ci"):
        line += f"; K 95 % CI {_fmt(model['K_ci'][0], '.4g')} to {_fmt(model['K_ci'][1], '.4g')}"
    return [line]


def _metrology_lines(result: SeriesResult, shown: list[int], note: list[str]) -> list[str]:
    m = result.metrology
    if m is None:
        return []
    lines = [f"metrology (sigma {m['sigma_px']:.4g} px: spatial resolution "
             f"d = {m['spatial_resolution_px']:.3g} px (10 % attenuation period), step "
             f"10-90 % over "
             f"{m['step_width_px']:.3g} px; efficiency = resolution x d for u, x d^2 for "
             "strain, px^2)",
             "                     u_x px    u_y px    e_xx      e_yy      e_xy"]
    for i in shown:
        st = m["states"][i]
        names = ("ux", "uy", "exx", "eyy", "exy")
        res = "  ".join(f"{_fmt(st[k]['resolution']):<8}" for k in names)
        eff = "  ".join(f"{_fmt(st[k]['efficiency']):<8}" for k in names)
        lines.append(f"  {result.names[i + 1]:<9} resolution {res}")
        lines.append(f"  {'':<9} efficiency {eff}")
    return lines + note


def _systematic_lines(result: SeriesResult, shown: list[int], note: list[str]) -> list[str]:
    sy = result.systematic
    if sy is None:
        return []
    a = sy["aliasing"]
    how = "harmonics measured" if a["observable"] else "a sharp print's harmonics"
    ux, uy = a.get("u_px_components", [a["u_px"]] * 2)
    lines = [f"systematic: harmonic aliasing up to {_fmt(ux)}/{_fmt(uy)} px (u_x/u_y, "
             f"{how}); "
             "window smoothing of strain gradients (bound on the peak error, "
             f"{sy['smoothing'][0].get('factor', 1) if sy['smoothing'] else 1:g} x the "
             "largest sigma^2/2 lap e):"]
    for i in shown:
        if i >= len(sy["smoothing"]):
            continue
        sm = sy["smoothing"][i]
        lines.append(f"  {result.names[i + 1]:<9} e_xx {_fmt(sm['max'][0])}  e_yy "
                     f"{_fmt(sm['max'][1])}  e_xy {_fmt(sm['max'][2])}")
    lines += note if sy["smoothing"] else []
    offsets = [r for r in sy.get("vibration_offset", ()) if r is not None]
    if offsets:
        lines.append("vibration offset about the frames' mean position, removed (rad, k1/k2):")
        lines += [f"  {r['series']:<9} {_fmt(r['removed_rad'][0])}/{_fmt(r['removed_rad'][1])}"
                  for r in offsets]
    pairs = sy.get("pair_match", ())
    if pairs:
        lines.append("pair check (each state's content against the reference's, warped back):")
        rows, more = pairs, []
        if note:  # a record: the states shown, and every one whose content does not match
            names = {result.names[i + 1] for i in shown}
            rows = [r for r in pairs if r["state"] in names or r["verdict"] in _FAILED_PAIRS]
            more = [f"  ({len(rows)} of {len(pairs)} states: the same, and every one whose "
                    "content does not match)"]
        lines += [f"  {r['state']:<9} {r['verdict']}: correlation {_fmt(r['rho'], '.3f')} for "
                  f"{_fmt(r['rho_match'], '.3f')} expected (match {_fmt(r['match'], '.2f')}, "
                  f"spread {_fmt(r['rho_sd'], '.3f')})" for r in rows] + more
    return lines


_FAILED_PAIRS = ("mismatch", "nothing matches")


def jsonable(value):
    """``value`` with NaN and infinities replaced by None, tuples by lists."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def summary(result: SeriesResult, *, outputs: dict, seconds: float,
            pixel_size: float | None = None, unit: str | None = None) -> dict:
    """JSON-ready summary of a measurement."""
    def num(x):
        return float(x) if x is not None and math.isfinite(x) else None

    states = []
    for i, m in enumerate(result.measurements):
        v = result.valid[i]
        states.append({
            "name": result.names[i + 1], "frames": result.n_frames[i + 1],
            "excluded_frames": list(result.excluded[i + 1]) if result.excluded else [],
            "files": list(result.sources[i + 1]), "valid_fraction": float(v.mean()),
            "mean": {name: num(float(np.mean(result.get_map(name)[i][v]))) if v.any()
                     else None for name in MAP_FIELDS},
            "iterations": int(m.iterations), "guess_px": list(result.guesses[i]),
            "guess_source": result.guess_sources[i],
            "fringe_order": result.fringe_orders[i].as_dict() if result.fringe_orders
            else None,
            "load": None if result.load is None else num(result.load[i]),
            "time_s": None if result.time is None else num(result.time[i]),
        })
    lat = result.lattice
    return {
        "outputs": outputs,
        "image": list(result.shape),
        "bit_depth": result.bit_depth[0], "scale": result.scale[0],
        "lattice": {"k1": list(lat.k1), "k2": list(lat.k2), "pitches_px": list(lat.pitches),
                    "angles_deg": list(lat.angles), "detected": result.lattice_detected},
        "sigma_px": result.sigma, "method": result.method, "lagrangian": result.lagrangian,
        "margin": result.margin, "pixel_size": pixel_size, "unit": unit,
        "reference": {"frames": result.n_frames[0], "files": list(result.sources[0]),
                      "excluded_frames": list(result.excluded[0]) if result.excluded
                      else []},
        "state_order": result.state_order, "load_unit": result.load_unit,
        "loads": result.load_source, "states": states,
        "vibration": [{"series": v.name, "frames": v.n_frames,
                       "std_px": [num(x) for x in v.std],
                       "contrast_factor": [num(x) for x in v.contrast_factor],
                       "phase_offset_std_rad": [num(x) for x in v.phase_offset_std],
                       "estimator": v.estimator} for v in result.vibration],
        "noise_floor": result.noise.as_dict(),
        "uncertainty_median": _uncertainty_medians(result),
        "noise_model": result.noise.model,
        "metrology": result.metrology,
        "systematic_errors": result.systematic,
        "warnings": list(result.warnings),
        "findings": findings_json(result.warnings),
        "seconds": seconds,
    }


def _uncertainty_medians(result: SeriesResult):
    """Median of each per-pixel std map over the valid pixels, per state."""
    if result.uncertainty is None:
        return None
    out = []
    for i in range(result.n_states):
        v = result.valid[i]
        out.append({k: (float(np.median(a[i][v])) if v.any() else None)
                    for k, a in result.uncertainty.items()})
    return out
