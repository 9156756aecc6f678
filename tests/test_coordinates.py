"""One rule for the places a command or function names (issue 41, point 1): a region or
point in the result file's physical unit when it has a pixel size, in px with ``--px``
(or without a pixel size in Python); a place outside the measured field, or with no
valid pixel, refused in one line naming the field's extent; map axes in that unit.
Also: a result changed with ``dataclasses.replace`` is saved with its own maps.

The oracle of every conversion is written here: px = mm / pixel size, and the pixels a
region holds are those whose centre ``col * PS`` lies in ``[x0, x1)``.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from gridstrain import measure_series
from gridstrain.cli import main
from gridstrain.post import gauge, history, plot_history, plot_states
from gridstrain.results import load

H, W = 192, 256
PITCH = 5.0  # px: a 0.2 mm grid at PS
PS = 0.04  # mm per px, not a power of two: px = mm / PS is not exact in binary
#: The axial strain of each loaded state and the specimen's law.
STRAINS = tuple(0.3e-3 * k for k in range(1, 8))  # seven: --window 7 of the docs
NU, E_MPA, AREA = 0.3, 70_000.0, 20.0  # MPa, mm2
DT = 0.5  # s between states
NOISE = 5.0  # grey levels, std


def grid_image(exx: float, eyy: float, rng) -> np.ndarray:
    """A cross grid of pitch ``PITCH`` px under the homogeneous strain (exx, eyy).

    Assumptions: the grid model of the method's paper (eq. 1), ``2000 (1 + 0.4
    cos(2 pi X / p) + 0.4 cos(2 pi Y / p))``, sampled at the pixel centres (no pixel
    integration: it would only scale the contrast of a band-limited cosine); the
    material point ``X`` seen at ``x = (1 + exx) X`` (Lagrangian, so the small-strain
    tensor is exactly ``(exx, eyy, 0)``); white Gaussian noise of std ``NOISE``.
    """
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    X, Y = x / (1.0 + exx), y / (1.0 + eyy)
    level = 2000.0 * (1.0 + 0.4 * np.cos(2 * np.pi * X / PITCH)
                      + 0.4 * np.cos(2 * np.pi * Y / PITCH))
    return level + rng.normal(0.0, NOISE, level.shape)


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    """A tensile test of seven states, its loads and times from a one-row-per-state file,
    saved with a pixel size of ``PS`` mm: ``(path, loaded result)``."""
    d = tmp_path_factory.mktemp("coordinates")
    rng = np.random.default_rng(41)
    ref = grid_image(0.0, 0.0, rng)
    states = [grid_image(e, -NU * e, rng) for e in STRAINS]
    loads = d / "loads.csv"
    with open(loads, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["load [N]", "time [s]"])
        for k, e in enumerate(STRAINS):
            w.writerow([E_MPA * AREA * e, DT * (k + 1)])
    res = measure_series(ref, states, guess=None, noise_model=(1e-6, NOISE**2),
                         loads=loads)
    # lossless: the readings in mm and px are compared to the last bit
    path = res.save(d / "maps.h5", pixel_size=PS, unit="mm", lossless=True)
    return path, load(path)


def _mm_to_px(values):
    return [v / PS for v in values]


def _region_oracle(result, region_mm, name="exx"):
    """Mean of ``name`` over the valid pixels whose centre (col * PS, row * PS) lies in
    the region, state by state: written here, independently of the gauge."""
    x0, y0, x1, y1 = region_mm
    cols, rows = np.arange(W) * PS, np.arange(H) * PS
    inside = ((rows[:, None] >= y0) & (rows[:, None] < y1)
              & (cols[None, :] >= x0) & (cols[None, :] < x1))
    out = []
    for i in range(result.n_states):
        ok = inside & np.asarray(result.valid[i])
        out.append(float(np.mean(np.asarray(result.get_map(name)[i])[ok])))
    return np.array(out)


def _run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


# a region whose edges fall between pixel centres in both units
REGION_MM = (2.01, 2.03, 8.05, 6.02)
OUTSIDE_MM = (9.0, 2.0, 12.0, 4.0)  # x1 beyond the 10.24 mm of the field
# the border band the window's margin leaves invalid: inside the field, no valid pixel
INVALID_MM = (0.0, 0.0, 0.2, 0.2)
EXTENT_MM = "x 0 to 10.24, y 0 to 7.68 mm"


# ----------------------------------------------------------------------------- Python


def test_gauge_mm_and_px_read_the_same_pixels(result_file):
    _, res = result_file
    mm = gauge(res, region=REGION_MM, pixel_size=PS, unit="mm")
    px = gauge(res, region=_mm_to_px(REGION_MM), px=True)
    # the same pixels: the same sums, bit for bit
    assert_array_equal(mm.n_pixels, px.n_pixels)
    assert_array_equal(mm.exx, px.exx)
    assert_array_equal(mm.eyy_std, px.eyy_std)
    # the pixels are those the oracle selects: its mean to the rounding of a sum of
    # ~1e4 float64 values (1e-15 strain), far below any strain shown
    assert_allclose(mm.exx, _region_oracle(res, REGION_MM), rtol=0, atol=1e-12)
    assert "mm" in mm.where
    assert "px" not in mm.where.split("(")[0]
    # and the strain is the one imposed, to the noise of the gauge's mean (its std is
    # ~1e-6 here; 5 std)
    assert_allclose(mm.exx, STRAINS, rtol=0, atol=5 * float(np.max(mm.exx_std)))


def test_gauge_point_mm_and_px(result_file):
    _, res = result_file
    x, y = 5.013, 3.987  # mm: the nearest pixel is (125, 100), 0.33 and 0.33 px away
    mm = gauge(res, point=(x, y), pixel_size=PS, unit="mm")
    px = gauge(res, point=(x / PS, y / PS), px=True)
    assert_array_equal(mm.exx, px.exx)
    assert_array_equal(mm.exx, np.asarray(res.exx[:, 100, 125]))
    assert "x = 125, y = 100 px" in mm.where


@pytest.mark.parametrize(("place", "what"), [
    ({"region": OUTSIDE_MM}, "region corner (12, 4) mm lies outside"),
    ({"point": (3.0, 7.7)}, "point (3, 7.7) mm lies outside"),
    ({"polygon": [(1, 1), (11, 1), (1, 5)]}, "polygon vertex (11, 1) mm lies outside"),
    ({"region": INVALID_MM}, f"holds no valid pixel in any of the {len(STRAINS)} state(s)"),
])
def test_gauge_refuses_a_place_outside_or_without_valid_pixel(result_file, place, what):
    _, res = result_file
    with pytest.raises(ValueError, match="the measured field spans") as info:
        gauge(res, pixel_size=PS, unit="mm", **place)
    msg = str(info.value)
    assert what in msg
    assert EXTENT_MM in msg
    assert "\n" not in msg
    # the same place in px: the same refusal, the extent in px
    px = {k: np.asarray(v, dtype=float) / PS for k, v in place.items()}
    with pytest.raises(ValueError, match="x 0 to 256, y 0 to 192 px"):
        gauge(res, px=True, **px)


def test_the_result_carries_its_pixel_size_and_places_say_their_unit(result_file):
    _, res = result_file
    # the file's pixel size, carried by the loaded result
    assert (res.pixel_size, res.unit) == (PS, "mm")
    # an mm region named with the result's unit and its px equivalent: one gauge
    mm = gauge(res, region=REGION_MM, unit="mm")
    px = gauge(res, region=_mm_to_px(REGION_MM), px=True)
    assert_array_equal(mm.n_pixels, px.n_pixels)
    assert_array_equal(mm.exx, px.exx)
    assert_array_equal(mm.exy_std, px.exy_std)
    assert_allclose(mm.exx, _region_oracle(res, REGION_MM), rtol=0, atol=1e-12)
    # the pixel size given again (as read from the file, or typed from its 6 printed
    # digits) is the same rule
    again = gauge(res, region=REGION_MM, pixel_size=PS * (1 + 2e-6), unit="mm")
    assert_array_equal(again.exx, mm.exx)
    # a place without its unit on a result with a pixel size: refused (it read px
    # before results carried their pixel size), naming both ways to write it
    for call in (lambda: gauge(res, region=REGION_MM),
                 lambda: gauge(res, point=(5.0, 4.0)),
                 lambda: plot_history(res, region=REGION_MM)):
        with pytest.raises(ValueError, match=r"does not say its unit.*unit='mm'.*"
                                             r"px=True"):
            call()
    # another pixel size, another unit, or both px and a unit: refused
    with pytest.raises(ValueError, match="disagrees with this result's own"):
        gauge(res, region=REGION_MM, pixel_size=0.05, unit="mm")
    with pytest.raises(ValueError, match="this result's length unit 'mm'"):
        gauge(res, region=REGION_MM, unit="um")
    with pytest.raises(ValueError, match="px=True names places in pixels"):
        gauge(res, region=REGION_MM, unit="mm", px=True)
    # the whole field needs no unit
    assert_array_equal(gauge(res).n_pixels, gauge(res, px=True).n_pixels)
    # outside the field: one line naming the field's extent in the unit given
    with pytest.raises(ValueError, match=EXTENT_MM):
        gauge(res, region=OUTSIDE_MM, unit="mm")


def test_maps_of_a_result_draw_its_own_unit(result_file):
    _, res = result_file
    for fig, want in ((plot_states(res, "exx", states=[0]), "mm"),
                      (plot_states(res, "exx", states=[0], px=True), "px")):
        ax = fig.axes[0]
        assert (ax.get_xlabel(), ax.get_ylabel()) == (f"x ({want})", f"y ({want})")
    ax = plot_states(res, "exx", states=[0]).axes[0]
    assert_allclose(ax.get_xlim(), (-0.5 * PS, (W - 0.5) * PS), rtol=1e-12)


def test_a_result_without_pixel_size_reads_px(result_file, tmp_path):
    _, res = result_file
    bare = dataclasses.replace(res, pixel_size=None, unit=None)
    assert_array_equal(gauge(bare, region=_mm_to_px(REGION_MM)).exx,
                       gauge(res, region=REGION_MM, unit="mm").exx)
    with pytest.raises(ValueError, match="needs a pixel size, and this result carries none"):
        gauge(bare, region=REGION_MM, unit="mm")
    # saved without one, it loads without one; saved with one, it loads with it
    assert load(bare.save(tmp_path / "bare.h5", lossless=True)).pixel_size is None
    back = load(bare.save(tmp_path / "mm.h5", pixel_size=0.05, unit="mm", lossless=True))
    assert (back.pixel_size, back.unit) == (0.05, "mm")
    # and a result carrying one writes it as the file's attribute, read back
    with h5py.File(res.save(tmp_path / "own.h5", lossless=True)) as h5:
        assert (float(h5.attrs["pixel_size"]), h5.attrs["unit"]) == (PS, "mm")


def test_an_older_file_without_the_fields_loads(result_file, tmp_path):
    """A file written before results carried their pixel size: no such members in its
    result group, the pixel size in the root attributes only."""
    path, _ = result_file
    old = tmp_path / "old.h5"
    old.write_bytes(Path(path).read_bytes())
    with h5py.File(old, "r+") as h5:
        removed = 0
        def drop(name, obj):
            nonlocal removed
            for key in ("pixel_size", "unit"):
                if key in obj.attrs and name.endswith("result"):
                    del obj.attrs[key]
                    removed += 1
        h5.visititems(drop)
        group = h5["gridstrain"]["result"]
        for key in ("pixel_size", "unit"):
            if key in group:
                del group[key]
                removed += 1
        assert removed, "the result group stores the fields somewhere"
    back = load(old)
    assert (back.pixel_size, back.unit) == (PS, "mm")


def test_no_valid_pixel_message_names_the_valid_extent(result_file):
    _, res = result_file
    valid = np.zeros((H, W), dtype=bool)
    for i in range(res.n_states):
        valid |= np.asarray(res.valid[i])
    rows, cols = np.nonzero(valid.any(axis=1))[0], np.nonzero(valid.any(axis=0))[0]
    with pytest.raises(ValueError, match="holds no valid pixel") as info:
        gauge(res, region=INVALID_MM, pixel_size=PS, unit="mm")
    want = (f"its valid pixels lie in x {cols[0] * PS:g} to {cols[-1] * PS:g}, "
            f"y {rows[0] * PS:g} to {rows[-1] * PS:g} mm")
    assert want in str(info.value)


def test_extensometer_mm_and_px(result_file):
    _, res = result_file
    ends = (2.0, 4.0, 8.0, 4.0)  # mm: 150 px apart along x
    mm = gauge(res, extensometer=ends, pixel_size=PS, unit="mm")
    px = gauge(res, extensometer=_mm_to_px(ends), px=True)
    assert_array_equal(mm.extensometer, px.extensometer)
    # its length in the unit its ends were named in, and in px
    assert mm.extensometer_where.endswith("L = 6 mm (150.0 px)")
    assert px.extensometer_where.endswith("L = 150.0 px")
    # the engineering strain between two points of a homogeneous field is exx; the
    # displacement noise of two points 150 px apart gives ~1e-5 (5 std)
    assert_allclose(mm.extensometer, STRAINS, rtol=0,
                    atol=5 * float(np.max(mm.extensometer_std)))
    with pytest.raises(ValueError, match=r"extensometer .* lies outside: the measured field spans"):
        gauge(res, extensometer=(2.0, 4.0, 11.0, 4.0), pixel_size=PS, unit="mm")


def test_history_of_an_mm_gauge_is_the_px_one(result_file):
    _, res = result_file
    mm = history(gauge(res, region=REGION_MM, pixel_size=PS, unit="mm"), window=3,
                 pixel_size=PS, unit="mm")
    px = history(gauge(res, region=_mm_to_px(REGION_MM), px=True), window=3, pixel_size=PS,
                 unit="mm")
    assert_array_equal(mm.exx_rate, px.exx_rate)
    # the strain rate of a ramp of 0.3e-3 every 0.5 s: 0.6e-3 /s, within the noise
    assert_allclose(mm.exx_rate, (STRAINS[1] - STRAINS[0]) / DT, rtol=0,
                    atol=5 * float(np.max(mm.exx_rate_std)))


def test_history_of_a_result_by_the_rule_of_places(result_file):
    _, res = result_file
    # places and velocities on the result itself, in its unit: the gauge's history
    h = history(res, region=REGION_MM, unit="mm", window=5, finite=True)
    g = history(gauge(res, region=REGION_MM, unit="mm", finite=True), window=5,
                unit="mm", finite=True)
    assert_array_equal(h.vx, g.vx)
    assert_array_equal(h.gl_xx, g.gl_xx)
    assert h.unit == "mm"
    # the same pixels read in px: velocities PS times smaller (to rounding)
    assert_allclose(history(res, region=_mm_to_px(REGION_MM), px=True, window=5).vx,
                    h.vx / PS, rtol=1e-12)
    # the imposed stretch's Green-Lagrange strain e + e^2 / 2 (exact for the uniaxial
    # Lagrangian stretch of the generator), within 5 std of the smoothed reading
    e = np.array(STRAINS)
    assert np.all(np.abs(h.gl_xx - (e + e**2 / 2)) < 5 * h.gl_xx_std)
    assert np.all(np.abs(h.gl_yy - (-NU * e + (NU * e) ** 2 / 2)) < 5 * h.gl_yy_std)
    # a velocity without its unit on a result with a pixel size: refused
    with pytest.raises(ValueError, match=r"do not say their unit.*unit='mm'"):
        history(res, window=5)
    with pytest.raises(ValueError, match=r"does not say its unit"):
        history(res, region=REGION_MM, window=5)


def test_cli_history_finite(result_file, tmp_path, capsys):
    path, res = result_file
    code, out, err = _run(["history", path, "--region", *REGION_MM, "--window", 5,
                           "--finite", "--strain-units", "%", "-o", tmp_path / "h.csv"],
                          capsys)
    assert code == 0, err
    lines = out.splitlines()
    assert "gl_xx [%]" in lines[1], lines[1]
    assert "vx [mm/s]" in lines[1], lines[1]
    want = history(res, region=REGION_MM, unit="mm", window=5, finite=True)
    rows = _csv_rows(tmp_path / "h.csv")
    # the CSV's 10 digits
    assert_allclose([float(r["gl_xx [-]"]) for r in rows], want.gl_xx, rtol=1e-9)
    assert_allclose([float(r["log_yy_rate [1/s]"]) for r in rows], want.log_yy_rate,
                    rtol=1e-9)
    # the table in percent: the first state's gl_xx to 1e-5 %
    assert f"{want.gl_xx[0] * 100:.5f}" in lines[2]


def _curves(fig):
    return [np.asarray(line.get_ydata()) for line in fig.axes[0].lines
            if len(line.get_ydata()) == len(STRAINS)]


def test_plot_history_mm_and_px(result_file):
    _, res = result_file
    mm = plot_history(res, region=REGION_MM, pixel_size=PS, unit="mm")
    px = plot_history(res, region=_mm_to_px(REGION_MM), px=True)
    for a, b in zip(_curves(mm), _curves(px), strict=True):
        assert_array_equal(a, b)
    # exx in µε, the oracle's mean of the same pixels
    assert_allclose(_curves(mm)[0], _region_oracle(res, REGION_MM) * 1e6, atol=1e-6)
    assert "mm" in mm.axes[0].get_title()
    # displacements in the place's unit: the px curve times PS
    ux_mm = plot_history(res, point=(5.0, 4.0), names=("ux", "ux_std"), pixel_size=PS,
                         unit="mm")
    ux_px = plot_history(res, point=(125, 100), names=("ux", "ux_std"), px=True)
    for a, b in zip(_curves(ux_mm), _curves(ux_px), strict=True):
        assert_allclose(a, b * PS, rtol=1e-12)
    assert ux_mm.axes[0].get_ylabel() == "displacement (mm)"
    # the axis says what it draws, in the unit drawn
    assert mm.axes[0].get_ylabel() == "strain (µε)"
    pct = plot_history(res, region=REGION_MM, unit="mm", names=("gl_xx",), microstrain="%")
    assert pct.axes[0].get_ylabel() == "strain (%)"
    # a strain and a displacement on one axis would be read against one label: refused
    with pytest.raises(ValueError, match=r"share one unit.*exx \(µε\), ux \(mm\)"):
        plot_history(res, region=REGION_MM, unit="mm", names=("exx", "ux"))
    assert_allclose(_curves(ux_mm)[0], np.asarray(res.ux[:, 100, 125]) * PS, rtol=1e-12)
    # a quantity outside the gauge (the rotation) on the same pixels
    rot_mm = plot_history(res, point=(5.0, 4.0), names=("rotation",), pixel_size=PS,
                          unit="mm")
    assert_allclose(_curves(rot_mm)[0], np.asarray(
        [res.measurements[i].rotation[100, 125] for i in range(len(STRAINS))]) * 1e3, atol=1e-9)
    # never an empty figure: a place outside, or without valid pixel, is refused
    for place in ({"region": OUTSIDE_MM}, {"region": INVALID_MM}):
        with pytest.raises(ValueError, match=EXTENT_MM):
            plot_history(res, pixel_size=PS, unit="mm", **place)
    with pytest.raises(ValueError, match=EXTENT_MM):
        plot_history(res, names=("rotation",), pixel_size=PS, unit="mm",
                     region=INVALID_MM)


def test_map_axes_in_the_unit(result_file):
    _, res = result_file
    fig = plot_states(res, "exx", pixel_size=PS, unit="mm", states=[0])
    ax = fig.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (mm)", "y (mm)")
    # the pixels' edges, in mm: the first centred on 0, the last on (W - 1) PS
    assert_allclose(ax.get_xlim(), (-0.5 * PS, (W - 0.5) * PS), rtol=1e-12)
    assert_allclose(sorted(ax.get_ylim()), (-0.5 * PS, (H - 0.5) * PS), rtol=1e-12)
    fig = plot_states(res, "exx", states=[0], px=True)
    assert fig.axes[0].get_xlabel() == "x (px)"
    assert_allclose(fig.axes[0].get_xlim(), (-0.5, W - 0.5))


@pytest.mark.parametrize(("region", "what"), [(OUTSIDE_MM, "lies outside"),
                                              (INVALID_MM, "holds no valid pixel")])
def test_identify_region_by_the_same_rule(result_file, capsys, region, what):
    from gridstrain.identify import identify

    path, res = result_file
    with pytest.raises(ValueError, match=EXTENT_MM):
        identify(res, thickness=2.0, loaded_edge="right", load_direction="x",
                 pixel_size=PS, unit="mm", region=region)
    code, _, err = _run(["identify", path, "--thickness", 2, "--loaded-edge", "right",
                         "--load-direction", "x", "--region", *region], capsys)
    assert code != 0
    assert len(err.strip().splitlines()) == 1, err
    assert what in err
    assert EXTENT_MM in err


# ----------------------------------------------------------------------------- CLI


def _csv_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("command", ["gauge", "history"])
def test_cli_mm_and_px_give_the_same_numbers(result_file, tmp_path, capsys, command):
    path, res = result_file
    extra = ["--window", "3"] if command == "history" else []
    code, _, err = _run([command, path, "--region", *REGION_MM, *extra,
                         "-o", tmp_path / "mm.csv"], capsys)
    assert code == 0, err
    code, _, err = _run([command, path, "--px", "--region", *_mm_to_px(REGION_MM), *extra,
                         "-o", tmp_path / "px.csv"], capsys)
    assert code == 0, err
    mm, px = _csv_rows(tmp_path / "mm.csv"), _csv_rows(tmp_path / "px.csv")
    assert len(mm) == len(px) == len(STRAINS)
    for a, b in zip(mm, px, strict=True):
        # --px puts every length in px: a velocity in mm/s is PS times the px/s one
        for key, value in a.items():
            if "mm" in key:
                assert_allclose(float(value), float(b[key.replace("mm", "px")]) * PS,
                                rtol=1e-9)  # the CSV's 10 digits
            else:
                assert value == b[key], key
    if command == "gauge":  # the oracle's mean, to the CSV's 10 digits
        assert_allclose([float(r["exx [-]"]) for r in mm], _region_oracle(res, REGION_MM),
                        rtol=1e-9)


def test_cli_modulus_mm_and_px(result_file, capsys):
    path, _ = result_file
    runs = []
    for args in (["--region", *REGION_MM], ["--px", "--region", *_mm_to_px(REGION_MM)]):
        code, out, err = _run(["modulus", path, *args, "--area", AREA, "--json"], capsys)
        assert code == 0, err
        runs.append(json.loads(out))
    assert runs[0]["E"] == runs[1]["E"]
    assert runs[0]["nu"] == runs[1]["nu"]
    # the law of the generator: E and nu within their 95 % intervals
    assert runs[0]["E_ci"][0] <= E_MPA <= runs[0]["E_ci"][1]


@pytest.mark.parametrize("command", ["gauge", "modulus", "history", "plot"])
@pytest.mark.parametrize(("region", "what"), [(OUTSIDE_MM, "lies outside"),
                                              (INVALID_MM, "holds no valid pixel")])
def test_cli_refuses_a_region_in_one_line(result_file, tmp_path, capsys, command, region,
                                          what):
    path, _ = result_file
    extra = {"modulus": ["--area", AREA], "history": ["--window", "3"],
             "plot": ["-o", tmp_path / "figs", "--maps", "exx"]}.get(command, [])
    code, _, err = _run([command, path, "--region", *region, *extra], capsys)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert what in lines[0]
    assert EXTENT_MM in lines[0]
    assert "Traceback" not in err
    assert not (tmp_path / "figs").exists()  # nothing drawn, no empty figure


def test_cli_plot_region_in_mm_and_axes(result_file, tmp_path, capsys, monkeypatch):
    path, _ = result_file
    from matplotlib.axes import Axes

    labels = []
    original = Axes.set_xlabel

    def record(self, text, *a, **k):
        labels.append(text)
        return original(self, text, *a, **k)

    monkeypatch.setattr(Axes, "set_xlabel", record)
    code, _, err = _run(["plot", path, "-o", tmp_path / "figs", "--maps", "exx",
                           "--region", *REGION_MM], capsys)
    assert code == 0, err
    assert (tmp_path / "figs" / "history.png").is_file()
    assert "x (mm)" in labels
    assert "x (px)" not in labels
    labels.clear()
    code, _, err = _run(["animate", path, "exx", "-o", tmp_path / "exx.gif"], capsys)
    assert code == 0, err
    assert labels == ["x (mm)"]
    labels.clear()
    code, _, err = _run(["plot", path, "-o", tmp_path / "figs_px", "--maps", "exx",
                           "--px", "--region", *_mm_to_px(REGION_MM)], capsys)
    assert code == 0, err
    assert "x (px)" in labels
    assert "x (mm)" not in labels


def test_cli_plot_reads_a_machine_log_as_gauge_does(result_file, tmp_path, capsys):
    """``plot --loads`` joins a log sampled faster than the camera to the states' times
    (it was read as one row per state: "17 rows for 7 states")."""
    path, _ = result_file
    log = tmp_path / "machine.csv"
    t = np.arange(17) * 0.25  # 0 to 4 s, twice the camera's rate
    with open(log, "w", newline="") as fh:
        w = csv.writer(fh, delimiter=";")
        w.writerow(["Zeit [s]", "Kraft [kN]"])
        for ti in t:
            w.writerow([f"{ti:.2f}".replace(".", ","),
                        f"{1.4 * ti:.4f}".replace(".", ",")])
    code, _, err = _run(["plot", path, "-o", tmp_path / "figs", "--maps", "exx",
                           "--loads", log], capsys)
    assert code == 0, err
    # the same options as gauge: an offset that puts a state past the log's end is
    # refused, naming it
    code, _, err = _run(["plot", path, "-o", tmp_path / "figs2", "--maps", "exx",
                           "--loads", log, "--loads-offset", "1.0"], capsys)
    assert code != 0
    assert len(err.strip().splitlines()) == 1, err
    assert "outside the log's time" in err


# ----------------------------------------------------------------------------- README


def _readme_command(name: str) -> list[str]:
    readme = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    lines = [ln for ln in readme.splitlines() if ln.startswith(f"gridstrain {name} ")]
    assert len(lines) == 1, lines
    return lines[0].split()[1:]


def test_readme_modulus_example_runs(result_file, tmp_path, capsys, monkeypatch):
    """The README's ``modulus`` command, as written, on a result of its ``measure``
    command's shape (a 0.2 mm grid, 5 px per pitch: 0.04 mm per px)."""
    path, _ = result_file
    measure = _readme_command("measure ref/ steps/")
    assert "--grid-pitch" in measure
    assert "--unit" in measure
    argv = _readme_command("modulus")
    monkeypatch.chdir(tmp_path)
    Path(argv[1]).write_bytes(Path(path).read_bytes())  # the file the README names
    code, out, err = _run(argv, capsys)
    assert code == 0, err
    e = re.search(r"E\s+=\s+([\d.]+) GPa", out)
    assert e is not None, out
    # the generator's 70 GPa, to the noise (the interval is ~0.2 %): 1 %
    assert abs(float(e.group(1)) - E_MPA / 1e3) < 0.01 * E_MPA / 1e3


def test_gauges_page_commands_run(result_file, tmp_path, capsys, monkeypatch):
    """The gauge, modulus and history commands at the top of the gauges page, as
    written (a region and an extensometer in mm), on the generated result."""
    path, _ = result_file
    page = Path(__file__).parents[1] / "docs" / "user_guide" / "gauges.rst"
    lines = [ln.split()[1:] for ln in page.read_text(encoding="utf-8").splitlines()
             if re.match(r"\s+gridstrain (gauge|modulus|history) ", ln)]
    assert [a[0] for a in lines] == ["gauge", "modulus", "history"]
    monkeypatch.chdir(tmp_path)
    Path("maps.h5").write_bytes(Path(path).read_bytes())
    Path("loads.csv").write_bytes((Path(path).parent / "loads.csv").read_bytes())
    for argv in lines:
        code, _, err = _run(argv, capsys)
        assert code == 0, (argv, err)
    rows = _csv_rows("gauge.csv")
    # the extensometer between x = 1 and 9 mm reads the imposed strain; its std from
    # the displacement noise at two points 200 px apart is ~1e-5 (5 std)
    ext = np.array([float(r["extensometer [-]"]) for r in rows])
    std = np.array([float(r["extensometer_std [-]"]) for r in rows])
    assert_allclose(ext, STRAINS, rtol=0, atol=5 * float(std.max()))


# ----------------------------------------------------------------------------- saving


def test_a_replaced_result_is_saved_with_its_own_maps(result_file, tmp_path):
    """``dataclasses.replace(result, u=..., valid=...)`` then saved: the file holds the
    new maps (it held the measurements' again, silently)."""
    _, res = result_file
    u = np.asarray(res.u) + 1.0  # px: a rigid shift by one pixel
    valid = np.asarray(res.valid).copy()
    valid[:, :, : W // 2] = False
    strain = np.asarray(res.strain) * 2.0
    moved = dataclasses.replace(res, u=u, strain=strain, valid=valid)
    back = load(moved.save(tmp_path / "moved.h5", pixel_size=PS, unit="mm", lossless=True))
    assert_array_equal(back.u, u)
    assert_array_equal(back.strain, strain)
    assert_array_equal(back.valid, valid)
    # the measurements come back with the maps the file holds
    assert_array_equal(back.measurements[2].u, u[2])
    with h5py.File(tmp_path / "moved.h5", "r") as h5:
        phys = np.asarray(h5["ux_phys"])
    assert_allclose(phys, u[:, 0] * PS, equal_nan=True)
    # one state too many: refused, not saved with the measurements' maps
    with pytest.raises(ValueError, match=r"result\.u must be a"):
        dataclasses.replace(res, u=np.concatenate([u, u[:1]])).save(tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_noise_floor_table_keeps_its_columns_under_long_state_names(result_file):
    from gridstrain.cli._summary import report_lines

    _, res = result_file
    # a camera's file names, longer than the 9 characters the column once had
    named = dataclasses.replace(res, names=("reference", *(f"frame{k:06d}" for k in
                                                           range(1, len(STRAINS) + 1))))
    lines = report_lines(named)
    start = next(i for i, line in enumerate(lines) if line.startswith("noise floor"))
    head = lines[start]
    rows = [line for line in lines[start + 1:start + 9] if re.search(r"\de-\d\d", line)]
    assert len(rows) >= 4
    # every row's first number starts at the same column, one after "u_x px" begins
    cols = {re.search(r"\d\.\d\de-\d\d", line).start() for line in rows}
    assert cols == {head.index("u_x px") + 1}, (head, rows)
