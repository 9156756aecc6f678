"""Young's modulus and Poisson's ratio by the virtual fields method (``gridstrain identify``).

The oracle is the exact plane-stress solution of a cantilever loaded by a shear force at
its free end (Timoshenko & Goodier, Theory of Elasticity, 3rd ed., §21), written here
with numpy only: its strains, its stresses and its end resultant are closed forms, and
its field is heterogeneous (bending plus shear), so that E and nu are both identifiable.
A uniform coupon, a uniform shear and an equibiaxial field are the homogeneous cases.
Noise is white Gaussian strain noise of a known std, as the identification assumes.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from gridstrain.identify import NotIdentifiable, VirtualFields, identify, virtual_fields
from gridstrain.post import GaugeReading, elastic_constants

E, NU = 70e3, 0.33  # MPa, -: aluminium
H, W, PIXEL, THICKNESS = 48, 192, 10.0 / 48, 2.0  # px, px, mm, mm: a 10 x 40 mm beam
LOADS = np.array([25.0, 50.0, 75.0, 100.0])  # N: up to 1700 µε at the root


def cantilever(load, *, shape=(H, W), pixel=PIXEL, thickness=THICKNESS):
    """Strains ``(3, H, W)`` and stresses ``(3, H, W)`` of an end-loaded cantilever.

    Assumptions: plane stress, small strains, linear-elastic isotropic (E, NU); the
    beam fills the image, its depth ``2c = H pixel`` along the rows, its length
    ``W pixel`` along the columns; the load ``load`` (N) is the +y component of the
    resultant acting on the left edge (x = 0, the free end), carried as the parabolic
    shear of the exact solution; the right edge is built in (it carries the reaction
    and the moment); top and bottom are free. Each pixel is a ``pixel``-mm square
    sampled at its centre. With ``I = 2 c^3 / 3`` (per unit thickness), ``x`` the
    distance from the loaded edge and ``y`` from the neutral axis (downward):
    ``sigma_xx = -F x y / (I t)``, ``sigma_yy = 0``,
    ``sigma_xy = -F (c^2 - y^2) / (2 I t)`` — equilibrium and compatibility hold
    exactly, and the traction ``-sigma_xy`` on the left edge sums to ``F``.
    """
    rows, cols = np.indices(shape, dtype=np.float64)
    c = shape[0] * pixel / 2
    x = (cols + 0.5) * pixel
    y = (rows + 0.5) * pixel - c
    inertia = 2 * c**3 / 3
    sxx = -load * x * y / (inertia * thickness)
    sxy = -load * (c * c - y * y) / (2 * inertia * thickness)
    strain = np.stack([sxx / E, -NU * sxx / E, sxy * (1 + NU) / E])
    return strain, np.stack([sxx, np.zeros_like(sxx), sxy])


def uniform(load, kind, *, shape=(H, W), pixel=PIXEL, thickness=THICKNESS):
    """Strains ``(3, H, W)`` of a homogeneous field whose resultant on the right edge is
    ``load`` (N): ``"tension"`` along x (a coupon), ``"shear"`` (sigma_xy, the load
    along y) or ``"biaxial"`` (equal sigma_xx and sigma_yy). Plane stress, isotropic."""
    s = load / (shape[0] * pixel * thickness)
    e = np.zeros((3, *shape))
    if kind == "tension":
        e[0], e[1] = s / E, -NU * s / E
    elif kind == "shear":
        e[2] = s * (1 + NU) / E
    else:
        e[0] = e[1] = s * (1 - NU) / E
    return e


def _run(strain, std, loads, **kw):
    opts = {"thickness": THICKNESS, "loaded_edge": "left", "load_direction": "y",
            "pixel_size": PIXEL}
    return virtual_fields(strain, std, loads, **{**opts, **kw})


def test_exact_field_gives_E_and_nu():
    strain = np.stack([cantilever(f)[0] for f in LOADS])
    # exact maps: a negligible stated std (the noise's share of the equations, taken
    # out, is then nil)
    r = _run(strain, np.full_like(strain, 1e-7), LOADS)
    assert isinstance(r, VirtualFields)
    assert r.stress_unit == "MPa"
    assert r.combined == "slope"
    # the only error is the pixel sum standing for the integral (midpoint rule, a
    # relative (pixel / depth)^2 / 3 ~ 1.4e-4 on the parabolic shear): measured 3.6e-4
    assert pytest.approx(E, rel=1e-3) == r.E
    assert pytest.approx(NU, abs=1e-3) == r.nu
    # every state alone gives the same: the field is linear in the load
    np.testing.assert_allclose(r.E_states, r.E, rtol=1e-6)
    # the identified stress is the exact one, to the same 1e-3 of its largest value
    sigma = cantilever(LOADS[-1])[1]
    np.testing.assert_allclose(r.stress(strain[-1]), sigma,
                               atol=1e-3 * np.abs(sigma).max())
    assert not r.E_states.flags.writeable
    # float32 maps are computed in float64: the same constants to their rounding (6e-8)
    r32 = _run(strain.astype(np.float32), np.full_like(strain, 1e-7, dtype=np.float32),
               LOADS)
    assert pytest.approx(r.E, rel=1e-5) == r32.E
    assert r32.stress(strain[-1].astype(np.float32)).dtype == np.float64


@pytest.mark.parametrize("edge", ["left", "right", "top", "bottom"])
def test_every_loaded_edge(edge):
    # the beam mirrored and turned so that each edge carries the load (mirror x -> -x
    # or y -> -y: exy and the force across the mirror change sign; a transpose swaps
    # exx and eyy and the load's direction)
    e = cantilever(LOADS[-1])[0]
    direction, loads = "y", LOADS[-1:]
    if edge == "right":
        e = np.stack([e[0], e[1], -e[2]])[:, :, ::-1]
    elif edge in ("top", "bottom"):
        e = np.stack([e[1], e[0], e[2]]).transpose(0, 2, 1)
        direction = "x"
        if edge == "bottom":
            e = np.stack([e[0], e[1], -e[2]])[:, ::-1, :]
    r = _run(e[None], np.full((1, *e.shape), 1e-7), loads, loaded_edge=edge,
             load_direction=direction)
    assert pytest.approx(E, rel=1e-3) == r.E  # as above: the pixel sum (3.6e-4)
    assert pytest.approx(NU, abs=1e-3) == r.nu
    # a load of the wrong sign is a stiffness no solid has: refused, not printed
    with pytest.raises(NotIdentifiable, match="not one of a solid"):
        _run(e[None], np.full((1, *e.shape), 1e-7), -loads, loaded_edge=edge,
             load_direction=direction)


def test_noise_errors_and_interval_coverage():
    # one state, so that the interval is the method's own (the stated std through the
    # special fields) and nothing else: over 60 draws its 95 % interval must hold the
    # truth 57 +- 3 x 1.7 times (binomial)
    # (a 32 x 128 px beam of the same 10 x 40 mm, for speed)
    pixel = 10.0 / 32
    clean = cantilever(LOADS[-1], shape=(32, 128), pixel=pixel)[0][None]
    s = 1e-4  # per pixel: a grid-method strain map at sigma ~ 2 pitches
    std = np.full_like(clean, s)
    rng = np.random.default_rng(7)
    out = []
    for _ in range(60):
        r = _run(clean + rng.normal(0.0, s, clean.shape), std, LOADS[-1:], pixel_size=pixel)
        assert r.interval_basis == "stated std"
        out.append((r.E, r.E_std, r.nu, r.nu_std))
    Es, sE, nus, snu = np.array(out).T
    z = 1.959964
    cover_E = np.sum(np.abs(Es - E) < z * sE)
    cover_nu = np.sum(np.abs(nus - NU) < z * snu)
    assert 52 <= cover_E <= 60, cover_E
    assert 52 <= cover_nu <= 60, cover_nu
    # the stated std is the scatter's: the sample std of 60 draws is within 3 x 9 %
    # (1 / sqrt(2 x 59)) of the truth
    assert 0.73 < np.std(Es, ddof=1) / np.median(sE) < 1.27
    assert 0.73 < np.std(nus, ddof=1) / np.median(snu) < 1.27
    # no bias beyond the sampling of the mean (3 std / sqrt(60)) plus the pixel sum's
    # (under 1e-3 on this coarser beam: (1 / 32)^2 / 3 on the shear)
    assert abs(np.mean(Es) - E) < 3 * np.median(sE) / np.sqrt(60) + 1e-3 * E
    assert abs(np.mean(nus) - NU) < 3 * np.median(snu) / np.sqrt(60) + 1e-3


def _smoothed_noise(rng, shape, s, sigma):
    """White noise convolved with a Gaussian of std ``sigma`` px whose squares sum to 1
    (drawn on a larger field and cropped, so that every pixel's std is ``s``), and its
    correlation between pixels: the kernel's autocorrelation, centre 1. A stand-in for
    the window's smoothing of a grid measurement, written here."""
    from scipy.signal import fftconvolve

    r = int(np.ceil(4 * sigma))
    d = np.arange(-r, r + 1)
    g = np.exp(-(d[:, None] ** 2 + d[None, :] ** 2) / (2 * sigma**2))
    g /= np.sqrt(np.sum(g**2))
    rho = fftconvolve(g, g[::-1, ::-1], mode="full")
    w = rng.normal(0.0, 1.0, (3, shape[0] + 2 * r, shape[1] + 2 * r))
    return s * np.stack([fftconvolve(c, g, mode="valid") for c in w]), rho


@pytest.mark.slow
def test_correlated_noise_coverage():
    # noise smoothed over a few pixels (as the window smooths a grid measurement) puts
    # far more of its power at the elements' scale than independent pixels of the same
    # std: with its correlation given, the interval holds the truth 95 % of the time
    # (40 draws: 38 +- 3 x 1.4); taken as independent, the std is several times too
    # small (measured: 393 MPa stated against 1876 MPa of scatter, 9 of 40 covered;
    # with the correlation 1924 against 2076, 37 of 40)
    pixel = 10.0 / 32
    clean = cantilever(LOADS[-1], shape=(32, 128), pixel=pixel)[0][None]
    s = 1e-4
    std = np.full_like(clean, s)
    rng = np.random.default_rng(9)
    out = []
    for _ in range(40):
        noise, rho = _smoothed_noise(rng, (32, 128), s, 1.5)
        r = _run(clean + noise[None], std, LOADS[-1:], pixel_size=pixel,
                 correlation=(rho, rho, rho))
        out.append((r.E, r.E_std, r.nu, r.nu_std))
    Es, sE, nus, snu = np.array(out).T
    z = 1.959964
    assert 34 <= np.sum(np.abs(Es - E) < z * sE) <= 40
    assert 34 <= np.sum(np.abs(nus - NU) < z * snu) <= 40
    # the stated std is the scatter's, within 3 x 11 % (1 / sqrt(2 x 39))
    assert 0.67 < np.std(Es, ddof=1) / np.median(sE) < 1.33
    assert 0.67 < np.std(nus, ddof=1) / np.median(snu) < 1.33
    white = _run(clean + noise[None], std, LOADS[-1:], pixel_size=pixel)
    assert white.E_std < 0.5 * np.median(sE)


def test_correlated_noise_one_draw():
    # the same, one draw, in the default run: the interval holds the truth (a 5 %
    # chance of failing is not taken: 3 std) and is wider than independent pixels'
    pixel = 10.0 / 32
    clean = cantilever(LOADS[-1], shape=(32, 128), pixel=pixel)[0][None]
    s = 1e-4
    noise, rho = _smoothed_noise(np.random.default_rng(4), (32, 128), s, 1.5)
    r = _run(clean + noise[None], np.full_like(clean, s), LOADS[-1:], pixel_size=pixel,
             correlation=(rho, rho, rho))
    white = _run(clean + noise[None], np.full_like(clean, s), LOADS[-1:], pixel_size=pixel)
    assert abs(r.E - E) < 3 * r.E_std
    assert abs(r.nu - NU) < 3 * r.nu_std
    assert r.E_std > 2 * white.E_std
    with pytest.raises(ValueError, match="correlation must be 3 kernels"):
        _run(clean, np.full_like(clean, s), LOADS[-1:], pixel_size=pixel,
             correlation=(rho, rho))


def test_states_combined_and_the_reference_noise():
    clean = np.stack([cantilever(f)[0] for f in LOADS])
    s = 1e-4
    std = np.full_like(clean, s)
    rng = np.random.default_rng(3)
    noisy = clean + rng.normal(0.0, s, clean.shape)
    r = _run(noisy, std, LOADS)
    # 4 states of 9216 px at 1e-4: E to about 500 MPa, nu to 0.004 (the stated std)
    assert abs(r.E - E) < 3 * r.E_std
    assert abs(r.nu - NU) < 3 * r.nu_std
    assert r.E_interval[0] < r.E < r.E_interval[1]
    assert r.E_std < 0.01 * E
    assert r.nu_std < 0.01
    # the reference image's noise is common to every state: the per-pixel slope's
    # intercept takes it up, so that it changes nothing (equal weights: exactly)
    common = rng.normal(0.0, s, clean.shape[1:])
    r2 = _run(noisy + common, std, LOADS)
    assert pytest.approx(r.E, rel=1e-9) == r2.E
    assert pytest.approx(r.nu, rel=1e-9) == r2.nu
    # a state whose load is wrong by 20 % scatters beyond its std: the interval widens
    wrong = LOADS * np.array([1.0, 1.0, 1.2, 1.0])
    r3 = _run(noisy, std, wrong)
    assert r3.interval_basis == "scatter over states"
    assert max(r3.reduced_chi2) > 1
    assert r3.E_std > 2 * r.E_std


def _gauge_reading(strain, s, loads):
    """The whole map's mean strain, std s / sqrt(N) (white noise), as a gauge reads it."""
    n = strain[0, 0].size
    mean = strain.mean(axis=(2, 3))
    sd = np.full(len(loads), s / np.sqrt(n))
    zero = np.zeros(len(loads))
    return GaugeReading(
        states=tuple(f"s{i}" for i in range(len(loads))), where="whole map",
        n_pixels=np.full(len(loads), n), exx=mean[:, 0], exx_std=sd, eyy=mean[:, 1],
        eyy_std=sd, exy=mean[:, 2], exy_std=sd, ux=zero, ux_std=zero, uy=zero,
        uy_std=zero, load=np.asarray(loads), load_unit="N")


def test_uniform_coupon_agrees_with_modulus():
    # a coupon in tension gives both constants: its free edges say sigma_yy = 0
    loads = np.array([100.0, 200.0, 300.0, 400.0, 500.0])
    shape = (48, 96)
    clean = np.stack([uniform(f, "tension", shape=shape) for f in loads])
    s = 1e-4
    noisy = clean + np.random.default_rng(5).normal(0.0, s, clean.shape)
    r = virtual_fields(noisy, np.full_like(noisy, s), loads, thickness=THICKNESS,
                       loaded_edge="right", load_direction="x", pixel_size=PIXEL)
    c = elastic_constants(_gauge_reading(noisy, s, loads),
                          area=shape[0] * PIXEL * THICKNESS)
    assert c.stress_unit == r.stress_unit == "MPa"
    # each one's value inside the other's 95 % interval
    assert c.E_ci[0] < r.E < c.E_ci[1]
    assert r.E_interval[0] < c.E < r.E_interval[1]
    assert c.nu_ci[0] < r.nu < c.nu_ci[1]
    assert r.nu_interval[0] < c.nu < r.nu_interval[1]
    assert abs(r.E - E) < 3 * r.E_std
    assert abs(r.nu - NU) < 3 * r.nu_std


@pytest.mark.parametrize(("kind", "says"), [("shear", "shear modulus"),
                                            ("biaxial", "biaxial modulus")])
def test_fields_that_cannot_separate_E_from_nu(kind, says):
    loads = np.array([100.0, 200.0, 300.0])
    direction = "y" if kind == "shear" else "x"
    strain = np.stack([uniform(f, kind, shape=(32, 64)) for f in loads])
    with pytest.raises(NotIdentifiable, match=says):
        virtual_fields(strain, np.full_like(strain, 1e-4), loads, thickness=THICKNESS,
                       loaded_edge="right", load_direction=direction, pixel_size=PIXEL)
    # with noise, no number either: the other combination is the noise's alone
    noisy = strain + np.random.default_rng(2).normal(0.0, 1e-4, strain.shape)
    with pytest.raises(NotIdentifiable, match=f"separate E from nu: they give only the {says}"):
        virtual_fields(noisy, np.full_like(strain, 1e-4), loads, thickness=THICKNESS,
                       loaded_edge="right", load_direction=direction, pixel_size=PIXEL)


def test_a_region_short_of_the_free_edges_is_refused():
    # the maps of a measurement stop a margin short of the specimen's edges: the beam's
    # rows 8 to 39 only (the specimen all 48) lose the shear carried in the strips
    # (without the check: Q12 / Q11 = 0.81, no solid's). Refused, not printed
    strain = np.stack([cantilever(f)[0] for f in LOADS])
    std = np.full_like(strain, 1e-7)
    specimen = np.ones((H, W), dtype=bool)
    inner = np.zeros((H, W), dtype=bool)
    inner[8:40] = True
    with pytest.raises(ValueError, match="stops short of the specimen's free edges"):
        _run(strain, std, LOADS, valid=inner, specimen=specimen)
    # a region that ends at a cross-section (the gripped side) is a region of the beam:
    # accepted, exact
    part = np.zeros((H, W), dtype=bool)
    part[:, :144] = True
    r = _run(strain, std, LOADS, valid=part, specimen=specimen)
    assert pytest.approx(E, rel=1e-3) == r.E  # the pixel sum's 3.6e-4, as above
    # a speck of invalid pixels inside costs its own area only: accepted
    speck = np.ones((H, W), dtype=bool)
    speck[20:23, 100:103] = False
    r = _run(strain, std, LOADS, valid=speck, specimen=specimen)
    assert pytest.approx(E, rel=3e-3) == r.E  # 9 of 9216 px left out: 1e-3


def test_a_ragged_cross_section_is_not_a_cut_free_edge():
    """The frame's border column valid in a few rows only (a record measured up to
    its edges): the region's gripped side is then ragged by a pixel. Its missing
    pixels face the cross-section, not a free edge: accepted, the sparse
    side columns left out, not refused as a region short of the free edges."""
    strain = np.stack([cantilever(f)[0] for f in LOADS])
    std = np.full_like(strain, 1e-7)
    specimen = np.ones((H, W), dtype=bool)
    part = np.zeros((H, W), dtype=bool)
    part[:, :144] = True
    part[:5, 144] = True  # the next column, in five rows only
    r = _run(strain, std, LOADS, valid=part, specimen=specimen)
    assert pytest.approx(E, rel=1e-3) == r.E  # the sparse column dropped: as above
    # free edges cut short are still refused, ragged side or not
    inner = part.copy()
    inner[:8] = inner[40:] = False
    with pytest.raises(ValueError, match="stops short of the specimen's free edges"):
        _run(strain, std, LOADS, valid=inner, specimen=specimen)


def test_argument_errors():
    strain = np.stack([cantilever(f)[0] for f in LOADS])
    std = np.full_like(strain, 1e-4)
    with pytest.raises(ValueError, match="loaded_edge must be one of"):
        _run(strain, std, LOADS, loaded_edge="middle")
    with pytest.raises(ValueError, match="load must hold 4 finite values"):
        _run(strain, std, LOADS[:3])
    with pytest.raises(ValueError, match="std must have strain's shape"):
        _run(strain, std[:, :2], LOADS)
    with pytest.raises(ValueError, match="thickness must be"):
        _run(strain, std, LOADS, thickness=-1.0)
    with pytest.raises(ValueError, match="elements must be"):
        _run(strain, std, LOADS, elements=(0, 4))
    with pytest.raises(ValueError, match="usable pixels"):
        _run(strain, np.zeros_like(std), LOADS)


@pytest.fixture(scope="module")
def beam_file(tmp_path_factory):
    """A result file whose maps are the cantilever's with noise: a small measured
    series (the numpy-only grid of ``independent_grid``, undeformed) with its strain,
    std and validity maps replaced by the beam's, saved with its pixel size, and a
    loads CSV."""
    from gridstrain import measure_series
    from independent_grid import camera, scene

    rng = np.random.default_rng(11)
    level = scene((H, W), pitch=5.0, angle=0.0, hole=False, light=False)[0]
    images = [camera(level, 0.28, 5.0, rng).astype(np.float64) for _ in range(5)]
    res = measure_series(images[0], images[1:], noise_model=(16 * 0.28, 256 * 5.0))
    # white noise, where the result's window says its noise is correlated over a few
    # sigma (5 px): the stated variance of the virtual work is then larger than this
    # noise's, which the command's plumbing does not mind; small enough to be identified
    s = 3e-5
    strain = np.stack([cantilever(f)[0] for f in LOADS])
    strain = strain + rng.normal(0.0, s, strain.shape)
    std = np.full((len(LOADS), H, W), s)
    valid = np.ones((len(LOADS), H, W), dtype=bool)
    # the file is written from each state's measurement: replaced there too
    ms = tuple(dataclasses.replace(m, strain=strain[i], valid=valid[i])
               for i, m in enumerate(res.measurements))
    res = dataclasses.replace(
        res, strain=strain, valid=valid, measurements=ms,
        uncertainty={**res.uncertainty, "exx_std": std, "eyy_std": std, "exy_std": std})
    d = tmp_path_factory.mktemp("beam")
    # lossless: the command must read back the very maps identified here
    path = res.save(d / "beam.h5", pixel_size=PIXEL, unit="mm", lossless=True)
    loads = d / "loads.csv"
    loads.write_text("state,load [N]\n" + "".join(
        f"{name},{float(f)!r}\n" for name, f in zip(res.names[1:], LOADS, strict=True)))
    return res, path, loads


def test_identify_result_and_command(beam_file, tmp_path, capsys):
    from gridstrain.cli import main

    res, path, loads = beam_file
    fit = identify(res, thickness=THICKNESS, loaded_edge="left", load_direction="y",
                   pixel_size=PIXEL, unit="mm", load=LOADS, load_unit="N")
    assert abs(fit.E - E) < 3 * fit.E_std
    assert abs(fit.nu - NU) < 3 * fit.nu_std
    stress = tmp_path / "stress.npz"
    args = ["identify", str(path), "--thickness", str(THICKNESS), "--loaded-edge", "left",
            "--load-direction", "y", "--loads", str(loads)]
    assert main([*args, "--json", "--stress-out", str(stress)]) == 0
    out = json.loads(capsys.readouterr().out)
    # the command reads the same maps, loads and pixel size: the same numbers
    assert out["E"] == pytest.approx(fit.E, rel=1e-9)
    assert out["nu"] == pytest.approx(fit.nu, rel=1e-9)
    assert out["E_unit"] == "MPa"
    assert out["E_interval"][0] < E < out["E_interval"][1]
    assert out["nu_interval"][0] < NU < out["nu_interval"][1]
    assert len(out["E_states"]) == len(LOADS)
    with np.load(stress) as z:
        assert z["sxx"].shape == (len(LOADS), H, W)
        assert str(z["unit"]) == "MPa"
        # sigma_xx of the heaviest state: the exact one to the noise's 1e-4 x Q11 ~ 8 MPa
        # per pixel (5 std: 40 MPa) against a 240 MPa peak
        np.testing.assert_allclose(z["sxx"][-1], cantilever(LOADS[-1])[1][0], atol=40.0)
    # a region: its own edges are the loaded and gripped ones (the beam's left 30 mm
    # is a cantilever too, loaded the same way)
    assert main([*args, "--json", "--region", "0", "0", "30", "10"]) == 0
    part = json.loads(capsys.readouterr().out)
    assert part["n_pixels"] == H * 144
    assert abs(part["E"] - E) < 3 * part["E_std"]
    # the text output
    assert main(args) == 0
    assert capsys.readouterr().out.startswith("E  = ")
    # errors: one line on stderr, exit 2, no traceback
    assert main(["identify", str(path), "--thickness", "2", "--loaded-edge", "left",
                 "--load-direction", "y"]) == 2
    err = capsys.readouterr().err
    assert "no loads" in err
    assert len(err.strip().splitlines()) == 1
    assert main([*args, "--load-direction", "x"]) == 2  # the beam's load is along y
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "error:" in err
    assert main([*args, "--stress-out", str(stress)]) == 2  # exists, no --overwrite
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_identify_uses_the_result_s_own_pixel_size(beam_file):
    res, _, _ = beam_file  # measured here: no pixel size of its own
    own = dataclasses.replace(res, pixel_size=PIXEL, unit="mm")
    kw = {"thickness": THICKNESS, "loaded_edge": "left", "load_direction": "y",
          "load": LOADS, "load_unit": "N"}
    given = identify(res, pixel_size=PIXEL, unit="mm", **kw)
    fit = identify(own, **kw)
    # the same lengths: the same E to the last digit, in MPa (N and mm)
    assert fit.E == given.E
    assert (fit.pixel_size, fit.unit, fit.stress_unit) == (PIXEL, "mm", "MPa")
    # another pixel size or unit: refused in one line naming both, before any work
    for ps, unit in ((PIXEL * 1.01, "mm"), (PIXEL / 1000, "m")):
        with pytest.raises(ValueError, match=rf"pixel_size={ps:g} {unit} disagrees with "
                                             rf"this result's own \({PIXEL:g} mm\)") as e:
            identify(own, pixel_size=ps, unit=unit, **kw)
        assert "\n" not in str(e.value)
        assert "px=True" not in str(e.value)  # identify names no place in px
    # a result without one, and none given: refused, saying how to give it
    with pytest.raises(ValueError, match="identify needs the pixel size, and this result "
                                         "carries none"):
        identify(res, **kw)


def test_region_in_px(beam_file, capsys):
    """``--px`` (and ``px=True``) name the region in px, by the rule of every command
    (gridstrain.post's places); the thickness and the moduli keep the file's mm."""
    from gridstrain.cli import main

    res, path, loads = beam_file
    kw = {"thickness": THICKNESS, "loaded_edge": "left", "load_direction": "y",
          "load": LOADS, "load_unit": "N"}
    mm = identify(res, region=(0, 0, 30, 10), pixel_size=PIXEL, unit="mm", **kw)
    px = identify(res, region=(0, 0, 144, 48), px=True, pixel_size=PIXEL, unit="mm", **kw)
    assert px.n_pixels == mm.n_pixels == H * 144
    assert px.E == mm.E  # the same pixels, the same lengths: the same modulus
    args = ["identify", str(path), "--thickness", str(THICKNESS), "--loaded-edge", "left",
            "--load-direction", "y", "--loads", str(loads), "--json"]
    assert main([*args, "--px", "--region", "0", "0", "144", "48"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_pixels"] == H * 144
    assert out["E"] == pytest.approx(mm.E, rel=1e-9)
    # a region past the field in px is refused in px, in one line
    assert main([*args, "--px", "--region", "0", "0", "300", "48"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "px" in err
    assert "outside" in err
