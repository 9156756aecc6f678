"""The first state's step from the reference, told above SMALL_STEP without being
measured (:func:`gridstrain.kinematics.tracking._beyond_small_step`): never said where
the measurement (:func:`_first_step`, the oracle) finds it small."""

from __future__ import annotations

import dataclasses

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
