"""The camera noise (K, L) from one grid image, and uncertainty maps for one-frame states.

Images from the numpy-only generator of ``tests/independent_grid.py`` (its
assumptions are in its docstring).
"""

from __future__ import annotations

import numpy as np
import pytest

from gridstrain.series import measure_series
from gridstrain.uncertainty import estimate_noise_image
from independent_grid import camera as _camera
from independent_grid import scene as _scene

CASES = [
    # K, L (sensor), pitch, angle, pattern
    (0.28, 5.0, 5.3, 20.0, "checker"),
    (0.6, 20.0, 7.1, -12.0, "checker"),
    (0.1, 2.0, 4.0, 0.0, "lines"),
    (0.4, 10.0, 6.2, 5.0, "sine"),
]


@pytest.mark.parametrize(("K", "L", "pitch", "angle", "kind"), CASES)
def test_single_image_noise_model(K, L, pitch, angle, kind):
    level, _ = _scene((512, 688), pitch=pitch, angle=angle, kind=kind)
    img = _camera(level, K, L, np.random.default_rng(7))
    m = estimate_noise_image(img, saturation=65520, scale=16)
    assert m.method == "single image"
    assert m.n_frames == 1
    # stored units are 16 and 256 times the sensor's
    assert np.isclose(m.K_sensor, m.K / 16)
    assert np.isclose(m.L_sensor, m.L / 256)
    # K within 15 % and the variance at the image's mean level within 10 % (the
    # acceptance figures), and tighter, at about five standard errors of each:
    # K within 3 % and the variance within 2 % (measured: within 1.5 % and 0.8 %);
    # the truth includes the quantisation's 1/12 grey level^2
    mean = float(level.mean())
    truth = K * mean + L + 1 / 12
    assert abs(m.K_sensor / K - 1) < 0.03
    assert abs((m.K_sensor * mean + m.L_sensor) / truth - 1) < 0.02
    # the 95 % interval of K (half-width 1.2 % to 6 %) is about right: the truth lies
    # within its 99.9 % extension (3.29 / 1.96 = 1.68 times); measured: inside the
    # 95 % interval in 15 cases of 16, the sine grid's K 1 % low
    lo, hi = m.K_sensor_ci
    assert abs(m.K_sensor - K) < 1.68 * (hi - lo) / 2


@pytest.mark.parametrize(("texture", "scale", "low", "high"), [
    # 5 % contrast over 20 px: measured +0.2 % on the variance at the mean level;
    # 2 % is four standard errors of that variance
    (0.05, 20.0, -0.02, 0.02),
    # over 5 px: measured +1.6 %
    (0.05, 5.0, -0.02, 0.04),
    # over 3 px the texture is noise-like and passes the filter: measured +7.5 %
    (0.02, 3.0, 0.03, 0.15),
])
def test_print_texture_bias(texture, scale, low, high):
    """A print texture smooth over 5 px or more modulates the harmonics within their
    (widened) notches and is removed with the grid; a texture at the pixel scale
    counts as noise, its bias growing as its contrast squared."""
    level, _ = _scene((512, 688), pitch=5.3, angle=20.0, texture=texture,
                      texture_scale=scale, seed=1)
    img = _camera(level, 0.28, 5.0, np.random.default_rng(1))
    m = estimate_noise_image(img, saturation=65520, scale=16)
    mean = float(level.mean())
    bias = (m.K_sensor * mean + m.L_sensor) / (0.28 * mean + 5 + 1 / 12) - 1
    assert low < bias < high


def test_single_image_refusals():
    level, _ = _scene((128, 128), pitch=5.0, angle=0.0, over=2)
    img = _camera(level, 0.28, 5.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="at least 160 x 160"):
        estimate_noise_image(img)
    # a denoised (noise-free) image has no signal-dependent noise to find
    level, _ = _scene((256, 256), pitch=5.0, angle=0.0, over=2, hole=False)
    with pytest.raises(ValueError, match="noise"):
        estimate_noise_image(np.round(level))
    with pytest.raises(ValueError, match="n_bins"):
        estimate_noise_image(np.round(level), n_bins=2)


def _displacement(H, W):
    """A non-uniform field: strains varying by 3e-3 across the image, shear."""
    def u(X, Y):
        ux = 1e-3 * X + 3e-3 * W / (2 * np.pi) * np.sin(2 * np.pi * X / W) + 5e-4 * Y
        uy = 1e-3 * Y + 2e-3 * H / (2 * np.pi) * np.cos(2 * np.pi * Y / H + 0.3)
        return ux, uy
    return u


def _empirical_vs_predicted(size, draws, seed):
    H = W = size
    ref0, _ = _scene((H, W), pitch=5.3, angle=10.0, kind="sine", amplitude=1500.0,
                     over=3)
    cur0, _ = _scene((H, W), pitch=5.3, angle=10.0, kind="sine", amplitude=1500.0,
                     over=3, displacement=_displacement(H, W))
    rng = np.random.default_rng(seed)
    res = [measure_series(_camera(ref0, 0.28, 5.0, rng).astype(np.float64),
                          _camera(cur0, 0.28, 5.0, rng).astype(np.float64), guess=None)
           for _ in range(draws)]
    valid = np.all([r.valid[0] for r in res], axis=0)
    ratios = {}
    for name in ("ux", "uy", "exx", "eyy", "exy"):
        assert all(r.uncertainty is not None for r in res)
        maps = np.array([r.get_map(name)[0] for r in res])
        emp = maps.std(axis=0, ddof=1)
        pred = np.median([r.uncertainty[name + "_std"][0] for r in res], axis=0)
        ratios[name] = float(np.median(emp[valid]) / np.median(pred[valid]))
    return res, ratios


def test_one_frame_uncertainty_maps_match_repeated_draws():
    """One frame per state: the std maps from the single-image noise model against
    the scatter over 8 noise draws (256 x 256, a hole, non-uniform strain).
    Measured: ratios 0.99 to 1.01. Tolerance 10 %: the empirical std of 8 draws
    has a 27 % spread per pixel, its median over the ~100 independent windows of
    the valid region about 3 %, and the model of one image about 1 %."""
    res, ratios = _empirical_vs_predicted(256, 8, 0)
    r = res[0]
    assert r.noise.model["source"] == "single image"
    assert all(np.isfinite(r.noise.theory_u[0]))
    assert all(np.isfinite(r.noise.theory_strain[0]))
    for name, ratio in ratios.items():
        assert abs(ratio - 1) < 0.10, (name, ratio)


@pytest.mark.slow
def test_one_frame_uncertainty_maps_large():
    """The same on 512 x 512 with 40 draws: within 5 % (measured: 1.005 to 1.012)."""
    _, ratios = _empirical_vs_predicted(512, 40, 1)
    for name, ratio in ratios.items():
        assert abs(ratio - 1) < 0.05, (name, ratio)


def test_tile_spectrum_by_batches_is_the_median_over_all_tiles(monkeypatch):
    # the tiles transformed a few at a time (here 3 per batch) give the median, bin
    # by bin, of every usable tile's Blackman-Harris periodogram taken at once
    from numpy.lib.stride_tricks import sliding_window_view
    from scipy import ndimage

    from gridstrain.uncertainty import _noise_image as noise

    rng = np.random.default_rng(41)
    img = rng.normal(1000.0, 10.0, (160, 224))
    usable = np.ones(img.shape, dtype=bool)
    usable[5, 5] = False  # leaves out the tiles that hold it
    tile = 32
    monkeypatch.setattr(noise, "_TILE_BATCH_BYTES", 3 * tile * tile * 8)
    got = noise._tile_spectrum(img, usable, tile)
    w = noise._blackman_harris(tile)
    tiles = sliding_window_view(img, (tile, tile))[::16, ::16]
    ok = sliding_window_view(usable, (tile, tile))[::16, ::16].all(axis=(2, 3))
    sel = tiles[ok]
    assert 0 < len(sel) < tiles.shape[0] * tiles.shape[1]
    per = np.abs(np.fft.fft2((sel - sel.mean(axis=(1, 2), keepdims=True)) * np.outer(w, w)))
    want = ndimage.uniform_filter(np.median(per**2, axis=0), 3, mode="wrap")
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_single_image_noise_holds_a_few_images_of_memory():
    # numpy's allocations (tracemalloc: deterministic, not a timing): the estimate
    # once held 12 times the image (float64) at its peak; each full-size map is now
    # dropped once used and the tile periodograms go straight into the median's table
    import tracemalloc

    level, _ = _scene((600, 800), pitch=5.0, angle=12.0, amplitude=2500.0)
    img = _camera(level, K=1.0, L=25.0, rng=np.random.default_rng(5)).astype(np.float64)
    tracemalloc.start()
    try:
        estimate_noise_image(img)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 7 * img.nbytes


def test_single_image_read_noise_is_never_negative():
    """``L`` of one image is poorly pinned (its interval spans hundreds of stored grey
    levels^2): a sensor with little read noise gives negative fits in many draws,
    refitted at ``L = 0``; ``K`` stays within its acceptance figure."""
    K, L = 0.3, 0.2  # sensor units: L is 1/12 of quantisation plus a little read noise
    level, _ = _scene((256, 320), pitch=5.3, angle=20.0, kind="checker")
    Ls, Ks = [], []
    for seed in range(8):
        m = estimate_noise_image(_camera(level, K, L, np.random.default_rng(seed)),
                                 saturation=65520, scale=16)
        assert m.L >= 0
        assert m.L_ci[0] >= 0
        assert m.L_ci[0] <= m.L <= m.L_ci[1]
        Ls.append(m.L)
        Ks.append(m.K_sensor)
    # some draws hit the bound (the unconstrained fit is negative in about half of
    # them at this read noise)
    assert min(Ls) == 0.0
    # K within 10 % in every draw: on 256 x 320 px its single-image standard error is
    # about 3 %, K and L trading against each other (measured: within 6.2 %)
    assert np.max(np.abs(np.array(Ks) / K - 1)) < 0.10


@pytest.mark.parametrize(("pitch", "angle"), [(6.0, 12.0), (5.3, -20.0), (4.0, 0.0)])
def test_grid_removal_filter_is_the_one_of_the_notch_by_notch_loop(pitch, angle):
    # the candidates' bins and peaks taken at once, each notch written through slices
    # (two where it wraps round the spectrum's edge): the same filter, bit for bit, as
    # the loop that gathered and scattered each notch's block
    import math

    from gridstrain import Lattice
    from gridstrain.uncertainty import _noise_image as N

    shape, tile, s = (200, 260), 128, 0.02
    lattice = Lattice.from_pitch(pitch, angle=angle)
    spec = np.random.default_rng(7).random((tile, tile)) + 1.0
    spec[3, 5] = spec[-3, -5] = 40.0  # a strong peak: a wide notch where it is a harmonic

    cand = N._harmonics(lattice, N._MAX_ORDER)
    near = np.zeros((tile, tile), dtype=bool)
    for fy, fx in cand:
        iy, ix = round(fy * tile) % tile, round(fx * tile) % tile
        near[np.ix_(np.arange(iy - 3, iy + 4) % tile, np.arange(ix - 3, ix + 4) % tile)] = True
    far = spec[~near] if (~near).sum() >= 20 else spec.ravel()
    floor = float(np.median(far)) if (~near).sum() >= 20 else float(np.quantile(far, 0.1))
    n = np.arange(-N._MAX_ORDER, N._MAX_ORDER + 1)
    nn, mm = np.meshgrid(n, n)
    always = (np.abs(nn) + np.abs(mm)).ravel() <= 1
    want = np.ones(shape)
    fy_all, fx_all = np.fft.fftfreq(shape[0]), np.fft.fftfreq(shape[1])
    used = []
    for (fy, fx), keep in zip(cand, always, strict=True):
        iy, ix = round(fy * tile) % tile, round(fx * tile) % tile
        local = spec[np.ix_(np.arange(iy - 1, iy + 2) % tile, np.arange(ix - 1, ix + 2) % tile)]
        if not keep and local.max() <= N._PEAK_FACTOR * floor:
            continue
        used.append((fy, fx))
        sh = s * (1.0 + N._WIDEN * math.log10(max(float(local.max()) / floor, 1.0)))
        dy = (fy_all - fy + 0.5) % 1.0 - 0.5
        dx = (fx_all - fx + 0.5) % 1.0 - 0.5
        ri, ci = np.nonzero(np.abs(dy) < 8 * sh)[0], np.nonzero(np.abs(dx) < 8 * sh)[0]
        g = np.exp(-0.5 * dy[ri, None] ** 2 / sh**2) * np.exp(-0.5 * dx[None, ci] ** 2 / sh**2)
        want[np.ix_(ri, ci)] *= (1.0 - g) ** 2

    got, got_used = N._residual_filter(shape, lattice, spec, s)
    assert np.array_equal(got, want)
    assert np.array_equal(got_used, np.array(used))
