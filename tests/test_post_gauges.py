"""Virtual gauges and extensometers (gridstrain.post.gauge, ``gridstrain gauge``).

Images from the numpy-only generator of ``tests/independent_grid.py``: a pitch-5
checkerboard, 12-bit Poisson-Gaussian sensor stored x16, homogeneous strain.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from gridstrain import measure_series
from gridstrain.cli import main
from gridstrain.post import gauge, read_loads
from gridstrain.post._correlation import std_of_mean, strain_kernel
from independent_grid import camera, scene

H, W = 128, 160
K, L = 0.28, 5.0
# the camera's noise in the stored grey levels (12-bit values stored x16)
NOISE = (16 * K, 256 * L)
EXX, EYY = 1e-3, -0.33e-3


def _strained(exx, eyy, angle=0.0):
    return scene((H, W), pitch=5.0, angle=angle, hole=False, light=False,
                 displacement=lambda X, Y: (exx * X, eyy * Y))[0]


def _measure(levels, rng):
    images = [camera(lv, K, L, rng).astype(np.float64) for lv in levels]
    return measure_series(images[0], images[1:], guess=None, noise_model=NOISE)


def test_gauge_std_matches_repeated_noise_draws():
    """The std of a gauge's mean against its scatter over 40 noise draws.

    Four disjoint gauges (a large rectangle, a small square, a thin strip, one
    pixel) and the three strain components: the pooled ratio predicted / empirical
    must lie in [0.85, 1.15]. Measured: 1.03 (200 draws: 0.90 to 1.06 per gauge and
    component). The empirical std of 40 draws scatters by 11 % for one gauge and
    component; pooled over 12 nearly independent ones, by about 4 %.
    Two states of the same strain: their difference holds each state's own noise
    only (the reference's share cancels), checked the same way.
    """
    ref0, cur0 = _strained(0.0, 0.0, 20.0), _strained(EXX, EYY, 20.0)
    rng = np.random.default_rng(3)
    regions = [(40, 40, 120, 70), (60, 80, 70, 90), (20, 30, 23, 100), (100, 95, 101, 96)]
    means, preds, diffs, diff_preds, ext = [], [], [], [], []
    for _ in range(40):
        res = _measure([ref0, cur0, cur0], rng)
        row = [gauge(res, region=reg) for reg in regions]
        e = gauge(res, point=(50, 50), extensometer=(25, 60, 135, 60))
        ext.append((e.extensometer[0], e.extensometer_std[0]))
        means.append([[g.exx[0], g.eyy[0], g.exy[0]] for g in row])
        preds.append([[g.exx_std[0], g.eyy_std[0], g.exy_std[0]] for g in row])
        diffs.append([[g.exx[1] - g.exx[0], g.eyy[1] - g.eyy[0], g.exy[1] - g.exy[0]]
                      for g in row])
        diff_preds.append([[np.sum(getattr(g, f"{c}_std") ** 2 * (1 - g.reference_share))
                            for c in ("exx", "eyy", "exy")] for g in row])
    means, preds = np.array(means), np.array(preds)
    pred_var = np.mean(preds**2, axis=0)
    ratio = float(np.sqrt(np.mean(pred_var / means.var(axis=0, ddof=1))))
    assert 0.85 <= ratio <= 1.15, ratio
    # each gauge and component on its own, within the 40 draws' sampling (3 x 11 %)
    each = np.sqrt(pred_var / means.var(axis=0, ddof=1))
    assert np.all((each > 0.6) & (each < 1.4)), each
    # the correlation matters: the large gauge's std is several times what N
    # independent pixels would give (its derivative noise cancels across the region)
    assert np.all(preds[:, 0, 0] < preds[:, 3, 0] / 5)
    # the difference of two states: measured 0.97 (one image per state like the
    # reference: a share of 0.50)
    ratio = float(np.sqrt(np.mean(np.mean(diff_preds, axis=0)
                                  / np.var(diffs, axis=0, ddof=1))))
    assert 0.85 <= ratio <= 1.15, ratio
    # the extensometer (110 px): measured 1.02; one quantity over 40 draws scatters
    # by 11 %, hence 3 times that
    ext = np.array(ext)
    ratio = float(np.mean(ext[:, 1]) / np.std(ext[:, 0], ddof=1))
    assert 0.67 <= ratio <= 1.33, ratio


@pytest.mark.parametrize(("shape", "boxes"), [
    ((24, 30), ((slice(3, 20), slice(5, 17)), (slice(10, 12), slice(20, 28)))),
    ((40, 50), ((slice(10, 11), slice(0, 50)),)),  # one row: lags along x only
    ((6, 7), ((slice(0, 6), slice(0, 7)),)),  # a region smaller than the kernel
])
def test_std_of_mean_is_the_double_sum(shape, boxes):
    # the spectral double sum against a direct sum over every pair of pixels
    from gridstrain import Lattice

    rng = np.random.default_rng(0)
    s = rng.uniform(1.0, 2.0, shape)
    inside = np.zeros(s.shape, dtype=bool)
    for box in boxes:
        inside[box] = True
    inside &= rng.random(shape) > 0.1  # holes: invalid pixels inside the region
    kern = strain_kernel(Lattice.from_pitch(5.0, angle=30.0), 3.0, "exy")
    r = kern.shape[0] // 2
    ys, xs = np.nonzero(inside)
    total = 0.0
    for y1, x1 in zip(ys, xs, strict=True):
        for y2, x2 in zip(ys, xs, strict=True):
            dy, dx = y2 - y1, x2 - x1
            if abs(dy) <= r and abs(dx) <= r:
                total += s[y1, x1] * s[y2, x2] * kern[r + dy, r + dx]
    want = math.sqrt(total) / ys.size
    assert math.isclose(std_of_mean(s, inside, kern), want, rel_tol=1e-10)


def test_strain_kernel_integrates_to_zero_and_is_one_at_zero():
    # a derivative kernel has no mean: its noise's autocorrelation sums to 0
    from gridstrain import Lattice

    for comp in ("exx", "eyy", "exy"):
        k = strain_kernel(Lattice.from_pitch(5.0, angle=15.0), 4.0, comp)
        c = k.shape[0] // 2
        assert k[c, c] == pytest.approx(1.0)
        assert abs(k.sum()) < 1e-4 * (4 * math.pi * 16)  # 1e-4 of the Gaussian's sum


@pytest.fixture(scope="module")
def series_file(tmp_path_factory):
    """Three loaded states of homogeneous strain, saved with a pixel size of 0.05 mm."""
    d = tmp_path_factory.mktemp("gauge")
    rng = np.random.default_rng(11)
    steps = (1.0, 2.0, 3.0)
    levels = [_strained(0.0, 0.0)] + [_strained(s * EXX, s * EYY) for s in steps]
    res = _measure(levels, rng)
    path = d / "maps.h5"
    res.save(path, pixel_size=0.05, unit="mm")
    return res, path, steps


def test_gauge_rows_hold_the_truth_and_the_extensometer_reads_the_stretch(series_file):
    res, _, steps = series_file
    g = gauge(res, region=(30, 30, 130, 100), extensometer=(30, 64, 130, 64))
    for i, s in enumerate(steps):
        # 4 stated std: the mean, unbiased, within the noise it states
        assert abs(g.exx[i] - s * EXX) < 4 * g.exx_std[i]
        assert abs(g.eyy[i] - s * EYY) < 4 * g.eyy_std[i]
        assert abs(g.exy[i]) < 4 * g.exy_std[i]
        # the extensometer along x reads exx (small strain: (l - L) / L = exx)
        assert abs(g.extensometer[i] - s * EXX) < 4 * g.extensometer_std[i]
    assert g.states == tuple(res.names[1:])
    assert g.n_pixels.min() > 0
    xr = pytest.importorskip("xarray")
    ds = g.to_xarray()
    assert isinstance(ds, xr.Dataset)
    np.testing.assert_array_equal(ds["exx_std"].values, g.exx_std)
    assert list(ds["state"].values) == list(g.states)
    assert ds["extensometer"].attrs["units"] == "1"


def test_physical_coordinates_select_the_same_pixels(series_file):
    res, _, _ = series_file
    a = gauge(res, region=(30, 30, 130, 100))
    b = gauge(res, region=(1.5, 1.5, 6.5, 5.0), pixel_size=0.05, unit="mm")
    np.testing.assert_array_equal(a.exx, b.exx)
    p = gauge(res, point=(2.0, 2.5), pixel_size=0.05, unit="mm")
    assert p.exx[0] == res.exx[0][50, 40]
    poly = gauge(res, polygon=[(30, 30), (130, 30), (130, 100), (30, 100)])
    assert poly.n_pixels[0] > 0
    with pytest.raises(ValueError, match="region"):
        gauge(res, region=(200, 0, 300, 10))
    with pytest.raises(ValueError, match="one of region, point or polygon"):
        gauge(res, region=(0, 0, 10, 10), point=(3, 3))


def test_loads_file_is_read_strictly(tmp_path):
    names = ("ref", "s1", "s2")
    p = tmp_path / "loads.csv"
    p.write_text("state,load [kN],time [s]\nref,0,0\ns2,2.5,2\ns1,1.5,1\n")
    load, unit, time = read_loads(p, names)
    assert unit == "kN"
    np.testing.assert_array_equal(load, [1.5, 2.5])
    np.testing.assert_array_equal(time, [1.0, 2.0])
    p.write_text("load [N]\n1\n2\n")
    assert read_loads(p, names)[0].tolist() == [1.0, 2.0]
    for bad, match in (("load [N]\n1\n", "1 row.* for 2 state"),
                       ("state,load [N]\ns1,1\ns3,2\n", "'s3' is not one of"),
                       ("extension [mm]\n1\n2\n", "no load column"),
                       ("load [N],time [weeks]\n1,1\n2,2\n", "not a time unit"),
                       ("load [N]\n1\nx\n", "row 3")):
        p.write_text(bad)
        with pytest.raises(ValueError, match=match):
            read_loads(p, names)


def test_gauge_principal_strains_hold_the_truth(series_file):
    """A homogeneous strain along the axes: e1 = exx, e2 = eyy, angle 0, and the
    equivalent strain of the closed form (2/sqrt 3) sqrt(exx^2 + exx eyy + eyy^2)."""
    res, _, steps = series_file
    g = gauge(res, region=(30, 30, 130, 100))
    p = g.principal_strains()
    for i, s in enumerate(steps):
        exx, eyy = s * EXX, s * EYY
        # 4 stated std, as for the components: e1 and e2 are exx and eyy to first
        # order here (R = 0.67e-3 s, 100 times their std)
        assert abs(p.e1[i] - exx) < 4 * p.e1_std[i]
        assert abs(p.e2[i] - eyy) < 4 * p.e2_std[i]
        assert abs(p.principal_angle[i]) < 4 * p.principal_angle_std[i]
        eq = 2 / math.sqrt(3) * math.sqrt(exx**2 + exx * eyy + eyy**2)
        assert abs(p.equivalent[i] - eq) < 4 * p.equivalent_std[i]
        assert abs(p.max_shear[i] - (exx - eyy) / 2) < 4 * p.max_shear_std[i]
    # with the components' std of the axes: exy's std moves the angle, exx's e1
    assert_allclose(p.e1_std, g.exx_std, rtol=1e-3)  # exy / R ~ 1e-2: 1e-4 change
    cols = g.columns(derived=True)
    assert list(cols)[7:11] == ["e1 [-]", "e1_std [-]", "e2 [-]", "e2_std [-]"]
    assert "principal_angle [rad]" in cols
    # the table in percent and with the angle in degrees
    text = g.table(strain_units="%", derived=True)
    assert "exx [%]" in text
    assert "principal_angle [deg]" in text
    assert f"{g.exx[2] * 100:.5f}" in text


def test_gauge_command_writes_the_csv(series_file, tmp_path, capsys):
    res, path, steps = series_file
    loads = tmp_path / "loads.csv"
    loads.write_text("load [N],time [s]\n" + "".join(f"{100 * s},{s}\n" for s in steps))
    out = tmp_path / "g.csv"
    rc = main(["gauge", str(path), "--region", "1.5", "1.5", "6.5", "5", "--loads",
               str(loads), "--extensometer", "1.5", "3.2", "6.5", "3.2", "-o", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "exx [µε]" in text
    assert "mm" in text
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["state", "load [N]", "time [s]", "exx [-]", "exx_std [-]",
                             "eyy [-]", "eyy_std [-]", "exy [-]", "exy_std [-]",
                             "extensometer [-]", "extensometer_std [-]"]
    assert [r["state"] for r in rows] == list(res.names[1:])
    assert float(rows[2]["load [N]"]) == 300.0
    assert abs(float(rows[2]["exx [-]"]) - 3 * EXX) < 4 * float(rows[2]["exx_std [-]"])
    # --derived: the principal strains in the table and the CSV; --strain-units %
    rc = main(["gauge", str(path), "--region", "1.5", "1.5", "6.5", "5", "--derived",
               "--strain-units", "%", "-o", str(tmp_path / "d.csv")])
    assert rc == 0
    assert "e1 [%]" in capsys.readouterr().out
    with open(tmp_path / "d.csv", newline="") as fh:
        head = next(csv.reader(fh))
    assert head[7:11] == ["e1 [-]", "e1_std [-]", "e2 [-]", "e2_std [-]"]
    # an existing file is refused without --overwrite: one line, exit 2
    assert main(["gauge", str(path), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err


# ------------------------------------------------------------------ finite strains

STRETCH, SHEAR = 0.02, 0.02  # large enough that E - eps = e^2 / 2 = 2e-4 is 30 std


@pytest.fixture(scope="module")
def finite_result():
    """A uniaxial stretch ``x = (1 + e) X`` and a simple shear ``x = X + g Y`` of the
    paper's grid model (eq. 1, pitch 5, 128 x 128 px, white noise of 5 grey levels),
    measured with the Lagrangian correction (the default)."""
    rng = np.random.default_rng(11)

    def img(mapping):
        y, x = np.mgrid[0:128, 0:128].astype(np.float64) - 64.0
        X, Y = mapping(x, y)
        return 2000.0 * (1 + 0.4 * np.cos(2 * np.pi * X / 5.0)
                         + 0.4 * np.cos(2 * np.pi * Y / 5.0)) + rng.normal(0, 5.0, x.shape)

    return measure_series(img(lambda x, y: (x, y)),
                          [img(lambda x, y: (x / (1 + STRETCH), y)),
                           img(lambda x, y: (x - SHEAR * y, y))],
                          guess=None, noise_model=(1e-6, 25.0))


def test_gauge_finite_strains_of_a_stretch_and_a_shear(finite_result):
    r = gauge(finite_result, region=(32, 32, 96, 96), finite=True)
    f = r.finite_strains()
    e, g = STRETCH, SHEAR
    # the exact finite strains: stretch E = e + e^2 / 2, L = ln(1 + e); simple shear
    # E_yy = g^2 / 2, E_xy = g / 2, L's principal values +-asinh(g / 2)
    want = {"Exx": (e + e * e / 2, 0.0), "Eyy": (0.0, g * g / 2), "Exy": (0.0, g / 2),
            "Lxx": (np.log1p(e), None), "Lyy": (0.0, None)}
    for name, values in want.items():
        got, std = getattr(f, name), getattr(f, f"{name}_std")
        assert np.all(std > 0), name
        assert np.all(std < 2e-5), name  # the gauge's ~6e-6
        for k, v in enumerate(values):
            if v is not None:
                # 5 std of the gauge's reading: the noise (the window's bias on a
                # homogeneous field is below it); E - eps is 2e-4, 30 std
                assert got[k] == pytest.approx(v, abs=5 * std[k]), (name, k)
    rad = np.hypot((f.Lxx[1] - f.Lyy[1]) / 2, f.Lxy[1])
    assert rad == pytest.approx(np.arcsinh(g / 2), abs=5 * float(f.Lxy_std[1]))
    # the simple shear's rotation, -g / 2, read with the std of its mean
    assert r.rotation[1] == pytest.approx(-g / 2, abs=5 * r.rotation_std[1])
    # the columns and the table carry them
    cols = r.columns(finite=True)
    assert list(cols)[-12:] == [f"{n}{s} [-]" for n in ("gl_xx", "gl_yy", "gl_xy",
                                                         "log_xx", "log_yy", "log_xy")
                                for s in ("", "_std")]
    assert "gl_xx [µε]" in r.table(finite=True)


def test_finite_strain_maps_std_against_their_scatter(finite_result):
    """The first-order std maps of the finite strains (from the uncertainty maps'
    gradient noise) against the scatter of the maps of the homogeneous stretch."""
    maps = finite_result.derived_maps(0)
    valid = np.asarray(finite_result.valid[0])
    for name in ("gl_xx", "gl_yy", "log_xx", "log_yy"):
        predicted = np.sqrt(np.mean(maps[f"{name}_std"][valid] ** 2))
        seen = np.std(maps[name][valid])
        # ~100 independent window patches over the field: 7 % on a std, 3 x 7 %
        assert 0.8 < predicted / seen < 1.25, (name, predicted / seen)
    # the rotation's std map is exy's under the uncertainty maps' noise model
    assert_allclose(maps["rotation_std"][valid],
                    np.asarray(finite_result.uncertainty["exy_std"][0])[valid], rtol=1e-12)


def test_an_eulerian_result_offers_no_finite_strains(finite_result):
    import dataclasses

    euler = dataclasses.replace(finite_result, lagrangian=False)
    with pytest.raises(ValueError, match="lagrangian=False"):
        euler.finite_strains(0)
    with pytest.raises(ValueError, match="lagrangian=False"):
        gauge(euler, finite=True)
    with pytest.raises(ValueError, match="lagrangian=False"):
        gauge(euler).finite_strains()
    # asked of a gauge read without its rotation: says how to read it
    with pytest.raises(ValueError, match=r"gauge\(\.\.\., finite=True\)"):
        gauge(finite_result).finite_strains()
    assert "gl_xx" not in euler.derived_maps(0)


def test_cli_gauge_finite_columns(finite_result, tmp_path, capsys):
    path = finite_result.save(tmp_path / "f.h5", lossless=True)
    out = tmp_path / "g.csv"
    assert main(["gauge", str(path), "--region", "32", "32", "96", "96", "--finite",
                 "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "gl_xx [µε]" in printed
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    f = gauge(finite_result, region=(32, 32, 96, 96), finite=True).finite_strains()
    # 10 significant digits in the CSV: 1e-10 relative
    assert_allclose([float(r["gl_xx [-]"]) for r in rows], f.Exx, rtol=1e-9)
    assert_allclose([float(r["log_xy_std [-]"]) for r in rows], f.Lxy_std, rtol=1e-9)
