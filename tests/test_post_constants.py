"""Young's modulus and Poisson's ratio of a generated tensile coupon (``gridstrain modulus``).

Twelve one-image load steps of an aluminium coupon (E = 70 GPa, nu = 0.33, 20 mm^2,
250 to 3000 N: up to 2140 µε), drawn by the numpy-only generator of
``tests/independent_grid.py`` (pitch-5.3 checkerboard, 12-bit Poisson-Gaussian
sensor stored x16), measured by ``gridstrain.measure_series``; the loads come from
a CSV file.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from gridstrain import measure_series
from gridstrain.cli import main
from gridstrain.post import elastic_constants, gauge, read_loads
from independent_grid import camera, scene

H, W = 192, 240
E, NU, AREA = 70e3, 0.33, 20.0  # MPa, -, mm^2
LOADS = np.linspace(250.0, 3000.0, 12)  # N
REGION = (40, 40, 200, 152)


def _levels(e):
    return scene((H, W), pitch=5.3, angle=0.0, hole=False, light=False,
                 displacement=lambda X, Y: (e * (X - W / 2), -NU * e * (Y - H / 2)))[0]


@pytest.fixture(scope="module")
def coupon(tmp_path_factory):
    d = tmp_path_factory.mktemp("coupon")
    rng = np.random.default_rng(1)
    images = [camera(_levels(e), 0.28, 5.0, rng).astype(np.float64)
              for e in (0.0, *(LOADS / AREA / E))]
    res = measure_series(images[0], images[1:], noise_model=(16 * 0.28, 256 * 5.0))
    path = d / "coupon.h5"
    res.save(path)
    loads = d / "loads.csv"
    loads.write_text("state,load [N],time [s]\n" + "".join(
        f"{name},{float(f)!r},{0.5 * (i + 1)!r}\n"
        for i, (name, f) in enumerate(zip(res.names[1:], LOADS, strict=True))))
    return res, path, loads


def test_coupon_gives_E_and_nu(coupon):
    res, _, loads = coupon
    load, unit, time = read_loads(loads, res.names)
    g = gauge(res, region=REGION, load=load, load_unit=unit, time=time)
    truth = LOADS / AREA / E
    # every row within 3 of its stated std of the truth (measured: at most 2.6, eyy)
    assert np.all(np.abs(g.exx - truth) < 3 * g.exx_std)
    assert np.all(np.abs(g.eyy + NU * truth) < 3 * g.eyy_std)
    assert np.all(np.abs(g.exy) < 3 * g.exy_std)
    c = elastic_constants(g, area=AREA)
    assert c.stress_unit == "MPa"
    # targets: E within 2 % with its interval holding the truth (measured 70148 MPa,
    # [69577, 70728]); nu within 0.01 (measured 0.3272, [0.3182, 0.3363])
    assert abs(c.E / E - 1) < 0.02
    assert c.E_ci[0] < E < c.E_ci[1]
    assert abs(c.nu - NU) < 0.01
    assert c.nu_ci[0] < NU < c.nu_ci[1]
    # the intervals are those of the stated std unless the scatter is larger
    assert (c.interval_basis == "residual scatter") == (max(c.reduced_chi2) > 1)


def test_interval_widens_with_the_scatter(coupon):
    # a non-linearity the noise cannot explain widens the interval (residual scatter)
    res, _, _ = coupon
    g = gauge(res, region=REGION, load=LOADS, load_unit="N")
    c0 = elastic_constants(g, area=AREA)
    bent = g.__class__(**{**g.__dict__, "exx": g.exx + 3e-4 * np.sin(np.arange(12.0))})
    c1 = elastic_constants(bent, area=AREA)
    assert c1.interval_basis == "residual scatter"
    assert c1.E_ci[1] - c1.E_ci[0] > 3 * (c0.E_ci[1] - c0.E_ci[0])


def test_modulus_command(coupon, tmp_path, capsys):
    _, path, loads = coupon
    plot = tmp_path / "ss.png"
    rc = main(["modulus", str(path), "--region", *map(str, REGION), "--area", str(AREA),
               "--loads", str(loads), "--json", "--plot", str(plot)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["E_unit"] == "MPa"
    assert out["E_ci"][0] < E < out["E_ci"][1]
    assert abs(out["nu"] - NU) < 0.01
    assert plot.stat().st_size > 0
    # a strain range fits the states inside it only
    rc = main(["modulus", str(path), "--region", *map(str, REGION), "--area", str(AREA),
               "--loads", str(loads), "--json", "--strain-range", "0", "1e-3"])
    assert rc == 0
    assert len(json.loads(capsys.readouterr().out)["states"]) == 5
    # printed in GPa, the unit a modulus of 70 000 MPa reads best in
    rc = main(["modulus", str(path), "--region", *map(str, REGION), "--area", str(AREA),
               "--loads", str(loads)])
    assert rc == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("E  = 70.")
    assert lines[1].endswith("] GPa")
    assert not any(line.startswith("note:") for line in lines)  # a metal's modulus
    # the same area in m2 given as mm2 (the default unit): E a million times too large,
    # printed with a note that names the area's unit, and in the JSON
    args = ["modulus", str(path), "--region", *map(str, REGION), "--area",
            str(AREA * 1e-6), "--loads", str(loads)]
    assert main(args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("E  = 7.0")
    assert "PPa" not in lines[1]
    assert lines[2].startswith("note: E = ")
    assert "--area-unit" in lines[2]
    assert main([*args, "--json"]) == 0
    assert "--area-unit" in json.loads(capsys.readouterr().out)["doubt"]
    # no loads: one line, exit 2
    assert main(["modulus", str(path), "--area", "20"]) == 2
    assert "no loads" in capsys.readouterr().err
    # a plot named without .png (a PNG under another name opens as nothing): refused
    for name in ("ss", "ss.pdf"):
        assert main(["modulus", str(path), "--region", *map(str, REGION), "--area",
                     str(AREA), "--loads", str(loads), "--plot", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert "--plot must name a .png file" in err
        assert not (tmp_path / name).exists()


def _reading(load, load_unit, axial):
    """A gauge that read exactly ``axial`` (and -0.3 of it across), std 1e-6."""
    n = len(load)
    one = np.full(n, 1e-6)
    zero = np.zeros(n)
    from gridstrain.post import GaugeReading

    return GaugeReading(states=tuple(f"s{i}" for i in range(n)), where="test",
                        n_pixels=np.ones(n, int), exx=axial, exx_std=one,
                        eyy=-0.3 * axial, eyy_std=one, exy=zero, exy_std=one, ux=zero,
                        ux_std=one, uy=zero, uy_std=one, load=np.asarray(load, float),
                        load_unit=load_unit)


@pytest.mark.parametrize(("load_unit", "area", "area_unit", "to_mpa", "shown"), [
    ("N", 20.0, "mm2", 1.0, "70 GPa"),
    ("N", 0.2, "cm2", 1e-2, "70 GPa"),       # was "10 kPa" as a unit
    ("kN", 0.2, "cm²", 10.0, "70 GPa"),
    ("N", 2e-5, "m2", 1e-6, "70 GPa"),
    ("kN", 20.0, "mm^2", 1e3, "70 GPa"),
])
def test_stress_in_mpa_and_modulus_in_gpa(load_unit, area, area_unit, to_mpa, shown):
    """70 GPa read by a noise-free gauge: the same E whatever units the load and the
    area come in; ``to_mpa`` is the stress in MPa of one load unit on one area unit."""
    load = np.linspace(100.0, 1000.0, 6)
    axial = load / area * to_mpa / E  # E = 70e3 MPa
    c = elastic_constants(_reading(load, load_unit, axial), area=area, area_unit=area_unit)
    assert c.stress_unit == "MPa"
    # exact data: the fit's rounding only, 1e-9 relative
    assert abs(c.E / E - 1) < 1e-9
    assert c.E_text().startswith(f"{shown}, 95 % interval [")
    assert c.E_text().endswith("] GPa")


@pytest.mark.parametrize(("load_unit", "area_unit", "stress_mpa", "doubt"), [
    ("N", "mm2", 70e3, False),     # aluminium
    ("N", "mm2", 1.2e6, False),    # diamond, the stiffest solid
    ("N", "mm2", 1e-3, False),     # a soft gel, 1 kPa
    ("N", "mm2", 70e9, True),      # an area in m2 given as mm2
    # aluminium's 70 GPa with an area in mm2 given as m2 reads 70 kPa, a soft solid's
    # modulus: the range cannot tell, nothing said
    ("N", "m2", 70e3, False),
    ("lbf", "in2", 1e7 / 145.0377, False),  # 10 Msi
    ("lbf", "in2", 1e13 / 145.0377, True),
    ("kgf", "mm2", 70e9, False),   # a unit of unknown scale: nothing said
])
def test_a_modulus_no_solid_has_is_doubted(load_unit, area_unit, stress_mpa, doubt):
    """E outside 100 Pa to 2 TPa is a unit's slip: ``unit_doubt`` says so, naming the
    area's unit; a modulus any solid may have, or a stress of unknown scale, is not
    doubted."""
    load = np.linspace(1.0, 10.0, 6)
    per = {"MPa": 1.0, "psi": 1 / 145.0377}
    c = elastic_constants(_reading(load, load_unit, load / 2.0 / (stress_mpa /
                                   per.get("psi" if load_unit == "lbf" else "MPa"))),
                          area=2.0, area_unit=area_unit)
    text = c.unit_doubt()
    assert (text is not None) == doubt
    if doubt:
        assert "--area-unit" in text
        assert text.startswith(f"E = {c.E_text(3).split(',')[0]}")


def test_soft_and_imperial_moduli_keep_a_sensible_unit():
    load = np.linspace(1.0, 10.0, 6)
    soft = elastic_constants(_reading(load, "N", load / 10.0 / 5.0), area=10.0)  # 5 MPa
    assert soft.E_text().startswith("5 MPa")
    # 10 Msi (aluminium): lbf on in2 stays psi
    imp = elastic_constants(_reading(load, "lbf", load / 0.5 / 1e7), area=0.5,
                            area_unit="in2")
    assert imp.stress_unit == "psi"
    assert imp.E_text().startswith("10 Msi")
    # units it does not know are written as they came, unscaled
    odd = elastic_constants(_reading(load, "kgf", load / 2.0 / 7e3), area=2.0)
    assert odd.stress_unit == "kgf/mm2"
    assert odd.E_text().startswith("7000 kgf/mm2")


def test_a_strain_range_in_microstrain_is_told_what_the_strains_are():
    """The tables print microstrain; --strain-range is dimensionless. A range that
    holds no state names the option and the span of the states' axial strains."""
    load = np.linspace(100.0, 1000.0, 6)
    axial = load / 20.0 / E  # 71 to 714 µε
    with pytest.raises(ValueError, match="a fit needs at least 3 states") as info:
        elastic_constants(_reading(load, "N", axial), area=20.0, strain_range=(100, 600))
    msg = str(info.value)
    assert "strain_range (--strain-range)" in msg
    assert "dimensionless" in msg
    assert f"{axial.min():.3g} to {axial.max():.3g}" in msg
