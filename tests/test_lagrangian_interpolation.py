"""The deformed maps evaluated off the pixel grid (Lagrangian correction) against a direct sum."""

import dataclasses

import numpy as np
import pytest
from scipy import ndimage
from skimage.restoration import unwrap_phase as _original_unwrap_phase

from gridstrain import Lattice, deformation, wft
from gridstrain.kinematics import _deformation as kinematics
from gridstrain.kinematics._deformation import _Spline

SIGMA = 5.0
N = 96


def _cosine_grid(lat, noise, seed):
    """Two crossed cosine families with smooth phase modulations, numpy only.

    Assumptions: grey level ``1000 (1 + 0.45 cos(2 pi k1.x + phi1) + 0.45 cos(2 pi k2.x
    + phi2))`` sampled at the pixel centres, plus white Gaussian noise of ``noise``
    grey levels (a 12-bit camera at mid-range has about 10).
    """
    yy, xx = np.mgrid[0:N, 0:N].astype(float)
    ph1 = 0.4 * np.sin(2 * np.pi * yy / 50)
    ph2 = 0.3 * np.cos(2 * np.pi * xx / 40)
    (a, b), (c, d) = lat.k1, lat.k2
    img = 1000 * (1 + 0.45 * np.cos(2 * np.pi * (a * xx + b * yy) + ph1)
                  + 0.45 * np.cos(2 * np.pi * (c * xx + d * yy) + ph2))
    return img + noise * np.random.default_rng(seed).standard_normal(img.shape)


def _direct_psi(img, k, px, py):
    """Eq. (22) at a point off the pixel grid, summed over the whole image.

    ``Psi(x) = sum_xi v(xi) g(xi - x) exp(-2 i pi k.xi)`` with the unit-sum sampled
    Gaussian's normalisation: a continuous function of ``x``, the transform that the
    interpolation of the sampled maps must reproduce.
    """
    yy, xx = np.mgrid[0:N, 0:N].astype(float)
    v = img - img.mean()
    n = np.arange(-400, 401)
    norm = np.exp(-(n**2) / (2 * SIGMA**2)).sum() ** 2
    g = np.exp(-((xx - px) ** 2 + (yy - py) ** 2) / (2 * SIGMA**2)) / norm
    return np.sum(v * g * np.exp(-2j * np.pi * (k[0] * xx + k[1] * yy)))


@pytest.mark.parametrize("noise", [0.0, 10.0])
def test_prefiltered_cubic_spline_matches_the_transform_off_the_grid(noise):
    lat = Lattice.from_pitch(SIGMA, angle=20.0)
    img = _cosine_grid(lat, noise, seed=3)
    pm = wft(img, lat, sigma=SIGMA)
    rng = np.random.default_rng(11)
    # at >= 8 sigma from the border the image edge weighs < exp(-32) in the direct sum
    pts = rng.uniform(40, 56, size=(2, 12, 1))
    for j, k in enumerate((lat.k1, lat.k2)):
        spline = _Spline(pm.psi[j])
        got = spline(pts)[:, 0]
        want = np.array([_direct_psi(img, k, px, py) for py, px in pts[:, :, 0].T])
        # 1e-6 rad is 8e-7 px at this pitch, a hundredth of the 1e-4 px bound on
        # displacements; cubic splines give 3e-7 rad here, quadratic ones 7e-6 rad
        np.testing.assert_array_less(np.abs(np.angle(got / want)), 1e-6)
        np.testing.assert_allclose(np.abs(got), np.abs(want), rtol=1e-6)


def test_prefiltered_spline_equals_scipy_with_its_own_prefilter():
    # the padding before the prefilter reproduces map_coordinates(mode="nearest"),
    # including points outside the map, to rounding
    rng = np.random.default_rng(5)
    arr = rng.standard_normal((40, 50)) + 1j * rng.standard_normal((40, 50))
    coords = rng.uniform(-6, 56, size=(2, 30, 7))
    want = (ndimage.map_coordinates(arr.real, coords, order=3, mode="nearest")
            + 1j * ndimage.map_coordinates(arr.imag, coords, order=3, mode="nearest"))
    np.testing.assert_allclose(_Spline(arr)(coords), want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("complex_maps", [True, False])
def test_compiled_spline_equals_map_coordinates(monkeypatch, complex_maps):
    # four planes (two complex maps or four real ones) at once by the compiled loop,
    # against scipy's map_coordinates of each map with its own prefilter, to rounding,
    # at points inside, on and beyond the border (within the padding)
    pytest.importorskip("numba")
    rng = np.random.default_rng(7)
    shape = (2, 40, 50) if complex_maps else (2, 2, 40, 50)
    arr = rng.standard_normal(shape)
    if complex_maps:
        arr = arr + 1j * rng.standard_normal(shape)
    # rows and columns up to 9 px beyond the maps, within the 12 px of padding
    coords = np.stack([rng.uniform(-9, 48, size=(30, 7)), rng.uniform(-9, 58, size=(30, 7))])
    flat = arr.reshape(-1, 40, 50)

    def scipy_at(a):
        return ndimage.map_coordinates(a, coords, order=3, mode="nearest")

    want = np.stack([scipy_at(a.real) + (1j * scipy_at(a.imag) if complex_maps else 0)
                     for a in flat]).reshape(*arr.shape[:-2], 30, 7)
    spline = kinematics._Spline(arr)
    assert spline.kern is not None
    np.testing.assert_allclose(spline(coords), want, rtol=0, atol=1e-12)
    monkeypatch.setattr(kinematics, "_COMPILED", False)
    plain = kinematics._Spline(arr)
    assert plain.kern is None
    np.testing.assert_allclose(plain(coords), want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("shape", [(6, 9), (40, 50), (250, 400)])
def test_compiled_prefilter_equals_scipys_spline_filter(shape):
    # the compiled prefilter's coefficients against scipy.ndimage.spline_filter of each
    # edge-padded map, to rounding: a short line (30 x 33 padded, under the 35 terms of
    # the initial sum's horizon, where the wrapped terms count), a test's size and a
    # benchmark frame's (the wrapped terms all under the horizon, left out); the maps
    # span 1e6 so that a term left out would show against the smaller coefficients
    pytest.importorskip("numba")
    rng = np.random.default_rng(3)
    arr = (rng.standard_normal((2, *shape)) + 1j * rng.standard_normal((2, *shape))) \
        * np.logspace(0, 6, shape[1])
    spline = kinematics._Spline(arr)
    assert spline.kern is not None
    pad = kinematics._SPLINE_PAD
    planes = [p for a in arr for p in (a.real, a.imag)]
    for k, p in enumerate(planes):
        want = ndimage.spline_filter(np.pad(p, pad, mode="edge"), 3, mode="nearest")
        # float64 rounding of sums whose terms reach the largest coefficient
        np.testing.assert_allclose(spline.coef[k], want, rtol=0,
                                   atol=1e-14 * np.abs(want).max())


def _noisy_pair(shift, strain, *, seed, n=160):
    """Maps of a noisy pair generated here in numpy: two cosine families at 7 deg,
    10 grey levels of noise on 1000, the deformed image the reference pattern at
    ``x - u(x)`` (first order in the strain, enough to compare two corrections of the
    same maps), ``u`` a translation ``shift`` (px), a strain ``strain`` (e_xx, e_yy),
    a shear of 1e-3 and a 0.05 px wave along y."""
    c = (n - 1) / 2
    lat = Lattice.from_pitch(SIGMA, angle=7.0)
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    ux = shift[0] + strain[0] * (xx - c) + 1e-3 * (yy - c) + 0.05 * np.sin(2 * np.pi * yy / 60)
    uy = shift[1] + strain[1] * (yy - c)
    rng = np.random.default_rng(seed)

    def pattern(x, y):
        (a, b), (d, e) = lat.k1, lat.k2
        img = 1000 * (1 + 0.45 * np.cos(2 * np.pi * (a * x + b * y))
                      + 0.45 * np.cos(2 * np.pi * (d * x + e * y)))
        return img + 10 * rng.standard_normal(img.shape)

    return wft(pattern(xx, yy), lat, sigma=SIGMA), wft(pattern(xx - ux, yy - uy), lat,
                                                       sigma=SIGMA)


def test_cubic_correction_equals_the_quintic_one(monkeypatch):
    """The whole large-displacement correction with cubic against quintic splines.

    Noisy pair, 2.7 px translation with strain (2e-3, -3e-3) and a 0.05 px wavy
    component, generated here in numpy: the deformed image is the reference pattern
    at ``x - u(x)`` (first order in the strain, enough for a comparison of two
    interpolations of the same maps).
    """
    ref, cur = _noisy_pair((2.7, -1.4), (2e-3, -3e-3), seed=8)
    cubic = deformation(ref, cur, guess=(3.0, -1.0))
    if kinematics._load_kernels() is not None:
        # the compiled loop and map_coordinates: the same correction, to rounding
        monkeypatch.setattr(kinematics, "_COMPILED", False)
        plain = deformation(ref, cur, guess=(3.0, -1.0))
        np.testing.assert_array_equal(cubic.valid, plain.valid)
        np.testing.assert_allclose(cubic.u[:, cubic.valid], plain.u[:, plain.valid],
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(cubic.strain[:, cubic.valid], plain.strain[:, plain.valid],
                                   rtol=0, atol=1e-12)
    monkeypatch.setattr(kinematics, "_SPLINE_ORDER", 5)
    quintic = deformation(ref, cur, guess=(3.0, -1.0))
    np.testing.assert_array_equal(cubic.valid, quintic.valid)
    v = cubic.valid
    assert v.mean() > 0.3
    # a hundredth of the 1e-4 px bound on u (measured 3e-7 px) and a tenth of the
    # 1e-5 strain users resolve (measured 8e-8)
    np.testing.assert_allclose(cubic.u[:, v], quintic.u[:, v], rtol=0, atol=1e-6)
    np.testing.assert_allclose(cubic.strain[:, v], quintic.strain[:, v], rtol=0, atol=1e-6)


def _skimage_unwrap(wrapped, valid):
    return np.ma.filled(_original_unwrap_phase(np.ma.masked_array(wrapped, mask=~valid), rng=0),
                        0.0)


def _two_regions(rng, shape):
    """Valid pixels with holes, cut in two regions by a column: each free to take its
    own multiple of 2 pi."""
    valid = rng.random(shape) > 0.05
    valid[40:70, 60:100] = False
    valid[:, 75] = False
    return valid


def _check_against_scikit_image(monkeypatch, wrapped, valid, calls, **kw):
    """``_unwrap(wrapped, valid, **kw)`` calls scikit-image ``calls`` times and gives its
    result up to one whole turn per connected region, to rounding, 0 off ``valid``."""
    want = _skimage_unwrap(wrapped, valid)
    seen = []

    def spy(*args, **kwargs):
        seen.append(1)
        return _original_unwrap_phase(*args, **kwargs)

    monkeypatch.setattr(kinematics, "unwrap_phase", spy)
    got = kinematics._unwrap(wrapped, valid, **kw)
    assert len(seen) == calls
    np.testing.assert_array_equal(got[~valid], 0.0)
    labels, n = ndimage.label(valid)
    assert n == 2
    turns = (got - want) / (2 * np.pi)
    for lab in range(1, n + 1):
        t = turns[labels == lab]
        np.testing.assert_allclose(t, np.rint(t[0]), rtol=0, atol=1e-12)


# the shortcuts' compiled loop (numba) and their numpy operations
_PATHS = [pytest.param(True, id="compiled"), pytest.param(False, id="numpy")]


@pytest.mark.parametrize("compiled", _PATHS)
@pytest.mark.parametrize(("amplitude", "offset", "calls"),
                         [(2.0, 0.0, 0), (2.0, 2.5, 0), (6.0, 0.0, 1)])  # rad
def test_unwrap_shortcut_decides_what_scikit_image_decides(monkeypatch, amplitude, offset,
                                                           calls, compiled):
    # spread over less than a fringe (2 x 2 rad), centred or offset so that the
    # wrapped map jumps: scikit-image is spared; over three fringes it runs
    monkeypatch.setattr(kinematics, "_COMPILED", compiled)
    rng = np.random.default_rng(int(amplitude * 10 + offset))
    yy, xx = np.mgrid[0:120, 0:150].astype(float)
    phase = (offset + amplitude * np.sin(xx / 40) * np.cos(yy / 30)
             + 0.2 * rng.standard_normal(xx.shape))
    _check_against_scikit_image(monkeypatch, np.angle(np.exp(1j * phase)),
                                _two_regions(rng, xx.shape), calls)


@pytest.mark.parametrize(("guess_error", "calls"), [
    (0.0, 0),  # a previous state's field, a few tenths of a radian off
    (0.6, 1),  # a patch where the guess is 0.6 turn off (a crack opened): no shortcut
])
@pytest.mark.parametrize("compiled", _PATHS)
def test_unwrap_around_a_guess_decides_what_scikit_image_decides(monkeypatch, guess_error,
                                                                 calls, compiled):
    """A field spread over seven fringes (a record's late state) is unwrapped around
    the phase its guess predicts, scikit-image spared, when the result has no jump;
    where the guess is wrong by more than half a turn somewhere, scikit-image runs."""
    monkeypatch.setattr(kinematics, "_COMPILED", compiled)
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:120, 0:150].astype(float)
    phase = 0.3 * xx + 4.0 * np.sin(yy / 25) + 0.2 * rng.standard_normal(xx.shape)
    # the guess: smooth, a few tenths of a radian off, whole turns apart per region
    around = phase + 0.4 * np.cos(xx / 30) + 2 * np.pi * np.where(xx < 75, 3, -2)
    around[10:30, 10:40] += 2 * np.pi * guess_error
    _check_against_scikit_image(monkeypatch, np.angle(np.exp(1j * phase)),
                                _two_regions(rng, xx.shape), calls, around=around)


def _both_paths(monkeypatch, fn):
    """``fn()`` with the compiled loops and with numpy only."""
    if kinematics._load_kernels() is None:
        pytest.skip("numba is not installed")
    fast = fn()
    monkeypatch.setattr(kinematics, "_COMPILED", False)
    plain = fn()
    monkeypatch.setattr(kinematics, "_COMPILED", True)
    return fast, plain


@pytest.mark.parametrize("case", ["centred", "offset", "around", "around-nan",
                                  "no-shortcut", "nan-inside"])
def test_compiled_unwrap_is_numpys_bit_for_bit(monkeypatch, case):
    """The shortcuts' compiled loop does numpy's operations (its ``mod`` by selections
    within [-2 pi, 4 pi), numpy's own ``fmod`` beyond): the same bits, and scikit-image
    called where numpy calls it."""
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:120, 0:150].astype(float)
    spread = 0.3 * xx if case.startswith("around") or case == "no-shortcut" else 0.0
    phase = spread + 1.0 * np.sin(yy / 25) + 0.2 * rng.standard_normal(xx.shape)
    if case == "offset":
        phase += 2.9  # the wrapped map jumps; turned by its circular mean, it does not
    wrapped = np.angle(np.exp(1j * phase))
    if case == "nan-inside":
        # a value fmod must take: the row left to numpy's (with no jump elsewhere:
        # scikit-image does not return on a NaN)
        wrapped[5, 7] = np.nan
    valid = _two_regions(rng, xx.shape)
    around = None
    if case.startswith("around"):
        around = phase + 0.4 * np.cos(xx / 30) + 2 * np.pi * np.where(xx < 75, 3, -2)
        if case == "around-nan":
            around[3, 3] = np.nan
    fast, plain = _both_paths(monkeypatch,
                              lambda: kinematics._unwrap(wrapped, valid, around=around))
    np.testing.assert_array_equal(fast.view(np.int64), plain.view(np.int64))


@pytest.mark.parametrize("guess", ["field", "constant", "half-period-off"])
def test_compiled_fringe_order_is_numpys(monkeypatch, guess):
    """The whole periods each region takes: where every pixel's phase change from the
    guess rounds to one whole number the compiled loop takes it without the median;
    elsewhere (a patch half a period off) the median decides, as in numpy. Two
    regions, each with its own order: the same bits, from the same phase difference
    (its compiled argument differs from numpy's by an ulp or two,
    test_compiled_arctan2_is_numpys_to_two_ulp)."""
    kern = kinematics._load_kernels()
    if kern is not None:
        monkeypatch.setattr(kinematics, "_phase_difference", lambda r, c, out:
                            kern.phase_difference(kinematics._real_view(r),
                                                  kinematics._real_view(c), out))
    rng = np.random.default_rng(5)
    ref, cur = _noisy_pair((2.7, -1.4), (2e-3, -3e-3), seed=9)
    valid = _two_regions(rng, ref.shape)
    ref = dataclasses.replace(ref, valid=ref.valid & valid)
    K = ref.lattice.K
    v = ref.valid & cur.valid
    if guess == "constant":
        g = np.broadcast_to(np.array([2.7 + 5.0, -1.4])[:, None, None], (2, *ref.shape))
    else:
        yy, xx = np.mgrid[0:ref.shape[0], 0:ref.shape[1]].astype(float)
        g = np.stack([2.7 + 0.02 * np.sin(yy / 9) + 5.0 * (xx < 75), -1.4 + 0 * xx])
        if guess == "half-period-off":
            g[0, 20:60, 20:60] += 0.6 * 5.0  # px: 0.6 period along x
    fast, plain = _both_paths(
        monkeypatch, lambda: kinematics._unwrapped_displacement(ref, cur, v, K, g))
    np.testing.assert_array_equal(fast.view(np.int64), plain.view(np.int64))


def test_correction_stops_within_tol_of_its_fixed_point():
    """The iterations stop on a bound of the error left, not on the last step.

    Noisy pair (12-bit-like noise, 10 grey levels), a 9 px translation with strain
    (3e-3, -2e-3) and a wavy component, generated here in numpy as in
    ``test_cubic_correction_equals_the_quintic_one``. The fixed point iterated to
    rounding is the oracle: the default stop must be within its ``tol`` of it.
    """
    ref, cur = _noisy_pair((9.2, -4.1), (3e-3, -2e-3), seed=21)
    tol = 1e-6  # px, the default
    got = deformation(ref, cur, guess=(9.0, -4.0), tol=tol)
    exact = deformation(ref, cur, guess=(9.0, -4.0), tol=1e-14, max_iter=30)
    assert exact.iterations > got.iterations >= 1
    v = got.valid
    np.testing.assert_array_equal(v, exact.valid)
    err = np.sqrt(np.mean(np.sum((got.u[:, v] - exact.u[:, v]) ** 2, axis=0)))
    assert err < tol
    # the strain takes the deformed derivatives at X + u: moving u by under 1e-6 px
    # changes them by under 1e-9 (their gradient is below 1e-3 rad/px^2 here)
    np.testing.assert_allclose(got.strain[:, v], exact.strain[:, v], rtol=0, atol=1e-9)


def test_compiled_correction_equals_scipy_around_a_hole(monkeypatch):
    """Compiled loops against map_coordinates and numpy, with invalid pixels inside.

    A pair with a hole (masked in the reference, unreadable in the deformed image:
    its grey level is uniform there) moved by 6.4 px: the validity carried to
    ``X + u`` by bilinear interpolation must agree pixel for pixel, the maps to
    rounding.
    """
    if kinematics._load_kernels() is None:
        pytest.skip("numba is not installed")
    n = 140
    lat = Lattice.from_pitch(SIGMA, angle=-11.0)
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    ux, uy = 6.4 + 2e-3 * (xx - 70), -3.3 + 1e-3 * (yy - 70)

    def image(x, y):
        (a, b), (d, e) = lat.k1, lat.k2
        img = 1000 * (1 + 0.45 * np.cos(2 * np.pi * (a * x + b * y))
                      + 0.45 * np.cos(2 * np.pi * (d * x + e * y)))
        hole = (x - 60) ** 2 + (y - 75) ** 2 < 15**2  # in the reference configuration
        return np.where(hole, 300.0, img) + 5 * np.random.default_rng(4).standard_normal(
            img.shape), hole

    ref_img, hole = image(xx, yy)
    cur_img, _ = image(xx - ux, yy - uy)
    ref = wft(ref_img, lat, sigma=SIGMA, mask=~hole)
    cur = wft(cur_img, lat, sigma=SIGMA)
    fast = deformation(ref, cur, guess=(6.0, -3.0))
    monkeypatch.setattr(kinematics, "_COMPILED", False)
    plain = deformation(ref, cur, guess=(6.0, -3.0))
    assert fast.iterations == plain.iterations
    np.testing.assert_array_equal(fast.valid, plain.valid)
    assert 0.2 < fast.valid.mean() < 0.9
    assert not fast.valid[75, 60]  # the hole
    v = fast.valid
    # float64 rounding through a few hundred operations
    np.testing.assert_allclose(fast.u[:, v], plain.u[:, v], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.strain[:, v], plain.strain[:, v], rtol=0, atol=1e-12)


def test_compiled_correction_is_the_same_on_any_number_of_threads(monkeypatch):
    """The compiled loops run on fixed blocks of rows (and of columns for the
    prefilter), the step's sums added in the blocks' order: the displacement, the
    strain, the validity and the iterations are the same bits on 1, 2 and 3 threads.
    The maps (160 px, padded to 184) do not divide into whole blocks."""
    if kinematics._load_kernels() is None:
        pytest.skip("numba is not installed")
    ref, cur = _noisy_pair((9.2, -4.1), (3e-3, -2e-3), seed=21)
    # threads on maps this small too (by default they run on the calling thread)
    monkeypatch.setattr(kinematics, "_THREADED_PIXELS", 0)
    runs = []
    for threads in (1, 2, 3):
        monkeypatch.setattr(kinematics, "check_workers", lambda _w, n=threads: n)
        calls = []
        real = kinematics._by_blocks

        def spy(n, size, fn, pixels, calls=calls, real=real):
            calls.append(n)
            return real(n, size, fn, pixels)

        monkeypatch.setattr(kinematics, "_by_blocks", spy)
        runs.append(deformation(ref, cur, guess=(9.0, -4.0), tol=1e-9))
        monkeypatch.setattr(kinematics, "_by_blocks", real)
        # the prefilters (rows and columns, twice), the start, the steps, the gradient
        assert len(calls) >= 7
    one = runs[0]
    assert one.iterations >= 2
    for other in runs[1:]:
        assert other.iterations == one.iterations
        np.testing.assert_array_equal(other.valid, one.valid)
        np.testing.assert_array_equal(other.u, one.u)
        np.testing.assert_array_equal(other.strain, one.strain)


def test_small_maps_run_their_blocks_on_the_calling_thread(monkeypatch):
    """Below _THREADED_PIXELS the blocks are not handed to the pool's threads, from
    it on they are (on the usable cores)."""
    from gridstrain._runtime import threads as pool

    workers = []
    real = pool.map_leaves

    def spy(fn, items, n):
        workers.append(n)
        return real(fn, items, n)

    monkeypatch.setattr(kinematics, "map_leaves", spy)
    monkeypatch.setattr(kinematics, "check_workers", lambda _w: 2)
    kinematics._by_blocks(300, 64, lambda i0, i1: i1 - i0, kinematics._THREADED_PIXELS - 1)
    kinematics._by_blocks(300, 64, lambda i0, i1: i1 - i0, kinematics._THREADED_PIXELS)
    assert workers == [1, 2]


def test_compiled_arctan2_is_numpys_to_two_ulp():
    """The compiled loops' arctan2 against numpy's: within 2 ulp of pi (4.4e-16 rad,
    some 1e-16 px of displacement at a 5 px pitch) over ratios from 1e-300 to 1e300
    and every octant; numpy's values exactly at the signed zeros, the axes, the
    infinities and NaN."""
    kern = kinematics._load_kernels()
    if kern is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(3)
    for scale in (1e-300, 1e-8, 1.0, 1e8, 1e300):
        y = rng.standard_normal(200_000) * scale
        x = rng.standard_normal(200_000) * scale * rng.choice([1e-6, 1.0, 1e6], 200_000)
        out = np.empty_like(y)
        kern.arctan2(y, x, out)
        np.testing.assert_allclose(out, np.arctan2(y, x), rtol=0, atol=2 * np.spacing(np.pi))
    # the octants' edges: |y| = |x|, |y| = tan(pi/8) |x| and its neighbours
    x = np.repeat([1.0, -1.0, 3e-200, -7e150], 6)
    t = np.tile([1.0, np.tan(np.pi / 8), np.nextafter(np.tan(np.pi / 8), 0), 1e-17,
                 -1.0, -np.tan(np.pi / 8)], 4)
    y = t * np.abs(x)
    out = np.empty_like(y)
    kern.arctan2(y, x, out)
    np.testing.assert_allclose(out, np.arctan2(y, x), rtol=0, atol=2 * np.spacing(np.pi))
    inf, nan = np.inf, np.nan
    y = np.array([0.0, -0.0, 0.0, -0.0, 1.0, -1.0, inf, inf, -inf, 1.0, -1.0, nan, 1.0, nan])
    x = np.array([0.0, 0.0, -0.0, -0.0, 0.0, -0.0, inf, -inf, inf, inf, -inf, 1.0, nan, nan])
    out = np.empty_like(y)
    kern.arctan2(y, x, out)
    want = np.arctan2(y, x)
    np.testing.assert_array_equal(np.signbit(out), np.signbit(want))
    np.testing.assert_allclose(out, want, rtol=0, atol=2 * np.spacing(np.pi))


def test_compiled_phase_difference_is_numpys_to_two_ulp(monkeypatch):
    """The start's phase difference ``arg(Psi_def conj Psi_ref)`` from the compiled
    loop against numpy's product and arctan2: within 2 ulp of pi, NaN and the
    signed zeros where numpy has them (an all-zero transform in a masked corner)."""
    kern = kinematics._load_kernels()
    if kern is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(8)
    shape = (2, 37, 53)
    ref = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    cur = rng.standard_normal(shape) * 1e3 + 1j * rng.standard_normal(shape)
    ref[0, :5, :5] = 0.0
    cur[1, -3:, -4:] = -0.0
    ref[1, 10, 10] = np.nan
    fast = np.empty(shape)
    kern.phase_difference(kinematics._real_view(ref), kinematics._real_view(cur), fast)
    plain = np.empty(shape)
    kinematics._phase_difference(ref, cur, plain)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(plain))
    ok = ~np.isnan(plain)
    np.testing.assert_array_equal(np.signbit(fast[ok]), np.signbit(plain[ok]))
    np.testing.assert_allclose(fast[ok], plain[ok], rtol=0, atol=2 * np.spacing(np.pi))


def test_gradient_box_shortcut_decides_what_the_interpolated_validity_decides():
    """Where the deformed state's valid pixels fill a rectangle, the gradient's loop
    skips the bilinear interpolation of the validity for points whose four
    neighbours lie inside it; points near its edges (fractions of 0, 1e-4, 1e-3
    and 0.5 px past an edge) still get it: the same validity and strain bits as the
    loop told of no rectangle."""
    kern = kinematics._load_kernels()
    if kern is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(12)
    H, W = 60, 80
    coef = rng.standard_normal((4, H + 2 * kinematics._SPLINE_PAD, W + 2 * kinematics._SPLINE_PAD))
    cur_valid = np.zeros((H, W), bool)
    cur_valid[7:50, 9:71] = True
    # displacements that bring X + u onto, just past and well past the rectangle's edges
    frac = rng.choice([0.0, 1e-4, 9.99e-4, 1.001e-3, 0.5, -1e-4, -0.5], (2, H, W))
    u = rng.integers(-3, 4, (2, H, W)) + frac
    ref_valid = rng.random((H, W)) > 0.1
    d_ref = rng.standard_normal((2, 2, H, W))
    two_pi_k = 2 * np.pi * Lattice.from_pitch(SIGMA, angle=7.0).K
    out = []
    for box in ((7, 50, 9, 71), (0, 0, 0, 0)):
        strain, rotation = np.empty((3, H, W)), np.empty((H, W))
        valid = np.empty((H, W), bool)
        kern.lagrangian_gradient(coef, float(kinematics._SPLINE_PAD), u, cur_valid,
                                 np.array(box, dtype=np.int64), ref_valid, d_ref, two_pi_k,
                                 strain, rotation, valid, 0, H)
        out.append((strain, rotation, valid))
    (s1, r1, v1), (s2, r2, v2) = out
    np.testing.assert_array_equal(v1, v2)
    assert 0.2 < v1.mean() < 0.8
    np.testing.assert_array_equal(s1.view(np.int64), s2.view(np.int64))
    np.testing.assert_array_equal(r1.view(np.int64), r2.view(np.int64))


def test_compiled_evaluation_by_runs_equals_map_coordinates():
    """The compiled evaluation of four coefficient planes at a smooth field's points
    (long runs of points sharing their neighbourhoods' rows, cut where the field
    crosses a pixel), at points 20 px beyond the padding (clamped to the padded map
    first, one point at a time) and at NaN ones, against scipy's ``map_coordinates``
    of each plane (``prefilter=False``, ``mode="nearest"``) at the clamped points: to
    float64 rounding of sums of 16 terms of coefficients up to 3 (5e-13)."""
    kern = kinematics._load_kernels()
    if kern is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(21)
    H, W, pad = 50, 70, kinematics._SPLINE_PAD
    coef = rng.standard_normal((4, H + 2 * pad, W + 2 * pad))
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    cy = yy + 2.3 + 0.8 * np.sin(xx / 9)  # crosses whole pixels along each row
    cx = xx - 4.6 + 3e-2 * (yy - 25)
    cy[5, 10:20] = -30.0  # beyond the padding: clamped
    cx[40, 60:] = W + 25.0
    cy[7, 3] = np.nan
    out = np.full((4, H, W), -7.0)
    kern.cubic4_at(coef, float(pad), cy, cx, out)
    ok = np.isfinite(cy)
    # a point beyond the padded map is first clamped to it (cubic4_at's docstring)
    at = [np.clip(cy[ok] + pad, 0, H + 2 * pad - 1), np.clip(cx[ok] + pad, 0, W + 2 * pad - 1)]
    for p in range(4):
        want = ndimage.map_coordinates(coef[p], at, order=3, mode="nearest", prefilter=False)
        np.testing.assert_allclose(out[p][ok], want, rtol=0, atol=1e-14 * 16 * 3)
