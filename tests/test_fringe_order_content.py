"""The fringe order from what the images hold below the grid's frequency.

Broad stains and a wood-like grain move with the specimen but hold nothing as sharp
as a pitch: the correlation at the pitch sees only the grid's residue, as good a whole
period away. Compared at whole-period offsets of the phases' field, once the grid is
low-passed away, they give the order, and no period is lost; but a stain darkens the
grid as a lamp's hot spot lights it, and neither changes the grid's contrast: a light
that moved by the same whole periods would say the same, so the order is used, not
confirmed. A grid with nothing else, or content fixed to the camera, must leave it
unconfirmed too. The images come from ``independent_grid`` (numpy
only, not :mod:`gridstrain.models.synthetic`); the lighting is fixed to the camera (a broad
Gaussian falling to about 40 %) and the sensor is Poisson-Gaussian.
"""

from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pytest
import tifffile

from findings import said
from gridstrain import Lattice, wft
from gridstrain.cli import main
from gridstrain.kinematics import deformation
from gridstrain.kinematics._fringe_order import strain_if_off
from gridstrain.series import measure_series
from independent_grid import camera, grain, scene, stains

SHAPE = (192, 256)
PITCH = 5.0
CENTRE = ((SHAPE[1] - 1) / 2, (SHAPE[0] - 1) / 2)
# two whole periods and more: the smallest displacement the phases allow is wrong
SHIFT = (11 * math.cos(0.5), -11 * math.sin(0.5))


def _field(shift, exx=1e-3, eyy=-5e-4):
    def U(X, Y):
        return shift[0] + exx * (X - CENTRE[0]), shift[1] + eyy * (Y - CENTRE[1])

    return U


def _pair(reflectance, *, angle, shift=SHIFT, seed=0, texture=0.0):
    """Reference and deformed camera images (float grey levels) and the field."""
    U = _field(shift)
    kw = {"pitch": PITCH, "angle": angle, "hole": False, "reflectance": reflectance,
          "texture": texture}
    rng = np.random.default_rng(seed)
    ref = camera(scene(SHAPE, **kw)[0], 1.0, 4.0, rng) / 16.0
    cur = camera(scene(SHAPE, displacement=U, **kw)[0], 1.0, 4.0, rng) / 16.0
    return ref, cur, U


def _errors(u, valid, U):
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(float)
    d = u[:, valid] - np.array(U(xx, yy))[:, valid]
    return float(np.max(np.abs(d))), float(np.sqrt(np.mean(d * d)))


def test_broad_stains_give_the_order_through_the_cli(tmp_path, capsys):
    """Two stains of 25 and 17 px std, the specimen moved by 11 px: the content below
    the grid's frequency gives the order, and no period is lost; not confirmed, since
    two hot spots of a lamp moved by 11 px would look the same."""
    ref, cur, U = _pair(stains(SHAPE), angle=12.0)
    for name, img in (("ref", ref), ("def", cur)):
        tifffile.imwrite(tmp_path / f"{name}.tif", np.rint(img).astype(np.uint16))
    out = tmp_path / "out.h5"
    rc = main(["measure", str(tmp_path / "ref.tif"), str(tmp_path / "def.tif"), "-o",
               str(out), "--json", "--quiet"])
    assert rc in (0, None)
    order = json.loads(capsys.readouterr().out)["states"][0]["fringe_order"]
    assert order["source"] == "image features"
    assert order["confirmed"] is False
    assert "could be the light" in order["detail"]
    # the correlation at the pitch could not decide: the content below it did
    assert order["peak_to_alias"] < 1.5
    assert order["residual_ratio"] >= 1.5
    assert order["tiles_agreeing"] == order["tiles_informative"] >= 1
    with h5py.File(out, "r") as h5:
        v = h5["valid"][0]
        u = np.array([h5["ux"][0], h5["uy"][0]])
    worst, rms = _errors(u, v, U)
    # px: a whole period off would be 5 px; the noise of one 12-bit frame leaves a few
    # hundredths
    assert worst < 0.5
    assert rms < 0.05


@pytest.mark.parametrize("grain_angle", [90.0, 0.0])
def test_wood_grain_along_a_lattice_period_gives_the_order(grain_angle):
    """A grain 40 px long and 3 px across, along one of the grid's periods: a whole
    period along the grain correlates almost as well at the pitch. The content below
    the grid's frequency gives the order; the grain multiplies the grid as light
    does, and leaves its contrast as it is: not confirmed."""
    ref, cur, U = _pair(grain(1, angle=grain_angle), angle=0.0, shift=(0.8, 11.25))
    res = measure_series(ref, cur)
    order = res.fringe_orders[0]
    assert not order.confirmed
    assert "could be the light" in order.detail
    assert order.source == "image features"
    assert order.residual_ratio >= 1.5
    worst, rms = _errors(res.u[0], res.valid[0], U)
    assert worst < 0.5  # px: a period is 5 px
    assert rms < 0.05


@pytest.mark.parametrize("case", ["strain 5 %", "turned 5 degrees"])
def test_content_gives_the_order_under_large_strain_and_rotation(case):
    """Under a homogeneous strain of 5 % or a rotation of 5 degrees the phases' field
    at the camera's point differs from that at the material point by up to a pixel
    (the gradient times the 11-px displacement): the comparison reads it at the
    material point, or a grain 3 px wide would not match at any whole period."""
    t = math.radians(5.0)

    def U(X, Y):
        x, y = X - CENTRE[0], Y - CENTRE[1]
        if case == "strain 5 %":
            return SHIFT[0] + 0.05 * x, SHIFT[1] + 0 * y
        return (SHIFT[0] + (math.cos(t) - 1) * x - math.sin(t) * y,
                SHIFT[1] + math.sin(t) * x + (math.cos(t) - 1) * y)

    kw = {"pitch": PITCH, "angle": 12.0, "hole": False, "reflectance": grain(1)}
    rng = np.random.default_rng(0)
    ref = camera(scene(SHAPE, **kw)[0], 1.0, 4.0, rng) / 16.0
    cur = camera(scene(SHAPE, displacement=U, **kw)[0], 1.0, 4.0, rng) / 16.0
    res = measure_series(ref, cur)
    order = res.fringe_orders[0]
    assert not order.confirmed  # a grain: as light would (the test above)
    assert order.source == "image features"
    worst, rms = _errors(res.u[0], res.valid[0], U)
    assert worst < 0.5  # px: a period is 5 px
    assert rms < 0.05


@pytest.mark.parametrize(("kind", "texture"), [("featureless", 0.0),
                                               ("texture fixed to the camera", 0.15)])
def test_nothing_that_moves_with_the_specimen_leaves_the_order_unconfirmed(kind, texture):
    """A grid with nothing else (the lighting fixed to the camera), or a print texture
    fixed to the camera (dust, a stained lens): not confirmed, and the state says by
    how much its strain may be off too."""
    ref, cur, _ = _pair(None, angle=12.0, texture=texture, shift=(7.4, 2.0))
    res = measure_series(ref, cur)
    order = res.fringe_orders[0]
    assert not order.confirmed
    assert order.source == "smallest displacement"
    # the ratio of residuals of a grid with nothing else: 1.00 to 1.11 measured
    if kind == "featureless":
        assert order.residual_ratio < 1.5
    # a homogeneous strain has no gradient: what is left is the difference of the
    # strain maps' own errors a period apart, which are correlated over the window
    # (about a pitch): at most twice those errors (95th percentiles both)
    v = res.valid[0]
    e = res.strain[0]
    err = np.abs(np.stack([e[0][v] - 1e-3, e[1][v] + 5e-4, e[2][v]])).max(axis=0)
    assert 0 < order.strain_if_off < 2 * np.percentile(err, 95)
    (doubt,) = said(res.warnings, "fringe_order.unconfirmed")
    assert "strain may be off too" in doubt


def test_strain_if_off_is_the_strain_a_period_away():
    """With the large-displacement correction, a displacement one period off reads the
    deformed phases a period away: under ``u_x = c (X - X0)^2 / 2`` (``e_xx = c (X -
    X0)``) the strain moves by ``c p`` along the period ``(p, 0)``, and by nothing
    along ``(0, p)``: what :func:`strain_if_off` predicts from the strain maps."""
    c = 4e-5  # 1/px: e_xx from -5e-3 to 5e-3 across the image

    def U(X, Y):
        return 3.0 + 0.5 * c * (X - CENTRE[0]) ** 2, -1.0 + 0 * Y

    kw = {"pitch": PITCH, "angle": 0.0, "hole": False, "light": False}
    ref, _ = scene(SHAPE, **kw)
    cur, _ = scene(SHAPE, displacement=U, **kw)
    lat = Lattice.from_pitch(PITCH)
    rm, cm = wft(ref, lat), wft(cur, lat)
    right = deformation(rm, cm, guess=(3.0, -1.0))
    period = lat.periods[:, int(np.argmax(np.abs(lat.periods[0])))]  # along x
    off = deformation(rm, cm, guess=(3.0 + period[0], -1.0 + period[1]))
    v = right.valid & off.valid
    # px: the order taken is the one asked, a period away
    assert np.median(off.u[0][v] - right.u[0][v]) == pytest.approx(period[0], abs=1e-3)
    change = np.median(off.strain[0][v] - right.strain[0][v])
    # the first-order change: the strain gradient times the period
    assert change == pytest.approx(c * period[0], rel=0.05)
    # the 95th percentile of the largest change over both periods and components:
    # c p everywhere (the window's bias of a linear strain field is nil)
    assert strain_if_off(right) == pytest.approx(c * PITCH, rel=0.05)
    # without the correction the strain does not depend on the order
    assert strain_if_off(deformation(rm, cm, guess=(3.0, -1.0), lagrangian=False)) == 0.0


def test_a_record_on_a_bare_grid_compares_its_content_only_now_and_then(monkeypatch):
    """A record whose reference holds nothing but the grid: its content decides nothing,
    so after three states it is compared only every ninth; the maps and every state's
    verdict are those of comparing it at every state."""
    from gridstrain.kinematics import _fringe_order
    from sequence_record import record

    frames = record(13, (96, 128), strain=2e-3)
    calls = []
    real = _fringe_order._CoarseReference.content

    def counted(self, *args, **kwargs):
        c = real(self, *args, **kwargs)
        calls.append(c.tiles_informative)
        return c

    monkeypatch.setattr(_fringe_order._CoarseReference, "content", counted)
    gated = measure_series(frames[0], list(frames[1:]))
    gated_calls = list(calls)
    monkeypatch.setattr(_fringe_order, "_FUTILE", 10**9)
    calls.clear()
    every = measure_series(frames[0], list(frames[1:]))
    assert not any(calls)  # nothing informative, state after state
    # states 4 to 11 not compared: three decided nothing, then eight skipped
    assert len(gated_calls) == len(calls) - 8
    np.testing.assert_array_equal(np.asarray(gated.u), np.asarray(every.u))
    np.testing.assert_array_equal(np.asarray(gated.valid), np.asarray(every.valid))
    assert [r.confirmed for r in gated.fringe_orders] == \
        [r.confirmed for r in every.fringe_orders]
    assert [r.source for r in gated.fringe_orders] == [r.source for r in every.fringe_orders]


@pytest.mark.parametrize(("shape", "s", "q"), [((104, 137), 6.0, 6), ((97, 64), 5.3, 5),
                                               ((50, 81), 3.0, 1), ((33, 40), 2.2, 3)])
def test_the_low_pass_summed_at_the_samples_kept_is_the_filter_bit_for_bit(shape, s, q):
    # the same kernel and order of summation as scipy's symmetric correlation, only at
    # the samples kept: the same bits, not merely close ones
    from scipy import ndimage

    from gridstrain.kinematics._grid_free import smooth_decimate

    a = np.random.default_rng(3).random(shape) * 4000.0
    full = ndimage.gaussian_filter1d(a, s, axis=0, mode="constant", truncate=4.0)[::q]
    full = ndimage.gaussian_filter1d(full, s, axis=1, mode="constant", truncate=4.0)[:, ::q]
    assert np.array_equal(smooth_decimate(a, s, q), full)


def test_the_window_weights_from_two_profiles_are_the_whole_frame_filtered():
    # separable: the product of the two profiles is the 2-D filter of a frame of ones
    # to within rounding (a few 1e-16 relative)
    from scipy import ndimage

    from gridstrain.kinematics._fringe_order import _window_weights
    from gridstrain.kinematics._grid_free import smooth_decimate

    shape, sigma, pitch, q = (130, 171), 5.0, 6.0, 6
    w = ndimage.gaussian_filter(np.ones(shape), sigma, mode="constant", truncate=4.0)
    np.testing.assert_allclose(_window_weights(shape, sigma, pitch, q),
                               smooth_decimate(w, pitch, q), rtol=1e-14, atol=0)


def test_the_content_memo_gives_back_only_what_the_same_object_made():
    # a state's features and its check after the warp compare the same objects: made
    # once; another object (a later state's image, equal or not) is made again, and a
    # freed object is neither kept alive nor taken for one at its address
    import gc
    import weakref

    from gridstrain.kinematics._fringe_order import _Contents

    calls = []

    def make(a, k):
        calls.append(k)
        return a.sum() * k

    memo = _Contents()
    ref, cur = np.ones((4, 4)), np.full((4, 4), 2.0)
    for _ in range(2):
        assert memo(make, ref, 3) == 48.0
        assert memo(make, cur, 3) == 96.0
    assert calls == [3, 3]
    assert memo(make, cur, 4) == 128.0  # other arguments: made again
    assert memo(make, cur.copy(), 4) == 128.0  # an equal copy is another object
    assert calls == [3, 3, 4, 4]
    gone = weakref.ref(cur)
    del cur
    gc.collect()
    assert gone() is None
