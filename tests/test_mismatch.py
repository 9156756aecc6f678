"""A reference and a deformed image of two different specimens are told from a pair of one
specimen by their content once the deformed image is warped back
(:func:`gridstrain.kinematics.pair_match`, the check of :func:`measure_series`).

The images come from ``independent_grid`` (numpy only). The specimens differ by their
printing defects: reflectance blots of 1.5 to 4 px radius, fixed to the material (drawn
here at each pixel's material point, found by the same fixed-point inversion of the
Lagrangian displacement as the generator's)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import tifffile

from findings import said
from gridstrain import measure_series
from gridstrain.kinematics import pair_match
from independent_grid import camera, scene

H, W, PITCH = 128, 160, 5.0
K, L = 0.28, 5.0  # sensor gain and read-noise variance, 12-bit grey levels
YS, XS = np.mgrid[0:H, 0:W].astype(np.float64)


def _material(disp):
    """Each pixel's material point ``X`` (``x = X + u(X)``)."""
    X, Y = XS, YS
    if disp is not None:
        for _ in range(12):
            ux, uy = disp(X, Y)
            X, Y = XS - ux, YS - uy
    return X, Y


def _defects(X, Y, seed):
    """A specimen's reflectance: 150 blots of +-5 to 20 %, at its own random places."""
    rng = np.random.default_rng(seed)
    c = rng.uniform([0, 0], [W, H], (150, 2))
    r = rng.uniform(1.5, 4.0, 150)
    a = rng.choice([-1.0, 1.0], 150) * rng.uniform(0.05, 0.2, 150)
    t = np.ones_like(X)
    for (cx, cy), rr, aa in zip(c, r, a, strict=True):
        t += aa * np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / (2 * rr**2))
    return t


def _frames(rng, *, specimen=0, disp=None, light=None, vibration=0.0, n=3):
    """``n`` frames of a specimen under ``disp`` (Lagrangian, in material
    coordinates), each moved by a rigid vibration of std ``vibration`` px."""
    out = []
    for _ in range(n):
        a = rng.normal(0.0, vibration, 2) if vibration else np.zeros(2)

        def moved(X, Y, a=a):
            ux, uy = disp(X, Y) if disp is not None else (0 * X, 0 * Y)
            return ux - a[0], uy - a[1]

        img, _ = scene((H, W), pitch=PITCH, angle=0.0, hole=False, displacement=moved)
        img = img * _defects(*_material(moved), specimen)
        if light is not None:
            img = img * light
        out.append(camera(img, K, L, rng))
    return np.stack(out)


def _stretch(e):
    return lambda X, Y: (e * (X - W / 2), 0 * Y)


def _rotation(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return lambda X, Y: (c * (X - W / 2) - s * (Y - H / 2) - (X - W / 2),
                         s * (X - W / 2) + c * (Y - H / 2) - (Y - H / 2))


def _crack(X, Y):
    # the right half opens by 0.7 px along x and slides 0.3 px along y
    right = X > 0.55 * W
    return 0.002 * (X - W / 2) + 0.7 * right, 0.3 * right


@pytest.fixture(scope="module")
def reference():
    return _frames(np.random.default_rng(1))


def _pair_record(res):
    (rec,) = res.systematic["pair_match"]
    return rec


def _mismatch_warnings(res):
    return said(res.warnings, "pair.mismatch")


TRUE_PAIRS = {
    "5 % strain": {"disp": _stretch(0.05)},
    "5 deg rotation": {"disp": _rotation(5.0)},
    # six frames: the stack's noise variance has the frames' shifts regressed out (from
    # four frames on), so the grid's motion does not count as noise
    "0.5 px vibration": {"disp": _stretch(0.002), "vibration": 0.5, "n": 6},
    # lighting fixed to the camera, 40 % brighter on the right than on the left
    "illumination gradient": {"disp": _stretch(0.002), "light": 0.8 + 0.4 * XS / W},
    "crack": {"disp": _crack},
}


@pytest.mark.parametrize("case", list(TRUE_PAIRS))
def test_a_true_pair_is_not_flagged(reference, case):
    rng = np.random.default_rng(list(TRUE_PAIRS).index(case) + 20)
    state = _frames(rng, **TRUE_PAIRS[case])
    res = measure_series(reference, [state])
    rec = _pair_record(res)
    assert not _mismatch_warnings(res), res.warnings
    # the check decided (enough content): a pass that cannot fail proves nothing
    assert rec["conclusive"], rec
    assert rec["verdict"] == "match"
    # the content keeps most of its correlation: the warp, strain's change of the
    # defects' scale (5 %) and the crack's band take a few per cent
    assert rec["match"] > 0.8, rec


def test_another_specimen_at_the_same_pitch_is_refused_naming_both_files(tmp_path, reference):
    rng = np.random.default_rng(7)
    other = _frames(rng, specimen=7, disp=_stretch(0.003))
    for name, frames in (("REF", reference), ("DEF", other)):
        (tmp_path / name).mkdir()
        for t, f in enumerate(frames):
            tifffile.imwrite(tmp_path / name / f"img{t}.tif", f, photometric="minisblack")
    with pytest.raises(ValueError, match="nothing matches") as err:
        measure_series(tmp_path / "REF", [tmp_path / "DEF"])
    text = str(err.value)
    assert "img0.tif" in text
    assert "REF" in text
    assert "DEF" in text
    assert "--outliers warn" in text  # what to do if they are one specimen after all
    # asked to go on, the measurement says it and records the figure
    res = measure_series(tmp_path / "REF", [tmp_path / "DEF"], outliers="warn")
    (told,) = _mismatch_warnings(res)
    assert "REF" in told
    assert "DEF" in told
    rec = _pair_record(res)
    assert rec["conclusive"]
    assert rec["verdict"] in ("mismatch", "nothing matches")
    # unrelated content: the correlation is about 0 within its spread (plus what the
    # shared lighting, fixed to the camera, leaves after the high-pass)
    assert rec["match"] < 0.5, rec


def test_another_specimen_moved_far_is_flagged(reference):
    # a rigid move of 3.3 px: the content fixed to the camera (the lighting) matches
    # the unwarped image better; still nothing of the reference's defects is there
    rng = np.random.default_rng(8)
    other = _frames(rng, specimen=11, disp=lambda X, Y: (0 * X + 3.3, 0 * Y - 1.2))
    res = measure_series(reference, [other], outliers="warn")
    assert _mismatch_warnings(res)
    assert _pair_record(res)["match"] < 0.5


def test_a_grid_without_content_is_inconclusive_not_flagged():
    # no defect on either specimen: nothing to compare, no verdict either way
    rng = np.random.default_rng(3)
    ref, _ = scene((H, W), pitch=PITCH, angle=0.0, hole=False, light=False)
    cur, _ = scene((H, W), pitch=PITCH, angle=0.0, hole=False, light=False,
                   displacement=_stretch(0.01))
    var = np.mean(K * ref + L)
    m = pair_match(camera(ref, K, L, rng), camera(cur, K, L, rng),
                   np.stack(_stretch(0.01)(XS, YS)), np.ones((H, W), bool), pitch=PITCH,
                   noise=(256 * var, 256 * var))  # stored x16: variances x256
    assert not m.conclusive
    assert m.verdict == "inconclusive"
    # the noise model holds: the content left is within a few tenths of the noise
    assert max(m.snr) < 1.0, m


def test_the_noise_model_accounts_for_the_variance_of_a_flat_image():
    # a flat field: the filtered image is noise only, and its variance is the predicted
    # one: the content's variance is 0 within the sampling spread of a variance over
    # this small field (10 % of the noise's, measured over seeds); the SNR is clipped at
    # 0 from below, so an underestimated noise, which would raise false alarms, fails
    rng = np.random.default_rng(4)
    level = np.full((H, W), 1500.0)
    img = camera(level, K, L, rng).astype(np.float64)
    var = 256 * (K * 1500 + L + 1 / 12)  # Poisson-Gaussian plus quantisation, x16 storage
    m = pair_match(img, img, np.zeros((2, H, W)), np.ones((H, W), bool), pitch=PITCH,
                   noise=(var, var))
    assert m.snr[0] < 0.25, m


def test_the_result_file_summary_and_report_carry_the_check(tmp_path, reference):
    from gridstrain.cli._summary import report_lines, summary
    from gridstrain.post import write_report
    from gridstrain.results import load

    state = _frames(np.random.default_rng(9), disp=_stretch(0.01))
    res = measure_series(reference, [state], output=tmp_path / "r.h5")
    back = load(tmp_path / "r.h5")
    assert back.systematic["pair_match"] == res.systematic["pair_match"]
    assert back.systematic["vibration_offset"] == res.systematic["vibration_offset"]
    (rec,) = summary(back, outputs={}, seconds=0.0)["systematic_errors"]["pair_match"]
    assert rec["verdict"] == "match"
    assert any(line.startswith("pair check") for line in report_lines(back))
    html = write_report(tmp_path / "r.h5", tmp_path / "r.html").read_text(encoding="utf-8")
    assert "Pair check" in html
    assert "Vibration offset" in html


def _texture(rng, shape, scale=3.0):
    """A reflectance of std 10 %: white noise smoothed by a Gaussian of ``scale`` px."""
    f2 = np.fft.fftfreq(shape[0])[:, None] ** 2 + np.fft.fftfreq(shape[1])[None] ** 2
    t = np.real(np.fft.ifft2(np.fft.fft2(rng.standard_normal(shape))
                             * np.exp(-2 * np.pi**2 * scale**2 * f2)))
    return 2000.0 * (1 + 0.1 * t / t.std())


def test_the_stated_spread_is_that_of_the_correlation():
    # The false-alarm rate rests on rho_sd. Between unrelated contents (H0) rho
    # scatters about 0 with rho_sd; for one content seen twice through independent
    # noise (H1), atanh(rho) scatters with at most rho_sd. 200 pairs of 256 x 320 px
    # (about 400 independent patches): a std from 200 draws is within 5 % (1 sigma),
    # hence 15 %. (On 128 x 160 px, ~90 patches, the spread is 15 % above rho_sd: a
    # small-sample bias of the autocorrelations.)
    rng = np.random.default_rng(1)
    shape = (256, 320)
    u, v = np.zeros((2, *shape)), np.ones(shape, bool)
    h0, sd0, z1, sd1 = [], [], [], []
    for _ in range(200):
        a, b = _texture(rng, shape), _texture(rng, shape)
        noisy = [a + rng.normal(0.0, 40.0, shape), a + rng.normal(0.0, 40.0, shape)]
        m = pair_match(a, b, u, v, pitch=PITCH, noise=(1e-6, 1e-6))
        h0.append(m.rho)
        sd0.append(m.rho_sd)
        m = pair_match(*noisy, u, v, pitch=PITCH, noise=(1600.0, 1600.0))
        z1.append(math.atanh(m.rho))
        sd1.append(m.rho_sd)
    assert abs(np.std(h0) / np.mean(sd0) - 1) < 0.15
    assert abs(np.mean(h0)) < 3 * np.mean(sd0) / math.sqrt(200)  # no shared content
    assert np.std(z1) < 1.15 * np.mean(sd1)


def test_the_frames_of_one_record_are_not_compared(tmp_path):
    # the reference taken from the record's first frames (--reference-frames): the
    # states are frames of the same file, one camera's record of one specimen
    from sequence_record import record

    frames = record(4, (96, 128), strain=1e-3)
    tifffile.imwrite(tmp_path / "rec.tif", frames, photometric="minisblack")
    res = measure_series(None, tmp_path / "rec.tif", reference_frames=1)
    assert [r["verdict"] for r in res.systematic["pair_match"]] == ["same record"] * 3
    # the same frames as files of their own are compared
    for t, f in enumerate(frames):
        tifffile.imwrite(tmp_path / f"f{t}.tif", f)
    res = measure_series(tmp_path / "f0.tif", [tmp_path / f"f{t}.tif" for t in (1, 2, 3)])
    assert "same record" not in [r["verdict"] for r in res.systematic["pair_match"]]


@pytest.mark.parametrize("q", [1, 5, 6])
def test_the_pair_checks_low_pass_sums_at_the_rows_kept_bit_for_bit(q):
    # the columns' filter summed at the rows kept only: the bits of filtering every row
    from scipy import ndimage

    from gridstrain.kinematics._pair_match import _low_pass

    rng = np.random.default_rng(11)
    a = rng.random((90, 121)) * 3000.0
    m = rng.random(a.shape) > 0.05

    def old(f, s):
        f = ndimage.gaussian_filter1d(f, s, axis=1, mode="constant")[:, ::q]
        return ndimage.gaussian_filter1d(f, s, axis=0, mode="constant")[::q]

    want = old(np.where(m, a, 0.0), 6.0) / np.maximum(old(m.astype(np.float64), 6.0), 1e-12)
    assert np.array_equal(_low_pass(a, m, 6.0, q), want)
