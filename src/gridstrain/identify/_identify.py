"""E and nu of every state with known load, by the virtual fields method: the states
combined, their intervals, and the refusals."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validation import check_choice, check_positive, freeze_arrays
from ._mesh import Mesh
from ._models import Isotropic
from ._vfm import NotIdentifiable, special_fields, virtual_work

#: Two-sided coverage of the intervals
LEVEL = 0.95
#: Stress unit of a load / length^2 pair, and its factor to MPa
_STRESS = {("N", "mm"): 1.0, ("kN", "mm"): 1e3, ("N", "m"): 1e-6, ("kN", "m"): 1e-3,
           ("MN", "m"): 1.0, ("N", "cm"): 1e-2, ("N", "um"): 1e6, ("N", "µm"): 1e6}
#: The largest share of the used region's free boundary (all but the loaded and gripped
#: sides) that may face specimen pixels left out: a few invalid pixels inside (a speck)
#: cost the integral their own area; a strip along a free edge loses the load it carries
MAX_CUT_FRACTION = 0.05
# px: a loaded or gripped side's last columns (rows) left out when sparse, as a record
# measured up to its frame's border leaves them (that column valid in some rows only)
_RAGGED = 2
#: Elements along the longer side of the region when not given
ELEMENTS_LONG_SIDE = 8
#: The smallest element side, px: an element of a few pixels only adds noise
MIN_ELEMENT_PX = 4
_MODELS = {"isotropic": Isotropic}


@dataclass(frozen=True)
class VirtualFields:
    """Elastic constants identified by the virtual fields method.

    Attributes
    ----------
    E : float
        Young's modulus, in ``stress_unit`` (MPa with loads in N and lengths in mm).
    E_interval : (float, float)
        Its 95 % interval.
    nu : float
        Poisson's ratio, dimensionless.
    nu_interval : (float, float)
    E_std, nu_std : float
        The std behind the intervals.
    stress_unit : str
    model : str
        The stiffness model, ``"isotropic"``.
    parameters : dict of str to float
        The model's stiffness components (``Q11``, ``Q12``), ``stress_unit``.
    parameters_cov : (n_par, n_par) float64 ndarray
        Their covariance from the strains' stated std (the method's own variance).
    states : tuple of str
    load : (n_states,) float64 ndarray
        The loads used, ``load_unit``.
    load_unit : str
    E_states, nu_states, E_states_std, nu_states_std : (n_states,) float64 ndarray
        Each state identified on its own (the reference taken at zero load), with its
        std from the stated noise.
    combined : {"slope", "through zero"}
        How the states were combined: the per-pixel slope of the strains against the
        load (an intercept absorbs the reference's noise and a preload), or, with one
        state or one load, the strains over the load.
    interval_basis : {"stated std", "scatter over states"}
    reduced_chi2 : tuple of float
        Per stiffness component, of the states' virtual work in its special field about
        the straight line of the load, against its stated std (NaN without the degrees
        of freedom: fewer than 3 states, or 2 with one load).
    elements : (int, int)
        ``(ny, nx)`` of the virtual fields' mesh.
    fields : (n_par, ny + 1, nx + 1, 2) float64 ndarray
        The combined special virtual fields' nodal displacements ``(u*_x, u*_y)``,
        node ``[row, col]``, scaled as the special conditions set them for a unit
        load (their shape is what a reader looks at).
    used : (H, W) bool ndarray
        The pixels integrated (valid in every state, inside the region).
    n_pixels : int
    iterations : int
        Of the optimal fields on the combined maps.
    thickness, pixel_size : float
    unit : str
        Length unit of ``thickness`` and ``pixel_size``.
    loaded_edge, load_direction : str
    """

    E: float
    E_interval: tuple[float, float]
    nu: float
    nu_interval: tuple[float, float]
    E_std: float
    nu_std: float
    stress_unit: str
    model: str
    parameters: dict
    parameters_cov: np.ndarray
    states: tuple[str, ...]
    load: np.ndarray
    load_unit: str
    E_states: np.ndarray
    nu_states: np.ndarray
    E_states_std: np.ndarray
    nu_states_std: np.ndarray
    combined: str
    interval_basis: str
    reduced_chi2: tuple[float, float]
    elements: tuple[int, int]
    fields: np.ndarray
    used: np.ndarray
    n_pixels: int
    iterations: int
    thickness: float
    pixel_size: float
    unit: str
    loaded_edge: str
    load_direction: str

    def __post_init__(self):
        freeze_arrays(self)

    def to_dict(self) -> dict:
        """The identification as JSON-ready values, units included (a value that could
        not be had, NaN, as None)."""
        def finite(values):
            return [float(v) if math.isfinite(v) else None for v in values]

        return {"E": self.E, "E_interval": list(self.E_interval), "E_std": self.E_std,
                "E_unit": self.stress_unit, "nu": self.nu,
                "nu_interval": list(self.nu_interval), "nu_std": self.nu_std,
                "nu_unit": "1", "level": LEVEL, "model": self.model,
                "parameters": dict(self.parameters), "states": list(self.states),
                "load": self.load.tolist(), "load_unit": self.load_unit,
                "E_states": finite(self.E_states), "nu_states": finite(self.nu_states),
                "combined": self.combined, "interval_basis": self.interval_basis,
                "reduced_chi2": finite(self.reduced_chi2), "elements": list(self.elements),
                "n_pixels": self.n_pixels, "thickness": self.thickness,
                "unit": self.unit, "loaded_edge": self.loaded_edge,
                "load_direction": self.load_direction}

    def stress(self, strain) -> np.ndarray:
        """The stress of strain maps by the identified stiffness.

        Parameters
        ----------
        strain : (..., 3, H, W) array_like
            ``exx, eyy, exy`` (tensor shear), dimensionless.

        Returns
        -------
        (..., 3, H, W) float64 ndarray
            ``sigma_xx, sigma_yy, sigma_xy``, ``stress_unit``; NaN outside ``used``.
        """
        e = np.asarray(strain, dtype=np.float64)
        if e.ndim < 3 or e.shape[-3:] != (3, *self.used.shape):
            raise ValueError(f"strain must be (..., 3, {self.used.shape[0]}, "
                             f"{self.used.shape[1]}), got {e.shape}")
        C = _MODELS[self.model].stiffness([self.parameters[k] for k in
                                           _MODELS[self.model].parameters])
        voigt = np.stack([e[..., 0, :, :], e[..., 1, :, :], 2.0 * e[..., 2, :, :]], axis=-3)
        out = np.einsum("ij,...jhw->...ihw", C, voigt)
        return np.where(self.used, out, np.nan)


def _stress_unit(load_unit, unit):
    factor = _STRESS.get((load_unit, unit))
    if factor is None:
        return 1.0, f"{load_unit or 'load'}/{unit}2"
    return factor, "MPa"


def default_elements(rows, cols) -> tuple[int, int]:
    """``(ny, nx)``: about square elements, ``ELEMENTS_LONG_SIDE`` along the longer side,
    none smaller than ``MIN_ELEMENT_PX``."""
    h = int(rows.max() - rows.min() + 1)
    w = int(cols.max() - cols.min() + 1)
    side = max(h, w) / ELEMENTS_LONG_SIDE
    return (max(1, min(round(h / side), h // MIN_ELEMENT_PX)),
            max(1, min(round(w / side), w // MIN_ELEMENT_PX)))


def _check_elements(elements, rows, cols):
    if elements is None:
        return default_elements(rows, cols)
    try:
        ny, nx = (int(v) for v in elements)
    except (TypeError, ValueError):
        raise ValueError(f"elements must be two positive integers (ny, nx), got "
                         f"{elements!r}") from None
    h = int(rows.max() - rows.min() + 1)
    w = int(cols.max() - cols.min() + 1)
    if ny < 1 or nx < 1 or h / ny < 2 or w / nx < 2:
        raise ValueError(f"elements must be positive and at most half the region's "
                         f"size in px ({h} x {w}), got {elements!r}")
    return ny, nx


def _check_correlation(correlation):
    if correlation is None:
        return None
    try:
        out = tuple(np.asarray(k, dtype=np.float64) for k in correlation)
    except (TypeError, ValueError):
        out = ()
    if len(out) != 3 or any(k.ndim != 2 or k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0
                            or not np.all(np.isfinite(k)) for k in out):
        raise ValueError(f"correlation must be 3 kernels (exx, eyy, exy) of odd sides, "
                         f"got {correlation!r:.80}")
    return out


def _slopes(values, stds, load):
    """Per pixel, the weighted slope of the strains against the load and its std.

    ``values``, ``stds``: ``(n, 3, P)``. With two distinct loads or more, a straight
    line with an intercept; else through zero (the reference at zero load).
    """
    w = 1.0 / stds**2
    L = load[:, None, None]
    if np.ptp(load) > 0:
        sw = w.sum(axis=0)
        mean = (w * L).sum(axis=0) / sw
        d = L - mean
        sxx = (w * d * d).sum(axis=0)
        return (w * d * values).sum(axis=0) / sxx, 1.0 / np.sqrt(sxx), "slope"
    sxx = (w * L * L).sum(axis=0)
    return (w * L * values).sum(axis=0) / sxx, 1.0 / np.sqrt(sxx), "through zero"


def _scatter(mesh, values, stds, load, p, fields, model, combined, thickness,
             correlation):
    """Per parameter, the reduced chi2 of the states' virtual work in its special field
    about the straight line of the load (with an intercept for ``"slope"``)."""
    n = load.size
    work = np.empty((n, len(p)))
    var = np.empty_like(work)
    for i in range(n):
        work[i], var[i] = virtual_work(mesh, values[i], stds[i], p, fields, model,
                                       thickness=thickness, correlation=correlation)
    w = 1.0 / var
    # in the (nearly) special fields of the unit-load maps the work is linear in the
    # load, plus, for "slope", the reference's share common to every state: fitted, the
    # residuals hold what the noise does not explain
    L = load[:, None]
    if combined == "slope":
        sw = w.sum(axis=0)
        mean_L = (w * L).sum(axis=0) / sw
        mean_y = (w * work).sum(axis=0) / sw
        dL = L - mean_L
        slope = (w * dL * (work - mean_y)).sum(axis=0) / (w * dL * dL).sum(axis=0)
        r = work - mean_y - slope * dL
        dof = n - 2
    else:
        slope = (w * L * work).sum(axis=0) / (w * L * L).sum(axis=0)
        r = work - slope * L
        dof = n - 1
    return tuple(float(v) for v in np.sum(w * r * r, axis=0) / dof)


def _trimmed_sides(used, loaded_edge):
    """``used`` without the sparse last columns (rows, for a load along y) of its
    loaded and gripped sides: fewer than half the median's usable pixels, up to
    :data:`_RAGGED` of them on each side. Those sides are then cross-sections: the
    pixels a ragged side would leave out are not a free edge's, and a side element
    holding a few of them biases the virtual work (2.5 % on E in the tests)."""
    along_x = loaded_edge in ("left", "right")
    u = used if along_x else used.T
    counts = u.sum(axis=0)
    lines = np.nonzero(counts)[0]
    if lines.size <= 2 * _RAGGED:
        return used
    full = float(np.median(counts[lines]))
    lo, hi = int(lines[0]), int(lines[-1])
    for _ in range(_RAGGED):
        lo += int(counts[lo] < 0.5 * full)
        hi -= int(counts[hi] < 0.5 * full)
    u = u.copy()
    u[:, :lo] = False
    u[:, hi + 1:] = False
    return u if along_x else u.T


def _cut_fraction(used, specimen, loaded_edge):
    """The share of the used region's boundary, its loaded and gripped sides aside,
    whose outer neighbour is specimen left out (not a free edge)."""
    rows, cols = np.nonzero(used)
    box = (rows.min(), rows.max(), cols.min(), cols.max())
    pad_used = np.pad(used, 1)
    pad_spec = np.pad(specimen, 1)
    along_x = loaded_edge in ("left", "right")
    boundary = cut = 0
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        out = ~pad_used[1 + dr:pad_used.shape[0] - 1 + dr,
                        1 + dc:pad_used.shape[1] - 1 + dc] & used
        # the loaded and gripped sides are cross-sections: cut by design
        if along_x and dc:
            out[:, box[2] if dc < 0 else box[3]] = False
        if not along_x and dr:
            out[box[0] if dr < 0 else box[1], :] = False
        beyond = pad_spec[1 + dr:pad_spec.shape[0] - 1 + dr,
                          1 + dc:pad_spec.shape[1] - 1 + dc]
        boundary += int(out.sum())
        cut += int((out & beyond).sum())
    return cut / max(boundary, 1), cut


def _checked_maps(strain, std, load, valid, specimen, loaded_edge):
    """``(strain, std, load, used)`` checked: the maps as float64, the loads one per
    state, and the pixels usable in every state (inside ``valid``); a region that
    stops short of the specimen's free edges refused."""
    e = np.asarray(strain, dtype=np.float64)
    s = np.asarray(std, dtype=np.float64)
    if e.ndim != 4 or e.shape[1] != 3:
        raise ValueError(f"strain must be (n_states, 3, H, W), got shape {e.shape}")
    if s.shape != e.shape:
        raise ValueError(f"std must have strain's shape {e.shape}, got {s.shape}")
    n, _, H, W = e.shape
    try:
        load = np.array(load, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"load must be numbers, one per state, got {load!r}") from None
    if load.size != n or not np.all(np.isfinite(load)):
        raise ValueError(f"load must hold {n} finite values (one per state), got "
                         f"{load.tolist()}")
    if not np.any(load != 0):
        raise ValueError("load must not be zero in every state: the virtual work of a "
                         "zero load identifies nothing")
    used = np.all(np.isfinite(e) & np.isfinite(s) & (s > 0), axis=(0, 1))
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape not in ((H, W), (n, H, W)):
            raise ValueError(f"valid must be ({H}, {W}) or ({n}, {H}, {W}), got {v.shape}")
        used &= v if v.ndim == 2 else np.all(v, axis=0)
    used = _trimmed_sides(used, loaded_edge)
    rows = np.count_nonzero(used)
    if rows < 16:
        raise ValueError(f"the virtual fields need usable pixels (finite strains with a "
                         f"positive std in every state, inside valid), got {rows}")
    if specimen is not None:
        spec = np.asarray(specimen, dtype=bool)
        if spec.shape != (H, W):
            raise ValueError(f"specimen must be ({H}, {W}), got {spec.shape}")
        fraction, n_cut = _cut_fraction(used, spec, loaded_edge)
        if fraction > MAX_CUT_FRACTION:
            raise ValueError(
                f"the region used stops short of the specimen's free edges along {n_cut} "
                f"px of its boundary ({fraction:.0%}): the load carried between it and "
                f"the edges is missing from the virtual work (a bias, not noise). The "
                f"maps stop a margin from the specimen's edges; the virtual fields need "
                f"data up to them, or a region whose sides other than the loaded and "
                f"gripped ones are free edges")
    return e, s, load, used


def _each_state(mesh, T, values, stds, load, model_cls, kw):
    """E, nu and their std identified from each state alone (NaN where a state
    cannot give them: the reference at zero load, a state that does not separate
    E from nu); one state: left to the combined identification."""
    n = load.size
    E_k, nu_k, sE_k, snu_k = (np.full(n, np.nan) for _ in range(4))
    for i in range(n if n > 1 else 0):  # one state: the combined identification is its
        if load[i] == 0:
            continue
        try:
            p, cov, _, _, _ = special_fields(mesh, T, values[i], stds[i], load[i],
                                             model_cls, **kw)
        except NotIdentifiable:
            continue
        if model_cls.plausible(p):
            (E_k[i], nu_k[i]), c = model_cls.constants(p, cov)
            sE_k[i], snu_k[i] = np.sqrt(np.diag(c))
    return E_k, nu_k, sE_k, snu_k


def virtual_fields(strain, std, load, *, thickness: float, loaded_edge: str,
                   load_direction: str, pixel_size: float, unit: str = "mm",
                   load_unit: str = "N", valid=None, specimen=None, correlation=None,
                   elements=None, states=None, model: str = "isotropic") -> VirtualFields:
    """Young's modulus and Poisson's ratio from strain maps and loads, by the virtual
    fields method with the noise-optimal special virtual fields.

    Parameters
    ----------
    strain : (n_states, 3, H, W) array_like
        ``exx, eyy, exy`` (tensor shear) of each loaded state against the
        reference, dimensionless (:mod:`gridstrain.conventions`).
    std : (n_states, 3, H, W) array_like
        Their per-pixel standard deviations (the result's ``*_std`` maps).
    load : (n_states,) array_like
        The load of each state, ``load_unit``: the component along +x (or +y, see
        ``load_direction``) of the resultant force that acts on the specimen through
        ``loaded_edge`` (a tensile test loaded on the right is positive).
    thickness : float
        The specimen's thickness, ``unit``.
    loaded_edge : {"left", "right", "top", "bottom"}
        The region's edge that carries the load; the opposite one is gripped. Top is
        row 0.
    load_direction : {"x", "y"}
    pixel_size : float
        Side of a pixel, ``unit``.
    unit, load_unit : str
        With ``"mm"`` and ``"N"`` (defaults) the moduli are in MPa.
    valid : (n_states, H, W) or (H, W) bool array_like, optional
        The pixels to integrate (default: where every map is finite); a region is a
        ``valid`` cut to it.
    specimen : (H, W) bool array_like, optional
        The specimen's pixels (a result's ``mask``): when given, a used region whose
        boundary (its loaded and gripped sides aside) faces specimen pixels left out
        along more than 5 % of its length is refused, its edges not being free.
    correlation : sequence of 3 (2R+1, 2R+1) array_like, optional
        The correlation of the noise of ``exx``, ``eyy`` and ``exy`` between two
        pixels as a function of their offset ``[dy, dx]`` (centre 1, even): a
        measured result's, from its window (:func:`gridstrain.post.strain_noise_correlation`).
        Default: independent pixels, which understates the noise that the window's
        smoothing puts at the scale of the elements.
    elements : (int, int), optional
        ``(ny, nx)`` elements of the virtual fields' mesh over the used pixels' box.
        Default: about square, 8 along the longer side.
    states : sequence of str, optional
        The states' names.
    model : {"isotropic"}

    Returns
    -------
    VirtualFields

    Raises
    ------
    NotIdentifiable
        A ``ValueError`` when the fields cannot separate E from nu (a uniform shear
        gives only G; an equibiaxial field only E / (1 - nu)), or when the noise leaves
        nu's interval wider than the range an isotropic solid allows, (-1, 0.5).

    Notes
    -----
    The principle of virtual work over the used pixels, each of area
    ``pixel_size^2``, with bilinear virtual fields on a rectangular mesh: zero on the
    edge opposite to ``loaded_edge``, a rigid translation along ``load_direction`` on
    ``loaded_edge`` (so that only the measured resultant works), free elsewhere. The
    edges of the used region other than the loaded and the gripped ones must be free
    of traction, and the loaded and gripped edges must be cross-sections that carry the
    whole load: integrating a region that stops short of a free edge leaves that
    edge's traction out (a bias; ``specimen`` detects it). Among the special fields
    (each gives one stiffness component directly), those of least variance from the
    stated strain noise are taken, computed again with the identified stiffness until
    it settles (Avril & Pierron 2004); their variance is the method's own.

    The states are combined before the identification: per pixel, the strains are
    fitted against the load (weighted by their std) and the slope, the strain per
    unit load, is identified with a unit load; the intercept takes up the reference
    image's noise, common to every state, and any preload. Each state is also
    identified on its own. The internal virtual work of each state in the combined
    special fields is linear in the load (plus an intercept): when it scatters about
    that straight line more than the stated std explains (reduced chi2
    above 1: a non-linearity, a slipping grip, a wrong load), that component's std is
    scaled by the square root of its reduced chi2 and Student's quantile is used, with
    n - 2 degrees of freedom (n - 1 through zero): the wider of the two intervals.
    Intervals are ``value +- q std``, ``E`` and ``nu`` from the stiffness components
    to first order. The noise of two pixels is correlated as ``correlation`` says
    (independent without it); the three components' noises are taken as independent
    of each other. The noise also enters the equations themselves (the fields are
    drawn from the noisy strains): its expected share of ``A H^-1 A'`` is taken out
    (errors in variables), and a test where that share is more than a tenth of the
    weakest combination is refused.

    References
    ----------
    S. Avril, F. Pierron, "General framework for the identification of constitutive
    parameters from full-field measurements in linear elasticity", Int. J. Solids
    Struct. 44 (2007) 4978-5002, https://doi.org/10.1016/j.ijsolstr.2006.12.018.
    S. Avril, M. Grédiac, F. Pierron, "Sensitivity of the virtual fields method to
    noisy data", Comput. Mech. 34 (2004) 439-452,
    https://doi.org/10.1007/s00466-004-0589-6.
    F. Pierron, M. Grédiac, The Virtual Fields Method, Springer (2012),
    https://doi.org/10.1007/978-1-4614-1824-5.
    """
    thickness = check_positive(thickness, "thickness")
    pixel_size = check_positive(pixel_size, "pixel_size")
    loaded_edge = check_choice(loaded_edge, "loaded_edge", ("left", "right", "top",
                                                            "bottom"))
    load_direction = check_choice(load_direction, "load_direction", ("x", "y"))
    model_cls = _MODELS[check_choice(model, "model", tuple(_MODELS))]
    e, s, load, used = _checked_maps(strain, std, load, valid, specimen, loaded_edge)
    n = e.shape[0]
    if states is None:
        states = tuple(f"state {i}" for i in range(n))
    rows, cols = np.nonzero(used)
    elements = _check_elements(elements, rows, cols)
    mesh = Mesh(rows, cols, pixel_size, elements)
    T = mesh.kinematics(loaded_edge, load_direction)
    values = e[:, :, rows, cols]
    stds = s[:, :, rows, cols]
    factor, stress_unit = _stress_unit(load_unit, unit)
    correlation = _check_correlation(correlation)
    kw = {"thickness": thickness, "correlation": correlation}

    E_k, nu_k, sE_k, snu_k = _each_state(mesh, T, values, stds, load, model_cls, kw)
    slope, slope_std, combined = _slopes(values, stds, load)
    p, cov, fields, iterations, _ = special_fields(mesh, T, slope, slope_std, 1.0,
                                                   model_cls, **kw)
    if not model_cls.plausible(p):
        found = ", ".join(f"{k} = {v:.4g}" for k, v in zip(model_cls.parameters, p * factor,
                                                           strict=True))
        raise NotIdentifiable(
            f"the identified stiffness is not one of a solid ({found} {stress_unit}): the "
            f"fields do not separate E from nu, or the loads, edges or direction are wrong")
    (E, nu), c = model_cls.constants(p, cov)
    sE, snu = (float(v) for v in np.sqrt(np.diag(c)))
    if n == 1:
        E_k[0], nu_k[0], sE_k[0], snu_k[0] = E, nu, sE, snu
    from scipy import stats  # loaded when used: the face imports light

    q = float(stats.norm.ppf(0.5 + LEVEL / 2))
    chi = (math.nan,) * len(p)
    basis = "stated std"
    dof = n - (2 if combined == "slope" else 1)
    if dof >= 1:
        chi = _scatter(mesh, values, stds, load, p, fields, model_cls, combined, thickness,
                       correlation)
        if max(chi) > 1.0:
            basis = "scatter over states"
            q = float(stats.t.ppf(0.5 + LEVEL / 2, dof))
            d = np.sqrt(np.maximum(chi, 1.0))
            # never narrower than the stated std's (a correlation could shrink one)
            c = model_cls.constants(p, cov * np.outer(d, d))[1]
            sE, snu = (max(a, float(b)) for a, b in zip((sE, snu), np.sqrt(np.diag(c)),
                                                       strict=True))
    lo_nu, hi_nu = model_cls.nu_range
    if 2 * q * snu > hi_nu - lo_nu:
        raise NotIdentifiable(
            f"the measured fields do not separate E from nu: nu = {nu:.3g} with a 95 % "
            f"interval [{nu - q * snu:.3g}, {nu + q * snu:.3g}], wider than the range an "
            f"isotropic solid allows ({lo_nu:g}, {hi_nu:g}); a heterogeneous field (a "
            f"hole, a notch, bending) or less noise is needed")
    if E - q * sE <= 0:
        raise NotIdentifiable(
            f"E = {E * factor:.4g} {stress_unit} with a 95 % interval reaching "
            f"{(E - q * sE) * factor:.4g}: the noise swamps the virtual work")
    nodes = fields.reshape(fields.shape[0], elements[0] + 1, elements[1] + 1, 2)
    return VirtualFields(
        E=E * factor, E_interval=((E - q * sE) * factor, (E + q * sE) * factor), nu=nu,
        nu_interval=(nu - q * snu, nu + q * snu), E_std=sE * factor, nu_std=snu,
        stress_unit=stress_unit, model=model_cls.name,
        parameters={k: float(v) * factor for k, v in zip(model_cls.parameters, p,
                                                          strict=True)},
        parameters_cov=cov * factor**2, states=tuple(states), load=load,
        load_unit=load_unit, E_states=E_k * factor, nu_states=nu_k,
        E_states_std=sE_k * factor, nu_states_std=snu_k, combined=combined,
        interval_basis=basis, reduced_chi2=chi, elements=elements, fields=nodes,
        used=used, n_pixels=int(rows.size), iterations=iterations, thickness=thickness,
        pixel_size=pixel_size, unit=unit, loaded_edge=loaded_edge,
        load_direction=load_direction)
