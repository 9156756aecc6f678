"""Large rotations and homogeneous strains through ``gridstrain measure``.

A state rotated or strained homogeneously has its grid's carrier moved by ``|k|
(strain + rotation)``: its frames are probed and transformed at its own carrier
(gridstrain.phase.follow_lattice) and its maps brought to the reference's
lattice. Images from the independent generator (tests/independent_grid.py), 12-bit
Poisson-Gaussian noise, lighting falling to 40 %, 160 x 200 px, pitch 5 px.
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from findings import said
from gridstrain import detect_lattice, load, measure, wft
from gridstrain.cli import main
from gridstrain.kinematics import grid_shows
from gridstrain.phase import Lattice, follow_lattice
from independent_grid import camera, scene

H, W = 160, 200
C = ((W - 1) / 2, (H - 1) / 2)


def _rotation(deg):
    t = np.deg2rad(deg)

    def disp(X, Y):
        dx, dy = X - C[0], Y - C[1]
        return ((np.cos(t) - 1) * dx - np.sin(t) * dy, np.sin(t) * dx + (np.cos(t) - 1) * dy)
    return disp


def _strain(e, nu=0.3):
    def disp(X, Y):
        return e * (X - C[0]), -nu * e * (Y - C[1])
    return disp


def _pair(tmp_path, disp, *, pitch=5.0, pitch_def=None, seed=1, hole=False):
    ref, _ = scene((H, W), pitch=pitch, angle=0, hole=hole)
    cur, _ = scene((H, W), pitch=pitch if pitch_def is None else pitch_def, angle=0,
                   hole=hole, displacement=disp)
    rng = np.random.default_rng(seed)
    paths = tmp_path / "ref.tif", tmp_path / "def.tif"
    for p, img in zip(paths, (ref, cur), strict=True):
        tifffile.imwrite(p, camera(img, 0.3, 4.0, rng), photometric="minisblack")
    return paths


def _measure(tmp_path, paths):
    out = tmp_path / "maps.h5"
    code = main(["measure", str(paths[0]), str(paths[1]), "-o", str(out), "--quiet",
                 "--overwrite"])
    assert code == 0
    return load(out)


@pytest.mark.parametrize(("name", "disp", "hole"), [
    ("rotation 2 deg", _rotation(2.0), False), ("rotation 5 deg", _rotation(5.0), False),
    ("rotation 10 deg", _rotation(10.0), False), ("strain 3.5 %", _strain(0.035), False),
    ("strain 10 %", _strain(0.10), False), ("strain -10 %", _strain(-0.10, nu=-1.0), False),
    # a hole off the centre moves by 4 px under the 10 % strain while the field's
    # median does not: compared as a rigid shift its image would put u a period off
    ("strain 10 %, hole", _strain(0.10), True),
    ("rotation 10 deg, hole", _rotation(10.0), True)])
def test_cli_measures_large_rotations_and_strains(tmp_path, name, disp, hole):
    res = _measure(tmp_path, _pair(tmp_path, disp, hole=hole))
    v = res.valid[0]
    # the 4-sigma borders' band leaves ~58 % of the frame, ~45 % with the hole
    assert v.mean() > 0.35
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    err = np.stack(res.u[0]) - np.stack(disp(xx, yy))
    std = np.stack([res.uncertainty["ux_std"][0], res.uncertainty["uy_std"][0]])
    # no whole period off anywhere (a period is 5 px)
    assert np.abs(err[:, v]).max() < 0.1
    # the sensor noise alone gives a median |error| of 0.67 x 2.7e-3 px; 0.05 px is
    # the acceptance figure
    assert np.median(np.abs(err[:, v])) < 0.05
    # the stated std holds: a Gaussian leaves 6e-7 of its values beyond 5 std; 2 %
    # is the acceptance figure (measured: none)
    assert np.mean(np.any(np.abs(err[:, v]) > 5 * std[:, v], axis=0)) <= 0.02
    corrected = said(res.warnings, "fringe_order.corrected")
    if name == "rotation 10 deg, hole":
        # the smallest displacement is a period off here (the hole's content moved 5 px
        # from the field's median): the deformed image warped back shows it, the field
        # is corrected (the errors above), and the result says so by its code; its
        # offset is a whole period, 5 px, to a tenth of one
        (told,) = corrected
        assert np.hypot(*told.figures["offset_px"]) == pytest.approx(5.0, abs=0.5)
    else:
        assert not corrected


def test_follow_lattice_finds_a_rotated_and_strained_grid():
    lat = Lattice.from_pitch(5.0)
    img, _ = scene((H, W), pitch=5.0 * 1.08, angle=7.0, hole=False, light=False)
    own = follow_lattice(img, lat)
    # a grid of pitch 5.4 px at 7 degrees: to 1e-3 px and 0.01 degree (noise-free,
    # the refinement of detect_lattice)
    assert own.pitches == pytest.approx((5.4, 5.4), abs=1e-3)
    assert own.angles == pytest.approx((7.0, 97.0), abs=1e-2)
    with pytest.raises(ValueError, match="no grid within"):
        follow_lattice(img, Lattice.from_pitch(5.0, angle=45.0), max_change=0.1)


def test_a_pair_of_other_grids_is_named(tmp_path, capsys):
    # a reference of pitch 5 against a state of pitch 5.9: an 18 % stretch, more than
    # a plausible strain
    paths = _pair(tmp_path, None, pitch_def=5.9)
    res = _measure(tmp_path, paths)
    (carrier,) = said(res.warnings, "carrier.implausible")
    assert str(paths[1]) in carrier
    assert "+18.0%" in carrier
    # a 10 % strain is not
    res = _measure(tmp_path, _pair(tmp_path, _strain(0.10)))
    assert not said(res.warnings, "carrier.implausible")


def test_demodulated_in_place_is_demodulated_at():
    """A state's maps brought to the reference's carrier over their own memory are
    those of the copying function bit for bit, read-only again, and a view (memory
    it does not own) is copied rather than written over."""
    from gridstrain.phase import PhaseMaps, demodulated_at, demodulated_in_place, wft
    from gridstrain.phase.lattice import Carrier

    img, _ = scene((96, 128), pitch=5.0, angle=10.0, hole=False)
    lat = Lattice.from_pitch(5.0, angle=10.0)
    k = lat.K @ np.array([[1.01, 0.02], [-0.02, 1.01]])  # stretched 1 % and turned
    own = Carrier(tuple(k[0]), tuple(k[1]), window_pitch=lat.pitch)
    want = demodulated_at(wft(img, own), lat)
    got = demodulated_in_place(wft(img, own), lat)
    np.testing.assert_array_equal(got.psi, want.psi)
    np.testing.assert_array_equal(got.dphi, want.dphi)
    assert not got.psi.flags.writeable
    pm = wft(img, own)
    view = PhaseMaps(psi=pm.psi[:, :, :], dphi=pm.dphi, valid=pm.valid, lattice=own,
                     sigma=pm.sigma)
    before = np.array(pm.psi)
    np.testing.assert_array_equal(demodulated_in_place(view, lat).psi, want.psi)
    np.testing.assert_array_equal(pm.psi, before)  # the viewed maps left alone


def test_the_grid_modulus_shows_a_rotated_field_a_period_off_past_a_wide_margin():
    # the field is carried across the invalid margin round the hole to first order: as
    # a constant it puts the hole's edge, the modulus's strongest content, 0.3 to 0.5
    # period off at 10 degrees and 3 pitches, and half periods are favoured
    rng = np.random.default_rng(1)
    ref, _ = scene((H, W), pitch=5.0, angle=0, hole=True)
    cur, _ = scene((H, W), pitch=5.0, angle=0, hole=True, displacement=_rotation(10.0))
    ref, cur = (camera(img, 0.3, 4.0, rng) for img in (ref, cur))
    lat = detect_lattice(ref)
    pr, pc = wft(ref, lat), wft(cur, lat)
    m = measure(ref, cur, lattice=lat)
    valid = ndimage.binary_erosion(m.valid, iterations=15)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    t = np.deg2rad(10.0)
    period = 5.0 * np.array([-np.sin(t), np.cos(t)])  # the rotated grid's a2
    u = np.stack(_rotation(10.0)(xx, yy)) + period[:, None, None]
    shown, said = grid_shows(pr, pc, u, valid, (0, -1))
    assert shown, said


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_demodulated_at_multiplies_by_the_carriers_change(monkeypatch, compiled, dtype):
    """``Psi exp(2 i pi (k - k') . x)`` against the product written here with one
    complex exponential per pixel (float64), in the compiled loop and in numpy: within
    16 ulp of |Psi| in the maps' precision (a phase of 4e-15 rad in float64, 2e-6 in
    float32: the rounding of the exponentials' arguments, up to 3 rad here, and of the
    two products; a wrong sign or axis is off by the whole change), the derivatives
    moved by ``2 pi (k - k')``."""
    from gridstrain.phase import _maps, demodulated_at, wft
    from gridstrain.phase.lattice import Carrier

    if compiled and _maps._load_kernels() is None:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(_maps, "_COMPILED", compiled)
    img, _ = scene((64, 90), pitch=5.0, angle=10.0, hole=False)
    lat = Lattice.from_pitch(5.0, angle=10.0)
    k = lat.K @ np.array([[1.02, 0.01], [-0.03, 0.99]])
    own = Carrier(tuple(k[0]), tuple(k[1]), window_pitch=lat.pitch)
    pm = wft(img.astype(dtype), own)
    got = demodulated_at(pm, lat)
    yy, xx = np.mgrid[0:64, 0:90].astype(float)
    dk = np.array(own.K) - np.array(lat.K)
    for j in range(2):
        want = pm.psi[j].astype(np.complex128) * np.exp(2j * np.pi * (dk[j, 0] * xx
                                                                      + dk[j, 1] * yy))
        ulp = np.finfo(dtype).eps * np.abs(want)
        assert np.all(np.abs(got.psi[j] - want) <= 16 * ulp + 1e-300)
        for a in range(2):
            np.testing.assert_allclose(got.dphi[j, a], pm.dphi[j, a] + 2 * np.pi * dk[j, a],
                                       rtol=0, atol=4 * np.finfo(dtype).eps)
