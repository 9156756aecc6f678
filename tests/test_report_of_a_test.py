"""The report shows what a test was run for (gauge, E and nu with their intervals),
in plain values; the maps' colour limits come from the signal (robust percentiles)."""

from __future__ import annotations

import dataclasses
import html
import re

import numpy as np
import pytest

from gridstrain.cli import main
from gridstrain.post import elastic_constants, gauge, modulus_unit, render_report
from gridstrain.results import load, read_attrs, save_result
from gridstrain.series import measure_series

N = 96  # px
PITCH = 5.0  # px
E_TRUE, NU_TRUE = 70e3, 0.33  # MPa, dimensionless
AREA = 20.0  # mm2
LOADS_KN = np.array([0.5, 1.0, 1.5, 2.0])  # stress 25 to 100 MPa: 357 to 1429 µε


def _grid(exx: float, eyy: float, rng, *, T: int = 2) -> np.ndarray:
    """``(T, N, N)`` frames of a grid under a homogeneous strain, with noise.

    Assumptions: a cross-line grid of pitch :data:`PITCH` px along x and y,
    ``I = A/2 (2 + g cos(2 pi X / p) + g cos(2 pi Y / p))`` at the material point
    ``X`` of each pixel ``x``; the strain is homogeneous about the image centre, so
    ``x - c = (1 + exx) (X - c)`` inverts exactly; Gaussian noise of std 8 grey
    levels on a mean of 1500 (a 12-bit camera), independent between frames.
    """
    c = (N - 1) / 2
    y, x = np.mgrid[0:N, 0:N].astype(np.float64)
    X = c + (x - c) / (1 + exx)
    Y = c + (y - c) / (1 + eyy)
    img = 750.0 * (2 + 0.9 * np.cos(2 * np.pi * X / PITCH) + 0.9 * np.cos(2 * np.pi * Y / PITCH))
    return img + rng.normal(0.0, 8.0, (T, N, N))


@pytest.fixture(scope="module")
def tested(tmp_path_factory):
    """A result of four load steps with the loads of a machine's file, saved."""
    d = tmp_path_factory.mktemp("test")
    rng = np.random.default_rng(41)
    stress = LOADS_KN * 1e3 / AREA  # MPa
    states = [_grid(s / E_TRUE, -NU_TRUE * s / E_TRUE, rng) for s in stress]
    # as a machine writes it: a preamble, semicolons, decimal commas, kN
    (d / "loads.csv").write_text(
        "Test: tensile coupon\n\nStep;Force (kN)\n"
        + "".join(f"{k + 1};{v:.2f}\n".replace(".", ",") for k, v in enumerate(LOADS_KN)),
        encoding="utf-8")
    res = measure_series(_grid(0.0, 0.0, rng), states, loads=d / "loads.csv")
    return save_result(res, d / "r.h5")


def _text(page: str) -> str:
    """The page's visible text (tags dropped, entities decoded)."""
    return html.unescape(re.sub(r"<[^>]+>", " ", page))


@pytest.fixture(scope="module")
def page(tested):
    """The report of :func:`tested` with the coupon's area, as the command writes it."""
    out = tested.with_name("r.html")
    assert main(["report", str(tested), "-o", str(out), "--area", str(AREA)]) == 0
    return out.read_text(encoding="utf-8")


def test_report_shows_e_and_nu_with_their_intervals(tested, page):
    text = _text(page)
    # the oracle: the constants of the default gauge (the whole valid region),
    # computed here from the result file
    c = elastic_constants(gauge(load(tested)), area=AREA)
    k, unit = modulus_unit(c.E, c.stress_unit)
    assert unit == "GPa"
    assert f"{c.E * k:.4g} GPa" in text
    assert f"[{c.E_ci[0] * k:.4g}, {c.E_ci[1] * k:.4g}] GPa" in text
    assert f"{c.nu:.4f}" in text
    assert f"[{c.nu_ci[0]:.4f}, {c.nu_ci[1]:.4f}]" in text
    assert 'alt="stress-strain plot"' in page
    assert 'alt="gauge history"' in page
    # and the oracle against the strain the frames were drawn with: within 3 % for E
    # and 0.03 for nu (four states of 96 px with 8-level noise: the gauges' std of
    # ~10 µε on 357-1429 µε give an interval of ~2 % on E)
    assert pytest.approx(E_TRUE, rel=0.03) == c.E
    assert c.nu == pytest.approx(NU_TRUE, abs=0.03)


def test_report_without_area_says_e_needs_it(tested):
    page = render_report(load(tested), attrs=read_attrs(tested))
    assert 'alt="load-strain plot"' in page
    assert 'alt="stress-strain plot"' not in page
    assert "need the specimen's cross-section" in _text(page)


def test_report_values_are_plain_text_and_one_table_per_state(tested, page):
    for raw in ("np.float64(", "array(", "{'", "np.int64(", "dtype=", "FrameScreen("):
        assert raw not in page, raw
    tables = re.findall(r"<table>(.*?)</table>", page, flags=re.S)
    # one table of the maps' means per state (the gauge's own table aside)
    per_state = [t for t in tables if "mean ε_xx" in t]
    assert len(per_state) == 1
    assert per_state[0].count("<tr>") == 1 + len(LOADS_KN)
    assert "noise ε_xx" in per_state[0]
    # each state's panel is titled with its load
    from gridstrain.post import plot_states

    fig = plot_states(load(tested), "exx")
    assert fig.axes[3].get_title().startswith("state 3, 2 kN\n")


def test_report_refuses_bad_options_in_one_line(tested, tmp_path, capsys):
    for bad in (["--area", "-1"], ["--limits", "explicit", "1"], ["--cmap", "nope"]):
        assert main(["report", str(tested), "-o", str(tmp_path / "x.html"), *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert err[0].startswith("gridstrain report: error:"), err
    assert not (tmp_path / "x.html").exists()


def test_plot_robust_limits_are_the_percentiles_of_every_state(tested, tmp_path,
                                                               monkeypatch):
    import gridstrain.post as post

    drawn = {}
    real = post.plot_states

    def spy(result, name, **kw):
        fig = real(result, name, **kw)
        drawn[name] = fig
        return fig

    monkeypatch.setattr(post, "plot_states", spy)
    assert main(["plot", str(tested), "-o", str(tmp_path / "f"), "--maps", "exx,eyy",
                 "--limits", "robust", "--dpi", "30"]) == 0
    res = load(tested)
    for name in ("exx", "eyy"):
        values = np.concatenate([np.asarray(res.get_map(name)[i])[res.valid[i]]
                                 for i in range(res.n_states)]) * 1e6  # µε
        lo, hi = np.percentile(values, [0.5, 99.5])
        if lo < 0 < hi and min(-lo, hi) > 0.05 * (hi - lo):
            # both signs hold more than 5 % of the range (map_norm's rule): a
            # diverging map, white at 0, spanning the larger percentile
            lo, hi = -max(-lo, hi), max(-lo, hi)
        norm = drawn[name].axes[0].get_images()[1].norm
        # the same order statistics: equal to float rounding (1e-9 µε)
        assert (norm.vmin, norm.vmax) == (pytest.approx(lo, abs=1e-9),
                                          pytest.approx(hi, abs=1e-9))
    # explicit limits and a colormap are drawn as given
    assert main(["plot", str(tested), "-o", str(tmp_path / "g"), "--maps", "exx",
                 "--limits", "explicit", "0", "2000", "--cmap", "cividis",
                 "--dpi", "30"]) == 0
    im = drawn["exx"].axes[0].get_images()[1]
    assert (im.norm.vmin, im.norm.vmax) == (0.0, 2000.0)
    assert im.get_cmap().name.startswith("cividis")


def test_animate_draws_explicit_limits_in_the_colormap_given(tested, tmp_path):
    import imageio.v3 as iio
    from matplotlib import colormaps

    out = tmp_path / "a.gif"
    # limits far above every strain (357-1429 µε): each valid pixel takes the lowest
    # colour of cividis, as a clipped value does
    assert main(["animate", str(tested), "exx", "-o", str(out), "--limits", "explicit",
                 "1e6", "2e6", "--cmap", "cividis", "--dpi", "40"]) == 0
    frame = iio.imread(out, index=0)[..., :3].astype(int)
    low = np.round(np.array(colormaps["cividis"](0.0)[:3]) * 255).astype(int)
    # within 2 grey levels (the GIF's 255-colour palette); the valid region is a
    # third of the map, a tenth of the frame at least
    share = np.mean(np.all(np.abs(frame - low) <= 2, axis=-1))
    assert share > 0.05
    assert main(["animate", str(tested), "exx", "-o", str(tmp_path / "b.gif"), "--limits",
                 "explicit", "5", "1"]) == 2


def test_report_of_several_gauges_side_by_side(tested, tmp_path):
    """``--region`` repeated: one table with each gauge's columns, each gauge's E and
    nu from its own fit (the oracle: the gauge of that region alone)."""
    regions = [(20.0, 20.0, 48.0, 76.0), (48.0, 20.0, 76.0, 76.0)]
    out = tmp_path / "two.html"
    argv = ["report", str(tested), "-o", str(out), "--area", str(AREA)]
    for r in regions:
        argv += ["--region", *map(str, r)]
    assert main(argv) == 0
    page = out.read_text(encoding="utf-8")
    text = _text(page)
    res = load(tested)
    for g, r in enumerate(regions, start=1):
        reading = gauge(res, region=r)
        c = elastic_constants(reading, area=AREA)
        k, unit = modulus_unit(c.E, c.stress_unit)
        assert f"Young's modulus E (G{g}) {c.E * k:.4g} {unit}" in " ".join(text.split())
        assert f'alt="stress-strain plot (G{g})"' in page
        # the gauge's strain of the last state, in its own column
        assert f"G{g} ε_xx (µε)" in text
        # shown to the std's second significant digit: "1443 ± 12"
        v, sd = reading.exx[-1] * 1e6, reading.exx_std[-1] * 1e6
        d = max(0, 1 - int(np.floor(np.log10(sd))))
        assert f"{v:.{d}f} ± {sd:.{d}f}" in text
    assert "G1, gauge over x in [20, 48)" in " ".join(text.split())


def test_report_state_table_says_displacements_in_the_maps_unit(tested):
    # the maps and the histories draw displacements in mm on a result with a pixel
    # size: the per-state table says the same unit, with the same numbers
    res = dataclasses.replace(load(tested), pixel_size=0.05, unit="mm")
    page = render_report(res)
    table = next(t for t in re.findall(r"<table>(.*?)</table>", page, flags=re.S)
                 if "mean ε_xx" in t)
    assert "mean u_x (mm)" in table
    assert "(px)" not in table
    v = np.asarray(res.valid[0])
    # the oracle: the mean of the valid pixels of state 0's u_x, px to mm, 4 digits
    assert f"{float(np.mean(np.asarray(res.ux[0])[v])) * 0.05:.4g}" in _text(table)
    # numbers in a µε column without an exponent: a noise floor of 834 µε reads 830
    assert "e+" not in _text(table)
    from gridstrain.post._report import _micro

    assert (_micro(8.34e-4), _micro(1.26e-5), _micro(float("nan"))) == ("830", "13", "–")


@pytest.fixture(scope="module")
def unloaded(tmp_path_factory):
    """Two strain states of :func:`_grid` measured without loads, saved."""
    d = tmp_path_factory.mktemp("unloaded")
    rng = np.random.default_rng(43)
    res = measure_series(_grid(0.0, 0.0, rng), [_grid(5e-4, -1.6e-4, rng),
                                               _grid(1e-3, -3.3e-4, rng)])
    return save_result(res, d / "r.h5")


def test_report_gauge_of_a_result_without_loads(unloaded, tmp_path):
    """A region named on a result without loads is gauged (its strains per state and
    their history), not silently ignored; no load column, no E; the note says why."""
    out = tmp_path / "g.html"
    region = (20.0, 20.0, 76.0, 76.0)
    assert main(["report", str(unloaded), "-o", str(out), "--region",
                 *map(str, region)]) == 0
    page = out.read_text(encoding="utf-8")
    section = page[page.index("<h2>The test</h2>"):page.index("<h2>Maps</h2>")]
    text = " ".join(_text(section).split())
    assert "gauge over x in [20, 76)" in text
    assert "load (" not in text  # the gauge's table has no load column
    assert 'alt="gauge history"' in section
    assert "The states have no loads" in text
    # the oracle: the gauge of that region alone, last state, as the table prints it
    reading = gauge(load(unloaded), region=region)
    v, sd = reading.exx[-1] * 1e6, reading.exx_std[-1] * 1e6
    d = max(0, 1 - int(np.floor(np.log10(sd))))
    assert f"{v:.{d}f} ± {sd:.{d}f}" in text


def test_report_region_outside_a_result_without_loads_is_refused(unloaded, tmp_path,
                                                                 capsys):
    # outside the 96-px field: one line naming the field's extent, no page
    out = tmp_path / "far.html"
    assert main(["report", str(unloaded), "-o", str(out), "--region",
                 "500", "500", "600", "600"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "96" in err
    assert not out.exists()


def test_report_of_a_result_without_loads_and_no_region_has_no_test_section(unloaded,
                                                                           tmp_path):
    out = tmp_path / "plain.html"
    assert main(["report", str(unloaded), "-o", str(out)]) == 0
    assert "<h2>The test</h2>" not in out.read_text(encoding="utf-8")


def test_report_area_on_a_result_without_loads_says_e_needs_them(unloaded, tmp_path):
    """--area asks for E: on a result without loads the test is shown (the gauge of
    the whole valid region) with the note that says what is missing, never dropped
    without a word."""
    out = tmp_path / "area.html"
    assert main(["report", str(unloaded), "-o", str(out), "--area", "20"]) == 0
    page = out.read_text(encoding="utf-8")
    assert "<h2>The test</h2>" in page
    assert "The states have no loads" in " ".join(_text(page).split())


def test_report_takes_the_loads_file_as_the_other_commands_do(unloaded, tmp_path):
    """``report --loads`` gives the states their loads (a machine's file, one row per
    state), as gauge, modulus and export do: the table's load column and the
    constants then come from it."""
    loads = tmp_path / "loads.csv"
    loads.write_text("Schritt;Kraft [kN]\n1;0,7\n2;1,4\n", encoding="utf-8")
    out = tmp_path / "loaded.html"
    assert main(["report", str(unloaded), "-o", str(out), "--loads", str(loads)]) == 0
    text = " ".join(_text(out.read_text(encoding="utf-8")).split())
    assert "load (kN)" in text
    assert "The states have no loads" not in text
    # the options that say how to read a loads file need one
    assert main(["report", str(unloaded), "-o", str(tmp_path / "x.html"),
                 "--loads-offset", "0.2"]) == 2
    assert not (tmp_path / "x.html").exists()
