"""The evidence behind a fringe order: "confirmed" must mean right.

Families of cases that imitate evidence, each against its truth:

- a steep continuous gradient of an intact grid (not a crack), and a torn grid (a crack);
- light that moves on its own: a lamp's hot spot moving through a load series, a
  specular highlight moved by a lattice vector between a pair;
- false alarms: an ordinary tensile test on a plain grid, followed by small steps; a
  true pair whose images hold nothing but the grid, which the pair check must not
  refuse.

Images from ``tests/lab_light.py`` (a printed grid under a lab's light: a moving hot
spot, a specular highlight) and, for the crack, ``tests/world_camera.py`` (whose
camera sees the crack's dark inside); neither shares code with gridstrain.
"""

from __future__ import annotations

import numpy as np
import pytest

from findings import said
from gridstrain.kinematics import measure, pair_match
from gridstrain.series import measure_series
from lab_light import photograph, spots
from world_camera import Specimen, edge_crack, strain_bump
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
    assert not said(res.warnings, "jump.found", "jump.part"), res.warnings
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
    assert said(res.warnings, "jump.found")
    # px: the pixels left are right (noise 3e-3 px; a side a period off is 6.4 px)
    assert np.abs(_errors(res, 0, disp)).max() < 0.05


# ------------------------------------------------------------ light that moves on its own


def _tensile(k, shape):
    """State ``k`` of an ordinary tensile test: 1e-3 strain a state about the centre,
    Poisson's ratio 0.3, a drift of 0.02 px a state (under 1 px in all)."""
    H, W = shape
    e = 1e-3 * k

    def u(X, Y):
        return e * (X - W / 2) + 0.02 * k, -0.3 * e * (Y - H / 2)

    return u


def _verdicts(res, truths, pitch):
    """Per state: (wrong, confirmed); wrong is an error beyond a quarter period (a
    state whole periods off is a pitch off; the noise is 1e-2 px)."""
    out = []
    for i, disp in enumerate(truths):
        err = _errors(res, i, disp)
        out.append((bool(np.abs(err).max() > pitch / 4), res.fringe_orders[i].confirmed))
    return out


@pytest.mark.parametrize(("pitch", "hot_sd", "printed"), [(5.0, 6.0, False),
                                                          (5.0, 10.0, False),
                                                          (5.0, 8.0, True)])
def test_a_hot_spot_moving_through_a_load_series_confirms_nothing_wrong(pitch, hot_sd,
                                                                        printed):
    # the lamp's hot spot moves (-15, +5) px a state, three periods and one at pitch 5:
    # in the image (and in the grid's modulus, which it multiplies) it imitates the
    # specimen moving by whole periods; the specimen moves by less than a pixel
    shape = (160, 192)
    rng = np.random.default_rng(0)
    D = spots(shape, 3) if printed else None
    at = np.array([110.0, 70.0])
    ref = photograph(shape, pitch, defects=D, hot=0.8, hot_at=at, hot_sd=hot_sd,
                     noise=rng, full=1800)
    truths = [_tensile(k, shape) for k in (1, 2, 3)]
    states = [photograph(shape, pitch, f, defects=D, hot=0.8, hot_sd=hot_sd, noise=rng,
                         hot_at=at + k * np.array([-15.0, 5.0]), full=1800)
              for k, f in zip((1, 2, 3), truths, strict=True)]
    res = measure_series(ref, states, outliers="warn")
    verdicts = _verdicts(res, truths, pitch)
    assert not any(w and c for w, c in verdicts), verdicts  # never wrong and confirmed
    assert not any(w for w, _ in verdicts), verdicts  # the small steps followed: right
    if printed:
        # printed defects attached to the specimen agree with the small steps
        assert all(c for _, c in verdicts), [r.detail for r in res.fringe_orders]
    elif not res.fringe_orders[0].confirmed:
        # the image features followed the light: the state says which evidence said
        # what, keeps the followed displacement, and the later states inherit the doubt
        told = [m for m in said(res.warnings, "fringe_order.unconfirmed")
                if m.state == res.names[1] and "disagree by whole periods" in m]
        assert told, res.warnings
        assert "light that moved" in told[0]
        assert "followed displacement is kept" in told[0]
        assert not any(r.confirmed for r in res.fringe_orders[1:])
    else:
        # the features, not shown by the grid's modulus, did not decide: followed
        assert res.fringe_orders[0].detail.startswith("followed from the reference")


@pytest.mark.parametrize(("pitch", "glare_sd", "move", "u0"), [
    (6.4, 6.0, (2, -1), (0.9, -0.3)),
    (6.4, 4.0, (-2, 1), (0.9, 0.4)),
    (5.0, 5.0, (3, 0), (0.8, 0.3)),
])
def test_a_highlight_moved_by_a_lattice_vector_is_not_the_specimen(pitch, glare_sd, move,
                                                                   u0):
    # a pair: the specimen moves by about a pixel (more than the 0.1 period a first
    # step is followed within), the highlight by a lattice vector plus that pixel
    shape = (160, 192)
    rng = np.random.default_rng(0)
    at = np.array([100.0, 75.0])

    def disp(X, Y):
        return u0[0] + 1e-3 * (X - 96), u0[1] - 3e-4 * (Y - 80)

    ref = photograph(shape, pitch, glare=0.6, glare_at=at, glare_sd=glare_sd, noise=rng,
                     full=1800)
    cur = photograph(shape, pitch, disp, glare=0.6, glare_sd=glare_sd, noise=rng,
                     full=1800, glare_at=at + pitch * np.array(move) + np.array(u0))
    res = measure_series(ref, cur, outliers="warn")
    ((wrong, confirmed),) = _verdicts(res, [disp], pitch)
    assert not (wrong and confirmed)
    assert not wrong  # the phases' smallest displacement is kept: right
    # no correction stated as a fact; the record says which evidence said what
    assert not said(res.warnings, "fringe_order.corrected"), res.warnings
    assert "the grid's own modulus does not show them" in res.fringe_orders[0].detail


def _lamp_pair(pitch, shape, u0, *, hot_sd, hot_move, printed, seed, hot=0.8):
    """A pair under a lamp whose hot spot (std ``hot_sd`` px, +``hot`` of the light)
    moved by ``hot_move`` px while the specimen moved by ``u0`` px and strained."""
    rng = np.random.default_rng(seed)
    at = np.array([100.0, 75.0])
    D = spots(shape, seed + 5) if printed else None

    def disp(X, Y):
        return u0[0] + 1e-3 * (X - 96), u0[1] - 3e-4 * (Y - 80)

    ref = photograph(shape, pitch, defects=D, hot=hot, hot_at=at, hot_sd=hot_sd, noise=rng,
                     full=1800)
    cur = photograph(shape, pitch, disp, defects=D, hot=hot, hot_sd=hot_sd, noise=rng,
                     full=1800, hot_at=at + np.asarray(hot_move, dtype=float))
    return ref, cur, disp


@pytest.mark.parametrize(("pitch", "hot_sd", "move", "plus_u", "printed"), [
    (5.0, 4.0, (1, 0), False, False), (5.0, 4.0, (1, 1), True, True),
    (5.0, 6.0, (0, 1), False, False), (5.0, 10.0, (1, 0), False, False),
    (5.0, 16.0, (1, 1), True, True), (5.0, 25.0, (0, 1), False, False),
    (6.4, 4.0, (1, 0), False, False), (6.4, 6.0, (1, 0), True, True),
    (6.4, 10.0, (-1, 0), True, False), (6.4, 25.0, (1, 1), False, True),
])
def test_a_hot_spot_moved_by_a_lattice_vector_is_never_confirmed(pitch, hot_sd, move,
                                                                 plus_u, printed):
    # a pair: the specimen moves by about a pixel (0.8, 0.3) px, more than the 0.1
    # period a first state is followed within; the lamp's hot spot (std 4 to 25 px,
    # +80 % of the light) by a lattice vector, or a lattice vector plus that pixel. It
    # multiplies the grid as a stain would: the image features and the grid's modulus
    # follow it; the ratio of the grid's harmonics cannot
    shape = (160, 192)
    u0 = (0.8, 0.3)
    hot_move = pitch * np.array(move, dtype=float) + (np.array(u0) if plus_u else 0.0)
    ref, cur, disp = _lamp_pair(pitch, shape, u0, hot_sd=hot_sd, hot_move=hot_move,
                                printed=printed, seed=int(10 * hot_sd + pitch))
    res = measure_series(ref, cur, outliers="warn")
    ((wrong, confirmed),) = _verdicts(res, [disp], pitch)
    record = res.fringe_orders[0]
    assert not (wrong and confirmed), record.detail
    if wrong:
        # the state says why: the content that moved could be the light
        assert "could be the light" in record.detail or "light that moved" in record.detail
        assert [m for m in said(res.warnings, "fringe_order.unconfirmed")
                if m.state == res.names[1]]


@pytest.mark.parametrize(("hot_sd", "move", "plus_u", "printed"), [
    (4.0, (1, 0), False, False), (6.0, (0, 1), False, False), (10.0, (1, 0), False, False),
    (4.0, (1, 1), True, True)])
def test_the_pair_api_never_confirms_a_hot_spot_moved_by_a_lattice_vector(hot_sd, move,
                                                                          plus_u, printed):
    # the same pairs through gridstrain.measure (no series, no check after the warp):
    # the image features and the grid's modulus follow the hot spot, and only the ratio
    # of the grid's harmonics could confirm them (the first three were wrong and
    # confirmed when the pair's record took the features' order as confirmed)
    pitch, shape, u0 = 5.0, (160, 192), (0.8, 0.3)
    hot_move = pitch * np.array(move, dtype=float) + (np.array(u0) if plus_u else 0.0)
    ref, cur, disp = _lamp_pair(pitch, shape, u0, hot_sd=hot_sd, hot_move=hot_move,
                                printed=printed, seed=int(10 * hot_sd + pitch))
    res = measure(ref, cur)
    H, W = shape
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    err = (np.asarray(res.u) - np.stack(disp(xx, yy)))[:, res.valid]
    wrong = bool(np.abs(err).max() > pitch / 4)  # as _verdicts: a period off is a pitch
    record = res.fringe_order
    assert not (wrong and record.confirmed), record.detail
    if wrong:
        assert "could be the light" in record.detail, record.detail
        # how far its strain may be off is said with it
        assert record.strain_if_off >= 0, record


@pytest.mark.parametrize(("pitch", "hot_sd", "glare_sd", "move"), [
    (5.0, 10.0, 6.0, (1, 0)), (5.0, 16.0, 5.0, (0, 1)), (5.0, 6.0, 6.0, (1, 0)),
    (6.4, 25.0, 4.0, (-1, 0))])
def test_a_lamp_and_its_highlight_moved_together_are_never_confirmed(pitch, hot_sd,
                                                                     glare_sd, move):
    # the lamp's hot spot (multiplying the grid: the modulus follows it) and its
    # specular highlight (adding to the image: the grid's contrast follows it) moved
    # together by a lattice vector plus the specimen's (0.8, 0.3) px: only what no
    # light changes, the ratio of the grid's harmonics, may confirm whole periods
    shape = (160, 192)
    rng = np.random.default_rng(int(hot_sd))
    u0 = np.array([0.8, 0.3])

    def disp(X, Y):
        return u0[0] + 1e-3 * (X - 96), u0[1] - 3e-4 * (Y - 80)

    at = np.array([100.0, 75.0])
    mv = pitch * np.array(move, dtype=float) + u0
    light = {"hot": 0.8, "hot_sd": hot_sd, "glare": 0.6, "glare_sd": glare_sd,
             "full": 1500}
    ref = photograph(shape, pitch, hot_at=at, glare_at=at, noise=rng, **light)
    cur = photograph(shape, pitch, disp, hot_at=at + mv, glare_at=at + mv, noise=rng,
                     **light)
    res = measure_series(ref, cur, outliers="warn")
    ((wrong, confirmed),) = _verdicts(res, [disp], pitch)
    assert not (wrong and confirmed), res.fringe_orders[0].detail


@pytest.mark.parametrize(("pitch", "move", "hot"), [
    (5.0, (1, 0), 0.0), (5.0, (0, -1), 0.0), (6.4, (2, 0), 0.0), (5.0, (1, 1), 0.2)])
def test_a_printed_specimen_moved_by_whole_periods_is_confirmed(pitch, move, hot):
    # the specimen itself moves by whole periods plus (0.8, 0.3) px, its printed spots
    # (1 to 2.5 px, sharper than any lamp's light) with it, the lamp still
    shape = (160, 192)
    u0 = pitch * np.array(move, dtype=float) + np.array([0.8, 0.3])
    ref, cur, disp = _lamp_pair(pitch, shape, u0, hot_sd=16.0, hot_move=(0.0, 0.0),
                                printed=True, seed=50 + int(pitch), hot=hot)
    res = measure_series(ref, cur, outliers="warn")
    assert _verdicts(res, [disp], pitch) == [(False, True)], res.fringe_orders[0].detail
    assert res.fringe_orders[0].source == "image features"


# ------------------------------------------------------------------------ false alarms


@pytest.mark.parametrize("pitch", [5.0, 6.4])
def test_an_ordinary_tensile_test_is_confirmed_by_following(pitch):
    # a plain grid (nothing but the grid moves with the specimen), six states of 1e-3
    # strain and 0.02 px of drift each: steps of 0.01 to 0.02 period, 0.7 px at most
    shape = (128, 192)
    rng = np.random.default_rng(11)
    ref = photograph(shape, pitch, noise=rng, full=2000)
    truths = [_tensile(k, shape) for k in range(1, 7)]
    states = [photograph(shape, pitch, f, noise=rng, full=2000) for f in truths]
    res = measure_series(ref, states)
    verdicts = _verdicts(res, truths, pitch)
    assert not any(w for w, _ in verdicts), verdicts
    records = res.fringe_orders
    assert all(r.confirmed for r in records), [r.detail for r in records]
    assert all(r.source == "previous state" for r in records)
    # the reason is stated: the first state from the reference, each later one from
    # the state before, with the step followed (0.02 period at most)
    assert records[0].detail.startswith("followed from the reference")
    assert all(r.detail.startswith(f"followed from {n}")
               for r, n in zip(records[1:], res.names[1:-1], strict=True))
    assert all(r.step < 0.05 for r in records)
    # no flag on an ordinary state: no doubt on the order, none on the strain
    assert not said(res.warnings, "fringe_order.unconfirmed", "fringe_order.inherited"), \
        res.warnings


def test_a_first_state_a_third_of_a_period_away_is_not_confirmed_by_following():
    # a first step of 0.34 period (a pair moved 3.3 px at pitch 5, seen as -1.7 px) may
    # be a step of 0.66 period: following from the reference confirms steps of 0.1
    # period at most
    shape = (128, 160)
    rng = np.random.default_rng(2)

    def disp(X, Y):
        return 3.3 + 0 * X, -1.0 + 0 * Y

    ref = photograph(shape, 5.0, noise=rng, full=2000)
    res = measure_series(ref, photograph(shape, 5.0, disp, noise=rng, full=2000))
    assert res.fringe_orders[0].source == "smallest displacement"
    assert not res.fringe_orders[0].confirmed


@pytest.mark.parametrize(("pitch", "amplitude", "angle"), [(7.0, 0.05, 0.5), (5.0, 0.1, 0.0)])
def test_a_true_pair_without_texture_is_inconclusive_not_refused(pitch, amplitude, angle):
    # a nearly noise-free grid (0.01 grey level std, stated as such) carrying a smooth
    # strain bump (2 pitches std), nothing printed or lying on it: what is left below
    # the grid's frequency is the grid's own moire with the pixels (1e-4 of the light),
    # which the strain changes; it is no evidence of another specimen
    H, W = 192, 192
    rng = np.random.default_rng(0)
    disp, _ = strain_bump(amplitude, 2 * pitch, (W / 2, H / 2))
    ref = photograph((H, W), pitch, angle=angle, full=2000)
    cur = photograph((H, W), pitch, disp, angle=angle, full=2000)
    ref = ref + rng.normal(0.0, 0.01, ref.shape)
    cur = cur + rng.normal(0.0, 0.01, cur.shape)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    valid = np.zeros((H, W), dtype=bool)
    valid[25:-25, 25:-25] = True
    m = pair_match(ref, cur, np.stack(disp(xx, yy)), valid, pitch=pitch,
                   noise=(1e-4, 1e-4))
    assert m.verdict == "inconclusive", m
    assert not m.conclusive


def test_another_specimen_without_noise_is_still_refused():
    # the same grid, each specimen with its own print defects (dark spots of 1 to 2.5
    # px, 40 %): content of a percent, evidence of another specimen
    H, W = 192, 192
    rng = np.random.default_rng(0)
    disp, _ = strain_bump(0.05, 14.0, (W / 2, H / 2))
    ref = photograph((H, W), 7.0, defects=spots((H, W), 1), full=2000)
    cur = photograph((H, W), 7.0, disp, defects=spots((H, W), 2), full=2000)
    ref = ref + rng.normal(0.0, 0.01, ref.shape)
    cur = cur + rng.normal(0.0, 0.01, cur.shape)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    valid = np.zeros((H, W), dtype=bool)
    valid[25:-25, 25:-25] = True
    m = pair_match(ref, cur, np.stack(disp(xx, yy)), valid, pitch=7.0, noise=(1e-4, 1e-4))
    assert m.conclusive
    assert m.verdict in ("mismatch", "nothing matches"), m
