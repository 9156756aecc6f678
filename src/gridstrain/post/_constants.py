"""Young's modulus and Poisson's ratio from a gauge's readings and the loads."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .._progress import Finding
from .._validation import check_choice, check_positive, check_type
from ._gauges import GaugeReading

#: Forces in N and areas in mm2 of the units a load and an area are given in: with both
#: known the stress is in MPa (N/mm2); lbf over in2 stays in psi; other pairs are
#: written "load/area", unscaled.
_FORCE_N = {"mN": 1e-3, "N": 1.0, "daN": 10.0, "kN": 1e3, "MN": 1e6}
_AREA_MM2 = {"mm2": 1.0, "cm2": 1e2, "dm2": 1e4, "m2": 1e6}


def _area_unit(text: str) -> str:
    return str(text).strip().replace("²", "2").replace("^2", "2")


def stress_unit(load_unit: str | None, area_unit: str) -> tuple[float, str]:
    """``(factor, unit)``: load / area times ``factor`` is a stress in ``unit``.

    MPa for every force unit of ``N``, ``kN``, ``MN``, ``daN``, ``mN`` over an area in
    ``mm2``, ``cm2``, ``dm2``, ``m2`` (``mm²`` and ``mm^2`` too): a load of 5 N on 1 cm2
    is 0.05 MPa, not "5 N/cm2"; psi for ``lbf`` over ``in2``; else the quotient
    unscaled, its unit written ``load/area``.
    """
    area = _area_unit(area_unit)
    if load_unit in _FORCE_N and area in _AREA_MM2:
        return _FORCE_N[load_unit] / _AREA_MM2[area], "MPa"
    if (load_unit, area) == ("lbf", "in2"):
        return 1.0, "psi"
    return 1.0, f"{load_unit or 'load'}/{area}"


#: The units a modulus is shown in, by the stress unit it is computed in: the largest
#: whose value is at least 1 (GPa from 1 GPa up, else MPa; Msi, ksi, psi).
_MODULUS_UNITS = {"MPa": (("GPa", 1e3), ("MPa", 1.0)),
                  "psi": (("Msi", 1e6), ("ksi", 1e3), ("psi", 1.0))}


def modulus_unit(value: float, unit: str) -> tuple[float, str]:
    """``(scale, unit)`` to show the modulus ``value`` (in ``unit``) as
    ``value * scale`` in the returned unit: GPa from 1 GPa up, else MPa (Msi, ksi or psi
    for psi); an unknown unit is kept.

    Examples
    --------
    >>> modulus_unit(70148.0, "MPa")
    (0.001, 'GPa')
    >>> modulus_unit(850.0, "MPa")
    (1.0, 'MPa')
    """
    choices = _MODULUS_UNITS.get(unit)
    if choices is None or not math.isfinite(value):
        return 1.0, unit
    for name, size in choices:
        if abs(value) >= size:
            return 1.0 / size, name
    return 1.0 / choices[-1][1], choices[-1][0]
#: Two-sided coverage of the intervals.
LEVEL = 0.95

#: Young's moduli of solids lie between these, MPa (soft gels about 1 kPa, diamond
#: 1.2 TPa): a fitted E outside is a unit's slip, not a material's (an area in m2 read
#: as mm2 makes E a million times too large).
SOLID_MODULI_MPA = (1e-4, 2e6)
# MPa in one unit of the stress units whose scale is known
_MPA_PER = {"MPa": 1.0, "psi": 0.006894757293168361}


@dataclass(frozen=True)
class ElasticConstants:
    """Young's modulus and Poisson's ratio fitted on a gauge's readings.

    Attributes
    ----------
    E : float
        Young's modulus, ``stress_unit`` (:meth:`E_text` shows it in GPa or MPa).
    E_ci : (float, float)
        Its 95 % interval.
    nu : float
        Poisson's ratio, dimensionless.
    nu_ci : (float, float)
    stress_unit : str
        MPa for loads in N, kN... on areas in mm2, cm2, m2...; psi for lbf on in2
        (:func:`stress_unit`).
    axis : {"x", "y"}
        The loading axis: the axial strain is ``exx`` (or ``eyy``).
    states : tuple of str
        The states fitted.
    stress : (n,) float64 ndarray
        Load / area of the states fitted.
    axial, axial_std, transverse, transverse_std : (n,) float64 ndarray
        The gauge's strains and their std, dimensionless.
    interval_basis : {"stated std", "residual scatter"}
        What set the intervals' width (see :func:`elastic_constants`).
    reduced_chi2 : (float, float)
        Of the axial and transverse fits, against the stated std.
    """

    E: float
    E_ci: tuple[float, float]
    nu: float
    nu_ci: tuple[float, float]
    stress_unit: str
    axis: str
    states: tuple[str, ...]
    stress: np.ndarray
    axial: np.ndarray
    axial_std: np.ndarray
    transverse: np.ndarray
    transverse_std: np.ndarray
    interval_basis: str
    reduced_chi2: tuple[float, float]

    def E_text(self, digits: int = 5) -> str:
        """``E`` and its interval in a unit chosen for it (:func:`modulus_unit`):
        ``"70.148 GPa, 95 % interval [69.577, 70.728] GPa"``."""
        scale, unit = modulus_unit(self.E, self.stress_unit)
        lo, hi = (v * scale for v in self.E_ci)
        return (f"{self.E * scale:.{digits}g} {unit}, {LEVEL * 100:g} % interval "
                f"[{lo:.{digits}g}, {hi:.{digits}g}] {unit}")

    def unit_doubt(self) -> Finding | None:
        """A ``modulus.units`` finding (:data:`gridstrain.FINDINGS`; its sentence names
        what to check, its figures ``E_mpa``) when ``E`` lies outside any solid's
        Young's modulus (:data:`SOLID_MODULI_MPA`); None otherwise, or when the stress
        unit's scale is not known."""
        per = _MPA_PER.get(self.stress_unit)
        if per is None or not math.isfinite(self.E):
            return None
        lo, hi = SOLID_MODULI_MPA
        if lo <= self.E * per <= hi:
            return None
        return Finding(
            "modulus.units",
            f"E = {self.E_text(3).split(',')[0]} is no solid's Young's modulus (about "
            "1 kPa for a soft gel to 1.2 TPa for diamond): check the cross-section's "
            "value and unit (area_unit, --area-unit, mm2 by default: an area in m2 "
            "given as mm2 makes E a million times too large) and the loads' unit",
            E_mpa=self.E * per)

    def to_dict(self) -> dict:
        """The constants as JSON-ready values, units included."""
        return {"E": self.E, "E_ci": list(self.E_ci), "E_unit": self.stress_unit,
                "nu": self.nu, "nu_ci": list(self.nu_ci), "nu_unit": "1",
                "level": LEVEL, "axis": self.axis, "states": list(self.states),
                "interval_basis": self.interval_basis,
                "reduced_chi2": list(self.reduced_chi2), "doubt": self.unit_doubt()}


def _fit(x, y, s):
    """Weighted straight line ``y = a x + b``: slope, its variance, reduced chi2."""
    w = 1.0 / s**2
    X = np.stack([x, np.ones_like(x)], axis=1)
    cov = np.linalg.inv(X.T @ (w[:, None] * X))
    a, b = cov @ (X.T @ (w * y))
    dof = x.size - 2
    chi2 = float(np.sum(w * (y - a * x - b) ** 2)) / dof
    return float(a), float(cov[0, 0]), chi2


def elastic_constants(reading: GaugeReading, *, area: float, area_unit: str = "mm2",
                      axis: str = "x", strain_range=None) -> ElasticConstants:
    """Young's modulus and Poisson's ratio from a gauge read on a tensile test.

    Parameters
    ----------
    reading : GaugeReading
        With loads (:func:`gauge`'s ``load``) and uncertainty (its std).
    area : float
        The specimen's cross-section, in ``area_unit``.
    area_unit : str
        ``"mm2"`` (default), ``"m2"``, ``"cm2"``, ``"in2"``...: with a load in N, kN
        or MN and an area in mm2, cm2 or m2 the stress is in MPa, with lbf on in2 in
        psi (:func:`stress_unit`).
    axis : {"x", "y"}
        Loading direction: ``exx`` (``eyy``) is the axial strain.
    strain_range : (low, high) floats, optional
        Fit only the states whose axial strain lies in ``[low, high]``
        (dimensionless): the linear part of the curve.

    Returns
    -------
    ElasticConstants

    Notes
    -----
    The load is the exact variable and the strains carry the noise, so both strains
    are fitted as straight lines of the stress, weighted by the gauge's std:
    ``axial = stress / E + a0`` and ``transverse = -nu stress / E + t0``; then
    ``E = 1 / slope_axial`` and ``nu = -slope_transverse / slope_axial``. The
    intercepts absorb the reference image's noise, common to every state, so the
    weights are each state's own noise: the gauge's variance less the reference's
    share (``GaugeReading.reference_share``; all of it when unknown). The
    intervals come from that std when the fits' residuals agree with it
    (reduced chi2 <= 1: normal quantile); when the residuals scatter more than the
    noise explains (a non-linearity, a slipping grip, a bias the std maps do not
    cover), the slopes' covariance is scaled by the reduced chi2 and Student's
    quantile with n - 2 degrees of freedom is used: the wider of the two, so that
    an interval is never narrower than either the noise or the scatter supports.
    ``E``'s interval is the inverse of the slope's; ``nu``'s is from the ratio's
    first-order variance, the noises of ``exx`` and ``eyy`` taken as independent.
    """
    check_type(reading, "reading", GaugeReading)
    area = check_positive(area, "area")
    axis = check_choice(axis, "axis", ("x", "y"))
    if reading.load is None:
        raise ValueError("the gauge has no loads: give them (gridstrain modulus --loads "
                         "FILE.csv, or gauge(..., load=...))")
    axial, axial_s = (reading.exx, reading.exx_std) if axis == "x" else \
        (reading.eyy, reading.eyy_std)
    trans, trans_s = (reading.eyy, reading.eyy_std) if axis == "x" else \
        (reading.exx, reading.exx_std)
    keep = np.isfinite(axial) & np.isfinite(trans)
    if strain_range is not None:
        lo, hi = (float(v) for v in strain_range)
        if not lo < hi:
            raise ValueError(f"strain_range must be (low, high) with low < high, got "
                             f"{strain_range!r}")
        keep &= (axial >= lo) & (axial <= hi)
    if not np.all(np.isfinite(axial_s[keep]) & (axial_s[keep] > 0)):
        raise ValueError("the gauge has no std (a result without uncertainty maps): a "
                         "weighted fit needs them")
    # the reference's noise, common to every state, falls into the intercepts: the
    # slopes see each state's own noise only
    own = 1.0 if reading.reference_share is None else \
        np.sqrt(1.0 - reading.reference_share[keep])
    if keep.sum() < 3:
        if strain_range is None:
            raise ValueError(f"a fit needs at least 3 states, got {int(keep.sum())}")
        # the tables print microstrain: a range written in it holds no state
        seen = axial[np.isfinite(axial)]
        span = (f"; the states' axial strains span {seen.min():.3g} to {seen.max():.3g}"
                if seen.size else "")
        raise ValueError(f"a fit needs at least 3 states, got {int(keep.sum())} in "
                         f"strain_range (--strain-range) [{lo:g}, {hi:g}], dimensionless "
                         f"(1e-3 is 1000 µε){span}")
    factor, unit = stress_unit(reading.load_unit, area_unit)
    stress = reading.load[keep] / area * factor
    if np.all(stress == stress[0]):  # else "Singular matrix" from the fit
        raise ValueError(f"the loads of the {int(keep.sum())} states fitted are all "
                         f"{reading.load[keep][0]:g} {reading.load_unit or ''}".rstrip()
                         + ": a modulus needs states at different loads (a constant or "
                         "all-zero load column? choose the force with --load-column)")
    a, var_a, chi_a = _fit(stress, axial[keep], axial_s[keep] * own)
    c, var_c, chi_t = _fit(stress, trans[keep], trans_s[keep] * own)
    dof = int(keep.sum()) - 2
    scale = max(chi_a, chi_t)
    if scale > 1.0:
        basis, q = "residual scatter", float(stats.t.ppf(0.5 + LEVEL / 2, dof))
        var_a, var_c = var_a * max(chi_a, 1.0), var_c * max(chi_t, 1.0)
    else:
        basis, q = "stated std", float(stats.norm.ppf(0.5 + LEVEL / 2))
    if a <= 0:
        raise ValueError(f"the axial strain does not grow with the load (slope {a:.3g} per "
                         f"unit stress): check --axis and the loads")
    sa = math.sqrt(var_a)
    E = 1.0 / a
    E_ci = (1.0 / (a + q * sa), 1.0 / (a - q * sa) if a > q * sa else math.inf)
    nu = -c / a
    s_nu = math.sqrt((var_c + nu**2 * var_a) / a**2)
    return ElasticConstants(
        E=E, E_ci=E_ci, nu=nu, nu_ci=(nu - q * s_nu, nu + q * s_nu), stress_unit=unit,
        axis=axis, states=tuple(np.array(reading.states)[keep].tolist()), stress=stress,
        axial=axial[keep], axial_std=axial_s[keep], transverse=trans[keep],
        transverse_std=trans_s[keep], interval_basis=basis, reduced_chi2=(chi_a, chi_t))
