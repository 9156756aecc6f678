"""Where the noise comes from (``--noise``, ``--noise-model``, one image), the
metrological figures, the systematic-error warnings and sigma as typed.

Images from the numpy-only generator of ``tests/independent_grid.py``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import tifffile

from findings import said
from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.io import read_hdf5, read_noise_model
from gridstrain.results import load
from gridstrain.series import measure_series
from independent_grid import camera as _camera
from independent_grid import scene as _scene

SHAPE = (320, 320)


def _run(argv):
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """One reference and one loaded image (uniform 1e-3 strain), 12-bit stored x16."""
    root = tmp_path_factory.mktemp("pair")
    rng = np.random.default_rng(12)
    ref, _ = _scene(SHAPE, pitch=5.3, angle=10.0, kind="sine", hole=False)
    cur, _ = _scene(SHAPE, pitch=5.3, angle=10.0, kind="sine", hole=False,
                    displacement=lambda X, Y: (1e-3 * X, 0 * Y))
    tifffile.imwrite(root / "ref.tif", _camera(ref, 0.28, 5.0, rng))
    tifffile.imwrite(root / "def.tif", _camera(cur, 0.28, 5.0, rng))
    return root


def test_noise_from_one_image_then_measure_with_it(pair, tmp_path, capsys):
    out = tmp_path / "noise.h5"
    assert _run(["noise", pair / "ref.tif", "-o", out, "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "from the first image alone" in text
    model = read_noise_model(out)
    assert model.method == "single image"
    assert model.scale == 16
    assert model.bit_depth == 12
    # K of one 320^2 image: ~2 % standard error; 15 % is the acceptance figure
    assert model.K_sensor == pytest.approx(0.28, rel=0.15)

    res = tmp_path / "maps.h5"
    assert _run(["measure", pair / "ref.tif", pair / "def.tif", "-o", res, "--noise", out,
                 "--json", "--guess", 0, 0]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["noise_model"]["source"] == "given (single image)"
    assert summary["noise_model"]["K"] == pytest.approx(model.K, rel=1e-12)
    assert summary["uncertainty_median"][0]["exx_std"] > 0
    met = summary["metrology"]
    sigma = summary["sigma_px"]
    # 10 % attenuation period, FWHM and 10-90 % step width of a Gaussian window
    assert met["spatial_resolution_px"] == pytest.approx(13.688 * sigma, rel=1e-4)
    assert met["window_fwhm_px"] == pytest.approx(2.3548200450309493 * sigma)
    assert met["step_width_px"] == pytest.approx(2.5631031310892007 * sigma)
    st = met["states"][0]
    d = met["spatial_resolution_px"]
    assert st["ux"]["efficiency"] == pytest.approx(st["ux"]["resolution"] * d)
    assert st["exx"]["efficiency"] == pytest.approx(st["exx"]["resolution"] * d**2)
    assert "aliasing" in summary["systematic_errors"]
    h5 = read_hdf5(res)
    assert "ux_std" in h5["datasets"]
    assert h5["attrs"]["noise_model_source"] == "given (single image)"
    assert h5["attrs"]["spatial_resolution_px"] == pytest.approx(d)
    assert h5["units"]["efficiency_strain"] == "px^2"
    assert h5["units"]["resolution_u"] == "px"
    np.testing.assert_allclose(h5["datasets"]["efficiency_strain"][0, 0],
                               st["exx"]["efficiency"], rtol=1e-12)
    assert "systematic_smoothing_strain" in h5["datasets"]
    assert "systematic_aliasing_u_px" in h5["attrs"]
    back = load(res)
    assert back.noise.model["K"] == pytest.approx(model.K)
    assert back.metrology == json.loads(json.dumps(back.metrology))
    assert back.systematic["aliasing"]["u_px"] == pytest.approx(
        summary["systematic_errors"]["aliasing"]["u_px"])


def test_measure_single_frames_gets_maps_and_report(pair, tmp_path, capsys):
    res = tmp_path / "maps.h5"
    assert _run(["measure", pair / "ref.tif", pair / "def.tif", "-o", res, "--guess", 0, 0,
                 "--quiet"]) == 0
    h5 = read_hdf5(res)
    assert h5["attrs"]["noise_model_source"] == "single image"
    for name in ("ux_std", "uy_std", "exx_std", "eyy_std", "exy_std"):
        assert np.isfinite(h5["datasets"][name][h5["datasets"]["valid"]]).all()
    capsys.readouterr()
    assert _run(["measure", pair / "ref.tif", pair / "def.tif", "-o", res, "--overwrite",
                 "--guess", 0, 0]) == 0
    text = capsys.readouterr().out
    assert "image noise: single image" in text
    assert "uncertainty maps, median" in text
    assert "efficiency" in text
    assert "systematic" in text


def test_noise_model_typed_in_stored_units(pair, tmp_path, capsys):
    res = tmp_path / "maps.h5"
    # the camera's K = 0.28, L = 5 in stored units: x16 and x256
    assert _run(["measure", pair / "ref.tif", pair / "def.tif", "-o", res, "--json",
                 "--noise-model", 0.28 * 16, 5 * 256, "--guess", 0, 0]) == 0
    summary = json.loads(capsys.readouterr().out)
    nm = summary["noise_model"]
    assert nm["source"] == "given (given)"
    assert nm["K"] == pytest.approx(4.48)
    assert nm["L"] == pytest.approx(1280)
    # the theory floor with the true model: e_xx std of a 1-frame pair at sigma =
    # pitch is a few 1e-4; the maps' median agrees with it to a few per cent
    th = summary["noise_floor"]["theory_strain"][0][0]
    med = summary["uncertainty_median"][0]["exx_std"]
    assert med == pytest.approx(th, rel=0.05)
    # four times the variance, twice the std: the maps follow the model given
    assert _run(["measure", pair / "ref.tif", pair / "def.tif", "-o", res, "--json",
                 "--overwrite", "--noise-model", 4 * 4.48, 4 * 1280, "--guess", 0, 0]) == 0
    four = json.loads(capsys.readouterr().out)["uncertainty_median"][0]
    for name, value in four.items():
        assert value == pytest.approx(2 * summary["uncertainty_median"][0][name], rel=1e-9)


def test_noise_options_refused(pair, tmp_path, capsys):
    res = tmp_path / "maps.h5"
    noise_json = tmp_path / "n.json"
    assert _run(["noise", pair / "ref.tif", "-o", noise_json, "--quiet"]) == 0
    other = json.loads(noise_json.read_text())
    other["noise_model"]["bit_depth"] = 8
    (tmp_path / "n8.json").write_text(json.dumps(other))
    other["noise_model"]["bit_depth"] = 12
    other["noise_model"]["scale"] = 1
    (tmp_path / "n1.json").write_text(json.dumps(other))
    (tmp_path / "junk.json").write_text(json.dumps({"K": 1}))
    capsys.readouterr()
    cases = [(["--noise-model", -1, 5], "K must be a positive"),
             (["--noise-model", 1, "nan"], "L must be a finite"),
             (["--noise", tmp_path / "junk.json"], "not a noise result"),
             (["--noise", tmp_path / "n8.json"], "8-bit"),
             (["--noise", tmp_path / "n1.json"], "stored x1"),
             (["--noise", noise_json, "--noise-model", 1, 1], "not both"),
             (["--sigma", 6, "--sigma-pitches", 1.5], "not both"),
             (["--sigma-pitches", 0.5], "--sigma-pitches must be at least")]
    for extra, match in cases:
        assert _run(["measure", pair / "ref.tif", pair / "def.tif", "-o", res, "--quiet",
                     *extra]) != 0, extra
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        assert match in err[0], (extra, err[0])
        assert not res.exists()


def test_sigma_as_typed(pair):
    ref = tifffile.imread(pair / "ref.tif").astype(np.float64)
    cur = tifffile.imread(pair / "def.tif").astype(np.float64)
    th = math.radians(10.0)
    pitch = 5.3 * (1 + 5e-7)  # a detected pitch a hair above the typed one
    k1 = (math.cos(th) / pitch, math.sin(th) / pitch)
    lat = Lattice(k1, (-k1[1], k1[0]))
    # typed as 5.3: within 1e-3 below the pitch, taken as the pitch
    res = measure_series(ref, cur, lattice=lat, sigma=5.3, guess=None)
    assert res.sigma == pytest.approx(lat.pitch, rel=1e-12)
    with pytest.raises(ValueError, match="at least the pitch"):
        measure_series(ref, cur, lattice=lat, sigma=5.3 * 0.99, guess=None)
    res = measure_series(ref, cur, lattice=lat, sigma_pitches=1.5, guess=None)
    assert res.sigma == pytest.approx(1.5 * lat.pitch, rel=1e-12)
    assert res.parameters["sigma_pitches"] == 1.5


def _lines_pair(kind, pitch, shift, **kw):
    """Reference and state translated by ``shift`` px and stretched by 1e-3 along x."""
    ref, _ = _scene((256, 256), pitch=pitch, angle=0.0, kind=kind, hole=False, light=False,
                    **kw)
    cur, _ = _scene((256, 256), pitch=pitch, angle=0.0, kind=kind, hole=False, light=False,
                    displacement=lambda X, Y: (shift + 1e-3 * X, 0 * Y), **kw)
    return ref, cur


def test_sharp_lines_at_pitch_4_warn_of_aliasing():
    """Noise-free grid of sharp lines (edges ~0.05 px) at pitch 4: the 3rd, 5th, 7th
    harmonics fold onto the carrier. The error is real and the warning says so."""
    ref, cur = _lines_pair("lines", 4.0, 0.1, edge=20.0, over=8)
    res = measure_series(ref, cur, lattice=Lattice.from_pitch(4.0), guess=None,
                         noise_model=(1e-6, 1e-6))
    v = res.valid[0]
    x = np.mgrid[0:256, 0:256][1]
    err_u = float(np.max(np.abs(res.u[0, 0][v] - 0.1 - 1e-3 * x[v])))
    err_e = float(np.max(np.abs(res.strain[0, 0][v] - 1e-3)))
    alias = res.systematic["aliasing"]
    # measured: 0.026 px and 4.7e-4 strain (a sine: below 1e-6); the estimate for
    # sharp lines (the profile cannot be seen at pitch 4) is 0.096 px and 6.8e-4:
    # a bound of the displacement error within a factor of 10, the strain error's
    # order (measured on other sizes: 0.7 to 1.4 times the estimate)
    assert err_u > 0.01
    assert err_e > 1e-4
    assert err_u < alias["u_px"] < 10 * err_u
    assert err_e / 2 < alias["strain_per_strain"] * 1e-3 < 10 * err_e
    assert alias["pattern"] == "lines"
    assert not alias["observable"]
    assert said(res.warnings, "aliasing.bound")


def test_sharp_checkerboard_estimate_uses_its_own_harmonics():
    """A sharp checkerboard at pitch 4 folds fewer and weaker harmonics onto its
    carriers than a grid of lines (amplitudes 1/|n^2 - m^2|): measured 0.013 px
    of error, estimate 0.057 px (0.096 px with the lines' model)."""
    ref, cur = _lines_pair("checker", 4.0, 0.1, over=6)
    res = measure_series(ref, cur, guess=None, noise_model=(1e-6, 1e-6))
    v = res.valid[0]
    x = np.mgrid[0:256, 0:256][1]
    err_u = float(np.max(np.abs(res.u[0, 0][v] - 0.1 - 1e-3 * x[v])))
    alias = res.systematic["aliasing"]
    assert alias["pattern"] == "checkerboard"
    assert err_u < alias["u_px"] < 10 * err_u


def test_sine_at_pitch_5_3_no_aliasing_warning():
    ref, cur = _lines_pair("sine", 5.3, 0.3)
    rng = np.random.default_rng(0)
    res = measure_series(_camera(ref, 0.28, 5.0, rng).astype(float),
                         _camera(cur, 0.28, 5.0, rng).astype(float), guess=None)
    # a sine has no harmonics, and at pitch 5.3 none would fold near the carrier: the
    # bound, 3.6e-4 px, is what the fit finds at the folds in the noise, a tenth of
    # the displacement noise std (3.7e-3 px); a fifth of it leaves room for the draw
    std = float(np.median(np.asarray(res.uncertainty["ux_std"][0])[res.valid[0]]))
    assert res.systematic["aliasing"]["u_px"] < 0.2 * std
    assert not said(res.warnings, "aliasing.bound")


def test_check_sigma_snaps_within_1e_3_and_refuses_below():
    from gridstrain._validation import check_sigma

    assert check_sigma(None, 6.000003) == 6.000003
    # typed as 6 for a detected 6.000003 px: the pitch itself
    assert check_sigma(6.0, 6.000003) == 6.000003
    assert check_sigma(6.0 * (1 - 0.9e-3), 6.0) == 6.0
    assert check_sigma(9.0, 6.0) == 9.0
    with pytest.raises(ValueError, match="at least the pitch"):
        check_sigma(6.0 * (1 - 1.1e-3), 6.0)
    with pytest.raises(TypeError, match="sigma"):
        check_sigma("6", 6.0)


def test_predicted_and_measured_floors_are_one_type_and_agree(pair):
    from gridstrain import uncertainty, wft

    ref = tifffile.imread(pair / "ref.tif").astype(np.float64)
    cur = tifffile.imread(pair / "def.tif").astype(np.float64)
    K, L = 0.28 * 16, 5 * 256  # the camera's model in stored units (x16 storage)
    lat = Lattice.from_pitch(5.3, angle=10.0)
    res = measure_series(ref, cur, lattice=lat, guess=(0.0, 0.0), noise_model=(K, L))
    measured = res.noise
    assert type(measured) is uncertainty.NoiseFloor
    predicted = uncertainty.noise_floor(wft(ref, lat, sigma=res.sigma), ref, K=K, L=L)
    assert isinstance(measured, uncertainty.NoiseFloor)
    assert isinstance(predicted, uncertainty.NoiseFloor)
    assert predicted.frames == measured.frames == (1, 1)
    assert predicted.sigma == measured.sigma
    # the same theory (eqs. 23-25, 34-35): the measurement evaluates it at the mean
    # variance and median modulus, the prediction takes the median of its per-pixel
    # maps; on this uniform sine grid they differ by the modulus' spread (0.8 %)
    np.testing.assert_allclose(predicted.theory_u, measured.theory_u, rtol=0.03)
    np.testing.assert_allclose(predicted.theory_strain, measured.theory_strain, rtol=0.03)
    np.testing.assert_allclose(predicted.modulus, measured.modulus, rtol=0.02)
    assert np.all(np.isnan(predicted.split_u))
    assert np.all(np.isnan(predicted.vibration_u))
    d = predicted.as_dict()
    assert d["model"] == {"source": "given", "K": K, "L": L}
    assert d["frames"] == [1, 1]
    assert len(d["theory_phase"][0]) == 2
