"""Tests of ``gridstrain measure`` and ``gridstrain demo`` through cli.main."""

from __future__ import annotations

import hashlib
import json
import math
import os
import shlex
from pathlib import Path

import h5py
import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.models import kirsch, synthetic
from gridstrain.post import figure_names
from gridstrain.results import load

LAT = Lattice.from_pitch(5.0)
N, A_HOLE = 128, 14.0
C = ((N - 1) / 2, (N - 1) / 2)


def _frames(T, *, loaded, rng):
    """12-bit frames of a plate with a hole, noisy and vibrating, as raw x16 uint16."""
    el = {"radius": A_HOLE, "remote_stress": 100.0, "centre": C}

    def refl(X, Y):
        return ((X - C[0]) ** 2 + (Y - C[1]) ** 2 >= A_HOLE**2).astype(float)

    out = []
    for _ in range(T):
        a = rng.normal(0.0, 0.01, 2)

        def disp(X, Y, a=a):
            ux, uy = (kirsch.displacement(X, Y, inside="extend", **el) if loaded
                      else (0 * X, 0 * Y))
            return ux + 1.2 - a[0], uy - 0.4 - a[1]

        img = synthetic.grid_image((N, N), LAT, amplitude=2400.0, displacement=disp,
                                   reflectance=refl) + 100.0
        out.append((synthetic.add_noise(img, rng=rng, clip=True) * 16).astype(np.uint16))
    return out


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A reference directory of 3 TIFFs, a loaded state as a 3-page TIFF, a mask."""
    root = tmp_path_factory.mktemp("series")
    rng = np.random.default_rng(2015)
    (root / "ref").mkdir()
    for k, f in enumerate(_frames(3, loaded=False, rng=rng)):
        tifffile.imwrite(root / "ref" / f"img{k}.tif", f, photometric="minisblack")
    tifffile.imwrite(root / "load.tif", np.stack(_frames(3, loaded=True, rng=rng)),
                     photometric="minisblack")
    yy, xx = np.mgrid[0:N, 0:N]
    mask = (xx - C[0]) ** 2 + (yy - C[1]) ** 2 > (A_HOLE + 1) ** 2
    tifffile.imwrite(root / "mask.tif", (mask * 255).astype(np.uint8))
    return root


def _hashes(root: Path) -> dict:
    return {p: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _run(argv):
    """``main(argv)`` -> return code, also for argparse's SystemExit."""
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


# ------------------------------------------------------------------- success


def test_measure_writes_hdf5_csv_and_figures(data, tmp_path, capsys):
    before = _hashes(data)
    out = tmp_path / "maps.h5"
    rc = _run(["measure", data / "ref", data / "load.tif", "-o", out, "--mask",
               data / "mask.tif", "--pixel-size", "0.04", "--unit", "mm", "--csv",
               tmp_path / "maps.csv", "--figures", tmp_path / "figs", "--json", "--quiet"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert cap.err == ""  # --quiet: no progress bar
    summary = json.loads(cap.out)
    assert summary["outputs"]["hdf5"] == str(out)
    assert summary["bit_depth"] == 12
    assert summary["scale"] == 16
    assert summary["reference"]["frames"] == 3
    assert summary["states"][0]["frames"] == 3
    assert math.isclose(summary["lattice"]["pitches_px"][0], 5.0, rel_tol=1e-4)
    assert _hashes(data) == before  # inputs untouched

    with h5py.File(out, "r") as h5:
        for name, unit in (("ux", "px"), ("uy", "px"), ("exx", "1"), ("eyy", "1"),
                           ("exy", "1"), ("ux_phys", "mm"), ("uy_phys", "mm")):
            assert h5[name].shape == (1, N, N)
            assert h5[name].attrs["units"] == unit
        valid = h5["valid"][()]
        assert valid.dtype == bool
        assert valid.shape == (1, N, N)
        # ux and ux_phys are each rounded to a tenth of their std (ux_std, in px or in
        # mm): they agree to two tenths of it
        diff = np.abs(h5["ux_phys"][()] - 0.04 * h5["ux"][()].astype(np.float64))
        assert np.all(diff[valid] <= 0.2 * 0.04 * h5["ux_std"][()][valid])
        exx = h5["exx"][0][valid[0]]
        assert h5.attrs["unit"] == "mm"
        assert h5.attrs["pixel_size"] == 0.04
        assert h5.attrs["mask_file"] == str(data / "mask.tif")
        assert h5["vibration_shifts"].shape == (2, 3, 2)  # series, frame, (alpha, beta)
        assert h5["noise_theory_strain"].shape == (1, 3)
        files = list(h5.attrs["reference_files"])
        assert [Path(f).name for f in files] == ["img0.tif", "img1.tif", "img2.tif"]
    # the plate is in tension: e_xx near the remote 1.4e-3 on average (the noise
    # floor of T = 3 frames, ~3e-4 per pixel, averages out over the map)
    assert 1.0e-3 < float(np.mean(exx)) < 2.0e-3

    rows = np.genfromtxt(tmp_path / "maps.csv", delimiter=",", names=True)
    assert rows.size == int(valid.sum())
    assert rows.dtype.names[:5] == ("state", "x_px", "y_px", "x_mm", "y_mm")

    figs = sorted((tmp_path / "figs").glob("*.png"))
    assert [f.name for f in figs] == sorted(figure_names(1))
    assert len(figs) == 5 + 2  # five maps of one state, two vibration plots
    for f in figs:
        img = iio.imread(f)
        assert img.ndim == 3
        assert img.shape[2] in (3, 4)
        assert min(img.shape[:2]) > 200
        assert img.std() > 0  # something drawn
    assert summary["outputs"]["figures"] == [str(tmp_path / "figs" / n)
                                             for n in figure_names(1)]


def test_report_progress_and_overwrite(data, tmp_path, capsys):
    out = tmp_path / "maps.h5"
    argv = ["measure", data / "ref", data / "load.tif", "-o", out, "--mask",
            data / "mask.tif", "--pitch", "5"]
    assert _run(argv) == 0
    cap = capsys.readouterr()
    assert "noise floor" in cap.out
    assert "spatial resolution" in cap.out
    assert "vibrations" in cap.out
    assert "wrote" in cap.out
    assert "lattice (given)" in cap.out
    assert "%" not in cap.err  # no progress bar when stderr is not a terminal
    first = out.stat().st_mtime_ns
    # kept without --overwrite, replaced with it
    assert _run(argv) == 2
    assert out.stat().st_mtime_ns == first
    capsys.readouterr()
    assert _run([*argv, "--overwrite", "--quiet"]) == 0
    cap = capsys.readouterr()
    assert cap.out == ""
    assert cap.err == ""


def test_config_file_and_command_line_override(data, tmp_path, capsys):
    cfg = tmp_path / "run.toml"
    cfg.write_text(f'output = "maps.h5"\npitch = 5\nsigma = 6.0\nmethod = "B"\n'
                   f'mask = "{data / "mask.tif"}"\npixel_size = 0.04\nunit = "mm"\n'
                   'no-lagrangian = true\nquiet = true\n')
    rc = _run(["measure", data / "ref", data / "load.tif", "--config", cfg, "--sigma", "7"])
    assert rc == 0, capsys.readouterr().err
    out = tmp_path / "maps.h5"  # relative to the config file
    with h5py.File(out, "r") as h5:
        assert h5.attrs["sigma"] == 7.0  # the command line wins
        assert h5.attrs["method"] == "B"
        assert not h5.attrs["lagrangian"]
        assert h5.attrs["config_file"] == str(cfg)
        assert h5.attrs["unit"] == "mm"


# ------------------------------------------------------------------- bad input


def _write(path, arr, **kw):
    tifffile.imwrite(path, arr, **{"photometric": "minisblack", **kw})
    return path


def _case_missing(d, t):
    return [t / "nope", d / "load.tif"]


def _case_empty_dir(d, t):
    (t / "empty").mkdir()
    return [t / "empty", d / "load.tif"]


def _case_mixed_sizes(d, t):
    (t / "mixed").mkdir()
    _write(t / "mixed" / "a.tif", np.zeros((N, N), np.uint16))
    _write(t / "mixed" / "b.tif", np.zeros((N, N - 8), np.uint16))
    return [t / "mixed", d / "load.tif"]


def _case_corrupt(d, t):
    (t / "bad.tif").write_bytes(b"II*\x00" + b"\x07" * 64)
    return [t / "bad.tif", d / "load.tif"]


def _case_rgb(d, t):
    return [_write(t / "rgb.tif", np.zeros((N, N, 3), np.uint8), photometric="rgb"),
            d / "load.tif"]


def _case_nan(d, t):
    img = synthetic.grid_image((N, N), LAT, amplitude=1000.0).astype(np.float32)
    img[5, 5] = np.nan
    return [_write(t / "nan.tif", img), d / "load.tif"]


def _case_saturated(d, t):
    img = np.rint(synthetic.grid_image((N, N), LAT, amplitude=150.0)).astype(np.uint8)
    img[:10] = 255  # 8 % saturated
    return [d / "ref", _write(t / "sat.tif", img)]


def _case_no_grid(d, t):
    noise = np.random.default_rng(1).normal(30000, 300, (N, N)).astype(np.uint16)
    return [_write(t / "noise.tif", noise), _write(t / "noise2.tif", noise)]


def _case_mask_size(d, t):
    return [d / "ref", d / "load.tif", "--mask",
            _write(t / "m.tif", np.ones((N, N + 1), np.uint8))]


def _case_mask_empty(d, t):
    return [d / "ref", d / "load.tif", "--mask", _write(t / "m0.tif", np.zeros((N, N),
                                                                                np.uint8))]


def _case_negative_pixel_size(d, t):
    return [d / "ref", d / "load.tif", "--pixel-size", "-0.04", "--unit", "mm"]


def _case_method_d(d, t):
    return [d / "ref", d / "load.tif", "--method", "D"]


def _case_out_dir_is_a_file(d, t):
    # a missing folder is made (mkdir -p); a file in its way is refused
    (t / "nodir").write_text("a file")
    return [d / "ref", d / "load.tif", "-o", t / "nodir" / "out.h5"]


def _case_existing_output(d, t):
    (t / "out.h5").write_bytes(b"earlier result")
    return [d / "ref", d / "load.tif"]


def _case_bad_toml_key(d, t):
    (t / "c.toml").write_text("pich = 5\n")
    return [d / "ref", d / "load.tif", "--config", t / "c.toml"]


def _case_bad_toml_syntax(d, t):
    (t / "c.toml").write_text("pitch = = 5\n")
    return [d / "ref", d / "load.tif", "--config", t / "c.toml"]


def _case_bad_toml_type(d, t):
    (t / "c.toml").write_text('sigma = "five"\n')
    return [d / "ref", d / "load.tif", "--config", t / "c.toml"]


def _case_sigma_below_pitch(d, t):
    return [d / "ref", d / "load.tif", "--pitch", "5", "--sigma", "3"]


def _case_k1_without_k2(d, t):
    return [d / "ref", d / "load.tif", "--k1", "0.2", "0"]


def _case_pitch_and_k(d, t):
    return [d / "ref", d / "load.tif", "--pitch", "5", "--k1", "0.2", "0", "--k2", "0", "0.2"]


def _case_unit_without_size(d, t):
    return [d / "ref", d / "load.tif", "--unit", "mm"]


def _case_output_is_input(d, t):
    # even with --overwrite an input is never replaced (the output is redirected
    # to the input file; the check in _run_case sees no new file)
    return [d / "ref", d / "load.tif", "--overwrite", "--csv", d / "load.tif"]


def _case_state_size(d, t):
    return [d / "ref", _write(t / "small.tif", np.zeros((N - 8, N), np.uint16) + 16)]


def _case_bit_depth(d, t):
    return [d / "ref", d / "load.tif", "--bit-depth", "20"]


def _case_csv_dir_is_a_file(d, t):
    (t / "nodir").write_text("a file")
    return [d / "ref", d / "load.tif", "--csv", t / "nodir" / "sub" / "x.csv"]


def _case_figures_is_file(d, t):
    (t / "figs").write_text("not a directory")
    return [d / "ref", d / "load.tif", "--figures", t / "figs"]


def _case_nyquist_pitch(d, t):
    return [d / "ref", d / "load.tif", "--pitch", "1.5"]


def _case_wrong_lattice(d, t):
    return [d / "ref", d / "load.tif", "--pitch", "8"]


def _case_zero_margin(d, t):
    return [d / "ref", d / "load.tif", "--margin", "0"]


def _case_guess_one_value(d, t):
    return [d / "ref", d / "load.tif", "--guess", "1"]


CASES = {name[6:]: f for name, f in globals().items() if name.startswith("_case_")}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_gives_one_line_and_no_output(case, data, tmp_path, capsys):
    args = CASES[case](data, tmp_path)
    before = {p.name for p in tmp_path.iterdir()}
    data_before = _hashes(data)
    argv = ["measure", *args, "--quiet"]
    if "-o" not in args:
        argv += ["-o", tmp_path / "out.h5"]
    rc = _run(argv)
    cap = capsys.readouterr()
    assert rc != 0
    lines = cap.err.splitlines()
    assert len(lines) == 1, cap.err
    assert lines[0].startswith("gridstrain measure: error:"), cap.err
    assert "Traceback" not in cap.err
    assert cap.out == ""
    # no output left behind (the case may have created its inputs in tmp_path)
    after = {p.name for p in tmp_path.iterdir()}
    assert after == before, after - before
    assert _hashes(data) == data_before


@pytest.mark.parametrize("extra", [("--report", "out.h5"),
                                   ("--csv", "out.csv", "--export", "csv"),
                                   ("--report", "out.mat", "--export", "mat,vtk")])
def test_two_outputs_of_one_run_under_one_name_are_refused(extra, data, tmp_path, capsys):
    """The result, its CSV, its exports and its report are four files: two of them
    under one name would leave one in place of the other (with --overwrite, the
    report in place of the result), so the run is refused before it starts."""
    extra = [tmp_path / v if v.startswith("out.") else v for v in extra]
    rc = _run(["measure", data / "ref", data / "load.tif", "--quiet", "--overwrite",
               "-o", tmp_path / "out.h5", *extra])
    err = capsys.readouterr().err.splitlines()
    assert rc == 2
    assert len(err) == 1
    assert "name the same file" in err[0]
    assert list(tmp_path.iterdir()) == []


def test_at_least_fifteen_kinds_of_bad_input():
    assert len(CASES) >= 15


def test_error_after_the_progress_bar_has_a_line_of_its_own(data, tmp_path, capsys):
    args = _case_saturated(data, tmp_path)
    rc = _run(["measure", *args, "-o", tmp_path / "out.h5"])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.endswith("\n")
    assert "%" in err
    last = err.splitlines()[-1]
    assert last.startswith("gridstrain measure: error: sat: frame 0"), err  # the file's stem
    assert "saturated" in last
    assert not (tmp_path / "out.h5").exists()


# ------------------------------------------------------------------- demo


@pytest.mark.slow
def test_demo_defaults(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert _run(["demo", "--json", "--quiet"]) == 0
    s = json.loads(capsys.readouterr().out)
    # per-pixel errors against the homogeneous truth: at the predicted noise floor
    # (1.3 x: the valid region of a 192^2 image holds ~30 independent windows)
    floor = np.max(s["noise_floor"]["theory_strain"], axis=0)
    for i, name in enumerate(("exx", "eyy", "exy")):
        assert s["demo"]["rms_error"][name] < 1.3 * floor[i]
    c = s["demo"]["elastic_constants"]
    assert c["E_ci"][0] < c["E_true"] < c["E_ci"][1]
    assert c["nu_ci"][0] < c["nu_true"] < c["nu_ci"][1]


DEMO_SMALL = ["demo", "--size", "128", "--steps", "3", "--out", "d"]


def test_demo_measures_a_tensile_test_with_the_machines_log(tmp_path, monkeypatch, capsys):
    from gridstrain.post import elastic_constants, gauge, modulus_unit

    monkeypatch.chdir(tmp_path)
    assert _run([*DEMO_SMALL, "--json", "--quiet"]) == 0
    s = json.loads(capsys.readouterr().out)
    d = tmp_path / "d"
    frames = sorted((d / "record").iterdir())
    assert [f.name for f in frames] == [f"frame{k:06d}.tif" for k in range(4)]
    ref = tifffile.imread(frames[0])
    assert ref.dtype == np.uint16
    assert not np.any(ref % 16)  # 12-bit data x16
    for name in ("mask.tif", "maps.h5", "truth.h5", "report.html"):
        assert (d / name).is_file()
    # the log as a testing machine writes it: a preamble, ';', a decimal comma, kN,
    # a row every 0.1 s, many more rows than images
    log = (d / "loads.csv").read_text(encoding="utf-8").splitlines()
    header = next(i for i, line in enumerate(log) if line.startswith("Zeit [s];"))
    assert header >= 2
    assert "Kraft [kN]" in log[header]
    rows = [r.split(";") for r in log[header + 1:]]
    assert len(rows) > 10 * 4
    assert all("," in c and "." not in c for c in rows[1])
    t = np.array([float(r[0].replace(",", ".")) for r in rows])
    np.testing.assert_allclose(np.diff(t), 0.1, atol=1e-9)  # s: printed to 0.01 s
    # the states' loads: the log interpolated at the images' times (2, 4, 6 s; the
    # log's clock 0.2 s ahead): the true ramp to 3 kN within 1e-3 kN (5 std of the
    # load cell's 2e-4 kN noise; a linear ramp interpolates exactly)
    res = load(d / "maps.h5")
    assert res.load_unit == "kN"
    np.testing.assert_allclose(res.time, [2.0, 4.0, 6.0])
    np.testing.assert_allclose(res.load, [1.0, 2.0, 3.0], atol=1e-3)
    # strain maps at the predicted noise floor (1.5 x: a 128^2 image's valid region
    # holds ~12 independent windows, 20 % sampling)
    floor = np.max(s["noise_floor"]["theory_strain"], axis=0)
    for i, name in enumerate(("exx", "eyy", "exy")):
        assert s["demo"]["rms_error"][name] < 1.5 * floor[i]
    # E and nu: those of the default gauge computed here (the oracle), printed in
    # the report with their intervals; the truth inside them
    c = elastic_constants(gauge(res), area=20.0)
    got = s["demo"]["elastic_constants"]
    assert got["E"] == pytest.approx(c.E, rel=1e-12)
    assert got["nu"] == pytest.approx(c.nu, rel=1e-12)
    assert c.E_ci[0] < 70e3 < c.E_ci[1]
    assert c.nu_ci[0] < 0.33 < c.nu_ci[1]
    page = (d / "report.html").read_text(encoding="utf-8")
    k, unit = modulus_unit(c.E, c.stress_unit)
    assert "Young&#39;s modulus E" in page or "Young's modulus E" in page
    assert f"[{c.E_ci[0] * k:.4g}, {c.E_ci[1] * k:.4g}] {unit}" in page
    assert f"[{c.nu_ci[0]:.4f}, {c.nu_ci[1]:.4f}]" in page
    assert 'alt="stress-strain plot"' in page
    assert s["demo"]["measure_command"].startswith("gridstrain measure d/record ")
    # an earlier demo is kept without --overwrite
    assert _run(DEMO_SMALL) == 2
    assert "earlier gridstrain run" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_overwrite_then_run_its_commands(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    argv = ["demo", "--size", "128", "--out", "d"]
    assert _run([*argv, "--steps", "4", "--quiet"]) == 0
    assert _run([*argv, "--steps", "3", "--overwrite"]) == 0
    assert len(list((tmp_path / "d" / "record").iterdir())) == 4  # no stale frame left
    out = capsys.readouterr().out
    assert "RMS error against the truth" in out
    assert "E  = " in out
    lines = out.strip().splitlines()
    commands = [c.strip() for c in lines[lines.index("do the same yourself:") + 1:]]
    assert commands[0].startswith("gridstrain measure d/record --reference-frames 1")
    for command in commands:
        rc = _run([*shlex.split(command)[1:], *(["--quiet"] if "measure" in command
                                                else [])])
        assert rc == 0, capsys.readouterr().err
    assert "E  = " in capsys.readouterr().out
    first, again = load(tmp_path / "d" / "maps.h5"), load(tmp_path / "maps.h5")
    np.testing.assert_array_equal(again.load, first.load)
    np.testing.assert_array_equal(again.get_map("exx"), first.get_map("exx"))
    assert (tmp_path / "report.html").is_file()


def test_demo_result_replays_its_measurement(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert _run(["demo", "--size", "96", "--steps", "3", "--out", "d", "--quiet"]) == 0
    rc = _run(["measure", "--config", "d/maps.h5", "-o", "again.h5", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    first, again = load(tmp_path / "d" / "maps.h5"), load(tmp_path / "again.h5")
    assert again.method == first.method
    # the same frames, log, mask and options: the same numbers, whatever the run
    np.testing.assert_array_equal(again.valid, first.valid)
    np.testing.assert_array_equal(again.load, first.load)
    np.testing.assert_array_equal(again.time, first.time)
    for name in ("ux", "uy", "exx"):
        np.testing.assert_array_equal(again.get_map(name), first.get_map(name))


@pytest.mark.parametrize("bad", [["--size", "32"], ["--steps", "2"], ["--steps", "13"],
                                 ["--vibration", "-1"], ["--stress", "1e4"],
                                 ["--area", "0"], ["--translation", "3", "0"]])
def test_demo_bad_options(bad, tmp_path, capsys):
    rc = _run(["demo", "--out", tmp_path / "d", *bad])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("gridstrain demo: error:")
    assert not (tmp_path / "d").exists()


def test_outputs_into_folders_not_made_yet(data, tmp_path, capsys):
    """Every option that writes into a folder makes the missing ones (mkdir -p): the
    result, its CSV, exports, report and figures of measure, then report, export,
    plot and gauge on the result; a refused run leaves no folder behind."""
    out = tmp_path / "a" / "b" / "maps.h5"
    rc = _run(["measure", data / "ref", data / "load.tif", "-o", out, "--mask",
               data / "mask.tif", "--csv", tmp_path / "c" / "d" / "maps.csv",
               "--export", "mat", "--report", tmp_path / "r" / "s" / "r.html",
               "--figures", tmp_path / "f" / "g" / "figs", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    for p in (out, out.with_suffix(".mat"), tmp_path / "c" / "d" / "maps.csv",
              tmp_path / "r" / "s" / "r.html"):
        assert p.is_file(), p
    assert sorted(p.name for p in (tmp_path / "f" / "g" / "figs").glob("*.png")) == \
        sorted(figure_names(1))
    for argv, made in (
            (["report", out, "-o", tmp_path / "R" / "x" / "r.html"], "R/x/r.html"),
            (["export", out, "--to", "csv,vtk", "-o", tmp_path / "E" / "x" / "pre"],
             "E/x/pre.pvd"),
            (["plot", out, "--maps", "exx", "-o", tmp_path / "P" / "x" / "figs"],
             "P/x/figs/exx.png"),
            (["gauge", out, "-o", tmp_path / "G" / "x" / "g.csv"], "G/x/g.csv")):
        assert _run(argv) == 0, capsys.readouterr().err
        assert (tmp_path / made).is_file(), made
    capsys.readouterr()
    # refused after the folders of the first output were made: none is left
    (tmp_path / "taken.csv").write_text("not gridstrain's\n")
    rc = _run(["measure", data / "ref", data / "load.tif", "-o",
               tmp_path / "n1" / "n2" / "maps.h5", "--csv", tmp_path / "taken.csv",
               "--quiet"])
    assert rc == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not (tmp_path / "n1").exists()
    # refused for what the result lacks (a history of a result without times)
    assert _run(["history", out, "-o", tmp_path / "H" / "x" / "h.csv"]) == 2
    assert not (tmp_path / "H").exists()
    capsys.readouterr()
    # a folder that cannot be made (a file in the way): one line naming it
    assert _run(["gauge", out, "-o", tmp_path / "taken.csv" / "g.csv"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "taken.csv" in err
    assert "a file" in err


def test_python_dash_m_gridstrain_is_the_command():
    # `python -m gridstrain` runs the same command line as `gridstrain`
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-m", "gridstrain", "--version"],
                       capture_output=True, text=True, timeout=120, check=False)
    q = subprocess.run([sys.executable, "-m", "gridstrain.cli", "--version"],
                       capture_output=True, text=True, timeout=120, check=False)
    assert p.returncode == 0, p.stderr
    assert p.stdout == q.stdout
    assert "gridstrain" in p.stdout


_ENTRY = """
import atexit, sys, threading, time
marker, wait_for = sys.argv[1], sys.argv[2] == "thread"
atexit.register(lambda: open(marker, "a").write("exit handler ran;"))
if wait_for:  # a thread still working when the command returns
    threading.Thread(target=lambda: (time.sleep(0.5),
                                     open(marker, "a").write("thread ended;"))).start()
sys.argv = ["gridstrain", *sys.argv[3:]]
print("printed before;", end="")
from gridstrain.cli import entry
entry()
"""


@pytest.mark.parametrize("thread", ["thread", "none"])
def test_the_commands_own_process_ends_with_its_handlers_run(thread, data, tmp_path):
    """The console script's end (cli.entry) skips the interpreter's teardown only: the
    exit status is the command's, what was printed is flushed, Python's exit handlers
    run, a thread still working is waited for, the result is whole."""
    import subprocess
    import sys

    marker = tmp_path / "marker.txt"
    out = tmp_path / "maps.h5"
    p = subprocess.run([sys.executable, "-c", _ENTRY, str(marker), thread, "measure",
                        str(data / "ref"), str(data / "load.tif"), "-o", str(out),
                        "--quiet"], capture_output=True, text=True, timeout=300,
                       check=False)
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("printed before;")
    done = marker.read_text()
    assert "exit handler ran;" in done
    assert ("thread ended;" in done) == (thread == "thread")
    assert np.isfinite(load(out).ux).any()  # the state measured, readable
    # a refused input: its one line and status 2, the handlers run all the same
    marker.unlink()
    q = subprocess.run([sys.executable, "-c", _ENTRY, str(marker), "none", "gauge",
                        str(tmp_path / "missing.h5")], capture_output=True, text=True,
                       timeout=300, check=False)
    assert q.returncode == 2
    assert len(q.stderr.strip().splitlines()) == 1
    assert marker.read_text() == "exit handler ran;"


def test_python_dash_m_run_by_a_callers_runpy_leaves_the_caller_running(tmp_path):
    """``python -m gridstrain``'s module run inside another program (runpy, as an IDE
    or a test harness runs it) raises SystemExit as always: the caller catches it, goes
    on, and its own open files are whole (the process's fast end is the command's own
    process's only)."""
    import subprocess
    import sys

    host = (
        "import runpy, sys\n"
        "out = open(sys.argv[1], 'w')\n"
        "out.write('before;')\n"
        "sys.argv = ['gridstrain', 'gauge', sys.argv[2]]\n"
        "try:\n"
        "    runpy.run_module('gridstrain', run_name='__main__', alter_sys=True)\n"
        "except SystemExit as exc:\n"
        "    out.write(f'caught {exc.code};')\n"
        "out.write('after')\n"
        "out.close()\n")
    # a probe of the interpreter's teardown: an object whose finaliser writes a word
    probe = tmp_path / "probe"
    probe.mkdir()
    (probe / "sitecustomize.py").write_text(
        "import sys\n"
        "class _Probe:\n"
        "    def __del__(self):\n"
        "        sys.stderr.write('TEARDOWN')\n"
        "sys._gridstrain_probe = _Probe()\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(probe), env.get("PYTHONPATH", "")])
    log = tmp_path / "host.log"
    p = subprocess.run([sys.executable, "-c", host, str(log), str(tmp_path / "none.h5")],
                       capture_output=True, text=True, timeout=120, check=False, env=env)
    assert p.returncode == 0, p.stderr
    assert log.read_text() == "before;caught 2;after"
    assert p.stderr.endswith("TEARDOWN")  # the caller's process ended as usual
    # python -m run by the interpreter itself: the command's own process, ended
    # without the teardown, its status and its one line kept
    for module in ("gridstrain", "gridstrain.cli"):
        q = subprocess.run([sys.executable, "-m", module, "gauge", str(tmp_path / "none.h5")],
                           capture_output=True, text=True, timeout=120, check=False,
                           env=env)
        assert q.returncode == 2
        assert "TEARDOWN" not in q.stderr
        assert len(q.stderr.strip().splitlines()) == 1


def test_a_folder_removed_under_a_run_is_made_again(data, tmp_path, capsys, monkeypatch):
    """Two runs write into the same new folder; the one that made it fails and removes
    it while still empty: the other, which found it there, makes it again when it
    writes its file rather than failing at the end with its work lost."""
    from gridstrain.post import _report

    out = tmp_path / "maps.h5"
    assert _run(["measure", data / "ref", data / "load.tif", "-o", out, "--quiet"]) == 0
    shared = tmp_path / "shared"
    shared.mkdir()  # made by the other run, before this one started
    render = _report.render_report

    def render_then_lose_the_folder(*args, **kwargs):
        text = render(*args, **kwargs)
        shared.rmdir()  # the other run's rollback, while this one was drawing
        return text

    monkeypatch.setattr(_report, "render_report", render_then_lose_the_folder)
    rc = _run(["report", out, "-o", shared / "r.html"])
    assert rc == 0, capsys.readouterr().err
    assert (shared / "r.html").is_file()
    # and an API writer outside a command still refuses a missing folder
    from gridstrain.io import write_atomic

    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_atomic(tmp_path / "nowhere" / "x.bin", b"x")


def test_an_output_through_a_symbolic_link_to_nothing_is_refused(data, tmp_path, capsys):
    """A folder named through a dangling symbolic link is refused in one line naming
    the link: never made wherever the link points (plot made it there before)."""
    out = tmp_path / "maps.h5"
    assert _run(["measure", data / "ref", data / "load.tif", "-o", out, "--quiet"]) == 0
    capsys.readouterr()
    target = tmp_path / "nowhere"
    (tmp_path / "dl").symlink_to(target)
    for argv in (["plot", out, "--maps", "exx", "-o", tmp_path / "dl" / "figs"],
                 ["report", out, "-o", tmp_path / "dl" / "x" / "r.html"],
                 ["gauge", out, "-o", tmp_path / "dl" / "g.csv"]):
        assert _run(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert "symbolic link" in err
        assert not target.exists()


def test_every_option_with_a_default_says_it_in_its_help():
    """A user reads --help for the units and the defaults: every option of every
    command that has a default value names it."""
    import argparse

    from gridstrain.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    silent = [(name, a.option_strings[0]) for name, sp in sub.choices.items()
              for a in sp._actions
              if a.option_strings and a.help not in (None, argparse.SUPPRESS)
              and not isinstance(a, argparse._HelpAction | argparse._VersionAction)
              and a.default not in (None, False, True) and "default" not in a.help]
    assert silent == []
