"""The noise floors of a series measurement: the theory's (the measured sensor noise through
the transform, eqs. 34-35) and the split reference's (the reference's two halves measured
against each other), and the systematic errors worth a warning.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from collections.abc import Sequence

import numpy as np

from .. import theory
from .._progress import Finding, Progress
from .._stats import median
from .._validation import (
    check_positive,
)
from ..kinematics import (
    Measurement,
    eulerian_gradient,
    phase_products,
    small_strain,
    solve_k,
)
from ..phase import (
    EDGE_HARMONIC_SPREAD,
    Lattice,
    PhaseMaps,
    Window,
    edge_harmonic_bias,
    edge_noise_gain,
    edge_pixels,
    finite_derivatives,
    transform,
)
from ..stacks.accumulate import SeriesPass
from ..uncertainty import (
    SPATIAL_RESOLUTION_PER_SIGMA,
    NoiseFloor,
    NoiseModel,
    aliasing_advice,
    estimate_noise_image,
    noise_weighted,
    phase_variance,
    smoothing_bias,
    std_from_phase_variance,
)
from ._records import _Measured, _Stats, _Summary

# Aliasing of the grid's harmonics is flagged only above this displacement error, px
# (when the noise is lower still): below it no measurement can tell it from noise.
_ALIAS_MIN_PX = 1e-3
# ... and above this many times the median displacement noise std: a bound (the two
# images' terms in phase) within twice the noise does not stand out of it.
_ALIAS_FACTOR = 2.0



# The reference's side of every state's theory floor is the same: kept, not computed
# again for each state (two of the four calls, 0.04 ms a state of 250 x 400 px, one core)
_wft_noise_std = functools.lru_cache(maxsize=8)(theory.wft_noise_std)


def _theory_floor(var_ref, T_ref, mod_ref, var_s, T_s, mod_s, sigma, lattice):
    """(2,) px and (3,) strain from the WFT noise theory; NaN when unavailable."""
    if not (math.isfinite(var_ref) or math.isfinite(var_s)):
        return np.full(2, np.nan), np.full(3, np.nan)
    # a single-frame series is taken as noisy per frame as the other one
    var_ref = var_ref if math.isfinite(var_ref) else var_s
    var_s = var_s if math.isfinite(var_s) else var_ref
    if not (np.all(np.isfinite(mod_ref)) and np.all(np.isfinite(mod_s))):
        return np.full(2, np.nan), np.full(3, np.nan)
    ph_r, d_r, ph_s, d_s = [], [], [], []
    for j in range(2):
        p, d = _wft_noise_std(var_ref / T_ref, float(mod_ref[j]), sigma)  # Prop. 2.3
        ph_r.append(p)
        d_r.append(d)
        p, d = theory.wft_noise_std(var_s / T_s, float(mod_s[j]), sigma)  # its own
        ph_s.append(p)
        d_s.append(d)
    su = theory.displacement_noise_std(ph_r, ph_s, lattice)  # eq. (34)
    se = theory.strain_noise_std(d_r, d_s, lattice)  # eq. (35)
    return su, se


def _split_floor(acc: SeriesPass, lattice, window: Window, mask, method: str, report,
                 mean_maps: PhaseMaps | None = None):
    """Spatial std of a half-against-half measurement of the reference, from the
    halves' sums of its pass (method A, or method C when it was the method).

    With ``mean_maps``, the maps of the mean of all the kept frames (method A's
    reference maps, same mask), only the first half is transformed: the mean is
    ``m = h1 + (n2 / T) (h2 - h1)`` and the transform is linear, so that to first
    order in the noise every map of eqs. (34)-(35) moves from ``h1`` to ``m`` by
    ``n2 / T`` of its move to ``h2``: ``std(h2 - h1) = (T / n2) std(m - h1)``. The
    phase difference is ``Im log(1 + r)`` with ``r`` the ratio of the halves'
    difference to the transform (phase noise, 1e-4 to 1e-2 rad), so the second-order
    term changes the std by about ``|r| n1 / 2T`` of itself, below 0.5 % and below
    the std's own sampling error (1 % for the 4,500 independent windows of a
    megapixel map at sigma = 5 px). The large-displacement correction is left out
    (eqs. 34-35 as printed, :func:`_difference_std`): it would evaluate the second
    maps at ``x + u`` instead of ``x``, a change of ``-(1/2pi) K^-1 grad(phi) u`` in
    ``u``, where the carrier's ``2 pi K u`` is already eq. (34)'s own term and what
    is left is the grid's own phase modulation: its gradient, at most 5e-3 rad/px in
    the paper's example against ``2 pi / p = 1.26`` rad/px at a 5-px pitch, makes it
    0.4 % of ``u``. Between two halves of a static series ``u`` is noise (1e-3 px)
    and their mean vibration shifts (0.02 px at most): 1e-4 px, added in quadrature
    to a noise floor ten times larger.
    """
    n1, n2 = acc.half_counts()
    if mean_maps is not None and method == "A":
        img = acc.half_means()[0]
        h1 = finite_derivatives(transform(img, lattice, window, mask=mask, workers=None))
        report(2 / 3, "half 1 of the reference")
        su, se = _difference_std(h1, mean_maps)
        report(1.0, "half against the whole")
        scale = (n1 + n2) / n2
        return su * scale, se * scale
    halves = []
    for h in (0, 1):
        if method == "C":
            halves.append(acc.method_c(mask=mask, halves=(h,)).maps)
        else:
            img = acc.half_means()[h]
            halves.append(transform(img, lattice, window, mask=mask, workers=None))
        report((h + 1) / 3, f"half {h + 1} of the reference")
    su, se = _difference_std(finite_derivatives(halves[0]), finite_derivatives(halves[1]))
    report(1.0, "half against half")
    return su, se


def _difference_std(a: PhaseMaps, b: PhaseMaps) -> tuple[np.ndarray, np.ndarray]:
    """Spatial std (ddof 1) of the displacement (2,) and small strain (3,) between
    two phase-map sets of a static specimen, over the pixels valid in both: eqs.
    (34)-(35) without the large-displacement correction, as
    :func:`gridstrain.kinematics.deformation` gives them with ``lagrangian=False``,
    on the valid pixels only (the maps differ by noise: no phase wraps, and whole
    periods would not change a standard deviation).

    Computed by bands of rows that stay in cache, their means and sums of squared
    deviations merged exactly (Chan et al.'s pairwise update): no map-sized
    temporary."""
    valid = a.valid & b.valid & np.all(np.isfinite(a.dphi), axis=(0, 1))
    K = a.lattice.K
    n, mean, m2 = 0, np.zeros(5), np.zeros(5)
    for rows, v, z in phase_products(a, b, valid):
        k = z.shape[1]
        dD = b.dphi[:, :, rows][:, :, v].astype(np.float64)
        dD -= a.dphi[:, :, rows][:, :, v]
        q = np.concatenate([-solve_k(K, np.angle(z)) / (2 * np.pi),  # eq. (34)
                            small_strain(eulerian_gradient(K, dD))])  # eq. (35)
        qm = q.mean(axis=1)
        qm2 = ((q - qm[:, None]) ** 2).sum(axis=1)
        delta = qm - mean
        tot = n + k
        mean = mean + delta * (k / tot)
        m2 = m2 + qm2 + delta**2 * (n * k / tot)
        n = tot
    if n < 2:
        return np.full(2, np.nan), np.full(3, np.nan)
    std = np.sqrt(m2 / (n - 1))
    return std[:2], std[2:]


def _check_noise_model(noise_model):
    """A NoiseModel from ``noise_model`` (a NoiseModel or a (K, L) pair), or None."""
    if noise_model is None or isinstance(noise_model, NoiseModel):
        if noise_model is not None and not noise_model.K > 0:
            raise ValueError(f"noise_model: K must be positive, got {noise_model.K!r}")
        return noise_model
    if isinstance(noise_model, str | bytes) or not isinstance(noise_model, Sequence) \
            or len(noise_model) != 2:
        raise TypeError(f"noise_model must be a NoiseModel or a (K, L) pair in stored grey "
                        f"levels, got {noise_model!r}")
    K = check_positive(noise_model[0], "noise_model K")
    L = noise_model[1]
    if isinstance(L, bool) or not isinstance(L, numbers.Real) or not math.isfinite(L):
        raise ValueError(f"noise_model L must be a finite number of grey levels^2, got {L!r}")
    return NoiseModel(K=K, L=float(L), method="given")


def _check_model_units(given, series) -> None:
    """Refuse a given noise model in other units than the series' grey levels."""
    if given is None:
        return
    for s in series:
        if s.bit_depth is not None and given.bit_depth is not None \
                and given.bit_depth != s.bit_depth:
            raise ValueError(f"noise model: estimated on {given.bit_depth}-bit images but "
                             f"{s.name} is {s.bit_depth}-bit; estimate it on this camera's "
                             "images or give --noise-model K L in their stored units")
        if given.method != "given" and given.scale != s.scale:
            raise ValueError(f"noise model: estimated on images stored x{given.scale:g} but "
                             f"{s.name} is stored x{s.scale:g}; its K and L are in other "
                             "units")


def _describe_model(model, what: str) -> str:
    return (f"{what}: Var = K l + L, K = {model.K:.4g}, L = {model.L:.4g} (stored grey "
            "levels)")


class _Noise:
    """The per-frame noise variance map of each series, series by series.

    A given camera model sets every series' variance to ``K mean + L``; otherwise
    the series of two frames or more keep their temporal variance, and those of one
    frame get the model estimated from one image (:func:`estimate_noise_image`),
    on the first such series met (the camera is the same).
    """

    def __init__(self, given, lattice: Lattice, ref_mask: np.ndarray, warnings: list):
        self.given, self.lattice, self.ref_mask = given, lattice, ref_mask
        self.warnings = warnings
        self.model = self.how = self.estimated_on = None
        self.failed = False
        self.singles = 0
        self._first = True

    @staticmethod
    def _from_model(r: _Measured, model, how: str) -> _Measured:
        st = r.stats
        var = np.maximum(model.K * st.mean + model.L, 0.0)
        return dataclasses.replace(r, stats=_Stats(st.mean, var, how, st.saturation))

    def complete(self, r: _Measured) -> _Measured:
        """``r`` with its noise variance map."""
        is_ref, self._first = self._first, False
        if self.given is not None:
            return self._from_model(r, self.given, _describe_model(
                self.given, f"camera model ({self.given.method})"))
        if r.stats.variance is not None:
            return r
        self.singles += 1
        if self.model is None and not self.failed:
            s0 = r.series
            try:
                model = estimate_noise_image(r.stats.mean, self.lattice,
                                             mask=self.ref_mask if is_ref else None,
                                             saturation=s0.saturation_level, scale=s0.scale)
            except ValueError as exc:
                self.warnings.append(Finding(
                    "noise.unavailable",
                    f"{s0.name}: the noise could not be estimated from its single image "
                    f"({exc}); the single-frame series get no uncertainty of their own "
                    "(give --noise or --noise-model)", state=s0.name))
                self.failed = True
                return r
            self.model = dataclasses.replace(model, bit_depth=s0.bit_depth)
            self.estimated_on = s0.name
            self.how = _describe_model(self.model, f"single image ({s0.name})")
        return r if self.failed else self._from_model(r, self.model, self.how)

    def info(self, done: list) -> dict:
        """Where the variances came from (``NoiseFloor.model``)."""
        if self.given is not None:
            return {"source": f"given ({self.given.method})", **self.given.as_dict()}
        if self.singles == 0:
            return {"source": "stack"}
        if self.failed:
            return {"source": "unavailable"}
        source = "single image" if self.singles == len(done) else "stack and single image"
        return {"source": source, "estimated_on": self.estimated_on, **self.model.as_dict()}


class _ReferenceFloor:
    """The noise floor and uncertainty of every state against the reference.

    Holds the reference's maps and the half-against-half measurement of its frames;
    :meth:`state` gives one state's floors, uncertainty maps and systematic-error
    figures (with their warnings), :meth:`noise_floor` the table of them all.
    """

    def __init__(self, r: _Measured, summary: _Summary, ref_pass: SeriesPass,
                 lattice: Lattice, window: Window, method: str, report: Progress,
                 warnings: list, *, to_edges: bool = False):
        self.r, self.lattice, self.sigma = r, lattice, window.sigma
        # measured up to the edges: the factors on the std there (gridstrain.phase)
        self.edge_gain = edge_noise_gain(r.mask, lattice, window) if to_edges else None
        self.edge_fit: list = [None]  # the smoothing bound's edge fit, kept for the run
        # ... and the bias the print's harmonics leave there (stated once a run)
        self.edge_bias = _edge_band_bias(r, lattice, window) if to_edges else None
        self.alias_said = False  # the aliasing's warning, given once a run
        T1, T2 = ref_pass.half_counts()
        if min(T1, T2) >= 1:
            self.su, self.se = _split_floor(ref_pass, lattice, window, r.mask, method, report,
                                            mean_maps=r.maps)
        else:
            self.su, self.se, (T1, T2) = np.full(2, np.nan), np.full(3, np.nan), (1, 1)
            warnings.append(Finding(
                "noise.single_reference", "a single reference frame: no split-halves noise "
                "estimate (measure a second image of the unloaded specimen as a state: its "
                "maps are the noise floor)"))
        self.T1, self.T2 = T1, T2
        self.sr = summary
        self.local_ref = self._local(r)
        self.var_ref_phase = None  # the reference's phase variance (_uncertainty)
        self.r = r.dropping("variance")  # only its smoothed copy is used from here on
        self.rows: dict[str, list] = {k: [] for k in ("theory_u", "theory_strain", "split_u",
                                                      "split_strain", "vibration_u")}

    def _local(self, r: _Measured, where=None):
        """The sensor's variance of ``r`` averaged as its noise enters Psi; with
        ``where``, at the box of those pixels alone (NaN elsewhere)."""
        if r.stats.variance is None:
            return None
        # the weight of a pixel's noise in Psi is g^2, a Gaussian of std sigma / sqrt 2
        return noise_weighted(r.stats.variance, self.sigma, where=where)

    def state(self, c: _Measured, sc: _Summary, res: Measurement, alias: dict,
              warnings: list) -> tuple:
        """``(uncertainty maps or None, floors)`` of state ``c`` (summarised in
        ``sc``); the aliasing's warning, once a run, appended to ``warnings``."""
        ref = self.sr
        th_u, th_e = _theory_floor(ref.variance, ref.T, ref.modulus, sc.variance, sc.T,
                                   sc.modulus, self.sigma, self.lattice)
        scale = math.sqrt((1 / ref.T + 1 / sc.T) / (1 / self.T1 + 1 / self.T2))
        vib_u = np.full(2, np.nan)
        offs = [np.array(v.phase_offset_std) for v in (ref.vib, sc.vib)]
        if all(np.all(np.isfinite(o)) for o in offs):
            # the offsets are phases: eq. (34) turns them into a rigid translation
            vib_u = theory.displacement_noise_std(offs[0], offs[1], self.lattice)
        row = {"theory_u": th_u, "theory_strain": th_e, "split_u": self.su * scale,
               "split_strain": self.se * scale, "vibration_u": vib_u}
        unc, medians = self._uncertainty(c, res)
        if ref.kept_flagged or sc.kept_flagged:
            # frames flagged but kept: the precision of this state is not known
            row = {k: np.full_like(np.asarray(v, dtype=float), np.nan) for k, v in row.items()}
            if unc is not None:
                unc = {k: np.full_like(v, np.nan) for k, v in unc.items()}
                medians = None
        for k, v in row.items():
            self.rows[k].append(np.asarray(v, dtype=float))
        if unc is not None and res.valid.any():
            floors = {k.removesuffix("_std"): median(a[res.valid], overwrite_input=True)
                      for k, a in unc.items()} if medians is None else \
                dict(zip(("ux", "uy", "exx", "eyy", "exy"), medians, strict=True))
        else:
            floors = {"ux": float(row["theory_u"][0]), "uy": float(row["theory_u"][1]),
                      "exx": float(row["theory_strain"][0]),
                      "eyy": float(row["theory_strain"][1]),
                      "exy": float(row["theory_strain"][2])}
        if self.edge_bias is not None:
            said = _edge_harmonics_warning(c.name, self.edge_bias, unc, res, floors)
            self.edge_bias = None
            if said is not None:
                warnings.append(said)
        if not self.alias_said:  # the reference's print at its pitch: once a run
            said = _aliasing_warning(c.name, res, floors, alias, self.lattice)
            if said is not None:
                warnings.append(said)
                self.alias_said = True
        return unc, floors

    def smoothing(self, name: str, res: Measurement, floors: dict) -> tuple:
        """``(record, warnings)`` of the window's smoothing of state ``name``'s strain
        gradients (:func:`smoothing_bias`), against its ``floors``."""
        smooth = smoothing_bias(res.strain, res.valid, sigma=self.sigma, keep=self.edge_fit)
        smooth["computed"] = True
        return smooth, _smoothing_warnings(name, res, floors, smooth)

    @staticmethod
    def smoothing_not_computed(why: str) -> dict:
        """The smoothing record of a state it was not computed on: every figure None,
        ``why`` in its definition."""
        none3 = [None, None, None]
        return {"max": none3, "estimate_max": none3, "p95": none3,
                "feature_error": none3, "attenuation": none3,
                "below_resolution": [False, False, False], "factor": math.nan,
                "definition": f"not computed: {why}", "computed": False}

    def _uncertainty(self, c: _Measured, res: Measurement):
        """``(maps, medians)``: the state's uncertainty maps (None without a noise
        variance) and their medians over its valid pixels, ``[ux, uy, exx, eyy,
        exy]`` (None where the maps are not those :func:`std_from_phase_variance`
        gives: scaled up to the edges)."""
        # the maps are read at the state's valid pixels alone (NaN elsewhere)
        local = self._local(c, res.valid)
        # a single-frame series is taken as noisy per frame as the other one
        v_ref = self.local_ref if self.local_ref is not None else local
        v_def = local if local is not None else self.local_ref
        if v_ref is None:
            return None, None
        if self.local_ref is None:
            var_ref = phase_variance(self.r.maps, v_ref / self.sr.T)
        else:  # the reference's side, the same for every state: made once
            if self.var_ref_phase is None:
                self.var_ref_phase = phase_variance(self.r.maps, v_ref / self.sr.T)
            var_ref = self.var_ref_phase
        T = c.series.n_frames
        # a one-frame state's variance as it is (x / 1 is x): no map of its quotient
        u_std, strain_std, *medians = std_from_phase_variance(
            var_ref, c.maps, variance_def=v_def if T == 1 else v_def / T, valid=res.valid,
            medians=self.edge_gain is None)
        if self.edge_gain is not None:
            u_std *= self.edge_gain[0]
            strain_std *= self.edge_gain[1]
        names = ("ux_std", "uy_std", "exx_std", "eyy_std", "exy_std")
        return dict(zip(names, (*u_std, *strain_std), strict=True)), \
            (medians[0] if medians else None)

    def noise_floor(self, done: list, model_info: dict) -> NoiseFloor:
        n = len(done) - 1
        rows = {k: np.array(v, dtype=float).reshape(n, 2 if k.endswith("_u") else 3)
                for k, v in self.rows.items()}
        return NoiseFloor(sigma=self.sigma, sensor_variance=tuple(d.variance for d in done),
                          variance_method=tuple(d.variance_method for d in done),
                          modulus=np.array([d.modulus for d in done]), model=model_info,
                          frames=tuple(int(d.T) for d in done), **rows)


# The edge band's harmonic bias (its bound, twice EDGE_HARMONIC_SPREAD times one
# image's, noise-free: gridstrain.phase.edge_harmonic_bias) is stated where it exceeds
# this many times the band's largest stated strain std: the bias the std maps miss.
_EDGE_BIAS_NOISE = 1.0
# ... and this strain: a cosine print's noise-free 1e-7 stays unsaid.
_EDGE_BIAS_MIN = 1e-5


def _edge_band_bias(r: _Measured, lattice: Lattice, window: Window) -> dict:
    """The reference's one-image strain bias from its print's harmonics in the edge
    band of its mask (:func:`edge_harmonic_bias`): the band, its largest value per
    component, and the band's width."""
    band = edge_pixels(r.mask, window)
    if not band.any():
        return {"band": band, "one_image": np.zeros(3), "band_px": float(window.band),
                "margin": float(window.margin)}
    b = edge_harmonic_bias(r.stats.mean, lattice, window, mask=r.mask)
    return {"band": band, "one_image": np.abs(b[:, band]).max(axis=1),
            "band_px": float(window.band), "margin": float(window.margin)}


def _edge_harmonics_warning(name: str, eb: dict, unc, m: Measurement,
                            fl: dict) -> Finding | None:
    """The warning of the edge band's bias from the print's harmonics (not continued
    beyond the edges) where it stands out of the band's noise, or None: one image's
    bias seen on the reference, times :data:`EDGE_HARMONIC_SPREAD` for another
    position of the grid against the edges, twice for two images."""
    comps = ("exx", "eyy", "exy")
    band = eb["band"] & m.valid
    if not band.any():
        return None
    if unc is not None:
        noise = np.array([float(np.nanmax(unc[f"{k}_std"][band])) for k in comps])
    else:
        noise = np.array([fl[k] for k in comps], dtype=float)
    noise = np.where(np.isfinite(noise), noise, 0.0)
    one = eb["one_image"]
    bound = 2 * EDGE_HARMONIC_SPREAD * one
    if not np.any((bound > _EDGE_BIAS_NOISE * noise) & (bound > _EDGE_BIAS_MIN)):
        return None
    return Finding(
        "edges.harmonics",
        f"{name}: the print's harmonics are not continued beyond the edges: the strain "
        f"within {eb['band_px']:.3g} px ({eb['margin']:g} sigmas) of the mask's edges "
        f"may be biased by up to {bound[0]:.2g} (e_xx), {bound[1]:.2g} (e_yy), "
        f"{bound[2]:.2g} (e_xy), not held by the std maps (one image's bias seen on the "
        f"reference, up to {one.max():.2g}, times {EDGE_HARMONIC_SPREAD:g} for another "
        "position of the grid against the edges and twice for two images); a "
        "sinusoidal print, or leave that band out, or measure without --to-edges",
        state=name, strain_bias=[float(v) for v in bound], band_px=eb["band_px"],
        one_image=[float(v) for v in one])


def _aliasing_warning(name: str, m: Measurement, fl: dict, alias: dict,
                      lattice: Lattice) -> str | None:
    """The warning of the harmonics' aliasing where its bound exceeds the state's
    noise, or None. The bound is the reference's print at its pitch, the same for
    every state: the series gives it once."""
    known = [fl[k] for k in ("ux", "uy") if math.isfinite(fl[k])]
    u_noise = max(known) if known else 0.0
    noise_txt = f"{u_noise:.2g} px" if known else "unknown"
    if not alias["u_px"] > max(_ALIAS_FACTOR * u_noise, _ALIAS_MIN_PX):
        return None
    how = ("measured on the reference image" if alias["observable"] else
           "a sharp print's scaled by the sharpness seen on the harmonics of their "
           "parity elsewhere: harmonics on the carrier cannot be seen in one image")
    e_max = float(np.max(np.abs(m.strain[:, m.valid]))) if m.valid.any() else 0.0
    ux, uy = alias.get("u_px_components", [alias["u_px"]] * 2)
    e_bound = alias["strain_per_strain"] * e_max + alias.get("strain_ripple", 0.0)
    ratio = f", {alias['u_px'] / u_noise:.0f} times the noise std ({noise_txt})" \
        if known and u_noise > 0 else f" (noise {noise_txt})"
    return (f"{name}: harmonics of the grid alias onto the carrier at pitch "
            f"{lattice.pitch:.3g} px: displacement error up to {ux:.2g} px (u_x) and "
            f"{uy:.2g} px (u_y), periodic in the displacement, and strain error up "
            f"to {e_bound:.2g} (amplitudes {how}){ratio}; "
            + aliasing_advice(alias, lattice, u_noise if known else _ALIAS_MIN_PX)
            + " (the reference's print at its pitch: the states after it share the bound)")


def _smoothing_warnings(name: str, m: Measurement, fl: dict, smooth: dict) -> list[str]:
    """Warnings for the window's smoothing of one state's strain gradients where its
    bias can exceed the noise."""
    out = []
    for j, comp in enumerate(("exx", "eyy", "exy")):
        b, bound = smooth["estimate_max"][j], smooth["max"][j]
        e_noise = fl[comp]
        # noise alone takes the largest sigma^2/2 lap(e) to about 1.1 noise std on a
        # 200 x 200 field, 1.5 on 2000 x 2000: 2.5 times it is signal
        if b is None or not math.isfinite(e_noise) or b <= 2.5 * e_noise or b <= 1e-6:
            continue
        text = (f"{name}: the window smooths the {comp} gradients: its bias may reach "
                f"{bound:.2g} (the larger of {smooth['factor']:g} x the largest sigma^2/2 "
                "lap(e) and 1.5 x the sharpest feature's deconvolved peak error) against "
                f"a noise std of {e_noise:.2g}")
        if smooth["below_resolution"][j]:
            text += (f"; the sharpest feature is at or below the spatial resolution "
                     f"({SPATIAL_RESOLUTION_PER_SIGMA * m.sigma:.3g} px): its peak may be "
                     f"lowered by up to {smooth['attenuation'][j]:.0%}")
        out.append(text + "; a smaller sigma resolves them better at the cost of noise")
    return out
