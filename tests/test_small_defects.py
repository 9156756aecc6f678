"""Smaller defects of the phase and stack tools, each against a computation written
here.

- ``stacks.correct_phases``: both choices of ``about`` give the phases rotated back by
  the offset computed directly from the shifts, for a bare ``PhaseMaps`` and for a
  ``StackResult`` alike.
- the pair API (``gridstrain.measure``) without a mask: a hole's neighbourhood is left
  out as with a mask, and the strain that remains is the masked measurement's.
- a step of the grid's contrast (a stain's or a hole's edge), not moved: the error next
  to it, its leak into the carrier's band, within the per-pixel bound
  ``uncertainty.contrast_step_bound`` states; no finding on uniform grids.

Images come from ``independent_grid`` (numpy only; its assumptions are in its
docstring).
"""

from __future__ import annotations

import numpy as np
import pytest

from gridstrain import Lattice
from gridstrain.stacks import correct_phases, method_a
from gridstrain.uncertainty import contrast_step_bound
from independent_grid import camera, scene

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


# --------------------------------------------------------------------------- hole


def _plate_with_hole():
    """A plate under a uniform strain (eps_xx = 2e-3, eps_yy = -0.3 eps_xx about the
    centre) with a hole of radius 12.5 px showing the uniform dark background
    (``independent_grid.scene``: checkerboard of pitch 5, lighting falling to 40 %,
    noise-free), before and after; the true strain is the uniform one at every pixel
    of the plate. Returns both images, the hole in the reference and each pixel's
    distance to the hole's edge, px."""
    H, W = 128, 160
    eps = 2e-3

    def stretch(X, Y):
        return eps * (X - W / 2), -0.3 * eps * (Y - H / 2)

    ref, hole = scene((H, W), pitch=PITCH, angle=0.0, hole=True)
    cur, _ = scene((H, W), pitch=PITCH, angle=0.0, hole=True, displacement=stretch)
    yy, xx = np.mgrid[0:H, 0:W]
    edge = np.hypot(xx - 0.7 * W, yy - 0.35 * H) - 0.075 * H * 1.3
    return ref, cur, hole, edge, np.array([eps, -0.3 * eps, 0.0])


def test_an_unmasked_hole_is_as_good_as_a_masked_one():
    from gridstrain import measure

    ref, cur, hole, edge, want = _plate_with_hole()
    masked = measure(ref, cur, lattice=LAT, mask=~hole, guess=None)
    bare = measure(ref, cur, lattice=LAT, guess=None)
    sigma = bare.sigma
    near = (edge > 0) & (edge < 8 * sigma)  # the plate within 8 windows of the hole

    def worst(res):
        e = np.abs(res.strain - want[:, None, None])[:, res.valid & near]
        return float(e.max())

    # the margin of 4 sigmas keeps the cut window's bias near 4e-6 along a straight
    # edge (gridstrain.phase.window); along the hole's curved edge the masked
    # measurement's worst pixel reaches about 1.5e-5: 3e-5, below the 1e-4 of a
    # pixel 3 sigmas from an edge and far below the 1e-3 to 5e-3 of the windows
    # that straddled an unmasked hole
    assert worst(masked) < 3e-5
    assert worst(bare) < 3e-5
    # the band left out is counted from where the modulus collapses (below a quarter
    # of its median), about a sigma inside the hole's edge, rather than from the edge:
    # at least the masked measurement's valid pixels, and at most half as many again
    n_bare = np.count_nonzero(bare.valid & near)
    n_masked = np.count_nonzero(masked.valid & near)
    assert n_masked <= n_bare <= 1.5 * n_masked
    # no valid pixel whose window reaches into the hole: none within 2.5 sigmas of it
    # (the collapse ~1 sigma inside, then the margin of 4)
    assert not np.any(bare.valid & (edge < 2.5 * sigma))


# --------------------------------------------------------------------------- contrast step


def _contrast_step(drop, *, mean_drop=0.0, shape=(96, 128), x0=64.3, over=3):
    """A checkerboard of pitch 5 (tanh edges, as ``independent_grid``) whose contrast
    falls by ``drop`` beyond the column ``x0`` (and its mean level by ``mean_drop``: a
    stain darkens both), not moved; each pixel integrates ``over`` x ``over``
    sub-samples; no noise."""
    H, W = shape
    ys, xs = np.mgrid[0:H * over, 0:W * over].astype(np.float64)
    x, y = (xs + 0.5) / over - 0.5, (ys + 0.5) / over - 0.5
    side = x > x0
    c = 3.0
    m = np.tanh(c * np.sin(np.pi * (x + y) / PITCH)) * np.tanh(
        c * np.sin(np.pi * (x - y) / PITCH)) / np.tanh(c) ** 2
    v = 2000 * (1 - mean_drop * side) * (0.5 + 0.45 * (1 - drop * side) * m)
    return v.reshape(H, over, W, over).mean(axis=(1, 3))


def _hole_appearing():
    """A hole's edge that appears between the states (the specimen not moved): the
    reference a plain grid, the deformed image the same with a hole showing the dark
    background (``independent_grid.scene``, lighting falling to 40 %)."""
    ref, _ = scene((96, 128), pitch=PITCH, angle=0.0, hole=False)
    cur, _ = scene((96, 128), pitch=PITCH, angle=0.0, hole=True)
    return ref, cur


_STEPS = {
    "contrast 0.5": lambda: (_contrast_step(0.0), _contrast_step(0.5)),
    "contrast 0.9": lambda: (_contrast_step(0.0), _contrast_step(0.9)),
    "stain": lambda: (_contrast_step(0.0), _contrast_step(0.5, mean_drop=0.5)),
    "mean level": lambda: (_contrast_step(0.0), _contrast_step(0.0, mean_drop=0.5)),
    "hole edge": _hole_appearing,
}


def _bound(res):
    return contrast_step_bound(res.reference.psi, res.deformed.psi, res.u, res.valid,
                               sigma=res.sigma)


@pytest.mark.parametrize("case", sorted(_STEPS))
def test_a_contrast_step_bias_is_bounded_on_every_valid_pixel(case):
    """The step's spectrum, a 1/f tail, leaks the grid's conjugate, its harmonics
    and (for a stain) the mean level into the carrier's band: 0.012 to 0.20 px next
    to the step (0.0033 px of noise: a Poisson-Gaussian sensor of K = 0.5, L = 5),
    on valid pixels. Not moved, the truth is zero: the error is ``|u|``."""
    from gridstrain import measure

    ref, cur = _STEPS[case]()
    res = measure(ref, cur, lattice=LAT, guess=None)
    err = np.hypot(*res.u)[res.valid]
    bound = _bound(res)[res.valid]
    # the errors above a third of that noise std: below it a bias hides in the noise
    big = err > 1e-3
    assert err.max() > 0.01  # the case is one the bound must state
    assert np.mean(bound[big] >= err[big]) >= 0.95
    assert np.all(bound[big] >= 0.5 * err[big])
    # and it says no more than the leak: within 8 times the largest error (the
    # coefficient covers the mean level's step, 5 times a pure contrast step's)
    assert bound.max() <= 8 * err.max()


@pytest.mark.parametrize("hole", [False, True])
@pytest.mark.parametrize("angle", [0.0, 10.0])
@pytest.mark.parametrize("kind", ["checker", "lines"])
def test_uniform_grids_raise_no_contrast_step_finding(kind, angle, hole):
    """A uniform print under lighting falling to 40 %, stretched and moved (with a
    hole moving with it, or none), through a Poisson-Gaussian sensor: the bound made
    of the moduli's noise stays within the displacement's noise, and no pixel is
    stated beyond it."""
    from gridstrain import measure
    from gridstrain.uncertainty import contrast_step_findings

    def moved(X, Y):
        return 0.3 + 1e-3 * (X - 64), -0.2 + 0 * Y

    rng = np.random.default_rng(1)
    lat = Lattice.from_pitch(PITCH, angle=angle)
    ref = camera(scene((96, 128), pitch=PITCH, angle=angle, kind=kind, hole=hole)[0],
                 0.5, 5.0, rng).astype(float)
    cur = camera(scene((96, 128), pitch=PITCH, angle=angle, kind=kind, hole=hole,
                       displacement=moved)[0], 0.5, 5.0, rng).astype(float)
    res = measure(ref, cur, lattice=lat, guess=None)
    yy, xx = np.mgrid[0:96, 0:128].astype(np.float64)
    tx, ty = moved(xx, yy)
    err = res.u - np.stack([tx, ty])
    # the noise std of each component, measured against the truth
    std = {c: float(np.std(e[res.valid])) for c, e in zip(("ux", "uy"), err, strict=True)}
    noise = (std["ux"], std["uy"])
    assert contrast_step_findings(_bound(res), res.valid, noise=noise, name="s") == []
    # the measurement's own: the same bound, the same (no) finding
    np.testing.assert_array_equal(res.contrast_step_bound(), _bound(res))
    assert res.contrast_step_findings(noise=noise) == []


def test_a_stain_under_noise_is_stated_with_its_pixels_counted():
    """The stain of the test above through the same sensor: the finding names the
    state, counts the pixels whose bound exceeds twice the noise and gives the
    largest bound, at least the largest noise-free error (0.10 px)."""
    from gridstrain import measure
    from gridstrain.uncertainty import contrast_step_findings

    rng = np.random.default_rng(2)
    ref = camera(_contrast_step(0.0), 0.5, 5.0, rng).astype(float)
    cur = camera(_contrast_step(0.5, mean_drop=0.5), 0.5, 5.0, rng).astype(float)
    res = measure(ref, cur, lattice=LAT, guess=None)
    # the displacement noise std of this pair, measured on the same images
    noise = (0.0033 / np.sqrt(2), 0.0033 / np.sqrt(2))
    said = contrast_step_findings(_bound(res), res.valid, noise=noise, name="s1")
    assert [f.code for f in said] == ["contrast.step"]
    f = said[0]
    assert f.state == "s1"
    # the step's band: a few sigmas either side of it, rows all along
    assert 0 < f.figures["pixels"] < np.count_nonzero(res.valid)
    assert f.figures["max_px"] >= 0.10
    # the pair API states it as measure_series does: the same sentence and figures
    (own,) = res.contrast_step_findings(noise=noise, name="s1")
    assert own == f
    assert dict(own.figures) == dict(f.figures)


def test_the_contrast_step_takes_the_noise_in_the_forms_the_api_gives():
    """The noise as predict_uncertainty gives it (an Uncertainty, its u_std, its
    median()), as maps or as floors: the same finding as the floors it stands for;
    a form it cannot read is refused in one line naming the accepted ones."""
    from gridstrain import measure, predict_uncertainty
    from gridstrain.uncertainty import contrast_step_findings

    rng = np.random.default_rng(2)
    ref = camera(_contrast_step(0.0), 0.5, 5.0, rng).astype(float)
    cur = camera(_contrast_step(0.5, mean_drop=0.5), 0.5, 5.0, rng).astype(float)
    res = measure(ref, cur, lattice=LAT, guess=None)
    # the sensor's 5-grey-level read noise (its shot noise left out: a floor)
    unc = predict_uncertainty(res.reference, res.deformed, variance_ref=25.0,
                              variance_def=25.0)
    b = _bound(res)
    maps = contrast_step_findings(b, res.valid, noise={"ux_std": unc.u_std[0],
                                                       "uy_std": unc.u_std[1]})
    assert [f.code for f in maps] == ["contrast.step"]
    assert contrast_step_findings(b, res.valid, noise=unc) == maps
    assert contrast_step_findings(b, res.valid, noise=unc.u_std) == maps
    med = unc.median()
    floors = contrast_step_findings(b, res.valid, noise=(med["ux"], med["uy"]))
    assert contrast_step_findings(b, res.valid, noise=med) == floors
    assert res.contrast_step_findings(noise=unc, name="state") == maps
    for bad in ("loud", np.ones((3, 5, 5)), {"u": 1.0}):
        with pytest.raises(ValueError, match=r"noise must be|noise as a mapping"):
            contrast_step_findings(b, res.valid, noise=bad)


@pytest.mark.parametrize("case", ["contrast step", "uniform"])
def test_a_series_states_a_contrast_step_and_not_a_uniform_grid(case):
    """Through ``measure_series`` (images large enough for the noise to be estimated
    from each): a contrast drop of 0.8 appearing (0.036 px of bias against 0.0033 px
    of noise) gives one ``contrast.step`` finding; a uniform grid with a hole, moved
    and stretched, gives none."""
    from gridstrain import measure_series

    shape = (176, 176)
    rng = np.random.default_rng(2)
    if case == "contrast step":
        levels = (_contrast_step(0.0, shape=shape), _contrast_step(0.8, shape=shape))
    else:
        def moved(X, Y):
            return 0.3 + 1e-3 * (X - 88), -0.2 + 0 * Y

        levels = (scene(shape, pitch=PITCH, angle=0.0)[0],
                  scene(shape, pitch=PITCH, angle=0.0, displacement=moved)[0])
    ref, cur = (camera(v, 0.5, 5.0, rng).astype(float) for v in levels)
    res = measure_series(ref, cur, lattice=LAT, guess=None)
    said = [w for w in res.warnings if w.code == "contrast.step"]
    assert len(said) == (1 if case == "contrast step" else 0)
    if said:
        assert "noise std" in said[0]
        assert said[0].figures["max_px"] >= 0.036


def test_a_hole_moving_with_the_specimen_adds_no_bound():
    """A hole is seen at the same material point in both states, its bias with it,
    which cancels in ``u``: noise-free, moved by (0.3, -0.2) px and stretched by 1e-3,
    the bound beside the hole stays under 1e-3 px (a third of the noise std of this
    sensor), though the hole's collapsing modulus lies a few sigmas away."""
    from gridstrain import measure

    def moved(X, Y):
        return 0.3 + 1e-3 * (X - 64), -0.2 + 0 * Y

    ref, _ = scene((96, 128), pitch=PITCH, angle=0.0)
    cur, _ = scene((96, 128), pitch=PITCH, angle=0.0, displacement=moved)
    res = measure(ref, cur, lattice=LAT, guess=None)
    assert np.nanmax(_bound(res)) < 1e-3
