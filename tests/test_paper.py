"""The paper's synthetic data set (§3.2): phase maps, vibrations, frames, Prop. 2.1."""

import math

import numpy as np
import pytest

from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.paper import (
    clean_frame,
    draw_shifts,
    iter_frames,
    mean_image_bias,
    paper_phases,
    vibrated_frame,
    vibration_cases,
)


@pytest.fixture(scope="module")
def phases512():
    return paper_phases((512, 512))


def test_phase_maps_largest_derivative_is_0005(phases512):
    _, der = phases512
    # each map is scaled on its own; both reach 0.005 rad/px (to rounding)
    for j in range(2):
        assert np.abs(der[j]).max() == pytest.approx(0.005, rel=1e-12)
    assert np.abs(der).max() == pytest.approx(0.005, rel=1e-12)


def test_phase_maps_reach_the_papers_maxima(phases512):
    phases, _ = phases512
    # §3.2 quotes 0.06 and 0.42 rad; our shapes give them to 1 % on 512 x 512
    assert phases[0].max() == pytest.approx(0.06, rel=0.01)
    assert phases[1].max() == pytest.approx(0.42, rel=0.01)


def test_phase_map_derivatives_match_finite_differences(phases512):
    phases, der = phases512
    # Central differences of the sampled maps: truncation error h^2/6 |phi'''|, at most
    # 0.06 (2 pi / 75)^3 / 6 = 6e-6 rad/px for phi1; phi2 is quadratic between kinks,
    # where the central difference is exact (to 1e-15).
    d1y = (phases[0, 2:, 1:-1] - phases[0, :-2, 1:-1]) / 2
    d1x = (phases[0, 1:-1, 2:] - phases[0, 1:-1, :-2]) / 2
    np.testing.assert_allclose(d1y, der[0, 1, 1:-1, 1:-1], atol=7e-6)
    np.testing.assert_allclose(d1x, der[0, 0, 1:-1, 1:-1], atol=7e-6)
    p2 = phases[1, :, 0]
    d2 = der[1, 1, :, 0]
    central = (p2[2:] - p2[:-2]) / 2
    H = p2.size
    kinks = np.array([k * (H - 1) / 4 for k in (1, 2, 3)])
    away = np.min(np.abs(np.arange(1, H - 1)[:, None] - kinks[None, :]), axis=1) > 1.0
    np.testing.assert_allclose(central[away], d2[1:-1][away], atol=1e-12)


def test_phi2_is_piecewise_quadratic_in_y_only(phases512):
    phases, der = phases512
    assert np.all(phases[1] == phases[1][:, :1])  # no x dependence
    assert np.all(der[1, 0] == 0)  # the null ground truth of the paper's Fig. 10
    d2 = der[1, 1, :, 0]
    jumps = np.abs(np.diff(d2))
    # a smooth piece changes by at most 0.005 * 3.2 / 128 = 1.3e-4 rad/px per row; the
    # three jumps are 1e-3 rad/px or more
    assert np.count_nonzero(jumps > 1e-3) == 3
    # piecewise linear derivative: second differences vanish away from the jumps
    dd = np.abs(np.diff(d2, 2))
    assert np.count_nonzero(dd > 1e-12) <= 6


def test_phase_maps_validation():
    with pytest.raises(ValueError, match="shape"):
        paper_phases((4, 100))
    with pytest.raises(ValueError, match="shape"):
        paper_phases("big")
    with pytest.raises(ValueError, match="max_derivative"):
        paper_phases((64, 64), max_derivative=-1.0)


def test_vibration_cases_are_the_papers():
    assert vibration_cases() == {1: (0.15, 0.1), 2: (0.1, 0.05), 3: (0.01, 0.01),
                                 4: (0.001, 0.005)}


@pytest.mark.parametrize("case", [1, 2, 3, 4, (0.3, 0.02)])
def test_shift_sample_moments(case):
    T = 40000
    sa, sb = vibration_cases()[case] if isinstance(case, int) else case
    sh = draw_shifts(T, case, rng=np.random.default_rng(7))
    assert sh.shape == (T, 2)
    # 4.5 standard errors: the mean's is sigma/sqrt(T), the standard deviation's
    # sigma/sqrt(2T), the correlation's 1/sqrt(T); false alarm below 1e-5 per check
    tol = 4.5 / math.sqrt(T)
    for k, s in enumerate((sa, sb)):
        assert abs(sh[:, k].mean()) < tol * s
        assert sh[:, k].std() == pytest.approx(s, rel=tol / math.sqrt(2))
    assert abs(np.corrcoef(sh.T)[0, 1]) < tol


def test_shifts_are_seeded_and_shared_across_cases():
    a = draw_shifts(50, 1, rng=3)
    np.testing.assert_array_equal(a, draw_shifts(50, 1, rng=np.random.default_rng(3)))
    assert not np.array_equal(a, draw_shifts(50, 1, rng=4))
    # the same draws, scaled: case 2 = case 1 * (0.1/0.15, 0.05/0.1)
    np.testing.assert_allclose(draw_shifts(50, 2, rng=3), a * [0.1 / 0.15, 0.05 / 0.1],
                               rtol=1e-15)


def test_shift_validation():
    with pytest.raises(ValueError, match="case"):
        draw_shifts(3, 5)
    with pytest.raises(TypeError, match="case"):
        draw_shifts(3, "strong")
    with pytest.raises(ValueError, match="T"):
        draw_shifts(0, 1)
    with pytest.raises(ValueError, match="case"):
        draw_shifts(3, (-0.1, 0.1))


def test_clean_frame_is_eq1():
    phases, _ = paper_phases((64, 80))
    lat = Lattice.from_pitch(5.0)

    def lookup(X, Y):  # the maps at the integer pixel positions
        i, j = np.rint(Y).astype(int), np.rint(X).astype(int)
        return phases[0][i, j], phases[1][i, j]

    ref = synthetic.grid_image((64, 80), lat, amplitude=4096.0, contrast=0.9,
                               phases=lookup)
    np.testing.assert_allclose(clean_frame(phases), ref, rtol=1e-13)


def test_clean_frame_integer_shift_is_a_translation():
    phases, _ = paper_phases((64, 64))
    s = clean_frame(phases)
    v = clean_frame(phases, (2.0, -3.0))  # v(x, y) = s(x + 2, y - 3)
    np.testing.assert_allclose(v[3:, :-2], s[:-3, 2:], rtol=1e-13)


def test_clean_frame_bilinear_phase_interpolation():
    phases, _ = paper_phases((48, 48))
    a, b = 0.3, -0.45
    v = clean_frame(phases, (a, b), amplitude=2.0, contrast=1.0, profile="sin")
    # direct evaluation of eq. (1) at one pixel with hand-written bilinear weights
    i, j = 20, 17
    y0, x0 = i - 1, j  # y + b = 19.55 lies between rows 19 and 20, x + a between 17, 18
    fy, fx = (i + b) - y0, (j + a) - x0

    def bil(p):
        return ((1 - fy) * (1 - fx) * p[y0, x0] + (1 - fy) * fx * p[y0, x0 + 1]
                + fy * (1 - fx) * p[y0 + 1, x0] + fy * fx * p[y0 + 1, x0 + 1])

    t1 = 2 * np.pi / 5 * (j + a) + bil(phases[0])
    t2 = 2 * np.pi / 5 * (i + b) + bil(phases[1])
    expected = 1.0 * (2 + 0.5 * np.sin(t1) + 0.5 * np.sin(t2))
    assert v[i, j] == pytest.approx(expected, rel=1e-13)


def test_noise_variance_follows_k_l_plus_l():
    phases, _ = paper_phases((48, 48))
    s = clean_frame(phases)
    N = 300
    K, L = 0.28, 5.0
    stack = np.stack([vibrated_frame(phases, (0.0, 0.0), K=K, L=L, rng=r)
                      for r in np.random.default_rng(11).spawn(N)])
    # mean: unbiased (rounding is symmetric); standard error sqrt(var/N) <= 2.4 grey
    # levels per pixel, so the average over 2304 pixels is within 5 * 2.4/48 = 0.25
    assert abs(float(np.mean(stack.mean(axis=0) - s))) < 0.25
    # variance: the per-pixel sample variance over N frames has a relative standard
    # error sqrt(2/(N-1)) = 8 %; averaged over 2304 independent pixels, 0.17 %.
    # The model adds the rounding's 1/12 grey level^2. Tolerance: 5 standard errors.
    expected = K * s + L + 1.0 / 12.0
    ratio = stack.var(axis=0, ddof=1) / expected
    assert float(ratio.mean()) == pytest.approx(1.0, abs=5 * math.sqrt(2 / (N - 1)) / 48)
    # slope in l: regress the variance on the intensity; K within 3 %, about 6 of its
    # standard errors (the intensity spans 1000-6000 grey levels)
    slope = np.polyfit(s.ravel(), stack.var(axis=0, ddof=1).ravel(), 1)[0]
    assert slope == pytest.approx(K, rel=0.03)


def test_frames_are_reproducible_and_streamed():
    phases, _ = paper_phases((32, 32))
    sh = draw_shifts(4, 2, rng=0)
    a = list(iter_frames(phases, sh, rng=5))
    b = list(iter_frames(phases, sh, rng=np.random.default_rng(5)))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0], a[1])
    # a prefix of the stack does not depend on the stack's length
    c = list(iter_frames(phases, sh[:2], rng=5))
    np.testing.assert_array_equal(c[1], a[1])
    assert np.all(a[0] == np.round(a[0]))  # 12-bit quantisation: integer grey levels
    assert a[0].max() > 4095  # A = 2^12 is not clipped (see gridstrain.paper)


def test_frame_validation():
    phases, _ = paper_phases((32, 32))
    with pytest.raises(ValueError, match="phases"):
        clean_frame(phases[0])
    with pytest.raises(ValueError, match="shift"):
        clean_frame(phases, 0.5)
    with pytest.raises(ValueError, match="contrast"):
        clean_frame(phases, contrast=1.5)
    with pytest.raises(ValueError, match="shifts"):
        list(iter_frames(phases, [0.1, 0.2]))


def test_prop21_bias_matches_gaussian_quadrature():
    # Oracle: E[s(x + alpha, y + beta)] by 12 x 12 Gauss-Hermite quadrature over the
    # generator itself (bilinear phases included). Prop. 2.1 truncates at second order:
    # with sigma = (0.03, 0.02) px the third harmonic's fourth-order term is
    # (2 pi 3 f sigma)^2 / 4 = 0.3 % of the bias; 2 % leaves room for the phase-map
    # terms that eqs. (10)-(11) neglect.
    phases, _ = paper_phases((40, 40))
    std = (0.03, 0.02)
    z, w = np.polynomial.hermite_e.hermegauss(12)
    w = w / w.sum()
    s = clean_frame(phases)
    expect = sum(wa * wb * clean_frame(phases, (std[0] * za, std[1] * zb))
                 for za, wa in zip(z, w, strict=True) for zb, wb in zip(z, w, strict=True))
    pred = mean_image_bias(phases, (std[0] ** 2, std[1] ** 2))
    inner = (slice(2, -2), slice(2, -2))  # the map edges are repeated beyond the image
    err = (expect - s)[inner] - pred[inner]
    assert np.sqrt(np.mean(err**2)) < 0.02 * np.sqrt(np.mean(pred[inner] ** 2))
