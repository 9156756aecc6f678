"""Tests of gridstrain.theory against independent oracles.

Oracles: analytic Fourier series, direct quadrature, Monte Carlo and Gauss-Hermite
averages of shifted images made by gridstrain.models.synthetic.grid_image, and the real
windowed Fourier transform gridstrain.phase.wft. Each tolerance says what it is.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.polynomial.hermite_e import hermegauss
from numpy.testing import assert_allclose
from scipy import integrate

from gridstrain import theory
from gridstrain.models import PROFILES, add_noise, grid_image
from gridstrain.phase import Lattice, wft

F = 0.2  # the paper's carrier, cycles/px (pitch 5)
CASE1 = (0.15, 0.10)  # paper §3.2, Std(alpha), Std(beta) in px
CASE2 = (0.10, 0.05)


def shifted(shape, lattice, a, **kw):
    """Frame s(x + alpha, y + beta) of paper eq. (2): the specimen moved by -a."""
    al, be = float(a[0]), float(a[1])
    return grid_image(shape, lattice, displacement=lambda X, Y: (-al + 0 * X, -be + 0 * Y),
                      **kw)


def gauss_hermite_shifts(cov, n=24):
    """Nodes (N, 2) px and weights (N,) that integrate exactly against N(0, cov).

    Probabilists' Gauss-Hermite with n nodes per axis is exact for polynomials of
    degree 2n - 1; the grids' exp(i m theta) with m theta of std <= 1.2 rad are
    then integrated to rounding.
    """
    z, w = hermegauss(n)
    w = w / w.sum()
    Z = np.stack(np.meshgrid(z, z, indexing="ij"), -1).reshape(-1, 2)
    W = np.outer(w, w).ravel()
    L = np.linalg.cholesky(np.asarray(cov, dtype=float))
    return Z @ L.T, W


# ---------------------------------------------------------------- profile coefficients

def test_sin3_coefficients_are_the_analytic_ones():
    # sin^3 t / 2 = (3 sin t - sin 3t) / 8, sin t = (e^it - e^-it) / 2i
    n = 6
    d = theory.profile_coefficients("sin3", n_harmonics=n)
    want = np.zeros(2 * n + 1, dtype=complex)
    want[n + 1], want[n - 1] = -3j / 16, 3j / 16
    want[n + 3], want[n - 3] = 1j / 16, -1j / 16
    assert d.shape == (2 * n + 1,)
    # dimensionless; FFT rounding of 1024 samples of size 0.5
    assert_allclose(d, want, atol=1e-15)


def test_coefficients_of_callable_and_square_profile_match_quadrature():
    d = theory.profile_coefficients(np.cos, n_harmonics=2)
    assert_allclose(d, [0, 0.5, 0, 0.5, 0], atol=1e-15)
    ell = PROFILES["square"]
    d = theory.profile_coefficients("square", n_harmonics=7)
    for k in range(-7, 8):
        re = integrate.quad(lambda t, k=k: ell(t) * math.cos(k * t), 0, 2 * math.pi,
                            epsabs=1e-13, limit=200)[0]
        im = integrate.quad(lambda t, k=k: -ell(t) * math.sin(k * t), 0, 2 * math.pi,
                            epsabs=1e-13, limit=200)[0]
        # quadrature tolerance 1e-13 over a 2 pi period
        assert abs(d[7 + k] - (re + 1j * im) / (2 * math.pi)) < 1e-12


# ------------------------------------------------------------ Prop. 2.2, eq. (14)

def test_averaged_profile_coefficients_match_averaged_shifted_profiles():
    rng = np.random.default_rng(0)
    alphas = rng.normal(0.0, CASE1[0], 400)
    theta = 2 * np.pi * F * alphas
    N = 256  # samples per period; sin^3 has harmonics up to 3, so the FFT is exact
    t = 2 * np.pi * np.arange(N) / N
    ell = PROFILES["sin3"]
    averaged = np.mean([ell(t + th) for th in theta], axis=0)
    d_avg = np.fft.fft(averaged) / N
    n = 3
    d = theory.profile_coefficients("sin3", n_harmonics=n)
    pred = theory.averaged_profile_coefficients(d, F, alphas.mean(), np.mean(alphas**2))
    for k in (1, 3, -1, -3):
        # rigorous Taylor remainder of eq. (3): |e^ix - 1 - ix + x^2/2| <= |x|^3 / 6
        bound = np.mean(np.abs(k * theta) ** 3) / 6 * abs(d[n + k])
        assert abs(d_avg[k % N] - pred[n + k]) <= bound + 1e-15
        # and the exact coefficient mean exp(i k theta) d_k, to rounding
        assert abs(d_avg[k % N] - np.mean(np.exp(1j * k * theta)) * d[n + k]) < 1e-14
    assert_allclose(theory.exact_contrast_factor(F, alphas), abs(d_avg[1]) / abs(d[n + 1]),
                    rtol=1e-12)


def test_contrast_factor_matches_large_stack():
    rng = np.random.default_rng(1)
    T = 20000
    alphas = rng.normal(0.0, CASE1[0], T)
    s2 = (2 * np.pi * F * CASE1[0]) ** 2  # Var of the phase shift, rad^2
    measured = theory.exact_contrast_factor(F, alphas)
    predicted = theory.contrast_factor(F, CASE1[0] ** 2)
    # fourth-order term of exp(-s2/2) (s2^2 / 8) plus 4 standard errors of
    # mean cos(theta), whose variance is about s2^2 / 2 per frame
    tol = s2**2 / 8 + 4 * math.sqrt(s2**2 / 2 / T)
    assert abs(measured - predicted) < tol
    assert tol < 0.1 * (1 - predicted)  # the loss of contrast itself is resolved


# ---------------------------------------------------------------- Prop. 2.1, image bias

@pytest.mark.parametrize(("lattice", "stds"), [
    (Lattice.from_pitch(5), CASE2),
    (Lattice.from_pitch(5), CASE1),
    (Lattice.from_pitch(6, angle=25.0), CASE1),
])
def test_grid_bias_matches_averaged_shifted_grids(lattice, stds):
    rng = np.random.default_rng(2)
    shape, A, gamma = (40, 48), 1.0, 0.9
    half = rng.normal(0.0, 1.0, (200, 2)) * np.asarray(stds)
    # antithetic pairs: the odd moments of the shifts vanish exactly, so the
    # average is E(v_bar) for the symmetric 400-point law whose covariance is
    # the sample second moment below (Prop. 2.1 needs no more than that)
    shifts = np.concatenate([half, -half])
    cov = shifts.T @ shifts / len(shifts)
    s = grid_image(shape, lattice, amplitude=A, contrast=gamma)
    mean = np.mean([shifted(shape, lattice, a, amplitude=A, contrast=gamma)
                    for a in shifts], axis=0)
    pred = theory.grid_mean_image_bias(shape, lattice, cov, amplitude=A, contrast=gamma)
    # fourth-order Taylor remainder, |e^ix - sum_{n<4} (ix)^n / n!| <= x^4 / 24, for
    # each harmonic m of each family: grey levels
    d = theory.profile_coefficients("sin3", n_harmonics=3)
    m = np.arange(-3, 4)
    theta = 2 * np.pi * shifts @ lattice.K.T
    bound = A / 2 * gamma * sum(
        np.sum(np.abs(d) * np.mean(theta[:, j, None] ** 4, axis=0) * m**4) / 24
        for j in range(2))
    assert_allclose(mean - s, pred, rtol=0, atol=bound)
    assert bound < 0.2 * np.sqrt(np.mean(pred**2))  # the bias itself is resolved


def test_exact_grid_bias_matches_gaussian_quadrature():
    lattice = Lattice.from_pitch(6, angle=25.0)
    cov = np.array([[0.15**2, 0.006], [0.006, 0.1**2]])
    shape = (24, 32)
    s = grid_image(shape, lattice)
    shifts, w = gauss_hermite_shifts(cov)
    expect = np.tensordot(w, np.array([shifted(shape, lattice, a) for a in shifts]), 1)
    exact = theory.grid_mean_image_bias(shape, lattice, cov, exact=True)
    # grey levels (A = 1): quadrature and series are both exact to rounding
    assert_allclose(expect - s, exact, rtol=0, atol=1e-12)
    second = theory.grid_mean_image_bias(shape, lattice, cov)
    # Prop. 2.1 drops E(x^4)/24 = 3 q^2 / 24 per harmonic, q = m^2 (2 pi)^2 k^T C k
    d = np.abs(theory.profile_coefficients("sin3", n_harmonics=3))
    m = np.arange(-3, 4)
    bound = 0.5 * 0.9 * sum(np.sum(d * (m**2 * (2 * np.pi) ** 2 * (k @ cov @ k)) ** 2) / 8
                            for k in lattice.K)
    assert np.max(np.abs(second - exact)) <= bound
    assert np.max(np.abs(second - exact)) > 0.1 * bound  # the bound is not loose


def test_spectral_bias_matches_quadrature_on_band_limited_checkerboard():
    # pitch 8: the checkerboard's highest frequency, 3/8 cycles/px, is below Nyquist,
    # and 64 px hold whole periods, the two conditions of the spectral derivative
    lattice = Lattice.from_pitch(8)
    cov = np.array([[0.2**2, -0.01], [-0.01, 0.15**2]])
    shape = (64, 64)
    s = grid_image(shape, lattice, kind="checkerboard")
    shifts, w = gauss_hermite_shifts(cov)
    expect = np.tensordot(w, np.array([shifted(shape, lattice, a, kind="checkerboard")
                                       for a in shifts]), 1) - s
    exact = theory.mean_image_bias(s, cov, exact=True)
    assert exact.dtype == np.float64
    assert_allclose(exact, expect, rtol=0, atol=1e-12)  # grey levels, rounding
    second = theory.mean_image_bias(s, cov)
    # per Fourier component c_nu, the dropped fourth-order term is at most
    # |c_nu| (2 pi)^4 3 (nu^T C nu)^2 / 24 (grey levels)
    fy, fx = np.meshgrid(np.fft.fftfreq(64), np.fft.fftfreq(64), indexing="ij")
    q = cov[0, 0] * fx**2 + 2 * cov[0, 1] * fx * fy + cov[1, 1] * fy**2
    bound = np.sum(np.abs(np.fft.fft2(s)) / s.size * (2 * np.pi) ** 4 * q**2 / 8)
    assert np.max(np.abs(second - expect)) <= bound
    assert bound < 0.2 * np.max(np.abs(expect))
    # float32 stays float32, to single-precision rounding of grey levels ~1
    b32 = theory.mean_image_bias(s.astype(np.float32), cov)
    assert b32.dtype == np.float32
    assert_allclose(b32, second, rtol=0, atol=1e-5)


def test_spectral_and_analytic_bias_agree_on_band_limited_grid():
    lattice = Lattice.from_pitch(8)
    cov = np.diag(np.square(CASE1))
    s = grid_image((64, 64), lattice)
    assert_allclose(theory.mean_image_bias(s, cov),
                    theory.grid_mean_image_bias((64, 64), lattice, cov), atol=1e-14)


def test_spectral_bias_is_wrong_for_aliased_harmonics():
    # the documented limit: at pitch 5 the third harmonic of sin^3 is above Nyquist
    lattice = Lattice.from_pitch(5)
    cov = np.diag(np.square(CASE2))
    s = grid_image((60, 60), lattice)
    analytic = theory.grid_mean_image_bias((60, 60), lattice, cov)
    spectral = theory.mean_image_bias(s, cov)
    assert np.sqrt(np.mean((spectral - analytic) ** 2)) > 0.3 * np.sqrt(np.mean(analytic**2))


def test_bias_rms_is_the_level_of_the_averaged_image_rmse():
    lattice = Lattice.from_pitch(5)
    cov = np.diag(np.square(CASE1))
    A = 4096.0
    exact = theory.mean_image_bias_rms(lattice, cov, amplitude=A, exact=True)
    sampled = theory.mean_image_bias_rms(lattice, cov, amplitude=A, exact=True,
                                         shape=(50, 50))
    # 50 px hold whole periods and no harmonic product aliases to 0: same mean square
    assert_allclose(sampled, exact, rtol=1e-12)
    shifts, w = gauss_hermite_shifts(cov, n=16)
    s = grid_image((20, 20), lattice, amplitude=A)
    mean = np.tensordot(w, np.array([shifted((20, 20), lattice, a, amplitude=A)
                                     for a in shifts]), 1)
    # 20 px = 4 periods: the RMS over it is the RMS over the plane, to rounding
    assert_allclose(np.sqrt(np.mean((mean - s) ** 2)), exact, rtol=1e-10)
    second = theory.mean_image_bias_rms(lattice, cov, amplitude=A)
    assert 1.05 * exact < second < 1.1 * exact  # Prop. 2.1 overestimates case 1 by 7 %


# ------------------------------------------------------ eqs. (28)-(30): phase offset

def measured_offset(image, reference, lattice, sigma):
    """Phase of wft(image) minus that of wft(reference), median over valid pixels."""
    p, q = wft(image, lattice, sigma=sigma), wft(reference, lattice, sigma=sigma)
    valid = p.valid & q.valid
    return np.array([np.median(np.angle(p.psi[j] * np.conj(q.psi[j]))[valid])
                     for j in range(2)]), p, q


# the wft module measures an edge bias of ~1e-5 rad at its 3.5 sigma margin; the
# differences of two maps of the same grid cancel most of it
WFT_PHASE_TOL = 2e-5  # rad


@pytest.mark.parametrize("a", [(0.25, 0.0), (-0.3, 0.12), (0.07, -0.4)])
def test_sign_of_offset_against_wft(a):
    lattice = Lattice.from_pitch(6, angle=20.0)
    shape = (80, 80)
    s = grid_image(shape, lattice)
    v = shifted(shape, lattice, a)
    got, _, _ = measured_offset(v, s, lattice, 6.0)
    # s(x + a) raises the wft phase by +2 pi k . a
    assert_allclose(got, 2 * np.pi * lattice.K @ np.asarray(a), atol=WFT_PHASE_TOL)
    assert_allclose(got, theory.phase_offsets([a], lattice, exact=True), atol=WFT_PHASE_TOL)
    assert_allclose(got, theory.phase_offsets([a], lattice, exact=True, method="B"),
                    atol=WFT_PHASE_TOL)


def test_offset_of_averaged_image_against_wft():
    rng = np.random.default_rng(3)
    lattice = Lattice.from_pitch(5)
    shape = (72, 72)
    shifts = rng.normal(0, 1, (12, 2)) * np.asarray(CASE1)
    s = grid_image(shape, lattice, amplitude=4096.0)
    frames = [shifted(shape, lattice, a, amplitude=4096.0) for a in shifts]
    got, p, q = measured_offset(np.mean(frames, axis=0), s, lattice, 5.0)
    exact = theory.phase_offsets(shifts, lattice, exact=True)
    assert_allclose(got, exact, atol=WFT_PHASE_TOL)
    assert np.max(np.abs(exact)) > 100 * WFT_PHASE_TOL  # a resolved offset
    # eq. (29) for each wave vector, against a rigorous bound: the exact
    # fundamental is z2 + r with z2 = 1 + i m1 - m2/2, |r| <= mean|theta|^3 / 6
    eq29 = theory.phase_offsets(shifts, lattice)
    for j in range(2):
        theta = 2 * np.pi * shifts @ lattice.K[j]
        z2 = abs(1 + 1j * theta.mean() - 0.5 * np.mean(theta**2))
        bound = math.asin(np.mean(np.abs(theta) ** 3) / 6 / z2)
        assert abs(eq29[j] - got[j]) <= bound + WFT_PHASE_TOL
        assert eq29[j] == pytest.approx(theory.phase_offset(shifts[:, j], F))
        assert exact[j] == pytest.approx(theory.phase_offset(shifts[:, j], F, exact=True))
    # the averaged grid's modulus shrinks by the exact contrast factor; relative,
    # the ratio of two moduli of the same grid cancels most of the wft's edge bias
    valid = p.valid & q.valid
    ratio = np.median(np.abs(p.psi[0][valid]) / np.abs(q.psi[0][valid]))
    assert ratio == pytest.approx(theory.exact_contrast_factor(F, shifts[:, 0]), rel=1e-5)
    # method B: mean of the per-frame wft phases
    per_frame = np.mean([measured_offset(f, s, lattice, 5.0)[0] for f in frames], axis=0)
    assert_allclose(per_frame, theory.phase_offsets(shifts, lattice, exact=True, method="B"),
                    atol=WFT_PHASE_TOL)


def test_grid_modulus_matches_wft():
    lattice = Lattice.from_pitch(5)
    p = wft(grid_image((64, 64), lattice, amplitude=4096.0), lattice, sigma=5.0)
    mod = theory.grid_modulus(4096.0, 0.9)
    assert mod == pytest.approx(2048 * 0.9 * 3 / 16)
    # relative: the wft's edge bias of the modulus at its 4 sigma margin, measured
    # 5e-5 for this grid (it is 1e-9 at the centre)
    assert_allclose(p.modulus[:, p.valid], mod, rtol=1e-4)
    assert_allclose(p.modulus[:, 32, 32], mod, rtol=1e-8)


# ------------------------------------------------------------ Prop. 2.4, eq. (31)

def test_offset_std_matches_monte_carlo():
    rng = np.random.default_rng(4)
    R, T, sd = 10000, 25, 0.05
    alphas = rng.normal(0.0, sd, (R, T))
    eq29 = np.array([theory.phase_offset(a, F) for a in alphas])
    exact = np.array([theory.phase_offset(a, F, exact=True) for a in alphas])
    method_b = np.array([theory.phase_offset(a, F, method="B") for a in alphas])
    want = theory.phase_offset_std(F, sd**2, T)
    # relative: 4 standard errors of a sample std, 1/sqrt(2R) = 0.7 %, plus the
    # delta method's ~0.3 % at this vibration level
    tol = 4 / math.sqrt(2 * (R - 1)) + 0.003
    assert np.std(eq29) == pytest.approx(want, rel=tol)
    assert np.std(exact) == pytest.approx(want, rel=tol)
    assert np.std(method_b) == pytest.approx(theory.phase_offset_std(F, sd**2, T, method="B"),
                                             rel=tol)
    assert abs(np.mean(eq29)) < 4 * want / math.sqrt(R)  # zero mean
    # the worked example of the paper, 0.1 / sqrt(T), is rejected; ours is 0.063
    assert want * math.sqrt(T) == pytest.approx(0.063, abs=5e-4)
    assert abs(np.std(eq29) * math.sqrt(T) - 0.1) > 10 * tol * 0.063


# ------------------------------------------------------------------ WFT noise

def test_window_energy_continuous_limit():
    for sigma in (3.0, 4.5, 5.0, 10.0):
        assert_allclose(theory.window_energy(sigma),
                        theory.window_energy(sigma, continuous=True), rtol=1e-12)


def effective_samples(kernel):
    """Sum over lags of rho^2 for white noise filtered by ``kernel`` (px^2)."""
    K = np.fft.fft2(kernel, s=(4 * kernel.shape[0], 4 * kernel.shape[1]))
    ac = np.fft.ifft2(np.abs(K) ** 2).real
    rho = ac / ac[0, 0]
    return float(np.sum(rho**2))


def test_wft_noise_std_matches_monte_carlo():
    rng = np.random.default_rng(5)
    lattice = Lattice.from_pitch(5)
    sigma, A, noise_sd, R = 5.0, 4096.0, 30.0, 60
    s = grid_image((128, 128), lattice, amplitude=A)
    clean = wft(s, lattice, sigma=sigma)
    errs_phase, errs_deriv = [], []
    for _ in range(R):
        p = wft(s + rng.normal(0.0, noise_sd, s.shape), lattice, sigma=sigma)
        v = p.valid & clean.valid
        dphase = np.angle(p.psi * np.conj(clean.psi))
        errs_phase += [dphase[0][v], dphase[1][v]]
        errs_deriv += [(p.dphi[0, 0] - clean.dphi[0, 0])[v], (p.dphi[1, 1] - clean.dphi[1, 1])[v]]
    n_pix = errs_phase[0].size
    want_phase, want_deriv = theory.wft_noise_std(noise_sd**2, theory.grid_modulus(A, 0.9),
                                                  sigma)
    # Pixels are correlated through the window: the mean of X^2 over N pixels of
    # a Gaussian field has relative variance 2 sum(rho^2) / N. The two wave
    # vectors' noises are independent (window transfer at k1 - k2 ~ 1e-34).
    n = np.arange(-40, 41)
    g1 = np.exp(-(n**2) / (2 * sigma**2))
    g2d = np.outer(g1, g1)
    for errs, want, kernel in ((errs_phase, want_phase, g2d),
                               (errs_deriv, want_deriv, g2d * n[None, :])):
        got = math.sqrt(np.mean(np.concatenate(errs) ** 2))
        rel_sd_of_std = 0.5 * math.sqrt(2 * effective_samples(kernel) / (n_pix * 2 * R))
        # relative: 4 standard errors (about 4 %) of the Monte Carlo std
        assert got == pytest.approx(want, rel=4 * rel_sd_of_std)
        assert 4 * rel_sd_of_std < 0.05


def test_effective_noise_variance_matches_sensor_model():
    rng = np.random.default_rng(6)
    lattice = Lattice.from_pitch(5)
    s = grid_image((128, 128), lattice, amplitude=2000.0)
    T, K, L = 4, 0.28, 5.0
    stack = np.array([add_noise(s, K=K, L=L, rng=rng, bits=None) for _ in range(T)])
    resid = stack.mean(axis=0) - s
    want = theory.effective_noise_variance(K, L, float(s.mean()), T=T)
    # relative: 4 standard errors of a variance over 16384 independent pixels
    assert np.mean(resid**2) == pytest.approx(want, rel=4 * math.sqrt(2 / s.size))


# ----------------------------------------------------- eqs. (34)-(35): propagation

def test_noise_propagation_axis_aligned():
    lattice = Lattice.from_pitch(5)
    u = theory.displacement_noise_std(0.003, 0.004, lattice)
    assert_allclose(u, 5 / (2 * np.pi) * 0.005, rtol=1e-14)
    e = theory.strain_noise_std(3e-4, 4e-4, lattice)
    assert_allclose(e, np.array([1, 1, 2**-0.5]) * 5 / (2 * np.pi) * 5e-4, rtol=1e-14)


def test_noise_propagation_skew_lattice_matches_monte_carlo():
    rng = np.random.default_rng(7)
    lattice = Lattice((0.2, 0.03), (-0.05, 0.16))
    R = 200000
    ref, dfm = np.array([0.003, 0.002]), np.array([0.001, 0.004])
    dphi = rng.normal(size=(R, 2)) * np.hypot(ref, dfm)
    u = -np.linalg.solve(lattice.K, dphi.T).T / (2 * np.pi)
    # relative: 4 standard errors of a sample std, 1/sqrt(2R) = 0.16 %
    tol = 4 / math.sqrt(2 * R)
    assert_allclose(u.std(axis=0), theory.displacement_noise_std(ref, dfm, lattice), rtol=tol)
    dref = np.array([[1e-4, 2e-4], [3e-4, 1e-4]])
    ddef = np.array([[2e-4, 1e-4], [1e-4, 3e-4]])
    dD = rng.normal(size=(R, 2, 2)) * np.hypot(dref, ddef)
    G = -np.einsum("ij,rjm->rim", np.linalg.inv(lattice.K), dD) / (2 * np.pi)
    eps = np.stack([G[:, 0, 0], G[:, 1, 1], 0.5 * (G[:, 0, 1] + G[:, 1, 0])], axis=1)
    assert_allclose(eps.std(axis=0), theory.strain_noise_std(dref, ddef, lattice), rtol=tol)


# ----------------------------------------------------------------------- bad inputs

LAT = Lattice.from_pitch(5)


@pytest.mark.parametrize(("call", "name"), [
    (lambda: theory.profile_coefficients("zigzag"), "profile"),
    (lambda: theory.profile_coefficients("sin3", n_harmonics=0), "n_harmonics"),
    (lambda: theory.profile_coefficients(lambda t: np.ones(3)), "profile"),
    (lambda: theory.averaged_profile_coefficients([1, 2], F, 0, 0), "d"),
    (lambda: theory.averaged_profile_coefficients([0, 1, 0], 0.7, 0, 0), "frequency"),
    (lambda: theory.averaged_profile_coefficients([0, 1, 0], F, 0, -1), "mean_square"),
    (lambda: theory.contrast_factor(F, -0.1), "variance"),
    (lambda: theory.exact_contrast_factor(F, []), "alphas"),
    (lambda: theory.mean_image_bias(np.ones((16, 16)), [[1, 0], [0]]), "cov"),
    (lambda: theory.mean_image_bias(np.ones((16, 16)), [[1, 2], [2, 1]]), "cov"),
    (lambda: theory.mean_image_bias(np.ones((16, 16)), [[1, 0.1], [0, 1]]), "cov"),
    (lambda: theory.mean_image_bias(np.ones(16), np.eye(2)), "image"),
    (lambda: theory.grid_mean_image_bias((0, 8), LAT, np.eye(2)), "shape"),
    (lambda: theory.grid_mean_image_bias((8, 8), LAT, np.eye(2), contrast=2), "contrast"),
    (lambda: theory.mean_image_bias_rms(LAT, np.eye(2), amplitude=-1), "amplitude"),
    (lambda: theory.phase_offset([[0.1]], F), "shifts"),
    (lambda: theory.phase_offset([np.nan], F), "shifts"),
    (lambda: theory.phase_offset([0.1], 0.0), "frequency"),
    (lambda: theory.phase_offset([0.1], F, method="C"), "method"),
    (lambda: theory.phase_offsets([0.1, 0.2], LAT), "shifts_xy"),
    (lambda: theory.phase_offset_std(F, 0.0025, 0), "T"),
    (lambda: theory.phase_offset_std(F, 0.0025, 2.5), "T"),
    (lambda: theory.phase_offset_std(F, 2.0, 10), "variance"),
    (lambda: theory.window_energy(0), "sigma"),
    (lambda: theory.wft_noise_std(-1, 1, 5), "noise_variance"),
    (lambda: theory.wft_noise_std(1, 0, 5), "modulus"),
    (lambda: theory.grid_modulus(1, 0), "contrast"),
    (lambda: theory.effective_noise_variance(-1, 5, 100), "K"),
    (lambda: theory.effective_noise_variance(0.28, 5, 100, T=0), "T"),
    (lambda: theory.displacement_noise_std([1, 2, 3], 0, LAT), "phase_std_ref"),
    (lambda: theory.strain_noise_std(0, -1, LAT), "deriv_std_def"),
])
def test_bad_inputs_raise_value_error_naming_the_parameter(call, name):
    with pytest.raises(ValueError, match=name):
        call()


@pytest.mark.parametrize("call", [
    lambda: theory.phase_offsets([[0.1, 0.2]], "pitch 5"),
    lambda: theory.contrast_factor("0.2", 0.01),
    lambda: theory.phase_offset_std(F, True, 3),
])
def test_wrong_types_raise_type_error(call):
    with pytest.raises(TypeError):
        call()


def test_method_c_theory_reduces_to_method_b_and_its_offset():
    # exact shifts: the noise of T frames at full contrast, i.e. method B's terms,
    # and relative to s the mean position, method B's offset (Prop. 2.4, "B")
    v, mod, sigma, T, f = 1150.0, 344.0, 5.0, 25, 0.2
    p, d, off = theory.compensated_noise_std(v, mod, sigma, T, frequency=f,
                                             vibration_variance=0.1**2)
    p1, d1 = theory.wft_noise_std(v, mod, sigma)
    assert p == pytest.approx(p1 / math.sqrt(T), rel=1e-12)
    assert d == pytest.approx(d1 / math.sqrt(T), rel=1e-12)
    assert off == pytest.approx(theory.phase_offset_std(f, 0.1**2, T, method="B"),
                                rel=1e-12)
    with pytest.raises(ValueError, match="shift_error_variance"):
        theory.compensated_noise_std(v, mod, sigma, T, frequency=f,
                                     shift_error_variance=10.0)


def test_method_c_offset_about_the_mean_position_is_third_order():
    """Monte Carlo of the phasor algebra behind compensated_noise_std (no images).

    Centred estimates a_t - a_bar + e_t - e_bar leave the carrier's phase at
    arg mean exp(-2 i pi f (e_t - e_bar)) about the mean position: no first- or
    second-order term, a third-order one (the sample third central moment over 6) of
    variance (2 pi f)^6 Var(e)^3 (T - 1)(T - 2) / (6 T^3).
    With e = 0.1 px (200 times frame_shifts' error, to make the term measurable)
    and 20 000 stacks the sampling error of the std is 0.5 %; the next order of the
    expansion adds about (2 pi f Std e)^2 = 1.6 %, hence 5 %. Absolute shifts with
    the same errors keep the first-order term 2 pi f Std(e) / sqrt(T).
    """
    rng = np.random.default_rng(11)
    f, se, T, n = 0.2, 0.1, 10, 20000
    e = rng.normal(0, se, (n, T))
    w = 2 * np.pi * f
    centred = np.angle(np.mean(np.exp(-1j * w * (e - e.mean(axis=1, keepdims=True))), axis=1))
    absolute = np.angle(np.mean(np.exp(-1j * w * e), axis=1))
    # sensor noise switched off (v = 0) so that only the shift-error terms remain
    p_c = theory.compensated_noise_std(0.0, 1.0, 5.0, T, frequency=f,
                                       shift_error_variance=se**2)[0]
    p_a = theory.compensated_noise_std(0.0, 1.0, 5.0, T, frequency=f,
                                       shift_error_variance=se**2, centred=False)[0]
    assert np.std(centred) == pytest.approx(p_c, rel=0.05)
    assert np.std(absolute) == pytest.approx(p_a, rel=0.05)
    assert p_c < 0.05 * p_a  # third order against first
