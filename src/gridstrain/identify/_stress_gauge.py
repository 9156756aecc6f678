"""The stress gauge of an image-based inertial impact (IBII) test.

A bar is struck on one end; the other end is free. Across a section at a distance
``d`` from the free edge, the axial resultant is the only force on the slab between
the section and the free edge, so that the slab's momentum balance gives the mean
axial stress over the section from the slab's mean acceleration (Pierron and Forquin
2012)::

    sigma(d, t) = s rho d a(d, t),      a(d, t) = (1 / d) int_0^d a_col(x', t) dx'

with ``a_col`` the mean axial acceleration of a cross-section, ``rho`` the density
and ``s`` the sign of the free edge: ``+1`` for a free edge on the left (top), the
slab lying towards ``-x`` (``-y``) of the section, ``-1`` for a free edge on the right
(bottom). The sign follows the usual convention: tension positive. The accelerations
are the second time derivative of the measured displacements; with the mean axial
strain of the same section, each section gives a stress-strain curve, and their slope
Young's modulus at the test's strain rate.

Coordinates follow :mod:`gridstrain.conventions`: x the column, y the row, pixel ``j``
centred on ``x = j`` and spanning ``[j - 1/2, j + 1/2]``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.signal import savgol_filter

from .._validation import check_choice, check_int, check_positive, freeze_arrays

#: Free edges and, for each, (axial axis, sign of the stress: +1 when the slab
#: between the free edge and a section lies towards -x or -y of it).
FREE_EDGES = {"left": ("x", 1.0), "right": ("x", -1.0), "top": ("y", 1.0),
              "bottom": ("y", -1.0)}

#: Metres per length unit, for the stress in Pa from lengths in the result's unit.
METRES = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6,
          "in": 0.0254}

#: Two-sided coverage of the interval on E.
LEVEL = 0.95

#: Largest departure of a time step from the mean step, relative (as for
#: :func:`gridstrain.post.history`: the filter assumes evenly spaced samples).
_UNIFORM = 1e-3


@dataclass(frozen=True)
class StressGauge:
    """Stress, strain and strain rate of every cross-section of an impact record.

    Every map is ``(n_states, n_sections)``; sections are ordered from the free
    edge inwards.

    Attributes
    ----------
    time : (n_states,) ndarray
        s.
    distance : (n_sections,) ndarray
        Distance of each section from the free edge, ``unit``.
    index : (n_sections,) int ndarray
        The column (free edge left or right) or row (top or bottom) of each section.
    stress, stress_std : ndarray
        Mean axial stress over the section, ``s rho d a``, MPa (tension positive),
        and its std from the displacement noise.
    acceleration, acceleration_std : ndarray
        Mean axial acceleration of the slab between the free edge and the section,
        m/s^2, along the axis pointing from the free edge into the specimen.
    strain, strain_std : ndarray
        Mean axial strain over the section's valid pixels, dimensionless.
    strain_rate, strain_rate_std : ndarray
        Its time derivative (the same filter), 1/s.
    strip_stress : ndarray
        The part of ``stress`` that comes from the strip between the free edge and
        the first measured section, extrapolated (see :func:`stress_gauge`), MPa.
    fitted : (n_states, n_sections) bool ndarray
        The points the modulus was fitted on.
    E, E_std : float
        Young's modulus, MPa, and its std from the noise.
    E_interval : (float, float)
        Its 95 % interval, MPa.
    interval_basis : {"stated std", "residual scatter"}
        What set the interval's width (see :func:`stress_gauge`).
    residual_rms : float
        RMS of ``stress - E strain - intercept`` over the fitted points, MPa.
    strain_rate_range : (float, float)
        Smallest and largest ``|strain_rate|`` over the fitted points, 1/s.
    window, order : int
        The Savitzky-Golay filter over time: a polynomial of degree ``order`` fitted
        to ``window`` consecutive states.
    bias_coefficient : float
        s^2: the acceleration's bias is ``bias_coefficient`` times the fourth time
        derivative of the displacement (its leading term; exact for a quartic).
    strip_width : float
        Width of the strip without data between the free edge and the first
        section's pixel, ``unit``.
    density : float
        kg/m^3.
    free_edge : {"left", "right", "top", "bottom"}
    unit : str
        Length unit of ``distance`` and ``strip_width``.
    """

    time: np.ndarray
    distance: np.ndarray
    index: np.ndarray
    stress: np.ndarray
    stress_std: np.ndarray
    acceleration: np.ndarray
    acceleration_std: np.ndarray
    strain: np.ndarray
    strain_std: np.ndarray
    strain_rate: np.ndarray
    strain_rate_std: np.ndarray
    strip_stress: np.ndarray
    fitted: np.ndarray
    E: float
    E_std: float
    E_interval: tuple[float, float]
    interval_basis: str
    residual_rms: float
    strain_rate_range: tuple[float, float]
    window: int
    order: int
    bias_coefficient: float
    strip_width: float
    density: float
    free_edge: str
    unit: str

    def __post_init__(self):
        freeze_arrays(self)

    def to_dict(self) -> dict:
        """The modulus, its interval and the test's conditions, JSON-ready."""
        return {"E": self.E, "E_interval": list(self.E_interval), "E_std": self.E_std,
                "E_unit": "MPa", "level": LEVEL, "interval_basis": self.interval_basis,
                "residual_rms_MPa": self.residual_rms,
                "strain_rate_range": list(self.strain_rate_range),
                "strain_rate_unit": "1/s", "points_fitted": int(self.fitted.sum()),
                "sections": int(self.distance.size), "states": int(self.time.size),
                "free_edge": self.free_edge, "density_kg_m3": self.density,
                "window": self.window, "order": self.order,
                "acceleration_bias_coefficient_s2": self.bias_coefficient,
                "strip_width": self.strip_width, "unit": self.unit,
                "strip_stress_max_MPa": float(np.max(np.abs(self.strip_stress))),
                "peak_stress_MPa": float(np.max(np.abs(self.stress)))}

    def curves(self) -> dict[str, np.ndarray]:
        """The stress-strain curves as a long table: one row per state and section."""
        T, S = self.stress.shape
        return {"time [s]": np.repeat(self.time, S),
                f"distance [{self.unit}]": np.tile(self.distance, T),
                "stress [MPa]": self.stress.ravel(),
                "stress_std [MPa]": self.stress_std.ravel(),
                "strain [-]": self.strain.ravel(),
                "strain_std [-]": self.strain_std.ravel(),
                "strain_rate [1/s]": self.strain_rate.ravel(),
                "acceleration [m/s2]": self.acceleration.ravel(),
                "strip_stress [MPa]": self.strip_stress.ravel(),
                "fitted": self.fitted.ravel()}

    def plot(self, *, sections: int = 6):
        """Stress against strain for ``sections`` sections spread from the free edge
        inwards, the points fitted marked, and the line of slope E.

        Returns
        -------
        matplotlib.figure.Figure
        """
        from matplotlib.figure import Figure

        sections = check_int(sections, "sections", minimum=1)
        fig = Figure(figsize=(6.4, 4.4))
        ax = fig.add_subplot()
        picks = np.unique(np.linspace(0, self.distance.size - 1, sections).astype(int))
        for j in picks:
            line, = ax.plot(self.strain[:, j] * 1e6, self.stress[:, j], lw=1,
                            label=f"d = {self.distance[j]:.3g} {self.unit}")
            f = self.fitted[:, j]
            ax.plot(self.strain[f, j] * 1e6, self.stress[f, j], ".", ms=3,
                    color=line.get_color())
        e = np.linspace(np.min(self.strain), np.max(self.strain), 2)
        ax.plot(e * 1e6, self.E * e, "k--", lw=1, label="slope E")
        lo, hi = self.E_interval
        ax.set_xlabel("mean axial strain (µε)")
        ax.set_ylabel("mean axial stress (MPa)")
        ax.set_title(f"E = {self.E:.5g} MPa [{lo:.5g}, {hi:.5g}] (95 %); dots: fitted",
                     fontsize=9)
        ax.legend(fontsize=7)
        fig.tight_layout()
        return fig

    def __repr__(self) -> str:
        lo, hi = self.E_interval
        return (f"StressGauge(E={self.E:.5g} MPa [{lo:.5g}, {hi:.5g}], "
                f"{self.time.size} states x {self.distance.size} sections, free edge "
                f"{self.free_edge})")


def _maps(value, name: str, shape=None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a numeric array, got {type(value).__name__}") \
            from None
    if arr.ndim != 3 or (shape is not None and arr.shape != shape):
        want = "(n_states, H, W)" if shape is None else str(shape)
        raise ValueError(f"{name} must be a {want} array, got shape {arr.shape}")
    return arr


def _canonical(arr: np.ndarray, axis: str, sign: float) -> np.ndarray:
    """``(T, H, W)`` turned so that the axial axis is the last and the free edge at 0."""
    if axis == "y":
        arr = np.swapaxes(arr, 1, 2)
    return arr[..., ::-1] if sign < 0 else arr


def displacement_correlation(sigma: float | None, d: np.ndarray) -> np.ndarray:
    """Correlation of the displacement noise of two pixels ``d`` px apart along an axis.

    ``exp(-d^2 / (4 sigma^2))``: the autocorrelation of the Gaussian window of
    standard deviation ``sigma`` (:mod:`gridstrain.post`'s gauges use the same law);
    independent pixels (the identity) when ``sigma`` is None.
    """
    d = np.asarray(d, dtype=np.float64)
    if sigma is None:
        return (d == 0).astype(np.float64)
    return np.exp(-d * d / (4.0 * sigma * sigma))


def strain_correlation(sigma: float | None, d: np.ndarray) -> np.ndarray:
    """Correlation of the axial strain noise of two pixels ``d`` px apart along the
    axis: ``exp(-d^2 / (4 sigma^2)) (1 - d^2 / (2 sigma^2))``, the derivative kernel's
    autocorrelation (a grid aligned with the axes); the identity without ``sigma``."""
    d = np.asarray(d, dtype=np.float64)
    if sigma is None:
        return (d == 0).astype(np.float64)
    return np.exp(-d * d / (4.0 * sigma * sigma)) * (1.0 - d * d / (2.0 * sigma * sigma))


def _section_means(values, std, valid, sigma):
    """Per state and column, the mean over the valid rows and its std.

    The rows' noises are correlated by :func:`displacement_correlation` (across the
    axis, the window's Gaussian for a displacement and for the axial strain alike):
    ``Var = s^T R s / n^2`` with ``s`` the column's std, zero where not valid.
    """
    n = valid.sum(axis=1)
    total = np.where(valid, values, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / n
    if std is None:
        return mean, None
    s = np.where(valid, std, 0.0)
    if sigma is None:
        var = np.sum(s * s, axis=1)
    else:
        rows = np.arange(values.shape[1])
        R = displacement_correlation(sigma, rows[:, None] - rows[None, :])
        var = np.einsum("tik,tik->tk", s, np.einsum("ij,tjk->tik", R, s))
    with np.errstate(invalid="ignore", divide="ignore"):
        return mean, np.sqrt(var) / n


def savgol_operator(n: int, *, window: int, order: int, deriv: int, delta: float):
    """The ``(n, n)`` matrix of the Savitzky-Golay filter (mode "interp"): output ``i``
    is ``sum_j A[i, j] x_j``, as :func:`scipy.signal.savgol_filter` computes it."""
    return savgol_filter(np.eye(n), window, order, deriv=deriv, delta=delta, axis=0,
                         mode="interp")


def acceleration_bias_coefficient(*, window: int, order: int, delta: float) -> float:
    """``b`` (s^2) such that the filtered second derivative of ``x(t)`` is ``x''(t) +
    b x''''(t)`` to leading order (away from the record's ends).

    The centre weights ``w_k`` of the second derivative reproduce every polynomial
    of degree up to ``order`` (3 at least: the weights are even, so orders 2 and 3
    coincide); the quartic term ``x'''' (k delta)^4 / 24`` gives
    ``b = sum_k w_k (k delta)^4 / 24``, zero from order 4 on (the bias then starts
    at the sixth derivative).
    """
    w = savgol_filter(np.eye(window), window, order, deriv=2, delta=delta, axis=0,
                      mode="interp")[window // 2]
    k = (np.arange(window) - window // 2) * delta
    return float(np.sum(w * k**4) / 24.0)


def _strip_weights(first: float, centres: np.ndarray, n_fit: int) -> tuple[np.ndarray,
                                                                             float]:
    """Weights on the first ``n_fit`` sections' accelerations whose sum is the integral
    over ``[0, first]`` of the straight line fitted to them (least squares), px."""
    if first <= 0:
        return np.zeros(n_fit), 0.0
    X = np.stack([np.ones(n_fit), centres[:n_fit]], axis=1)
    pinv = np.linalg.pinv(X)  # (2, n_fit): intercept and slope from the accelerations
    # int_0^first (c0 + c1 x) dx = first c0 + first^2 / 2 c1
    return first * pinv[0] + first**2 / 2.0 * pinv[1], first


def _region_operator(centres: np.ndarray, first: float, n_fit: int) -> np.ndarray:
    """``M (S, S)``: the integral of the axial acceleration from the free edge (x = 0)
    to the centre of section ``j`` is ``sum_k M[j, k] a_k``, px.

    Sections are 1 px wide and contiguous from ``first`` (the first one's near side):
    whole sections before ``j`` and half of ``j`` (the midpoint rule), and the strip
    ``[0, first]`` from the straight line fitted to the first ``n_fit`` sections.
    """
    S = centres.size
    M = np.tril(np.ones((S, S)), -1) + 0.5 * np.eye(S)
    w, _ = _strip_weights(first, centres, n_fit)
    M[:, :n_fit] += w[None, :]
    return M


def _quad_diag(M: np.ndarray, S: np.ndarray, R: np.ndarray | None) -> np.ndarray:
    """``diag((M S) R (M S)^T)`` for each row of ``S`` (``(T, K)`` stds); ``R`` None
    for the identity."""
    if R is None:
        return (S**2) @ (M**2).T
    T, K = S.shape
    B = (M[None, :, :] * S[:, None, :]).reshape(-1, K)  # (T S, K): one product
    return np.einsum("ik,ik->i", B, B @ R).reshape(T, -1)


def stress_gauge(displacement, strain, time, *, density: float, free_edge: str,
                 pixel_size: float, unit: str = "mm", valid=None, displacement_std=None,
                 strain_std=None, reference_share=None, sigma: float | None = None,
                 edge: float | None = None, window: int = 9, order: int = 4,
                 strip_fit: int | None = None, strain_floor: float = 0.1,
                 fit_from: float = 0.0) -> StressGauge:
    """Mean axial stress over every cross-section of an impact record, and E.

    Parameters
    ----------
    displacement : (n_states, H, W) array_like
        The axial displacement of each state, px: ``u_x`` for a free edge on the
        left or right, ``u_y`` for one on the top or bottom. Lagrangian, against a
        reference taken before the impact.
    strain : (n_states, H, W) array_like
        The axial strain (``e_xx`` or ``e_yy``), dimensionless.
    time : (n_states,) array_like
        s, evenly spaced (within 0.1 % of the mean step).
    density : float
        kg/m^3.
    free_edge : {"left", "right", "top", "bottom"}
        The specimen's free edge, opposite the impact.
    pixel_size : float
        Size of a pixel in ``unit``.
    unit : str
        Length unit: one of :data:`METRES` ("mm" by default).
    valid : (n_states, H, W) or (H, W) bool array_like, optional
        Pixels measured (default: every finite pixel of both maps).
    displacement_std, strain_std : (n_states, H, W) array_like, optional
        Per-pixel std of the maps (px and dimensionless). Without them, the stds and
        E's interval come from the residual scatter only.
    reference_share : (n_states,) array_like, optional
        Part of each state's variance that the reference image gives, common to every
        state (:attr:`gridstrain.post.GaugeReading.reference_share`); it cancels in
        the time derivatives. Default: none (independent states).
    sigma : float, optional
        Std of the measurement's Gaussian window, px: neighbouring pixels' noises are
        correlated through it (:func:`displacement_correlation`). Default:
        independent pixels.
    edge : float, optional
        Position of the free edge along the axis, px (a column's ``x`` or a row's
        ``y``; a pixel ``j`` spans ``[j - 1/2, j + 1/2]``). Default: the image's
        border on that side (``-1/2`` or ``W - 1/2``).
    window, order : int
        Savitzky-Golay filter over time: a polynomial of degree ``order`` (2 to
        ``window - 1``) fitted to ``window`` (odd) consecutive states.
    strip_fit : int, optional
        Sections whose accelerations the straight line extrapolated over the strip
        without data is fitted on (default: twice the strip's width in px, at least
        4).
    strain_floor : float
        The modulus is fitted on the points whose ``|strain|`` is at least this
        fraction of the largest (0 keeps them all), away from the record's first and
        last ``window // 2`` states (where the filter extrapolates).
    fit_from : float
        The sections nearer than this, px, to the free edge or to the far end of the
        sections used enter the slab's integral but not E's fit: maps measured up to
        the edges
        (:func:`gridstrain.phase.transform_to_edges`) carry there a strain bias of
        order ``sigma^2 eps''`` that the stress, an integral of accelerations, does
        not share (default 0: every section).

    Returns
    -------
    StressGauge

    Raises
    ------
    ValueError, TypeError
        Maps of different shapes, uneven times, no section measured in every state,
        a free edge not named, a unit not in :data:`METRES`.

    Notes
    -----
    Assumptions: one-dimensional uniaxial stress along the axis (the section's mean
    stress only: a thin specimen in plane stress, no transverse resultant), small
    strains, linear elasticity for the modulus; the strain rate reported says at
    which rate it holds. The density is the user's and enters the stress linearly.

    The steps, all linear in the maps:

    1. each section (a column, or a row) gives the mean of the axial displacement and
       strain over its valid pixels; a section is measured when it has a valid pixel
       in every state, and the sections used run contiguously from the one nearest
       the free edge;
    2. the accelerations are the Savitzky-Golay second derivative of the mean
       displacements over time (:func:`scipy.signal.savgol_filter`, mode "interp"):
       exact for a polynomial of degree ``order`` in time, biased by
       ``bias_coefficient x''''`` beyond (:func:`acceleration_bias_coefficient`), the
       strain rate its first derivative;
    3. the slab's integral of the acceleration from the free edge to a section's
       centre is the sum of the sections' (the midpoint rule, error ``a'' h^2 / 24``
       per px), plus the strip between the free edge and the first measured section
       (the grid method's margin), where there is no data: the straight line fitted
       to the first ``strip_fit`` sections' accelerations is integrated over it. A
       profile of curvature ``a''`` over the strip (width ``g``) and the fit (length
       ``l``) is missed by ``a'' (g^3 / 3 + l g^2 / 2 + l^2 g / 6) / 2`` (the line
       fitted to a parabola, extrapolated), times ``rho`` in the stress: a bias the
       std does not hold. ``strip_stress`` is the extrapolated part of the stress, to
       compare with the stress itself; E does not depend on it (below);
    4. ``sigma = s rho int a``, in MPa with the lengths converted to metres.

    The std of every output is propagated exactly through these linear operators
    from the per-pixel stds: rows of a section correlated by
    :func:`displacement_correlation`, sections by the same law (the displacement) or
    :func:`strain_correlation` (the strain), states independent but for the
    reference's share, which is common to all of them (as
    :func:`gridstrain.post.history` does: the share cancels in a derivative, whose
    weights sum to zero). The column stds are taken as uniform down a column for the
    correlation between columns.

    E is the slope of ``stress = E strain + c`` fitted by ordinary least squares over
    the chosen states and sections (the intercept takes the reference's noise, a
    common strain offset). Its std is the linear propagation of both maps' noises
    through the slope (each alone: their cross-correlation is left out); the interval
    is ``E +- 1.96 std`` unless the fit's residuals scatter more than the stress's
    noise explains (a model error: a non-uniaxial stress, a smoothing bias, an
    inelastic material), in which case the std is scaled by the ratio of RMS
    residual to RMS predicted noise: an interval is never narrower than the scatter
    supports. The interval holds the noise, not the filter's bias: that moves stress
    and strain together and leaves no residual (``bias_coefficient`` states it). The
    propagation is to first order: it holds while E's std is a small
    part of E (measured: predicted / empirical std 0.97 to 1.03 up to 2 %, but 0.82
    at 19 %, where the noise of the strains that weight the slope and choose the
    points counts too).

    References
    ----------
    F. Pierron, P. Forquin, Ultra-high-speed full-field deformation measurements on
    concrete spalling specimens and stiffness identification with the virtual fields
    method, Strain 48 (2012) 388-405, doi:10.1111/j.1475-1305.2012.00835.x.

    L. Fletcher, J. Van Blitterswyk, F. Pierron, A novel image-based inertial impact
    test (IBII) for the transverse properties of composites at high strain rates,
    J. Dyn. Behav. Mater. 5 (2019) 65-92, doi:10.1007/s40870-019-00186-y.
    """
    free_edge = check_choice(free_edge, "free_edge", tuple(FREE_EDGES))
    axis, sign = FREE_EDGES[free_edge]
    rho = check_positive(density, "density")
    ps = check_positive(pixel_size, "pixel_size")
    if unit not in METRES:
        raise ValueError(f"unit must be one of {sorted(METRES)} to convert the stress to "
                         f"MPa, got {unit!r}")
    u, eps, ok, u_std, e_std = _checked_maps(displacement, strain, valid,
                                             displacement_std, strain_std)
    n_states = u.shape[0]
    t, step, window, order = _checked_time(time, n_states, window, order)
    f = np.zeros(n_states) if reference_share is None else \
        np.asarray(reference_share, dtype=np.float64).reshape(-1)
    if f.shape != (n_states,) or not np.all((f >= 0) & (f <= 1)):
        raise ValueError(f"reference_share must hold one fraction in [0, 1] per state "
                         f"({n_states}), got {np.asarray(reference_share)!r}")
    if sigma is not None:
        sigma = check_positive(sigma, "sigma")
    strain_floor = float(strain_floor)
    if not 0 <= strain_floor < 1:
        raise ValueError(f"strain_floor must lie in [0, 1), got {strain_floor!r}")

    # the axial axis last, the free edge at index 0, the axial displacement pointing
    # into the specimen: then sigma = rho int_0^d a (s = +1) on every side
    u, eps, ok = (_canonical(a, axis, sign) for a in (u, eps, ok))
    u = sign * u
    if u_std is not None:
        u_std, e_std = (_canonical(a, axis, sign) for a in (u_std, e_std))
    L = u.shape[2]
    run, first, centres = _sections(ok, _canonical_edge(edge, L, sign))
    n_fit = check_int(strip_fit, "strip_fit", minimum=2) if strip_fit is not None else \
        max(4, math.ceil(2 * first))
    n_fit = min(n_fit, run.size)

    # step 1: the sections' means; 2: their accelerations; 3: the slab's integral
    u_mean, u_s = _section_means(u[..., run], None if u_std is None else u_std[..., run],
                                 ok[..., run], sigma)
    e_mean, e_s = _section_means(eps[..., run], None if e_std is None else e_std[..., run],
                                 ok[..., run], sigma)
    A2 = savgol_operator(n_states, window=window, order=order, deriv=2, delta=step)
    A1 = savgol_operator(n_states, window=window, order=order, deriv=1, delta=step)
    M = _region_operator(centres, first, n_fit)
    acc_cols = A2 @ u_mean  # (T, S) px/s^2
    # step 4: px^2/s^2 to MPa
    m = METRES[unit] * ps  # metres per px
    scale = rho * m * m * 1e-6
    stress = scale * (acc_cols @ M.T)
    strip = scale * (acc_cols[:, :n_fit] @ _strip_weights(first, centres, n_fit)[0])
    rate = A1 @ e_mean
    noise = _Noise(A2, M, u_s, e_s, f, sigma, run.size)
    stress_std, rate_std = noise.stress_std(scale), noise.rate_std(A1)
    if isinstance(fit_from, bool) or not isinstance(fit_from, numbers.Real) or \
            not 0 <= fit_from < math.inf:
        raise ValueError(f"fit_from must be a finite distance >= 0, px, got {fit_from!r}")
    fit = _fit_modulus(stress, stress_std, e_mean, noise, scale, window=window,
                       strain_floor=strain_floor,
                       sections=(centres >= fit_from) & (centres <= centres[-1] - fit_from))
    rates = np.abs(rate[fit["fitted"]])
    d_m = centres * m  # metres
    return StressGauge(
        time=t, distance=centres * ps, index=run.copy() if sign > 0 else (L - 1) - run,
        stress=stress, stress_std=stress_std, acceleration=stress / (rho * d_m) * 1e6,
        acceleration_std=stress_std / (rho * d_m) * 1e6, strain=e_mean,
        strain_std=e_s if e_s is not None else np.full_like(stress, np.nan),
        strain_rate=rate, strain_rate_std=rate_std,
        strip_stress=np.repeat(strip[:, None], run.size, axis=1), **fit,
        strain_rate_range=(float(rates.min()), float(rates.max())),
        window=window, order=order,
        bias_coefficient=acceleration_bias_coefficient(window=window, order=order,
                                                       delta=step),
        strip_width=float(first * ps), density=rho, free_edge=free_edge, unit=unit)


def _checked_maps(displacement, strain, valid, displacement_std, strain_std):
    """The maps as float64 ``(T, H, W)``, the pixels to use, and the std maps (or None)."""
    u = _maps(displacement, "displacement")
    eps = _maps(strain, "strain", u.shape)
    ok = np.isfinite(u) & np.isfinite(eps)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape == u.shape[1:]:
            v = np.broadcast_to(v, u.shape)
        if v.shape != u.shape:
            raise ValueError(f"valid must be (n_states, H, W) {u.shape} or (H, W), got "
                             f"shape {v.shape}")
        ok &= v
    if (displacement_std is None) != (strain_std is None):
        raise ValueError("displacement_std and strain_std go together: give both maps "
                         "or neither")
    if displacement_std is None:
        return u, eps, ok, None, None
    return (u, eps, ok, _maps(displacement_std, "displacement_std", u.shape),
            _maps(strain_std, "strain_std", u.shape))


def _checked_time(time, n_states: int, window, order):
    """``(time, step, window, order)``: one finite time per state, evenly spaced, and
    the filter's window and order checked against them."""
    window = check_int(window, "window", minimum=3)
    order = check_int(order, "order", minimum=2)
    t = np.asarray(time, dtype=np.float64).reshape(-1)
    if t.size != n_states or not np.all(np.isfinite(t)):
        raise ValueError(f"time must hold one finite value per state ({n_states}), got "
                         f"{t.size}")
    if window % 2 == 0 or window <= order or window > n_states:
        raise ValueError(f"window must be odd, above order ({order}) and at most the "
                         f"number of states ({n_states}), got {window}")
    dt = np.diff(t)
    step = float(dt.mean())
    if step <= 0 or np.max(np.abs(dt - step)) > _UNIFORM * step:
        raise ValueError(f"time must increase evenly for the Savitzky-Golay filter (steps "
                         f"from {dt.min():.6g} to {dt.max():.6g} s)")
    return t, step, window, order


def _canonical_edge(edge, L: int, sign: float) -> float:
    """The free edge's position, px, in the turned maps (the image's border by default)."""
    if edge is None:
        return -0.5
    try:
        e = float(edge)
    except (TypeError, ValueError):
        e = math.nan
    if not math.isfinite(e):
        raise ValueError(f"edge must be a finite position in px, got {edge!r}")
    return e if sign > 0 else (L - 1) - e


def _sections(ok: np.ndarray, edge: float):
    """The sections used (indices in the turned maps), the strip's width and the
    sections' distances from the free edge, px.

    A section is measured when it has a valid pixel in every state; those used run
    contiguously from the one nearest the free edge (the integral needs them all).
    """
    measured = ok.any(axis=1).all(axis=0)
    cols = np.flatnonzero(measured & (np.arange(ok.shape[2]) > edge))
    if cols.size == 0:
        raise ValueError("no section has a valid pixel in every state: nothing to gauge")
    run = cols[: int(np.argmax(np.diff(np.append(cols, cols[-1] + 2)) > 1)) + 1]
    if run.size < 5:
        raise ValueError(f"the sections measured in every state from the free edge number "
                         f"{run.size}: at least 5 are needed")
    return run, run[0] - 0.5 - edge, run - edge


class _Noise:
    """The noise of the sections' means carried through the linear steps.

    ``u_s``, ``e_s``: ``(T, S)`` stds of the sections' mean displacement and strain
    (None without std maps); sections correlated by ``R`` (:func:`displacement_correlation`,
    :func:`strain_correlation`; None: independent), states independent but for the
    reference's share ``f`` of each variance, common to all of them.
    """

    def __init__(self, A2, M, u_s, e_s, f, sigma, n_sections):
        self.A2, self.M, self.u_s, self.e_s, self.f = A2, M, u_s, e_s, f
        self.known = u_s is not None
        self.Ru = self.Re = None
        if sigma is not None:
            k = np.arange(n_sections)
            self.Ru = displacement_correlation(sigma, k[:, None] - k[None, :])
            self.Re = strain_correlation(sigma, k[:, None] - k[None, :])

    def stress_std(self, scale):
        if not self.known:
            return np.full((self.A2.shape[0], self.M.shape[0]), np.nan)
        A2, M, s, f = self.A2, self.M, self.u_s, self.f
        own = (A2**2 * (1.0 - f)[None, :]) @ _quad_diag(M, s, self.Ru)
        common = _quad_diag(M, A2 @ (np.sqrt(f)[:, None] * s), self.Ru)
        return scale * np.sqrt(own + common)

    def rate_std(self, A1):
        if not self.known:
            return np.full((A1.shape[0], self.M.shape[0]), np.nan)
        s, f = self.e_s, self.f
        return np.sqrt((A1**2 * (1.0 - f)[None, :]) @ (s**2)
                       + (A1 @ (np.sqrt(f)[:, None] * s)) ** 2)

    def slope_variance(self, w, E, scale):
        """Variance of ``sum w stress - E sum w strain``: a slope's noise, MPa^2."""
        stress = _weighted_sum_variance(self.A2.T @ w @ self.M, self.u_s, self.f, self.Ru)
        return stress * scale**2 + E**2 * _weighted_sum_variance(w, self.e_s, self.f,
                                                                 self.Re)


def _fit_modulus(stress, stress_std, strain, noise: _Noise, scale, *, window,
                 strain_floor, sections=None) -> dict:
    """E, its std and interval, and the points fitted (see :func:`stress_gauge`);
    ``sections``: the sections that may be fitted (all by default)."""
    # the states where the filter is centred, the points where the strain counts
    T = stress.shape[0]
    h = window // 2
    fitted = np.zeros_like(stress, dtype=bool)
    fitted[h:T - h] = True
    if sections is not None:
        fitted &= np.asarray(sections, dtype=bool)[None, :]
    big = np.nanmax(np.abs(strain[h:T - h]))
    fitted &= np.abs(strain) >= strain_floor * big
    if fitted.sum() < 3 or not big > 0:
        raise ValueError("fewer than 3 points have a strain above strain_floor "
                         f"({strain_floor:g} of the largest): nothing to fit E on")
    # one intercept per state: the strip's part of the stress, the same for every
    # section of a state, falls into it, so that E owes nothing to the extrapolation
    count = fitted.sum(axis=1)
    fitted &= (count >= 2)[:, None]
    count = fitted.sum(axis=1)
    n_states = int(np.sum(count > 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        centre = np.where(fitted, strain, 0.0).sum(axis=1) / count
    xc = np.where(fitted, strain - centre[:, None], 0.0)
    sxx = float(np.sum(xc**2))
    if not sxx > 0:
        raise ValueError("the strain does not vary along the specimen in any state: the "
                         "stress gauge cannot separate E from the strip's stress")
    w = xc / sxx  # E = sum w stress
    E = float(np.sum(w * stress))
    with np.errstate(invalid="ignore", divide="ignore"):
        c_t = np.where(fitted, stress - E * strain, 0.0).sum(axis=1) / count
    rms = float(np.sqrt(np.mean((stress - E * strain - c_t[:, None])[fitted] ** 2)))
    if noise.known:
        E_std = math.sqrt(noise.slope_variance(w, E, scale))
        expected = float(np.sqrt(np.mean(stress_std[fitted] ** 2)))
        ratio = rms / expected if expected > 0 else math.inf
    else:
        E_std, ratio = math.nan, math.inf
    q = float(stats.norm.ppf(0.5 + LEVEL / 2))
    basis = "stated std"
    if ratio > 1.0:
        basis = "residual scatter"
        dof = int(fitted.sum()) - n_states - 1
        # the residual scatter in the place of the noise; without std maps the points
        # are taken as independent (an interval too narrow where they are correlated)
        E_std = E_std * ratio if math.isfinite(E_std) else rms / math.sqrt(sxx)
        q = float(stats.t.ppf(0.5 + LEVEL / 2, max(dof, 1)))
    return {"fitted": fitted, "E": E, "E_std": E_std,
            "E_interval": (E - q * E_std, E + q * E_std), "interval_basis": basis,
            "residual_rms": rms}


def _weighted_sum_variance(w, s, f, R) -> float:
    """Variance of ``sum_tk w[t, k] x[t, k]``, ``x`` of std ``s``, its columns correlated
    by ``R`` (None: independent), its states independent but for the common share
    ``f`` of each variance."""
    ws = w * s
    wr = ws if R is None else ws @ R
    own = np.einsum("tk,tk->t", ws, wr)
    hvec = np.sum(ws * np.sqrt(f)[:, None], axis=0)
    common = hvec @ (hvec if R is None else R @ hvec)
    return float(np.sum(own * (1.0 - f)) + common)


def _free_edge_position(mask: np.ndarray, free_edge: str) -> float:
    """The specimen's border on the free edge's side, px: the outer side of the first
    (last) column or row of the mask that holds the specimen."""
    axis, sign = FREE_EDGES[free_edge]
    along = mask.any(axis=0) if axis == "x" else mask.any(axis=1)
    idx = np.flatnonzero(along)
    if idx.size == 0:
        raise ValueError("the result's mask holds no specimen pixel")
    return float(idx[0] - 0.5) if sign > 0 else float(idx[-1] + 0.5)


def stress_gauge_of(result, *, density: float, free_edge: str,
                    pixel_size: float | None = None, unit: str | None = None,
                    edge: float | None = None, window: int = 9, order: int = 4,
                    strip_fit: int | None = None, strain_floor: float = 0.1
                    ) -> StressGauge:
    """:func:`stress_gauge` on a measured impact record.

    Parameters
    ----------
    result : gridstrain.results.SeriesResult
        A record measured one frame per state with the frame rate
        (``measure_series(..., each_frame=True, frame_rate=HZ)``, ``gridstrain measure
        --each-frame --frame-rate HZ``): its ``time``, its maps, their uncertainty
        maps and its window's ``sigma`` are used.
    density : float
        kg/m^3.
    free_edge : {"left", "right", "top", "bottom"}
    pixel_size : float, optional
        Size of a pixel in ``unit``. Default: the result's own
        (:attr:`gridstrain.results.SeriesResult.pixel_size`); given, it must be its
        own (within 1e-5: typed from a printed one): another is refused naming both,
        since it would scale the stress.
    unit : str, optional
        One of :data:`METRES`; default: the result's own.
    edge : float, optional
        Position of the free edge along the axis, px. Default: the border of the
        result's specimen mask on that side (the image's border without a mask).
        A result measured up to the edges (``to_edges`` in its parameters) has its
        maps there: the strip without data is at most a pixel wide, and the sections
        within its band (``margin * sigma``) enter the stress but not E's fit
        (``fit_from``).
    window, order, strip_fit, strain_floor
        As in :func:`stress_gauge`.

    Returns
    -------
    StressGauge

    Raises
    ------
    ValueError, TypeError
        A result without times or without a pixel size, and :func:`stress_gauge`'s.
    """
    from ..post import own_length, reference_share
    from ..results import SeriesResult

    if not isinstance(result, SeriesResult):
        raise TypeError(f"result must be a SeriesResult, got {type(result).__name__}")
    if result.time is None:
        raise ValueError("the result has no times: measure the impact record with "
                         "--each-frame --frame-rate HZ (each_frame=True, frame_rate=HZ), "
                         "or give a loads file with a 'time [s]' column")
    pixel_size, unit = own_length(result.pixel_size, result.unit, pixel_size=pixel_size,
                                  unit=unit, px_too=False)
    if pixel_size is None:
        raise ValueError("the stress gauge needs the pixel size, and this result carries "
                         "none: measure with --pixel-size SIZE --unit mm, or give "
                         "pixel_size= and unit=")
    free_edge = check_choice(free_edge, "free_edge", tuple(FREE_EDGES))
    axis, _ = FREE_EDGES[free_edge]
    comp = 0 if axis == "x" else 1
    n = result.n_states
    shape = (n, *result.shape)
    u, eps = np.empty(shape), np.empty(shape)
    valid = np.empty(shape, dtype=bool)
    unc = result.uncertainty
    names = (f"u{axis}_std", f"e{axis}{axis}_std")
    has_std = unc is not None and all(k in unc for k in names)
    u_std = np.empty(shape) if has_std else None
    e_std = np.empty(shape) if has_std else None
    for i in range(n):  # one state at a time: a record's maps may sit in its file
        u[i] = np.asarray(result.u[i])[comp]
        eps[i] = np.asarray(result.strain[i])[comp]
        valid[i] = np.asarray(result.valid[i])
        if has_std:
            u_std[i] = np.asarray(unc[names[0]][i])
            e_std[i] = np.asarray(unc[names[1]][i])
    if has_std:
        valid &= np.isfinite(u_std) & np.isfinite(e_std)
    if edge is None:
        edge = _free_edge_position(np.asarray(result.mask, dtype=bool), free_edge)
    # measured up to the edges: the strip is measured, not extrapolated, and the edge
    # pixels' strain bias is kept out of E's fit
    to_edges = bool((result.parameters or {}).get("to_edges"))
    fit_from = float(result.margin) * float(result.sigma) if to_edges else 0.0
    return stress_gauge(u, eps, result.time, density=density, free_edge=free_edge,
                        pixel_size=pixel_size, unit=unit, valid=valid,
                        displacement_std=u_std, strain_std=e_std,
                        reference_share=reference_share(result) if has_std else None,
                        sigma=result.sigma, edge=edge, window=window, order=order,
                        strip_fit=strip_fit, strain_floor=strain_floor, fit_from=fit_from)
