"""The precision policy of gridstrain.conventions, held by every public entry point.

float32 images give float32 maps (``psi`` complex64, ``dphi``, ``u``, strain, an
Anscombe-transformed image); any other input (integers, float64) gives float64
maps; sums, shifts, statistics and uncertainties are float64 whatever the input.

Frames: a cross-line grid of pitch 5 px, ``I = 120 + 50 (cos(2 pi x / 5) +
cos(2 pi y / 5))``, point-sampled, plus Poisson-Gaussian noise of variance
``0.3 I + 4`` (normal approximation), rounded into [0, 255] so that the same values
fit uint8, uint16 and the floats; generated here with numpy alone. The second state
is the same grid stretched by 1e-3 along x.
"""

from __future__ import annotations

import importlib
import numbers

import numpy as np
import pytest

import gridstrain
from gridstrain import Lattice, phase, series, stacks, uncertainty
from gridstrain.phase import wft_complex

LAT = Lattice.from_pitch(5.0)
N = 64
DTYPES = (np.float32, np.float64, np.uint16, np.uint8)


def _frames(T, strain=0.0, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:N, 0:N].astype(np.float64)
    X = (x + strain * (N - 1) / 2) / (1 + strain)
    i = 120 + 50 * (np.cos(2 * np.pi * X / 5) + np.cos(2 * np.pi * y / 5))
    out = [i + np.sqrt(0.3 * i + 4.0) * rng.standard_normal((N, N)) for _ in range(T)]
    return np.rint(np.clip(out, 0, 255))


def _precision(dtype):
    return np.dtype(np.float32) if np.dtype(dtype) == np.float32 else np.dtype(np.float64)


def _complex(dtype):
    return np.result_type(_precision(dtype), np.complex64)


def _ref_cur(dtype, T=3):
    return _frames(T).astype(dtype), _frames(T, strain=1e-3, seed=1).astype(dtype)


def _check_maps(pm, dtype):
    assert pm.psi.dtype == _complex(dtype)
    assert pm.dphi.dtype == _precision(dtype)


def _check_measurement(m, dtype):
    for name in ("u", "strain", "rotation"):
        assert getattr(m, name).dtype == _precision(dtype), name


# Each entry point: a function of the input dtype that runs it on images of that
# dtype and checks what it returns.
def _wft(dt):
    ref, _ = _ref_cur(dt)
    _check_maps(gridstrain.wft(ref[0], LAT), dt)


def _transform_to_edges(dt):
    ref, _ = _ref_cur(dt)
    from gridstrain.phase import Window, transform_to_edges

    mask = np.zeros((N, N), dtype=bool)
    mask[8:-8, 8:-8] = True  # a specimen smaller than the frame
    _check_maps(transform_to_edges(ref[0], LAT, Window(5.0), mask=mask), dt)


def _method_a(dt):
    ref, _ = _ref_cur(dt)
    res = stacks.method_a(ref, LAT)
    _check_maps(res.maps, dt)
    assert res.mean_image.dtype == np.float64  # a sum


def _method_b(dt):
    ref, _ = _ref_cur(dt)
    res = stacks.method_b(ref, LAT)
    _check_maps(res.maps, dt)
    assert res.resultant.dtype == np.float64


def _prefix_stacks(dt):
    ref, _ = _ref_cur(dt)
    for method in ("A", "B"):
        for res in stacks.prefix_stacks(ref, LAT, [1, 3], method=method):
            _check_maps(res.maps, dt)


def _correct_phases(dt):
    ref, _ = _ref_cur(dt)
    res = stacks.method_a(ref, LAT)
    _check_maps(stacks.correct_phases(res.maps, np.zeros((3, 2))), dt)


def _mean_image(dt):
    ref, _ = _ref_cur(dt)
    assert stacks.mean_image(ref).dtype == np.float64


def _measure(dt):
    ref, cur = _ref_cur(dt)
    _check_measurement(gridstrain.measure(ref[0], cur[0], lattice=LAT, guess=None), dt)


def _deformation(dt):
    ref, cur = _ref_cur(dt)
    m = gridstrain.deformation(gridstrain.wft(ref[0], LAT), gridstrain.wft(cur[0], LAT))
    _check_measurement(m, dt)
    # mixed precisions: float64 wins
    m = gridstrain.deformation(gridstrain.wft(ref[0], LAT),
                               gridstrain.wft(cur[0].astype(np.float64), LAT))
    _check_measurement(m, np.float64)


def _coarse_displacement(dt):
    ref, cur = _ref_cur(dt)
    est = gridstrain.coarse_displacement(ref[0], cur[0], LAT)
    assert np.asarray(est.shift).dtype == np.float64
    assert isinstance(est.correlation, numbers.Real)


def _measure_series(dt):
    ref, cur = _ref_cur(dt, T=4)
    for method in ("A", "B"):
        res = series.measure_series(ref, cur, lattice=LAT, guess=None, method=method)
        assert res.u.dtype == _precision(dt)
        assert res.strain.dtype == _precision(dt)
        _check_measurement(res.measurements[0], dt)
        assert res.reference_image.dtype == np.float64
        assert all(a.dtype == np.float64 for a in res.uncertainty.values())
        assert res.vibration[0].shifts.dtype == np.float64


def _predict_uncertainty(dt):
    ref, cur = _ref_cur(dt)
    u = gridstrain.predict_uncertainty(gridstrain.wft(ref[0], LAT), gridstrain.wft(cur[0], LAT),
                                       variance_ref=4.0, variance_def=4.0)
    assert all(np.asarray(a).dtype == np.float64 for a in (*u.u_std, *u.strain_std))


def _displacement_strain_std(dt):
    ref, cur = _ref_cur(dt)
    pa, pb = gridstrain.wft(ref[0], LAT), gridstrain.wft(cur[0], LAT)
    u, e = uncertainty.displacement_strain_std(pa, pb, variance_ref=4.0, variance_def=4.0,
                                               valid=pa.valid & pb.valid)
    assert u.dtype == e.dtype == np.float64  # as predict_uncertainty's


def _noise_variance_map(dt):
    ref, _ = _ref_cur(dt)
    v = uncertainty.noise_variance_map(ref[0], K=0.3, L=4.0, sigma=5.0)
    assert v.dtype == np.float64


def _noise_floor(dt):
    ref, _ = _ref_cur(dt)
    nf = uncertainty.noise_floor(gridstrain.wft(ref[0], LAT), ref[0], K=0.3, L=4.0)
    for a in (nf.theory_u, nf.theory_strain, nf.theory_phase, nf.theory_dphi, nf.modulus):
        assert a.dtype == np.float64
    assert all(isinstance(x, float) for x in nf.sensor_variance)


def _frame_shifts(dt):
    ref, _ = _ref_cur(dt)
    assert gridstrain.frame_shifts(ref, LAT).dtype == np.float64


def _vibration_report(dt):
    ref, _ = _ref_cur(dt)
    r = gridstrain.vibration_report(ref, LAT)
    assert all(getattr(r, k).dtype == np.float64
               for k in ("shifts", "std", "covariance", "contrast_factor", "phase_offset_std"))


def _screen_frames(dt):
    ref, _ = _ref_cur(dt)
    sc = stacks.screen_frames(ref, LAT)
    assert sc.deviation.dtype == np.float64
    assert sc.residual.dtype == np.float64
    assert sc.coefficients.dtype == np.complex128


def _anscombe(dt):
    ref, _ = _ref_cur(dt)
    z = gridstrain.anscombe(ref[0], K=0.3, L=4.0)
    assert z.dtype == _precision(dt)
    assert gridstrain.inverse_anscombe(z, K=0.3, L=4.0).dtype == _precision(dt)


def _estimate_noise(dt):
    ref = _frames(16).astype(dt)
    m = gridstrain.estimate_noise(ref, LAT, degree=0, n_bins=8)
    assert isinstance(m.K, float)
    assert isinstance(m.L, float)


def _detect_lattice(dt):
    ref, _ = _ref_cur(dt)
    lat = gridstrain.detect_lattice(ref[0])
    assert all(isinstance(v, float) for v in (*lat.k1, *lat.k2))


def _reference_lattice(dt):
    ref, _ = _ref_cur(dt)
    lat = series.reference_lattice(ref)
    assert all(isinstance(v, float) for v in (*lat.k1, *lat.k2))


def _follow_lattice(dt):
    _, cur = _ref_cur(dt)
    lat = phase.follow_lattice(cur[0], LAT)
    assert all(isinstance(v, float) for v in (*lat.k1, *lat.k2))


def _dask(dt):
    pytest.importorskip("distributed")
    from gridstrain import series as distributed

    ref, _ = _ref_cur(dt)
    assert distributed.mean_image_dask(ref).compute().dtype == np.float64
    _check_maps(distributed.method_a_dask(ref, LAT).maps, dt)
    _check_maps(distributed.method_b_dask(ref, LAT).maps, dt)


def _estimate_noise_image(dt):
    # the single-image estimate needs 160 px at least: the same grid on 192 x 192
    rng = np.random.default_rng(5)
    y, x = np.mgrid[0:192, 0:192].astype(np.float64)
    i = 120 + 50 * (np.cos(2 * np.pi * x / 5) + np.cos(2 * np.pi * y / 5))
    img = np.rint(np.clip(i + np.sqrt(0.3 * i + 4.0) * rng.standard_normal(i.shape), 0, 255))
    m = gridstrain.estimate_noise_image(img.astype(dt), LAT)
    assert isinstance(m.K, float)
    assert isinstance(m.L, float)
    assert m.levels.dtype == np.float64  # statistics are float64


def _aliasing_bias(dt):
    ref, _ = _ref_cur(dt)
    a = uncertainty.aliasing_bias(ref[0], LAT, sigma=5.0)
    assert isinstance(a["u_px"], float)
    assert all(isinstance(v, float) for v in a["phase_rad"])


def _method_c(dt):
    ref, _ = _ref_cur(dt)
    res = stacks.method_c(ref, LAT)
    _check_maps(res.maps, dt)
    assert res.shifts.dtype == np.float64


def _wft_complex(dt):
    # a complex image per wave vector, as method C makes them from frames of dtype
    # dt: the caller names the precision of the maps (that of its frames)
    ref, _ = _ref_cur(dt)
    z = np.stack([ref[0], ref[0]]).astype(np.complex128)
    _check_maps(wft_complex(z, LAT, dtype=_precision(dt)), dt)


def _smoothing_bias(dt):
    ref, cur = _ref_cur(dt)
    m = gridstrain.measure(ref[0], cur[0], lattice=LAT, guess=None)
    b = uncertainty.smoothing_bias(m.strain, m.valid, sigma=5.0)
    assert all(v is None or isinstance(v, float) for v in b["p95"])


def _contrast_step_bound(dt):
    # a bound made from maps of either precision: float64, finite on the valid pixels
    ref, cur = _ref_cur(dt)
    m = gridstrain.measure(ref[0], cur[0], lattice=LAT, guess=None)
    b = uncertainty.contrast_step_bound(m.reference.psi, m.deformed.psi, m.u, m.valid,
                                        sigma=m.sigma)
    assert b.dtype == np.float64
    assert np.all(np.isfinite(b[m.valid]))


def _edge_maps(dt):
    ref, _ = _ref_cur(dt)
    mask = np.zeros((N, N), dtype=bool)
    mask[8:56, 8:56] = True  # a specimen with free edges 8 px inside the frame
    window = phase.Window(5.0)
    return ref[0], mask, window, phase.transform_to_edges(ref[0], LAT, window, mask=mask)


def _partly_covered(dt):
    # a mask's partly covered edge pixels from maps of either precision: a bool map
    image, mask, _, maps = _edge_maps(dt)
    _check_maps(maps, dt)
    covered = phase.partly_covered(image, maps, mask)
    assert covered.dtype == np.bool_
    assert covered.shape == mask.shape


def _edge_harmonic_bias(dt):
    # the harmonics' bias of the edge band, a bound: float64 whatever the input
    image, mask, window, maps = _edge_maps(dt)
    b = phase.edge_harmonic_bias(image, LAT, window, mask=mask, maps=maps)
    assert b.dtype == np.float64
    assert b.shape == (3, N, N)
    assert np.all(np.isfinite(b))


def _contrast_step_findings(dt):
    # findings of a bound from either precision: their figures plain floats and ints
    ref, cur = _ref_cur(dt)
    m = gridstrain.measure(ref[0], cur[0], lattice=LAT, guess=None)
    b = m.contrast_step_bound()
    assert b.dtype == np.float64
    # the bound's spread as the noise: its largest pixels are stated
    found = uncertainty.contrast_step_findings(b, m.valid, noise=(0.0, 0.0), name="s")
    assert [f.code for f in found] == ["contrast.step"]
    assert isinstance(found[0].figures["max_px"], float)
    assert isinstance(found[0].figures["pixels"], int)


def _pair_match(dt):
    # figures of a check, float64 whatever the images' dtype
    from gridstrain.kinematics import pair_match

    ref, cur = _ref_cur(dt)
    shape = ref.shape[1:]
    m = pair_match(ref[0], cur[0], np.zeros((2, *shape), dtype=dt), np.ones(shape, bool),
                   pitch=5.0, noise=(1.0, 1.0))
    assert all(isinstance(v, float) for v in (m.match, m.rho, m.rho_match, m.rho_sd))


def _derived_strains(dt):
    # maps of a measurement in: derived maps in its precision
    from gridstrain.kinematics import finite_strains, principal_strains

    ref, cur = _ref_cur(dt)
    m = gridstrain.measure(ref[0], cur[0], lattice=LAT, guess=None)
    p = principal_strains(*m.strain, exx_std=m.strain[0], eyy_std=m.strain[1],
                          exy_std=m.strain[2])
    for name in ("e1", "principal_angle", "equivalent", "max_shear", "e1_std"):
        assert getattr(p, name).dtype == _precision(dt), name
    f = finite_strains(*m.strain, m.rotation)
    assert f.Exx.dtype == f.Lxy.dtype == _precision(dt)


ENTRY_POINTS = {
    "principal_strains": _derived_strains, "finite_strains": _derived_strains,
    "wft": _wft, "transform_to_edges": _transform_to_edges,
    "method_a": _method_a, "method_b": _method_b, "method_c": _method_c,
    "wft_complex": _wft_complex,
    "prefix_stacks": _prefix_stacks, "correct_phases": _correct_phases,
    "mean_image": _mean_image, "measure": _measure, "deformation": _deformation,
    "coarse_displacement": _coarse_displacement, "measure_series": _measure_series,
    "predict_uncertainty": _predict_uncertainty, "noise_variance_map": _noise_variance_map,
    "displacement_strain_std": _displacement_strain_std,
    "noise_floor": _noise_floor, "frame_shifts": _frame_shifts,
    "vibration_report": _vibration_report, "screen_frames": _screen_frames,
    "anscombe": _anscombe, "inverse_anscombe": _anscombe, "estimate_noise": _estimate_noise,
    "detect_lattice": _detect_lattice, "follow_lattice": _follow_lattice,
    "reference_lattice": _reference_lattice,
    "mean_image_dask": _dask, "method_a_dask": _dask,
    "method_b_dask": _dask,
    "estimate_noise_image": _estimate_noise_image, "aliasing_bias": _aliasing_bias,
    "smoothing_bias": _smoothing_bias, "pair_match": _pair_match,
    "contrast_step_bound": _contrast_step_bound,
    "contrast_step_findings": _contrast_step_findings,
    "partly_covered": _partly_covered, "edge_harmonic_bias": _edge_harmonic_bias,
}
# Public functions that take no image: their outputs are float64 by construction
# (frequencies; metrology's figures), files (save_*, load: the dtypes saved), or the
# frames themselves at a dtype the caller names (gridstrain.io; as_dask_stack);
# connect() opens a cluster, progress_bar() draws, state_names() names the inputs,
# circular_offset_std() takes shifts, edge_pixels() and edge_noise_gain() a mask.
NO_IMAGE = {"edge_noise_gain", "edge_pixels", "transfer_function", "save_result", "save_csv",
            "as_dask_stack", "connect", "load", "progress_bar", "metrology", "state_names",
            "circular_offset_std"}


# Public functions of the faces that this policy test does not call yet: each takes
# maps or measurements already in the caller's precision (demodulated_at,
# finite_derivatives, coupling_corrected, transform: PhaseMaps; the discontinuities:
# a Measurement; grid_shows: PhaseMaps; no_grid: a modulus map), or names a state
# (empty_state_message).
NOT_CALLED = {"check_parted", "check_parts", "coupling_corrected", "demodulated_at",
              "empty_state_message",
              "grid_shows", "no_grid",
              "find_discontinuities", "finite_derivatives", "transform",
              "without_discontinuities"}


def test_every_public_function_of_the_numerical_core_is_covered():
    # by module path: the package's own wft is the function, not a module
    modules = [importlib.import_module(f"gridstrain.{m}") for m in (
        "phase", "stacks", "kinematics", "uncertainty", "series")] + [gridstrain]
    public = {name for mod in modules for name in mod.__all__
              if callable(getattr(mod, name)) and not isinstance(getattr(mod, name), type)}
    assert public - set(ENTRY_POINTS) - NO_IMAGE - NOT_CALLED == set()


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_output_dtypes_follow_the_precision_policy(name, dtype):
    ENTRY_POINTS[name](dtype)
