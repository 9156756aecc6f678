"""Tests of gridstrain.uncertainty: Anscombe transform and noise estimation from a stack."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import stats

from gridstrain.models import add_noise, grid_image
from gridstrain.phase import Lattice
from gridstrain.uncertainty import NoiseModel, anscombe, estimate_noise, inverse_anscombe

# Paper defaults, 12-bit grey levels (../shared/paper/README.md).
K_TRUE, L_TRUE = 0.28, 5.0
# Rounding to integer grey levels adds a uniform error of variance 1/12 to every
# sample, which the model Var = K l + L counts in L.
L_EFF = L_TRUE + 1 / 12
CASE1 = (0.15, 0.1)  # px, paper §3.2
CASE2 = (0.1, 0.05)
LAT = Lattice.from_pitch(5.0)


def clean_stack(shape, ab, *, amplitude=2000.0, reflectance=None):
    """Noise-free frames ``s(x + a_t, y + b_t)`` (eq. 2) of the paper's grid."""
    return np.array([grid_image(shape, LAT, amplitude=amplitude, reflectance=reflectance,
                                displacement=lambda X, Y, a=a, b=b: (-a + 0 * X, -b + 0 * Y))
                     for a, b in ab])


def noisy(clean, rng, *, clip=False):
    return np.array([add_noise(c, K=K_TRUE, L=L_TRUE, rng=rng, bits=12, clip=clip)
                     for c in clean])


def theory_std(clean, T, degree=3, *, dof=None):
    """Standard errors of (K, L) of the pixel-level weighted fit, from theory.

    Each pixel's residual variance has variance 2 V^2 / dof (Gaussian noise) with
    V = K l + L at its level l: the inverse Fisher information of the linear fit.
    ``dof`` defaults to that of the polynomial model of ``degree``.
    """
    p = (degree + 1) * (degree + 2) // 2
    lvl = clean.mean(axis=0).ravel()
    w = (T - p if dof is None else dof) / (2 * (K_TRUE * lvl + L_EFF) ** 2)
    A = np.column_stack([lvl, np.ones_like(lvl)])
    cov = np.linalg.inv(A.T @ (w[:, None] * A))
    return np.sqrt(np.diag(cov))


@pytest.fixture(scope="module")
def case2():
    """A 256 x 256, T = 50 stack with case-2 vibrations and the paper's noise."""
    rng = np.random.default_rng(2015)
    T = 50
    ab = rng.normal(size=(T, 2)) * CASE2
    clean = clean_stack((256, 256), ab)
    return {"ab": ab, "clean": clean, "frames": noisy(clean, rng), "T": T}


@pytest.fixture(scope="module")
def case2_model(case2):
    return estimate_noise(case2["frames"], LAT)


# ------------------------------------------------------------------ Anscombe

def test_anscombe_stabilises_variance():
    rng = np.random.default_rng(1)
    for level in (100.0, 300.0, 1000.0, 2000.0, 3500.0):
        z = add_noise(np.full(200_000, level), K=K_TRUE, L=L_TRUE, rng=rng, bits=None)
        std = anscombe(z, K=K_TRUE, L=L_TRUE).std()
        # relative: the sample std of 2e5 values is known to 0.16 %, and the
        # transform's own departure from unit variance is 3 K / (8 l) < 0.1 %
        # at l >= 100; 1 % is 5 standard errors.
        assert abs(std - 1) < 0.01, (level, std)


def test_anscombe_with_quantisation_and_offset_in_L():
    # A black-level offset o enters only through L = s^2 - K o (documented): data
    # with offset 100 and read variance 5 behave as L = 5 - 0.28 * 100 = -23.
    rng = np.random.default_rng(2)
    lam = 1500.0 / K_TRUE
    z = K_TRUE * rng.poisson(lam, 200_000) + 100 + rng.normal(0, np.sqrt(5.0), 200_000)
    z = np.round(z)
    f = anscombe(z, K=K_TRUE, L=5.0 + 1 / 12 - K_TRUE * 100)
    assert abs(f.std() - 1) < 0.01  # relative, as above


def test_inverse_of_forward_is_identity_without_noise_terms():
    # The closed-form inverse and the algebraic one differ by the 1/8 and 1/D
    # bias terms: check the transform pair through their known difference.
    z = np.linspace(10.0, 4000.0, 50)
    D = anscombe(z, K=K_TRUE, L=L_TRUE)
    algebraic = ((K_TRUE * D / 2) ** 2 - 3 * K_TRUE**2 / 8 - L_TRUE) / K_TRUE
    assert_allclose(algebraic, z, rtol=1e-12)
    r = np.sqrt(1.5)
    extra = K_TRUE * (0.25 + r / (4 * D) - 11 / (8 * D**2) + 5 * r / (8 * D**3))
    assert_allclose(inverse_anscombe(D, K=K_TRUE, L=L_TRUE) - z, extra, atol=1e-9)


def _exact_mean(lam, K, L):
    """E[anscombe(z)] for z = K Poisson(lam) + N(0, L): Poisson sum x Gauss-Hermite."""
    n = np.arange(int(lam + 40 * np.sqrt(lam) + 60))
    pmf = stats.poisson.pmf(n, lam)
    if L == 0:
        return float(pmf @ anscombe(K * n, K=K, L=0.0))
    x, w = np.polynomial.hermite_e.hermegauss(80)
    z = K * n[:, None] + np.sqrt(L) * x[None, :]
    return float(pmf @ (anscombe(z, K=K, L=L) @ (w / w.sum())))


@pytest.mark.parametrize(("K", "L"), [(1.0, 0.0), (1.0, 1.0), (K_TRUE, L_TRUE)])
@pytest.mark.parametrize("lam", [0.5, 1.0, 5.0, 30.0, 1000.0, 1e4])
def test_inverse_anscombe_is_unbiased_on_exact_expectations(K, L, lam):
    D = _exact_mean(lam, K, L)
    err = (float(inverse_anscombe(D, K=K, L=L)) - K * lam) / K  # electrons
    # electrons: the documented accuracy of the closed form is 0.04 e- from half an
    # electron up; the algebraic inverse misses by 0.25 e- (checked below), so
    # 0.05 e- separates the two.
    assert abs(err) < 0.05
    algebraic = ((K * D / 2) ** 2 - 3 * K**2 / 8 - L) / K
    assert abs(algebraic - K * lam) / K > 0.1


def test_inverse_anscombe_round_trip_on_simulated_data():
    rng = np.random.default_rng(3)
    N = 1_000_000
    for level in (50.0, 500.0, 3000.0):
        z = add_noise(np.full(N, level), K=K_TRUE, L=L_TRUE, rng=rng, bits=None)
        back = float(inverse_anscombe(anscombe(z, K=K_TRUE, L=L_TRUE).mean(),
                                      K=K_TRUE, L=L_TRUE))
        # grey levels: the mean of N unit-variance values is known to 1/sqrt(N),
        # i.e. sqrt(K l + L) / sqrt(N) grey levels; 4 of those plus the closed
        # form's 0.04 electrons.
        tol = 4 * np.sqrt(K_TRUE * level + L_TRUE) / np.sqrt(N) + 0.04 * K_TRUE
        assert abs(back - level) < tol, (level, back)


def test_anscombe_dtype_and_inputs():
    img = np.linspace(100, 4000, 64, dtype=np.float32).reshape(8, 8)
    copy = img.copy()
    f = anscombe(img, K=K_TRUE, L=L_TRUE)
    assert f.dtype == np.float32
    assert inverse_anscombe(f, K=K_TRUE, L=L_TRUE).dtype == np.float32
    np.testing.assert_array_equal(img, copy)
    assert anscombe(img.astype(np.uint16), K=K_TRUE, L=L_TRUE).dtype == np.float64
    # float32: 7 significant digits on levels of 1e3
    assert_allclose(inverse_anscombe(f, K=K_TRUE, L=L_TRUE), img, rtol=1e-4, atol=0.1)
    with pytest.raises(ValueError, match="K must be a finite positive"):
        anscombe(img, K=0.0, L=L_TRUE)
    with pytest.raises(ValueError, match="L must be a finite number"):
        anscombe(img, K=K_TRUE, L=float("nan"))
    with pytest.raises(TypeError, match="L must be a finite number"):
        anscombe(img, K=K_TRUE, L="5")
    with pytest.raises(TypeError, match="image must be a real numeric array"):
        anscombe(np.array(["a"]), K=K_TRUE, L=L_TRUE)
    with pytest.raises(ValueError, match="positive values"):
        inverse_anscombe(np.array([1.0, 0.0]), K=K_TRUE, L=L_TRUE)


# ------------------------------------------------------------------ NoiseModel

def test_noise_model_units_and_variance():
    m = NoiseModel(K=16 * K_TRUE, L=256 * L_TRUE, K_ci=(4.0, 5.0), L_ci=(1000.0, 1500.0),
                   scale=16)
    assert_allclose(m.variance([0.0, 1000.0]), [256 * L_TRUE, 16 * K_TRUE * 1000 + 256 * L_TRUE])
    assert_allclose([m.K_sensor, m.L_sensor], [K_TRUE, L_TRUE])
    assert_allclose(m.K_sensor_ci, (0.25, 0.3125))
    assert_allclose(m.L_sensor_ci, (1000 / 256, 1500 / 256))
    assert "sensor units" in repr(m)
    with pytest.raises(AttributeError):
        m.K = 1.0
    with pytest.raises(ValueError, match="scale must be a finite positive"):
        NoiseModel(K=1.0, L=1.0, scale=-1)
    with pytest.raises(ValueError, match="K must be a finite number"):
        NoiseModel(K=float("inf"), L=1.0)
    assert NoiseModel(K=K_TRUE, L=L_TRUE).K_sensor_ci is None


# --------------------------------------------------------- estimation (fast)

def test_estimate_case2_acceptance(case2, case2_model):
    m = case2_model
    sK, sL = theory_std(case2["clean"], case2["T"], dof=m.dof)
    # relative: the acceptance target; the statistical error is 0.5 % (sK / K)
    assert abs(m.K / K_TRUE - 1) < 0.03
    # grey levels^2: L is an extrapolation to level 0 whose standard error from
    # theory is sL (2.7 here, half of L): 3 standard errors. The 20 % target needs
    # more pixels or a wider level range (tests below).
    assert abs(m.L - L_EFF) < 3 * sL
    # the reported 95 % intervals agree with the theoretical standard errors
    # (binning costs a few % of efficiency; 25 % margin)
    half_K = (m.K_ci[1] - m.K_ci[0]) / 2
    half_L = (m.L_ci[1] - m.L_ci[0]) / 2
    assert 0.8 < half_K / (1.96 * sK) < 1.25
    assert 0.8 < half_L / (1.96 * sL) < 1.25
    assert m.n_frames == case2["T"]
    # the mean, the 2 shifts and the first-order harmonics: at 0.1 px of vibration
    # the higher orders lower the residual variance by less than 1 %
    assert m.dof == case2["T"] - 7
    assert m.motion_terms[:2] == ("x", "y")
    assert m.n_pixels > 0.99 * 256 * 256  # no honest pixel rejected (1e-6 test)
    # reduced chi-square over 64 bins (62 degrees of freedom, std 0.18) when the
    # linear law and the Gaussian weights hold: about 3 standard deviations each way
    assert 0.5 < m.reduced_chi2 < 1.6
    assert m.levels.shape == m.variances.shape == m.variance_errors.shape


def test_naive_temporal_variance_is_biased(case2):
    # Ignoring vibrations: the per-pixel temporal variance mixes the noise with
    # (alpha_t, beta_t) . grad s (eq. 3), thousands of grey levels^2 on line edges.
    frames = case2["frames"]
    var = frames.var(axis=0, ddof=1).ravel()
    lvl = frames.mean(axis=0).ravel()
    K_naive, _ = np.polyfit(lvl, var, 1)
    assert abs(K_naive / K_TRUE - 1) > 0.03  # off by more than the tolerance...
    assert abs(K_naive / K_TRUE - 1) > 0.3  # ...by far (measured: -46 %)


def test_true_shifts_give_the_same_model(case2, case2_model):
    m = estimate_noise(case2["frames"], shifts=case2["ab"] + 3.0)  # any origin
    # relative: the measured shifts are off by 5e-4 px, which adds (5e-4 |grad s|)^2
    # ~ 0.1 grey level^2 to a few pixels' variance: 0.2 % on K at most
    assert abs(m.K / case2_model.K - 1) < 2e-3
    assert abs(m.L - case2_model.L) < 0.5  # grey levels^2, same reason


def test_streamed_frames_equal_array_and_progress(case2, case2_model):
    calls = []
    m = estimate_noise((f for f in case2["frames"]), LAT,
                       progress=lambda f, msg: calls.append((f, msg)))
    assert_allclose([m.K, m.L], [case2_model.K, case2_model.L], rtol=1e-10)
    assert len(calls) >= case2["T"]
    assert calls[-1][0] == 1.0
    assert all(0.0 <= f <= 1.0 for f, _ in calls)


def test_lattice_detected_when_not_given(case2, case2_model):
    frames = case2["frames"][:20, :128, :128]
    m = estimate_noise(frames)
    m_lat = estimate_noise(frames, LAT)
    # a detected pitch off by 1e-5 scales the shifts by 1e-5, which changes the
    # fitted space by as little: 1e-4 relative on K, 1e-3 grey levels^2 on L
    assert_allclose(m.K, m_lat.K, rtol=1e-4)
    assert_allclose(m.L, m_lat.L, atol=1e-3)


def test_storage_x16_is_equivariant(case2, case2_model):
    frames16 = (case2["frames"] * 16).astype(np.uint16)
    m = estimate_noise(frames16, LAT, scale=16, saturation=4095 * 16)
    assert_allclose(m.K, 16 * case2_model.K, rtol=1e-8)  # the fit is scale-equivariant
    assert_allclose(m.L, 256 * case2_model.L, rtol=1e-6)
    assert_allclose([m.K_sensor, m.L_sensor], [case2_model.K, case2_model.L], rtol=1e-6)
    assert abs(m.K / (16 * K_TRUE) - 1) < 0.03  # relative, acceptance target
    assert m.scale == 16


def test_saturated_pixels_are_left_out():
    rng = np.random.default_rng(7)
    T = 50
    ab = rng.normal(size=(T, 2)) * CASE2
    # A = 3000: the brightest crossings reach 4350 > 4095; 4 % of pixels clip
    clean = clean_stack((256, 256), ab, amplitude=3000.0)
    frames = noisy(clean, rng, clip=True)
    assert (frames >= 4095).any(axis=0).mean() > 0.02
    m = estimate_noise(frames, LAT, saturation=4095)
    keep = clean.max(axis=0) < 3900  # roughly the pixels the estimator keeps
    _, sL = theory_std(clean[:, keep], T)
    assert abs(m.K / K_TRUE - 1) < 0.03  # relative, acceptance target
    assert abs(m.L - L_EFF) < 3 * sL  # grey levels^2: 3 standard errors (sL = 4)
    # without the saturation level the clipped pixels drag the fit (measured:
    # K -5.9 %, L +43 on this stack): the option is needed
    bad = estimate_noise(frames, LAT)
    assert abs(bad.L - L_EFF) > 3 * sL or abs(bad.K / K_TRUE - 1) > 0.03


def test_outlier_pixels_are_rejected(case2, case2_model):
    # 1 % of the pixels with extra noise (hot pixels, dust): variance x4 there
    rng = np.random.default_rng(8)
    bad = rng.random((256, 256)) < 0.01
    frames = case2["frames"] + bad * rng.normal(0, 40.0, size=case2["frames"].shape)
    m = estimate_noise(frames, LAT)
    # relative and grey levels^2: the hot pixels are rejected (97 % of them at
    # this T) and the truncation is corrected, so the estimates move by a small
    # fraction of their standard errors (0.5 % on K, 2.7 on L)
    assert abs(m.K / case2_model.K - 1) < 3e-3
    assert abs(m.L - case2_model.L) < 1.0
    assert m.n_pixels < case2_model.n_pixels - 0.9 * bad.sum()


def test_case1_with_default_degree():
    rng = np.random.default_rng(9)
    T = 50
    ab = rng.normal(size=(T, 2)) * CASE1
    clean = clean_stack((192, 192), ab)
    m = estimate_noise(noisy(clean, rng), LAT)
    _, sL = theory_std(clean, T)
    assert abs(m.K / K_TRUE - 1) < 0.03  # relative, acceptance target
    assert abs(m.L - L_EFF) < 3 * sL  # grey levels^2: 3 standard errors (sL = 3.6)


def test_wide_level_range_gives_L_within_20_percent():
    # Lighting falling from 100 % to 10 % across the field spreads the levels
    # from 200 to 2900 grey levels: the intercept is then well constrained.
    rng = np.random.default_rng(10)
    T = 50
    ab = rng.normal(size=(T, 2)) * CASE2
    clean = clean_stack((256, 256), ab, reflectance=lambda X, Y: 0.1 + 0.9 * X / 256)
    m = estimate_noise(noisy(clean, rng), LAT)
    _, sL = theory_std(clean, T)
    assert 3 * sL < 0.2 * L_EFF  # the design can meet the target (sL = 0.26)...
    assert abs(m.L / L_EFF - 1) < 0.2  # ...and does: relative, the acceptance target
    assert abs(m.K / K_TRUE - 1) < 0.03


def test_validation_errors(case2):
    frames = case2["frames"][:16]
    with pytest.raises(ValueError, match="at least 13 frames"):
        estimate_noise(frames[:12], LAT, degree=3)
    with pytest.raises(ValueError, match="at least 6 frames"):
        estimate_noise(frames[:5], LAT)
    with pytest.raises(ValueError, match="degree must be"):
        estimate_noise(frames, LAT, degree=5)
    with pytest.raises(ValueError, match=r"shifts must be a finite \(T, 2\)"):
        estimate_noise(frames, LAT, shifts=np.zeros((16, 3)))
    with pytest.raises(ValueError, match="shifts has 11 rows but frames hold 16"):
        estimate_noise(frames, LAT, shifts=np.ones((11, 2)))
    with pytest.raises(ValueError, match="shifts has 11 rows but frames hold more"):
        estimate_noise((f for f in frames), LAT, shifts=np.ones((11, 2)))
    with pytest.raises(ValueError, match="use degree=0"):
        estimate_noise(frames, LAT, shifts=np.zeros((16, 2)), degree=3)
    with pytest.raises(ValueError, match="saturation must be a finite positive"):
        estimate_noise(frames, LAT, saturation=-1.0)
    with pytest.raises(TypeError, match="lattice must be a Lattice"):
        estimate_noise(frames, 5.0)
    with pytest.raises(ValueError, match="n_bins"):
        estimate_noise(frames, LAT, n_bins=2)
    with pytest.raises(ValueError, match="at least one frame"):
        estimate_noise([], LAT)
    with pytest.raises(ValueError, match="same shape"):
        estimate_noise([frames[0], frames[1][:100]], LAT)
    with pytest.raises(ValueError, match="shows no grid"):
        estimate_noise(frames, Lattice.from_pitch(7.3, angle=20.0))


@pytest.mark.parametrize("vibration", [0.0, 0.1, 0.3, 0.5])
def test_vibrated_stack_gives_K_and_L(vibration):
    """Rigid vibrations of 0 to 0.5 px (std, both axes) regressed out by the carriers'
    harmonics: K and L as on a still stack. The grid's response to a shift is
    periodic in the carrier phase, which a polynomial in the shifts only follows
    while 2 pi a / p stays small (at 0.3 px the cubic states L at 20 times its
    value, at 0.5 px no signal-dependent noise at all)."""
    rng = np.random.default_rng(7)
    T = 50
    ab = rng.normal(size=(T, 2)) * vibration
    clean = clean_stack((160, 160), ab)
    frames = noisy(clean, rng)
    m = estimate_noise(frames, LAT)
    _, sL = theory_std(clean, T, dof=m.dof)
    assert abs(m.K / K_TRUE - 1) < 0.03  # relative, acceptance target (0.5 % std err)
    assert abs(m.L - L_EFF) < 3 * sL  # grey levels^2: 3 standard errors (sL 2.8-4.4)
    # the harmonics are fitted only where the residual needs them
    n_harm = sum(t not in ("x", "y") for t in m.motion_terms)
    assert (n_harm == 0) if vibration == 0 else (n_harm >= 4)
    if vibration >= 0.3:
        # the polynomial model of the same frames is wrong by far more
        with np.errstate(all="ignore"):
            try:
                poly = estimate_noise(frames, LAT, degree=3)
            except ValueError:  # no signal-dependent noise left to find
                return
        assert abs(poly.L - L_EFF) > 10 * sL


def test_static_stack_with_degree_zero():
    # A truly static set-up: the plain temporal variance is the right estimator.
    rng = np.random.default_rng(11)
    clean = clean_stack((128, 128), np.zeros((40, 2)))
    m = estimate_noise(noisy(clean, rng), degree=0)
    _, sL = theory_std(clean, 40, degree=0)
    assert abs(m.K / K_TRUE - 1) < 0.03  # relative, acceptance target
    assert abs(m.L - L_EFF) < 3 * sL  # grey levels^2: 3 standard errors


# --------------------------------------------------------- estimation (slow)

@pytest.mark.slow
def test_acceptance_L_within_20_percent_on_a_large_stack():
    # The paper's grid (A = 2000, gamma = 0.9) needs many pixel-frames for L:
    # 1024 x 1024 x 200 frames, streamed, gives sL = 0.3 grey levels^2 (6 %).
    rng = np.random.default_rng(12)
    T = 200
    ab = rng.normal(size=(T, 2)) * CASE2
    frames = (add_noise(grid_image((1024, 1024), LAT, amplitude=2000.0,
                                   displacement=lambda X, Y, a=a, b=b: (-a + 0 * X, -b + 0 * Y)),
                        K=K_TRUE, L=L_TRUE, rng=rng) for a, b in ab)
    m = estimate_noise(frames, LAT)
    assert abs(m.K / K_TRUE - 1) < 0.03  # relative, acceptance target
    assert abs(m.L / L_EFF - 1) < 0.2  # relative, acceptance target (3.4 sL)


@pytest.mark.slow
def test_confidence_interval_coverage():
    # Over 40 independent stacks the 95 % intervals must hold the truth about
    # 38 times; at least 34 keeps the false-alarm rate of this test below 2 %.
    hits_K = hits_L = 0
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        ab = rng.normal(size=(30, 2)) * CASE2
        m = estimate_noise(noisy(clean_stack((128, 128), ab), rng), LAT)
        hits_K += m.K_ci[0] <= K_TRUE <= m.K_ci[1]
        hits_L += m.L_ci[0] <= L_EFF <= m.L_ci[1]
    assert hits_K >= 34
    assert hits_L >= 34
