"""Tests of gridstrain.io: reading lab image series, atomic writing of results."""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

import h5py
import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
from numpy.testing import assert_allclose, assert_array_equal

from gridstrain.io import (
    FrameSeries,
    atomic_path,
    close_readers,
    natural_sort_key,
    open_series,
    read_hdf5,
    read_mask,
    roi_mask,
    write_csv,
    write_hdf5,
    write_tiff_series,
)

SHAPE = (24, 32)


def _frames12(rng, n, shape=SHAPE):
    """12-bit sensor values (0..4095) as uint16."""
    return [rng.integers(0, 4096, shape).astype(np.uint16) for _ in range(n)]


def _snapshot(paths):
    """Content hash and modification time of every file: inputs must stay unchanged."""
    return {Path(p): (hashlib.sha256(Path(p).read_bytes()).hexdigest(),
                      os.stat(p).st_mtime_ns) for p in paths}


def _write(folder: Path, names, frames):
    for n, f in zip(names, frames, strict=True):
        tifffile.imwrite(folder / n, f, photometric="minisblack")
    return [folder / n for n in names]


# ------------------------------------------------------------------------ source kinds


def test_natural_sort_key():
    names = ["f10.tif", "F2.tif", "f1.tif", "f02.tif", "g1.tif", "f1b.tif"]
    assert sorted(names, key=natural_sort_key) == [
        "f1.tif", "f1b.tif", "F2.tif", "f02.tif", "f10.tif", "g1.tif"]
    # equal numbers (F2, f02) fall back to the plain string, so the order is total


def test_single_file(tmp_path):
    rng = np.random.default_rng(1)
    img = rng.integers(0, 65536, SHAPE).astype(np.uint16)
    (path,) = _write(tmp_path, ["one.tif"], [img])
    s = open_series(path)
    assert isinstance(s, FrameSeries)
    assert s.paths == (path,)
    assert (s.n_frames, len(s), s.shape, s.dtype) == (1, 1, SHAPE, np.dtype(np.uint16))
    out = s.read(0)
    assert out.dtype == np.float64
    assert_array_equal(out, img)  # uint16 -> float64 is exact
    assert s.read(0, dtype=None).dtype == np.uint16
    assert s.read(0, dtype=np.float32).dtype == np.float32
    assert s.source_of(0) == (path, 0)
    assert "n_frames=1" in repr(s)


def test_multipage_stack_read_page_by_page(tmp_path):
    rng = np.random.default_rng(2)
    stack = np.stack(_frames12(rng, 5))
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, stack, photometric="minisblack")
    s = open_series(str(path))
    assert s.n_frames == 5
    assert s.paths == (path,)
    for k, frame in enumerate(s.frames(dtype=None)):
        assert_array_equal(frame, stack[k])
    assert_array_equal(s.read(3), stack[3])
    assert_array_equal(s.read(-1), stack[4])
    assert s.source_of(3) == (path, 3)
    assert "page 3" in s.describe_frame(3)
    # a sub-range
    got = list(s.frames(start=1, stop=3, dtype=None))
    assert len(got) == 2
    assert_array_equal(got[1], stack[2])


def test_a_records_pages_are_read_from_one_open_file(tmp_path, monkeypatch):
    # a record's states read one page each: the file is opened once, not once a page
    # (each opening walks the chain of pages from the first)
    from gridstrain.io import _readers

    pages = np.arange(12 * 16 * 20, dtype=np.uint16).reshape(12, 16, 20)
    tifffile.imwrite(tmp_path / "rec.tif", pages, photometric="minisblack")
    s = open_series(tmp_path / "rec.tif")
    opened = []
    real = _readers.tifffile.TiffFile

    def counting(*args, **kwargs):
        opened.append(args[0])
        return real(*args, **kwargs)

    monkeypatch.setattr(_readers.tifffile, "TiffFile", counting)
    close_readers()
    for k in range(12):
        assert_array_equal(s.read(k, dtype=None), pages[k])
    assert len(opened) == 1
    # a file written again is read again, not from the open one
    tifffile.imwrite(tmp_path / "rec.tif", pages[::-1], photometric="minisblack")
    st = os.stat(tmp_path / "rec.tif")  # a later time, whatever the clock's resolution
    os.utime(tmp_path / "rec.tif", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert_array_equal(s.read(0, dtype=None), pages[-1])
    assert len(opened) == 2
    close_readers()
    assert _readers._TIFF_CURSOR.tif is None


def test_directory_natural_order_ignores_other_files(tmp_path):
    rng = np.random.default_rng(3)
    names = ["f10.tif", "f2.tif", "f1.tif"]
    frames = [np.full(SHAPE, v, np.uint16) + rng.integers(0, 5, SHAPE).astype(np.uint16)
              for v in (1000, 200, 100)]
    _write(tmp_path, names, frames)
    (tmp_path / "notes.txt").write_text("exposure 10 ms")
    (tmp_path / "._f3.tif").write_bytes(b"resource fork, not a TIFF")
    (tmp_path / "sub").mkdir()
    tifffile.imwrite(tmp_path / "sub" / "f0.tif", frames[0])
    s = open_series(tmp_path)
    assert [p.name for p in s.paths] == ["f1.tif", "f2.tif", "f10.tif"]
    # the order of the data follows the names, not the writing order
    assert [int(f.min()) // 100 for f in s.frames()] == [1, 2, 10]


def test_glob_natural_order(tmp_path):
    rng = np.random.default_rng(4)
    _write(tmp_path, ["img_10.tif", "img_9.tif", "img_1.tif", "other_1.tif"],
           _frames12(rng, 4))
    (tmp_path / "img_5.txt").write_text("not an image")
    s = open_series(str(tmp_path / "img_*"))
    assert [p.name for p in s.paths] == ["img_1.tif", "img_9.tif", "img_10.tif"]


def test_list_keeps_given_order_and_expands_stacks(tmp_path):
    rng = np.random.default_rng(5)
    frames = _frames12(rng, 4)
    a, b = _write(tmp_path, ["b.tif", "a.tif"], frames[:2])
    stack = tmp_path / "s.tif"
    tifffile.imwrite(stack, np.stack(frames[2:]), photometric="minisblack")
    s = open_series([a, str(stack), b])
    assert s.paths == (a, stack, b)
    assert s.n_frames == 4
    got = list(s.frames(dtype=None))
    for g, want in zip(got, [frames[0], frames[2], frames[3], frames[1]], strict=True):
        assert_array_equal(g, want)


def test_png_and_bmp(tmp_path):
    rng = np.random.default_rng(6)
    g8 = rng.integers(0, 256, SHAPE).astype(np.uint8)
    g16 = rng.integers(0, 65536, SHAPE).astype(np.uint16)
    iio.imwrite(tmp_path / "a.png", g8)
    iio.imwrite(tmp_path / "b.bmp", g8)
    iio.imwrite(tmp_path / "c.png", g16)
    s8 = open_series([tmp_path / "a.png", tmp_path / "b.bmp"])
    assert (s8.bit_depth, s8.saturation_level) == (8, 255)
    for f in s8.frames(dtype=None):
        assert_array_equal(f, g8)
    s16 = open_series(tmp_path / "c.png")
    assert s16.dtype == np.uint16
    assert_array_equal(s16.read(0, dtype=None), g16)


# ------------------------------------------------------------------------ bit depth


def test_depth_8_bit(tmp_path):
    rng = np.random.default_rng(7)
    (p,) = _write(tmp_path, ["a.tif"], [rng.integers(0, 256, SHAPE).astype(np.uint8)])
    s = open_series(p)
    assert (s.bit_depth, s.scale, s.saturation_level) == (8, 1, 255)


def test_depth_12_bit_stored_x16(tmp_path):
    rng = np.random.default_rng(8)
    sensor = _frames12(rng, 3)
    sensor[0][0, 0] = 4095  # the largest 12-bit value, 65520 once stored
    paths = _write(tmp_path, ["a1.tif", "a2.tif", "a3.tif"], [f * 16 for f in sensor])
    s = open_series(tmp_path)
    assert (s.bit_depth, s.scale, s.saturation_level) == (12, 16, 4095 * 16)
    # raw by default: the x16 is recorded, not removed
    assert_array_equal(s.read(0), sensor[0] * 16.0)
    assert_array_equal(s.read(0, to_sensor_units=True), sensor[0])
    assert_array_equal(s.read(1, dtype=None, to_sensor_units=True), sensor[1])
    # an explicit 16-bit declaration turns the detection off
    s16 = open_series(paths, bit_depth=16)
    assert (s16.bit_depth, s16.scale, s16.saturation_level) == (16, 1, 65535)


def test_depth_16_bit(tmp_path):
    rng = np.random.default_rng(9)
    img = rng.integers(0, 65536, SHAPE).astype(np.uint16)
    (p,) = _write(tmp_path, ["a.tif"], [img])
    s = open_series(p)
    assert (s.bit_depth, s.scale, s.saturation_level) == (16, 1, 65535)
    assert_array_equal(s.read(0, to_sensor_units=True), img)  # scale 1: no change


def test_depth_declared_right_aligned_12_bit(tmp_path):
    rng = np.random.default_rng(10)
    (p,) = _write(tmp_path, ["a.tif"], _frames12(rng, 1))
    s = open_series(p, bit_depth=12)
    assert (s.bit_depth, s.scale, s.saturation_level) == (12, 1, 4095)


def test_depth_declared_that_does_not_fit(tmp_path):
    img = np.full(SHAPE, 40001, np.uint16)
    (p,) = _write(tmp_path, ["a.tif"], [img])
    with pytest.raises(ValueError, match=r"bit_depth=12 does not fit .*a\.tif"):
        open_series(p, bit_depth=12)
    with pytest.raises(ValueError, match=r"bit_depth must be an integer in \[1, 16\]"):
        open_series(p, bit_depth=20)


def test_depth_float(tmp_path):
    img = np.random.default_rng(11).random(SHAPE, dtype=np.float32)
    (p,) = _write(tmp_path, ["a.tif"], [img])
    s = open_series(p)
    assert (s.bit_depth, s.scale, s.saturation_level) == (None, 1, None)
    assert s.read(0, dtype=None).dtype == np.float32
    with pytest.raises(ValueError, match="bit_depth applies to integer images"):
        open_series(p, bit_depth=12)


def test_later_frame_breaking_x16_refused_in_sensor_units(tmp_path):
    rng = np.random.default_rng(12)
    frames = [f * 16 for f in _frames12(rng, 4)]
    frames[3][5, 5] += 3  # not a multiple of 16
    paths = _write(tmp_path, [f"f{i}.tif" for i in range(4)], frames)
    s = open_series(tmp_path)
    assert s.scale == 16  # set by the first three frames
    with pytest.raises(ValueError, match=r"f3\.tif.*not multiples of 16"):
        s.mean(to_sensor_units=True)
    assert_array_equal(s.read(3), frames[3])  # raw reading is unaffected
    assert paths[3] in s.paths


# ------------------------------------------------------------------------ streaming mean


def test_mean_integer_frames_exact(tmp_path):
    rng = np.random.default_rng(13)
    frames = [f * 16 for f in _frames12(rng, 7)]
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.stack(frames[:4]), photometric="minisblack")
    singles = _write(tmp_path, ["x1.tif", "x2.tif", "x3.tif"], frames[4:])
    s = open_series([stack, *singles])
    calls = []
    m = s.mean(progress=lambda f, msg: calls.append((f, msg)))
    # oracle: the integer sum is exact, so the mean is that sum divided once by T,
    # correctly rounded; float64 accumulation of 16-bit integers is exact as well
    total = np.sum(np.stack(frames).astype(np.int64), axis=0)
    assert m.dtype == np.float64
    assert_array_equal(m, total / 7)
    assert_array_equal(m, np.mean(np.stack(frames), axis=0, dtype=np.float64))
    assert_array_equal(s.mean(to_sensor_units=True), total / 7 / 16)
    assert s.mean(dtype=np.float32).dtype == np.float32
    fractions = [f for f, _ in calls]
    assert fractions[0] == 0.0
    assert fractions[-1] == 1.0
    assert fractions == sorted(fractions)
    assert len(fractions) == 8
    # a sub-range: frames 2..4
    assert_array_equal(s.mean(start=2, stop=5),
                       np.sum(np.stack(frames[2:5]).astype(np.int64), axis=0) / 3)


def test_mean_float_frames_to_rounding(tmp_path):
    rng = np.random.default_rng(14)
    T = 6
    frames = [(rng.random((8, 9)) * 1e3).astype(np.float32) for _ in range(T)]
    path = tmp_path / "f.tif"
    tifffile.imwrite(path, np.stack(frames), photometric="minisblack")
    m = open_series(path).mean()
    # oracle: the correctly rounded sum of each pixel's values (math.fsum)
    want = np.array([[math.fsum(float(f[i, j]) for f in frames) / T
                      for j in range(9)] for i in range(8)])
    # relative: T sequential float64 additions each round by at most 2**-53
    assert_allclose(m, want, rtol=T * 2.0**-53, atol=0)


# ------------------------------------------------------------------------ bad inputs


def test_missing_path(tmp_path):
    p = tmp_path / "nope.tif"
    with pytest.raises(FileNotFoundError, match=r"nope\.tif does not exist"):
        open_series(p)
    with pytest.raises(FileNotFoundError, match=r"nope\.tif does not exist"):
        open_series([p])


def test_empty_directory_and_directory_without_images(tmp_path):
    with pytest.raises(ValueError, match=rf"directory {tmp_path} holds no image file"):
        open_series(tmp_path)
    (tmp_path / "readme.txt").write_text("x")
    with pytest.raises(ValueError, match=r"holds no image file .*1 other file"):
        open_series(tmp_path)


def test_glob_matching_nothing(tmp_path):
    pattern = str(tmp_path / "run*.tif")
    with pytest.raises(FileNotFoundError, match="no file matches the glob pattern"):
        open_series(pattern)
    (tmp_path / "run1.txt").write_text("x")
    with pytest.raises(ValueError, match="matches 1 file"):
        open_series(str(tmp_path / "run*"))


def test_empty_list_and_bad_types(tmp_path):
    with pytest.raises(ValueError, match="list of image files is empty"):
        open_series([])
    with pytest.raises(TypeError, match="must be a path"):
        open_series(42)
    with pytest.raises(ValueError, match="is a directory"):
        open_series([tmp_path])


def test_unknown_extension(tmp_path):
    p = tmp_path / "frame.gif"
    p.write_bytes(b"GIF89a")
    with pytest.raises(ValueError, match=r"frame\.gif has extension '\.gif'"):
        open_series(p)


def test_mixed_sizes_names_offending_file(tmp_path):
    rng = np.random.default_rng(15)
    _write(tmp_path, ["f1.tif", "f2.tif", "f3.tif"],
           [*_frames12(rng, 2), _frames12(rng, 1, (24, 31))[0]])
    with pytest.raises(ValueError, match=r"f3\.tif is \(24, 31\) but .*f1\.tif is \(24, 32\)"):
        open_series(tmp_path, name="deformed")
    with pytest.raises(ValueError, match=r"^deformed: frames of different sizes"):
        open_series(tmp_path, name="deformed")


def test_mixed_pixel_types(tmp_path):
    _write(tmp_path, ["f1.tif", "f2.tif"],
           [np.zeros(SHAPE, np.uint16), np.zeros(SHAPE, np.uint8)])
    with pytest.raises(ValueError, match=r"f2\.tif holds uint8 but .*f1\.tif holds uint16"):
        open_series(tmp_path)


def test_corrupt_tiff(tmp_path):
    garbage = tmp_path / "bad.tif"
    garbage.write_bytes(b"this is not a TIFF file at all")
    with pytest.raises(OSError, match=r"bad\.tif"):
        open_series(garbage)
    header_only = tmp_path / "head.tif"
    header_only.write_bytes(b"II*\x00\xff\xff\xff\x00 garbage")
    with pytest.raises(OSError, match=r"head\.tif"):
        open_series(header_only)
    png = tmp_path / "bad.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    with pytest.raises(OSError, match=r"^series: cannot read .*bad\.png"):
        open_series(png)


def test_truncated_tiff_fails_when_read(tmp_path):
    rng = np.random.default_rng(16)
    paths = _write(tmp_path, ["a1.tif", "a2.tif", "a3.tif", "b.tif"],
                   _frames12(rng, 4, (64, 64)))
    data = paths[3].read_bytes()
    paths[3].write_bytes(data[: len(data) // 2])  # header intact, pixel data cut
    # refused on opening, naming the file: the page's data run past its end
    with pytest.raises(OSError, match=r"b\.tif is truncated"):
        open_series(tmp_path)


@pytest.mark.parametrize("kind", ["rgb_tif", "rgb_tif_planar", "rgb_png", "rgba_png",
                                  "gray_alpha_png"])
def test_colour_images_read_as_luminance(tmp_path, kind):
    """Colour frames are read as 0.2126 R + 0.7152 G + 0.0722 B (BT.709), alpha ignored.

    Oracle: the weighted sum of the channels written, computed here by hand.
    """
    rng = np.random.default_rng(7)
    nch = {"rgb_png": 3, "rgba_png": 4, "gray_alpha_png": 2}.get(kind, 3)
    rgb = rng.integers(0, 256, (*SHAPE, nch), dtype=np.uint8)
    if kind.startswith("rgb_tif"):
        p = tmp_path / "c.tif"
        planar = kind.endswith("planar")
        tifffile.imwrite(p, np.moveaxis(rgb, -1, 0) if planar else rgb, photometric="rgb",
                         planarconfig="separate" if planar else "contig")
    else:
        p = tmp_path / "c.png"
        iio.imwrite(p, rgb)
    s = open_series(p, name="ref")
    assert s.shape == SHAPE
    assert s.channels == nch
    assert s.bit_depth == 8
    assert s.saturation_level == 255
    c = rgb.astype(float)
    want = c[..., 0] if nch == 2 else 0.2126 * c[..., 0] + 0.7152 * c[..., 1] \
        + 0.0722 * c[..., 2]
    # the weights sum to 1: an exact multiple-add, rounding ~1e-13 grey levels
    assert_allclose(s.read(0), want, rtol=0, atol=1e-9)
    assert s.read(0, dtype=None).dtype == np.float64
    assert "ref: colour frames" in s.notes[0]


def test_jpeg_and_packed_and_lzw_tiffs(tmp_path):
    rng = np.random.default_rng(8)
    img = rng.integers(0, 1024, SHAPE, dtype=np.uint16)
    tifffile.imwrite(tmp_path / "p10.tif", img, bitspersample=10, photometric="minisblack")
    s = open_series(tmp_path / "p10.tif")
    assert (s.bit_depth, s.scale, s.saturation_level) == (10, 1, 1023)
    assert_array_equal(s.read(0, dtype=None), img)
    tifffile.imwrite(tmp_path / "lzw.tif", img * 16, compression="lzw",
                     photometric="minisblack")
    s = open_series(tmp_path / "lzw.tif")
    assert_array_equal(s.read(0, dtype=None), img * 16)
    iio.imwrite(tmp_path / "a.jpg", (img // 4).astype(np.uint8))
    s = open_series(tmp_path / "a.jpg", name="state 0")
    assert s.shape == SHAPE
    assert "JPEG" in s.notes[0]


def test_read_mask(tmp_path):
    m = np.zeros(SHAPE, np.uint8)
    m[4:20, 5:25] = 255
    iio.imwrite(tmp_path / "m.png", m)
    tifffile.imwrite(tmp_path / "m.tif", (m > 0).astype(np.uint16))
    tifffile.imwrite(tmp_path / "m1.tif", m > 0)  # 1-bit
    # drawn in a paint program: white on black (RGB), or on a transparent layer
    rgb = np.zeros((*SHAPE, 3), np.uint8)
    rgb[m > 0] = (250, 30, 0)
    iio.imwrite(tmp_path / "rgb.png", rgb)
    rgba = np.zeros((*SHAPE, 4), np.uint8)
    rgba[..., :3] = 255  # white everywhere: only the alpha says where the specimen is
    rgba[m > 0, 3] = 255
    iio.imwrite(tmp_path / "rgba.png", rgba)
    for name in ("m.png", "m.tif", "m1.tif", "rgb.png", "rgba.png"):
        got = read_mask(tmp_path / name, SHAPE)
        assert got.dtype == bool
        assert_array_equal(got, m > 0)
    with pytest.raises(ValueError, match=r"m\.png has shape \(24, 32\), expected \(24, 30\)"):
        read_mask(tmp_path / "m.png", (24, 30))
    with pytest.raises(FileNotFoundError, match=r"none\.png does not exist"):
        read_mask(tmp_path / "none.png", SHAPE)
    iio.imwrite(tmp_path / "black.png", np.zeros((*SHAPE, 3), np.uint8))
    with pytest.raises(ValueError, match="selects no pixel"):
        read_mask(tmp_path / "black.png", SHAPE)
    iio.imwrite(tmp_path / "zero.png", np.zeros(SHAPE, np.uint8))
    with pytest.raises(ValueError, match="selects no pixel"):
        read_mask(tmp_path / "zero.png", SHAPE)
    with pytest.raises(ValueError, match="shape must be two positive integers"):
        read_mask(tmp_path / "m.png", 24)


def test_roi_mask():
    m = roi_mask((24, 32), rectangle=(5, 4, 25, 20))
    want = np.zeros((24, 32), bool)
    want[4:20, 5:25] = True
    assert_array_equal(m, want)
    # a right triangle (0,0) (10,0) (0,10): pixel centres with x + y <= 10 (edge
    # pixels are a convention of the rasteriser: count only the strict interior)
    tri = roi_mask((24, 32), polygon=[(0, 0), (10, 0), (0, 10)])
    yy, xx = np.mgrid[0:24, 0:32]
    assert tri[(xx + yy) < 9.5].all()
    assert not tri[(xx + yy) > 10.5].any()
    with pytest.raises(ValueError, match="inside the 32 x 24 px image"):
        roi_mask((24, 32), rectangle=(5, 4, 40, 20))
    with pytest.raises(ValueError, match="at least 3 vertices"):
        roi_mask((24, 32), polygon=[(0, 0), (10, 0)])
    with pytest.raises(ValueError, match="four integers"):
        roi_mask((24, 32), rectangle=(1.5, 0, 4, 4))


# ------------------------------------------------------------------------ atomic output


def test_atomic_path_success(tmp_path):
    dest = tmp_path / "out.txt"
    with atomic_path(dest) as tmp:
        assert tmp.parent == tmp_path
        assert tmp != dest
        tmp.write_text("done")
        assert not dest.exists()  # nothing visible before the block ends
    assert dest.read_text() == "done"
    assert sorted(tmp_path.iterdir()) == [dest]


def test_atomic_path_failure_leaves_nothing(tmp_path):
    dest = tmp_path / "out.txt"

    def fail(overwrite):
        with atomic_path(dest, overwrite=overwrite) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        fail(False)
    assert list(tmp_path.iterdir()) == []
    # the same when the block fails and an old file was to be replaced
    dest.write_text("old")
    with pytest.raises(RuntimeError, match="boom"):
        fail(True)
    assert dest.read_text() == "old"
    assert list(tmp_path.iterdir()) == [dest]


def test_atomic_path_refusals(tmp_path):
    dest = tmp_path / "out.txt"
    dest.write_text("old")
    with pytest.raises(FileExistsError, match=r"out\.txt already exists"), atomic_path(dest):
        pass
    assert dest.read_text() == "old"
    with atomic_path(dest, overwrite=True) as tmp:
        tmp.write_text("new")
    assert dest.read_text() == "new"
    missing = tmp_path / "no_such_dir" / "out.txt"
    with pytest.raises(FileNotFoundError, match=r"output directory .*no_such_dir does not "
                                                "exist"), atomic_path(missing):
        pass
    with pytest.raises(IsADirectoryError), atomic_path(tmp_path, overwrite=True):
        pass
    with pytest.raises(FileNotFoundError, match="nothing was written"), \
            atomic_path(tmp_path / "never.txt"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


# ------------------------------------------------------------------------ HDF5


def test_hdf5_round_trip(tmp_path):
    rng = np.random.default_rng(19)
    datasets = {
        "maps/u": rng.standard_normal((2, 20, 30)),
        "maps/eps_xx": rng.standard_normal((20, 30)).astype(np.float32),
        "maps/valid": rng.random((20, 30)) > 0.3,
        "psi": rng.standard_normal((4, 5)) + 1j * rng.standard_normal((4, 5)),
        "n_frames": np.array(12),
        "counts": np.arange(7, dtype=np.int32),
    }
    attrs = {"software": "gridstrain 0.1.0", "sigma": 5.0, "pitch_px": 5, "flag": True,
             "k": np.array([0.2, 0.0]), "inputs": ["a.tif", "b.tif"],
             "lattice": {"k1": [0.2, 0.0], "k2": [0.0, 0.2]}, "pixel_size": None}
    groups = {"parameters": {"sigma": 5.0, "method": "B", "window": {"kind": "gauss"}}}
    units = {"maps/u": "px", "maps/eps_xx": "1", "psi": "grey levels"}
    path = tmp_path / "r.h5"
    assert write_hdf5(path, datasets, attrs, groups=groups, units=units) == path
    back = read_hdf5(path)
    assert set(back["datasets"]) == set(datasets)
    for key, arr in datasets.items():
        assert back["datasets"][key].dtype == arr.dtype
        assert_array_equal(back["datasets"][key], arr)  # lossless compression
    assert back["units"] == units
    for key in ("software", "sigma", "pitch_px", "flag", "inputs", "lattice", "pixel_size"):
        assert back["attrs"][key] == attrs[key]
    assert type(back["attrs"]["flag"]) is bool
    assert_array_equal(back["attrs"]["k"], attrs["k"])
    assert back["groups"]["parameters"] == groups["parameters"]
    assert back["groups"]["maps"] == {}
    with h5py.File(path, "r") as h5:
        d = h5["maps/u"]
        assert d.compression == "gzip"
        assert d.chunks is not None
        assert d.fletcher32
        assert h5["n_frames"].chunks is None  # scalars cannot be chunked
        assert isinstance(h5.attrs["inputs"], str)  # JSON text, readable anywhere


def test_hdf5_lzf_and_refusals(tmp_path):
    path = tmp_path / "r.h5"
    write_hdf5(path, {"a": np.arange(100.0)}, compression="lzf")
    with h5py.File(path, "r") as h5:
        assert h5["a"].compression == "lzf"
    with pytest.raises(FileExistsError, match=r"r\.h5 already exists"):
        write_hdf5(path, {"a": np.zeros(3)})
    write_hdf5(path, {"b": np.ones(3)}, overwrite=True)
    assert set(read_hdf5(path)["datasets"]) == {"b"}
    bad = tmp_path / "bad.h5"
    with pytest.raises(ValueError, match=r"units\['c'\] names no dataset"):
        write_hdf5(bad, {"a": np.zeros(3)}, units={"c": "px"})
    with pytest.raises(TypeError, match=r"attrs\['when'\] has unsupported type object"):
        write_hdf5(bad, {"a": np.zeros(3)}, {"when": object()})
    with pytest.raises(TypeError, match=r"datasets\['s'\] must be a numeric"):
        write_hdf5(bad, {"s": np.array(["x"])})
    with pytest.raises(ValueError, match="compression must be one of"):
        write_hdf5(bad, {"a": np.zeros(3)}, compression="zstd")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_hdf5(tmp_path / "none.h5")
    (tmp_path / "text.h5").write_text("not hdf5")
    with pytest.raises(OSError, match=r"text\.h5"):
        read_hdf5(tmp_path / "text.h5")
    assert not bad.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.h5", "text.h5"]


# ------------------------------------------------------------------------ CSV


def test_csv_round_trip_exact(tmp_path):
    rng = np.random.default_rng(20)
    n = 1003
    cols = {
        "x": np.arange(n, dtype=np.int64),
        "u": rng.standard_normal(n) * 1e-3,
        "eps": rng.standard_normal(n).astype(np.float32) * np.float32(1e-5),
        "valid": rng.random(n) > 0.5,
    }
    cols["u"][[3, 17]] = np.nan
    path = tmp_path / "c.csv"
    write_csv(path, cols, chunk_rows=100)  # several chunks, with a partial last one
    lines = path.read_text().splitlines()
    assert lines[0] == "x,u,eps,valid"
    assert len(lines) == n + 1
    back = np.loadtxt(path, delimiter=",", skiprows=1)
    assert_array_equal(back[:, 0], cols["x"])
    assert_array_equal(back[:, 1], cols["u"])  # exact, NaN in place
    assert_array_equal(back[:, 2].astype(np.float32), cols["eps"])
    assert_array_equal(back[:, 3], cols["valid"])
    # fixed digits on request
    write_csv(path, {"v": np.array([1 / 3])}, overwrite=True, digits=4)
    assert path.read_text() == "v\n0.3333\n"


def test_csv_maps_and_refusals(tmp_path):
    path = tmp_path / "m.csv"
    u = np.arange(6.0).reshape(2, 3)
    write_csv(path, {"row": np.indices((2, 3))[0], "u": u})
    back = np.loadtxt(path, delimiter=",", skiprows=1)
    assert_array_equal(back[:, 1], u.ravel())  # C order: row by row
    with pytest.raises(FileExistsError, match=r"m\.csv"):
        write_csv(path, {"u": u})
    with pytest.raises(ValueError, match=r"columns\['v'\] has shape \(5,\), expected "
                                         r"\(6,\) like columns\['u'\]"):
        write_csv(tmp_path / "b.csv", {"u": np.zeros(6), "v": np.zeros(5)})
    with pytest.raises(ValueError, match="column names must be non-empty strings"):
        write_csv(tmp_path / "b.csv", {"": np.zeros(6)})
    with pytest.raises(TypeError, match="real numeric"):
        write_csv(tmp_path / "b.csv", {"z": np.zeros(3, complex)})
    assert not (tmp_path / "b.csv").exists()


def test_csv_quotes_what_needs_it_and_pandas_reads_it_back(tmp_path):
    """Names from other people's files: commas, quotes, line breaks, a leading space,
    non-ASCII text, a formula-looking cell; RFC 4180 quoting keeps each in its cell."""
    pd = pytest.importorskip("pandas")
    names = np.array(['a,b', 'say "hi"', "two\nlines", " lead", "µε 5 %", "=1+1",
                      "plain", "cr\rlf"])
    cols = {"state": names, 'load [kN, "raw"]': np.arange(8) * 0.5,
            "x\ny": np.arange(8, dtype=np.int64)}
    path = write_csv(tmp_path / "q.csv", cols)
    text = path.read_bytes().decode("utf-8")
    assert text.startswith('state,"load [kN, ""raw""]","x\ny"\r\n')
    assert "\r\nplain,3.0,6\r\n" in text  # unquoted where nothing needs it
    assert '"cr\rlf"' in text
    df = pd.read_csv(path, keep_default_na=False)
    assert list(df.columns) == list(cols)
    assert list(df["state"]) == list(names)
    assert_array_equal(df['load [kN, "raw"]'], cols['load [kN, "raw"]'])
    assert_array_equal(df["x\ny"], cols["x\ny"])


# ------------------------------------------------------------------------ TIFF series


def test_write_tiff_series_round_trip(tmp_path):
    rng = np.random.default_rng(21)
    frames = [rng.random(SHAPE) * 4000 for _ in range(3)]
    # rounded, then x16 as a PCO camera stores them: read back as 12-bit data
    folder = tmp_path / "lab"
    paths = write_tiff_series(folder, (np.rint(f) * 16 for f in frames), prefix="img")
    assert [p.name for p in paths] == ["img000000.tif", "img000001.tif", "img000002.tif"]
    s = open_series(folder)
    assert s.paths == paths
    assert (s.dtype, s.bit_depth, s.scale) == (np.dtype(np.uint16), 12, 16)
    for got, f in zip(s.frames(to_sensor_units=True), frames, strict=True):
        assert_array_equal(got, np.rint(f))
    # unrounded floats stored as uint16: the error is at most half a grey level
    rounded = write_tiff_series(tmp_path / "r", frames)
    for got, f in zip(open_series(rounded).frames(), frames, strict=True):
        assert np.max(np.abs(got - f)) <= 0.5
    listed = write_tiff_series(tmp_path / "b", frames, dtype=np.float32, start=9)
    assert [p.name for p in listed] == ["frame0009.tif", "frame0010.tif", "frame0011.tif"]
    assert_array_equal(open_series(listed[0]).read(0, dtype=None), frames[0].astype(np.float32))


def test_write_tiff_series_refusals(tmp_path):
    with pytest.raises(ValueError, match=r"frames\[1\] has values in .* outside the uint16 "
                                         "range"):
        write_tiff_series(tmp_path / "a", [np.zeros(SHAPE), np.full(SHAPE, 70000.0)])
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["frame0000.tif"]
    with pytest.raises(FileExistsError, match=r"frame0000\.tif already exists"):
        write_tiff_series(tmp_path / "a", [np.zeros(SHAPE)])
    write_tiff_series(tmp_path / "a", [np.ones(SHAPE)], overwrite=True)
    assert open_series(tmp_path / "a").read(0).max() == 1.0
    with pytest.raises(FileNotFoundError, match=r"parent .* does not exist"):
        write_tiff_series(tmp_path / "x" / "y", [np.zeros(SHAPE)])
    with pytest.raises(ValueError, match="dtype must be one of"):
        write_tiff_series(tmp_path / "c", [np.zeros(SHAPE)], dtype=np.int8)
    with pytest.raises(ValueError, match=r"frames\[0\] has NaN"):
        write_tiff_series(tmp_path / "c", [np.full(SHAPE, np.nan)])
