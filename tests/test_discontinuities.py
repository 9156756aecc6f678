"""Cracks: the pixels whose window straddles a displacement jump are left out and
the jump is named.

Images from the independent generator (tests/independent_grid.py): a displacement
with a jump across the line y = 78.3 px (an edge crack closing at its tip, or a line
across the frame), over a smooth strain of 1e-3, 12-bit Poisson-Gaussian noise,
160 x 200 px, pitch 5 px, sigma 5 px; with or without printed spots that move with
the specimen (the only content that tells one period from the next).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from scipy import ndimage
from scipy.special import erf

from findings import said
from gridstrain import Lattice, coarse_displacement, load
from gridstrain.cli import main
from gridstrain.kinematics import find_discontinuities
from independent_grid import camera, scene

H, W = 160, 200
Y0, TIP = 78.3, 120.0


def _crack(opening, kind):
    def disp(X, Y):
        side = np.where(Y > Y0, 0.5, -0.5)
        if kind == "edge":  # closing smoothly at the tip, fading away from the line
            op = opening * np.clip(1 - X / TIP, 0, None) ** 2 * np.exp(-np.abs(Y - Y0) / 60)
        else:
            op = opening + 0 * X
        return 1e-3 * (X - 100), -3e-4 * (Y - 80) + side * op
    return disp


def _tip_field(opening):
    """A crack from the left border to a tip at (TIP, Y0): the near-tip field of
    linear elastic fracture mechanics (mode I, Williams' first term, plane stress,
    Poisson's ratio 0.3), opening by ``opening`` px at the left border, over the
    smooth strain of :func:`_crack`."""
    kappa = (3 - 0.3) / (1 + 0.3)
    a = opening / (2 * (kappa + 1) * np.sqrt(TIP))

    def disp(X, Y):
        r = np.hypot(X - TIP, Y - Y0)
        half = np.arctan2(Y - Y0, X - TIP) / 2
        ux = a * np.sqrt(r) * np.cos(half) * (kappa - 1 + 2 * np.sin(half) ** 2)
        uy = a * np.sqrt(r) * np.sin(half) * (kappa + 1 - 2 * np.cos(half) ** 2)
        return 1e-3 * (X - 100) + ux, -3e-4 * (Y - 80) + uy
    return disp


def _spots(rows=(0, H), n=90, seed=5):
    """Dark printed spots 1 to 2.5 px in radius, ``(X, Y) -> factor``, attached to the
    specimen (in the rows ``rows`` of the reference)."""
    rng = np.random.default_rng(seed)
    cx, cy = rng.uniform(-10, W + 10, n), rng.uniform(rows[0] - 10, rows[1] + 10, n)
    rr = rng.uniform(1.0, 2.5, n)

    def factor(X, Y):
        out = np.ones_like(X)
        for a, b, r in zip(cx, cy, rr, strict=True):
            out = out - 0.35 * np.exp(-((X - a) ** 2 + (Y - b) ** 2) / (2 * r * r))
        return np.clip(out, 0.2, None)

    return factor


def _images(disp, defects=None, hole=False):
    ref, _ = scene((H, W), pitch=5, angle=0, hole=hole, reflectance=defects)
    cur, _ = scene((H, W), pitch=5, angle=0, hole=hole, displacement=disp, reflectance=defects)
    rng = np.random.default_rng(2)
    return [camera(img, 0.3, 4.0, rng) for img in (ref, cur)]


def _measure(tmp_path, disp, defects=None, capsys=None, hole=False):
    paths = [tmp_path / "ref.tif", tmp_path / "def.tif"]
    for p, img in zip(paths, _images(disp, defects, hole), strict=True):
        tifffile.imwrite(p, img, photometric="minisblack")
    out = tmp_path / "maps.h5"
    extra = [] if capsys is None else ["--json"]
    assert main(["measure", *map(str, paths), "-o", str(out), "--quiet", *extra]) == 0
    if capsys is None:
        return load(out)
    return load(out), json.loads(capsys.readouterr().out)


def _beyond_5_std(res, disp):
    v = res.valid[0]
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    err = np.stack(res.u[0]) - np.stack(disp(xx, yy))
    std = np.stack([res.uncertainty["ux_std"][0], res.uncertainty["uy_std"][0]])
    return float(np.mean(np.any(np.abs(err[:, v]) > 5 * std[:, v], axis=0)))


@pytest.mark.parametrize(("opening", "kind"), [(0.5, "edge"), (2.0, "edge"), (0.5, "full"),
                                               (2.0, "full")])
def test_a_crack_is_left_out_and_named(tmp_path, opening, kind):
    disp = _crack(opening, kind)
    res = _measure(tmp_path, disp)
    # without it 6 to 18 % of the valid pixels are beyond 5 std (the window smooths
    # the jump over +-2 sigma); 0.2 % is the acceptance figure (measured: none)
    assert _beyond_5_std(res, disp) <= 0.002
    (regions,) = res.discontinuities
    assert len(regions) == 1
    r = regions[0]
    # the box holds the crack's line and, along it, reaches the tip (or the frame's
    # valid band, 4 sigma = 20 px from its borders)
    assert r["rows"][0] < Y0 < r["rows"][1]
    assert r["cols"][0] <= 20
    assert r["cols"][1] >= (TIP - 20 if kind == "edge" else W - 21)
    assert any(f"rows {r['rows'][0]}-{r['rows'][1]}" in w
               for w in said(res.warnings, "jump.found"))
    # the pixels left out are not valid
    assert res.valid[0].mean() < 0.55  # 0.60 without the crack's band


@pytest.mark.parametrize("opening", [3.0, 8.0])
def test_a_crack_is_followed_to_its_tip(tmp_path, opening):
    # opening by 8 px at the border, the crack passes through half a pitch (2.5 px)
    # and a whole pitch: where the deformed grid vanishes along it (half a pitch) the
    # hole left in the maps must not part the ridge from its tip, whose window holds
    # the jump and the singular strain (4.8 % of the pixels beyond 5 std when it did)
    disp = _tip_field(opening)
    res = _measure(tmp_path, disp)
    assert _beyond_5_std(res, disp) <= 0.002  # the acceptance figure (measured: <= 0.01 %)
    boxes = res.discontinuities[0]
    # the pixels left out reach the tip (the valid band ends 20 px from the border)
    assert max(r["cols"][1] for r in boxes) >= TIP
    assert min(r["rows"][0] for r in boxes) < Y0 < max(r["rows"][1] for r in boxes)


@pytest.mark.parametrize("opening", [4.0, 6.0])
def test_each_part_of_a_cracked_field_is_fixed_by_its_own_features(tmp_path, opening):
    # across an opening of more than half a pitch (2.5 px) the phases put one side
    # whole periods off; the printed spots of each side, warped back by that side's
    # field, say by how many
    disp = _crack(opening, "full")
    res = _measure(tmp_path, disp, _spots())
    # 0.2 % is the acceptance figure (measured: none; half the pixels a period off
    # for 6 px when both sides take the order closest to the guess)
    assert _beyond_5_std(res, disp) <= 0.002
    rec = res.fringe_orders[0]
    assert rec.confirmed
    assert rec.source == "image features"
    assert "cuts the field into 2 parts" in rec.detail
    assert res.valid[0].mean() > 0.3  # both sides measured: 0.37 with the band left out


def test_a_cracked_part_without_features_of_its_own_is_left_out(tmp_path):
    # spots on the lower side only: the upper side cannot be told from a period away
    disp = _crack(6.0, "full")
    res = _measure(tmp_path, disp, _spots(rows=(0, 60), n=60))
    assert _beyond_5_std(res, disp) <= 0.002  # the acceptance figure (measured: none)
    v = res.valid[0]
    # the valid band starts 4 sigma = 20 px from the borders; the crack's at row 58
    assert v[25:50, 25:175].all()
    assert not v[90:].any()
    assert res.fringe_orders[0].confirmed
    assert any("no image features of its own" in w and "left out" in w
               for w in said(res.warnings, "jump.part"))


def test_a_hole_fixes_the_part_it_lies_in(tmp_path):
    # a plain grid with a hole (radius 16 px, centre 22 px above the crack) cut in two
    # by an opening of 4 px: the hole's edge, in the margin round it, fixes the upper
    # part's whole periods; the lower part holds nothing of the kind and is left out
    # (the whole images' estimate, the hole's, had put it a period off: 58 % of the
    # valid pixels beyond 5 std)
    disp = _crack(4.0, "full")
    res = _measure(tmp_path, disp, hole=True)
    assert _beyond_5_std(res, disp) <= 0.002  # the acceptance figure (measured: none)
    v = res.valid[0]
    assert v[:50].any()
    assert not v[100:].any()
    assert res.fringe_orders[0].confirmed


def test_a_cracked_field_without_features_is_not_confirmed(tmp_path, capsys):
    # a plain grid: nothing tells either side's whole periods; each takes the one
    # closest to the guess (zero), a period off for an opening of 6 px: said, in the
    # record, the warnings, and the JSON summary
    res, summary = _measure(tmp_path, _crack(6.0, "full"), capsys=capsys)
    assert not res.fringe_orders[0].confirmed
    assert "cuts the field into 2 parts" in res.fringe_orders[0].detail
    assert any("none has image features of its own" in w
               for w in said(res.warnings, "fringe_order.unconfirmed"))
    (state,) = summary["states"]
    assert state["fringe_order"]["confirmed"] is False
    assert any("none has image features of its own" in w
               for w in said(summary, "fringe_order.unconfirmed"))


def test_a_cracked_field_is_unwrapped_part_by_part(tmp_path):
    # 4 px opening (0.8 period) of a plain grid, each side within half a period of
    # the guess (zero): each part unwrapped on its own gets its order right, where a
    # strip joining them along the frame's border put one a period off
    disp = _crack(4.0, "full")
    res = _measure(tmp_path, disp)
    assert _beyond_5_std(res, disp) <= 0.002  # the acceptance figure (measured: none)
    assert not res.fringe_orders[0].confirmed  # nothing but the guess says so


def test_a_cracked_field_followed_from_the_previous_state(tmp_path):
    # a plain grid cut in two, opening by 3 then 6 px: the second state's sides
    # (+-3 px) each lie more than half a pitch from the guess's median (zero) but
    # within it of the first state's field (+-1.5 px), pixel by pixel
    disps = [_crack(3.0, "full"), _crack(6.0, "full")]
    ref, _ = scene((H, W), pitch=5, angle=0, hole=False)
    curs = [scene((H, W), pitch=5, angle=0, hole=False, displacement=d)[0] for d in disps]
    rng = np.random.default_rng(2)
    paths = [tmp_path / f"{n}.tif" for n in ("ref", "def1", "def2")]
    for p, img in zip(paths, (ref, *curs), strict=True):
        tifffile.imwrite(p, camera(img, 0.3, 4.0, rng), photometric="minisblack")
    out = tmp_path / "maps.h5"
    assert main(["measure", *map(str, paths), "-o", str(out), "--quiet"]) == 0
    res = load(out)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    v = res.valid[1]
    err = np.stack(res.u[1]) - np.stack(disps[1](xx, yy))
    std = np.stack([res.uncertainty["ux_std"][1], res.uncertainty["uy_std"][1]])
    # 0.2 %: the acceptance figure (measured: none; all of them a period off when
    # each side took the whole periods closest to the guess's median)
    assert np.mean(np.any(np.abs(err[:, v]) > 5 * std[:, v], axis=0)) <= 0.002
    assert not res.fringe_orders[1].confirmed  # nothing but the previous state says so


def test_a_region_is_correlated_on_its_own():
    # the spots lie in the upper rows: the lower part alone holds none, and its
    # estimate must not borrow the whole image's
    lat = Lattice.from_pitch(5.0)
    ref, cur = _images(lambda X, Y: (0 * X, 5.0 + 0 * Y), _spots(rows=(0, 60), n=60))
    lower = np.zeros((H, W), dtype=bool)
    lower[90:] = True
    whole = coarse_displacement(ref, cur, lat, phase_shift=(0.0, 0.0))
    assert whole.confident
    assert whole.shift == pytest.approx((0.0, 5.0), abs=0.05)  # px: a whole period
    part = coarse_displacement(ref, cur, lat, phase_shift=(0.0, 0.0), region=lower)
    assert not part.confident
    upper = coarse_displacement(ref, cur, lat, phase_shift=(0.0, 0.0), region=~lower)
    assert upper.confident
    assert upper.shift == pytest.approx((0.0, 5.0), abs=0.05)


def test_no_crack_in_a_smooth_strain_concentration(tmp_path):
    def disp(X, Y):  # e_xx: a bump of 2 %, 1.5 sigma wide (std), along a band
        return (0.02 * 7.5 * np.sqrt(np.pi / 2) * erf((X - 100) / (np.sqrt(2) * 7.5))
                * np.exp(-(Y - 80) ** 2 / (2 * 22.5**2)), 0 * Y)
    res = _measure(tmp_path, disp)
    assert res.discontinuities == ((),)
    assert not said(res.warnings, "jump.found")


def _strain_only(strain, valid, sigma=5.0):
    """A Measurement holding only the maps the search reads (its strain, validity, sigma)."""
    from gridstrain import Lattice
    from gridstrain.kinematics import Measurement

    zeros = np.zeros((2, *valid.shape))
    return Measurement(u=zeros, strain=strain, rotation=zeros[0], valid=valid,
                       lattice=Lattice.from_pitch(5.0), sigma=sigma, lagrangian=True,
                       iterations=1, step_rms=0.0, guess=(0.0, 0.0), guess_source="zero",
                       reference=None, deformed=None)


@pytest.mark.parametrize("height", [0.99, 1.01])
@pytest.mark.parametrize("skip", [True, False])
def test_the_range_pre_test_never_hides_a_ridge(monkeypatch, height, skip):
    # one pixel's spike on a constant strain is the tightest case of the range bound:
    # its departure from the local median is the whole range. A jump of min_jump
    # (0.25 px) leaves a ridge of 0.25 / (sqrt(2 pi) sigma); the spike stands 1 % below
    # or above it, so the pre-test may skip only the first, and the full search
    # (pre-test off) must agree with it on both
    from gridstrain.kinematics import _discontinuities as dc

    if not skip:
        monkeypatch.setattr(dc, "_no_seed_possible", lambda *a: False)
    threshold = 0.25 / (np.sqrt(2 * np.pi) * 5.0)
    valid = np.zeros((H, W), dtype=bool)
    valid[20:-20, 20:-20] = True
    strain = np.full((3, H, W), 1e-3)
    strain[0, 80, 100] += height * threshold
    strain[:, ~valid] = np.nan
    disc = dc.find_discontinuities(_strain_only(strain, valid))
    if height < 1:
        assert not disc
    else:
        assert len(disc.regions) == 1
        assert disc.core[80, 100]


def test_the_range_pre_test_skips_a_noisy_smooth_field(monkeypatch):
    # strain noise of 4e-4 (a 12-bit grid at sigma 5 px) over a gradient of 1e-3: its
    # range stays below the ridge of the smallest jump looked for, 0.02, so no pixel
    # can seed one and the search is skipped, as the full search would conclude
    from gridstrain.kinematics import _discontinuities as dc

    rng = np.random.default_rng(5)
    valid = np.ones((H, W), dtype=bool)
    xx = np.arange(W)[None, :]
    strain = 1e-3 * xx / W + 4e-4 * rng.standard_normal((3, H, W))
    threshold = 0.25 / (np.sqrt(2 * np.pi) * 5.0)
    assert dc._no_seed_possible(strain, valid, threshold)
    assert not dc.find_discontinuities(_strain_only(strain, valid))
    monkeypatch.setattr(dc, "_no_seed_possible", lambda *a: False)
    assert not dc.find_discontinuities(_strain_only(strain, valid))


def _strain_fields(kind, size, sigma=5.0, angle=20.0):
    """(3, H, W) strain as the window shows it (its cross-section the window's,
    std ``sigma``, or wider): ``"opening"`` / ``"sliding"``, a jump of ``size`` px
    across the line through the frame's centre whose normal is at ``angle`` degrees
    from x; ``"bump"``, a round bump of e_xx of peak ``size`` and std 1.5 sigma
    (seen sqrt(1.5^2 + 1) sigma wide) with the shear of its displacement."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    X, Y = xx - W / 2, yy - H / 2
    if kind == "bump":
        s = np.hypot(1.5, 1.0) * sigma
        gy = np.exp(-Y**2 / (2 * s * s))
        c = size * s * np.sqrt(np.pi / 2)
        return np.stack([size * gy * np.exp(-X**2 / (2 * s * s)), 0 * X,
                         -0.5 * c * Y / (s * s) * gy * erf(X / (np.sqrt(2) * s))])
    a = np.radians(angle)
    n, t = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    b = size * (n if kind == "opening" else t)
    g = np.exp(-(X * n[0] + Y * n[1]) ** 2 / (2 * sigma**2)) / (np.sqrt(2 * np.pi) * sigma)
    # the strain of a jump b across the line: sym(b (x) n) times the window's profile
    return np.stack([b[0] * n[0] * g, b[1] * n[1] * g, 0.5 * (b[0] * n[1] + b[1] * n[0]) * g])


@pytest.mark.parametrize(("kind", "angle"), [("opening", 20.0), ("sliding", 20.0),
                                             ("opening", 90.0)])
def test_the_jump_is_the_strain_integrated_across_the_ridge(kind, angle):
    # a jump of 1 px leaves a ridge of the window's profile integrating to it (a
    # sliding one's shear, 0.5 px, stands above the smallest jump's ridge); the
    # strain noise of a 12-bit grid (4e-4 a pixel) moves the integral over +-3 sigma
    # by about 4e-4 * sqrt(6 sigma * sigma) = 2e-3 px, the median over the sections by
    # less: 0.02 px leaves room for the baseline's line through a noisy background
    rng = np.random.default_rng(7)
    valid = np.zeros((H, W), dtype=bool)
    valid[20:-20, 20:-20] = True
    strain = _strain_fields(kind, 1.0, angle=angle) + 1e-3
    strain += 4e-4 * _window_noise(rng.standard_normal((3, H, W)))
    strain[:, ~valid] = np.nan
    disc = find_discontinuities(_strain_only(strain, valid))
    (r,) = disc.regions
    assert abs(abs(r["jump_px"]) - 1.0) <= 0.02
    across, along = ("opening_px", "sliding_px")[:: 1 if kind == "opening" else -1]
    assert abs(abs(r[across]) - 1.0) <= 0.02
    assert abs(r[along]) <= 0.02
    # the jump is known modulo the lattice's period along it: 1 / max |K b| / |b|,
    # the pitch (5 px) along either family, 5 / cos(20 deg) at 20 degrees from one
    period = 5.0 / np.cos(np.radians(angle if angle < 45 else 90 - angle))
    assert r["pitch_px"] == pytest.approx(period, rel=1e-2)  # the normal's median
    assert f"modulo the period {r['pitch_px']:.3g} px" in disc.describe()


def _window_noise(noise, sigma=5.0):
    """Noise correlated over the window, as the strain maps' is, at unit std."""
    out = np.stack([ndimage.gaussian_filter(c, sigma / 2) for c in noise])
    return out / out.std()


def test_a_bump_as_the_window_shows_it_is_not_a_jump():
    # a round bump of 5 % (1.5 sigma wide, seen 1.8 sigma wide through the window)
    # stands 2.5 times above the ridge of the smallest jump looked for: only its
    # cross-section, wider than the window's, tells it from one
    valid = np.zeros((H, W), dtype=bool)
    valid[20:-20, 20:-20] = True
    strain = _strain_fields("bump", 0.05)
    strain[:, ~valid] = np.nan
    assert not find_discontinuities(_strain_only(strain, valid))


def _bump(amplitude, width):
    """A round Gaussian bump of e_xx, peak ``amplitude``, std ``width`` px, at the
    frame's centre: ``u_x = a w sqrt(pi/2) exp(-dy^2/2w^2) erf(dx / sqrt(2) w)``."""
    def disp(X, Y):
        return (amplitude * width * np.sqrt(np.pi / 2) * np.exp(-(Y - 80) ** 2 / (2 * width**2))
                * erf((X - 100) / (np.sqrt(2) * width)), 0 * Y)
    return disp


def _band(amplitude, width):
    """A Gaussian band of e_yy across y at y = 80 px, peak ``amplitude``, std ``width`` px."""
    def disp(X, Y):
        return (0 * X, amplitude * width * np.sqrt(np.pi / 2)
                * erf((Y - 80) / (np.sqrt(2) * width)))
    return disp


@pytest.mark.parametrize("amplitude", [0.03, 0.05, 0.10])
@pytest.mark.parametrize("widths", [1.5, 2.0, 3.0])
def test_a_strain_bump_is_never_a_crack(tmp_path, amplitude, widths):
    # smooth everywhere, so no displacement jumps: the window shows its ridge
    # sqrt(widths^2 + 1) sigma wide, wider than a jump's (the window's own profile),
    # and up to 7 % high, 3.5 times the ridge of the smallest jump looked for
    res = _measure(tmp_path, _bump(amplitude, widths * 5.0))
    assert res.discontinuities == ((),)
    assert not said(res.warnings, "jump.found")
    assert res.valid[0].mean() > 0.55  # 0.60 in the frame's band, none left out


def test_a_strain_band_is_not_a_crack(tmp_path):
    # a band of 5 %, 1.5 sigma wide, across the frame: line-like as a crack is, its
    # cross-section 1.8 sigma wide through the window
    res = _measure(tmp_path, _band(0.05, 1.5 * 5.0))
    assert res.discontinuities == ((),)
    assert not said(res.warnings, "jump.found")


@pytest.mark.parametrize("opening", [0.5, 1.0, 2.0, 3.0])
def test_a_crack_is_named_once_with_its_jump_modulo_the_pitch(tmp_path, opening):
    # the phases know the jump modulo the pitch (5 px): 3 px shows as -2 px
    res = _measure(tmp_path, _crack(opening, "full"))
    (regions,) = res.discontinuities
    assert len(regions) == 1  # one crack, one region
    seen = opening - 5.0 * round(opening / 5.0)
    # 20 %: the strain integrated over +-3 sigma across the ridge, less a baseline
    # read beyond it (measured: within 1 %)
    assert regions[0]["jump_px"] == pytest.approx(seen, rel=0.2)
    assert any(f"a jump of {regions[0]['jump_px']:.2g} px modulo the period 5 px" in w
               for w in said(res.warnings, "jump.found"))


def test_a_crack_opening_past_a_pitch_is_found(tmp_path):
    # the faces moved past a whole pitch (5.5 px, half a pixel beyond): the ridge,
    # seen 1.42 sigma wide, is wider than the window's, not as wide as a smooth
    # concentration's (1.5 sigma and more)
    res = _measure(tmp_path, _crack(5.5, "full"))
    (regions,) = res.discontinuities
    assert len(regions) == 1
    r = regions[0]
    assert r["rows"][0] < Y0 < r["rows"][1]
    assert r["cols"][0] <= 20  # across the valid band
    assert r["cols"][1] >= W - 21
    assert r["jump_px"] == pytest.approx(0.5, rel=0.2)  # modulo the pitch, as above
