"""The fringe order: never a whole period wrong without a flag.

The phases give the displacement modulo the lattice periods. These tests check that
a load-step series is followed (each state's order from the previous state), that the
image-feature estimate is trusted only when it clearly beats its aliases and agrees
with the phases, and that every state says how its order was fixed.

The images come from the generator below, written here with numpy alone (not
:mod:`gridstrain.models.synthetic`), so that the package is tested against an independent
model of a camera looking at a specimen.
"""

from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pytest
import tifffile

from findings import said
from gridstrain import Lattice, coarse_displacement, wft
from gridstrain.cli import main
from gridstrain.kinematics import _fringe_order as kinematics
from gridstrain.kinematics._fringe_order import _phase_shift
from gridstrain.results import load, save_result
from gridstrain.series import measure_series, state_names

# --------------------------------------------------------------------------- generator


def render(shape, pitch, u_fn=None, *, angle=0.0, kind="grid", vignette=0.4,
           defects=None, oversample=3, amplitude=2000.0, contrast=0.8, sharp=2.0):
    """Camera image of a specimen carrying a periodic pattern (numpy only).

    Assumptions: the pattern ``s(X)`` is defined on the specimen in the reference
    configuration ``X``; the deformed image at camera point ``x`` shows ``s(X)``
    with ``x = X + u(X)`` (Lagrangian ``u``, solved by fixed point, converging for
    ``|grad u| << 1``); each pixel integrates its area (``oversample^2`` points);
    the lighting is fixed to the camera (a radial vignette losing ``vignette`` of
    the light in the corners) and multiplies the grey level; ``defects(X, Y)``
    (printed spots) multiply the pattern and move with the specimen.

    ``kind="grid"``: two crossed sinusoids of period ``pitch`` turned by ``angle``
    degrees. ``kind="checkerboard"``: a checkerboard of square side
    ``pitch / sqrt 2``, whose fundamental wave vectors (of period ``pitch``) run
    along the squares' diagonals, at ``angle + 45`` degrees; its edges are
    softened by the lens (``tanh(sharp sin)``; ``sharp=2`` leaves the third
    harmonic at 0.17 of the fundamental, a square wave at 0.33).
    """
    H, W = shape
    out = np.zeros(shape)
    offs = (np.arange(oversample) + 0.5) / oversample - 0.5
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    for oy in offs:
        for ox in offs:
            x, y = xx + ox, yy + oy
            X, Y = x, y
            if u_fn is not None:
                for _ in range(8):  # contraction |grad u| <= 0.01 per iteration
                    ux, uy = u_fn(X, Y)
                    X, Y = x - ux, y - uy
            Xr, Yr = c * X + s * Y, -s * X + c * Y
            if kind == "grid":
                pat = 1 + 0.5 * contrast * (np.cos(2 * np.pi * Xr / pitch)
                                            + np.cos(2 * np.pi * Yr / pitch))
            else:
                # squares with edges softened by the lens (tanh of a sine: a
                # rounded square wave whose harmonics fall off fast)
                q = pitch / math.sqrt(2)
                pat = 1 + contrast * (np.tanh(sharp * np.sin(np.pi * Xr / q))
                                      * np.tanh(sharp * np.sin(np.pi * Yr / q)))
            if defects is not None:
                pat = pat * defects(X, Y)
            out += pat
    out /= oversample**2
    r2 = ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / ((H / 2) ** 2 + (W / 2) ** 2)
    return amplitude * out * (1 - vignette * r2)


def spots(rng, shape, n=60, depth=0.35, radius=(1.0, 2.5)):
    """Random dark printed spots, ``(X, Y) -> factor``, attached to the specimen."""
    H, W = shape
    cx, cy = rng.uniform(-20, W + 20, n), rng.uniform(-20, H + 20, n)
    rr = rng.uniform(*radius, n)

    def R(X, Y):
        out = np.ones_like(X)
        for a, b, r in zip(cx, cy, rr, strict=True):
            out = out - depth * np.exp(-((X - a) ** 2 + (Y - b) ** 2) / (2 * r * r))
        return np.clip(out, 0.2, None)

    return R


def rigid(ux, uy):
    return lambda X, Y: (ux + 0 * X, uy + 0 * Y)


def _run(argv, capsys):
    """``main(argv)`` -> (return code, stdout, stderr)."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:
        rc = exc.code
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _write(path, img):
    path.parent.mkdir(parents=True, exist_ok=True)
    # rounded to integers as a 16-bit camera file holds them (the noise this adds,
    # 0.29 grey level, is 1e-4 of the grid's modulus)
    tifffile.imwrite(path, np.rint(img).astype(np.uint16), photometric="minisblack")


# --------------------------------------------------------------------------- a load-step series

N_STEPS = 10
STEP = 1.3  # px of grip motion per load step
DIRECTION = (math.cos(math.radians(25)), math.sin(math.radians(25)))


def _coupon_field(i, centre):
    """Load step ``i`` (0-based): translation 1.3 (i + 1) px, strain up to 1 %."""
    t = STEP * (i + 1)
    exx, eyy = 1e-3 * (i + 1), -3e-4 * (i + 1)

    def U(X, Y):
        return (t * DIRECTION[0] + exx * (X - centre), t * DIRECTION[1] + eyy * (Y - centre))

    return U, (exx, eyy)


def _coupon_series(tmp_path, n, pitch, kind, angle):
    ref = render((n, n), pitch, kind=kind, angle=angle)
    _write(tmp_path / "ref" / "f.tif", ref)
    truths = []
    for i in range(N_STEPS):
        U, e = _coupon_field(i, (n - 1) / 2)
        _write(tmp_path / f"load{i + 1:02d}" / "f.tif", render((n, n), pitch, U, kind=kind,
                                                                angle=angle))
        truths.append((U, e))
    states = [tmp_path / f"load{i + 1:02d}" for i in range(N_STEPS)]
    return tmp_path / "ref", states, truths


def _check_series(h5path, truths, n):
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    with h5py.File(h5path, "r") as h5:
        ux, uy = h5["ux"][...], h5["uy"][...]
        exx, eyy, exy = h5["exx"][...], h5["eyy"][...], h5["exy"][...]
        valid = h5["valid"][...]
    errors = []
    for i, (U, (e_xx, e_yy)) in enumerate(truths):
        v = valid[i]
        assert v.mean() > 0.2, f"state {i}: {v.mean():.1%} valid"
        tx, ty = U(xx, yy)
        du = max(float(np.max(np.abs(ux[i][v] - tx[v]))), float(np.max(np.abs(uy[i][v] - ty[v]))))
        de = max(float(np.max(np.abs(exx[i][v] - e_xx))), float(np.max(np.abs(eyy[i][v] - e_yy))),
                 float(np.max(np.abs(exy[i][v]))))
        errors.append((du, de))
    return errors


@pytest.mark.parametrize(("kind", "pitch", "angle", "n"), [
    ("grid", 5.0, 0.0, 128),
    ("checkerboard", 6.0, 20.0, 144),
])
def test_featureless_load_series_is_followed_through_the_cli(tmp_path, capsys, kind, pitch,
                                                             angle, n):
    """Ten load steps of 1.3 px (13 px in all, 2 to 3 periods) and up to 1 % strain,
    no feature but the grid, lighting fixed to the camera: every state right."""
    ref, states, truths = _coupon_series(tmp_path, n, pitch, kind, angle)
    out = tmp_path / "out.h5"
    rc, stdout, err = _run(["measure", ref, *states, "-o", out, "--json", "--quiet"], capsys)
    assert rc == 0, err
    summary = json.loads(stdout)
    names = [s["name"] for s in summary["states"]]
    assert names == [f"load{i + 1:02d}" for i in range(N_STEPS)]  # the folders' names
    for errs in _check_series(out, truths, n):
        # px: the bound; a whole period off would be >= 5 px
        assert errs[0] < 0.05, errs
        # strain: the bound; measured ~1e-5 (the vignette's amplitude gradient
        # and the integer rounding of the files)
        assert errs[1] < 1e-4, errs
    orders = [s["fringe_order"] for s in summary["states"]]
    # the first step (1.3 px, a quarter period) has nothing to confirm it: the
    # smallest displacement, flagged; the others follow it
    assert orders[0]["source"] == "smallest displacement"
    assert not orders[0]["confirmed"]
    assert all(o["source"] == "previous state" for o in orders[1:])
    # tracked states inherit the first state's lack of confirmation, never more
    assert not any(o["confirmed"] for o in orders)
    # the increments: 1.3 px plus 0.1 % strain over the map, in periods
    for o in orders[1:]:
        assert o["step_periods"] < 0.4
    assert any("load01" in w for w in said(summary, "fringe_order.unconfirmed"))
    # and the later states' inherited doubt is said once, naming them
    (inherited,) = said(summary, "fringe_order.inherited")
    assert f"load02 to load{N_STEPS:02d}" in inherited
    with h5py.File(out, "r") as h5:
        assert [str(x) for x in h5.attrs["fringe_order_source"]] == \
            [o["source"] for o in orders]


def test_series_with_a_guess_for_the_first_state_is_confirmed(tmp_path):
    n, pitch = 128, 5.0
    ref = render((n, n), pitch)
    truths = [_coupon_field(i, (n - 1) / 2) for i in range(4)]
    states = [render((n, n), pitch, U) for U, _ in truths]
    U0 = truths[0][0]
    res = measure_series(ref, states, lattice=Lattice.from_pitch(pitch),
                         guess=U0((n - 1) / 2, (n - 1) / 2))
    assert [r.source for r in res.fringe_orders] == ["user"] + ["previous state"] * 3
    assert all(r.confirmed for r in res.fringe_orders)
    # the records survive the result file
    back = load(save_result(res, tmp_path / "r.h5"))
    assert [r.as_dict() for r in back.fringe_orders] == [r.as_dict() for r in res.fringe_orders]
    assert [m.fringe_order.as_dict() for m in back.measurements] == \
        [r.as_dict() for r in res.fringe_orders]
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    for i, (U, _) in enumerate(truths):
        v = res.valid[i]
        # px: as in the series test
        assert np.max(np.abs(res.u[i][:, v] - np.array(U(xx, yy))[:, v])) < 0.05


def test_independent_order_measures_each_state_on_its_own(tmp_path):
    """Today's behaviour for unordered states: 6.5 px is more than half a period,
    and without features nothing can tell; it must be flagged, not followed."""
    n, pitch = 128, 5.0
    ref = render((n, n), pitch)
    states = [render((n, n), pitch, _coupon_field(i, (n - 1) / 2)[0]) for i in (0, 4)]
    lat = Lattice.from_pitch(pitch)
    series = measure_series(ref, states, lattice=lat)
    indep = measure_series(ref, states, lattice=lat, order="independent")
    assert series.fringe_orders[1].source == "previous state"
    # the step from 1.3 to 6.5 px is a whole period and more: measured within half a
    # period of the previous field it is taken as -1.3 px ... and flagged
    assert not series.fringe_orders[1].confirmed
    assert series.fringe_orders[1].step > 0.4
    assert indep.parameters["order"] == "independent"
    assert [r.source for r in indep.fringe_orders] == ["smallest displacement"] * 2
    assert not any(r.confirmed for r in indep.fringe_orders)
    assert len(said(indep.warnings, "fringe_order.unconfirmed")) == 2


def test_a_step_of_nearly_half_a_period_is_flagged():
    n, pitch = 128, 5.0
    lat = Lattice.from_pitch(pitch)
    ref = render((n, n), pitch)
    # steps 1.0 px then 2.3 px (0.46 period): the second is followed, not confirmed
    states = [render((n, n), pitch, rigid(1.0, 0.0)), render((n, n), pitch, rigid(3.3, 0.0))]
    res = measure_series(ref, states, lattice=lat, guess=[(1.0, 0.0), "auto"])
    first, second = res.fringe_orders
    assert first.source == "user"
    assert first.confirmed
    assert second.source == "previous state"
    assert not second.confirmed
    assert 0.4 < second.step < 0.5  # periods: the 2.3-px step, measured
    assert any(w.state == res.names[2] and "changed by up to" in w
               for w in said(res.warnings, "fringe_order.unconfirmed"))


def test_printed_features_take_over_when_a_step_exceeds_half_a_period():
    """Grips moving 3 px a step at pitch 4.1 (0.73 period): followed step by step the
    displacement would lose a period each time; the printed spots fix every state."""
    n, pitch = 128, 4.1
    R = spots(np.random.default_rng(5), (n, n))
    ref = render((n, n), pitch, defects=R)
    shifts = [(3.0 * k, 0.0) for k in (1, 2, 3)]
    states = [render((n, n), pitch, rigid(*t), defects=R) for t in shifts]
    res = measure_series(ref, states, lattice=Lattice.from_pitch(pitch))
    assert [r.source for r in res.fringe_orders] == ["image features"] * 3
    assert all(r.confirmed for r in res.fringe_orders)
    for i, t in enumerate(shifts):
        v = res.valid[i]
        # px: noise-free rigid motions; a lost period would be 4.1 px
        assert np.max(np.abs(res.u[i][:, v] - np.array(t)[:, None])) < 0.05
    assert len(said(res.warnings, "fringe_order.features_used")) == 2


# --------------------------------------------------------------------------- pairs


def test_featureless_pair_moved_more_than_half_a_period_is_never_confirmed(tmp_path, capsys):
    n, pitch = 128, 5.0
    _write(tmp_path / "ref.tif", render((n, n), pitch))
    _write(tmp_path / "moved" / "f.tif", render((n, n), pitch, rigid(3.3, -1.0)))
    out = tmp_path / "out.h5"
    rc, stdout, err = _run(["measure", tmp_path / "ref.tif", tmp_path / "moved", "-o", out,
                            "--json", "--quiet"], capsys)
    assert rc == 0, err
    summary = json.loads(stdout)
    order = summary["states"][0]["fringe_order"]
    assert order["source"] == "smallest displacement"
    assert order["confirmed"] is False
    # the image features (the vignette is fixed to the camera) cannot choose
    assert order["peak_to_alias"] is None or order["peak_to_alias"] < 1.5
    warning = [w for w, f in zip(summary["warnings"], summary["findings"], strict=True)
               if f["code"] == "fringe_order.unconfirmed" and f["state"] == "moved"]
    assert warning
    assert "--guess" in warning[0]
    assert "intermediate image" in warning[0]
    # the text report says it too
    rc, stdout, _ = _run(["measure", tmp_path / "ref.tif", tmp_path / "moved", "-o", out,
                          "--overwrite"], capsys)
    assert rc == 0
    assert "NOT CONFIRMED" in stdout


def test_printed_features_fix_an_eleven_pixel_displacement(tmp_path, capsys):
    n, pitch = 128, 4.1
    rng = np.random.default_rng(11)
    R = spots(rng, (n, n))
    shift = (11 * math.cos(math.radians(30)), 11 * math.sin(math.radians(30)))
    _write(tmp_path / "ref.tif", render((n, n), pitch, defects=R))
    _write(tmp_path / "def.tif", render((n, n), pitch, rigid(*shift), defects=R))
    out = tmp_path / "out.h5"
    rc, stdout, err = _run(["measure", tmp_path / "ref.tif", tmp_path / "def.tif", "-o", out,
                            "--json", "--quiet"], capsys)
    assert rc == 0, err
    order = json.loads(stdout)["states"][0]["fringe_order"]
    assert order["source"] == "image features"
    assert order["confirmed"] is True
    assert order["peak_to_alias"] >= 1.5
    with h5py.File(out, "r") as h5:
        v = h5["valid"][0]
        u = np.array([h5["ux"][0][v], h5["uy"][0][v]])
        assert list(h5.attrs["fringe_order_confirmed"]) == [True]
    # px: the bound (the spots modulate the grid, but move with it)
    assert np.max(np.abs(u - np.array(shift)[:, None])) < 0.05


def _sinusoidal_field(c):
    # the core tests' noise-free field: |u| up to 2 px, below half the 5-px pitch
    def U(X, Y):
        return (0.8 + 1e-3 * (X - c) + 0.3 * np.sin(2 * np.pi * Y / 128),
                -1.7 - 5e-4 * (Y - c) + 0.2 * np.cos(2 * np.pi * X / 160))
    return U


def test_displacement_below_half_a_period_is_right_through_the_cli_defaults(tmp_path,
                                                                           capsys):
    n, pitch = 128, 5.0
    U = _sinusoidal_field((n - 1) / 2)
    _write(tmp_path / "ref.tif", render((n, n), pitch, vignette=0.0))
    _write(tmp_path / "def.tif", render((n, n), pitch, U, vignette=0.0))
    out = tmp_path / "out.h5"
    rc, _, err = _run(["measure", tmp_path / "ref.tif", tmp_path / "def.tif", "-o", out,
                       "--quiet"], capsys)
    assert rc == 0, err
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    truth = np.array(U(xx, yy))
    with h5py.File(out, "r") as h5:
        v = h5["valid"][0]
        u = np.array([h5["ux"][0], h5["uy"][0]])
    # px: the window attenuates the 128-px sinusoid by exp(-2 pi^2 25 / 128^2) = 0.97,
    # 0.01 px of its 0.3-px amplitude; a wrong period would be 5 px
    assert np.max(np.abs(u[:, v] - truth[:, v])) < 0.05


def test_aliasing_caught_features_periodic_with_twice_the_pitch():
    """Every second line printed darker: the features repeat every two periods, so
    the correlation cannot tell 11.2 px from 1.2 or 21.2; the best candidate may be
    a period pair off, and the estimate must not be trusted."""
    n, pitch = 160, 5.0
    lat = Lattice.from_pitch(pitch)

    def every_second_line(X, Y):
        return 1 + 0.15 * np.cos(2 * np.pi * X / (2 * pitch))

    ref = render((n, n), pitch, defects=every_second_line)
    cur = render((n, n), pitch, rigid(11.2, 0.7), defects=every_second_line)
    ps = _phase_shift(wft(ref, lat), wft(cur, lat))
    est = coarse_displacement(ref, cur, lat, phase_shift=ps)
    assert not est.confident
    assert est.peak_to_alias < 1.5
    res = measure_series(ref, cur, lattice=lat)
    assert not res.fringe_orders[0].confirmed
    assert res.fringe_orders[0].source == "smallest displacement"


def test_lens_dust_fixed_to_the_camera_disagrees_with_the_phases():
    """Sharp spots on the lens (fixed to the camera) correlate best at zero shift;
    the specimen moved by 7.4 px, 0.48 period from every multiple of the pitch:
    the correlation peak is far from every displacement the phases allow."""
    n, pitch = 160, 5.0
    lat = Lattice.from_pitch(pitch)
    dust = spots(np.random.default_rng(3), (n, n), depth=0.5)
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    ref = render((n, n), pitch) * dust(xx, yy)
    cur = render((n, n), pitch, rigid(7.4, 0.0)) * dust(xx, yy)
    ps = _phase_shift(wft(ref, lat), wft(cur, lat))
    est = coarse_displacement(ref, cur, lat, phase_shift=ps)
    # the best candidate is the one nearest the dust's peak: a whole period off
    assert abs(est.shift[0] - 7.4) == pytest.approx(5.0, abs=0.05)
    assert not est.confident
    assert est.disagreement > 0.25


def _lines(pitch):
    return lambda X, Y: 1 + 0.15 * np.cos(2 * np.pi * X / (2 * pitch))


def _dust_on_lens(n):
    dust = spots(np.random.default_rng(3), (n, n), n=400, depth=0.5)
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    return dust(xx, yy)


@pytest.mark.parametrize("n", [128, 576])
@pytest.mark.parametrize(("case", "shift", "confident"), [
    ("spots", (11.2, -3.1), True),
    ("featureless", (11.2, -3.1), False),
    ("every second line", (11.2, 0.7), False),
    ("lens dust", (7.4, 0.0), False),
])
def test_decimated_estimate_keeps_the_verdicts_of_full_resolution(monkeypatch, case, shift,
                                                                   confident, n):
    """Images of n px are correlated decimated by 2 (pitch 5): the band-pass keeps
    nothing above 0.8 / pitch, below the new Nyquist frequency, so the verdict and
    its figures must be those of the full-resolution correlation, the trust
    thresholds (0.5, 1.5, a quarter period) keeping their meaning; from the smallest
    image decimated (64 samples a side) to large ones."""
    pitch = 5.0
    lat = Lattice.from_pitch(pitch)
    assert kinematics._decimation((n, n), lat) == 2  # the decimated path is tested
    defects = {"spots": spots(np.random.default_rng(2), (n, n), n=300),
               "every second line": _lines(pitch)}.get(case)
    ref = render((n, n), pitch, defects=defects, oversample=1)
    cur = render((n, n), pitch, rigid(*shift), defects=defects, oversample=1)
    if case == "lens dust":
        dust = _dust_on_lens(n)
        ref, cur = ref * dust, cur * dust
    ps = _phase_shift(wft(ref, lat), wft(cur, lat))
    est = coarse_displacement(ref, cur, lat, phase_shift=ps)
    monkeypatch.setattr(kinematics, "_decimation", lambda shape, lattice: 1)
    full = coarse_displacement(ref, cur, lat, phase_shift=ps)
    assert est.confident == full.confident == confident, (est.reason, full.reason)
    if confident:
        # px: the candidates are the phases' shift plus whole periods (5 px apart)
        assert est.shift == pytest.approx(shift, abs=0.05)
        # period: the decimated peak, parabolic on 2-px samples, is good to 0.2 px
        assert est.disagreement < 0.05
        # the features' correlation, read by cubic splines between 2-px samples of
        # a peak some 3 px wide: within a few hundredths of the 0.5 threshold's scale
        assert est.correlation == pytest.approx(full.correlation, abs=0.05)
    # the ratio the 1.5 threshold judges (1.00 to 1.06 without features, 3.7 with)
    assert est.peak_to_alias == pytest.approx(full.peak_to_alias, rel=0.1)
    if case == "lens dust":  # the dust's peak at zero shift, 0.48 period off
        assert est.disagreement > 0.25


# --------------------------------------------------------------------------- names, options


def test_one_guess_per_state_through_the_cli(tmp_path, capsys):
    n, pitch = 96, 5.0
    _write(tmp_path / "ref.tif", render((n, n), pitch, vignette=0.0))
    _write(tmp_path / "a.tif", render((n, n), pitch, rigid(6.0, 0.0), vignette=0.0))
    _write(tmp_path / "b.tif", render((n, n), pitch, rigid(0.0, -7.0), vignette=0.0))
    rc, out, err = _run(["measure", tmp_path / "ref.tif", tmp_path / "a.tif", tmp_path / "b.tif",
                         "-o", tmp_path / "o.h5", "--json", "--quiet", "--order",
                         "independent", "--guess", "6", "0", "--guess", "0", "-7"], capsys)
    assert rc == 0, err
    states = json.loads(out)["states"]
    assert [s["fringe_order"]["source"] for s in states] == ["user", "user"]
    # px: noise-free rigid motions, measured to the interpolation error
    assert states[0]["mean"]["ux"] == pytest.approx(6.0, abs=1e-3)
    assert states[1]["mean"]["uy"] == pytest.approx(-7.0, abs=1e-3)


def test_states_are_named_after_their_folders_and_files(tmp_path):
    (tmp_path / "a" / "load").mkdir(parents=True)
    (tmp_path / "b" / "load").mkdir(parents=True)
    names = state_names([tmp_path / "a" / "load", tmp_path / "b" / "load",
                         tmp_path / "s3.tif", str(tmp_path / "run7" / "*.tif"),
                         np.zeros((8, 8)), tmp_path / "reference.tif"])
    assert names == ["load", "load (2)", "s3", "run7", "state 4", "reference (2)"]


def test_unquoted_glob_gets_a_warning(tmp_path, capsys):
    n, pitch = 64, 5.0
    _write(tmp_path / "f0.tif", render((n, n), pitch, vignette=0.0))
    for k in (1, 2):
        _write(tmp_path / f"f{k}.tif", render((n, n), pitch, rigid(0.1 * k, 0), vignette=0.0))
    # what the shell makes of   gridstrain measure run/*.tif -o out.h5
    rc, stdout, err = _run(["measure", *(tmp_path / f"f{k}.tif" for k in range(3)), "-o",
                            tmp_path / "out.h5", "--json", "--quiet"], capsys)
    assert rc == 0, err
    summary = json.loads(stdout)
    assert [s["name"] for s in summary["states"]] == ["f1", "f2"]
    assert any("quote it" in w for w in said(summary, "input"))
    # one image per state, named for what they are, is a layout of its own: no warning
    for old, new in (("f0", "ref"), ("f1", "load"), ("f2", "unload")):
        (tmp_path / f"{old}.tif").rename(tmp_path / f"{new}.tif")
    rc, stdout, err = _run(["measure", *(tmp_path / f"{k}.tif" for k in ("ref", "load", "unload")),
                            "-o", tmp_path / "out2.h5", "--json", "--quiet"], capsys)
    assert rc == 0, err
    assert not said(json.loads(stdout), "input")


def test_max_saturation_option(tmp_path, capsys):
    n, pitch = 64, 5.0
    img = render((n, n), pitch, vignette=0.0, amplitude=130.0)
    sat = img.copy()
    sat[:4] = 255  # 6 % of the pixels at the 8-bit ceiling
    import imageio.v3 as iio

    iio.imwrite(tmp_path / "r.png", np.rint(img).astype(np.uint8))
    iio.imwrite(tmp_path / "s.png", np.rint(sat).astype(np.uint8))
    args = ["measure", tmp_path / "r.png", tmp_path / "s.png", "--quiet"]
    rc, _, err = _run([*args, "-o", tmp_path / "a.h5"], capsys)
    assert rc == 2
    assert "saturated" in err
    rc, _, err = _run([*args, "-o", tmp_path / "b.h5", "--max-saturation", "0.1"], capsys)
    assert rc == 0, err


@pytest.mark.parametrize(("extra", "match"), [
    (["--guess", "1", "2", "--guess", "3", "4"], "--guess given 2 times"),
    (["--order", "backwards"], "--order must be one of 'series', 'independent'"),
    (["--max-saturation", "1.5"], "--max-saturation must be a number in [0, 1]"),
    (["--max-saturation", "-0.1"], "--max-saturation must be a number in [0, 1]"),
])
def test_bad_options_give_one_line(tmp_path, capsys, extra, match):
    n, pitch = 64, 5.0
    for name in ("r", "s1", "s2", "s3"):
        _write(tmp_path / f"{name}.tif", render((n, n), pitch, vignette=0.0))
    rc, out, err = _run(["measure", tmp_path / "r.tif", tmp_path / "s1.tif",
                         tmp_path / "s2.tif", tmp_path / "s3.tif", "-o", tmp_path / "o.h5",
                         *extra], capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("gridstrain measure: error:"), err
    assert match in lines[0]
    assert out == ""
    assert not (tmp_path / "o.h5").exists()


@pytest.mark.parametrize(("kw", "match"), [
    ({"guess": [(1.0, 2.0), None, "auto"]}, "one entry per loaded state"),
    ({"guess": ["auto", "zero"]}, r"guess\[1\]"),
    ({"order": "backwards"}, "order must be one of"),
    ({"max_saturation": 2.0}, "max_saturation"),
])
def test_bad_api_arguments(kw, match):
    img = render((64, 64), 5.0, vignette=0.0)
    with pytest.raises(ValueError, match=match):
        measure_series(img, [img, img], lattice=Lattice.from_pitch(5.0), **kw)


@pytest.mark.parametrize("masked", [False, True])
def test_image_features_correlation_is_the_direct_sum_at_every_shift_with_overlap(masked):
    # the normalised correlation map of the image-feature estimate, on transforms of h +
    # reach samples, with summed-area tables for unmasked images and correlations for
    # masked ones, against the direct sum over the overlap written here, at every shift
    # with overlap enough
    rng = np.random.default_rng(8)
    lat = Lattice.from_pitch(5.0)
    H, W = 60, 84
    ref = rng.normal(size=(H, W))
    cur = np.roll(ref, (3, -5), axis=(0, 1)) + 0.3 * rng.normal(size=(H, W))
    mask = np.ones((H, W), dtype=bool)
    if masked:
        mask[20:35, 30:50] = False  # a hole
    side = kinematics._reference_side(ref, lat, mask)
    assert side.q == 1
    assert (side.box is None) == masked
    b = kinematics._band_pass(cur, np.ones((H, W), dtype=bool), lat.pitch, 1,
                              weights=side.weights)
    c = kinematics._ncc_map(side, b)
    f, g = side.a, b
    ma, mb = side.ma, side.mb
    Sy, Sx = c.shape
    checked = 0
    for sy in range(-side.reach[0], side.reach[0] + 1):
        for sx in range(-side.reach[1], side.reach[1] + 1):
            if not side.enough[sy % Sy, sx % Sx]:
                continue
            # overlap of f's mask at x and g's mask at x + s
            ys, xs = np.nonzero(ma)
            ok = (ys + sy >= 0) & (ys + sy < H) & (xs + sx >= 0) & (xs + sx < W)
            ys, xs = ys[ok], xs[ok]
            keep = mb[ys + sy, xs + sx]
            fv, gv = f[ys[keep], xs[keep]], g[ys[keep] + sy, xs[keep] + sx]
            # g is centred on its whole mask first, f on its own, as the estimate does
            fv = fv - f[ma].mean()
            gv = gv - g[mb].mean()
            num = np.sum(fv * gv) - fv.sum() * gv.sum() / fv.size
            den = math.sqrt((np.sum(fv**2) - fv.sum() ** 2 / fv.size)
                            * (np.sum(gv**2) - gv.sum() ** 2 / gv.size))
            # float64 rounding of sums of a few thousand terms, differenced: ~1e-15
            assert abs(c[sy % Sy, sx % Sx] - num / den) < 1e-12
            checked += 1
    assert checked > 1000
    peak = np.unravel_index(int(np.nanargmax(c)), c.shape)
    assert (peak[0] - Sy if peak[0] > Sy // 2 else peak[0]) == 3
    assert (peak[1] - Sx if peak[1] > Sx // 2 else peak[1]) == -5
