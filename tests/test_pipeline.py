"""Tests of gridstrain.series: series of grid images to maps, vibrations, noise floor."""

from __future__ import annotations

import dataclasses
import datetime
import itertools
import math

import numpy as np
import pytest
import scipy
import tifffile
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage

from findings import said
from gridstrain import Lattice, __version__, theory
from gridstrain.io import open_series, read_hdf5
from gridstrain.models import kirsch, synthetic
from gridstrain.results import MAP_FIELDS, SeriesResult, read_attrs, save_csv, save_result
from gridstrain.series import measure_series
from gridstrain.uncertainty import FWHM_PER_SIGMA

LAT = Lattice.from_pitch(5.0)
AMP = 2400.0  # mean grey level, 12-bit: the grid peaks at 1.45 AMP = 3480 < 4095
E0 = 100.0 / kirsch.ALUMINIUM_YOUNGS_MODULUS  # remote strain of 100 MPa


class Plate:
    """A plate with a hole in tension imaged by a noisy, vibrating camera."""

    def __init__(self, n=128, radius=14.0, stress=100.0, translation=(0.0, 0.0)):
        self.n, self.a = n, radius
        self.c = ((n - 1) / 2, (n - 1) / 2)
        self.el = {"radius": radius, "remote_stress": stress, "centre": self.c}
        self.t = translation
        yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
        self.xx, self.yy = xx, yy
        self.r = np.hypot(xx - self.c[0], yy - self.c[1])
        self.mask = self.r > radius + 1  # the specimen, a pixel clear of the edge

    def _refl(self, X, Y):
        return ((X - self.c[0]) ** 2 + (Y - self.c[1]) ** 2 >= self.a**2).astype(float)

    def field(self, X, Y):
        ux, uy = kirsch.displacement(X, Y, inside="extend", **self.el)
        return ux + self.t[0], uy + self.t[1]

    def frames(self, T, *, loaded, rng=None, vibration=0.0, noise=True):
        """(T, H, W) frames and the (T, 2) true shifts (frame t = s(x + a_t))."""
        out, shifts = [], []
        for _ in range(T):
            a = rng.normal(0.0, vibration, 2) if vibration else np.zeros(2)
            shifts.append(a)

            def disp(X, Y, a=a):
                ux, uy = self.field(X, Y) if loaded else (0 * X, 0 * Y)
                return ux - a[0], uy - a[1]

            img = synthetic.grid_image((self.n, self.n), LAT, amplitude=AMP,
                                       displacement=disp, reflectance=self._refl) + 100.0
            out.append(synthetic.add_noise(img, rng=rng) if noise else img)
        return np.array(out), np.array(shifts)

    def truth(self):
        ux, uy = kirsch.displacement(self.xx, self.yy, **self.el)
        return (np.array([ux + self.t[0], uy + self.t[1]]),
                np.array(kirsch.strain(self.xx, self.yy, **self.el)))

    def windowed_truth(self, sigma):
        """The truth seen through the Gaussian window (eqs. 24-25), hole filled.

        Valid pixels lie >= 4 sigma + 1 px from the hole, where the window weighs
        exp(-(21/5)^2/2) ~ 1.5e-4: filling the hole with the remote values changes
        the result by < 1.5e-4 * 2 E0 = 4e-7 strain.
        """
        u, e = self.truth()
        fills = (self.t[0], self.t[1], E0, -kirsch.ALUMINIUM_POISSON_RATIO * E0, 0.0)
        out = []
        for comp, f in zip([*u, *e], fills, strict=True):
            out.append(ndimage.gaussian_filter(np.where(np.isnan(comp), f, comp), sigma,
                                               truncate=10.0, mode="reflect"))
        return np.array(out[:2]), np.array(out[2:])


def _rms(a):
    return math.sqrt(float(np.mean(np.square(a))))


# ------------------------------------------------------------------- the maps


def test_noise_free_plate_is_the_field_seen_through_the_window():
    p = Plate()
    ref, _ = p.frames(1, loaded=False, noise=False)
    cur, _ = p.frames(1, loaded=True, noise=False)
    res = measure_series(ref, cur, lattice=LAT, mask=p.mask)
    assert isinstance(res, SeriesResult)
    assert res.u.shape == (1, 2, 128, 128)
    assert res.strain.shape == (1, 3, 128, 128)
    v = res.valid[0]
    # validity: the hole, its margin (4 sigma from the mask) and the border are out
    assert v.sum() > 3000
    assert p.r[v].min() >= p.a + 1 + 4 * 5.0 - 1
    uw, ew = p.windowed_truth(5.0)
    # 8e-7 strain RMS measured: the WFT's edge bias at 4 sigma (4e-6 strain, see
    # gridstrain.wft) on the pixels nearest the border and the hole dominates
    for i in range(3):
        assert _rms(res.strain[0, i][v] - ew[i][v]) < 2e-6
    # px: the same bias on the phase, 7e-6 rad at 4 sigma times p / 2 pi
    for i in range(2):
        assert _rms(res.u[0, i][v] - uw[i][v]) < 4e-6
    # against the raw truth the window's smoothing of the a^2 cos(4 theta) / r^2
    # terms shows: sigma^2 / 2 * 12 a^2 / r^4 * E0 ~ 3e-5 at r = 2.5 a
    _u_true, e_true = p.truth()
    assert 2e-6 < _rms(res.strain[0, 0][v] - e_true[0][v]) < 3e-5
    # a single frame per series: no temporal noise estimate, no split
    assert math.isnan(res.noise.sensor_variance[0])
    assert np.isnan(res.noise.theory_strain).all()
    assert np.isnan(res.noise.split_strain).all()


@pytest.fixture(scope="module")
def noisy_plate():
    """192 x 192 plate, T = 4 frames per state, sensor noise and 0.01 px vibrations."""
    rng = np.random.default_rng(20150101)
    p = Plate(n=192, radius=20.0, translation=(3.4, -1.2))
    ref, a_ref = p.frames(4, loaded=False, rng=rng, vibration=0.01)
    cur, a_cur = p.frames(4, loaded=True, rng=rng, vibration=0.01)
    res = measure_series(ref, [cur], mask=p.mask)  # lattice detected, guess "auto"
    return p, ref, cur, (a_ref, a_cur), res


def test_plate_with_hole_recovers_strain_within_the_noise_floor(noisy_plate):
    p, _, _, _, res = noisy_plate
    assert_allclose(res.lattice.pitches, (5.0, 5.0), rtol=1e-4)  # detected
    v = res.valid[0]
    _, ew = p.windowed_truth(res.sigma)
    floor = res.noise.theory_strain[0]
    # the valid region (~1.9e4 px) holds about 60 independent windows (area
    # pi (2 sigma)^2 each), so an RMS of pure noise estimates its std to about
    # 1/sqrt(2 * 60) = 9 %: [0.7, 1.3] is more than 3 of those
    for i in range(3):
        ratio = _rms(res.strain[0, i][v] - ew[i][v]) / floor[i]
        assert 0.7 < ratio < 1.3, (i, ratio)
    # the theory of the windowed Fourier noise, with the measured sensor variance
    # and modulus, independently: Std(e_xx) = p/2pi sqrt(s_ref^2 + s_def^2)
    _g2, dg2 = theory.window_energy(res.sigma)
    mods = res.noise.modulus
    s = [math.sqrt(res.noise.sensor_variance[k] / 4 * dg2 / 2) / mods[k][0] for k in (0, 1)]
    assert_allclose(floor[0], 5.0 / (2 * math.pi) * math.hypot(*s), rtol=1e-3)
    # the half-against-half estimate agrees with the theory (its own sampling
    # error is ~13 % on the reference's ~30 windows per half... measured 2-4 %)
    assert_allclose(res.noise.split_strain[0], floor, rtol=0.3)
    assert_allclose(res.noise.split_u[0], res.noise.theory_u[0], rtol=0.3)


def test_uncertainty_maps_predict_the_error(noisy_plate, tmp_path):
    p, _, _, _, res = noisy_plate
    v = res.valid[0]
    uw, ew = p.windowed_truth(res.sigma)
    unc = res.uncertainty
    assert set(unc) == {"ux_std", "uy_std", "exx_std", "eyy_std", "exy_std"}
    # the error about the windowed truth, over the RMS of the predicted std: 1 within
    # the ~9 % sampling error of ~60 independent windows (previous test), and the
    # displacement's rigid vibration offset removed (it is not in the maps)
    for i, name in enumerate(("exx_std", "eyy_std", "exy_std")):
        assert np.all(np.isnan(unc[name][0][~v]))
        ratio = _rms(res.strain[0, i][v] - ew[i][v]) / _rms(unc[name][0][v])
        assert 0.7 < ratio < 1.3, (name, ratio)
    for i, name in enumerate(("ux_std", "uy_std")):
        err = res.u[0, i][v] - uw[i][v]
        ratio = _rms(err - err.mean()) / _rms(unc[name][0][v])
        assert 0.7 < ratio < 1.3, (name, ratio)
    data = read_hdf5(save_result(res, tmp_path / "maps.h5"))
    assert data["datasets"]["exx_std"].shape == (1, 192, 192)
    assert data["units"]["uy_std"] == "px"


def test_sensor_variance_is_the_camera_model(noisy_plate):
    _p, ref, _, _, res = noisy_plate
    # Var = K l + L (K = 0.28, L = 5) averaged over the valid pixels of the mean
    # image; 3 dof per pixel over ~1.9e4 pixels: 0.6 % sampling error
    v = res.measurements[0].reference.valid
    expected = float(np.mean(0.28 * ref.mean(axis=0)[v] + 5.0))
    assert_allclose(res.noise.sensor_variance[0], expected, rtol=0.03)
    assert "regressed" in res.noise.variance_method[0]


def test_vibration_diagnostics(noisy_plate):
    _p, _, _, (a_ref, a_cur), res = noisy_plate
    for vib, a, rtol in zip(res.vibration, (a_ref, a_cur), (1e-9, 1e-6), strict=True):
        # the state is probed at its own carrier (the reference's strained by ~1e-3):
        # |k| differs by that strain from the reference's k the closed forms below are
        # written with: 5e-8 on the contrast factor, 1e-3 relative on the offset std
        true = a - a.mean(axis=0)
        # px: the carrier phase of a noisy 192^2 frame measures a shift to ~1e-3 px
        # (sensor noise), plus an error ~0.05 |a| from the fixed apodisation under a
        # deformed grid with a hole; the vibrations are 1e-2 px
        assert _rms(vib.shifts - true) < 2.5e-3
        assert_allclose(vib.std, np.std(vib.shifts, axis=0, ddof=1), rtol=1e-12)
        cov = np.cov(vib.shifts.T)
        for j, k in enumerate(res.lattice.K):
            f = float(np.hypot(*k))
            var = float(k @ cov @ k) / f**2  # along k_j (the detected grid is ~axial)
            assert_allclose(var, vib.std[j] ** 2, rtol=1e-3)
            assert_allclose(vib.contrast_factor[j], 1 - 0.5 * (2 * math.pi * f) ** 2 * var,
                            rtol=rtol)
            assert_allclose(vib.phase_offset_std[j],
                            2 * math.pi * f / (1 - 0.5 * (2 * math.pi * f) ** 2 * var)
                            * math.sqrt(var / 4), rtol=max(rtol, 2e-3))  # eq. (31), T = 4
    # the rigid offset of u combines both series' offsets through eq. (34)
    offs = [np.array(v.phase_offset_std) for v in res.vibration]
    expected = np.array(res.lattice.pitches) / (2 * math.pi) * np.hypot(offs[0], offs[1])
    # the detected grid is axis-aligned to 1e-5 deg: K^-1 is diagonal to 1e-7
    assert_allclose(res.noise.vibration_u[0], expected, rtol=1e-6)


def test_fringe_order_from_the_hole(noisy_plate):
    p, _, _, _, res = noisy_plate
    # a translation of (3.4, -1.2) px is more than half a pitch: the fringe order
    # comes from the hole's edge in the images, which the mask hides (so the whole
    # images are correlated), and it is confirmed
    assert res.guess_sources[0] == "image features"
    assert res.fringe_orders[0].confirmed
    assert res.fringe_orders[0].peak_to_alias >= 1.5
    # px: the candidate is the phases' displacement, good to the map's noise plus
    # the hole's own motion (the Kirsch field) relative to the mean
    assert_allclose(res.guesses[0], (3.4, -1.2), atol=0.5)
    v = res.valid[0]
    u_true, _ = p.truth()
    for i in range(2):
        # px: noise 2e-3 and the vibration offset (~5e-3 px std) in the mean
        assert abs(float(np.mean(res.u[0, i][v] - u_true[i][v]))) < 0.02


def test_regions_without_grid_are_masked_automatically():
    p = Plate()
    ref, _ = p.frames(1, loaded=False, noise=False)
    cur, _ = p.frames(1, loaded=True, noise=False)
    res = measure_series(ref, cur, lattice=LAT)  # no mask: the hole is found
    v = res.valid[0]
    # the hole is masked where the window, centred about one sigma inside its
    # edge, sees less than a quarter of the grid's modulus
    assert not res.mask[p.r < p.a - 5.0].any()
    assert res.mask[p.r > p.a + 1].all()
    # and the margin applies around it: 4 sigma from the masked region
    assert p.r[v].min() > p.a - 5.0 + 4 * 5.0
    _, ew = p.windowed_truth(5.0)
    # strain: a little more edge bias than with an exact mask (the automatic one
    # follows the modulus, which fades over ~sigma at the edge)
    assert _rms(res.strain[0, 0][v] - ew[0][v]) < 1e-5


def test_two_states_in_order_and_files_agree_with_arrays(tmp_path):
    p = Plate()
    rng = np.random.default_rng(7)
    ref, _ = p.frames(2, loaded=False, rng=rng)
    cur, _ = p.frames(2, loaded=True, rng=rng)
    p2 = Plate(stress=-50.0)
    cur2, _ = p2.frames(2, loaded=True, rng=rng)
    for name, stack in (("ref", ref), ("s1", cur), ("s2", cur2)):
        # 12-bit stored x16, as a PCO camera writes it
        tifffile.imwrite(tmp_path / f"{name}.tif", (stack * 16).astype(np.uint16),
                         photometric="minisblack")
    files = measure_series(tmp_path / "ref.tif", [tmp_path / "s1.tif",
                                                  str(tmp_path / "s2.tif")],
                           lattice=LAT, mask=p.mask)
    arrays = measure_series(ref, [cur, cur2], lattice=LAT, mask=p.mask)
    assert files.n_states == 2
    assert files.names == ("reference", "s1", "s2")  # after the files' stems
    assert files.bit_depth == (12, 12, 12)
    assert files.scale == (16, 16, 16)
    # raw values x16: phases are scale-free, so the maps agree to rounding
    assert_array_equal(files.valid, arrays.valid)
    v = files.valid
    assert_allclose(files.strain[:, :, v[0]], arrays.strain[:, :, v[0]], atol=1e-12)
    # order: state 0 in tension along x, state 1 in compression
    assert np.mean(files.exx[0][v[0]]) > 0.5 * E0
    assert np.mean(files.exx[1][v[1]]) < -0.25 * E0
    assert files.sources[1] == (str(tmp_path / "s1.tif"),)


def test_method_b_agrees_with_method_a():
    p = Plate()
    rng = np.random.default_rng(3)
    ref, _ = p.frames(3, loaded=False, rng=rng, vibration=0.02, noise=False)
    cur, _ = p.frames(3, loaded=True, rng=rng, vibration=0.02, noise=False)
    a = measure_series(ref, cur, lattice=LAT, mask=p.mask, method="A")
    b = measure_series(ref, cur, lattice=LAT, mask=p.mask, method="B")
    assert b.method == "B"
    v = a.valid[0] & b.valid[0]
    assert v.sum() > 0.95 * a.valid[0].sum()
    # noise-free: both estimate the same phases up to the vibration offsets, which
    # are constant (rigid) and differ between methods by O((2 pi f alpha)^3) rad
    for i in range(3):
        assert _rms(a.strain[0, i][v] - b.strain[0, i][v]) < 1e-6
    du = a.u[0][:, v] - b.u[0][:, v]
    assert np.std(du, axis=1).max() < 1e-5  # px, once the rigid offset is removed


def test_method_c_agrees_with_method_a_and_keeps_the_contrast():
    p = Plate()
    rng = np.random.default_rng(4)
    ref, _ = p.frames(4, loaded=False, rng=rng, vibration=0.3, noise=False)
    cur, _ = p.frames(4, loaded=True, rng=rng, vibration=0.3, noise=False)
    a = measure_series(ref, cur, lattice=LAT, mask=p.mask, method="A")
    c = measure_series(ref, cur, lattice=LAT, mask=p.mask, method="C")
    assert c.method == "C"
    assert c.parameters["method"] == "C"
    assert not said(c.warnings, "vibration")  # rigid vibrations
    # 0.3 px costs method A 14 % of its contrast: it says so and names method C
    notes = said(a.warnings, "contrast.vibration")
    assert len(notes) == 2  # both series
    assert notes[0].startswith("reference: vibrations of")
    v = a.valid[0] & c.valid[0]
    assert v.sum() > 0.95 * a.valid[0].sum()
    # noise-free: the same strain; what differs is the average of the phase maps
    # over the 0.3-px vibrations (a 0.3 px * 1e-4 /px strain gradient), ~1e-6
    for i in range(3):
        assert _rms(a.strain[0, i][v] - c.strain[0, i][v]) < 5e-6
    # method A's averaged grid lost eq. (14)'s contrast; method C's did not
    f = 0.2
    loss = theory.contrast_factor(f, 0.3**2)  # 0.86 for 0.3 px at pitch 5
    ratio = a.noise.modulus[0] / c.noise.modulus[0]
    assert_allclose(ratio, loss, atol=0.1)  # four frames' scatter about the law
    assert np.all(c.noise.theory_strain[0] < a.noise.theory_strain[0])


def test_vibrations_do_not_pass_for_sensor_noise():
    # strong vibrations (0.05 px) raise the temporal variance of a grid image by
    # |grad s|^2 Var(alpha) ~ (700 * 0.05)^2 ~ 1e3 grey levels^2, more than the
    # sensor's 700: the regression on the measured shifts removes it
    p = Plate(n=96, radius=8.0)
    rng = np.random.default_rng(6)
    ref, _ = p.frames(12, loaded=False, rng=rng, vibration=0.05)
    res = measure_series(ref, ref[::-1], lattice=LAT, mask=p.mask)
    v = res.measurements[0].reference.valid
    expected = float(np.mean(0.28 * ref.mean(axis=0)[v] + 5.0))
    plain = float(np.mean(np.var(ref, axis=0, ddof=1)[v]))
    assert plain > 1.5 * expected  # the vibrations do show in the plain variance
    # second-order terms (Hessian of s times Var(alpha)) remain: a few per cent
    assert_allclose(res.noise.sensor_variance[0], expected, rtol=0.08)


# ------------------------------------------------------------------- arguments


@pytest.mark.parametrize(("kwargs", "exc", "match"), [
    ({"method": "D"}, ValueError, "method"),
    ({"sigma": 3.0, "lattice": LAT}, ValueError, "sigma must be at least the pitch"),
    ({"margin": -1.0}, ValueError, "margin"),
    ({"guess": "zero"}, ValueError, "guess"),
    ({"guess": (1.0, 2.0, 3.0)}, ValueError, "guess"),
    ({"lattice": 5.0}, TypeError, "lattice"),
    ({"mask": np.ones((10, 10), bool)}, ValueError, "mask"),
    ({"max_saturation": 2.0}, ValueError, "max_saturation"),
    ({"progress": 3}, TypeError, "progress"),
])
def test_bad_arguments(kwargs, exc, match):
    img = synthetic.grid_image((64, 64), LAT)
    with pytest.raises(exc, match=match):
        measure_series(img, img, **kwargs)


def test_bad_series():
    img = synthetic.grid_image((64, 64), LAT)
    with pytest.raises(ValueError, match="state 0: frames are"):
        measure_series(img, img[:32], lattice=LAT)
    with pytest.raises(ValueError, match="NaN"):
        measure_series(img, np.where(img > 1, np.nan, img), lattice=LAT)
    with pytest.raises(TypeError, match="reference"):
        measure_series(object(), img)
    with pytest.raises(ValueError, match="at least one"):
        measure_series(img, [])
    noise = np.random.default_rng(0).normal(1000, 30, (64, 64))
    with pytest.raises(ValueError, match="reference: image shows no periodic pattern"):
        measure_series(noise, noise)
    with pytest.raises(ValueError, match="no grid at the given lattice"):
        measure_series(noise, noise, lattice=LAT)
    # a grid of pitch 8 is not the pitch-5 grid the user claims, though the side
    # lobe of its third harmonic (0.375 cycles/px) gives a modulus at 0.2
    other = synthetic.grid_image((64, 64), Lattice.from_pitch(8.0))
    with pytest.raises(ValueError, match="given lattice is not the grid's"):
        measure_series(other, other, lattice=LAT)
    # a slightly different pitch (the magnification is never exact) is accepted:
    # 2 pi sigma |dk| = 2 pi 5 (1/5 - 1/5.05) = 0.06
    measure_series(img, img, lattice=Lattice.from_pitch(5.05))


def test_saturated_frames_are_refused(tmp_path):
    img = synthetic.grid_image((64, 64), LAT, amplitude=150.0)
    sat = img.copy()
    sat[:5] = 255  # 8 % of the pixels at the 8-bit ceiling
    tifffile.imwrite(tmp_path / "r.tif", np.rint(img).astype(np.uint8))
    tifffile.imwrite(tmp_path / "s.tif", np.rint(sat).astype(np.uint8))
    with pytest.raises(ValueError, match=r"^s: frame 0 .* saturated"):
        measure_series(tmp_path / "r.tif", tmp_path / "s.tif", lattice=LAT)


def test_progress_is_monotonic_and_ends_at_one():
    p = Plate(n=96, radius=8.0)
    rng = np.random.default_rng(8)
    ref, _ = p.frames(2, loaded=False, rng=rng)
    calls = []
    measure_series(ref, ref, mask=p.mask, method="B",
                   progress=lambda f, m: calls.append((f, m)))
    fr = [f for f, _ in calls]
    assert all(0 <= f <= 1 for f in fr)
    assert all(b >= a - 1e-12 for a, b in itertools.pairwise(fr))
    assert fr[-1] == 1.0
    assert all(isinstance(m, str) for _, m in calls)


# ------------------------------------------------------------------- saving


def test_save_result_layout(noisy_plate, tmp_path):
    _p, _, _, _, res = noisy_plate
    # lossless: the maps compared bit for bit (their rounding: test_compact_results)
    path = save_result(res, tmp_path / "out.h5", pixel_size=0.04, unit="mm",
                       attrs={"mask_file": "mask.tif"}, lossless=True)
    data = read_hdf5(path)
    d, u = data["datasets"], data["units"]
    a = read_attrs(path)
    n = (1, 192, 192)
    for name, unit in MAP_FIELDS.items():
        assert d[name].shape == n
        assert u[name] == unit
        assert_array_equal(d[name], res.get_map(name))
    assert d["valid"].dtype == bool
    assert d["valid"].shape == n
    assert_allclose(d["ux_phys"], d["ux"] * 0.04, rtol=1e-15, equal_nan=True)
    assert u["ux_phys"] == "mm"
    assert u["uy_phys"] == "mm"
    assert d["reference_image"].shape == (192, 192)
    assert d["mask"].dtype == bool
    assert a["k1"] == list(res.lattice.k1)
    assert a["pitches"] == list(res.lattice.pitches)
    assert a["angles"] == list(res.lattice.angles)
    assert_array_equal(d["n_frames"], [4, 4])
    assert a["sigma"] == res.sigma
    assert a["method"] == "A"
    assert a["lagrangian"] is True
    assert a["gridstrain_version"] == __version__
    created = datetime.datetime.fromisoformat(a["created"])
    assert created.utcoffset() == datetime.timedelta(0)
    # the libraries the numbers went through, as this process has them
    assert a["numpy"] == np.__version__
    assert a["scipy"] == scipy.__version__
    assert a["pixel_size"] == 0.04
    assert a["unit"] == "mm"
    assert a["mask_file"] == "mask.tif"
    assert d["vibration_shifts"].shape == (2, 4, 2)
    assert u["vibration_shifts"] == "px"
    assert_allclose(d["vibration_std"][0], res.vibration[0].std)
    assert_allclose(d["noise_theory_strain"], res.noise.theory_strain)
    assert_allclose(a["window_fwhm_px"], FWHM_PER_SIGMA * res.sigma)
    # the period of a sine displacement damped by 10 %: exp(-2 pi^2 sigma^2 / d^2) = 0.9
    d = a["spatial_resolution_px"]
    assert_allclose(np.exp(-2 * np.pi**2 * res.sigma**2 / d**2), 0.9, rtol=1e-12)
    # the existing file is kept without overwrite, replaced with it
    with pytest.raises(FileExistsError):
        save_result(res, path)
    save_result(res, path, overwrite=True)
    with pytest.raises(ValueError, match="unit"):
        save_result(res, tmp_path / "b.h5", pixel_size=0.04)
    with pytest.raises(ValueError, match="pixel_size"):
        save_result(res, tmp_path / "b.h5", pixel_size=-1.0, unit="mm")
    assert not (tmp_path / "b.h5").exists()
    # the place kept for per-pixel uncertainty maps: saved next to the maps
    std = np.full((1, 192, 192), 2e-3)
    with_std = dataclasses.replace(res, uncertainty={"ux_std": std})
    data = read_hdf5(save_result(with_std, tmp_path / "c.h5", lossless=True))
    assert_array_equal(data["datasets"]["ux_std"], std)
    assert data["units"]["ux_std"] == "px"


def test_save_csv(noisy_plate, tmp_path):
    _, _, _, _, res = noisy_plate
    path = save_csv(res, tmp_path / "out.csv", digits=None)
    rows = np.genfromtxt(path, delimiter=",", names=True)
    # "exx [-]": dimensionless, as genfromtxt spells its name
    assert rows.dtype.names[:8] == ("state", "x_px", "y_px", "ux_px", "uy_px", "exx_",
                                    "eyy_", "exy_")
    assert rows.size == int(res.valid.sum())
    x, y = rows["x_px"].astype(int), rows["y_px"].astype(int)
    assert res.valid[0, y, x].all()
    # exact decimal round trip with digits=None (gridstrain.io.write_csv)
    assert_array_equal(rows["exx_"], res.exx[0, y, x])
    assert_array_equal(rows["uy_px"], res.uy[0, y, x])


def test_result_is_read_only(noisy_plate):
    _, _, _, _, res = noisy_plate
    with pytest.raises(ValueError, match="read-only"):
        res.u[0, 0, 0, 0] = 1.0
    assert "1 state(s) of 192x192" in repr(res)
    assert "T=4" in repr(res.vibration[0])
    # open_series is what the command line uses; a FrameSeries is accepted as is
    assert open_series is not None


def test_the_split_floor_from_one_half_and_the_mean_is_half_against_half():
    """Method A's split floor transforms one half and compares it with the mean of
    all the frames, scaled by T / n2: the same std as the two halves against each
    other (computed here from numpy means of the frames), the halves unequal (5
    and 6 frames) and the frames shaken by 0.05 px."""
    from gridstrain import wft
    from gridstrain.phase import Window, finite_derivatives
    from gridstrain.series._floors import _difference_std, _split_floor
    from gridstrain.stacks.accumulate import PassPlan, SeriesPass

    lat = Lattice.from_pitch(5.0)
    rng = np.random.default_rng(4)
    shape, T = (160, 176), 11
    frames = []
    for _ in range(T):
        a = rng.normal(0, 0.05, 2)
        img = synthetic.grid_image(shape, lat, amplitude=1000.0,
                                   displacement=lambda X, Y, a=a: (a[0] + 0 * X, a[1] + 0 * Y))
        frames.append(img + rng.normal(0, 20.0, shape))
    acc = SeriesPass(PassPlan(lattice=lat, n_frames=T), frames[0])
    for t, f in enumerate(frames):
        acc.add(t, f)
    mask = np.ones(shape, dtype=bool)
    mean = finite_derivatives(wft(np.mean(frames, axis=0), lat, sigma=5.0, mask=mask))
    su, se = _split_floor(acc, lat, Window(5.0, 4.0), mask, "A", lambda f, m: None,
                          mean_maps=mean)
    h1, h2 = (finite_derivatives(wft(np.mean(frames[sl], axis=0), lat, sigma=5.0, mask=mask))
              for sl in (slice(0, T // 2), slice(T // 2, T)))
    want_u, want_e = _difference_std(h1, h2)
    # relative: the second-order term of the phase difference, |r| n1 / 2T with |r|
    # the phase noise of the halves' difference (about 1e-2 rad here), is 0.2 %; a
    # wrong scale (T / n1, or none) would be 20 % or 83 % off
    np.testing.assert_allclose(su, want_u, rtol=5e-3)
    np.testing.assert_allclose(se, want_e, rtol=5e-3)


def test_the_split_floor_is_deformation_without_its_maps():
    """The noise floor's half-against-half std, computed on the valid pixels alone,
    equals that of kinematics.deformation(lagrangian=False) on a rotated grid with
    a masked hole, to float rounding."""
    from gridstrain import wft
    from gridstrain.kinematics import deformation
    from gridstrain.phase import finite_derivatives
    from gridstrain.series._floors import _difference_std

    th, f = np.deg2rad(12.0), 1 / 5.0
    lat = Lattice((f * np.cos(th), f * np.sin(th)), (-f * np.sin(th), f * np.cos(th)))
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:128, 0:140]
    mask = (x - 90) ** 2 + (y - 60) ** 2 > 20**2
    a, b = (synthetic.grid_image((128, 140), lat) + rng.normal(0, 0.01, (128, 140))
            for _ in range(2))
    pa = finite_derivatives(wft(a, lat, mask=mask))
    pb = finite_derivatives(wft(b, lat, mask=mask))
    m = deformation(pa, pb, lagrangian=False, guess=None)
    su, se = _difference_std(pa, pb)
    v = m.valid
    np.testing.assert_allclose(su, [np.std(c[v], ddof=1) for c in m.u], rtol=1e-12)
    np.testing.assert_allclose(se, [np.std(c[v], ddof=1) for c in m.strain], rtol=1e-12)
