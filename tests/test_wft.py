"""Windowed Fourier transform against a direct double sum (paper eqs. 22-25)."""

import numpy as np
import pytest

from gridstrain import Lattice, wft
from gridstrain.models import synthetic
from gridstrain.phase import transfer_function


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


# "auto": wft's default, the compiled fast derivatives where numba is installed (the
# exact ones otherwise); "exact": the reference, whatever is installed
@pytest.mark.parametrize("derivatives", ["auto", "exact"])
def test_equals_direct_sum_at_random_interior_pixels(derivatives):
    lat, img = _modulated_grid()
    sigma = 5.0
    res = wft(img, lat, sigma=sigma, derivatives=derivatives)
    rng = np.random.default_rng(7)
    # at >= 8 sigma from the border the image edge weighs < exp(-32) in either sum
    pts = rng.integers(40, 88, size=(20, 2))
    for py, px in pts:
        for j, k in enumerate((lat.k1, lat.k2)):
            psi, dx, dy = _direct(img, k, sigma, px, py)
            # issue bound: 1e-9 rad on phases and rad/px on derivatives (we see ~1e-15;
            # the fast filter's derivatives ~6e-11, its design error near the carrier)
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


@pytest.mark.parametrize("derivatives", ["auto", "exact"])
def test_float32_stays_float32_and_is_accurate(derivatives):
    lat, img = _modulated_grid((256, 256))
    r64 = wft(img, lat, derivatives="exact")
    r32 = wft(img.astype(np.float32), lat, derivatives=derivatives)
    assert r32.psi.dtype == np.complex64
    assert r32.dphi.dtype == np.float32
    assert r64.dphi.dtype == np.float64
    v = r64.valid
    # issue bound on float32 derivatives: 1e-6 rad/px (we measure ~3e-8 exact, ~4e-7
    # with the fast filter, whose differences of neighbours amplify the rounding)
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
    # Measures the bias that justifies the default margin (gridstrain.phase.DEFAULT_MARGIN).
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


# --- derivatives="fast": Psi alone, differentiated by a short least-squares filter ---
# Two implementations of the same filter: numpy, and compiled loops (numba, the
# "fast" extra; gridstrain.phase._kernels). Each test runs on both where numba is there.

@pytest.fixture(params=["numpy", "compiled"])
def fast_path(request, monkeypatch):
    """Which implementation ``derivatives="fast"`` runs on."""
    from gridstrain.phase import _maps as phase_maps

    if request.param == "compiled":
        pytest.importorskip("numba")
        assert phase_maps.compiled_loops() is not None
    else:
        monkeypatch.setattr(phase_maps, "_COMPILED", False)
    return request.param


def _noisy(img, seed, sd=20.0):
    """Gaussian read noise of ``sd`` grey levels (a 12-bit camera's few tens)."""
    return img + np.random.default_rng(seed).normal(0.0, sd, img.shape)


def _fast_cases():
    """(lattice, image, sigma, mask): the situations the filter must hold in."""
    lat5, img5 = _modulated_grid((160, 176), angle=0.0)
    lat_r, img_r = _modulated_grid((150, 131), angle=23.0)
    lat4, img4 = _modulated_grid((140, 150), angle=-12.0, pitch=4.0)
    hole = np.ones((160, 176), bool)
    yy, xx = np.mgrid[0:160, 0:176]
    hole[(yy - 70) ** 2 + (xx - 90) ** 2 < 18**2] = False
    return {
        # carrier on FFT bins, no residual demodulation
        "aligned": (lat5, _noisy(img5, 1), None, None),
        # off-bin carrier along both axes, window wider than the pitch
        "rotated": (lat_r, _noisy(img_r, 2), 7.3, None),
        # sigma = 4: six taps; the noise is large against the grid's modulus
        "pitch 4": (lat4, _noisy(img4, 3, sd=150.0), None, None),
        "masked": (lat5, _noisy(img5, 4), None, hole),
        # no grid at all: white noise is the filter's worst case (a flat spectrum)
        "pure noise": (lat5, np.random.default_rng(5).normal(100.0, 20.0, (160, 176)), None,
                       None),
    }


def _same_transform(a, b):
    """``a`` and ``b`` are the same transform of the same image: bit for bit on scipy's
    pocketfft; on MKL (the ``mkl`` extra) to a few roundings relative to the largest
    |Psi|, since MKL's batched and single transforms of the same data round
    differently (7e-14 on |Psi| ~ 40, 1.5e-15 relative, measured)."""
    from gridstrain._runtime import fft

    if fft.name() != "mkl":
        np.testing.assert_array_equal(a, b)
        return
    eps = np.finfo(a.real.dtype).eps
    assert np.max(np.abs(a - b)) < 16 * eps * np.max(np.abs(b))


@pytest.mark.parametrize("case", list(_fast_cases()))
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_fast_derivatives_are_within_the_bound_of_the_exact_ones(case, dtype, fast_path):
    from gridstrain.phase._transform import _wft

    lat, img, sigma, mask = _fast_cases()[case]
    exact = _wft(img, lat, sigma=sigma, mask=mask, derivatives="exact")  # float64 truth
    same = _wft(img.astype(dtype), lat, sigma=sigma, mask=mask, derivatives="exact")
    fast = wft(img.astype(dtype), lat, sigma=sigma, mask=mask, derivatives="fast")
    assert fast.dphi.dtype == dtype
    assert fast.psi.dtype == same.psi.dtype
    # only the derivatives change: the same transform, the same validity
    if fast_path == "numpy":
        _same_transform(fast.psi, same.psi)
    else:
        # the compiled loops demodulate by the carrier's residual in another order:
        # a few roundings of the dtype, relative to the largest |Psi| (phase changes
        # of that order, far below the 1e-5 rad of float32 phases tested above)
        eps = np.finfo(dtype).eps
        scale = np.max(np.abs(same.psi))
        assert np.max(np.abs(fast.psi - same.psi)) < 64 * eps * scale
    np.testing.assert_array_equal(fast.valid, same.valid)
    v = exact.valid
    assert v.sum() > 1000
    err = np.max(np.abs(fast.dphi.astype(float) - exact.dphi)[:, :, v])
    if dtype == np.float64:
        # the filter is designed for 2e-9 rad/px per unit of |Psi|; a valid modulus is
        # at least a quarter of the median and a noise peak ~5 rms: 4e-8 rad/px at
        # worst, inside the 1e-7 rad/px bound (we measure 2e-10 to 5e-10 on grids,
        # 1.2e-8 on pure noise)
        assert err < 4e-8
    else:
        # float32 bound: 1e-6 rad/px. Differences of neighbouring samples cancel, so
        # float32 rounding of Psi (6e-8 relative) gives ~3e-7 rad/px on a grid, where
        # the exact float32 path gives 3e-8. On pure noise the exact float32 path's
        # own rounding already reaches 2e-6 at the faintest valid pixels: there the
        # fast one must not do worse than twice as much (the compiled loops measured
        # 1.58 times it on MKL's transforms, under 1.5 on pocketfft's).
        own = np.max(np.abs(same.dphi.astype(float) - exact.dphi)[:, :, v])
        assert err < (1e-6 if case != "pure noise" else 2.0 * own)


def test_fast_derivatives_against_the_direct_sum(fast_path):
    lat, img = _modulated_grid()
    res = wft(img, lat, sigma=5.0, derivatives="fast")
    rng = np.random.default_rng(7)
    pts = rng.integers(40, 88, size=(10, 2))
    worst = 0.0
    for py, px in pts:
        for j, k in enumerate((lat.k1, lat.k2)):
            _, dx, dy = _direct(img, k, 5.0, px, py)
            worst = max(worst, abs(res.dphi[j, 0, py, px] - dx), abs(res.dphi[j, 1, py, px] - dy))
    # a noise-free grid: the filter's error is that of its fit near the carrier, where
    # it is best (we measure 6e-11 rad/px); 1e-9 is the exact path's bound here
    assert worst < 1e-9


def test_fast_differentiator_on_sampled_tones():
    """The filter applied in space to e^(2 i pi nu x) against the analytic derivative.

    Independent of the package's transfer function: ``G(nu) = exp(-2 pi^2 sigma^2
    nu^2)`` (the unsampled Gaussian's; the sampled one differs by < 1e-20 where
    G > 1e-16 at sigma >= 3.5), and the derivative of the tone's phase is 2 pi nu.
    A tone of Psi's amplitude at nu leaves Psi with amplitude G(nu), so the error it
    causes is |D(nu) - 2 pi nu| G(nu), which the design keeps below 2e-9 rad/px.
    """
    from gridstrain.phase._transform import _differentiator

    x = np.arange(-20, 21)
    for sigma in (3.5, 5.0, 7.3, 12.0):
        taps, _, _ = _differentiator(sigma, np.dtype(np.float64))
        m = taps.size
        worst = 0.0
        for nu in np.linspace(-0.5, 0.5, 1001):
            tone = np.exp(2j * np.pi * nu * x)
            c = 20  # the sample at x = 0
            d = sum(a * (tone[c + n] - tone[c - n]) for n, a in enumerate(taps, start=1))
            rate = (d / tone[c]).imag  # d phi / dx that the filter measures, rad/px
            g = np.exp(-2 * np.pi**2 * sigma**2 * nu**2)
            worst = max(worst, abs(rate - 2 * np.pi * nu) * g)
        # design tolerance 2e-9 rad/px on its own grid of 4001 frequencies
        assert worst < 2.2e-9, (sigma, m, worst)


def test_fast_falls_back_to_exact_for_a_narrow_window(fast_path):
    # at sigma = 2.5 px a short filter cannot match the exact one to 1e-9: the exact
    # derivatives are computed, identical bits
    lat = Lattice.from_pitch(2.5, angle=10.0)
    img = _noisy(synthetic.grid_image((64, 72), lat, amplitude=1000.0), 6)
    fast = wft(img, lat, derivatives="fast")
    exact = wft(img, lat, derivatives="exact")
    np.testing.assert_array_equal(fast.dphi, exact.dphi)


def test_fast_derivatives_do_not_depend_on_the_blocks(monkeypatch, fast_path):
    import gridstrain.phase._transform as impl

    lat, img, sigma, _ = _fast_cases()["rotated"]
    whole = wft(img, lat, sigma=sigma, derivatives="fast")
    # blocks of 8 rows
    monkeypatch.setattr(impl, "_FAST_CHUNK_BYTES" if fast_path == "numpy"
                        else "_COMPILED_CHUNK_BYTES", 1)
    blocks = wft(img, lat, sigma=sigma, derivatives="fast")
    np.testing.assert_array_equal(blocks.psi, whole.psi)
    np.testing.assert_array_equal(blocks.valid, whole.valid)
    if fast_path == "numpy":
        # the same sums in another grouping of the matrix products: rounding only
        np.testing.assert_allclose(blocks.dphi, whole.dphi, rtol=0, atol=1e-13)
    else:
        # every pixel is computed by the same loop whatever the blocks
        np.testing.assert_array_equal(blocks.dphi, whole.dphi)


def test_derivatives_option_is_checked():
    lat, img = _modulated_grid((64, 64))
    with pytest.raises(ValueError, match="derivatives"):
        wft(img, lat, derivatives="central")


# --- the grid's modulus threshold without its median where a bound of it decides -------

def _moduli(case, rng, dtype):
    """Two moduli maps (2, 160, 200): a grid that shows everywhere (down to a
    third of the median at the borders, as a window cut by a corner), or with a hole,
    a NaN, or too few values to bound the median."""
    yy, xx = np.mgrid[0:160, 0:200]
    edge = np.minimum(np.minimum(yy, 159 - yy), np.minimum(xx, 199 - xx))
    mod = (1000 + 20 * rng.standard_normal((2, 160, 200))) * np.minimum(1, 0.34 + edge / 10)
    if case == "hole":
        mod[1, 50:60, 70:90] *= 0.05
    elif case == "nan":
        mod[0, 40, 40] = np.nan
    elif case == "few":  # under _BOUND_MIN values: the median is taken
        mod = mod[:, :80, :80]
    return mod.astype(dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("case", ["shows", "hole", "nan", "few"])
def test_modulus_threshold_is_the_medians(monkeypatch, case, dtype):
    # the pixels below min_modulus times the median, with the bound of the median
    # that spares taking it and without (the bound switched off): the same maps
    from gridstrain.phase import _validity

    rng = np.random.default_rng(3)
    mod = _moduli(case, rng, dtype)
    H, W = mod.shape[1:]
    valid = np.zeros((H, W), dtype=bool)
    valid[8:-8, 8:-8] = True
    box = np.s_[8:H - 8, 8:W - 8]
    mask = np.ones((H, W), dtype=bool)
    mask[:3] = False

    def both():
        return (_validity._shows_grid(list(mod), valid, box, mask, 0.25),
                _validity._shows_grid(list(mod), valid, None, mask, 0.25),
                _validity.no_grid(mod, valid, mask, 0.25))

    fast = both()
    monkeypatch.setattr(_validity, "_median_at_most", lambda values: np.nan)
    for got, want in zip(fast, both(), strict=True):
        np.testing.assert_array_equal(got, want)
    if case == "hole":
        assert fast[2].any()
    else:
        assert not fast[2].any()


@pytest.mark.parametrize("seed", range(20))
def test_median_bound_is_at_least_the_median(seed):
    # a value proved at least the median, or NaN: never below it, whatever the
    # distribution (heavy tails, ties, an even or odd count)
    from gridstrain.phase._validity import _median_at_most

    rng = np.random.default_rng(seed)
    n = int(rng.integers(2**14, 2**16))
    values = [rng.standard_normal(n), rng.standard_cauchy(n), rng.integers(0, 5, n) * 1.0,
              rng.standard_normal(n).astype(np.float32)][seed % 4]
    bound = _median_at_most(values)
    assert np.isnan(bound) or bound >= np.median(values)
    assert not np.isnan(_median_at_most(rng.standard_normal(n)))  # found, usually
