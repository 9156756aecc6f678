"""Animations of the states (``gridstrain animate``)."""

from __future__ import annotations

import numpy as np
import pytest

from gridstrain import measure_series
from gridstrain.cli import main
from independent_grid import camera, scene

H, W = 96, 120


@pytest.fixture(scope="module")
def series_file(tmp_path_factory):
    """Four states of growing tension (one image each), with times and loads."""
    d = tmp_path_factory.mktemp("anim")
    rng = np.random.default_rng(5)
    strains = (0.0, 5e-4, 1e-3, 1.5e-3, 2e-3)
    images = [camera(scene((H, W), pitch=5.0, angle=0.0, hole=False, light=False,
                           displacement=lambda X, Y, e=e: (e * X, 0 * Y))[0], 0.28, 5.0,
                     rng).astype(np.float64) for e in strains]
    res = measure_series(images[0], images[1:], noise_model=(16 * 0.28, 256 * 5.0))
    path = d / "maps.h5"
    res.save(path)
    loads = d / "loads.csv"
    loads.write_text("load [kN],time [s]\n1,0.1\n2,0.2\n3,0.3\n4,0.4\n")
    return res, path, loads


def test_gif_frames_share_their_colours_and_name_the_state(series_file, tmp_path):
    import imageio.v3 as iio

    from gridstrain.post import animate

    res, _, _ = series_file
    out = animate(res, "exx", tmp_path / "exx.gif", time=[0.1, 0.2, 0.3, 0.4], load=[1, 2,
                  3, 4], load_unit="kN")
    frames = iio.imread(out, index=None)
    assert frames.shape[0] == res.n_states
    # fixed colour limits: the colour bar and its ticks (the right fifth of the frame)
    # stay the same pixels, up to the GIF palette's rounding (measured 0.6 grey level
    # on average), while the map's colours follow the strain (measured 31)
    f = frames.astype(float)
    w = f.shape[2]
    assert np.abs(f[0, :, int(0.8 * w):] - f[-1, :, int(0.8 * w):]).mean() < 3
    assert np.abs(f[0, :, :int(0.7 * w)] - f[-1, :, :int(0.7 * w)]).mean() > 10


def test_animations_in_percent_and_of_the_derived_strains(series_file, tmp_path):
    import imageio.v3 as iio

    from gridstrain.post import animate

    res, _, _ = series_file
    micro = iio.imread(animate(res, "exx", tmp_path / "u.gif"), index=None)
    pct = iio.imread(animate(res, "exx", tmp_path / "p.gif", strain_units="%"),
                     index=None)
    assert pct.shape == micro.shape
    # the colour bar's unit and ticks (and the layout around them) change
    assert np.abs(micro.astype(float) - pct).mean() > 1
    e1 = iio.imread(animate(res, "e1", tmp_path / "e1.gif"), index=None)
    assert e1.shape[0] == res.n_states
    with pytest.raises(ValueError, match="strain units must be one of"):
        animate(res, "exx", tmp_path / "x.gif", strain_units="permille")


def test_animate_command_mp4_and_gif(series_file, tmp_path, capsys):
    pytest.importorskip("av")
    import imageio.v3 as iio

    _, path, loads = series_file
    mp4 = tmp_path / "exx.mp4"
    assert main(["animate", str(path), "exx", "-o", str(mp4), "--loads", str(loads)]) == 0
    assert capsys.readouterr().out.strip() == str(mp4)
    meta = iio.immeta(mp4, plugin="pyav")
    assert meta["fps"] == pytest.approx(5.0)
    assert main(["animate", str(path), "exx", "-o", str(tmp_path / "a.avi")]) == 2
    assert "-o must end in .gif or .mp4" in capsys.readouterr().err  # names the flag


def test_missing_video_extra_is_one_line(series_file, tmp_path, capsys, monkeypatch):
    import sys

    _, path, _ = series_file
    monkeypatch.setitem(sys.modules, "av", None)  # as if PyAV were not installed
    assert main(["animate", str(path), "exx", "-o", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gridstrain animate: error: MP4 needs PyAV: pip install "
                   "'gridstrain[video]'"]
    assert not (tmp_path / "x.mp4").exists()


def test_history_command(series_file, tmp_path, capsys):
    import csv

    _, path, loads = series_file
    out = tmp_path / "h.csv"
    assert main(["history", str(path), "--loads", str(loads), "--window", "3", "--order",
                 "2", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "window 3 states, order 2" in text
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4
    # exx grows by 5e-4 per 0.1 s: 5e-3 /s, within 4 stated std
    rate = np.array([float(r["exx_rate [1/s]"]) for r in rows])
    std = np.array([float(r["exx_rate_std [1/s]"]) for r in rows])
    assert np.all(np.abs(rate - 5e-3) < 4 * std)
    assert main(["history", str(path)]) == 2  # no times
    assert "no times" in capsys.readouterr().err
