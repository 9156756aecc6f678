"""Method C (vibration-compensated averaging) against an independent grid generator.

The frames are made here with numpy alone (not with gridstrain.models.synthetic or
gridstrain.paper): ``s(x, y) = A (1 + gamma/2 (l(2 pi x / p + phi1) + l(2 pi y / p +
phi2)))`` with the paper's sharp ``l = sin^3`` profile (it has a third harmonic, which
the weighting must leave rejected), evaluated *exactly* at the shifted points
``(x + a, y + b)`` (frame ``t`` is ``s(x + a_t, y + b_t)``, the paper's eq. 2), or at
rotated points for the rigidity check. Sensor noise, where used, is Gaussian of
variance ``K s + L`` (the Poisson-Gaussian model), not quantised.
"""

import importlib
import math

import numpy as np
import pytest

from findings import said
from gridstrain import Lattice, theory, wft
from gridstrain.stacks import method_a, method_c, prefix_stacks

P = 5.0
LAT = Lattice.from_pitch(P)
A, GAMMA = 2000.0, 0.9
K, L = 0.28, 5.0


def grid(shape, shift=(0.0, 0.0), *, rotation=0.0, phases=False):
    """``s(x + a, y + b)``; with ``rotation`` (rad), the grid turned about the centre."""
    H, W = shape
    y, x = np.mgrid[0:H, 0:W].astype(float)
    xc, yc = (W - 1) / 2, (H - 1) / 2
    c, s = math.cos(rotation), math.sin(rotation)
    X = xc + c * (x - xc) - s * (y - yc) + shift[0]
    Y = yc + s * (x - xc) + c * (y - yc) + shift[1]
    p1 = 0.05 * np.sin(2 * np.pi * Y / 60) if phases else 0.0
    p2 = 0.3 * (X / W) ** 2 if phases else 0.0
    def ell(t):
        return 0.5 * np.sin(t) ** 3  # peak-to-peak 1, zero mean

    return A * (1 + GAMMA / 2 * (ell(2 * np.pi * X / P + p1) + ell(2 * np.pi * Y / P + p2)))


def noisy(img, rng):
    return img + rng.standard_normal(img.shape) * np.sqrt(K * img + L)


def phase_error(maps, truth, valid):
    return np.angle(maps.psi * np.conj(truth.psi))[:, valid]


def test_weights_realign_the_carriers_with_the_conventions_sign():
    # noise-free frames of a uniform grid shaken by 0.5 px: with the true shifts,
    # method C must return the transform of the unshifted grid. What the window lets
    # through from the other spectral lines (at least |k| = 0.2 cycle/px away,
    # transfer exp(-2 pi^2 sigma^2 |k|^2) = 3e-9) is negligible; the error left is
    # the window cut by the border, which sees shifted content in each frame: 7e-6
    # rad of edge bias at the 4-sigma margin (gridstrain.wft), hence 2e-5 rad, and
    # for the derivatives 5e-6 rad/px (the 4e-6 strain of that margin), hence 1e-5.
    rng = np.random.default_rng(0)
    shifts = rng.normal(0, 0.5, (12, 2))
    frames = [grid((96, 96), a) for a in shifts]
    truth = wft(grid((96, 96)), LAT)
    res = method_c(frames, LAT, shifts=shifts)
    v = truth.valid & res.maps.valid
    assert np.abs(phase_error(res.maps, truth, v)).max() < 2e-5
    ratio = np.abs(res.maps.psi[:, v]) / np.abs(truth.psi[:, v])
    np.testing.assert_allclose(ratio, 1.0, atol=2e-5)  # no contrast loss (cf. eq. 14)
    assert np.abs(res.maps.dphi[:, :, v]).max() < 1e-5  # rad/px, uniform grid
    assert res.warnings == ()
    # the opposite sign doubles the carriers' scatter instead of cancelling it:
    # contrast exp(-(2 pi f 2 * 0.5)^2 / 2) ~ 0.45 expected, far from 1
    wrong = method_c(frames, LAT, shifts=-shifts)
    assert np.median(np.abs(wrong.maps.psi[:, v]) / np.abs(truth.psi[:, v])) < 0.8
    (told,) = said(wrong.warnings, "vibration")
    assert "disagree" in told
    # oracle: the given shifts are 2 a_t off the true ones, 4 pi k.a_t rad on each
    # carrier, RMS about their mean on the circle; 1e-3 rad for the measured shifts'
    # own error (noise-free frames: 1e-5 px and less)
    d = 2 * np.pi * (-2 * shifts) @ LAT.K.T
    d = np.angle(np.exp(1j * d) * np.conj(np.mean(np.exp(1j * d), axis=0)))
    assert told.figures["disagreement_rad"] == pytest.approx(np.sqrt(np.mean(d**2)), abs=1e-3)


def test_measured_shifts_give_the_grid_at_the_mean_position():
    # shifts measured from the frames are centred: the phase is that of the grid at
    # the stack's mean position, offset from s by exactly 2 pi k . a_bar (no eq. 29
    # truncation). Noise-free shift estimates are good to ~1e-5 px (frame_shifts),
    # i.e. 1e-4 rad at the largest.
    rng = np.random.default_rng(1)
    shifts = rng.normal(0, 0.2, (10, 2)) + np.array([0.1, -0.05])
    frames = [grid((128, 128), a, phases=True) for a in shifts]
    truth = wft(grid((128, 128), phases=True), LAT)
    res = method_c(frames, LAT)
    v = truth.valid & res.maps.valid
    mean_pos = 2 * np.pi * LAT.K @ shifts.mean(axis=0)
    d = phase_error(res.maps, truth, v) - mean_pos[:, None]
    # the phase maps move with the frames (phi(x + a_t)): a_bar . grad phi adds up
    # to 0.14 px * 0.006 rad/px ~ 1e-3 rad where phi varies
    assert np.abs(d).max() < 2e-3
    # the modulation moves too: each quadrant's carrier advances by (2 pi k +
    # <grad phi>) . a, a relative error of <grad phi> / (2 pi |k|) ~ 0.4 % on shifts
    # of up to 0.4 px (gridstrain.stacks.vibration.frame_shifts): 2e-3 px
    np.testing.assert_allclose(res.shifts, shifts - shifts.mean(axis=0), atol=2e-3)
    assert res.motion_residual < 1e-3  # px: a rigid translation
    assert res.method == "C"
    assert res.n_frames == 10
    # method A keeps eq. (14)'s contrast loss, method C none
    mod_a = np.median(method_a(frames, LAT).maps.modulus[:, v], axis=1)
    mod_c = np.median(res.maps.modulus[:, v], axis=1)
    expected = theory.contrast_factor(0.2, 0.2**2)  # 0.92 for 0.2 px at pitch 5
    np.testing.assert_allclose(mod_a / mod_c, expected, atol=0.05)  # 10 frames' scatter


def test_without_vibration_method_c_is_method_a(monkeypatch):
    # zero shifts: weights 1, and the transform of the complex average is that of the
    # mean image; the two paths differ by rounding only, once method A takes the
    # exact derivatives as method C does (not the compiled filter wft's default
    # takes with numba, within 4e-8 rad/px of them: tests/test_wft_kernel.py)
    monkeypatch.setattr(importlib.import_module("gridstrain.phase._maps"), "_COMPILED", False)
    rng = np.random.default_rng(2)
    frames = [noisy(grid((80, 90)), rng) for _ in range(5)]
    a = method_a(frames, LAT).maps
    c = method_c(frames, LAT, shifts=np.zeros((5, 2))).maps
    np.testing.assert_allclose(c.psi, a.psi, rtol=0, atol=1e-9 * np.abs(a.psi).max())
    np.testing.assert_allclose(c.dphi[:, :, a.valid], a.dphi[:, :, a.valid], atol=1e-12)
    assert np.array_equal(c.valid, a.valid)


def test_large_vibrations_need_the_shift_only_modulo_a_period():
    # 1.5 px of vibration (beyond half a period for a third of the frames): the
    # measured shifts wrap, the weights exp(-2 i pi k.a) do not care. Method A's
    # average has lost nearly all its contrast; method C none.
    rng = np.random.default_rng(3)
    shifts = rng.normal(0, 1.5, (16, 2))
    frames = [grid((96, 96), a) for a in shifts]
    truth = wft(grid((96, 96)), LAT)
    c = method_c(frames, LAT)
    v = truth.valid & c.maps.valid
    ratio = np.abs(c.maps.psi[:, v]) / np.abs(truth.psi[:, v])
    np.testing.assert_allclose(ratio, 1.0, atol=1e-4)  # estimates good to 1e-5 px
    a = method_a(frames, LAT).maps
    assert np.median(a.modulus[:, a.valid]) < 0.5 * np.median(truth.modulus[:, v])
    # what breaks instead: the phase maps move with the frames, a window of variance
    # sigma^2 + Var(a), 4 % wider here (sqrt(1 + 1.5^2 / 25) = 1.044)
    (told,) = said(c.warnings, "vibration")
    assert len(c.warnings) == 1
    assert "wider than sigma" in told
    # given shifts off by whole periods along the lines give the same weights
    moved = shifts + np.array([[P, -2 * P]])
    r1 = method_c(frames, LAT, shifts=shifts).maps
    r2 = method_c(frames, LAT, shifts=moved).maps
    np.testing.assert_allclose(r2.psi, r1.psi, atol=1e-9 * np.abs(r1.psi).max())


def test_at_half_a_pixel_of_vibration_method_c_is_15_percent_below_method_a():
    # 0.5 px of vibration at pitch 5: method A's averaged grid keeps |mean_t
    # exp(2 i pi f a_t)| of its contrast, about exp(-(2 pi f 0.5)^2 / 2) = 0.82 for a
    # long stack (eq. 14, exact for Gaussian shifts), and its derivative noise grows
    # by the inverse. A uniform grid (true derivatives 0), so the error is noise
    # alone; the same noisy frames for both methods, so the ratio is that of the
    # contrasts up to the small scatter of the noise's own projection (~1 %).
    rng = np.random.default_rng(9)
    T = 50
    shifts = rng.normal(0, 0.5, (T, 2))
    frames = [noisy(grid((128, 128), a), rng) for a in shifts]
    a = method_a(frames, LAT).maps
    c = method_c(frames, LAT).maps
    v = a.valid & c.valid
    rms = [math.sqrt(np.mean(m.dphi[:, :, v] ** 2)) for m in (a, c)]
    assert rms[1] < 0.85 * rms[0]
    contrast = np.abs(np.mean(np.exp(2j * np.pi * shifts @ LAT.K.T), axis=0))
    assert rms[1] / rms[0] == pytest.approx(float(np.sqrt(np.mean(contrast**2))), abs=0.03)


def test_rotating_frames_are_flagged_as_not_rigid():
    # frames turned by 5e-3 rad RMS about the centre: the quadrant centres (32 px off
    # centre on a 128-px frame) move by ~0.2 px against each other, 0.25 rad on the
    # carrier, beyond the 0.05 rad that method C tolerates. The rigid stack beside
    # it stays far below (noise of the quadrant estimates ~1e-3 px).
    rng = np.random.default_rng(4)
    shifts = rng.normal(0, 0.1, (8, 2))
    turns = rng.normal(0, 5e-3, 8)
    rotated = method_c([grid((128, 128), a, rotation=w)
                        for a, w in zip(shifts, turns, strict=True)], LAT)
    assert rotated.motion_residual > 0.05
    assert any("not a rigid translation" in w for w in said(rotated.warnings, "vibration"))
    # the screening fits a rotation out, not the quadrants' second-order motion of
    # these noise-free frames: it may name the most turned frame too, never another
    flagged = said(rotated.warnings, "screening.flagged")
    assert len(rotated.warnings) == 1 + len(flagged)  # and nothing else
    assert all(f.figures["flagged"] == [int(np.argmax(np.abs(turns)))] for f in flagged)
    rigid = method_c([noisy(grid((128, 128), a), rng) for a in shifts], LAT)
    assert rigid.motion_residual < 0.01
    assert rigid.warnings == ()


def test_prefix_stacks_and_method_c_agree():
    rng = np.random.default_rng(5)
    shifts = rng.normal(0, 0.15, (9, 2))
    frames = [noisy(grid((72, 72), a), rng) for a in shifts]
    got = list(prefix_stacks(frames, LAT, [3, 9], method="C"))
    for res, n in zip(got, (3, 9), strict=True):
        ref = method_c(frames[:n], LAT)
        np.testing.assert_allclose(res.maps.psi, ref.maps.psi,
                                   atol=1e-10 * np.abs(ref.maps.psi).max())
        assert res.n_frames == n


def test_float32_frames_give_float32_maps():
    rng = np.random.default_rng(6)
    frames = [noisy(grid((64, 64), a), rng).astype(np.float32)
              for a in rng.normal(0, 0.1, (3, 2))]
    res = method_c(frames, LAT)
    assert res.maps.dphi.dtype == np.float32
    assert res.maps.psi.dtype == np.complex64


@pytest.mark.parametrize(("shifts", "match"), [
    (np.zeros((4, 3)), "shifts must be a finite \\(T, 2\\) array"),
    (np.zeros((3, 2)), "one row per frame"),
    (np.zeros((5, 2)), "one row per frame"),
    ([[0.0, np.nan]] * 4, "finite"),
])
def test_bad_shifts_are_refused(shifts, match):
    frames = [grid((64, 64))] * 4
    with pytest.raises(ValueError, match=match):
        method_c(frames, LAT, shifts=shifts)


def test_noise_and_shift_errors_follow_the_theory():
    """Monte Carlo of theory.compensated_noise_std (the analogue of Props. 2.2-2.4).

    40 stacks of T = 8 frames (96 x 96, case-1 vibrations of the paper, Gaussian
    Poisson-like noise). Given *absolute* shifts with errors e ~ N(0, 0.03 px): the
    phase error adds 2 pi f Std(e) / sqrt(T) = 0.013 rad to the sensor-noise term
    (5e-3 rad), the derivatives are untouched (the error is uniform). The empirical
    stds pool ~40 windows of the valid region over 40 stacks: sampling error about
    3 %, hence 10 %.
    """
    rng = np.random.default_rng(7)
    T, reps, err = 8, 40, 0.03
    truth = wft(grid((96, 96)), LAT)
    ph, dv = [], []
    for _ in range(reps):
        shifts = rng.normal(0, 1, (T, 2)) * [0.15, 0.1]
        frames = [noisy(grid((96, 96), a), rng) for a in shifts]
        res = method_c(frames, LAT, shifts=shifts + rng.normal(0, err, (T, 2)))
        ph.append(np.angle(res.maps.psi[0] * np.conj(truth.psi[0])))
        dv.append(res.maps.dphi[0, 0] - truth.dphi[0, 0])
    v = truth.valid
    emp_phase = math.sqrt(np.mean(np.var(ph, axis=0, ddof=1)[v]))
    emp_der = math.sqrt(np.mean(np.var(dv, axis=0, ddof=1)[v]))
    modulus = theory.grid_modulus(A, GAMMA)
    p_std, d_std, off = theory.compensated_noise_std(
        K * A + L, modulus, P, T, frequency=0.2, vibration_variance=0.15**2,
        shift_error_variance=err**2, centred=False)
    assert off == 0.0
    assert emp_phase == pytest.approx(p_std, rel=0.10)
    assert emp_der == pytest.approx(d_std, rel=0.10)
    noise_only = theory.wft_noise_std((K * A + L) / T, modulus, P)[0]
    assert p_std > 2 * noise_only  # the shift-error term is what is being tested
