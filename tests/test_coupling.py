"""The window's phase-modulus coupling and its first-order correction, against a direct
Gaussian-window sum on images of known amplitude and known carrier mismatch."""

import numpy as np
import pytest

from gridstrain import Lattice, wft
from gridstrain.phase import PhaseMaps, coupling_corrected

H, W = 112, 128
PITCH = 6.4
SIGMA = PITCH
CX, CY = 64.0, 56.0  # the amplitude's dip, px


def _scene(deg, depth, radius):
    """Two cosines of pitch ``PITCH`` turned by ``deg`` from the lattice's axes, under an
    amplitude ``a = 1 - depth exp(-r^2 / 2 radius^2)`` (an ink gap or a shadow): the
    image, its true wave vectors (cycle/px) and ``grad ln a_w`` ((2, H, W), 1/px), with
    ``a_w`` the amplitude seen through the window, ``a`` smoothed by the Gaussian of std
    ``SIGMA``: ``1 - depth radius^2 / s^2 exp(-r^2 / 2 s^2)``, ``s^2 = radius^2 + SIGMA^2``."""
    t = np.deg2rad(deg)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    ks = [np.array([np.cos(t), np.sin(t)]) / PITCH, np.array([-np.sin(t), np.cos(t)]) / PITCH]
    r2 = (xx - CX) ** 2 + (yy - CY) ** 2
    a = 1 - depth * np.exp(-r2 / (2 * radius**2))
    img = 1000 * a * sum(np.cos(2 * np.pi * (k[0] * xx + k[1] * yy)) for k in ks)
    s2 = radius**2 + SIGMA**2
    bump = depth * radius**2 / s2 * np.exp(-r2 / (2 * s2))
    dln = np.stack([bump * (xx - CX), bump * (yy - CY)]) / s2 / (1 - bump)
    return img, ks, dln


def _direct_phase(img, k, px, py):
    """arg of ``sum_xi v(xi) g(xi - x) exp(-2 i pi k . xi)``, the mean-removed image and a
    Gaussian window of std ``SIGMA`` summed over 8 sigmas (gridstrain.conventions)."""
    r = int(8 * SIGMA)
    ys, xs = np.mgrid[py - r:py + r + 1, px - r:px + r + 1]
    v = img[ys.clip(0, H - 1), xs.clip(0, W - 1)] - img.mean()
    inside = (ys >= 0) & (ys < H) & (xs >= 0) & (xs < W)
    g = np.exp(-((xs - px) ** 2 + (ys - py) ** 2) / (2 * SIGMA**2)) * inside
    return np.angle(np.sum(v * g * np.exp(-2j * np.pi * (k[0] * xs + k[1] * ys))))


def _pixels():
    # the ring where the amplitude's log-gradient is largest, and the dip's centre
    return [(int(CX + dx), int(CY + dy)) for dx in range(-8, 9, 2) for dy in range(-8, 9, 2)]


@pytest.mark.parametrize(("deg", "depth", "radius"), [(1.5, 0.5, 4.0), (1.5, 0.3, 8.0),
                                                       (3.0, 0.5, 4.0)])
def test_the_coupling_with_the_amplitude_is_removed_to_third_order(deg, depth, radius):
    img, ks, dln = _scene(deg, depth, radius)
    lat = Lattice.from_pitch(PITCH)
    pm = wft(img, lat, sigma=SIGMA, derivatives="exact")
    fixed = coupling_corrected(pm)
    before, after, first = [], [], []
    for j, kt in enumerate(ks):
        k = np.array(lat.K[j])
        omega = 2 * np.pi * (kt - k)  # the carrier's mismatch, rad/px
        for px, py in _pixels():
            truth = omega[0] * px + omega[1] * py  # the demodulated phase of a cosine
            direct = _direct_phase(img, k, px, py)
            # gridstrain's transform is the direct sum (noise-free, float64 rounding)
            assert abs(np.angle(pm.psi[j, py, px] * np.exp(-1j * direct))) < 1e-7
            before.append(np.angle(np.exp(1j * (direct - truth))))
            after.append(np.angle(fixed.psi[j, py, px] * np.exp(-1j * truth)))
            first.append(SIGMA**2 * omega @ dln[:, py, px])
    before, after, first = map(np.abs, (before, after, first))
    w2 = SIGMA**2 * np.sum((2 * np.pi * (ks[0] - np.array(lat.K[0]))) ** 2)
    # the bias is the first-order term sigma^2 omega . grad ln a_w: its terms of higher
    # order are sigma^2 |omega|^2 (3 % at 1.5 degrees, 11 % at 3) of it
    np.testing.assert_allclose(before, first, atol=w2 * first.max())
    # what is left is of third order in omega: the Taylor term (sigma^6 / 6) (omega .
    # grad)^3 ln a_w, at most sigma^2 |omega|^2 / 2 of the first for a Gaussian dip
    # (|grad^3 ln a_w| <= 3 |grad ln a_w| / sigma^2), and as much again from the omega
    # the correction reads from the biased maps
    bound = w2 * first.max()
    assert after.max() <= bound, (after.max(), bound, before.max())
    assert before.max() > 3 * bound  # the test can tell a correction from none


@pytest.mark.parametrize(("deg", "kappa"), [(1.5, 1e-3), (3.0, 3e-3)])
def test_the_coupling_with_the_phase_curvature_is_removed(deg, kappa):
    """A uniform amplitude and a phase curved along x (``kappa`` rad/px^2, a strain
    gradient): off the local frequency, the window biases the phase by ``-(sigma^4 / 2)
    omega . grad grad phi . omega``, which a first-order correction from ``|Psi|`` alone
    would double."""
    t = np.deg2rad(deg)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    k1 = np.array([np.cos(t), np.sin(t)]) / PITCH
    k2 = np.array([-np.sin(t), np.cos(t)]) / PITCH
    bend = 0.5 * kappa * (xx - CX) ** 2
    img = 1000 * (np.cos(2 * np.pi * (k1[0] * xx + k1[1] * yy) + bend)
                  + np.cos(2 * np.pi * (k2[0] * xx + k2[1] * yy)))
    lat = Lattice.from_pitch(PITCH)
    pm = wft(img, lat, sigma=SIGMA, derivatives="exact")
    fixed = coupling_corrected(pm)
    omega = 2 * np.pi * (k1 - np.array(lat.K[0]))
    local = omega[0] + kappa * (xx - CX)  # the local frequency's mismatch along x, rad/px
    # the phase a window centred on the local frequency gives: the curve's own smoothing,
    # -1/2 arg(1 - i sigma^2 kappa) (closed form for a Gaussian window), and no coupling
    truth = omega[0] * xx + omega[1] * yy + bend + 0.5 * np.arctan(SIGMA**2 * kappa)
    v = pm.valid
    before = np.abs(np.angle(pm.psi[0] * np.exp(-1j * truth)))[v]
    after = np.abs(np.angle(fixed.psi[0] * np.exp(-1j * truth)))[v]
    coupling = (0.5 * SIGMA**4 * kappa * local**2)[v]
    # before: the coupling, to its third-order terms (sigma^2 |omega|^2 of it)
    np.testing.assert_allclose(before, coupling, atol=0.1 * coupling.max())
    # after: the third-order terms only
    assert after.max() < 0.05 * coupling.max(), (after.max(), coupling.max())


def test_nothing_changes_where_the_carrier_is_the_grids():
    img, _, _ = _scene(0.0, 0.5, 4.0)
    pm = wft(img, Lattice.from_pitch(PITCH), sigma=SIGMA, derivatives="exact")
    fixed = coupling_corrected(pm)
    v = pm.valid
    # omega = 0 but for the window's truncation at the border of the valid region (phase
    # gradients of ~1e-5 rad/px at 4 sigma): sigma^2 1e-5 |grad ln a_w| (0.012/px) is 5e-6
    # rad at most, against the 0.013 rad that a 1.5 degree mismatch makes of the same dip
    assert np.abs(np.angle(fixed.psi * np.conj(pm.psi)))[:, v].max() < 5e-6
    np.testing.assert_allclose(fixed.dphi[:, :, v], pm.dphi[:, :, v], atol=5e-6)
    assert fixed.psi.dtype == pm.psi.dtype
    assert fixed.dphi.dtype == pm.dphi.dtype


def test_float32_maps_stay_float32():
    img, _, _ = _scene(1.5, 0.5, 4.0)
    lat = Lattice.from_pitch(PITCH)
    pm32 = wft(img.astype(np.float32), lat, sigma=SIGMA)
    pm64 = wft(img, lat, sigma=SIGMA)
    f32, f64 = coupling_corrected(pm32), coupling_corrected(pm64)
    assert f32.psi.dtype == np.complex64
    assert f32.dphi.dtype == np.float32
    v = pm64.valid
    # float32 rounding of Psi (1e-7 relative) through the differentiator: 1e-6 rad
    assert np.abs(np.angle(f32.psi * np.conj(f64.psi)))[:, v].max() < 1e-5


@pytest.mark.parametrize("compiled", [True, False])
def test_float32_maps_corrected_into_float64(compiled, monkeypatch):
    from gridstrain.phase import _maps as phase_maps

    monkeypatch.setattr(phase_maps, "_COMPILED", compiled)
    img, _, _ = _scene(1.5, 0.5, 4.0)
    lat = Lattice.from_pitch(PITCH)
    pm32 = wft(img.astype(np.float32), lat, sigma=SIGMA)
    before = pm32.psi.copy()
    wide, narrow = coupling_corrected(pm32, dtype=np.float64), coupling_corrected(pm32)
    np.testing.assert_array_equal(pm32.psi, before)  # the given maps are not written
    assert wide.psi.dtype == np.complex128
    assert wide.dphi.dtype == np.float64
    v = pm32.valid
    # the same float32 correction, its values stored in float64: exactly the float32
    # maps (the option saves a copy, it adds no digits)
    np.testing.assert_array_equal(wide.psi.astype(np.complex64), narrow.psi)
    np.testing.assert_array_equal(wide.dphi, narrow.dphi)
    assert np.all(np.isfinite(wide.psi[:, v]))
    with pytest.raises(ValueError, match="dtype must be float32 or float64"):
        coupling_corrected(pm32, dtype=np.int16)


# --- the compiled loops (numba, the fast extra) against the numpy path ----------------

def _strained_scene():
    """A checker grid under a non-uniform light and two stains, strained, sheared and
    bent (the carrier's mismatch and the phase's curvature vary across the image), with
    a dark hole: both bias terms non-trivial, and saturated at the hole's edge."""
    from independent_grid import scene, stains

    shape = (128, 160)

    def u(X, Y):
        return (0.02 * (X - 80) + 1.5e-4 * (X - 80) ** 2, -0.01 * (Y - 64) + 0.01 * (X - 80))

    img, hole = scene(shape, pitch=5.0, angle=3.0, reflectance=stains(shape), displacement=u)
    return img, hole


def _both_paths(pm, monkeypatch):
    from gridstrain.phase import _maps as phase_maps

    compiled = coupling_corrected(pm)
    with monkeypatch.context() as patch:
        patch.setattr(phase_maps, "_COMPILED", False)
        numpy = coupling_corrected(pm)
    return compiled, numpy


@pytest.fixture
def kernels():
    from gridstrain.phase import _maps as phase_maps

    pytest.importorskip("numba")
    assert phase_maps.compiled_loops() is not None


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("masked", [False, True])
def test_compiled_loops_give_the_numpy_maps(kernels, monkeypatch, dtype, masked):
    img, hole = _strained_scene()
    pm = wft(img.astype(dtype), Lattice.from_pitch(5.0), mask=~hole if masked else None)
    compiled, numpy = _both_paths(pm, monkeypatch)
    bias = np.abs(np.angle(numpy.psi * np.conj(pm.psi)))
    assert bias.max() > 0.05  # the correction is no small one here
    # every pixel, the image's borders and the hole's included: ln |Psi| in float32
    # holds 1e-6 at |ln| ~ 10 (each path within 1.3e-6 of the same formula in float64),
    # through sigma^2 omega (0.5 rad px) and the differentiator: 2e-6 rad of phase and
    # 2e-6 rad/px of its derivatives, 1.6e-6 px and 1.6e-6 strain at a 5 px pitch
    assert np.abs(np.angle(compiled.psi * np.conj(numpy.psi))).max() < 2e-6
    np.testing.assert_allclose(compiled.dphi, numpy.dphi, rtol=0, atol=2e-6)
    assert compiled.psi.dtype == numpy.psi.dtype == pm.psi.dtype
    assert compiled.dphi.dtype == numpy.dphi.dtype == pm.dphi.dtype
    assert compiled.valid is pm.valid
    assert compiled.sigma == pm.sigma


def test_undefined_values_are_left_uncorrected_by_both_paths(kernels, monkeypatch):
    img, hole = _strained_scene()
    pm = wft(img, Lattice.from_pitch(5.0), mask=~hole)
    psi, dphi = pm.psi.copy(), pm.dphi.copy()
    # no signal in a patch (Psi = 0, its derivatives 0/0) in the first wave vector's
    # maps; a NaN in the second's Psi, which makes its largest modulus NaN: no
    # correction anywhere in that map
    psi[0, 40:50, 30:45] = 0
    dphi[0, :, 40:50, 30:45] = np.nan
    psi[1, 70, 90] = np.nan
    odd = PhaseMaps(psi=psi, dphi=dphi, valid=pm.valid, lattice=pm.lattice, sigma=pm.sigma)
    compiled, numpy = _both_paths(odd, monkeypatch)
    for out in (compiled, numpy):
        assert np.all(np.isnan(out.dphi[0, :, 40:50, 30:45]))
        assert np.all(out.psi[0, 40:50, 30:45] == 0)
        assert np.isnan(out.psi[1, 70, 90])
        np.testing.assert_array_equal(out.dphi[1], dphi[1])
    np.testing.assert_array_equal(compiled.psi[1], numpy.psi[1])
    np.testing.assert_array_equal(np.isnan(compiled.dphi), np.isnan(numpy.dphi))
    # elsewhere as above (float32 rounding of ln |Psi|)
    np.testing.assert_allclose(compiled.dphi, numpy.dphi, rtol=0, atol=2e-6)


@pytest.mark.parametrize("compiled", [True, False])
def test_an_image_scaled_by_a_power_of_two_gives_the_same_maps(compiled, monkeypatch):
    from gridstrain.phase import _maps as phase_maps

    if compiled and phase_maps.compiled_loops() is None:
        pytest.skip("the compiled loops need numba (the fast extra)")
    monkeypatch.setattr(phase_maps, "_COMPILED", compiled)
    img, _ = _strained_scene()
    lat = Lattice.from_pitch(5.0)
    one = coupling_corrected(wft(img, lat))
    # 12-bit levels stored x16: Psi is 16 times as large, exactly; ln |Psi| is taken
    # relative to its largest value, so that the correction is the same bits
    sixteen = coupling_corrected(wft(16 * img, lat))
    np.testing.assert_array_equal(sixteen.psi, 16 * one.psi)
    np.testing.assert_array_equal(sixteen.dphi, one.dphi)


def test_the_compiled_logarithm_is_within_an_ulp(kernels):
    from gridstrain.phase import _kernels

    rng = np.random.default_rng(3)
    # the ratios |Psi|^2 / max |Psi|^2 it takes: every binade of the normal numbers up
    # to 1, and the values that numpy's log answers: 0, subnormal, inf, NaN
    v = np.concatenate([np.exp(-rng.uniform(0, 87, 100_000)), rng.uniform(0.5, 2, 10_000),
                        [1.0, 0.5, np.sqrt(0.5), 2**-126]]).astype(np.float32)
    odd = np.array([0.0, 1e-40, np.inf, np.nan], np.float32)
    out = np.empty(v.size + odd.size, np.float32)
    _kernels._log(out, np.concatenate([v, odd]), np.empty_like(out), np.float32(1))
    exact = np.log(v.astype(np.float64))
    # float32's own rounding of ln v is half an ulp; numpy's float32 log is within 3
    ulp = np.spacing(np.abs(exact).astype(np.float32))
    assert np.max(np.abs(out[:v.size] - exact) / ulp) <= 1.0
    with np.errstate(divide="ignore"):
        np.testing.assert_array_equal(out[v.size:], np.log(odd))


def test_the_compiled_saturation_is_the_tanh(kernels):
    from gridstrain.phase import _kernels

    s = np.float32(0.2)
    b = np.concatenate([np.linspace(-3, 3, 6001), [1e-30, -1e-7, 1e3]]).astype(np.float32)
    got = np.array([_kernels._saturated(v, s) for v in b])
    exact = 0.2 * np.tanh(b.astype(np.float64) / 0.2)
    # the rational fit's 4e-7 of tanh in float32 arithmetic, times 0.2 rad: 1e-7 rad
    np.testing.assert_allclose(got, exact, rtol=4e-7, atol=1e-8)
    odd = np.array([_kernels._saturated(v, s) for v in np.float32([np.inf, -np.inf, np.nan])])
    np.testing.assert_array_equal(odd, 0)  # nothing corrected where b is undefined
