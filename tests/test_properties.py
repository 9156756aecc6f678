"""Invariants of the measurement chain, with hypothesis."""

import math

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy import ndimage

from gridstrain import Lattice, measure
from gridstrain.models import synthetic

_settings = settings(max_examples=8, deadline=None,
                     suppress_health_check=[HealthCheck.too_slow])

# from 5 px: at 4 px the third harmonic of the sin^3 profile (3/4 cycle/px) aliases
# exactly onto the conjugate fundamental (-1/4), a sampling limit, not a method one
pitches = st.floats(min_value=5.0, max_value=7.0)
angles = st.floats(min_value=-40.0, max_value=40.0)


def _defects(a, b):
    # smooth manufacturing defects of the grid (phase modulations of eq. 1), rad
    return lambda X, Y: (a * np.sin(2 * np.pi * Y / 70), b * np.cos(2 * np.pi * X / 90))


@_settings
@given(pitch=pitches, angle=angles, a=st.floats(-0.5, 0.5), b=st.floats(-0.5, 0.5))
def test_zero_deformation_gives_zero_strain(pitch, angle, a, b):
    lat = Lattice.from_pitch(pitch, angle=angle)
    img = synthetic.grid_image((128, 128), lat, phases=_defects(a, b))
    res = measure(img, img, lattice=lat, guess=None)
    v = res.valid
    # identical images: exactly zero up to float rounding (1e-12 is ~1e4 ulps of 1)
    assert np.max(np.abs(res.u[:, v])) < 1e-12
    assert np.max(np.abs(res.strain[:, v])) < 1e-12


@_settings
@given(pitch=pitches, angle=angles, ux=st.floats(-1.5, 1.5), uy=st.floats(-1.5, 1.5),
       a=st.floats(-0.5, 0.5))
# edge strains found: 2.03e-5 by hypothesis at its first valid column; 2.8e-5 where
# 4 sigma falls just below a whole pixel, the first valid pixels one nearer the border
@example(pitch=5.96875, angle=39.0, ux=1.5, uy=0.0, a=0.5)
@example(pitch=5.499, angle=-40.0, ux=-1.5, uy=1.5, a=-0.5)
def test_rigid_translation_gives_constant_displacement(pitch, angle, ux, uy, a):
    lat = Lattice.from_pitch(pitch, angle=angle)
    kw = {"phases": _defects(a, -a)}
    ref = synthetic.grid_image((128, 128), lat, **kw)
    cur = synthetic.grid_image((128, 128), lat, displacement=lambda X, Y: (ux + 0 * X, uy + 0 * Y),
                               **kw)
    res = measure(ref, cur, lattice=lat, guess=(ux, uy))
    v = res.valid
    # 1e-4 px: the bound for rigid motions. The first valid pixels' windows reach 3.8 to 4
    # sigma to the image's border (valid from 4 sigma beyond the last pixel outside):
    # the truncated Gaussian misses erfc(3.8 / sqrt 2) / 2 = 7e-5 of its weight, through
    # which the print's harmonics (the sin^3 profile) and the defects' phase enter
    # unattenuated, and differently in two images shifted against each other: up to
    # 6.1e-5 px there over some 5,000 corners and random draws of these ranges
    np.testing.assert_allclose(res.ux[v], ux, atol=1e-4)
    np.testing.assert_allclose(res.uy[v], uy, atol=1e-4)
    # the strain of a rigid motion is zero but for that truncation: measured up to
    # 2.8e-5 at the first valid pixels (the examples above), about twice that allowed.
    # A sigma further in the missing weight is a hundredth; what remains there is the
    # interpolation's and the coupling correction's error on the defects' phase (3.7e-7
    # still at 2 and 3 sigma inside, pitch 7, 40 degrees, a = 0.5): up to 7.5e-7 found
    # on the same draws, 2e-6 allowed
    assert np.max(np.abs(res.strain[:, v])) < 6e-5
    inner = ndimage.binary_erosion(v, iterations=math.ceil(res.sigma))
    assert inner.sum() > 0.4 * v.sum()  # the interior holds most of the valid pixels
    assert np.max(np.abs(res.strain[:, inner])) < 2e-6


@_settings
@given(top=st.integers(0, 30), left=st.integers(0, 30))
def test_results_do_not_depend_on_the_crop(top, left):
    lat = Lattice.from_pitch(5.0, angle=8.0)
    field = lambda X, Y: (0.4 + 1e-3 * X, -0.2 + 5e-4 * Y + 1e-3 * X)  # noqa: E731
    ref = synthetic.grid_image((160, 160), lat, phases=_defects(0.3, 0.2))
    cur = synthetic.grid_image((160, 160), lat, phases=_defects(0.3, 0.2), displacement=field)
    # "away from the border": 5 sigma, where the cut window's bias is ~6e-8 rad
    whole = measure(ref, cur, lattice=lat, guess=None, margin=5.0)
    crop = (slice(top, top + 120), slice(left, left + 120))
    part = measure(ref[crop], cur[crop], lattice=lat, guess=None, margin=5.0)
    v = part.valid & whole.valid[crop]
    assert v.sum() > 1000
    # what may change: the edge bias at 5 sigma (~6e-8 rad) and the window's DC
    # leakage, since the crop changes the image mean (~1e-8 rad): 1e-6 px / strain
    np.testing.assert_allclose(part.u[:, v], whole.u[:, crop[0], crop[1]][:, v], atol=1e-6)
    np.testing.assert_allclose(part.strain[:, v], whole.strain[:, crop[0], crop[1]][:, v],
                               atol=1e-6)
