"""Tests of gridstrain.models.kirsch: the analytic plate with a hole against elasticity."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from gridstrain.models import kirsch

A = 40.0  # hole radius, px
S = 100.0  # remote stress, MPa
E, NU = kirsch.ALUMINIUM_YOUNGS_MODULUS, kirsch.ALUMINIUM_POISSON_RATIO
C = (191.5, 191.5)  # an off-origin centre, px


def _ring(rng, n, rmin, rmax):
    """Random points between two radii about C."""
    r = rng.uniform(rmin, rmax, n)
    t = rng.uniform(-np.pi, np.pi, n)
    return C[0] + r * np.cos(t), C[1] + r * np.sin(t)


def test_stress_concentration_factor_is_three():
    # hoop stress at the edge, theta = +-90 deg, is s_xx there: 3 S (Kirsch)
    x = np.array([C[0], C[0]])
    y = np.array([C[1] + A, C[1] - A])
    sxx, syy, sxy = kirsch.stress(x, y, radius=A, remote_stress=S, centre=C)
    assert_allclose(sxx, 3 * S, rtol=1e-12)  # rounding only
    assert_allclose(syy, 0.0, atol=1e-12 * S)
    assert_allclose(sxy, 0.0, atol=1e-12 * S)
    # at theta = 0 the hoop stress is s_yy = -S
    sxx, syy, _ = kirsch.stress(np.array([C[0] + A]), np.array([C[1]]), radius=A,
                                remote_stress=S, centre=C)
    assert_allclose(syy, -S, rtol=1e-12)
    assert_allclose(sxx, 0.0, atol=1e-12 * S)


def test_hole_edge_is_traction_free_and_far_field_is_uniaxial(rng):
    t = rng.uniform(-np.pi, np.pi, 200)
    # a hair outside the edge, so that rounding never puts a point inside the hole
    x, y = C[0] + A * (1 + 1e-12) * np.cos(t), C[1] + A * (1 + 1e-12) * np.sin(t)
    sxx, syy, sxy = kirsch.stress(x, y, radius=A, remote_stress=S, centre=C)
    # traction on the edge: sigma . n with the outward normal n = (cos, sin)
    tx = sxx * np.cos(t) + sxy * np.sin(t)
    ty = sxy * np.cos(t) + syy * np.sin(t)
    # 1e-12 a off the edge the traction is d s_rr/dr * 1e-12 a <= 4e-12 S
    assert_allclose(tx, 0.0, atol=1e-11 * S)
    assert_allclose(ty, 0.0, atol=1e-11 * S)
    # far away the perturbation decays as (a/r)^2: at r = 1e4 a it is 1e-8 S
    x, y = _ring(rng, 50, 1e4 * A, 2e4 * A)
    sxx, syy, sxy = kirsch.stress(x, y, radius=A, remote_stress=S, centre=C)
    assert_allclose(sxx, S, atol=2e-8 * S)
    assert_allclose(syy, 0.0, atol=2e-8 * S)
    assert_allclose(sxy, 0.0, atol=2e-8 * S)


def test_stress_is_in_equilibrium(rng):
    # div sigma = 0 by central differences of step h: truncation h^2/6 * d3 sigma,
    # about 1e-9 S/px at r >= 1.2 a with h = 1e-3 px; rounding S * 1e-16 / h
    x, y = _ring(rng, 300, 1.2 * A, 6 * A)
    h = 1e-3

    def s(dx, dy):
        return kirsch.stress(x + dx, y + dy, radius=A, remote_stress=S, centre=C)

    dsxx_dx = (s(h, 0)[0] - s(-h, 0)[0]) / (2 * h)
    dsxy_dy = (s(0, h)[2] - s(0, -h)[2]) / (2 * h)
    dsxy_dx = (s(h, 0)[2] - s(-h, 0)[2]) / (2 * h)
    dsyy_dy = (s(0, h)[1] - s(0, -h)[1]) / (2 * h)
    scale = S / A  # the stress gradients are of order S / a
    assert_allclose(dsxx_dx + dsxy_dy, 0.0, atol=1e-7 * scale)
    assert_allclose(dsxy_dx + dsyy_dy, 0.0, atol=1e-7 * scale)


def test_strain_is_the_gradient_of_the_displacement(rng):
    # strain-displacement consistency: central differences of u against strain();
    # with h = 1e-3 px the truncation error is ~1e-12 and rounding
    # |u| * 1e-16 / h ~ 1e-14, against strains of 1e-3
    x, y = _ring(rng, 400, 1.05 * A, 5 * A)
    h = 1e-3
    kw = {"radius": A, "remote_stress": S, "youngs_modulus": E, "poisson_ratio": NU,
          "centre": C}

    def u(dx, dy):
        return kirsch.displacement(x + dx, y + dy, **kw)

    dux_dx = (u(h, 0)[0] - u(-h, 0)[0]) / (2 * h)
    dux_dy = (u(0, h)[0] - u(0, -h)[0]) / (2 * h)
    duy_dx = (u(h, 0)[1] - u(-h, 0)[1]) / (2 * h)
    duy_dy = (u(0, h)[1] - u(0, -h)[1]) / (2 * h)
    exx, eyy, exy = kirsch.strain(x, y, **dict(kw.items()))
    assert_allclose(dux_dx, exx, atol=1e-10)
    assert_allclose(duy_dy, eyy, atol=1e-10)
    assert_allclose(0.5 * (dux_dy + duy_dx), exy, atol=1e-10)


def test_far_field_and_symmetry(rng):
    # far from the hole: uniform strain (S/E, -nu S/E) about the fixed centre
    x, y = _ring(rng, 50, 1e4 * A, 2e4 * A)
    ux, uy = kirsch.displacement(x, y, radius=A, remote_stress=S, centre=C)
    r = np.hypot(x - C[0], y - C[1])
    # the perturbation of u decays as a^2 / r: 1e-4 * a * S/E relative to S/E * r
    assert_allclose(ux, S / E * (x - C[0]), atol=1e-3 * A * S / E)
    assert_allclose(uy, -NU * S / E * (y - C[1]), atol=1e-3 * A * S / E)
    assert np.all(r > 1e4 * A)
    # mirror symmetry about the hole's axes: u_x odd in x, even in y
    x, y = _ring(rng, 50, A, 4 * A)
    ux, uy = kirsch.displacement(x, y, radius=A, remote_stress=S, centre=C)
    mx, my = kirsch.displacement(2 * C[0] - x, y, radius=A, remote_stress=S, centre=C)
    assert_allclose(mx, -ux, atol=1e-12)
    assert_allclose(my, uy, atol=1e-12)


def test_inside_the_hole():
    x = np.array([C[0], C[0] + 0.5 * A, C[0] + A, C[0] + A + 1e-9])
    y = np.full(4, C[1])
    ux, _uy = kirsch.displacement(x, y, radius=A, remote_stress=S, centre=C)
    assert np.isnan(ux[:2]).all()
    assert np.isfinite(ux[2:]).all()
    ex, ey = kirsch.displacement(x, y, radius=A, remote_stress=S, centre=C, inside="extend")
    assert np.isfinite(ex).all()
    assert np.isfinite(ey).all()
    assert ex[0] == 0.0
    assert ey[0] == 0.0
    assert_allclose(ex[1], 0.5 * ex[2], rtol=1e-12)  # scaled by r / a
    assert_allclose(ex[2], ex[3], rtol=1e-8)  # continuous across the edge
    exx, _, _ = kirsch.strain(x, y, radius=A, remote_stress=S, centre=C)
    assert np.isnan(exx[:2]).all()


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"radius": -1.0}, "radius"),
    ({"radius": 10.0, "poisson_ratio": 0.7}, "poisson_ratio"),
    ({"radius": 10.0, "youngs_modulus": 0.0}, "youngs_modulus"),
    ({"radius": 10.0, "inside": "zero"}, "inside"),
    ({"radius": 10.0, "centre": (1.0,)}, "centre"),
    ({"radius": 10.0, "remote_stress": float("nan")}, "remote_stress"),
])
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        kirsch.displacement(np.zeros(2), np.zeros(2), **kwargs)
