"""The pixel size from the grid's printed pitch: ``--grid-pitch PITCH --unit mm`` and
:meth:`gridstrain.Lattice.pixel_size`.

The oracle is the law itself: a grid printed at 0.2 mm and imaged at 5.3 px has
pixels of 0.2 / 5.3 mm on the specimen.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import tifffile

from gridstrain import Lattice
from gridstrain.cli import main
from gridstrain.series import reference_lattice
from independent_grid import camera, scene

PITCH_PX, GRID_MM = 5.3, 0.2
SHAPE = (128, 160)


def _frame(rng, strain=0.0):
    level, _ = scene(SHAPE, pitch=PITCH_PX, angle=0.0, kind="sine", hole=False,
                     displacement=lambda X, Y: (strain * (X - 80), 0 * Y))
    return camera(level, 0.28, 5.0, rng)


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    root = tmp_path_factory.mktemp("grid_pitch")
    rng = np.random.default_rng(31)
    tifffile.imwrite(root / "ref.tif", np.stack([_frame(rng) for _ in range(2)]))
    tifffile.imwrite(root / "load.tif", _frame(rng, 1e-3))
    return root


def _run(argv) -> int:
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


def test_lattice_pixel_size_is_the_printed_pitch_over_the_pitch_in_px():
    assert Lattice.from_pitch(PITCH_PX).pixel_size(GRID_MM) == pytest.approx(
        GRID_MM / PITCH_PX, rel=1e-15)  # one division: rounding only
    # two pitches 0.5 % apart (a slightly oblique view): their mean
    lat = Lattice.from_pitch(5.0, pitch2=5.025)
    assert lat.pixel_size(1.0) == pytest.approx(1 / 5.0125, rel=1e-15)


@pytest.mark.parametrize("bad", [0.0, -0.2, float("nan")])
def test_lattice_pixel_size_refuses_a_pitch_that_is_not_a_length(bad):
    with pytest.raises(ValueError, match="grid_pitch"):
        Lattice.from_pitch(5.0).pixel_size(bad)


def test_lattice_pixel_size_refuses_two_different_pitches():
    with pytest.raises(ValueError, match=r"differ by 4\.8%.*pixel size itself"):
        Lattice.from_pitch(5.0, pitch2=5.25).pixel_size(0.2)


def test_reference_lattice_is_the_detected_pitch(series):
    lat = reference_lattice(series / "ref.tif")
    # detection on 12-bit noise: ~5e-6 relative at 512 px, a few 1e-5 on 128 x 160
    assert lat.pitches == pytest.approx((PITCH_PX, PITCH_PX), rel=1e-4)


def test_measure_grid_pitch_sets_the_pixel_size(series, tmp_path, capsys):
    out = tmp_path / "maps.h5"
    rc = _run(["measure", series / "ref.tif", series / "load.tif", "-o", out,
               "--grid-pitch", GRID_MM, "--unit", "mm", "--quiet", "--lossless"])
    assert rc == 0, capsys.readouterr().err
    with h5py.File(out, "r") as h5:
        ps = float(h5.attrs["pixel_size"])
        assert h5.attrs["unit"] == "mm"
        # the detected pitch carries the detection's error, ~1e-5 relative
        assert ps == pytest.approx(GRID_MM / PITCH_PX, rel=1e-4)
        np.testing.assert_allclose(h5["ux_phys"][()], ps * h5["ux"][()], rtol=1e-12)
    # the run's stored configuration replays it: the same pixel size
    again = tmp_path / "again.h5"
    assert _run(["measure", "--config", out, "-o", again, "--quiet"]) == 0
    with h5py.File(again, "r") as h5:
        assert float(h5.attrs["pixel_size"]) == ps


def test_measure_grid_pitch_with_a_given_pitch_is_exact(series, tmp_path, capsys):
    out = tmp_path / "maps.h5"
    rc = _run(["measure", series / "ref.tif", series / "load.tif", "-o", out,
               "--pitch", PITCH_PX, "--grid-pitch", GRID_MM, "--unit", "mm", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    with h5py.File(out, "r") as h5:
        assert float(h5.attrs["pixel_size"]) == pytest.approx(GRID_MM / PITCH_PX,
                                                              rel=1e-15)


@pytest.mark.parametrize(("extra", "message"), [
    (["--grid-pitch", "0.2"], "--grid-pitch and --unit go together"),
    (["--grid-pitch", "0.2", "--pixel-size", "0.04", "--unit", "mm"],
     "--pixel-size or --grid-pitch, not both"),
    (["--grid-pitch", "-0.2", "--unit", "mm"], "--grid-pitch"),
])
def test_measure_grid_pitch_errors_are_one_line(series, tmp_path, capsys, extra, message):
    out = tmp_path / "maps.h5"
    rc = _run(["measure", series / "ref.tif", series / "load.tif", "-o", out, "--quiet",
               *extra])
    err = capsys.readouterr().err
    assert rc != 0
    assert message in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()
