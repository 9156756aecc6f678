"""Every frame screened before averaging: series that used to come out quietly wrong.

The frames come from a generator written here with numpy alone (not
gridstrain.models.synthetic), so that the screening is tested against the world rather than
against the package's own model. Its assumptions (:func:`grid_frames`): a cross-line
grid of pitch 5 px whose reflectance is ``1 + c/2 (cos 2 pi X/p + cos 2 pi Y/p)``,
point-sampled at pixel centres (no blur, no pixel integration); an affine specimen
displacement ``u_x = e (X - x0) + t_x``, ``u_y = t_y`` inverted exactly; a rigid
vibration of the whole image, frame ``t`` showing ``s(x + a_t)`` with ``a_t`` normal
per axis (paper eq. 2); Poisson-Gaussian sensor noise ``Var = K I + L`` (normal
approximation, K = 0.28, L = 5, in grey levels); values rounded and clipped to
``[0, 2^bits - 1]`` and stored right-aligned in 16-bit integers, as a 12-bit camera
writing 16-bit files does.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
from numpy.testing import assert_allclose

from findings import said
from gridstrain import Lattice
from gridstrain.results import load, read_attrs, save_result
from gridstrain.series import measure_series
from gridstrain.stacks import method_a, method_b, method_c
from gridstrain.stacks.screening import screen_frames

PITCH = 5.0
LAT = Lattice.from_pitch(PITCH)
STRAIN = 2e-3


def grid_frames(T, rng, *, size=128, amplitude=2000.0, contrast=0.8, strain=0.0,
                translation=(0.0, 0.0), vibration=0.1, rotation=0.0, bits=12, slip=None):
    """``(frames (T, size, size) uint16, shifts (T, 2) px)``; see the module docstring.

    ``slip = (t0, (dx, dy))`` adds a rigid shift of ``(dx, dy)`` px to frames
    ``t >= t0`` (the camera or the grid slipped). ``shifts[t]`` is the total ``a_t``.
    ``rotation``: standard deviation of a rigid rotation of each frame about the
    image centre, rad (a camera that rocks).
    """
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    x0 = (size - 1) / 2
    frames, shifts = [], []
    for t in range(T):
        a = rng.normal(0.0, vibration, 2) if vibration else np.zeros(2)
        if slip is not None and t >= slip[0]:
            a = a + np.asarray(slip[1], dtype=float)
        th = rng.normal(0.0, rotation) if rotation else 0.0
        x = x0 + (xx - x0) * np.cos(th) - (yy - x0) * np.sin(th)
        y = x0 + (xx - x0) * np.sin(th) + (yy - x0) * np.cos(th)
        # pixel x shows the material point X with x + a = X + u(X)
        X = (x + a[0] + strain * x0 - translation[0]) / (1 + strain)
        Y = y + a[1] - translation[1]
        i = amplitude * (1 + contrast / 2 * (np.cos(2 * np.pi * X / PITCH)
                                             + np.cos(2 * np.pi * Y / PITCH)))
        i = i + np.sqrt(0.28 * i + 5.0) * rng.standard_normal(i.shape)
        frames.append(np.clip(np.rint(i), 0, 2**bits - 1).astype(np.uint16))
        shifts.append(a)
    return np.array(frames), np.array(shifts)


def write_folder(directory, frames, prefix="img"):
    directory.mkdir()
    for t, f in enumerate(frames):
        tifffile.imwrite(directory / f"{prefix}_{t:03d}.tif", f, photometric="minisblack")
    return directory


def mean_map(result, name, state=0):
    v = result.valid[state]
    return float(np.mean(result.get_map(name)[state][v]))


def screening_warnings(result):
    return said(result.warnings, "screening.flagged")


# --------------------------------------------------------------------------- bad series


def test_a_loaded_frame_in_the_reference_folder_is_named_and_excluded(tmp_path):
    rng = np.random.default_rng(1)
    ref, _ = grid_frames(10, rng)
    load, _ = grid_frames(11, rng, strain=STRAIN)
    folder = write_folder(tmp_path / "ref", np.concatenate([ref[:4], load[10:], ref[4:]]))
    res = measure_series(folder, load[:10], lattice=LAT)
    assert res.n_frames == (10, 10)
    assert res.excluded == ((4,), ())
    (w,) = screening_warnings(res)
    assert "reference: excluded 1 of 11" in w
    assert "img_004.tif" in w
    assert "another state" in w
    # the mean strain of the region; a tenth of a loaded frame in the reference made
    # it 1.81e-3 (-9.4 %); the noise of the mean over ~7000 valid pixels and the
    # window's bias stay below 1.5e-5 (0.75 %)
    assert abs(mean_map(res, "exx") - STRAIN) < 1.5e-5
    # the same measurement as with the ten reference frames alone
    clean = measure_series(ref, load[:10], lattice=LAT)
    assert_allclose(res.strain, clean.strain, rtol=0, atol=1e-12)  # the same frames
    with pytest.raises(ValueError, match=r"reference: frame 4 \(.*img_004\.tif\): "
                                         r"non-rigid displacement"):
        measure_series(folder, load[:10], lattice=LAT, outliers="refuse")


def test_a_loaded_frame_kept_on_request_voids_the_stated_precision():
    rng = np.random.default_rng(2)
    ref, _ = grid_frames(10, rng)
    load, _ = grid_frames(11, rng, strain=STRAIN)
    mixed = np.concatenate([ref[:4], load[10:], ref[4:]])
    res = measure_series(mixed, load[:10], lattice=LAT, outliers="warn", method="B")
    assert res.n_frames == (11, 10)
    assert res.excluded == ((), ())
    assert any("kept 1 flagged frame(s) of 11" in w and "frame 4:" in w
               for w in said(res.warnings, "screening.flagged"))
    # the strain is biased by about a tenth of the loaded frame's: no precision stated
    assert abs(mean_map(res, "exx") - STRAIN) > 1e-4
    assert np.all(np.isnan(res.uncertainty["exx_std"]))
    assert np.all(np.isnan(res.noise.theory_strain))
    assert np.all(np.isnan(res.noise.split_u))


def test_a_reference_slipping_half_way_is_refused_with_the_frames_named():
    rng = np.random.default_rng(3)
    ref, _ = grid_frames(10, rng, slip=(5, (3.0, 0.0)))
    cur, _ = grid_frames(10, rng, translation=(0.3, 0.0))
    # half the frames on each side: which half is right cannot be known
    with pytest.raises(ValueError, match=r"reference: frame [0-9]: rigid shift \([+-][12]\."
                                         r"\d\d, .*slipped.*5 of 10 frame\(s\) flagged \(half"):
        measure_series(ref, cur, lattice=LAT)


def test_a_reference_slipping_late_loses_its_last_frames_and_stays_right():
    rng = np.random.default_rng(4)
    ref, a_ref = grid_frames(10, rng, slip=(7, (3.0, 0.0)))
    cur, a_cur = grid_frames(10, rng, translation=(0.3, 0.0))
    res = measure_series(ref, cur, lattice=LAT)
    assert res.excluded == ((7, 8, 9), ())
    (w,) = screening_warnings(res)
    # a 3-px slip at pitch 5 reads as -2 px: known modulo a pitch, still a slip
    assert "excluded 3 of 10" in w
    assert "rigid shift (-2." in w
    # u = t - a (module docstring): averaged over the frames kept; the vibration
    # offsets are known exactly here, the rest is sensor noise of the mean (1e-3 px)
    want = 0.3 - a_cur[:, 0].mean() + a_ref[:7, 0].mean()
    assert abs(mean_map(res, "ux") - want) < 3e-3
    assert abs(mean_map(res, "exx")) < 1.5e-5  # no strain; the noise of the mean
    # the contrast of the mean reference is that of seven frames, not 0.27
    assert min(res.vibration[0].contrast_factor) > 0.98


def test_a_12_bit_camera_clipping_at_4095_in_16_bit_files_is_recognised(tmp_path):
    rng = np.random.default_rng(5)
    ref, _ = grid_frames(6, rng, amplitude=2200.0)  # peaks at 3960: never clipped
    cur, _ = grid_frames(6, rng, amplitude=2200.0 * 1.15, strain=STRAIN)  # 15 % brighter
    assert ref.max() < 4095
    assert (cur == 4095).mean() > 0.03
    r = write_folder(tmp_path / "ref", ref)
    c = write_folder(tmp_path / "cur", cur, prefix="load")
    with pytest.raises(ValueError, match=r"cur: frame 0 \(.*load_000\.tif\): 4\.\d+% of "
                                         r"its pixels saturated \(clipped at 4095 = 2\^12 - 1, "
                                         r"below the files' range"):
        measure_series(r, c, lattice=LAT)
    # clipping below max_saturation is measured and reported with its level
    few, _ = grid_frames(6, rng, amplitude=2200.0 * 1.02, strain=STRAIN)
    assert 0 < (few == 4095).mean() < 0.01
    res = measure_series(r, few, lattice=LAT)
    assert 0 < res.saturation[1] < 0.01
    assert any("state 0: up to" in w and "clipped at 4095" in w and "2^n - 1" in w
               for w in said(res.warnings, "saturation"))


def test_a_black_frame_in_the_reference_is_excluded_by_both_methods():
    rng = np.random.default_rng(6)
    ref, _ = grid_frames(10, rng)
    cur, _ = grid_frames(10, rng, strain=STRAIN)
    black = ref.copy()
    black[3] = np.rint(rng.normal(30.0, 3.0, ref.shape[1:])).astype(np.uint16)  # lens cap
    for method in ("A", "B"):
        res = measure_series(black, cur, lattice=LAT, method=method)
        assert res.excluded == ((3,), ())
        assert any("frame 3: shows no grid" in w
                   for w in said(res.warnings, "screening.flagged"))
        want = measure_series(np.delete(ref, 3, axis=0), cur, lattice=LAT, method=method)
        assert_allclose(res.strain, want.strain, rtol=0, atol=1e-12)  # the same frames
        # the noise variance's fit on the carriers' first harmonics (0.1 px of
        # vibration: their parts independent of the shifts are ~theta^3 / 6, 4e-4)
        # magnifies the rounding of the black frame's sums taken out (d ~ 2000 grey
        # levels) about a thousand times: 1e-12 of the variance, 1e-10 allowed
        assert_allclose(res.uncertainty["exx_std"], want.uncertainty["exx_std"], rtol=1e-10)
        assert res.n_frames == want.n_frames
        assert_allclose(res.noise.split_strain, want.noise.split_strain, rtol=1e-12)
        assert_allclose(res.noise.theory_strain, want.noise.theory_strain, rtol=1e-10)
        assert abs(mean_map(res, "exx") - STRAIN) < 1.5e-5  # noise of the mean strain


def test_a_uniform_frame_is_named_as_such():
    rng = np.random.default_rng(7)
    ref, _ = grid_frames(5, rng)
    ref[2] = 4095
    sc = screen_frames(ref, LAT, saturation_level=65535)
    assert sc.flagged == (2,)
    assert sc.reasons[2][0].startswith("uniform")
    assert sc.reasons[2][-1].startswith("100.00% of its pixels saturated (clipped at 4095")


# --------------------------------------------------------------------------- no false alarm


@pytest.mark.parametrize("seed", range(4))
def test_a_clean_series_raises_no_alarm(seed):
    rng = np.random.default_rng(100 + seed)
    ref, _ = grid_frames(10, rng, vibration=0.1)
    cur, _ = grid_frames(10, rng, vibration=0.1, strain=STRAIN, translation=(1.3, -0.4))
    res = measure_series(ref, cur, lattice=LAT, method="AB"[seed % 2])
    assert screening_warnings(res) == []
    assert res.excluded == ((), ())
    assert res.n_frames == (10, 10)


@pytest.mark.parametrize(("size", "vibration"), [(128, 0.1), (256, 0.1), (128, 0.25)])
def test_screening_statistics_of_clean_series_stay_within_their_limits(size, vibration):
    """Many frames, several seeds: no frame flagged, and the margins that say why."""
    for seed in range(3):
        rng = np.random.default_rng(200 + seed)
        frames, _ = grid_frames(40, rng, size=size, vibration=vibration, strain=STRAIN)
        sc = screen_frames(frames, LAT, saturation_level=65535)
        assert sc.flagged == ()
        # residuals of one state are alike: with 2 x 2 tiles (128 px, 5 degrees of
        # freedom) the largest of thousands of frames reached 3x the median, the
        # limit being 5x; with 4 x 4 (256 px, 29) 1.6x, the limit being 3x
        limit = 5.0 if size == 128 else 3.0
        assert sc.residual.max() < 0.7 * limit * np.median(sc.residual)
        assert np.all(sc.modulus_ratio > 0.9)  # vibrations change no frame's contrast
        assert np.all(sc.saturated == 0)


def test_a_camera_that_rocks_is_no_other_state():
    """Rigid rotations of 3e-4 rad move tiles 32 px from the centre by 0.01 px, ten
    times their noise: the rotation is fitted out with the translation."""
    for seed in range(3):
        rng = np.random.default_rng(300 + seed)
        frames, _ = grid_frames(12, rng, size=256, rotation=3e-4)
        sc = screen_frames(frames, LAT, saturation_level=65535)
        assert sc.flagged == ()
        # while a frame strained by 3e-4 (e_xx) stands out
        grown, _ = grid_frames(1, rng, size=256, strain=3e-4)
        sc = screen_frames(np.concatenate([frames, grown]), LAT, saturation_level=65535)
        assert sc.flagged == (12,)
        assert "another state" in sc.reasons[12][0]


def test_shifts_of_the_frames_kept_are_those_frame_shifts_gives():
    from gridstrain import frame_shifts

    rng = np.random.default_rng(8)
    frames, _ = grid_frames(8, rng, vibration=0.2)
    sc = screen_frames(frames, LAT)
    assert_allclose(sc.shifts(), frame_shifts(frames, LAT), rtol=0, atol=1e-12)
    keep = [0, 2, 3, 7]
    assert_allclose(sc.shifts(keep), frame_shifts(frames[keep], LAT), rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- records


def test_excluded_frames_are_recorded_in_the_file(tmp_path):
    rng = np.random.default_rng(9)
    ref, _ = grid_frames(6, rng)
    cur, _ = grid_frames(6, rng, strain=STRAIN)
    ref[5] = 0
    res = measure_series(ref, cur, lattice=LAT)
    out = save_result(res, tmp_path / "m.h5")
    attrs = read_attrs(out)  # the sentences and their codes, as any HDF5 reader sees them
    assert any("frame 5: uniform" in w
               for w, c in zip(attrs["warnings"], attrs["warning_codes"], strict=True)
               if c == "screening.flagged")
    back = load(out)
    assert back.excluded == ((5,), ())
    assert back.n_frames == (5, 6)
    sc = back.screening[0]
    assert sc.reasons[5][0].startswith("uniform")
    assert_allclose(sc.residual, res.screening[0].residual, rtol=0, equal_nan=True)
    assert_allclose(sc.deviation, res.screening[0].deviation, rtol=0, equal_nan=True)


def test_outliers_option_is_checked():
    rng = np.random.default_rng(10)
    ref, _ = grid_frames(2, rng)
    with pytest.raises(ValueError, match="outliers must be one of"):
        measure_series(ref, ref, lattice=LAT, outliers="drop")


def test_command_line_names_the_frame_and_follows_outliers(tmp_path, capsys):
    from gridstrain.cli import main

    rng = np.random.default_rng(11)
    ref, _ = grid_frames(6, rng)
    cur, _ = grid_frames(6, rng, strain=STRAIN)
    ref[2] = np.rint(rng.normal(30.0, 3.0, ref.shape[1:])).astype(np.uint16)  # black
    r = write_folder(tmp_path / "ref", ref)
    c = write_folder(tmp_path / "cur", cur)
    out = tmp_path / "m.h5"
    rc = main(["measure", str(r), str(c), "-o", str(out), "--pitch", "5", "--quiet",
               "--outliers", "refuse"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1
    assert not out.exists()
    assert "reference: frame 2 (" in err[0]
    assert "img_002.tif" in err[0]
    assert "no grid" in err[0]
    assert main(["measure", str(r), str(c), "-o", str(out), "--pitch", "5", "--json",
                 "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["reference"]["excluded_frames"] == [2]
    # the option from a configuration file, and a bad value refused in one line
    cfg = tmp_path / "run.toml"
    cfg.write_text('outliers = "refuse"\n')
    assert main(["measure", str(r), str(c), "-o", str(tmp_path / "n.h5"), "--pitch", "5",
                 "--quiet", "--config", str(cfg)]) != 0
    cfg.write_text('outliers = "drop"\n')
    assert main(["measure", str(r), str(c), "-o", str(tmp_path / "n.h5"), "--pitch", "5",
                 "--quiet", "--config", str(cfg)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert "no grid" in err[0]
    assert "outliers must be one of 'exclude', 'refuse', 'warn', got 'drop'" in err[1]
    assert summary["reference"]["frames"] == 5
    assert any("img_002.tif" in w for w in said(summary, "screening.flagged"))


def test_a_subset_of_a_file_series_names_frames_as_in_the_folder(tmp_path):
    from gridstrain.io import open_series

    rng = np.random.default_rng(12)
    frames, _ = grid_frames(4, rng, size=64)
    series = open_series(write_folder(tmp_path / "s", frames), name="reference")
    sub = series.subset([0, 2, 3]).subset([1, 2])
    assert sub.n_frames == 2
    assert sub.describe_frame(0) == f"frame 2 ({tmp_path / 's' / 'img_002.tif'})"
    np.testing.assert_array_equal(np.array(list(sub.frames(dtype=None))), frames[2:])
    assert_allclose(sub.mean(), frames[2:].mean(axis=0), rtol=1e-15)
    with pytest.raises(ValueError, match="at least one frame"):
        series.subset([])


def test_clipping_is_a_pile_up_at_the_top_not_a_maximum_that_happens_to_be_2n_minus_1():
    rng = np.random.default_rng(13)
    frames, _ = grid_frames(3, rng, size=64)
    frames[:, 10, 10] = 4095  # one pixel per frame at 4095: a maximum, no pile-up
    sc = screen_frames(frames, LAT, saturation_level=65535)
    assert np.all(sc.saturated == 0)
    # float data normalised to [0, 1] and clipped at 1 (2^1 - 1)
    flt = np.clip(frames / 3000.0, 0, 1).astype(np.float32)
    assert (flt == 1).mean() > 0.05  # the premise
    sc = screen_frames(flt, LAT, max_saturation=0.01)
    assert sc.flagged == (0, 1, 2)
    assert sc.reasons[0][0].endswith("(clipped at 1), more than max_saturation=1.00%")


def test_clipping_is_counted_on_the_specimen_only():
    """A lamp's glare clips a corner off the specimen: with a mask that leaves it out,
    no pixel of the specimen is clipped; without one (or with one that keeps every
    pixel) the corner is counted, 6 % of the frame."""
    rng = np.random.default_rng(14)
    frames, _ = grid_frames(4, rng, size=96)
    frames[:, :24, :24] = 4095  # 576 of 9216 pixels
    mask = np.ones((96, 96), dtype=bool)
    mask[:32, :32] = False
    sc = screen_frames(frames, LAT, saturation_level=65535, mask=mask)
    assert np.all(sc.saturated == 0)
    assert sc.flagged == ()
    for m in (None, np.ones((96, 96), dtype=bool)):
        sc = screen_frames(frames, LAT, saturation_level=65535, mask=m)
        assert_allclose(sc.saturated, 576 / 96**2)  # exact counts
        assert np.all(sc.clip_level == 4095)
        assert sc.flagged == (0, 1, 2, 3)


def test_white_paper_clipping_between_the_lines_points_to_max_saturation():
    """A photo of printed grid paper: 8-bit, the white paper between the lines clips at
    255 on about a quarter of the pixels. The default refuses and names the option
    that accepts it; with it the phase is still measured (within the noise of one
    8-bit pair)."""
    rng = np.random.default_rng(11)
    y, x = np.mgrid[0:128, 0:160].astype(float)

    def photo(shift):
        lines = np.cos(2 * np.pi * (x - shift) / 6) + np.cos(2 * np.pi * y / 6)
        img = 230 + 40 * lines + rng.normal(0, 2, x.shape)
        return np.clip(np.round(img), 0, 255).astype(np.uint8)

    ref, cur = photo(0.0), photo(0.4)
    assert 0.15 < np.mean(ref == 255) < 0.5
    with pytest.raises(ValueError, match=r"--max-saturation"):
        measure_series(ref, cur, lattice=Lattice.from_pitch(6.0))
    res = measure_series(ref, cur, lattice=Lattice.from_pitch(6.0), max_saturation=0.6)
    # a rigid 0.4-px shift. Clipping sharpens the profile, and at this integer pitch
    # its harmonics fold onto the carrier: measured 0.008 px of bias (the pixel noise,
    # 6e-3 px, averages out in the median); 0.02 px bounds it with room
    assert abs(np.nanmedian(res.ux[0]) - 0.4) < 0.02
    assert said(res.warnings, "saturation")
    # and that systematic error is stated, not silent
    assert said(res.warnings, "aliasing.bound")


def test_a_large_dark_hole_is_not_taken_for_noise():
    """A 128-px frame of a plate whose hole (radius 32 px, a dark background at 5 % of
    the grid's level) fills a fifth of it: the grid's carrier must stand out of the
    frame's noise level, which the hole's slowly varying darkness must not inflate
    (it once made every frame 'show no grid'). Numpy-only frames: a cosine grid of
    pitch 5 px along x and y, Gaussian noise of 2 grey levels."""
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:128, 0:128].astype(float)
    grid = 2000 + 600 * (np.cos(2 * np.pi * x / 5) + np.cos(2 * np.pi * y / 5))
    hole = (x - 80) ** 2 + (y - 50) ** 2 < 32**2
    frames = [np.where(hole, 100.0, grid) + rng.normal(0, 2, grid.shape) for _ in range(6)]
    sc = screen_frames(frames, Lattice.from_pitch(5.0))
    assert sc.flagged == ()
    # the grid stands tens of times above the noise, far from the limit of 5
    assert float(sc.prominence.min()) > 20


# --------------------------------------------------------------------------- bare methods


def _with_a_loaded_frame(seed, at=4):
    """10 reference frames, frame ``at`` swapped for a frame of the loaded state."""
    rng = np.random.default_rng(seed)
    ref, _ = grid_frames(10, rng)
    load, _ = grid_frames(1, rng, strain=STRAIN)
    ref[at] = load[0]
    return ref


@pytest.mark.parametrize("method", [method_a, method_b, method_c])
def test_bare_methods_name_a_loaded_frame_they_average(method):
    stack = _with_a_loaded_frame(21)
    res = method(stack, LAT)
    assert res.n_frames == 10  # a stream read once cannot be taken back: it stays in
    assert res.screening.flagged == (4,)
    (w,) = said(res.warnings, "screening.flagged")
    assert "frames[4]: non-rigid displacement" in w
    assert "measure_series" in w  # what the user can do
    clean = method(np.delete(stack, 4, axis=0), LAT)
    assert clean.screening.flagged == ()
    assert not said(clean.warnings, "screening.flagged")


def test_bare_methods_screen_a_black_frame_and_can_be_told_not_to():
    rng = np.random.default_rng(22)
    stack, _ = grid_frames(8, rng)
    stack[2] = np.rint(rng.normal(30.0, 3.0, stack.shape[1:])).astype(np.uint16)  # lens cap
    res = method_a(iter(list(stack)), LAT)  # a generator: screened as it is read
    assert res.screening.flagged == (2,)
    (flagged,) = said(res.warnings, "screening.flagged")
    assert "frames[2]: shows no grid" in flagged
    quiet = method_a(stack, LAT, screen=False)
    assert quiet.screening is None
    assert quiet.warnings == ()
    # the screening changes no number of the average
    assert_allclose(quiet.maps.phase, res.maps.phase, rtol=0, atol=0)


def test_method_b_screens_in_frame_order_on_any_number_of_threads():
    stack = _with_a_loaded_frame(23, at=6)
    one, two = method_b(stack, LAT, workers=1), method_b(stack, LAT, workers=2)
    assert one.screening.reasons == two.screening.reasons
    assert one.screening.flagged == (6,)
    assert one.warnings == two.warnings
