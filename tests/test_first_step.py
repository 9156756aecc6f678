"""The first state's step from the reference, told above SMALL_STEP without being
measured (:func:`gridstrain.kinematics.tracking._beyond_small_step`): never said where
the measurement (:func:`_first_step`, the oracle) finds it small."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest

from gridstrain import Lattice, wft
from gridstrain.kinematics.tracking import SMALL_STEP, _beyond_small_step, _first_step
from gridstrain.models import synthetic

PITCH = 6.0
SHAPE = (120, 150)


def _maps(field, angle=12.0, seed=0):
    lat = Lattice.from_pitch(PITCH, angle=angle)
    rng = np.random.default_rng(seed)
    kw = {"kind": "checkerboard", "amplitude": 2000.0, "oversample": 2}
    ref = synthetic.add_noise(synthetic.grid_image(SHAPE, lat, **kw), rng=rng)
    cur = synthetic.add_noise(synthetic.grid_image(SHAPE, lat, displacement=field, **kw),
                              rng=rng)
    return wft(ref, lat), wft(cur, lat)


def _affine(ux, uy, exx=0.0, eyy=0.0, exy=0.0, rot=0.0):
    H, W = SHAPE
    cx, cy = (W - 1) / 2, (H - 1) / 2

    def U(X, Y):
        return (ux + exx * (X - cx) + (exy - rot) * (Y - cy),
                uy + (exy + rot) * (X - cx) + eyy * (Y - cy))

    return U


@pytest.mark.parametrize(("field", "proved"), [
    # a tenth of a period and more everywhere (the 1040 x 1376 pair's case, 11 px
    # moved, 0.24 to 0.76 period from no motion): proved without the measurement
    (_affine(8.0, -7.5, 2e-3, -3e-3, 5e-4), True),
    (_affine(1.5, 0.5), True),
    # a small step (0.03 period): the measurement is made, it is the one kept
    (_affine(0.2, -0.1), False),
    # a strain spreading the field over a period: small steps near the centre,
    # large ones at the edges
    (_affine(0.0, 0.0, 2e-2, -1e-2), None),
    # a rotation of 5 degrees about the centre
    (_affine(0.3, 0.0, rot=0.087), None),
])
@pytest.mark.parametrize("lagrangian", [True, False])
def test_a_step_is_said_large_only_where_the_measurement_finds_it_large(field, proved,
                                                                      lagrangian):
    ref, cur = _maps(field)
    beyond = _beyond_small_step(ref, cur, lagrangian)
    _, step = _first_step(ref, cur, lagrangian)
    if beyond:
        assert step > SMALL_STEP
    if not lagrangian:
        # without the correction the start is the measurement: the same answer
        assert beyond == (step > SMALL_STEP)
    elif proved is not None:
        assert beyond == proved


def test_no_valid_pixel_proves_nothing():
    ref, cur = _maps(_affine(1.5, 0.5))
    none = np.zeros(SHAPE, bool)
    cur = dataclasses.replace(cur, valid=none)
    assert not _beyond_small_step(ref, cur, True)


@pytest.mark.parametrize("compiled", [True, False])
def test_largest_step_is_the_largest_change_along_each_wave_vector(monkeypatch, compiled):
    """The step a state is followed by, against a direct loop over the pixels valid in
    both states: ``max |k_j . (u - field)|`` in periods; inf where no pixel is left or
    a change is not finite."""
    from gridstrain.kinematics import _deformation as kin
    from gridstrain.kinematics.tracking import _largest_step

    if compiled and kin._load_kernels() is None:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(kin, "_COMPILED", compiled)
    rng = np.random.default_rng(2)
    lattice = Lattice.from_pitch(5.0, angle=17.0)
    shape = (31, 43)
    u = rng.normal(0.0, 0.3, (2, *shape))
    field = rng.normal(0.0, 0.3, (2, *shape))
    valid = rng.random(shape) > 0.3
    before = rng.random(shape) > 0.2
    res = types.SimpleNamespace(u=u, valid=valid)  # what the step reads of a measurement
    want = 0.0
    for i in range(shape[0]):
        for j in range(shape[1]):
            if valid[i, j] and before[i, j]:
                for k in (lattice.k1, lattice.k2):
                    d = k[0] * (u[0, i, j] - field[0, i, j]) + k[1] * (u[1, i, j] - field[1, i, j])
                    want = max(want, abs(d))
    # periods: the products' rounding only (1e-15 of a period)
    assert _largest_step(res, field, lattice, before) == pytest.approx(want, abs=1e-14)
    assert _largest_step(res, field, lattice, np.zeros(shape, bool)) == np.inf
    bad = np.where(valid & before)
    field[0][bad[0][3], bad[1][3]] = np.nan
    assert _largest_step(res, field, lattice, before) == np.inf

