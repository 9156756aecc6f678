"""Smaller defects of the phase and stack tools, each against a computation written
here.

- ``stacks.correct_phases``: both choices of ``about`` give the phases rotated back by
  the offset computed directly from the shifts, for a bare ``PhaseMaps`` and for a
  ``StackResult`` alike.

Images come from ``independent_grid`` (numpy only; its assumptions are in its
docstring).
"""

from __future__ import annotations

import numpy as np
import pytest

from gridstrain import Lattice
from gridstrain.stacks import correct_phases, method_a
from independent_grid import scene

PITCH = 5.0
LAT = Lattice.from_pitch(PITCH)


def _offset(shifts, about):
    """The phase offset of each wave vector written from its definition: the frames'
    phase advances ``theta_tj = 2 pi k_j . a_t``; ``"origin"``: ``arg mean_t exp(i
    theta_tj)``; ``"mean"``: the same about their mean, ``theta_tj - mean_t theta_tj``."""
    theta = np.array([[2 * np.pi * (k[0] * a[0] + k[1] * a[1]) for k in LAT.K]
                      for a in shifts])
    if about == "mean":
        theta = theta - theta.mean(axis=0)
    return np.array([np.angle(np.sum(np.exp(1j * theta[:, j]))) for j in range(2)])


@pytest.mark.parametrize("about", ["origin", "mean"])
def test_correct_phases_follows_about_for_maps_and_stack_results(about):
    rng = np.random.default_rng(3)
    frames = np.stack([scene((64, 64), pitch=PITCH, angle=0.0, hole=False, seed=t)[0]
                       for t in range(3)])
    # shifts far from centred, so that the two choices differ by about 1 rad
    shifts = rng.normal(0.0, 0.3, (3, 2)) + np.array([0.8, -0.5])
    res = method_a(frames, LAT, sigma=PITCH)
    want = _offset(shifts, about)
    other = _offset(shifts, "mean" if about == "origin" else "origin")
    assert np.all(np.abs(np.angle(np.exp(1j * (want - other)))) > 0.3)
    for given in (res.maps, res):
        out = correct_phases(given, shifts, exact=True, about=about)
        psi = out.psi if hasattr(out, "psi") else out.maps.psi
        got = np.angle(psi * np.conj(res.maps.psi))[:, res.maps.valid]
        # the offset removed, psi exp(-i delta), a uniform rotation in float64: exact
        # to a few ulps of pi
        np.testing.assert_allclose(np.angle(np.exp(1j * (got + want[:, None]))), 0.0,
                                   atol=1e-12)
