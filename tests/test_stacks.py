"""Stacks: streamed averaging, methods A and B, vibration phase correction."""

import math

import numpy as np
import pytest

from gridstrain import Lattice, PhaseMaps, wft
from gridstrain.models import synthetic
from gridstrain.paper import clean_frame, draw_shifts, iter_frames, paper_phases
from gridstrain.stacks import (
    StackResult,
    correct_phases,
    mean_image,
    method_a,
    method_b,
    prefix_stacks,
)

LAT = Lattice.from_pitch(5.0)


def _interior(maps, margin=21):
    H, W = maps.shape
    m = np.zeros((H, W), bool)
    m[margin:H - margin, margin:W - margin] = True
    return m & maps.valid


# ----------------------------------------------------------------- method A, mean

def test_mean_image_streams_and_equals_numpy_mean():
    rng = np.random.default_rng(1)
    stack = rng.normal(1000.0, 30.0, (7, 20, 24)).astype(np.float32)
    before = stack.copy()
    calls = []
    out = mean_image((f for f in stack), progress=lambda f, m: calls.append(f))
    assert out.dtype == np.float64  # accumulated in float64 whatever the frame dtype
    np.testing.assert_allclose(out, np.mean(stack, axis=0, dtype=np.float64), rtol=1e-15)
    np.testing.assert_array_equal(stack, before)  # input untouched
    assert len(calls) == 7
    # with a length, the progress fraction is known
    fr = []
    mean_image(list(stack), progress=lambda f, m: fr.append(f))
    assert fr[-1] == 1.0


def test_mean_image_validation():
    with pytest.raises(ValueError, match="at least one"):
        mean_image([])
    with pytest.raises(ValueError, match=r"frames\[1\]"):
        mean_image([np.zeros((10, 10)), np.zeros((10, 12))])
    with pytest.raises(TypeError, match="frames"):
        mean_image(3.0)
    with pytest.raises(ValueError, match="frames"):
        mean_image(np.zeros((10, 10)))


def test_method_a_is_the_wft_of_the_mean():
    phases, _ = paper_phases((64, 64))
    frames = list(iter_frames(phases, draw_shifts(5, 2, rng=0), rng=1))
    res = method_a(iter(frames), LAT)
    ref = wft(np.mean(frames, axis=0), LAT)
    assert isinstance(res, StackResult)
    assert res.method == "A"
    assert res.n_frames == 5
    np.testing.assert_array_equal(res.maps.psi, ref.psi)
    np.testing.assert_array_equal(res.maps.dphi, ref.dphi)
    np.testing.assert_allclose(res.mean_image, np.mean(frames, axis=0), rtol=1e-15)
    assert "method A" in repr(res)


# ------------------------------------------------------------------------ method B

def _constant_phase_frame(phase1, shape=(64, 64)):
    # arg Psi_1 = phi1 + arg d_1 with arg d_1 = -pi/2 for the sin^3 profile
    return synthetic.grid_image(shape, LAT, amplitude=1000.0,
                                phases=lambda X, Y: (phase1 + np.pi / 2 + 0 * X, 0 * Y))


def test_method_b_circular_mean_across_pi():
    # phases pi + eps_t straddle the cut at +-pi: wrapped they read ~ +3.0 and ~ -3.0,
    # whose arithmetic mean (~0) is off by pi; the circular mean is right
    eps = np.array([0.3, -0.25, 0.1, -0.2, 0.15])
    frames = [_constant_phase_frame(np.pi + e) for e in eps]
    res = method_b(frames, LAT)
    sel = _interior(res.maps, 18)
    wrapped = np.angle(np.exp(1j * (np.pi + eps)))
    # the naive mean of the wrapped phases lands more than 2 rad away from pi
    assert abs(np.angle(np.exp(1j * (wrapped.mean() - np.pi)))) > 2.0
    # oracle: the circular mean of the known phases, arg sum exp(i (pi + eps_t))
    expected = np.angle(np.sum(np.exp(1j * (np.pi + eps))))
    got = res.maps.phase[0][sel]
    # noise-free uniform phase: the WFT recovers it to ~1e-6 rad in the interior
    np.testing.assert_allclose(np.angle(np.exp(1j * (got - expected))), 0, atol=1e-5)
    # the resultant length is |mean exp(i eps)|
    np.testing.assert_allclose(res.resultant[0][sel], abs(np.mean(np.exp(1j * eps))),
                               rtol=1e-5)
    assert res.method == "B"
    assert res.n_frames == 5
    assert res.mean_image is None


def test_method_b_on_identical_frames_is_one_wft():
    phases, _ = paper_phases((64, 64))
    frame = clean_frame(phases, shift=(0.2, -0.1))
    res = method_b([frame] * 3, LAT)
    ref = wft(frame, LAT)
    np.testing.assert_allclose(res.maps.psi, ref.psi, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(res.maps.dphi, ref.dphi, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(res.maps.valid, ref.valid)


def test_method_b_transforms_integer_frames_in_float32_and_keeps_float64_maps(monkeypatch):
    from gridstrain.stacks import _accumulators as stacks

    rng = np.random.default_rng(3)
    phases, _ = paper_phases((96, 112))
    # 12-bit frames stored x16 in uint16, each with its own shift and photon noise
    frames = np.array([np.clip(np.round(0.6 * clean_frame(phases, tuple(rng.normal(0, 0.1, 2)))
                                        + rng.normal(0, 10, (96, 112))), 0, 4095)
                       for _ in range(6)]).astype(np.uint16) * 16
    seen = []
    transform = stacks._transform_input
    monkeypatch.setattr(stacks, "_transform_input",
                        lambda f, name: seen.append(transform(f, name)) or seen[-1])
    got = method_b(frames, LAT, workers=1)
    assert {img.dtype for img, _ in seen} == {np.dtype(np.float32)}
    assert {prec for _, prec in seen} == {np.dtype(np.float64)}
    assert got.maps.psi.dtype == np.complex128
    assert got.maps.dphi.dtype == np.float64
    want = method_b(frames.astype(np.float64), LAT, workers=1).maps
    np.testing.assert_array_equal(got.maps.valid, want.valid)
    v = want.valid
    # float32 rounding of each frame's transform (measured here 1.0e-7 rad and 9e-8
    # rad/px; 1.7e-7 rad and 4e-8 rad/px on 1040 x 1376 frames), four orders below
    # the phase noise of one frame (~1e-3 rad); 1e-6 is the float32 transform's bound
    dphase = np.angle(np.exp(1j * (got.maps.phase - want.phase)))[:, v]
    assert np.abs(dphase).max() < 1e-6
    assert np.abs(got.maps.dphi[:, :, v] - want.dphi[:, :, v]).max() < 1e-6
    # float frames keep their precision
    assert transform(frames[0].astype(np.float32))[0].dtype == np.float32
    assert transform(frames[0].astype(np.float32))[1] == np.float32
    assert transform(frames[0].astype(np.float64))[0].dtype == np.float64
    assert transform(frames[0].astype(np.int32))[0].dtype == np.float64  # > 16 bits


def test_method_b_averages_derivatives_and_ands_valid():
    phases, _ = paper_phases((96, 96))
    f1 = clean_frame(phases)
    f2 = clean_frame(phases, (0.3, 0.4))
    blank = f2.copy()
    # no grid on a 24-px square (+-2.4 sigma): the modulus at its centre falls to a few
    # per cent, below the 25 % validity threshold, in that frame only
    blank[36:60, 36:60] = f2.mean()
    res = method_b([f1, blank], LAT)
    m1, m2 = wft(f1, LAT), wft(blank, LAT)
    np.testing.assert_array_equal(res.maps.valid, m1.valid & m2.valid)
    assert not res.maps.valid[48, 48]
    assert m1.valid[48, 48]
    sel = res.maps.valid
    np.testing.assert_allclose(res.maps.dphi[:, :, sel],
                               (m1.dphi[:, :, sel] + m2.dphi[:, :, sel]) / 2, rtol=1e-12)
    # mean modulus times the mean unit phasor
    mod = (m1.modulus + m2.modulus) / 2
    np.testing.assert_allclose(res.maps.modulus[:, sel], mod[:, sel], rtol=1e-12)


def test_method_b_result_feeds_phase_maps_consumers():
    phases, _ = paper_phases((64, 64))
    res = method_b(list(iter_frames(phases, draw_shifts(2, 3, rng=0), rng=0)), LAT)
    assert isinstance(res.maps, PhaseMaps)
    assert res.maps.psi.shape == (2, 64, 64)
    assert res.maps.dphi.shape == (2, 2, 64, 64)
    assert res.maps.sigma == 5.0
    assert res.maps.lattice == LAT
    with pytest.raises(ValueError, match="read-only"):
        res.maps.psi[0, 0, 0] = 0  # results are read-only


# ------------------------------------------------------------------ phase correction

def test_wft_phase_rises_by_two_pi_k_dot_shift():
    # sign of eqs. (26)-(30): a frame s(x + alpha, y + beta) has arg Psi_j raised by
    # +2 pi k_j . (alpha, beta). Besides the carrier, the shifted phase maps add
    # alpha d phi/dx + beta d phi/dy, at most 0.005 * (0.3 + 0.2) = 2.5e-3 rad.
    phases, _ = paper_phases((96, 96))
    shift = (0.3, -0.2)
    ref = wft(clean_frame(phases), LAT)
    v = wft(clean_frame(phases, shift), LAT)
    sel = _interior(ref)
    d = np.angle(v.psi * np.conj(ref.psi))
    expected = 2 * np.pi * np.asarray(LAT.K) @ np.asarray(shift)
    for j in range(2):
        np.testing.assert_allclose(d[j][sel], expected[j], atol=2.5e-3)


@pytest.mark.parametrize("method", [method_a, method_b])
def test_corrected_phase_of_noise_free_vibrated_stack(method):
    # Noise-free stack with case-1 vibrations (the largest): uncorrected, the phase is
    # off by delta ~ 2 pi f alpha_bar; corrected with eqs. (29)-(30) it matches the
    # ground truth up to (i) the third-order remainder of eq. (29), which
    # exact=True removes, and (ii) the shifted phase maps, mean_t (alpha_t dphi/dx +
    # beta_t dphi/dy), bounded by 0.005 rad/px * (|alpha_bar| + |beta_bar|).
    phases, _ = paper_phases((96, 96))
    shifts = draw_shifts(24, 1, rng=np.random.default_rng(5))
    frames = [clean_frame(phases, sh) for sh in shifts]
    res = method(frames, LAT)
    gt = wft(clean_frame(phases), LAT)
    sel = _interior(gt)

    def err(maps):
        return np.angle(maps.psi * np.conj(gt.psi))[:, sel]

    theta = 2 * np.pi * shifts @ LAT.K.T  # (T, 2) phase advance of each frame
    exact = np.angle(np.mean(np.exp(1j * theta), axis=0))
    eq29 = np.arctan2(theta.mean(0), 1 - 0.5 * np.mean(theta**2, axis=0))
    maps_bound = 0.005 * np.abs(shifts.mean(axis=0)).sum() + 1e-5
    raw = err(res.maps)
    for j in range(2):
        np.testing.assert_allclose(raw[j], exact[j], atol=maps_bound)
    corr = err(correct_phases(res, shifts).maps)
    for j in range(2):
        # the residual is the known third-order difference between eq. (29) and exact
        np.testing.assert_allclose(corr[j], exact[j] - eq29[j], atol=maps_bound)
    corr_exact = err(correct_phases(res.maps, shifts, exact=True))
    assert np.abs(corr_exact).max() < maps_bound
    assert np.abs(raw).max() > 20 * maps_bound  # the correction matters here


def test_correct_phases_keeps_derivatives_and_types():
    phases, _ = paper_phases((64, 64))
    maps = wft(clean_frame(phases), LAT)
    shifts = np.array([[0.1, 0.0], [0.3, -0.2]])
    out = correct_phases(maps, shifts)
    assert isinstance(out, PhaseMaps)
    np.testing.assert_array_equal(out.dphi, maps.dphi)
    np.testing.assert_allclose(out.modulus, maps.modulus, rtol=1e-14)
    theta = 2 * np.pi * shifts @ LAT.K.T
    delta = np.arctan2(theta.mean(0), 1 - 0.5 * (theta**2).mean(0))
    np.testing.assert_allclose(np.angle(out.psi * np.conj(maps.psi))[:, 30, 30], -delta,
                               atol=1e-12)
    with pytest.raises(ValueError, match="shifts"):
        correct_phases(maps, [0.1, 0.2])
    with pytest.raises(TypeError, match="maps"):
        correct_phases(np.zeros((2, 8, 8)), shifts)


# ------------------------------------------------------------- the 1/sqrt(T) law

def test_derivative_rmse_falls_as_one_over_sqrt_t_for_a_and_b():
    # 96 x 96 frames, case 2 vibrations, T = 1..32, 4 independent repetitions.
    # The pooled RMSE of the four derivative maps over the 54 x 54 interior has a
    # relative sampling error of about 4 % per point (about 100 independent
    # window areas x 4 maps x 4 repetitions); over 1.5 decades of T the fitted
    # slope is then within +-0.03 (1 sigma): tolerance 0.1.
    phases, _ = paper_phases((96, 96))
    gt = wft(clean_frame(phases), LAT)
    sel = _interior(gt)
    counts = [1, 2, 4, 8, 16, 32]
    sq = {"A": np.zeros(len(counts)), "B": np.zeros(len(counts))}
    for rep in range(4):
        shifts = draw_shifts(32, 2, rng=np.random.default_rng([rep, 0]))
        for m in ("A", "B"):
            frames = iter_frames(phases, shifts, rng=np.random.default_rng([rep, 1]))
            for i, res in enumerate(prefix_stacks(frames, LAT, counts, method=m)):
                assert res.n_frames == counts[i]
                e = res.maps.dphi[:, :, sel] - gt.dphi[:, :, sel]
                sq[m][i] += np.mean(e**2)
    rmse = {m: np.sqrt(v / 4) for m, v in sq.items()}
    for m in ("A", "B"):
        slope = np.polyfit(np.log(counts), np.log(rmse[m]), 1)[0]
        assert slope == pytest.approx(-0.5, abs=0.1), m
    # A and B see the same frames and differ only by second-order effects (the
    # averaged grid's contrast is 1 - (2 pi f sigma)^2 / 2 = 0.8 % lower in case 2)
    np.testing.assert_allclose(rmse["B"] / rmse["A"], 1.0, atol=0.05)


def test_derivative_noise_matches_small_noise_theory():
    # Independent oracle: the small-noise formula written out here,
    # Std(dphi) = sqrt(v / (16 pi)) / (sigma^2 |Psi|), |Psi| = A/2 gamma 3/16,
    # v = K A + L + 1/12, for method A at T = 8 with case-4 (negligible) vibrations.
    # 128 x 128, 3 repetitions: pooled relative sampling error ~3 %; tolerance 10 %.
    phases, _ = paper_phases((128, 128))
    gt = wft(clean_frame(phases), LAT)
    sel = _interior(gt)
    T, A = 8, 4096.0
    v = (0.28 * A + 5.0 + 1 / 12) / T
    expected = math.sqrt(v / (16 * math.pi)) / (25 * A / 2 * 0.9 * 3 / 16)
    sq = 0.0
    for rep in range(3):
        shifts = draw_shifts(T, 4, rng=rep)
        res = method_a(iter_frames(phases, shifts, rng=[rep, 9]), LAT)
        sq += np.mean((res.maps.dphi[:, :, sel] - gt.dphi[:, :, sel]) ** 2)
    assert math.sqrt(sq / 3) == pytest.approx(expected, rel=0.10)


# ------------------------------------------------------------------- prefix stacks

def test_prefix_stacks_equal_independent_runs():
    phases, _ = paper_phases((48, 48))
    frames = list(iter_frames(phases, draw_shifts(6, 1, rng=0), rng=0))
    got = list(prefix_stacks(iter(frames), LAT, [2, 6], method="A"))
    np.testing.assert_allclose(got[0].mean_image, np.mean(frames[:2], axis=0), rtol=1e-15)
    np.testing.assert_array_equal(got[1].maps.psi, method_a(frames, LAT).maps.psi)
    gb = list(prefix_stacks(frames, LAT, [3], method="B"))
    np.testing.assert_allclose(gb[0].maps.dphi, method_b(frames[:3], LAT).maps.dphi,
                               rtol=1e-13, atol=1e-18)


def test_prefix_stacks_validation():
    frames = [np.random.default_rng(0).normal(100, 1, (16, 16)) for _ in range(3)]
    with pytest.raises(ValueError, match="at least 5"):
        list(prefix_stacks(frames, LAT, [1, 5]))
    with pytest.raises(ValueError, match="increasing"):
        list(prefix_stacks(frames, LAT, [2, 2]))
    with pytest.raises(ValueError, match="counts"):
        list(prefix_stacks(frames, LAT, [1.5]))
    with pytest.raises(ValueError, match="method"):
        list(prefix_stacks(frames, LAT, [1], method="D"))
    with pytest.raises(TypeError, match="lattice"):
        method_a(frames, 5.0)


def test_method_b_names_the_frame_that_is_not_finite():
    phases, _ = paper_phases((64, 64))
    frames = [clean_frame(phases) for _ in range(4)]
    frames[2] = frames[2].copy()
    frames[2][10, 10] = np.nan
    with pytest.raises(ValueError, match=r"frames\[2\] must be finite, got 1 NaN"):
        method_b(frames, LAT, workers=1, screen=False)
