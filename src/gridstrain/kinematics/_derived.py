"""Quantities derived from the strain tensor: principal, equivalent and maximum shear
strains with their first-order standard deviations, and the finite (Green–Lagrange and
logarithmic) strains rebuilt from the displacement gradient.

Axes, signs and the tensor shear are those of :mod:`gridstrain.conventions`: ``x`` is
the column (to the right), ``y`` the row (downwards), ``eps_xy`` is half the
engineering shear and the rotation is ``omega = (du_y/dx - du_x/dy) / 2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_float_array, float_dtype, freeze_arrays

__all__ = ["FINITE_COMPONENTS", "FiniteStrains", "PrincipalStrains", "finite_strains",
           "principal_strains"]

#: The derived strains of :func:`principal_strains`, with their units.
DERIVED_STRAINS = {"e1": "1", "e2": "1", "principal_angle": "rad", "equivalent": "1",
                   "max_shear": "1"}


@dataclass(frozen=True)
class PrincipalStrains:
    """Principal, equivalent and maximum shear strains of a 2-D strain tensor.

    Every array has the shape of the components given (a map ``(H, W)``, a stack
    ``(n, H, W)`` or a gauge's ``(n,)``). The ``*_std`` fields are None when no std
    of the components was given.

    Attributes
    ----------
    e1, e2 : ndarray
        The major and minor in-plane principal strains, ``e1 >= e2``, dimensionless.
    principal_angle : ndarray
        The direction of ``e1``, rad, in ``(-pi/2, pi/2]``, from the ``+x`` axis
        towards ``+y`` (the image's rows go down: clockwise as the image is shown).
    equivalent : ndarray
        The von Mises equivalent strain of the incompressible tensor,
        ``(2 / sqrt(3)) sqrt(e1^2 + e1 e2 + e2^2)``, dimensionless.
    max_shear : ndarray
        The maximum in-plane tensor shear ``(e1 - e2) / 2`` (half the engineering
        shear ``gamma_max``), dimensionless.
    e1_std, e2_std, principal_angle_std, equivalent_std, max_shear_std : ndarray or None
        First-order standard deviations (see :func:`principal_strains`).
    """

    e1: np.ndarray
    e2: np.ndarray
    principal_angle: np.ndarray
    equivalent: np.ndarray
    max_shear: np.ndarray
    e1_std: np.ndarray | None = None
    e2_std: np.ndarray | None = None
    principal_angle_std: np.ndarray | None = None
    equivalent_std: np.ndarray | None = None
    max_shear_std: np.ndarray | None = None

    def __post_init__(self):
        freeze_arrays(self)


def _components(exx, eyy, exy, names=("exx", "eyy", "exy")):
    arrays = [as_float_array(a, n) for a, n in zip((exx, eyy, exy), names, strict=True)]
    shapes = {a.shape for a in arrays}
    if len(shapes) != 1:
        raise ValueError(f"{', '.join(names)} must have one shape, got "
                         f"{', '.join(str(a.shape) for a in arrays)}")
    # float32 stays float32 only when every component is (conventions: precision)
    dtype = np.result_type(*(float_dtype(a.dtype) for a in arrays))
    return [a.astype(np.float64, copy=False) for a in arrays], dtype


def principal_strains(exx, eyy, exy, *, exx_std=None, eyy_std=None, exy_std=None,
                      correlation=(0.0, 0.0, 0.0)) -> PrincipalStrains:
    """Principal strains, their direction, the equivalent strain and the maximum shear.

    Parameters
    ----------
    exx, eyy, exy : array_like, one shape
        The small-strain tensor's components (tensor shear), dimensionless: maps,
        stacks of maps or a gauge's readings. NaN stays NaN.
    exx_std, eyy_std, exy_std : array_like, optional
        Their standard deviations, same shape; all three or none.
    correlation : (float, float, float)
        The correlation coefficients of the components' noises at one point,
        ``(rho_xx_yy, rho_xx_xy, rho_yy_xy)``, each in [-1, 1]. Default 0: see Notes.

    Returns
    -------
    PrincipalStrains
        float32 when every component is float32, float64 otherwise.

    Notes
    -----
    With ``c = (exx + eyy) / 2``, ``d = (exx - eyy) / 2`` and
    ``R = sqrt(d^2 + exy^2)`` (Mohr's circle): ``e1 = c + R``, ``e2 = c - R``,
    ``max_shear = R``, ``principal_angle = atan2(exy, d) / 2`` and
    ``equivalent = (2 / sqrt(3)) sqrt(exx^2 + eyy^2 + exx eyy + exy^2)``, the von Mises
    strain of the tensor completed by ``eps_zz = -(exx + eyy)`` (incompressible, as
    the digital image correlation packages define it); it is invariant under a
    rotation of the axes.

    The std are propagated to first order, ``var(f) = J C J^T`` with ``J`` the
    gradient of ``f`` in ``(exx, eyy, exy)`` and ``C`` the components' covariance
    built from their std and ``correlation``. The default takes the components'
    noises as uncorrelated: for an axis-aligned grid, ``exx`` and ``eyy`` come from
    derivatives of the two phases along two axes, and the x and y derivatives of one
    windowed noise field are uncorrelated at the same point (the Gaussian window is
    even); a grid at an angle mixes them, and the correlation can then be given.
    First order holds while ``R`` (and, for the equivalent strain, its value) is
    large against the components' std: near an equal biaxial state (``R`` within a
    few std of 0) the principal strains' noise is not Gaussian, ``e1`` is biased
    upwards and the angle is undefined; where ``R = 0`` exactly, the std of
    ``e1``, ``e2``, ``max_shear`` and the angle are NaN.

    References
    ----------
    .. [1] Sutton, Orteu and Schreier, *Image Correlation for Shape, Motion and
       Deformation Measurements*, Springer, 2009, appendix C (strain measures).
       https://doi.org/10.1007/978-0-387-78747-3

    Examples
    --------
    Mohr's circle of centre 2e-4 and radius 5e-4:

    >>> p = principal_strains(5e-4, -1e-4, 4e-4)
    >>> [round(float(v), 10) for v in (p.e1, p.e2, p.max_shear)]
    [0.0007, -0.0003, 0.0005]
    >>> round(float(np.degrees(p.principal_angle)), 4)  # atan(4/3) / 2
    26.5651
    """
    (xx, yy, xy), dtype = _components(exx, eyy, exy)
    stds = (exx_std, eyy_std, exy_std)
    given = [s is not None for s in stds]
    if any(given) and not all(given):
        raise ValueError("exx_std, eyy_std, exy_std must be given all three or none, got "
                         + ", ".join(n for n, g in zip(("exx_std", "eyy_std", "exy_std"),
                                                       given, strict=True) if g))
    rho = as_float_array(correlation, "correlation", dtype=np.float64)
    if rho.shape != (3,) or not np.all(np.abs(rho) <= 1):
        raise ValueError(f"correlation must be 3 coefficients in [-1, 1] (rho_xx_yy, "
                         f"rho_xx_xy, rho_yy_xy), got {correlation!r}")
    c, d = (xx + yy) / 2, (xx - yy) / 2
    R = np.hypot(d, xy)
    q = xx**2 + yy**2 + xx * yy + xy**2
    out = {"e1": c + R, "e2": c - R, "principal_angle": np.arctan2(xy, d) / 2,
           "equivalent": 2 / np.sqrt(3) * np.sqrt(q), "max_shear": R}
    # atan2 gives (-pi, pi]: half of it is (-pi/2, pi/2], with -pi/2 turned to pi/2
    out["principal_angle"] = np.where(out["principal_angle"] <= -np.pi / 2, np.pi / 2,
                                      out["principal_angle"])
    if all(given):
        (sx, sy, ss), _ = _components(*stds, names=("exx_std", "eyy_std", "exy_std"))
        if sx.shape != xx.shape:
            raise ValueError(f"exx_std must have the shape of exx {xx.shape}, got "
                             f"{sx.shape}")
        cov = {(0, 0): sx * sx, (1, 1): sy * sy, (2, 2): ss * ss,
               (0, 1): rho[0] * sx * sy, (0, 2): rho[1] * sx * ss, (1, 2): rho[2] * sy * ss}
        with np.errstate(divide="ignore", invalid="ignore"):
            dR = (d / (2 * R), -d / (2 * R), xy / R)
            r3 = np.sqrt(3 * q)
            grads = {"e1": (0.5 + dR[0], 0.5 + dR[1], dR[2]),
                     "e2": (0.5 - dR[0], 0.5 - dR[1], -dR[2]),
                     "principal_angle": (-xy / (4 * R**2), xy / (4 * R**2), d / (2 * R**2)),
                     "equivalent": ((2 * xx + yy) / r3, (2 * yy + xx) / r3, 2 * xy / r3),
                     "max_shear": dR}
        for name, g in grads.items():
            var = sum((1 if i == j else 2) * g[i] * g[j] * cov[i, j] for i, j in cov)
            out[f"{name}_std"] = np.sqrt(np.maximum(var, 0.0))
    return PrincipalStrains(**{k: np.asarray(v, dtype=dtype) for k, v in out.items()})


@dataclass(frozen=True)
class FiniteStrains:
    """The Green–Lagrange and logarithmic (Hencky) strain tensors, in-plane.

    Attributes
    ----------
    Exx, Eyy, Exy : ndarray
        Green–Lagrange strain ``E = (F^T F - I) / 2``, dimensionless (tensor shear).
    Lxx, Lyy, Lxy : ndarray
        Lagrangian logarithmic strain ``ln U = ln(F^T F) / 2``, dimensionless.
    Exx_std, ..., Lxy_std : ndarray or None
        First-order standard deviations (see :func:`finite_strains`); None when no std
        of the gradient was given.
    """

    Exx: np.ndarray
    Eyy: np.ndarray
    Exy: np.ndarray
    Lxx: np.ndarray
    Lyy: np.ndarray
    Lxy: np.ndarray
    Exx_std: np.ndarray | None = None
    Eyy_std: np.ndarray | None = None
    Exy_std: np.ndarray | None = None
    Lxx_std: np.ndarray | None = None
    Lyy_std: np.ndarray | None = None
    Lxy_std: np.ndarray | None = None

    def __post_init__(self):
        freeze_arrays(self)


#: The finite strains' components, by :class:`FiniteStrains` field.
FINITE_COMPONENTS = ("Exx", "Eyy", "Exy", "Lxx", "Lyy", "Lxy")

# Below this t = 2 h / c, (t / (1 - t^2) - atanh t) / t^3 by its series 2/3 + 4 t^2 / 5
# + 6 t^4 / 7 (next term 8 t^6 / 9: 1e-12 relative), where the closed form cancels.
_SERIES_T = 1e-2


def _finite(xx, h01, h10, yy):
    """The six components from the gradient ``[[xx, h01], [h10, yy]]`` (float64)."""
    Exx = xx + (xx**2 + h10**2) / 2
    Eyy = yy + (h01**2 + yy**2) / 2
    Exy = (h01 + h10) / 2 + (xx * h01 + h10 * yy) / 2
    # C = I + 2 E: its eigenvalues 1 + 2 (m +- h), m and h E's centre and radius
    m, h = (Exx + Eyy) / 2, np.hypot((Exx - Eyy) / 2, Exy)
    c2 = 1 + 2 * (m - h)
    with np.errstate(divide="ignore", invalid="ignore"):
        f1, f2 = np.log1p(2 * (m + h)) / 2, np.log1p(2 * (m - h)) / 2
        # (f1 - f2) / (c1 - c2) = log1p((c1 - c2) / c2) / (2 (c1 - c2)): no cancellation,
        # and 1 / (2 c2) = f'(c) as h -> 0
        slope = np.where(h > 0, np.log1p(4 * h / c2) / (8 * h), 1 / (2 * c2))
    iso = (f1 + f2) / 2
    return (Exx, Eyy, Exy, iso + slope * 2 * (Exx - m), iso + slope * 2 * (Eyy - m),
            slope * 2 * Exy)


def _log_jacobian(Exx, Eyy, Exy) -> dict:
    """``d(Lxx, Lyy, Lxy) / d(Exx, Eyy, Exy)`` of :func:`_finite`'s closed form, as
    ``{L: {E: array}}``.

    With ``c = 1 + 2 m``, ``c1,2 = c +- 2 h`` (``C``'s eigenvalues), ``D = Exx - Eyy``
    and ``P = D dD / 4 + Exy dExy`` (``h dh``): ``iso = (ln c1 + ln c2) / 4`` and
    ``slope = atanh(t) / (4 h)``, ``t = 2 h / c``, so that ``d iso = (1/c1 + 1/c2) / 2
    dm - 2 P / (c1 c2)`` and ``d slope = -dm / (c1 c2) + (2 / c^3) Q P``, ``Q = (t / (1 -
    t^2) - atanh t) / t^3``: every term finite where ``h = 0`` (an equal biaxial
    state, no strain), ``Q`` by its series there.
    """
    m, D = (Exx + Eyy) / 2, Exx - Eyy
    h = np.hypot(D / 2, Exy)
    c = 1 + 2 * m
    c1, c2 = c + 2 * h, c - 2 * h
    t = 2 * h / c
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(h > 0, np.log1p(4 * h / c2) / (8 * h), 1 / (2 * c2))
        closed = (t / (1 - t * t) - np.arctanh(t)) / t**3
    t2 = t * t
    Q = np.where(np.abs(t) < _SERIES_T, 2 / 3 + t2 * (4 / 5 + t2 * 6 / 7), closed)
    inv12 = 1 / (c1 * c2)
    iso_m = (1 / c1 + 1 / c2) / 2
    slope_P = 2 * Q / c**3
    # per E component: dm, dD, dP, dExy
    parts = {"Exx": (0.5, 1.0, D / 4, 0.0), "Eyy": (0.5, -1.0, -D / 4, 0.0),
             "Exy": (0.0, 0.0, Exy, 1.0)}
    out = {"Lxx": {}, "Lyy": {}, "Lxy": {}}
    for e, (dm, dD, dP, dxy) in parts.items():
        d_iso = iso_m * dm - 2 * inv12 * dP
        d_slope = -inv12 * dm + slope_P * dP
        out["Lxx"][e] = d_iso + D * d_slope + slope * dD
        out["Lyy"][e] = d_iso - D * d_slope - slope * dD
        out["Lxy"][e] = 2 * Exy * d_slope + 2 * slope * dxy
    return out


def finite_strains(exx, eyy, exy, rotation, *, gradient_std=None) -> FiniteStrains:
    """Green–Lagrange and logarithmic strains from the small-strain tensor and rotation.

    Parameters
    ----------
    exx, eyy, exy : array_like, one shape
        The symmetric part of the Lagrangian displacement gradient (tensor shear),
        dimensionless, as :func:`gridstrain.kinematics.measure` gives it.
    rotation : array_like, same shape
        Its antisymmetric part ``omega = (du_y/dx - du_x/dy) / 2``, rad.
    gradient_std : 4 array_like of that shape, optional
        The standard deviations of ``du_x/dx``, ``du_x/dy``, ``du_y/dx``, ``du_y/dy``,
        their noises taken as uncorrelated: gives the ``*_std`` (see Notes).
        :meth:`gridstrain.results.SeriesResult.finite_strains` gives those of its
        uncertainty maps.

    Returns
    -------
    FiniteStrains
        float32 when every input is float32, float64 otherwise.

    Notes
    -----
    The gradient ``H = du/dX`` is rebuilt exactly from its symmetric and
    antisymmetric parts (:mod:`gridstrain.conventions`): ``du_x/dx = exx``,
    ``du_y/dy = eyy``, ``du_x/dy = exy - omega``, ``du_y/dx = exy + omega``. With
    ``F = I + H`` and ``C = F^T F``, ``E = (C - I) / 2 = (H + H^T + H^T H) / 2``;
    the logarithmic strain ``ln(C) / 2`` is computed from the eigenvalues
    ``c1, c2`` of the symmetric 2 x 2 ``C`` in closed form,
    ``f(C) = (f(c1) + f(c2)) / 2 I + (f(c1) - f(c2)) / (c1 - c2) (C - (c1 + c2) / 2 I)``,
    (``f = ln / 2``; logarithms by ``log1p``, the divided difference as
    ``log1p((c1 - c2) / c2) / (2 (c1 - c2))``, ``f'`` where ``c1 = c2``), accurate to
    the rounding of the strain however small it is. Both are Lagrangian (material axes):
    a rigid rotation, however large, gives zero; a uniaxial stretch ``1 + e`` gives ``e
    + e^2 / 2`` and ``ln(1 + e)``. Only in-plane components are given (the out-of-plane
    stretch is not measured). These are meaningful when the displacement was measured
    with the large-displacement correction (``lagrangian=True``).

    The std are propagated to first order from the gradient's, ``var(f) = sum_k
    (df/dH_k)^2 s_k^2``: in closed form for Green–Lagrange (``dExx = (1 + H_xx) dH_xx
    + H_yx dH_yx``...), and through it for the logarithmic strain, whose derivative in
    ``E`` is in closed form too (finite where ``C``'s two eigenvalues meet). First
    order holds while the std are small against 1 (always, for a strain measured to
    1e-4).

    Examples
    --------
    >>> f = finite_strains(0.1, 0.0, 0.0, 0.0)
    >>> round(float(f.Exx), 12), round(float(f.Lxx), 12)
    (0.105, 0.095310179804)
    """
    (xx, yy, xy), dtype = _components(exx, eyy, exy)
    w = as_float_array(rotation, "rotation")
    if w.shape != xx.shape:
        raise ValueError(f"rotation must have the shape of exx {xx.shape}, got {w.shape}")
    dtype = np.result_type(dtype, float_dtype(w.dtype))
    w = w.astype(np.float64, copy=False)
    h01, h10 = xy - w, xy + w
    grad = (xx, h01, h10, yy)
    values = _finite(*grad)
    out = dict(zip(FINITE_COMPONENTS, values, strict=True))
    if gradient_std is not None:
        if len(gradient_std) != 4:
            raise ValueError(f"gradient_std must be the 4 std of du_x/dx, du_x/dy, "
                             f"du_y/dx, du_y/dy, got {len(gradient_std)} value(s)")
        stds = []
        for k, sk in enumerate(gradient_std):
            a = as_float_array(sk, f"gradient_std[{k}]")
            if a.shape != xx.shape:
                raise ValueError(f"gradient_std[{k}] must have the shape of exx "
                                 f"{xx.shape}, got {a.shape}")
            dtype = np.result_type(dtype, float_dtype(a.dtype))
            stds.append(a.astype(np.float64, copy=False))
        xx_, h01_, h10_, yy_ = grad
        # Green–Lagrange: d(E) / d(H_xx, H_xy, H_yx, H_yy) in closed form
        jac = {"Exx": (1 + xx_, 0, h10_, 0), "Eyy": (0, h01_, 0, 1 + yy_),
               "Exy": (h01_ / 2, (1 + xx_) / 2, (1 + yy_) / 2, h10_ / 2)}
        for name in ("Exx", "Eyy", "Exy"):
            out[f"{name}_std"] = np.sqrt(sum(np.square(j * sk) for j, sk in
                                             zip(jac[name], stds, strict=True)))
        # the log strain: d(L) / d(E) (_log_jacobian) times d(E) / d(H)
        dL = _log_jacobian(out["Exx"], out["Eyy"], out["Exy"])
        for name in ("Lxx", "Lyy", "Lxy"):
            var = 0.0
            for k, sk in enumerate(stds):
                g = sum(dL[name][e] * jac[e][k] for e in ("Exx", "Eyy", "Exy"))
                var = var + np.square(g * sk)
            out[f"{name}_std"] = np.sqrt(var)
    return FiniteStrains(**{k: np.asarray(v, dtype=dtype) for k, v in out.items()})

