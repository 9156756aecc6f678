"""The fast windowed Fourier transform against the plain spectral one, and method B.

gridstrain.wft (implemented in gridstrain.phase._transform) computes, per wave vector, 1-D
inverse FFTs of only the band of the spectrum where the window's transfer function
is non-zero (see its Notes). The oracle here is the textbook spectral evaluation of
eqs. (22)-(25): full 2-D inverse FFTs of the filtered spectra of the zero-padded
image, a distance transform for the valid region and np.median, at a different
padded size. The direct double sum of
tests/test_wft.py ties both to the definition.
"""

import importlib
import math
import threading

import numpy as np
import pytest
from scipy import ndimage

from gridstrain import Lattice, wft
from gridstrain._stats import median as _median
from gridstrain._stats import row_medians
from gridstrain.models import synthetic
from gridstrain.phase._spectrum import spectrum_block as _spectrum_block
from gridstrain.phase._spectrum import transfer_function
from gridstrain.phase._transform import _wft
from gridstrain.stacks import method_b


def _reference(img, lat, sigma, mask=None, margin=4.0, min_modulus=0.25):
    """Eqs. (22)-(25) by full 2-D FFTs; ``(psi, dphi, valid)``."""
    H, W = img.shape
    m = np.ones(img.shape, bool) if mask is None else mask
    v = np.where(m, img - img[m].mean(), 0.0)
    pad = math.ceil(8 * sigma) + 3  # any size >= H + 8 sigma makes the convolution linear
    ny, nx = H + pad, W + pad
    F = np.fft.fft2(v, s=(ny, nx))
    fy, fx = np.fft.fftfreq(ny)[:, None], np.fft.fftfreq(nx)[None, :]
    y, x = np.arange(H)[:, None], np.arange(W)[None, :]
    psi = np.empty((2, H, W), complex)
    dphi = np.empty((2, 2, H, W))
    for j, k in enumerate((lat.k1, lat.k2)):
        nux = (fx - k[0] + 0.5) % 1.0 - 0.5
        nuy = (fy - k[1] + 0.5) % 1.0 - 0.5
        gx, gy = transfer_function(nux, sigma), transfer_function(nuy, sigma)
        dgx = transfer_function(nux, sigma, derivative=True)
        dgy = transfer_function(nuy, sigma, derivative=True)
        c = np.fft.ifft2(F * gy * gx)[:H, :W]
        cx = np.fft.ifft2(F * gy * dgx)[:H, :W]
        cy = np.fft.ifft2(F * dgy * gx)[:H, :W]
        psi[j] = c * np.exp(-2j * np.pi * (k[0] * x + k[1] * y))
        dphi[j, 0] = np.imag(np.conj(c) * cx) / np.abs(c) ** 2
        dphi[j, 1] = np.imag(np.conj(c) * cy) / np.abs(c) ** 2
    dist = ndimage.distance_transform_edt(np.pad(m, 1))[1:-1, 1:-1]
    valid = dist > margin * sigma
    # both medians over the region valid by its distance to the edges (a copy:
    # the first modulus test must not thin the second one's region)
    ref = (valid if valid.any() else m).copy()
    mod = np.abs(psi)
    for j in range(2):
        valid &= mod[j] >= min_modulus * np.median(mod[j][ref])
    return psi, dphi, valid


def _noisy_grid(shape, lat, seed):
    img = synthetic.grid_image(
        shape, lat, amplitude=2000.0,
        phases=lambda X, Y: (0.3 * np.sin(2 * np.pi * Y / 60), 0.4 * np.cos(2 * np.pi * X / 45)))
    return synthetic.add_noise(img, rng=seed)


CASES = {
    # axis-aligned: the carrier falls on FFT bins, no residual demodulation
    "aligned": (Lattice.from_pitch(5.0), (96, 120), None, None),
    # rotated, sigma above the pitch: off-bin carrier, bands not centred on a bin
    "rotated": (Lattice.from_pitch(5.0, angle=23.0), (101, 87), 7.3, None),
    # pitch 2.5: the band of sigma = 2.5 wraps over the whole spectrum
    "small pitch": (Lattice.from_pitch(2.5, angle=10.0), (64, 72), None, None),
    # a hole: the valid region needs the distance transform
    "masked": (Lattice.from_pitch(5.0, angle=-15.0), (110, 100), None, "hole"),
    # a third of the image without grid: the modulus tests thin the valid region
    "gridless": (Lattice.from_pitch(5.0, angle=8.0), (120, 96), None, "patch"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_matches_full_2d_spectral_reference(case):
    lat, shape, sigma, mask = CASES[case]
    img = _noisy_grid(shape, lat, seed=len(case))
    if mask == "hole":
        yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
        mask = (yy - 50) ** 2 + (xx - 45) ** 2 > 12**2
    elif mask == "patch":
        img[:, 55:] = img.mean()
        mask = None
    res = wft(img, lat, sigma=sigma, mask=mask, derivatives="exact")
    psi, dphi, valid = _reference(img, lat, lat.pitch if sigma is None else sigma, mask)
    # float64 rounding of FFTs of ~1e3 grey levels over ~1e4 pixels and of carriers
    # at phases up to 2 pi k x ~ 1e3 rad: ~1e-13 relative on Psi, ~1e-16 rad/px on the
    # derivatives; 1e-11 relative and 1e-12 rad/px leave room and are 1000x below the
    # 1e-9 bound of tests/test_wft.py
    np.testing.assert_allclose(res.psi, psi, rtol=1e-11, atol=1e-11 * np.abs(psi).max())
    np.testing.assert_allclose(res.dphi[:, :, valid], dphi[:, :, valid], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(res.valid, valid)
    assert valid.any()


def test_blocks_of_rows_give_the_same_maps(monkeypatch):
    # the final inverse FFTs run by blocks of rows sized for the cache; force blocks
    # of 8 rows (the last one partial) and compare with one block for the image
    wft_module = importlib.import_module("gridstrain.phase._transform")  # the implementation
    lat, shape, sigma, _ = CASES["rotated"]
    img = _noisy_grid(shape, lat, seed=2)
    whole = wft(img, lat, sigma=sigma, derivatives="exact")
    monkeypatch.setattr(wft_module, "_CHUNK_BYTES", 1)
    blocks = wft(img, lat, sigma=sigma, derivatives="exact")
    # the same arithmetic on the same numbers, row by row: identical bits
    np.testing.assert_array_equal(blocks.psi, whole.psi)
    np.testing.assert_array_equal(blocks.dphi, whole.dphi)
    np.testing.assert_array_equal(blocks.valid, whole.valid)


@pytest.mark.parametrize("derivatives", ["exact", "fast"])
def test_two_threads_give_the_same_maps(derivatives):
    # one wave vector per thread, each on its own scratch arrays: the same arithmetic
    # on the same numbers, so identical bits (a shared buffer would show here)
    lat, shape, sigma, _ = CASES["rotated"]
    img = _noisy_grid(shape, lat, seed=4)
    mask = np.ones(shape, dtype=bool)
    mask[30:50, 40:70] = False
    for m in (None, mask):
        one = _wft(img, lat, sigma=sigma, mask=m, derivatives=derivatives)
        two = _wft(img, lat, sigma=sigma, mask=m, derivatives=derivatives, workers=2)
        np.testing.assert_array_equal(two.psi, one.psi)
        np.testing.assert_array_equal(two.dphi, one.dphi)
        np.testing.assert_array_equal(two.valid, one.valid)
    with pytest.raises(ValueError, match="workers"):
        wft(img, lat, workers=0)


def test_nothing_valid_takes_the_median_over_the_mask():
    # a margin wider than the image leaves no valid pixel; the modulus test then uses
    # the median over the whole mask, as the reference does
    lat = Lattice.from_pitch(5.0)
    img = _noisy_grid((48, 48), lat, seed=3)
    res = wft(img, lat, margin=10.0)
    _, _, valid = _reference(img, lat, 5.0, margin=10.0)
    assert not res.valid.any()
    np.testing.assert_array_equal(res.valid, valid)


def test_float32_stays_within_the_float32_bound():
    lat = Lattice.from_pitch(5.0, angle=20.0)
    img = _noisy_grid((128, 144), lat, seed=5)
    r64 = wft(img, lat)
    r32 = wft(img.astype(np.float32), lat)
    assert r32.psi.dtype == np.complex64
    assert r32.dphi.dtype == np.float32
    v = r64.valid
    # float32 bound of the issue on derivatives: 1e-6 rad/px (rounding gives ~1e-8)
    assert np.max(np.abs(r32.dphi - r64.dphi)[:, :, v]) < 1e-6
    # phases: float32 relative rounding 6e-8 times the FFT's log n growth, < 1e-5 rad
    assert np.max(np.abs(np.angle(r32.psi * np.conj(r64.psi)))[:, v]) < 1e-5


@pytest.mark.parametrize("n", [1, 2, 7, 1000, 1001])
def test_median_is_numpy_median(n):
    rng = np.random.default_rng(n)
    values = rng.integers(0, 5, n).astype(float) + rng.random(n) * (n % 2)  # ties when even
    before = values.copy()
    assert _median(values) == np.median(values)
    np.testing.assert_array_equal(values, before)  # not modified
    box = rng.random((n + 20, 31))[7:n + 9, 3:30]  # a 2-D view, as the valid box is
    assert _median(box) == np.median(box)
    f32 = values.astype(np.float32)  # in the values' precision, as numpy's
    assert _median(f32) == float(np.median(f32))
    values[n // 3] = np.nan  # a NaN anywhere gives NaN, as numpy's
    assert np.isnan(_median(values))
    assert np.isnan(np.median(values))
    work = box.copy()
    assert _median(work, overwrite_input=True) == np.median(box)


@pytest.mark.parametrize("n", [1, 2, 7, 300, 301])
def test_row_medians_are_numpy_medians(n):
    rng = np.random.default_rng(n)
    table = rng.integers(0, 4, (50, n)).astype(float) + rng.random((50, n)) * (n % 2)
    table[7, n // 2] = np.nan  # a row with a NaN gives NaN, as numpy's
    want = np.median(table, axis=1)
    got = row_medians(table.copy())
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got[7])
    assert row_medians(np.empty((3, 0))).shape == (3,)


@pytest.mark.parametrize("n", [2**14, 2**14 + 1, 90_001, 250_000])
def test_median_of_large_maps_is_numpy_median(n):
    # from 2**14 values the middle pair is selected among those a subsample brackets:
    # the same values as numpy's, for noise, ties, sorted data, float32, a view, and
    # data whose strided subsample misses the middle (every 7th value large)
    rng = np.random.default_rng(n)
    cases = [rng.normal(size=n), rng.integers(0, 3, n).astype(float), np.sort(rng.random(n)),
             rng.normal(size=n).astype(np.float32), np.full(n, 2.5),
             np.where(np.arange(n) % max(1, n // 2048) == 0, 1e3, rng.random(n)),
             rng.random((n // 100 + 2, 110))[1:-1, 5:105]]
    for values in cases:
        before = values.copy()
        assert _median(values) == np.median(values)
        np.testing.assert_array_equal(values, before)  # not modified
        assert _median(values.copy(), overwrite_input=True) == np.median(values)
    values = cases[0]
    values[n // 3] = np.nan
    assert np.isnan(_median(values))


@pytest.mark.parametrize("case", ["random", "sorted", "ties", "constant", "nan", "float32",
                                  "strided", "view"])
@pytest.mark.parametrize("n", [2**17, 2**17 + 1])
def test_bracketed_median_of_large_arrays_is_numpy_median(case, n):
    """From 2^16 values on, the middle is bracketed from a sample; the result must be
    numpy's exactly, also when the sample misrepresents the array (a layout whose
    every sampled value is the largest: the whole array is then sorted)."""
    rng = np.random.default_rng(n)
    values = rng.normal(size=n)
    if case == "sorted":
        values.sort()
    elif case == "ties":
        values = rng.integers(0, 7, n).astype(float)
    elif case == "constant":
        values = np.full(n, 3.25)
    elif case == "nan":
        values[rng.integers(n)] = np.nan
    elif case == "float32":
        values = values.astype(np.float32)
    elif case == "strided":
        values[::max(1, n // 2**14)] = 1e9  # the sample sees only these
    elif case == "view":
        values = rng.normal(size=(n // 64 + 3, 70))[1:n // 64 + 1, 3:67]
    before = values.copy()
    want = np.median(values)
    got = _median(values)
    if case == "nan":
        assert np.isnan(got)
        assert np.isnan(want)
    else:
        assert got == float(want)
    np.testing.assert_array_equal(values, before)  # not modified
    work = np.ascontiguousarray(values).copy()
    got = _median(work, overwrite_input=True)
    assert got == float(want) or (np.isnan(got) and np.isnan(want))


def test_median_of_nothing_is_nan():
    assert np.isnan(_median(np.array([])))


def test_median_of_integers_is_numpy_median():
    # the two middle values of 16-bit grey levels would overflow their own type
    values = np.array([65535, 65534, 1, 65533], dtype=np.uint16)
    assert _median(values) == np.median(values) == 65533.5
    assert _median(np.array([3, -7, 5], dtype=np.int32)) == 3.0


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize(("shape", "sigma"), [((250, 400), 5.0), ((64, 65), 1.4),
                                              ((7, 5), 9.0), ((1, 30), 3.0), ((30, 1), 3.0),
                                              ((40, 50), 28.0)])
def test_noise_weighted_mean_is_scipys_gaussian_filter(shape, sigma, compiled, monkeypatch):
    """The g^2-weighted mean of the uncertainty maps: scipy's gaussian_filter bit for
    bit, compiled or not; with lines shorter than the kernel (the nearest value
    repeated), grey levels of every scale, and NaN and inf spreading as scipy's."""
    from gridstrain.uncertainty import _maps

    if compiled and _maps._load_kernels() is None:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(_maps, "_COMPILED", compiled)
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    values = rng.normal(size=shape) * 10.0 ** rng.uniform(-3, 4, size=shape) + 1e3
    sd = sigma / math.sqrt(2)
    want = ndimage.gaussian_filter(values, sd, mode="nearest", truncate=5.0)
    got = _maps.noise_weighted(values, sigma)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64))
    values[shape[0] // 2, shape[1] // 3] = np.nan
    values[0, -1] = np.inf
    want = ndimage.gaussian_filter(values, sd, mode="nearest", truncate=5.0)
    np.testing.assert_array_equal(_maps.noise_weighted(values, sigma), want)
    view = rng.normal(size=(shape[0] + 4, shape[1] + 6))[2:-2, 3:-3]  # not contiguous
    np.testing.assert_array_equal(_maps.noise_weighted(view, sigma),
                                  ndimage.gaussian_filter(view, sd, mode="nearest",
                                                          truncate=5.0))


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize(("shape", "sigma", "box"),
                         [((250, 400), 5.0, (20, 230, 20, 380)), ((64, 65), 1.4, (0, 64, 3, 65)),
                          ((40, 50), 28.0, (5, 6, 49, 50)), ((30, 20), 3.0, (0, 30, 0, 20)),
                          ((30, 20), 3.0, None)])
def test_noise_weighted_mean_at_some_pixels_is_the_whole_maps(shape, sigma, box, compiled,
                                                             monkeypatch):
    """The g^2-weighted mean asked at some pixels (``where``): scipy's whole-map filter
    bit for bit in the box that holds them, NaN outside it; the box at the map's
    borders, one pixel, the whole map, and no pixel at all (all NaN)."""
    from gridstrain.uncertainty import _maps

    if compiled and _maps._load_kernels() is None:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(_maps, "_COMPILED", compiled)
    rng = np.random.default_rng(shape[0] + shape[1])
    values = rng.normal(size=shape) * 10.0 ** rng.uniform(-3, 4, size=shape) + 1e3
    want = ndimage.gaussian_filter(values, sigma / math.sqrt(2), mode="nearest",
                                   truncate=5.0)
    where = np.zeros(shape, dtype=bool)
    inside = np.zeros(shape, dtype=bool)
    if box is not None:
        r0, r1, c0, c1 = box
        inside[r0:r1, c0:c1] = True
        # the box's corners and a pixel within it: the box that holds them is the box
        where[r0, c0] = where[r1 - 1, c1 - 1] = where[(r0 + r1) // 2, (c0 + c1) // 2] = True
    got = _maps.noise_weighted(values, sigma, where=where)
    np.testing.assert_array_equal(got[inside].view(np.uint64), want[inside].view(np.uint64))
    assert np.isnan(got[~inside]).all()


@pytest.mark.parametrize(("ny", "nx", "r0", "nr", "c0", "nc"),
                         [(12, 16, 10, 5, 13, 6), (9, 10, 0, 9, 0, 10), (12, 15, 3, 4, 2, 4)])
def test_spectrum_block_is_the_full_dft_block(ny, nx, r0, nr, c0, nc):
    # bands that wrap around zero frequency in both axes, the whole spectrum, and a
    # block of positive frequencies only
    rng = np.random.default_rng(0)
    img = rng.standard_normal((ny, nx))
    full = np.fft.fft2(img)
    rows = np.sort((r0 + np.arange(nr)) % ny)
    cols = np.sort((c0 + np.arange(nc)) % nx)
    block = _spectrum_block(np.fft.rfft2(img), rows, cols, nx)
    # float64 FFT rounding of unit-variance data, ~1e-15 of the spectrum's size
    np.testing.assert_allclose(block, full[np.ix_(rows, cols)], atol=1e-12)


def _frames(lat, T, shape=(80, 96)):
    rng = np.random.default_rng(11)
    out = []
    for _ in range(T):
        ux, uy = rng.normal(0, 0.05, 2)
        img = synthetic.grid_image(shape, lat, amplitude=2000.0,
                                   displacement=lambda X, Y, a=ux, b=uy: (a + 0 * X, b + 0 * Y))
        out.append(synthetic.add_noise(img, rng=rng))
    return out


def test_method_b_on_threads_is_the_circular_mean_of_the_frames():
    lat = Lattice.from_pitch(5.0)
    frames = _frames(lat, 5)
    res = method_b(iter(frames), lat, workers=2).maps
    each = [wft(f, lat) for f in frames]
    # the paper's method B, on the circle: arg of the mean unit phasor (oracle written
    # here), mean modulus, mean derivatives, AND of the validity maps
    unit = np.mean([r.psi / np.abs(r.psi) for r in each], axis=0)
    # float64 sums of 5 terms and an angle: a few ulps of pi
    np.testing.assert_allclose(np.angle(res.psi * np.conj(unit)), 0, atol=1e-13)
    np.testing.assert_allclose(np.abs(res.psi), np.mean([np.abs(r.psi) for r in each], axis=0),
                               rtol=1e-13)
    np.testing.assert_allclose(res.dphi, np.mean([r.dphi for r in each], axis=0),
                               rtol=0, atol=1e-15)
    np.testing.assert_array_equal(res.valid, np.logical_and.reduce([r.valid for r in each]))
    # the frames add their blocks in frame order whatever the threads: identical bits
    serial = method_b(frames, lat, workers=1).maps
    np.testing.assert_array_equal(serial.psi, res.psi)
    np.testing.assert_array_equal(serial.dphi, res.dphi)
    np.testing.assert_array_equal(serial.valid, res.valid)


def test_method_b_on_threads_stops_on_a_failing_frame():
    # a uniform frame passes the stack's checks and fails in its transform, in a
    # worker thread, while the frames after it wait for its blocks: they must be
    # released with an error, not left waiting
    lat = Lattice.from_pitch(5.0)
    frames = _frames(lat, 6)
    frames[2] = np.full_like(frames[2], 100.0)
    outcome = []

    def run():
        try:
            method_b(frames, lat, workers=3)
        except ValueError as err:
            outcome.append(str(err))

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout=60)  # seconds; the whole stack takes ~0.1 s
    assert not t.is_alive()
    assert len(outcome) == 1
    assert "uniform" in outcome[0]


def test_method_b_on_threads_keeps_float32_and_reports_progress():
    lat = Lattice.from_pitch(5.0)
    frames = [f.astype(np.float32) for f in _frames(lat, 3)]
    calls = []
    res = method_b(frames, lat, workers=2, progress=lambda f, msg: calls.append(f)).maps
    assert res.psi.dtype == np.complex64
    assert res.dphi.dtype == np.float32
    assert calls == pytest.approx([1 / 3, 2 / 3, 1.0, 1.0])


def test_method_b_refuses_bad_workers():
    lat = Lattice.from_pitch(5.0)
    frames = _frames(lat, 2)
    with pytest.raises(ValueError, match="workers"):
        method_b(frames, lat, workers=0)
    with pytest.raises(ValueError, match="shape"):
        method_b([frames[0], frames[1][:, :-8]], lat, workers=2)
