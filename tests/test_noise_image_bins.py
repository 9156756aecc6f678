"""The single-image noise estimate's bins found by comparisons with their edges are
the binary searches' (np.searchsorted): the same model bit for bit."""

from __future__ import annotations

import numpy as np

from gridstrain import Lattice
from gridstrain.models import synthetic
from gridstrain.uncertainty import _noise_image, estimate_noise_image


def test_bins_by_comparison_are_the_binary_searches(monkeypatch):
    lat = Lattice.from_pitch(6.0, angle=12.0)
    rng = np.random.default_rng(5)
    img = synthetic.add_noise(synthetic.grid_image((256, 320), lat, kind="checkerboard",
                                                   amplitude=2000.0), rng=rng)
    by_comparison = estimate_noise_image(img, lat)
    monkeypatch.setattr(_noise_image, "_COMPARED_EDGES", 0)
    by_search = estimate_noise_image(img, lat)
    for name in ("K", "L", "levels", "variances", "variance_errors", "n_pixels"):
        assert np.array_equal(getattr(by_comparison, name), getattr(by_search, name))
