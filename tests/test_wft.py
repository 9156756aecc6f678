"""Windowed Fourier transform against a direct double sum (paper eqs. 22-25)."""

import numpy as np
import pytest

from gridstrain import Lattice, synthetic, wft
from gridstrain.wft import transfer_function


def _modulated_grid(shape=(128, 128), angle=20.0, pitch=5.0):
    lat = Lattice.from_pitch(pitch, angle=angle)
    img = synthetic.grid_image(
        shape, lat, amplitude=1000.0,
        phases=lambda X, Y: (0.4 * np.sin(2 * np.pi * Y / 50), 0.3 * np.cos(2 * np.pi * X / 40)))
    return lat, img


def _direct(img, k, sigma, px, py, truncate=None):
    """Eq. (22) summed literally over the image, with the analytic window derivative.

    The image is mean-removed, as gridstrain defines (see gridstrain.conventions).
    """
    H, W = img.shape
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    v = img - img.mean()
    d2 = (xx - px) ** 2 + (yy - py) ** 2
    n = np.arange(-400, 401)
    norm = np.exp(-(n**2) / (2 * sigma**2)).sum() ** 2  # unit sum of the sampled window
    g = np.exp(-d2 / (2 * sigma**2)) / norm
    if truncate is not None:
        g = np.where((np.abs(xx - px) <= truncate * sigma) & (np.abs(yy - py) <= truncate * sigma),
                     g, 0.0)
        g /= g.sum()
    e = np.exp(-2j * np.pi * (k[0] * xx + k[1] * yy))
    psi = np.sum(v * g * e)
    dpx = np.sum(v * g * (xx - px) / sigma**2 * e)  # d/dx of g(xi - x)
    dpy = np.sum(v * g * (yy - py) / sigma**2 * e)
    return psi, np.imag(np.conj(psi) * dpx) / abs(psi) ** 2, np.imag(np.conj(psi) * dpy) / abs(
        psi) ** 2


def test_equals_direct_sum_at_random_interior_pixels():
    lat, img = _modulated_grid()
    sigma = 5.0
    res = wft(img, lat, sigma=sigma)
    rng = np.random.default_rng(7)
    # at >= 8 sigma from the border the image edge weighs < exp(-32) in either sum
    pts = rng.integers(40, 88, size=(20, 2))
    for py, px in pts:
        for j, k in enumerate((lat.k1, lat.k2)):
            psi, dx, dy = _direct(img, k, sigma, px, py)
            # issue bound: 1e-9 rad on phases and rad/px on derivatives (we see ~1e-15)
            assert abs(np.angle(res.psi[j, py, px] / psi)) < 1e-9
            assert abs(res.psi[j, py, px] / psi - 1) < 1e-9
            assert abs(res.dphi[j, 0, py, px] - dx) < 1e-9
            assert abs(res.dphi[j, 1, py, px] - dy) < 1e-9


def test_truncated_window_would_fail_the_bound():
    # The MATLAB toolbox and scipy truncate the Gaussian at 4 sigma. That changes the
    # derivatives by more than the 1e-7 rad/px we require; our untruncated window
    # matches the untruncated sum (previous test), so this checks the oracle can tell.
    lat, img = _modulated_grid()
    res = wft(img, lat, sigma=5.0)
    worst = 0.0
    for py, px in [(60, 64), (70, 50), (55, 77)]:
        _, dx, dy = _direct(img, lat.k1, 5.0, px, py, truncate=4.0)
        worst = max(worst, abs(res.dphi[0, 0, py, px] - dx), abs(res.dphi[0, 1, py, px] - dy))
    assert worst > 1e-7


def test_window_sums_to_one_and_is_the_sampled_gaussian():
    sigma = 5.0
    n = 256
    f = np.fft.fftfreq(n)
    kernel = np.fft.ifft(transfer_function(f, sigma)).real
    x = (np.arange(n) + n // 2) % n - n // 2
    g = np.exp(-(x**2) / (2 * sigma**2))
    np.testing.assert_allclose(kernel.sum(), 1.0, rtol=1e-14)
    np.testing.assert_allclose(kernel, g / g.sum(), atol=1e-16)
    assert transfer_function(np.array([0.0]), sigma)[0] == pytest.approx(1.0, abs=1e-15)


def test_float32_stays_float32_and_is_accurate():
    lat, img = _modulated_grid((256, 256))
    r64 = wft(img, lat)
    r32 = wft(img.astype(np.float32), lat)
    assert r32.psi.dtype == np.complex64
    assert r32.dphi.dtype == np.float32
    assert r64.dphi.dtype == np.float64
    v = r64.valid
    # issue bound on float32 derivatives: 1e-6 rad/px (we measure ~2e-8)
    assert np.max(np.abs(r32.dphi - r64.dphi)[:, :, v]) < 1e-6
    # float32 phases: we measure ~4e-7 rad; 1e-5 rad is far below any noise floor
    assert np.max(np.abs(np.angle(r32.psi * np.conj(r64.psi)))[:, v]) < 1e-5


def test_phase_is_the_modulation_with_absolute_carrier():
    # eq. (24): arg Psi = arg d1 + g * phi. For a uniform phase offset phi0 the
    # phase must move by exactly phi0 everywhere, whatever the pixel's position.
    lat = Lattice.from_pitch(5.0, angle=15.0)
    a = synthetic.grid_image((128, 128), lat)
    b = synthetic.grid_image((128, 128), lat, phases=lambda X, Y: (0.7 + 0 * X, -0.4 + 0 * Y))
    ra, rb = wft(a, lat), wft(b, lat)
    v = ra.valid
    d = np.angle(rb.psi * np.conj(ra.psi))
    # noise-free: what remains is the edge bias at the 4-sigma margin (~7e-6 rad,
    # test_edge_bias_decays_as_a_gaussian) and the window's DC leakage (~1e-8 rad)
    np.testing.assert_allclose(d[0][v], 0.7, atol=1e-5)
    np.testing.assert_allclose(d[1][v], -0.4, atol=1e-5)


def test_edge_bias_decays_as_a_gaussian():
    # Measures the bias that justifies the default margin (gridstrain.wft.DEFAULT_MARGIN).
    lat = Lattice.from_pitch(5.0)
    N = 160
    img = synthetic.grid_image((N, N), lat)
    res = wft(img, lat, margin=0.5)
    phase = np.angle(res.psi[0] * np.conj(res.psi[0, N // 2, N // 2]))
    yy, xx = np.mgrid[0:N, 0:N]
    dist = np.minimum(np.minimum(xx, yy), np.minimum(N - 1 - xx, N - 1 - yy))
    err = {k: np.max(np.abs(phase[dist == 5 * k])) for k in (2, 3, 4, 5)}
    # measured: 3.5e-3, 2.5e-4, 6.6e-6, 6e-8 rad at 2, 3, 4, 5 sigma
    assert err[2] > 1e-3  # a cut window is visibly biased: the margin is needed
    assert err[4] < 2e-5  # the default margin (4 sigma) leaves < 2e-5 rad
    assert err[5] < err[4] / 20 < err[3] / 400


def test_valid_region_excludes_border_holes_and_gridless_areas():
    lat = Lattice.from_pitch(5.0)
    img = synthetic.grid_image((160, 160), lat)
    img[100:130, 20:50] = 1.0  # a patch without grid (uniform grey)
    mask = np.ones(img.shape, bool)
    yy, xx = np.mgrid[0:160, 0:160]
    hole = (xx - 60) ** 2 + (yy - 60) ** 2 < 15**2
    mask[hole] = False
    res = wft(img, lat, mask=mask)
    dist_hole = np.sqrt((xx - 60) ** 2 + (yy - 60) ** 2) - 15
    # within the margin of the hole (less one pixel: the hole's edge is pixelated)
    assert not res.valid[dist_hole < 4 * 5 - 1].any()
    assert not res.valid[:20].any()
    assert not res.valid[:, -20:].any()
    assert not res.valid[110:120, 30:40].any()  # no grid, low modulus
    assert res.valid[60, 120]
    assert res.valid[130, 120]


def test_sigma_below_pitch_is_refused():
    lat = Lattice.from_pitch(5.0)
    img = synthetic.grid_image((64, 64), lat)
    with pytest.raises(ValueError, match="sigma"):
        wft(img, lat, sigma=4.0)


def test_input_is_not_modified():
    lat, img = _modulated_grid()
    before = img.copy()
    wft(img, lat)
    np.testing.assert_array_equal(img, before)
