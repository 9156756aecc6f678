"""The compiled bilinear reads of the content comparison
(gridstrain.kinematics._bilinear_kernels) are scipy's map_coordinates(order=1,
mode="nearest"), bit for bit: points on pixels, between them, on the last row and
column and beyond every border."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from gridstrain.kinematics import _grid_free

pytestmark = pytest.mark.skipif(_grid_free._load_kernels() is None,
                                reason="numba not installed")


@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (37, 61), (120, 90)])
def test_compiled_reads_are_scipys_bit_for_bit(shape):
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    img = rng.normal(size=shape) * 10.0 ** rng.integers(-3, 4, size=shape)
    H, W = shape
    n = 5000
    ys = rng.uniform(-4.0, H + 3.0, n)
    xs = rng.uniform(-4.0, W + 3.0, n)
    # whole and half pixels, the last row and column, exactly
    ys[:40] = rng.integers(-2, H + 2, 40) + rng.choice([0.0, 0.5], 40)
    xs[:40] = rng.integers(-2, W + 2, 40) + rng.choice([0.0, 0.5], 40)
    ys[40:45], xs[40:45] = H - 1.0, W - 1.0
    coords = np.stack([ys, xs])
    expected = ndimage.map_coordinates(img, coords, order=1, mode="nearest")
    assert np.array_equal(_grid_free.bilinear(img, coords), expected)


def test_without_numba_scipy_reads(monkeypatch):
    monkeypatch.setattr(_grid_free, "_COMPILED", False)
    img = np.arange(12.0).reshape(3, 4)
    coords = np.array([[0.5, 2.0, -1.0], [1.25, 3.5, 0.0]])
    assert np.array_equal(_grid_free.bilinear(img, coords),
                          ndimage.map_coordinates(img, coords, order=1, mode="nearest"))
