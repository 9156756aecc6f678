"""Acceptance: the command line against photographs it was not written for.

Every case writes image files with the camera of ``tests/world_camera.py`` (its own
model of a printed grid, a lens, lighting fixed to the camera and a 12-bit sensor;
nothing shared with gridstrain.models.synthetic), runs ``python -m gridstrain.cli measure
REF DEF -o out.h5 --json --quiet`` in a subprocess with the default options unless a
user would obviously give one, loads the result file and compares it with the
imposed displacement, at the reference's pixels (Lagrangian).

Frames 200 x 260 px, grid pitch 6.4 px turned by 0.6 degree (5.0 px, or a
checkerboard of squares of 4.5 px, where said), one photograph per state, so the
noise is estimated from the image itself. The pitch is above 6 px so that the
largest crack's faces, moved by 3 px each way, stay within half a period of the
start. Cases that gridstrain fails are marked ``xfail(strict=True)`` with what is
wrong: once fixed they pass, and the mark must go.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

import gridstrain
from findings import said
from gridstrain.results import load
from world_camera import (
    Specimen,
    compose,
    edge_crack,
    expected_levels,
    photograph,
    rotation,
    strain_bands,
    strain_bump,
    stretch,
)

H, W = 200, 260
CENTRE = ((W - 1) / 2, (H - 1) / 2)
PITCH = 6.4
# the checkerboard's squares are 4.5 px: its fundamental pitch along the diagonals
# is 9 / sqrt(2) = 6.36 px, the grid's to 1 %
CHECKER = 9.0
SRC = str(Path(gridstrain.__file__).resolve().parents[1])


def _measure(tmp, *args):
    """``gridstrain measure ARGS -o out.h5 --json --quiet`` run in ``tmp``: the
    finished process and the result's path."""
    out = tmp / "out.h5"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [SRC, *filter(None, [os.environ.get("PYTHONPATH")])]))
    proc = subprocess.run([sys.executable, "-m", "gridstrain.cli", "measure", *map(str, args),
                           "-o", str(out), "--json", "--quiet"],
                          capture_output=True, text=True, env=env, cwd=tmp, timeout=1800)
    return proc, out


def _run(tmp, *args):
    """``gridstrain measure ARGS -o out.h5 --json --quiet``: (JSON summary, result)."""
    proc, out = _measure(tmp, *args)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout), load(out)


def _pair(tmp, disp, *, kind="grid", pitch=PITCH, seed=0, other=None):
    """Reference and deformed photographs as TIFFs; ``other`` photographs another
    specimen as the deformed one."""
    rng = np.random.default_rng(seed + 100)
    spec = Specimen((H, W), pitch=pitch, kind=kind, seed=seed)
    paths = tmp / "ref.tif", tmp / "def.tif"
    tifffile.imwrite(paths[0], photograph(spec, rng=rng))
    tifffile.imwrite(paths[1], photograph(other or spec, disp, rng=rng))
    return paths


def _errors(res, state, disp):
    """``(2, n)`` displacement errors at the valid pixels, px, and their stated std."""
    v = np.asarray(res.valid[state])
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    truth = np.stack(disp(xx, yy))
    err = np.stack([np.asarray(res.u[state][k]) for k in (0, 1)]) - truth
    unc = res.uncertainty
    std = np.stack([np.asarray(unc["ux_std"][state]), np.asarray(unc["uy_std"][state])])
    return err[:, v], std[:, v], v


def _figures(res, state, disp):
    err, std, v = _errors(res, state, disp)
    return {
        "valid": int(v.sum()),
        "max_err_px": float(np.abs(err).max()),
        "median_err_px": float(np.median(np.hypot(*err))),
        "beyond_5_std": float(np.mean(np.any(np.abs(err) > 5 * std, axis=0))),
        "median_std_px": float(np.median(std)),
    }


def _check_homogeneous(fig, pitch, record_property):
    for k, v in fig.items():
        record_property(k, v)
    # a whole period off shows as an error of a pitch; half of it cannot be noise
    # (the stated std is 3e-3 px)
    assert fig["max_err_px"] < pitch / 2, fig
    # 0.05 px, a twentieth of a pixel: more than ten times the noise (3e-3 px std)
    # and the aliasing at this pitch; a median beyond it is an error of the method
    assert fig["median_err_px"] <= 0.05, fig
    # a stated std that holds: 5 std is exceeded by 6e-7 of Gaussian noise; 2 %
    # leaves room for the window's bias where lighting and print vary
    assert fig["beyond_5_std"] <= 0.02, fig


# --- quick cases -----------------------------------------------------------------

@pytest.fixture(scope="module")
def rotated_2deg(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rot2")
    disp = rotation(2.0, CENTRE)
    summary, res = _run(tmp, *_pair(tmp, disp))
    return summary, res, disp


def test_a_2_degree_rotation_is_measured(rotated_2deg, record_property):
    _, res, disp = rotated_2deg
    _check_homogeneous(_figures(res, 0, disp), PITCH, record_property)


def test_the_spatial_resolution_is_13_69_sigma(rotated_2deg):
    summary, res, _ = rotated_2deg
    # d = pi sigma sqrt(2 / ln(1/0.9)) = 13.69 sigma; 2 % is the rounding of 13.69
    # many times over, and far below a wrong definition (FWHM 2.355 sigma)
    assert summary["metrology"]["spatial_resolution_px"] == pytest.approx(
        13.69 * res.sigma, rel=0.02)
    assert summary["noise_floor"]["spatial_resolution_px"] == pytest.approx(
        13.69 * res.sigma, rel=0.02)


def test_a_pair_of_different_specimens_is_named(tmp_path):
    # pitches 13 % apart: a strain a test rarely reaches homogeneously
    other = Specimen((H, W), pitch=PITCH * 1.13, seed=7)
    paths = _pair(tmp_path, None, other=other)
    proc, out = _measure(tmp_path, *paths)
    if proc.returncode == 0:  # measured: one warning names the state's file and the reference
        summary = json.loads(proc.stdout)
        mismatch = said(summary, "pair.mismatch")
        assert [w for w in mismatch if "def.tif" in w and "reference" in w], summary["warnings"]
    else:  # refused: one line naming both files, and no result
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1, proc.stderr
        assert "ref.tif" in lines[0], lines[0]
        assert "def.tif" in lines[0], lines[0]
        assert not out.exists()


# --- rigid rotations and homogeneous strains -------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize(("deg", "kind"), [(3.5, "grid"), (5.0, "grid"), (3.5, "checker")])
def test_rotations(tmp_path, deg, kind, record_property):
    disp = rotation(deg, CENTRE)
    pitch = CHECKER if kind == "checker" else PITCH
    _, res = _run(tmp_path, *_pair(tmp_path, disp, kind=kind, pitch=pitch, seed=1))
    _check_homogeneous(_figures(res, 0, disp), res.lattice.pitch, record_property)


@pytest.mark.slow
@pytest.mark.parametrize(("exx", "eyy", "kind"), [
    (0.02, -0.006, "grid"), (0.035, -0.0105, "grid"), (0.05, -0.015, "grid"),
    (0.05, 0.05, "grid"), (0.035, 0.035, "checker")])
def test_homogeneous_strains(tmp_path, exx, eyy, kind, record_property):
    disp = stretch(exx, eyy, CENTRE)
    pitch = CHECKER if kind == "checker" else PITCH
    _, res = _run(tmp_path, *_pair(tmp_path, disp, kind=kind, pitch=pitch, seed=2))
    _check_homogeneous(_figures(res, 0, disp), res.lattice.pitch, record_property)



@pytest.mark.slow
def test_a_grid_of_narrow_lines_at_pitch_5(tmp_path, record_property):
    disp = stretch(0.02, -0.006, CENTRE)
    summary, res = _run(tmp_path, *_pair(tmp_path, disp, pitch=5.0, seed=1))
    err, std, _ = _errors(res, 0, disp)
    alias = summary["systematic_errors"]["aliasing"]["u_px"]
    beyond = float(np.mean(np.any(np.abs(err) > 5 * std + alias, axis=0)))
    record_property("aliasing_bound_px", alias)
    record_property("median_err_px", float(np.median(np.hypot(*err))))
    record_property("beyond_5_std_plus_bound", beyond)
    # what gridstrain states at a pixel: the noise's std, and a bound on the
    # harmonics' aliasing beside it; 2 % as for the pairs above
    assert beyond <= 0.02, (beyond, alias)
    # a median error six times the noise std (0.004 px) is said, not only bounded
    assert said(summary, "aliasing.bound")

# --- an edge crack ---------------------------------------------------------------

Y_CRACK, X_TIP = 94.3, 130.0


@pytest.mark.slow
@pytest.mark.parametrize("opening", [0.5, 2.0, 6.0, 8.0])
def test_an_edge_crack(tmp_path, opening, record_property):
    disp = edge_crack(opening, Y_CRACK, X_TIP)
    summary, res = _run(tmp_path, *_pair(tmp_path, disp, seed=3))
    fig = _figures(res, 0, disp)
    jumps = said(summary, "jump.found")
    for k, v in fig.items():
        record_property(k, v)
    record_property("discontinuities", len(res.discontinuities[0]))
    assert fig["max_err_px"] < PITCH / 2, fig  # no side of the crack a period off
    # 0.2 %: the pixels whose window reaches the crack are left out; those left may
    # hold what the window's tails see of it, not more (5 std: 6e-7 of Gaussian noise)
    assert fig["beyond_5_std"] <= 0.002, fig
    assert jumps, summary["warnings"]
    assert res.discontinuities[0], "no discontinuity in the result"


# --- the window's smoothing of strain gradients ----------------------------------

def _peak_error(err, valid, axis):
    """Largest |median error| along a band (the median over ``axis`` removes the
    noise, leaving the window's bias); lines with fewer than 30 valid pixels are
    skipped."""
    e = np.where(valid, err, np.nan)
    keep = valid.sum(axis=axis) >= 30
    prof = np.nanmedian(e[:, keep] if axis == 0 else e[keep], axis=axis)
    return float(np.abs(prof).max())


@pytest.mark.slow
@pytest.mark.parametrize("widths", [1.5, 2.0])
def test_the_smoothing_bound_bounds_gaussian_bands(tmp_path, widths, record_property):
    # sigma is the detected pitch by default: the bands are drawn at widths x pitch
    # and their width in window sigmas is read back from the result
    amplitude = 0.02
    disp, strain = strain_bands(amplitude, widths * PITCH, CENTRE)
    summary, res = _run(tmp_path, *_pair(tmp_path, disp, seed=4))
    width = widths * PITCH / res.sigma
    record_property("width_sigma", width)
    assert width == pytest.approx(widths, rel=0.01)  # the detected pitch to 1 %
    v = np.asarray(res.valid[0])
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    truth = strain(xx, yy)
    bound = summary["systematic_errors"]["smoothing"][0]["max"]
    for i, axis in ((0, 0), (1, 1), (2, 1)):  # e_xx varies along x: median over rows
        err = np.asarray(res.strain[0][i]) - truth[i]
        actual = _peak_error(err, v, axis)
        record_property(f"peak_error_{i}", actual)
        record_property(f"bound_{i}", bound[i])
        # the bound states at most the peak error, and at most four times it: a
        # bound far above is no figure a user can use (the documented 1.2 to 2.5)
        assert 1.0 <= bound[i] / actual <= 4.0, (i, bound[i], actual)



BUMP = (130.0, 100.0)  # a pixel: the bump's peak error is read there


@pytest.mark.slow
@pytest.mark.parametrize("widths", [1.5, 2.0])
def test_the_smoothing_bound_bounds_a_round_bump(tmp_path, widths, record_property):
    disp, strain = strain_bump(0.02, widths * PITCH, BUMP)
    summary, res = _run(tmp_path, *_pair(tmp_path, disp, seed=4))
    width = widths * PITCH / res.sigma
    record_property("width_sigma", width)
    assert width == pytest.approx(widths, rel=0.01)  # the detected pitch to 1 %
    i, j = int(BUMP[1]), int(BUMP[0])
    yy, xx = np.mgrid[i - 1:i + 2, j - 1:j + 2].astype(np.float64)
    truth = strain(xx, yy)[0]
    # the 3 x 3 pixels at the peak: the window lowers it by 2 % x sigma²/(w² + sigma²),
    # 6e-3 and 4e-3, against a strain noise of 3e-4 a pixel
    actual = float(np.median(np.abs(np.asarray(res.strain[0][0])[i - 1:i + 2, j - 1:j + 2]
                                    - truth)))
    bound = summary["systematic_errors"]["smoothing"][0]["max"][0]
    record_property("peak_error", actual)
    record_property("bound", bound)
    assert 1.0 <= bound / actual <= 4.0, (bound, actual)  # as for the bands


@pytest.mark.slow
def test_a_strain_concentration_is_not_a_crack(tmp_path, record_property):
    disp, _ = strain_bump(0.03, 2.0 * PITCH, BUMP)
    summary, res = _run(tmp_path, *_pair(tmp_path, disp, seed=4))
    record_property("valid", int(np.asarray(res.valid[0]).sum()))
    record_property("discontinuities", len(res.discontinuities[0]))
    assert not res.discontinuities[0], res.discontinuities[0]
    assert not said(summary, "jump.found", "jump.part"), summary["warnings"]

# --- a stained checkerboard moved by almost two periods ---------------------------

class _Stained(Specimen):
    """A checkerboard without sharp defects, stained by two broad blots of
    reflectance (+10 % over a std of 30 px, -8 % over 20 px) that move with it: content
    below the grid's frequency that a lamp's hot spot, moved with the specimen, would
    imitate exactly (the performance pair's family, ``benchmarks/bench_pair.py``)."""

    def __init__(self, shape, **kw):
        super().__init__(shape, **kw)
        none = (np.zeros((0, 2)), np.zeros(0))
        self.blots = self.gaps = self.dust = none

    def reflectance(self, X, Y):
        stains = (1 + 0.1 * np.exp(-((X - 0.25 * W) ** 2 + (Y - 0.4 * H) ** 2) / (2 * 30.0**2))
                  - 0.08 * np.exp(-((X - 0.65 * W) ** 2 + (Y - 0.6 * H) ** 2) / (2 * 20.0**2)))
        return super().reflectance(X, Y) * stains


@pytest.mark.parametrize("seed", [1, 2])
def test_a_stained_checkerboard_moved_by_11_px_is_measured_not_confirmed(tmp_path, seed):
    # a checkerboard of fundamental pitch 6 px (squares of 4.24 px) turned by 12 degrees,
    # moved by (8, -7.5) px, 1.8 periods, and strained (exx 2e-3, eyy -3e-3, exy 5e-4).
    # Only the stains fix the whole periods: the image's content and the grid's modulus
    # both show them, nothing on the specimen's side says otherwise; a checkerboard has
    # no second harmonic and its grid vanishes nowhere, so nothing the light cannot
    # imitate shows them either. The displacement they support is taken, and it is
    # not confirmed. (Both seeds were a period off, 9.47 px RMS: the grid's vanishing
    # places, one constant in both images, "favoured" another offset by the ratios of
    # rounding errors; and whole periods the modulus showed were dropped where the
    # light might have moved.)
    def disp(X, Y):
        x, y = X - CENTRE[0], Y - CENTRE[1]
        return 8.0 + 2e-3 * x + 5e-4 * y, -7.5 + 5e-4 * x - 3e-3 * y

    spec = _Stained((H, W), pitch=6.0 * np.sqrt(2), angle=12.0 + 45.0, kind="checker",
                    seed=seed)
    rng = np.random.default_rng(seed + 100)
    paths = tmp_path / "ref.tif", tmp_path / "def.tif"
    tifffile.imwrite(paths[0], photograph(spec, rng=rng))
    tifffile.imwrite(paths[1], photograph(spec, disp, rng=rng))
    summary, res = _run(tmp_path, *paths)
    err, _, _ = _errors(res, 0, disp)
    # a period off is an error of 6 px; 0.02 px is ten times the noise of a 12-bit
    # photograph at this pitch (measured 2.4e-3 px RMS) and the window's bias of a
    # homogeneous strain (none)
    assert np.sqrt(np.mean(err**2)) < 0.02
    assert np.abs(err).max() < 0.1  # no pixel whole periods off, nor half way
    order = res.fringe_orders[0]
    assert order.source == "image features", order.detail
    # a lamp's hot spot moved with the specimen by whole periods reads the same:
    # not confirmed, and the warning says so and why
    assert not order.confirmed, order.detail
    doubt = said(summary, "fringe_order.unconfirmed")
    assert doubt, summary["warnings"]
    assert "could be the light" in doubt[0], doubt


# --- a load-step record ----------------------------------------------------------

N_FRAMES = 40


def _record_truth(t):
    """Frame ``t`` (0 the reference): a rigid drift of (0.3, -0.15) px a frame and a
    uniaxial strain growing to 3 % (Poisson's ratio 0.3) about the centre."""
    e = 0.03 * t / (N_FRAMES - 1)
    return compose(stretch(e, -0.3 * e, CENTRE),
                   lambda X, Y: (0.3 * t + 0 * X, -0.15 * t + 0 * Y))


@pytest.mark.slow
def test_a_record_with_loads_in_a_folder_of_unpadded_names(tmp_path, record_property):
    rec = tmp_path / "record"
    rec.mkdir()
    spec = Specimen((H, W), seed=5)
    rng = np.random.default_rng(105)
    for t in range(N_FRAMES):  # frame_1 ... frame_40: a plain sort puts frame_10 second
        iio.imwrite(rec / f"frame_{t + 1}.png",
                    photograph(spec, _record_truth(t) if t else None, rng=rng))
    loads = np.round(25.0 * np.arange(1, N_FRAMES) + rng.normal(0, 0.3, N_FRAMES - 1), 3)
    (tmp_path / "loads.csv").write_text("# load cell, 5 kN\nload [N]\n"
                                        + "".join(f"{v:.3f}\n" for v in loads))
    summary, res = _run(tmp_path, rec, "--each-frame", "--reference-frames", "1",
                        "--loads", "loads.csv", "--frame-rate", "1000")
    numbers = [int("".join(c for c in n.split("frame_")[-1] if c.isdigit()))
               for n in res.names[1:]]
    assert numbers == list(range(2, N_FRAMES + 1)), res.names
    assert res.state_order == "natural"
    assert res.load_unit == "N"
    np.testing.assert_allclose(res.load, loads, rtol=0, atol=1e-9)  # as written
    # frame t of the record (the reference is frame 0) at t / 1000 s
    np.testing.assert_allclose(res.time, np.arange(1, N_FRAMES) / 1000.0, rtol=1e-12)
    assert [s["load"] for s in summary["states"]] == pytest.approx(list(loads), abs=1e-9)
    assert [s["time_s"] for s in summary["states"]] == pytest.approx(
        list(np.arange(1, N_FRAMES) / 1000.0), rel=1e-12)
    figs = [_figures(res, s, _record_truth(s + 1)) for s in range(N_FRAMES - 1)]
    for k in ("median_err_px", "max_err_px", "beyond_5_std"):
        record_property(f"worst_{k}", max(f[k] for f in figs))
    for name, fig in zip(res.names[1:], figs, strict=True):
        assert fig["max_err_px"] < PITCH / 2, (name, fig)  # none a period off
        assert fig["median_err_px"] <= 0.05, (name, fig)  # as for the pairs above
        assert fig["beyond_5_std"] <= 0.02, (name, fig)  # as for the pairs above


# --- the camera itself -----------------------------------------------------------

def test_the_camera_moves_the_print_by_u():
    # the generator's own check, independent of gridstrain: a translation u moves
    # the fundamental's phase by -2 pi k.u (the print at x is the reference's at
    # x - u), read by a direct Hann-weighted Fourier sum at the printed wave vector
    spec = Specimen((H, W), seed=0)
    u = (1.3, -0.7)
    c, s = np.cos(spec.theta), np.sin(spec.theta)
    k = np.array([c, s]) / PITCH  # cycles/px, (x, y)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    win = np.outer(np.hanning(H), np.hanning(W))
    phase = []
    for disp in (None, lambda X, Y: (u[0] + 0 * X, u[1] + 0 * Y)):
        img = expected_levels(spec, disp)
        phase.append(np.angle(np.sum(win * img * np.exp(-2j * np.pi * (k[0] * xx + k[1] * yy)))))
    shift = np.angle(np.exp(1j * (phase[1] - phase[0])))
    # 2e-3 rad is 2e-3 px at this pitch: the print's defects and the lighting
    # leak this little into a Hann-weighted sum
    assert shift == pytest.approx(-2 * np.pi * (k[0] * u[0] + k[1] * u[1]), abs=2e-3)
