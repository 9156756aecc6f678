"""The aliasing bound: the grid's harmonics folded onto the carriers, measured on the
reference image, against images written here (a direct sum of a fundamental and one
harmonic) and photographs of printed grids (``tests/world_camera.py``,
``tests/independent_grid.py``), whose measured errors it must bound."""

from __future__ import annotations

import math

import numpy as np
import pytest

from findings import said
from gridstrain import Lattice
from gridstrain.series import measure_series
from gridstrain.uncertainty import aliasing_bias
from independent_grid import camera, scene
from world_camera import Specimen, expected_levels, photograph, stretch

H, W = 200, 260
CENTRE = ((W - 1) / 2, (H - 1) / 2)
ANGLE = 0.6  # degrees: the folds of an integer pitch lie 0.0105 cycle/px off the carrier
STRETCH = (0.02, -0.006)


def _two_waves(pitch, a4, *, e=0.0):
    """A direct sum: crossed cosines of amplitude 0.4 and a 4th harmonic of amplitude
    ``a4`` of the first family (phase 0.7 rad), point-sampled, the material stretched
    by ``e`` along both axes about the frame's centre ``c`` (``X = c + (x - c) / (1 +
    e)``)."""
    t = np.deg2rad(ANGLE)
    k1 = np.array([np.cos(t), np.sin(t)]) / pitch
    k2 = np.array([-np.sin(t), np.cos(t)]) / pitch
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    x = CENTRE[0] + (x - CENTRE[0]) / (1 + e)
    y = CENTRE[1] + (y - CENTRE[1]) / (1 + e)
    p1 = 2 * np.pi * (k1[0] * x + k1[1] * y)
    p2 = 2 * np.pi * (k2[0] * x + k2[1] * y)
    img = 1000.0 * (1 + 0.4 * np.cos(p1) + 0.4 * np.cos(p2) + a4 * np.cos(4 * p1 + 0.7))
    return img, Lattice(tuple(k1), tuple(k2))


def test_a_single_folded_harmonic_is_measured_and_bounds_the_error():
    pitch, a4, sigma = 5.0, 0.012, 5.0
    ref, lat = _two_waves(pitch, a4)
    alias = aliasing_bias(ref, lat, sigma=sigma)
    rec = {(tuple(r["order"]), r["carrier"]): r for r in alias["harmonics"]}
    # 4 k1 folds to -k1: its conjugate (-4, 0) sits by +k1, at 0.0105 cycle/px
    r = rec[((-4, 0), 1)]
    assert r["measured"]
    # the complex amplitudes a4/2 and 0.4/2: a ratio a4/0.4; 2 % of it is the Hann
    # window's leak of the other terms (its sidelobes below 1e-3 of the fundamental)
    assert r["relative_amplitude"] == pytest.approx(a4 / 0.4, rel=0.02)
    # 5 k1 is (cos t, sin t) cycle/px: (-4, 0) folds at |5 k1 - (1, 0)| = 2 sin(t/2)
    # from k1, exactly (a geometric identity)
    assert r["fold_distance"] == pytest.approx(2 * np.sin(np.deg2rad(ANGLE) / 2), rel=1e-9)
    # nothing else is in the image: the other families' records are nil (4 % of the
    # harmonic: the leak again, through the envelopes x and y times each fold, whose
    # spectra are the Hann window's derivative's, wider than its own; measured 2.7 %)
    others = [x["relative_amplitude"] for k, x in rec.items() if k != ((-4, 0), 1)]
    assert max(others, default=0.0) < 0.04 * a4 / 0.4
    # the measured error: the pair stretched by 1.5 %, whose phases sweep the
    # harmonic's term, 5 times faster than the carrier's, through 2 periods from the
    # centre to the edges: the reference's and the deformed image's terms meet in
    # antiphase somewhere
    e = 0.015
    cur, _ = _two_waves(pitch, a4, e=e)
    res = measure_series(ref, cur, lattice=lat, sigma=sigma, guess=None,
                         noise_model=(1e-6, 1e-6))
    v = res.valid[0]
    x = np.mgrid[0:H, 0:W][1].astype(np.float64)
    # Lagrangian: the reference pixel X is seen at c + (X - c)(1 + e)
    err = np.abs(np.asarray(res.u[0][0]) - (x - CENTRE[0]) * e)[v]
    bound = alias["u_px_components"][0]
    # a bound, and not a vacuous one: twice one image's amplitude, times the margin
    # 1.25 for a print that varies (here it does not): the error reaches 0.8 of it
    assert err.max() <= bound
    assert err.max() >= 0.6 * bound
    # the direct sum: the term's phase amplitude through the window's transfer,
    # both images, displacement p / 2 pi per rad
    G = math.exp(-2 * math.pi**2 * sigma**2 * r["fold_distance"] ** 2)
    direct = 2 * (a4 / 0.4) * G * pitch / (2 * math.pi)
    # 5 %: the fit's 2 % and the lattice's turn (K^-1 mixes in 1 % of carrier 2)
    assert err.max() == pytest.approx(direct, rel=0.05)


def test_a_folded_harmonic_is_measured_through_a_masks_window():
    """A hole masked in the image: the window (Hann times the mask, eroded and
    softened) is no product of two profiles, and the fit goes through its low-rank
    sum of separable terms; the harmonic's amplitude is the direct sum's still."""
    pitch, a4, sigma = 5.0, 0.012, 5.0
    ref, lat = _two_waves(pitch, a4)
    yy, xx = np.mgrid[0:H, 0:W]
    mask = (yy - 90) ** 2 + (xx - 150) ** 2 > 30**2
    alias = aliasing_bias(ref, lat, sigma=sigma, mask=mask)
    rec = {(tuple(r["order"]), r["carrier"]): r for r in alias["harmonics"]}
    r = rec[((-4, 0), 1)]
    assert r["measured"]
    # 2 %: the Hann window's leak of the other terms, as without a mask (the hole's
    # soft edge adds its own, under that)
    assert r["relative_amplitude"] == pytest.approx(a4 / 0.4, rel=0.02)


def _lines(pitch, width, noise, seed=1, angle=ANGLE):
    spec = Specimen((H, W), pitch=pitch, angle=angle, seed=seed)
    spec.h1 = spec.h1 * width / 0.35  # the print's lines, their fraction of the pitch
    spec.h2 = spec.h2 * width / 0.35
    disp = stretch(*STRETCH, CENTRE)
    if noise:
        rng = np.random.default_rng(seed + 100)
        return photograph(spec, rng=rng), photograph(spec, disp, rng=rng), disp
    return expected_levels(spec), expected_levels(spec, disp), disp


def _errors(res, disp):
    v = np.asarray(res.valid[0])
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    truth = np.stack(disp(xx, yy))
    err = np.stack([np.asarray(res.u[0][k]) for k in (0, 1)]) - truth
    return err[:, v], v


@pytest.mark.slow
@pytest.mark.parametrize("pitch", [4.0, 5.0, 6.0, 7.0])
@pytest.mark.parametrize("width", [0.2, 0.35, 0.5])
def test_the_bound_holds_for_printed_lines(pitch, width, record_property):
    """Noise-free photographs: the error is the aliasing (and the window's bias of a
    homogeneous stretch, nil); the bound per component must hold at every pixel."""
    ref, cur, disp = _lines(pitch, width, noise=False)
    res = measure_series(ref, cur, guess=None, noise_model=(1e-6, 1e-6))
    err, _ = _errors(res, disp)
    bound = np.array(res.systematic["aliasing"]["u_px_components"])
    worst = np.abs(err).max(axis=1)
    record_property("max_err_px", worst.tolist())
    record_property("bound_px", bound.tolist())
    assert np.all(worst <= bound), (worst, bound)
    # the strain: the homogeneous stretch's (e_xx, e_yy, e_xy) known exactly
    alias = res.systematic["aliasing"]
    v = np.asarray(res.valid[0])
    e = np.asarray(res.strain[0])
    e_err = np.abs(np.stack([e[0] - STRETCH[0], e[1] - STRETCH[1], e[2]]))[:, v].max()
    e_bound = alias["strain_per_strain"] * max(map(abs, STRETCH)) + alias["strain_ripple"]
    record_property("max_strain_err", float(e_err))
    record_property("strain_bound", e_bound)
    assert e_err <= e_bound, (e_err, e_bound)


def test_harmonics_on_the_carrier_take_a_sharp_prints_bound():
    """Lines along the pixel axes at pitch 5: the 4th and 6th harmonics fold exactly
    onto the carriers, where one image cannot tell them from the grid."""
    ref, cur, disp = _lines(5.0, 0.35, noise=False, angle=0.0)
    res = measure_series(ref, cur, guess=None, noise_model=(1e-6, 1e-6))
    err, _ = _errors(res, disp)
    alias = res.systematic["aliasing"]
    assert not alias["observable"]
    assert not any(r["measured"] for r in alias["harmonics"])
    # measured 0.022 px; the sharp print's bound, 0.14 px, holds
    assert np.all(np.abs(err).max(axis=1) <= np.array(alias["u_px_components"]))
    bound = said(res.warnings, "aliasing.bound")
    assert bound
    assert "cannot be seen in one image" in bound[0]


@pytest.mark.slow
@pytest.mark.parametrize(("pitch", "width"), [(5.0, 0.2), (5.0, 0.35), (7.0, 0.5)])
def test_noisy_photographs_are_within_noise_plus_bound_and_warned(pitch, width):
    ref, cur, disp = _lines(pitch, width, noise=True)
    res = measure_series(ref.astype(float), cur.astype(float), guess=None)
    err, v = _errors(res, disp)
    std = np.stack([np.asarray(res.uncertainty[c][0])[v] for c in ("ux_std", "uy_std")])
    alias = res.systematic["aliasing"]
    bound = np.array(alias["u_px_components"])[:, None]
    # 5 std is exceeded by 6e-7 of Gaussian noise; 2 % as the acceptance tests allow
    # for the window's bias where lighting and print vary
    assert np.mean(np.any(np.abs(err) > 5 * std + bound, axis=0)) <= 0.02
    warned = said(res.warnings, "aliasing.bound")
    if alias["u_px"] > 2 * float(np.median(std)):
        assert warned
        assert "px" in warned[0]
        assert "sigma" in warned[0]
    else:
        assert not warned


def test_a_sine_grid_states_a_small_bound_and_no_warning():
    lvl, _ = scene((H, W), pitch=5.0, angle=ANGLE, kind="sine", hole=False)
    rng = np.random.default_rng(3)
    ref = camera(lvl, 0.28, 5.0, rng).astype(float)
    cur = camera(scene((H, W), pitch=5.0, angle=ANGLE, kind="sine", hole=False,
                       displacement=lambda X, Y: (0.3 + 0 * X, 0 * Y))[0],
                 0.28, 5.0, rng).astype(float)
    res = measure_series(ref, cur, guess=None)
    std = float(np.nanmedian(np.asarray(res.uncertainty["ux_std"][0])[res.valid[0]]))
    # a sine has no harmonics: what is fitted at their folds is the noise's and the
    # lighting's, below twice the displacement noise, the level that is warned of
    assert res.systematic["aliasing"]["u_px"] < 2 * std
    assert not said(res.warnings, "aliasing.bound")
