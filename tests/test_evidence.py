"""The evidence behind a fringe order: "confirmed" must mean right.

Families of cases that imitate evidence, each against its truth:

- a steep continuous gradient of an intact grid (not a crack), and a torn grid (a crack);

Images from ``tests/lab_light.py`` (a printed grid under a lab's light: a moving hot
spot, a specular highlight) and, for the crack, ``tests/world_camera.py`` (whose
camera sees the crack's dark inside); neither shares code with gridstrain.
"""

from __future__ import annotations

import numpy as np
import pytest

from gridstrain.series import measure_series
from lab_light import photograph, spots
from world_camera import Specimen, edge_crack
from world_camera import photograph as world_photograph


def _errors(res, i, disp):
    """(2, n) displacement errors of state ``i`` at its valid pixels, px."""
    v = np.asarray(res.valid[i])
    H, W = v.shape
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    return (np.asarray(res.u[i]) - np.stack(disp(xx, yy)))[:, v]


# --------------------------------------------------------------- a gradient is not a tear


@pytest.mark.parametrize(("pitch", "printed", "seed"), [(6.4, True, 0), (8.0, False, 3)])
def test_a_steep_continuous_gradient_is_followed_not_cut(pitch, printed, seed):
    # u_x = A tanh((X - x0) / w): a rise of one period (2A = pitch) over about three
    # pitches (w = 1.5 pitch), the grid intact; the phases are continuous across it
    H, W = 144, 256
    A, w = pitch / 2, 1.5 * pitch

    def disp(X, Y):
        return A * np.tanh((X - W / 2) / w), 0 * Y

    rng = np.random.default_rng(seed)
    D = spots((H, W), seed) if printed else None
    ref = photograph((H, W), pitch, defects=D, noise=rng, full=2000)
    cur = photograph((H, W), pitch, disp, defects=D, noise=rng, full=2000)
    res = measure_series(ref, cur)
    assert res.discontinuities == ((),)
    assert not any("jump" in m for m in res.warnings), res.warnings
    v = np.asarray(res.valid[0])
    # the steep part is measured, not left out: its column holds the frame's band
    assert v[:, W // 2].sum() >= 0.9 * v[:, 40].sum()
    err = _errors(res, 0, disp)
    # a part a period off would be a pitch (6.4 or 8 px) off; a quarter of it is more
    # than the window's bias, sigma^2/2 |u''| <= 0.09 pitch at the step's inflections
    assert np.abs(err).max() < pitch / 4
    # px: RMS over the field, the window's bias (measured 0.045 and 0.068) with noise
    # of 3e-3 px; 0.1 px is a sixtieth of a period
    assert np.sqrt(np.mean(err**2)) < 0.1


def test_a_torn_grid_is_still_cut():
    # an edge crack opening by 4.5 px (0.7 period) at pitch 6.4: the camera sees the
    # crack's dark inside, and the phases the jump modulo the period (-1.9 px)
    H, W = 160, 208
    disp = edge_crack(4.5, 80.3, 130.0)
    rng = np.random.default_rng(1)
    spec = Specimen((H, W), pitch=6.4, seed=2)
    ref = world_photograph(spec, rng=rng).astype(float)
    cur = world_photograph(spec, disp, rng=rng).astype(float)
    res = measure_series(ref, cur)
    (regions,) = res.discontinuities
    assert len(regions) == 1
    assert regions[0]["rows"][0] < 80.3 < regions[0]["rows"][1]
    assert any("jumps" in m for m in res.warnings)
    # px: the pixels left are right (noise 3e-3 px; a side a period off is 6.4 px)
    assert np.abs(_errors(res, 0, disp)).max() < 0.05
