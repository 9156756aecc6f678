"""The contrast step's bound by its compiled loop (gridstrain.uncertainty._kernels) is the
numpy and scipy path's, bit for bit: the material points anywhere, off the image too,
invalid pixels, both precisions."""

from __future__ import annotations

import numpy as np
import pytest

from gridstrain.uncertainty import _contrast

pytestmark = pytest.mark.skipif(_contrast._load_kernels() is None,
                                reason="numba not installed")


def _bound(monkeypatch, compiled, *args, **kwargs):
    monkeypatch.setattr(_contrast, "_COMPILED", compiled)
    return _contrast.contrast_step_bound(*args, **kwargs)


@pytest.mark.parametrize("dtype", [np.complex128, np.complex64])
@pytest.mark.parametrize(("shape", "spread"), [((60, 90), 8.0), ((131, 77), 0.7),
                                               ((200, 150), 30.0)])
def test_compiled_bound_is_the_numpy_bound_bit_for_bit(monkeypatch, shape, spread, dtype):
    rng = np.random.default_rng(shape[0])
    ref = (rng.normal(size=(2, *shape)) + 1j * rng.normal(size=(2, *shape)) + 3.0)
    dfm = ref * (1.0 + 0.05 * rng.normal(size=(2, *shape)))
    ref, dfm = ref.astype(dtype), dfm.astype(dtype)
    # material points up to several pixels (or the whole image) off it
    u = rng.normal(0.0, spread, (2, *shape)).astype(ref.real.dtype)
    valid = rng.random(shape) > 0.2
    u[:, ~valid] = np.nan  # as a measurement leaves them
    a = _bound(monkeypatch, False, ref, dfm, u, valid, sigma=3.0)
    b = _bound(monkeypatch, True, ref, dfm, u, valid, sigma=3.0)
    assert np.array_equal(a, b, equal_nan=True)


def test_compiled_loop_at_the_edges_and_whole_points(monkeypatch):
    """Points exactly on pixels, on the last row and column, half a pixel and more
    beyond each border: scipy clamps the neighbours, not the point."""
    H, W = 40, 50
    rng = np.random.default_rng(7)
    rx, ry, dx, dy = (rng.normal(size=(H, W)) for _ in range(4))
    u = np.zeros((2, H, W))
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    u[1] = np.where(yy > H / 2, (H - 1) - yy + rng.choice([0.0, 0.5, 1.0, 3.25], (H, W)),
                    -yy - rng.choice([0.0, 0.5, 1.0, 3.25], (H, W)))
    u[0] = np.where(xx > W / 2, (W - 1) - xx + 0.5, -xx - 0.5)
    valid = np.ones((H, W), bool)
    s1, s2 = np.zeros((H, W)), np.zeros((H, W))
    _contrast._block_change(s1, (rx, ry), (dx, dy), u, valid, slice(0, H))
    _contrast._load_kernels().steepest_change(s2, rx, ry, dx, dy, u, valid, 0, H)
    assert np.array_equal(s1, s2)
    # a NaN already in the running maximum stays, as np.maximum keeps it
    s1[3, 4] = s2[3, 4] = np.nan
    _contrast._block_change(s1, (rx, ry), (dx, dy), u, valid, slice(0, H))
    _contrast._load_kernels().steepest_change(s2, rx, ry, dx, dy, u, valid, 0, H)
    assert np.array_equal(s1, s2, equal_nan=True)
