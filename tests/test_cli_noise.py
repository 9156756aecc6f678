"""``gridstrain noise`` on a generated static stack."""

import json

import numpy as np
import pytest
import tifffile

from findings import said
from gridstrain import Lattice, __version__
from gridstrain.cli import main
from gridstrain.io import read_hdf5
from gridstrain.models import synthetic


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    """40 frames, case-2 vibrations, 12-bit noise (K=0.28, L=5) stored x16."""
    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(3)
    frames, shifts = [], []
    for _ in range(40):
        a, b = rng.normal(0, 0.1), rng.normal(0, 0.05)
        shifts.append((a, b))
        s = synthetic.grid_image((160, 160), lat, amplitude=2000.0,
                                 displacement=lambda X, Y, a=a, b=b: (-a + 0 * X, -b + 0 * Y))
        frames.append(synthetic.add_noise(s, rng=rng) * 16)
    path = tmp_path_factory.mktemp("noise") / "stack.tif"
    tifffile.imwrite(path, np.array(frames, dtype=np.uint16))
    return path, np.array(shifts)


def test_noise_report(stack, tmp_path, capsys):
    stack, shifts = stack
    out = tmp_path / "rep.h5"
    assert main(["noise", str(stack), "-o", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "K = " in text
    assert "noise floor" in text
    rep = read_hdf5(out)
    assert rep["attrs"]["gridstrain_version"] == __version__
    assert rep["attrs"]["numpy"] == np.__version__
    noise = rep["attrs"]["noise"]
    # K from 40 frames of 160^2: ~1 % statistical error (tests/test_noise.py); the
    # x16 storage is undone in sensor units
    assert noise["K_sensor"] == pytest.approx(0.28, rel=0.05)
    measured = rep["datasets"]["vibration/shifts"]
    # the carrier-phase estimate is good to ~1e-3 px per frame at this size and noise
    np.testing.assert_allclose(measured, shifts - shifts.mean(axis=0), atol=4e-3)
    np.testing.assert_allclose(rep["attrs"]["vibration"]["std_px"], shifts.std(axis=0, ddof=1),
                               atol=1e-3)


def test_noise_json_and_floor_scales_as_one_over_sqrt_T(stack, capsys):
    stack, _ = stack
    floors = []
    for T in (4, 16):
        assert main(["noise", str(stack), "--json", "--T", str(T)]) == 0
        floors.append(json.loads(capsys.readouterr().out)["noise_floor"])
    # Prop. 2.3: the noise variance falls as 1/T, so the std halves from T=4 to 16
    ratio = np.array(floors[0]["strain_std"]) / np.array(floors[1]["strain_std"])
    np.testing.assert_allclose(ratio, 2.0, rtol=1e-9)


@pytest.mark.parametrize(
    ("argv", "match"),
    [(["noise", "missing.tif"], "missing.tif"),
     (["noise", "STACK", "-o", "out.txt"], "must end in"),
     (["noise", "STACK", "--T", "0"], "--T"),
     (["noise", "STACK", "--k1", "0.2", "0"], "--k1 and --k2")],
)
def test_noise_bad_input(stack, tmp_path, capsys, argv, match, monkeypatch):
    stack, _ = stack
    monkeypatch.chdir(tmp_path)
    argv = [str(stack) if a == "STACK" else a for a in argv]
    assert main([*argv, "--quiet"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("gridstrain noise: error:")
    assert match in err[0]
    assert not (tmp_path / "out.txt").exists()


def test_short_stack_uses_the_degree_it_allows(stack, tmp_path, capsys):
    stack, _ = stack
    import tifffile as tf

    short = tmp_path / "short.tif"
    tf.imwrite(short, tf.imread(stack)[:10])
    assert main(["noise", str(short), "--json"]) == 0
    noise = json.loads(capsys.readouterr().out)["noise"]
    # 10 frames: the shifts and the first-order harmonics (7 regressors with the
    # mean) are the most that leave 3 dof; the fit keeps what lowers the residual
    assert noise["vibration_model_degree"] is None
    assert len(noise["vibration_terms"]) <= 6
    assert noise["vibration_terms"][:2] == ["x", "y"]
    # 10 frames of 160^2 still pin K to a few per cent (tests/test_noise.py)
    assert noise["K_sensor"] == pytest.approx(0.28, rel=0.1)
    assert main(["noise", str(short), "--degree", "3", "--quiet"]) == 2
    assert "13 frames" in capsys.readouterr().err


def test_stack_noise_file_is_a_camera_model(stack, tmp_path):
    """The .h5 of a stack is what ``measure --noise`` reads, with its units."""
    from gridstrain.io import read_noise_model

    stack, _ = stack
    out = tmp_path / "cam.h5"
    assert main(["noise", str(stack), "-o", str(out), "--quiet"]) == 0
    model = read_noise_model(out)
    assert model.method == "stack"
    assert model.scale == 16
    assert model.bit_depth == 12
    # K from 40 frames of 160^2: ~1 % statistical error
    assert model.K_sensor == pytest.approx(0.28, rel=0.05)
    # a result that is not a noise model is refused by name
    with pytest.raises(ValueError, match="not a noise result"):
        read_noise_model(_not_noise(tmp_path))


def _not_noise(tmp_path):
    from gridstrain.io import write_hdf5

    return write_hdf5(tmp_path / "other.h5", {"x": np.zeros(3)}, {"K": 1.0})


@pytest.mark.parametrize("vibration", [0.0, 0.1, 0.3, 0.5])
def test_noise_of_a_vibrated_stack(tmp_path, capsys, vibration):
    """A stack vibrating rigidly by 0 to 0.5 px (std): the camera's K and L as
    without vibrations (the carriers' harmonics regress the grid's motion out)."""
    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(21)
    frames = []
    for a, b in rng.normal(0, vibration, (40, 2)):
        s = synthetic.grid_image((128, 128), lat, amplitude=2000.0,
                                 displacement=lambda X, Y, a=a, b=b: (-a + 0 * X, -b + 0 * Y))
        frames.append(synthetic.add_noise(s, K=0.28, L=5.0, rng=rng))
    path = tmp_path / "vib.tif"
    tifffile.imwrite(path, np.array(frames, dtype=np.uint16))
    assert main(["noise", str(path), "--json"]) == 0
    noise = json.loads(capsys.readouterr().out)["noise"]
    # K: 40 frames of 128^2 give a standard error under 1 % (tests/test_noise.py)
    assert noise["K"] == pytest.approx(0.28, rel=0.03)
    # L (5 plus the rounding's 1/12): its 95 % interval holds it, and that interval is
    # a statistical one (half-width 8 to 11 grey levels^2 here), not an excuse for
    # the vibrations' 100+ of a polynomial model
    lo, hi = noise["L_ci"]
    assert lo <= 5.0 + 1 / 12 <= hi
    assert hi - lo < 30


def test_a_frame_of_another_state_is_excluded_and_named(tmp_path, capsys):
    """A static stack with one frame of the loaded specimen (a strain of 3e-3) among
    them: its change is not a rigid vibration, which the estimate regresses out, and
    would pass for noise; it is screened out and named."""
    from gridstrain.uncertainty import estimate_noise

    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(8)
    frames = []
    for t in range(16):
        a, e = rng.normal(0, 0.05), (3e-3 if t == 5 else 0.0)
        s = synthetic.grid_image((160, 160), lat, amplitude=2000.0,
                                 displacement=lambda X, Y, a=a, e=e: (-a + e * (X - 80),
                                                                      0 * Y))
        frames.append(synthetic.add_noise(s, rng=rng) * 16)
    frames = np.array(frames, dtype=np.uint16)
    path = tmp_path / "foreign.tif"
    tifffile.imwrite(path, frames)
    assert main(["noise", str(path), "--json"]) == 0
    out = capsys.readouterr()
    summary = json.loads(out.out)
    assert "frame 5" in out.err
    assert "another state" in out.err
    assert summary["n_frames"] == 15
    (excluded,) = said(summary, "screening.flagged")
    assert "excluded 1 of 16 frames" in excluded
    # the camera's gain, as without that frame (5 %: the statistical error of 15
    # frames of 160^2 is about 1 %)
    assert summary["noise"]["K_sensor"] == pytest.approx(0.28, rel=0.05)
    # and the frame would have biased it: the same estimate with the frame kept
    kept = estimate_noise(frames.astype(float), lat, saturation=65535, scale=16)
    assert abs(kept.K_sensor / 0.28 - 1) > 0.08


def test_how_the_frames_were_read_is_said_by_code(tmp_path, capsys):
    """A colour stack is converted to grey before its noise is estimated: the command
    says so, on stderr and in its JSON summary, as a finding of code ``input``."""
    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(2)
    grey = [np.clip(synthetic.add_noise(synthetic.grid_image((160, 160), lat, amplitude=100.0),
                                        rng=rng), 0, 255) for _ in range(4)]
    rgb = np.array([np.stack([g, g, g], axis=-1) for g in grey]).astype(np.uint8)
    path = tmp_path / "rgb.tif"
    tifffile.imwrite(path, rgb, photometric="rgb")
    assert main(["noise", str(path), "--json"]) == 0
    out = capsys.readouterr()
    summary = json.loads(out.out)
    (colour,) = said(summary, "input")
    assert "colour frames (RGB)" in colour
    assert "colour frames (RGB)" in out.err
    (record,) = [f for f in summary["findings"] if f["code"] == "input"]
    assert record["figures"] == {"reading": "colour", "channels": 3}
