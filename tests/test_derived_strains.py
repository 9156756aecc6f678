"""Principal, equivalent, maximum shear and finite strains (``gridstrain.kinematics``)
against closed forms, an eigen-decomposition, a matrix logarithm and Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.linalg import logm

from gridstrain.kinematics import finite_strains, principal_strains


def _tensor(e1, e2, theta):
    """The components of the tensor of principal strains ``e1``, ``e2``, ``e1`` along
    the direction at ``theta`` from +x towards +y (a rotation of diag(e1, e2))."""
    c, s = np.cos(theta), np.sin(theta)
    return (e1 * c**2 + e2 * s**2, e1 * s**2 + e2 * c**2, (e1 - e2) * s * c)


def test_a_uniform_tensor_gives_its_principal_strains_and_angle():
    e1, e2 = 1.2e-3, -4e-4
    theta = np.linspace(-1.5, 1.5, 13)  # rad, inside (-pi/2, pi/2)
    exx, eyy, exy = _tensor(e1, e2, theta)
    p = principal_strains(exx, eyy, exy)
    # float64 rounding of products of 1e-3 numbers: 1e-18 strain; 1e-15 left for sums
    assert_allclose(p.e1, e1, rtol=0, atol=1e-15)
    assert_allclose(p.e2, e2, rtol=0, atol=1e-15)
    # the angle to 1e-12 rad: atan2 of components known to 1e-19 relative to R = 8e-4
    assert_allclose(p.principal_angle, theta, rtol=0, atol=1e-12)
    assert_allclose(p.max_shear, (e1 - e2) / 2, rtol=0, atol=1e-15)
    assert_allclose(p.equivalent, 2 / np.sqrt(3) * np.sqrt(e1**2 + e1 * e2 + e2**2),
                    rtol=1e-12)
    assert p.e1_std is None
    assert p.e1.dtype == np.float64
    # uniaxial tension of an incompressible solid (e2 = -e1/2): the equivalent strain
    # is the axial strain, at any angle
    u = principal_strains(*_tensor(2e-3, -1e-3, 0.7))
    assert float(u.equivalent) == pytest.approx(2e-3, rel=1e-12)


def test_principal_strains_agree_with_an_eigen_decomposition():
    rng = np.random.default_rng(3)
    comps = rng.normal(scale=2e-3, size=(3, 200))
    p = principal_strains(*comps)
    tensors = np.stack([[comps[0], comps[2]], [comps[2], comps[1]]]).transpose(2, 0, 1)
    values, vectors = np.linalg.eigh(tensors)  # ascending
    # eigh works to the rounding of 2e-3 numbers: 1e-18, well below 1e-15 strain
    assert_allclose(p.e1, values[:, 1], rtol=0, atol=1e-15)
    assert_allclose(p.e2, values[:, 0], rtol=0, atol=1e-15)
    major = vectors[:, :, 1]
    # the angle's direction is e1's eigenvector (sign free): |cross product| = 0
    d = np.stack([np.cos(p.principal_angle), np.sin(p.principal_angle)], axis=1)
    assert_allclose(d[:, 0] * major[:, 1] - d[:, 1] * major[:, 0], 0, atol=1e-9)
    assert np.all((p.principal_angle > -np.pi / 2) & (p.principal_angle <= np.pi / 2))


def test_float32_stays_float32_and_nan_stays_nan():
    exx = np.array([[1e-3, np.nan]], dtype=np.float32)
    p = principal_strains(exx, exx, exx, exx_std=exx, eyy_std=exx, exy_std=exx)
    assert p.e1.dtype == np.float32
    assert p.e1_std.dtype == np.float32
    assert np.isnan(p.e1[0, 1])
    assert np.isnan(p.equivalent_std[0, 1])
    assert not p.e1.flags.writeable
    mixed = principal_strains(exx, exx.astype(np.float64), exx)
    assert mixed.e1.dtype == np.float64


def test_options_are_checked():
    with pytest.raises(ValueError, match="exx, eyy, exy must have one shape"):
        principal_strains(np.zeros(3), np.zeros(2), np.zeros(3))
    with pytest.raises(ValueError, match="all three or none, got exx_std"):
        principal_strains(0.0, 0.0, 0.0, exx_std=1.0)
    with pytest.raises(ValueError, match=r"correlation must be 3 coefficients in \[-1, 1\]"):
        principal_strains(0.0, 0.0, 0.0, correlation=(2.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="rotation must have the shape of exx"):
        finite_strains(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(2))


@pytest.mark.parametrize("correlation", [(0.0, 0.0, 0.0), (0.4, -0.3, 0.2)])
def test_first_order_std_agrees_with_monte_carlo(correlation):
    """Gaussian noise of the components, the std drawn from 400 000 samples."""
    rng = np.random.default_rng(11)
    mean = np.array(_tensor(9e-4, -3e-4, 0.35))  # R = 6e-4
    std = np.array([2e-5, 3e-5, 1.5e-5])  # R / std >= 20: first order holds
    r = correlation
    corr = np.array([[1, r[0], r[1]], [r[0], 1, r[2]], [r[1], r[2], 1]])
    n = 400_000
    draws = rng.multivariate_normal(mean, corr * np.outer(std, std), size=n).T
    mc = principal_strains(*draws)
    p = principal_strains(*mean, exx_std=std[0], eyy_std=std[1], exy_std=std[2],
                          correlation=correlation)
    for name in ("e1", "e2", "principal_angle", "equivalent", "max_shear"):
        # a sample std of n draws is within 1/sqrt(2n) = 0.11 % (1 sigma); the second
        # order terms first-order propagation leaves out are (std / R)^2 ~ 0.25 %: 1 %
        assert float(getattr(p, f"{name}_std")) == pytest.approx(
            float(np.std(getattr(mc, name))), rel=1e-2), name


def test_green_lagrange_of_a_simple_shear_and_a_rigid_rotation():
    gamma = np.array([0.01, 0.2, 1.0])
    # simple shear u_x = gamma y: du_x/dy = gamma, exy = gamma/2, omega = -gamma/2
    f = finite_strains(0 * gamma, 0 * gamma, gamma / 2, -gamma / 2)
    # E = (H + H^T + H^T H) / 2 with H = [[0, gamma], [0, 0]]: exact, to rounding
    assert_allclose(f.Exx, 0, atol=1e-15)
    assert_allclose(f.Eyy, gamma**2 / 2, rtol=1e-14)
    assert_allclose(f.Exy, gamma / 2, rtol=1e-14)
    # the principal log strains of a simple shear are +-asinh(gamma / 2)
    trace = f.Lxx + f.Lyy
    radius = np.hypot((f.Lxx - f.Lyy) / 2, f.Lxy)
    assert_allclose(trace, 0, atol=1e-14)
    assert_allclose(radius, np.arcsinh(gamma / 2), rtol=1e-12)
    # a rigid rotation by theta: H = R(theta) - I, exx = eyy = cos - 1, omega = sin
    theta = np.radians([1.0, 30.0, 90.0])
    r = finite_strains(np.cos(theta) - 1, np.cos(theta) - 1, 0 * theta, np.sin(theta))
    for name in ("Exx", "Eyy", "Exy", "Lxx", "Lyy", "Lxy"):
        # zero, to the rounding of cos^2 + sin^2 = 1: 1e-15
        assert_allclose(getattr(r, name), 0, atol=1e-15, err_msg=name)
    # while the small-strain tensor of the 30 degree rotation is -13 %
    assert np.cos(theta[1]) - 1 < -0.13


def test_log_strain_of_a_uniaxial_stretch_and_of_any_gradient():
    e = np.array([-0.3, -1e-3, 1e-6, 0.05, 1.0])
    f = finite_strains(e, 0 * e, 0 * e, 0 * e)
    assert_allclose(f.Lxx, np.log1p(e), rtol=1e-12)
    assert_allclose(f.Exx, e + e**2 / 2, rtol=1e-14)
    assert_allclose(f.Lyy, 0, atol=1e-15)
    # any gradient: ln(F^T F) / 2 by scipy's matrix logarithm (Schur-Pade)
    rng = np.random.default_rng(5)
    H = rng.normal(scale=0.2, size=(20, 2, 2))
    exy, w = (H[:, 0, 1] + H[:, 1, 0]) / 2, (H[:, 1, 0] - H[:, 0, 1]) / 2
    g = finite_strains(H[:, 0, 0], H[:, 1, 1], exy, w)
    for k in range(20):
        F = np.eye(2) + H[k]
        L = logm(F.T @ F).real / 2
        E = (F.T @ F - np.eye(2)) / 2
        # logm is accurate to ~1e-13 on these well-conditioned 2 x 2 matrices
        assert_allclose([g.Lxx[k], g.Lyy[k], g.Lxy[k]], [L[0, 0], L[1, 1], L[0, 1]],
                        atol=1e-12)
        assert_allclose([g.Exx[k], g.Eyy[k], g.Exy[k]], [E[0, 0], E[1, 1], E[0, 1]],
                        atol=1e-15)


@pytest.mark.parametrize("angle", [0.0, 20.0])
def test_std_maps_of_a_measured_field_match_its_scatter(angle):
    """The first-order std maps of e1, e2, the angle, the equivalent strain and the
    maximum shear, propagated from the measured exx, eyy, exy std maps with the
    components taken as uncorrelated, against the scatter of the derived maps of a
    homogeneous field (the paper's grid model, eq. 1, 128 x 128 px, pitch 5, two
    frames per state, sensor noise of ``synthetic.add_noise``; uniform strain
    exx = 2e-2, eyy = -6e-3, exy = 5e-3, so R = 1.4e-2 is 17 times the 8e-4 noise)."""
    from gridstrain import Lattice, measure_series
    from gridstrain.models import synthetic

    rng = np.random.default_rng(4)
    lat = Lattice.from_pitch(5.0, angle=angle)

    def frames(s):
        def disp(X, Y):
            return s * (2e-2 * (X - 64) + 1e-2 * (Y - 64)), s * (-6e-3 * (Y - 64))

        img = synthetic.grid_image((128, 128), lat, amplitude=1500.0,
                                   displacement=disp) + 200.0
        return np.array([synthetic.add_noise(img, rng=rng) for _ in range(2)])

    res = measure_series(frames(0.0), [frames(1.0)], lattice=lat)
    valid = np.asarray(res.valid[0])
    p = res.principal_strains(0)
    ratios = []
    for name in ("e1", "e2", "principal_angle", "equivalent", "max_shear"):
        values = getattr(p, name)[valid]
        predicted = np.sqrt(np.mean(getattr(p, f"{name}_std")[valid] ** 2))
        ratios.append(predicted / np.std(values))
    # the scatter over ~9000 pixels correlated over the window (sigma = 5 px) rests on
    # ~150 independent patches: 6 % on a std, so 3 x 6 % for each; measured 0.95 to
    # 1.14 (the components' noise correlations were |rho| <= 0.08, neglected here)
    assert np.all((np.array(ratios) > 0.8) & (np.array(ratios) < 1.2)), ratios


@pytest.mark.parametrize(("name", "grad"), [
    # (du_x/dx, du_x/dy, du_y/dx, du_y/dy)
    ("uniaxial stretch", (0.2, 0.0, 0.0, 0.0)),
    ("simple shear", (0.0, 0.5, 0.0, 0.0)),
    ("rigid rotation", (np.cos(0.6) - 1, -np.sin(0.6), np.sin(0.6), np.cos(0.6) - 1)),
    ("small strain", (1.5e-3, 2e-4, -3e-4, -4e-4)),
])
def test_finite_strain_std_agrees_with_monte_carlo(name, grad):
    """The first-order std of the Green–Lagrange and log strains, against the scatter
    of the exact finite strains of gradients drawn with the given (uncorrelated) std.
    The drawn std, 1e-4, is that of a measured gradient (the floor of the method's
    strain maps): the terms first order leaves out are (1e-4)^2, relatively 1e-4."""
    a, b, c, d = grad
    s = np.array([1e-4, 2e-4, 1.5e-4, 0.8e-4])
    exy, w = (b + c) / 2, (c - b) / 2
    f = finite_strains(a, d, exy, w, gradient_std=tuple(s))
    rng = np.random.default_rng(7)
    n = 200_000
    H = np.array(grad)[:, None] + s[:, None] * rng.standard_normal((4, n))
    mc = finite_strains(H[0], H[3], (H[1] + H[2]) / 2, (H[2] - H[1]) / 2)
    for comp in ("Exx", "Eyy", "Exy", "Lxx", "Lyy", "Lxy"):
        stated, seen = float(getattr(f, f"{comp}_std")), float(np.std(getattr(mc, comp)))
        # a sample std of 2e5 draws is within 1/sqrt(2n) = 0.16 % (1 sigma): 1 %
        assert stated == pytest.approx(seen, rel=1e-2), (name, comp)
    # the exact values of the named cases (the oracle: E = (H + H^T + H^T H) / 2)
    F = np.eye(2) + np.array([[a, b], [c, d]])
    E = (F.T @ F - np.eye(2)) / 2
    assert_allclose([f.Exx, f.Eyy, f.Exy], [E[0, 0], E[1, 1], E[0, 1]], atol=1e-15)
    if name == "rigid rotation":
        # no strain, whatever the angle, and its std is the gradient's turned
        assert_allclose([f.Exx, f.Eyy, f.Exy, f.Lxx, f.Lyy, f.Lxy], 0, atol=1e-15)
    if name == "uniaxial stretch":
        assert float(f.Lxx) == pytest.approx(np.log1p(0.2), rel=1e-14)
        # dLxx/dH_xx = 1 / (1 + e): the std of ln(1 + e) is s / (1 + e), exactly
        assert float(f.Lxx_std) == pytest.approx(1e-4 / 1.2, rel=1e-8)
        # dExx/dH_xx = 1 + e
        assert float(f.Exx_std) == pytest.approx(1e-4 * 1.2, rel=1e-14)


def test_finite_strain_std_is_checked():
    with pytest.raises(ValueError, match="gradient_std must be the 4 std"):
        finite_strains(0.0, 0.0, 0.0, 0.0, gradient_std=(1.0, 1.0))
    with pytest.raises(ValueError, match=r"gradient_std\[2\] must have the shape"):
        finite_strains(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3),
                       gradient_std=(np.ones(3), np.ones(3), np.ones(2), np.ones(3)))
    assert finite_strains(0.0, 0.0, 0.0, 0.0).Exx_std is None


def test_log_strain_std_agrees_with_central_differences():
    """The closed-form derivative of the log strain, against central differences of
    the log strain itself (written here), on random gradients up to 30 %, an equal
    biaxial stretch (C's eigenvalues equal) and no deformation at all."""
    rng = np.random.default_rng(9)
    H = np.concatenate([rng.normal(scale=0.1, size=(50, 4)),
                        [[0.01, 0.0, 0.0, 0.01], [0.0, 0.0, 0.0, 0.0],
                         [1e-7, 2e-8, -1e-8, 1.2e-7]]])
    s = np.array([1e-4, 2e-4, 1.5e-4, 0.8e-4])

    def logs(h):
        exy, w = (h[:, 1] + h[:, 2]) / 2, (h[:, 2] - h[:, 1]) / 2
        f = finite_strains(h[:, 0], h[:, 3], exy, w)
        return np.stack([f.Lxx, f.Lyy, f.Lxy])

    step = 1e-6  # truncation 1e-12, rounding 1e-10: far below the 1e-7 asked
    var = 0.0
    for k in range(4):
        d = np.zeros(4)
        d[k] = step
        var = var + ((logs(H + d) - logs(H - d)) / (2 * step) * s[k]) ** 2
    exy, w = (H[:, 1] + H[:, 2]) / 2, (H[:, 2] - H[:, 1]) / 2
    f = finite_strains(H[:, 0], H[:, 3], exy, w,
                       gradient_std=tuple(np.broadcast_to(v, len(H)) for v in s))
    got = np.stack([f.Lxx_std, f.Lyy_std, f.Lxy_std])
    assert np.all(np.isfinite(got))
    assert_allclose(got, np.sqrt(var), rtol=1e-7)
