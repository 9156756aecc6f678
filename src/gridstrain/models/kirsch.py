"""Analytic field of an infinite elastic plate with a circular hole in tension (Kirsch).

The ground truth of ``gridstrain demo`` and of the end-to-end tests: an aluminium
plate with a hole, loaded by a remote uniaxial stress ``S`` along ``x``, linear
elastic and isotropic, plane stress. Coordinates follow
:mod:`gridstrain.conventions` (``x`` the column, ``y`` the row, both in px); the
field is symmetric about both axes through the hole's centre, so it reads the same
whether ``y`` points down the image or up.

With ``r, theta`` the polar coordinates about the centre (``theta`` from the
``x`` axis) and ``rho = a / r``:

Stresses (Kirsch, 1898)
    ``s_rr = S/2 (1 - rho^2) + S/2 (1 - 4 rho^2 + 3 rho^4) cos 2 theta``,
    ``s_tt = S/2 (1 + rho^2) - S/2 (1 + 3 rho^4) cos 2 theta``,
    ``s_rt = -S/2 (1 + 2 rho^2 - 3 rho^4) sin 2 theta``. The hoop stress at the
    hole's edge reaches ``3 S`` at ``theta = +-90 deg`` (stress concentration
    factor 3) and ``-S`` at ``theta = 0, 180 deg``; the edge is traction-free.

Displacements (plane stress)
    With the shear modulus ``mu = E / (2 (1 + nu))`` and ``kappa = (3 - nu) /
    (1 + nu)``:
    ``u_r = S / (4 mu) [r (kappa - 1) / 2 + a^2 / r + (r + (kappa + 1) a^2 / r -
    a^4 / r^3) cos 2 theta]``,
    ``u_t = -S / (4 mu) [r + (kappa - 1) a^2 / r + a^4 / r^3] sin 2 theta``.
    The centre of the hole does not move and the plate does not rotate. Far from
    the hole this is the uniform strain ``(S / E, -nu S / E)``.

Units: ``x``, ``y``, the radius and the centre in px give displacements in px;
``S`` and ``E`` in one unit (MPa by default) give dimensionless strains and
stresses in that unit.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_pair, check_choice, check_finite, check_positive, check_range

__all__ = [
    "ALUMINIUM_POISSON_RATIO",
    "ALUMINIUM_YOUNGS_MODULUS",
    "displacement",
    "strain",
    "stress",
]

#: Young's modulus of aluminium alloys, MPa (70 GPa).
ALUMINIUM_YOUNGS_MODULUS = 70e3
#: Poisson's ratio of aluminium alloys.
ALUMINIUM_POISSON_RATIO = 0.33


def _polar(x, y, radius, centre):
    a = check_positive(radius, "radius")
    cx, cy = (float(c) for c in as_pair(centre, "centre", unit="px"))
    X = np.asarray(x, dtype=np.float64) - cx
    Y = np.asarray(y, dtype=np.float64) - cy
    if X.shape != Y.shape:
        X, Y = np.broadcast_arrays(X, Y)
    r2 = X * X + Y * Y
    with np.errstate(invalid="ignore", divide="ignore"):
        # cos 2 theta and sin 2 theta without trigonometric calls; the centre itself
        # (r = 0) is inside the hole and gets NaN, replaced below when asked
        c2 = (X * X - Y * Y) / r2
        s2 = 2 * X * Y / r2
    return a, X, Y, r2, c2, s2


def _inside(inside: str) -> str:
    return check_choice(inside, "inside", ("nan", "extend"))


def stress(x, y, *, radius: float, remote_stress: float = 1.0,
           centre=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cartesian stresses ``(s_xx, s_yy, s_xy)`` of the plate with a hole.

    Parameters
    ----------
    x, y : array_like
        Positions, px (broadcast together).
    radius : float
        Hole radius ``a``, px.
    remote_stress : float
        Uniaxial stress ``S`` applied far away along ``x`` (negative: compression).
    centre : (float, float)
        Hole centre ``(x, y)``, px.

    Returns
    -------
    s_xx, s_yy, s_xy : ndarray
        In the unit of ``remote_stress``; NaN inside the hole (``r < a``).
    """
    S = check_finite(remote_stress, "remote_stress")
    a, _X, _Y, r2, c2, s2 = _polar(x, y, radius, centre)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        p2 = a * a / r2
        p4 = p2 * p2
        srr = S / 2 * (1 - p2) + S / 2 * (1 - 4 * p2 + 3 * p4) * c2
        stt = S / 2 * (1 + p2) - S / 2 * (1 + 3 * p4) * c2
        srt = -S / 2 * (1 + 2 * p2 - 3 * p4) * s2
        # rotation of the polar tensor to x, y: cos^2 = (1 + c2)/2, sin cos = s2/2
        mean, half = (srr + stt) / 2, (srr - stt) / 2
        sxx = mean + half * c2 - srt * s2
        syy = mean - half * c2 + srt * s2
        sxy = half * s2 + srt * c2
    out = r2 < a * a
    return tuple(np.where(out, np.nan, s) for s in (sxx, syy, sxy))


def strain(x, y, *, radius: float, remote_stress: float = 1.0,
           youngs_modulus: float = ALUMINIUM_YOUNGS_MODULUS,
           poisson_ratio: float = ALUMINIUM_POISSON_RATIO,
           centre=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Small strains ``(e_xx, e_yy, e_xy)`` of the plate with a hole (plane stress).

    Parameters
    ----------
    x, y, radius, remote_stress, centre
        As in :func:`stress`.
    youngs_modulus : float
        ``E``, in the unit of ``remote_stress`` (default: aluminium, 70 000 MPa).
    poisson_ratio : float
        ``nu``, in (-1, 0.5] (default: aluminium, 0.33).

    Returns
    -------
    e_xx, e_yy, e_xy : ndarray
        Dimensionless; ``e_xy`` is the tensor shear, half the engineering shear
        (:mod:`gridstrain.conventions`). NaN inside the hole.
    """
    E, nu = _elastic(youngs_modulus, poisson_ratio)
    sxx, syy, sxy = stress(x, y, radius=radius, remote_stress=remote_stress, centre=centre)
    return (sxx - nu * syy) / E, (syy - nu * sxx) / E, (1 + nu) / E * sxy


def _elastic(youngs_modulus, poisson_ratio) -> tuple[float, float]:
    E = check_positive(youngs_modulus, "youngs_modulus")
    nu = check_range(poisson_ratio, "poisson_ratio", -1.0, 0.5, include_low=False)
    return E, nu


def displacement(x, y, *, radius: float, remote_stress: float = 1.0,
                 youngs_modulus: float = ALUMINIUM_YOUNGS_MODULUS,
                 poisson_ratio: float = ALUMINIUM_POISSON_RATIO, centre=(0.0, 0.0),
                 inside: str = "nan") -> tuple[np.ndarray, np.ndarray]:
    """Displacement ``(u_x, u_y)`` of the plate with a hole (plane stress).

    Parameters
    ----------
    x, y, radius, remote_stress, youngs_modulus, poisson_ratio, centre
        As in :func:`strain`.
    inside : {"nan", "extend"}
        Inside the hole: NaN, or (``"extend"``) the edge value scaled by ``r / a``,
        a continuous field of small gradient with no physical meaning that lets an
        image generator solve ``x = X + u(X)`` across the hole's edge (the hole
        itself is then drawn without a grid).

    Returns
    -------
    u_x, u_y : ndarray
        In the unit of ``x`` (px).

    Examples
    --------
    >>> import numpy as np
    >>> ux, uy = displacement(np.array([1000.0]), np.array([0.0]), radius=10.0,
    ...                       remote_stress=70.0)
    >>> # far from the hole, S / E * x = 1e-3 * 1000 plus the hole's a^2 / r terms
    >>> round(float(ux[0]), 4)
    1.0003
    """
    S = check_finite(remote_stress, "remote_stress")
    E, nu = _elastic(youngs_modulus, poisson_ratio)
    _inside(inside)
    a, X, Y, r2, c2, s2 = _polar(x, y, radius, centre)
    hole = r2 < a * a
    if inside == "extend":
        # evaluate on the edge, along the same direction, then scale by r / a
        # the centre has no direction: any finite one will do, it is scaled by 0
        c2 = np.where(r2 > 0, c2, 1.0)
        s2 = np.where(r2 > 0, s2, 0.0)
        reval = np.where(hole, a, np.sqrt(r2))
    else:
        reval = np.sqrt(r2)
    mu = E / (2 * (1 + nu))
    kappa = (3 - nu) / (1 + nu)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        a2r = a * a / reval
        a4r3 = a2r * a2r / reval
        ur = S / (4 * mu) * (reval * (kappa - 1) / 2 + a2r
                             + (reval + (kappa + 1) * a2r - a4r3) * c2)
        ut = -S / (4 * mu) * (reval + (kappa - 1) * a2r + a4r3) * s2
        # cos theta, sin theta of the position
        cos_t = X / np.sqrt(r2)
        sin_t = Y / np.sqrt(r2)
        ux = ur * cos_t - ut * sin_t
        uy = ur * sin_t + ut * cos_t
    if inside == "extend":
        scale = np.where(hole, np.sqrt(r2) / a, 1.0)
        at_centre = r2 == 0
        ux = np.where(at_centre, 0.0, ux * scale)
        uy = np.where(at_centre, 0.0, uy * scale)
    else:
        ux = np.where(hole, np.nan, ux)
        uy = np.where(hole, np.nan, uy)
    return ux, uy
