"""Tests of gridstrain.stacks.vibration: per-frame shifts and the vibration report."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from gridstrain.models import add_noise, grid_image
from gridstrain.phase import Lattice, wft
from gridstrain.stacks.vibration import VibrationReport, frame_shifts, vibration_report

# Paper §3.2 vibration cases, (sigma_alpha, sigma_beta) in px.
CASE1 = (0.15, 0.1)
CASE2 = (0.1, 0.05)


def shifted(shape, lattice, a, b, **kw):
    """Frame ``s(x + a, y + b)``: the specimen displaced by ``(-a, -b)`` (eq. 2)."""
    return grid_image(shape, lattice, displacement=lambda X, Y: (-a + 0 * X, -b + 0 * Y), **kw)


def stack(shape, lattice, ab, *, rng=None, noise=False, amplitude=2000.0, **kw):
    frames = [shifted(shape, lattice, a, b, amplitude=amplitude, **kw) for a, b in ab]
    if noise:
        frames = [add_noise(f, K=0.28, L=5.0, rng=rng, bits=12) for f in frames]
    return np.array(frames)


def test_phase_sign_matches_wft():
    # The documented sign: s(x + a) has its WFT phase advanced by +2 pi k.a, as
    # gridstrain.wft measures it; frame_shifts must invert exactly that.
    lat = Lattice.from_pitch(5.0, angle=10.0)
    a, b = 0.3, -0.2
    s0 = grid_image((128, 128), lat)
    s1 = shifted((128, 128), lat, a, b)
    p0, p1 = wft(s0, lat), wft(s1, lat)
    v = p0.valid & p1.valid
    dphi = np.angle(p1.psi * np.conj(p0.psi))[:, v].mean(axis=1)
    # rad: the WFT's own bias in its valid region is 1e-5 rad (wft.DEFAULT_MARGIN)
    assert_allclose(dphi, 2 * np.pi * lat.K @ [a, b], atol=1e-4)
    got = frame_shifts([s1], lat, reference=s0)[0]
    assert_allclose(got, [a, b], atol=1e-5)  # px: see the noise-free accuracy test


@pytest.mark.parametrize(("shape", "lattice", "kind"), [
    ((256, 256), Lattice.from_pitch(5.0), "grid"),
    ((200, 256), Lattice.from_pitch(5.0, angle=10.0), "grid"),
    ((192, 160), Lattice.from_pitch(6.3, angle=-25.0, pitch2=4.4), "grid"),
    ((160, 160), Lattice.from_pitch(7.0, angle=45.0), "checkerboard"),
])
def test_noise_free_accuracy(shape, lattice, kind):
    rng = np.random.default_rng(1)
    # case-1 vibrations plus a few large shifts (up to 1.2 px, a quarter period)
    ab = np.vstack([rng.normal(size=(12, 2)) * CASE1, rng.uniform(-1.2, 1.2, (4, 2))])
    frames = stack(shape, lattice, ab, kind=kind)
    got = frame_shifts(frames, lattice)
    # px: the sin^4 window leaks under 1e-8 of the carrier from every other
    # spectral peak, i.e. ~1e-8 px; 1e-5 px leaves room and is 10x the brief's 1e-4.
    assert_allclose(got, ab - ab.mean(axis=0), atol=1e-5)
    assert got.dtype == np.float64
    assert_allclose(got.mean(axis=0), 0.0, atol=1e-12)  # px: centred by construction


def test_reference_image_gives_absolute_shifts():
    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(2)
    ab = rng.normal(size=(6, 2)) * CASE2 + [0.2, -0.1]
    frames = stack((128, 128), lat, ab)
    ref = grid_image((128, 128), lat, amplitude=2000.0)
    assert_allclose(frame_shifts(frames, lat, reference=ref), ab, atol=1e-5)  # px, as above


def test_streamed_frames_equal_array():
    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(3)
    ab = rng.normal(size=(8, 2)) * CASE2
    frames = stack((96, 128), lat, ab, rng=rng, noise=True).astype(np.uint16)
    from_array = frame_shifts(frames, lat)
    from_gen = frame_shifts((f for f in frames), lat)
    assert_allclose(from_gen, from_array, rtol=0, atol=1e-12)  # px: same arithmetic


def _noisy_error_std(side, T, seed):
    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(seed)
    ab = rng.normal(size=(T, 2)) * CASE2
    frames = stack((side, side), lat, ab, rng=rng, noise=True)
    err = frame_shifts(frames, lat) - (ab - ab.mean(axis=0))
    return err.std(axis=0, ddof=1)


def test_noisy_accuracy_and_inverse_side_law():
    # 12-bit Poisson-Gaussian noise (K = 0.28, L = 5), A = 2000, gamma = 0.9.
    big = _noisy_error_std(256, 100, seed=4)
    small = _noisy_error_std(128, 100, seed=5)
    # px: the documented per-frame error is 5e-4 px at 256 x 256; allow 2x
    assert np.all(big < 1e-3)
    # The phase noise is a sum over H W pixels against a carrier growing as H W:
    # std ~ 1/side. Each std from 100 frames is known to 7 %, the ratio to 10 %,
    # hence the +-25 % (2.5 sigma) band around 2.
    assert np.all((small / big > 1.5) & (small / big < 2.5))


def test_vibration_report_against_independent_oracles():
    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(6)
    T = 60
    ab = rng.normal(size=(T, 2)) * CASE1
    frames = stack((128, 128), lat, ab)
    rep = vibration_report(frames, lat)
    assert isinstance(rep, VibrationReport)
    assert rep.n_frames == T
    assert rep.shifts.shape == (T, 2)
    cov_true = np.cov(ab, rowvar=False, ddof=1)
    assert_allclose(rep.covariance, cov_true, atol=1e-6)  # px^2: shifts exact to 1e-5 px
    assert_allclose(rep.std, np.sqrt(np.diag(cov_true)), atol=1e-5)  # px

    # Contrast factor (Prop. 2.2): the WFT modulus of the averaged stack over that
    # of the still grid is |mean_t exp(i theta_t)|, theta_t = 2 pi k.a_t. The
    # paper's second-order law drops mean(theta^4) / 24 (3e-4 here, case 1): allow
    # twice that, plus 2e-5 for the WFT's own modulus error.
    still = wft(grid_image((128, 128), lat, amplitude=2000.0), lat)
    avg = wft(frames.mean(axis=0), lat)
    v = still.valid & avg.valid
    ratio = (avg.modulus[:, v] / still.modulus[:, v]).mean(axis=1)
    # The report estimates Var with T - 1 (unbiased for the process); this stack's
    # own average sees the T-denominator variance of its shifts.
    this_stack = 1 - (1 - rep.contrast_factor) * (T - 1) / T
    theta = 2 * np.pi * (ab - ab.mean(axis=0)) @ lat.K.T
    tol = (theta**4).mean(axis=0) / 12 + 2e-5
    assert np.all(np.abs(this_stack - ratio) <= tol)
    assert np.all(rep.contrast_factor < 1)

    # Method-A phase offset (Prop. 2.4, with Var(mean) = Var / T): Monte Carlo of
    # delta_j = arg mean_t exp(2 i pi k_j . a_t) over stacks drawn from the
    # measured covariance. 4000 draws give the std to 1.1 %; the delta method
    # neglects O((2 pi |k| Std)^2) = 4 %, hence 6 %.
    mc = np.random.default_rng(7)
    draws = mc.multivariate_normal([0, 0], rep.covariance, size=(4000, T))
    delta = np.angle(np.exp(2j * np.pi * draws @ lat.K.T).mean(axis=1))
    assert_allclose(rep.phase_offset_std, delta.std(axis=0), rtol=0.06)


def test_report_is_frozen_and_readonly():
    lat = Lattice.from_pitch(5.0)
    ab = np.random.default_rng(8).normal(size=(5, 2)) * CASE2
    rep = vibration_report(stack((64, 64), lat, ab), lat)
    with pytest.raises(AttributeError):
        rep.n_frames = 3
    with pytest.raises(ValueError, match="read-only"):
        rep.shifts[0, 0] = 1.0
    assert "VibrationReport(T=5" in repr(rep)


def test_measure_series_gives_the_same_vibration_report():
    """One vibration result: the pipeline's, for each series, is the VibrationReport
    of the stack (frame_shifts's estimator, from the screening's carrier sums),
    named after the series; a single frame says nothing (NaN)."""
    from gridstrain.series import measure_series

    lat = Lattice.from_pitch(5.0)
    ab = np.random.default_rng(10).normal(size=(8, 2)) * CASE1
    frames = stack((96, 96), lat, ab, rng=np.random.default_rng(11), noise=True)
    res = measure_series(frames, frames[:1], lattice=lat, guess=None)
    ref, one = res.vibration
    want = vibration_report(frames, lat)
    assert isinstance(ref, VibrationReport)
    assert ref.name == "reference"
    # px: the same estimator; only the order of the carrier sums differs (rounding)
    assert_allclose(ref.shifts, want.shifts, atol=1e-9)
    assert_allclose(ref.std, want.std, atol=1e-9)
    assert_allclose(ref.covariance, want.covariance, atol=1e-12)  # px^2
    assert_allclose(ref.contrast_factor, want.contrast_factor, atol=1e-12)
    assert_allclose(ref.phase_offset_std, want.phase_offset_std, rtol=1e-9)  # rad
    assert one.n_frames == 1
    assert np.all(np.isnan(one.std))
    assert np.all(np.isnan(one.phase_offset_std))


def test_inputs_not_modified():
    lat = Lattice.from_pitch(5.0)
    ab = np.random.default_rng(9).normal(size=(4, 2)) * CASE2
    frames = stack((64, 64), lat, ab)
    copy = frames.copy()
    frame_shifts(frames, lat)
    np.testing.assert_array_equal(frames, copy)


def test_validation_errors():
    lat = Lattice.from_pitch(5.0)
    img = grid_image((64, 64), lat)
    with pytest.raises(TypeError, match="lattice must be a Lattice"):
        frame_shifts([img], (0.2, 0.0))
    with pytest.raises(ValueError, match=r"frames must be a \(T, H, W\) array"):
        frame_shifts(img, lat)
    with pytest.raises(TypeError, match="frames must be a"):
        frame_shifts(3.0, lat)
    with pytest.raises(ValueError, match="at least one frame"):
        frame_shifts([], lat)
    with pytest.raises(ValueError, match=r"same shape.*frames\[1\]"):
        frame_shifts([img, img[:60]], lat)
    with pytest.raises(ValueError, match="reference must have"):
        frame_shifts([img], lat, reference=img[:60])
    with pytest.raises(ValueError, match="at least 2 frames"):
        vibration_report([img], lat)
    with pytest.raises(ValueError, match="finite"):
        frame_shifts([np.full((64, 64), np.nan)], lat)
    # a lattice the frames do not carry: the carrier is at the white-noise level
    noise = np.random.default_rng(0).normal(1000.0, 30.0, (3, 64, 64))
    with pytest.raises(ValueError, match=r"frames\[0\] shows no grid"):
        frame_shifts(noise, lat)
    with pytest.raises(ValueError, match="reference shows no grid"):
        frame_shifts([img], lat, reference=noise[0])
    with pytest.raises(ValueError, match="shows no grid"):
        frame_shifts([img], Lattice.from_pitch(7.3, angle=20.0))
