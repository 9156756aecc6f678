"""High-speed camera records: Phantom cine and Photron MRAW, read against files written
by ``tests/camera_files.py`` (numpy only, from the published layouts), frames made by
``tests/sequence_record.py`` (``tests/independent_grid.py``).

Frames must come back bit for bit; the header's significant bits, frame rate, trigger
and time stamps must land on the series and on the measured states; a record measured
with ``each_frame`` must give the maps of the same frames stored as a multi-page TIFF;
and a header that does not fit its file must be refused, naming the file and the field.
"""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from camera_files import SETUP_LENGTH, pack12, write_cine, write_mraw
from findings import said
from gridstrain.io import MemoryBudgetError, memory_budget, open_series
from gridstrain.series import measure_series
from sequence_record import record

SHAPE = (64, 96)
N = 5
RATE = 1000
FIRST = -2  # two frames before the trigger's
# TIME64 counts 2**-32 s: a time written from a float is exact to half of that
TIME64_RESOLUTION = 2.0**-32


@pytest.fixture(scope="module")
def frames():
    """(N, H, W) 12-bit frames, right-aligned (the record is stored x16)."""
    return record(N, SHAPE, strain=1e-3) // 16


def _times():
    """The time stamps written: one frame 3 us late, so that stamps, not the frame
    rate, must be what the reader returns."""
    t = (np.arange(N) + FIRST) / RATE
    t[3] += 3e-6
    return t


# --------------------------------------------------------------------------- cine


@pytest.mark.parametrize("kind", ["16-bit", "packed 12-bit", "8-bit"])
def test_cine_frames_bits_rate_and_time_stamps(tmp_path, frames, kind):
    data = (frames >> 4).astype(np.uint8) if kind == "8-bit" else frames
    bits = 8 if kind == "8-bit" else 12
    path = write_cine(tmp_path / "rec.cine", data, real_bpp=bits,
                      bit_count=8 if kind == "8-bit" else 16, packed=kind.startswith("p"),
                      frame_rate=RATE, first_number=FIRST, times=_times())
    s = open_series(path)
    assert (s.n_frames, s.shape, s.dtype) == (N, SHAPE, data.dtype)
    assert (s.bit_depth, s.scale, s.saturation_level) == (bits, 1, 2**bits - 1)
    for k in (3, 0, 4):  # in any order
        np.testing.assert_array_equal(s.read(k, dtype=None), data[k])
    assert s.frame_rate == RATE
    np.testing.assert_allclose(s.times, _times(), rtol=0, atol=TIME64_RESOLUTION)
    assert s.trigger_frame == -FIRST
    assert s.times[-FIRST] == 0.0
    assert s.subset([3, 2]).trigger_frame == 1


def test_cine_without_time_block_is_timed_by_its_frame_rate(tmp_path, frames):
    path = write_cine(tmp_path / "rec.cine", frames, real_bpp=12, frame_rate=RATE,
                      first_number=FIRST, times=None)
    s = open_series(path)
    np.testing.assert_array_equal(s.times, (np.arange(N) + FIRST) / RATE)


def test_cine_rows_are_stored_bottom_up(tmp_path):
    """The first stored row of a plain cine image is the image's last."""
    img = np.arange(4 * 6, dtype=np.uint16).reshape(1, 4, 6)
    path = write_cine(tmp_path / "r.cine", img, real_bpp=16, times=None)
    with open(path, "rb") as fh:
        fh.seek(44 + 40 + SETUP_LENGTH + 8 + 4 * 1 + 8 * 1 + 8 + 24)
        first_row = np.frombuffer(fh.read(12), "<u2")
    np.testing.assert_array_equal(first_row, img[0, -1])
    np.testing.assert_array_equal(open_series(path).read(0, dtype=None), img[0])


# --------------------------------------------------------------------------- MRAW


@pytest.mark.parametrize("header", ["cih", "cihx"])
@pytest.mark.parametrize("bit", [8, 12, 16])
def test_mraw_frames_bits_rate_and_times(tmp_path, frames, bit, header):
    data = (frames >> 4).astype(np.uint8) if bit == 8 else frames
    eff = 8 if bit == 8 else 12
    path = write_mraw(tmp_path / "rec.mraw", data, color_bit=bit, effective_bit=eff,
                      frame_rate=20000, start_frame=-1, header=header)
    s = open_series(path)
    assert (s.n_frames, s.shape, s.bit_depth, s.saturation_level) == (N, SHAPE, eff,
                                                                       2**eff - 1)
    for k in (4, 1, 2):
        np.testing.assert_array_equal(s.read(k, dtype=None), data[k])
    assert s.frame_rate == 20000
    assert s.trigger_frame == 1
    np.testing.assert_array_equal(s.times, (np.arange(N) - 1) / 20000)


def test_mraw_12_bit_packing_is_photrons(tmp_path):
    """Bytes ``AB CD EF`` hold the pixels 0xABC and 0xDEF (most significant bits
    first), written here byte by byte, not by the test writer."""
    write_mraw(tmp_path / "p.mraw", np.zeros((1, 2, 2), np.uint16), color_bit=12)
    (tmp_path / "p.mraw").write_bytes(bytes([0xAB, 0xCD, 0xEF, 0x01, 0x23, 0x45]))
    np.testing.assert_array_equal(open_series(tmp_path / "p.mraw").read(0, dtype=None),
                                  [[0xABC, 0xDEF], [0x012, 0x345]])
    assert pack12(np.array([0xABC, 0xDEF])) == bytes([0xAB, 0xCD, 0xEF])


def test_mraw_left_aligned_12_bits_are_found_as_scale_16(tmp_path, frames):
    path = write_mraw(tmp_path / "rec.mraw", frames * 16, color_bit=16, effective_bit=12,
                      side="Higher")
    s = open_series(path)
    assert (s.bit_depth, s.scale, s.saturation_level) == (12, 16, 4095 * 16)


# --------------------------------------------------------------------------- measured


def test_each_frame_measures_a_record_like_its_tiff(tmp_path, frames):
    """The same frames as a cine, an MRAW and a multi-page TIFF: the same maps; the
    camera's times are the states' times."""
    tifffile.imwrite(tmp_path / "rec.tif", frames, photometric="minisblack")
    tiff = measure_series(None, tmp_path / "rec.tif", reference_frames=1)
    cine = measure_series(None, write_cine(tmp_path / "rec.cine", frames, real_bpp=12,
                                           frame_rate=RATE, first_number=FIRST,
                                           times=_times()), reference_frames=1)
    mraw = measure_series(None, write_mraw(tmp_path / "rec.mraw", frames, color_bit=12,
                                           frame_rate=RATE, start_frame=FIRST),
                          reference_frames=1)
    for res in (cine, mraw):
        assert res.names[1:] == tuple(f"rec[{k}]" for k in range(1, N))
        for field in ("u", "strain"):
            np.testing.assert_array_equal(np.asarray(getattr(res, field)),
                                          np.asarray(getattr(tiff, field)))
    assert tiff.time is None
    np.testing.assert_allclose(cine.time, _times()[1:], rtol=0, atol=TIME64_RESOLUTION)
    np.testing.assert_array_equal(mraw.time, (np.arange(1, N) + FIRST) / RATE)


def test_cli_measures_a_cine_frame_by_frame(tmp_path, frames):
    import json

    path = write_cine(tmp_path / "rec.cine", frames, real_bpp=12, frame_rate=RATE,
                      first_number=FIRST, times=_times())
    p = subprocess.run([sys.executable, "-m", "gridstrain.cli", "measure", str(path),
                        "--reference-frames", "1", "-o", str(tmp_path / "a.h5"), "--json"],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout)
    np.testing.assert_allclose([st["time_s"] for st in s["states"]], _times()[1:],
                               rtol=0, atol=TIME64_RESOLUTION)


# --------------------------------------------------------------------------- refused


def _patch(path, offset, fmt, value):
    with open(path, "r+b") as fh:
        fh.seek(offset)
        fh.write(struct.pack(fmt, value))


def _cine(tmp_path, frames):
    return write_cine(tmp_path / "rec.cine", frames[:2], real_bpp=12, times=[0.0, 1e-3])


def test_truncated_cine_is_refused_naming_the_file(tmp_path, frames):
    path = _cine(tmp_path, frames)
    data = path.read_bytes()
    path.write_bytes(data[:-100])
    with pytest.raises(OSError, match=r"rec\.cine: .*header says 2 frame.*96x64 16-bit.*"
                                      r"file ends at byte"):
        open_series(path).read(1)
    path.write_bytes(data[:30])
    with pytest.raises(OSError, match=r"rec\.cine is not a Phantom cine"):
        open_series(path)


@pytest.mark.parametrize(("offset", "fmt", "value", "message"), [
    (20, "<I", 10**8, r"says 100000000 image offsets from byte \d+ \(OffImageOffsets\)"),
    (2, "<H", 40, r"Headersize is 40"),
    (84 + 140, "<2s", b"XX", r"SETUP at byte 84 has Mark b'XX'"),
    (44 + 4, "<i", 70000, r"biWidth is 70000"),
    (44 + 14, "<H", 12, r"biBitCount=12 and biCompression=0"),
    (84 + 896, "<I", 14, r"RealBPP is 14; expected 1 to 12"),
])
def test_corrupt_cine_headers_are_refused_by_field(tmp_path, frames, offset, fmt, value,
                                                   message):
    path = write_cine(tmp_path / "rec.cine", frames[:2], real_bpp=12, times=[0.0, 1e-3],
                      packed="RealBPP" in message)
    _patch(path, offset, fmt, value)
    with pytest.raises(OSError, match=r"rec\.cine: .*" + message):
        open_series(path)


def test_cine_image_pointer_past_the_end_is_refused(tmp_path, frames):
    path = _cine(tmp_path, frames)
    (table,) = struct.unpack_from("<I", path.read_bytes(), 32)
    _patch(path, table + 8, "<q", path.stat().st_size - 10)
    with pytest.raises(OSError, match=r"rec\.cine: image 1 is said to start at byte"):
        open_series(path).read(1)


def test_cine_time_block_of_the_wrong_size_is_refused(tmp_path, frames):
    path = _cine(tmp_path, frames)
    time_block = 84 + SETUP_LENGTH + 8 + 4 * 2
    _patch(path, time_block, "<I", 8 + 8 * 1)
    with pytest.raises(OSError, match=r"rec\.cine: the time block .* expected 8 per image"):
        open_series(path)


@pytest.mark.parametrize(("kw", "message"), [
    ({"cfa": 3}, r"colour cine \(CFA=3"),
    ({"compression": 2}, r"rec\.cine is an uninterpolated colour \(raw Bayer\) cine;"),
])
def test_colour_cines_are_refused(tmp_path, frames, kw, message):
    path = write_cine(tmp_path / "rec.cine", frames[:2], real_bpp=12, **kw)
    with pytest.raises(ValueError, match=message):
        open_series(path)


def test_packed_10_bit_cine_is_refused_by_name(tmp_path, frames):
    path = _cine(tmp_path, frames)
    _patch(path, 44 + 16, "<I", 256)
    with pytest.raises(ValueError, match=r"packed 10-bit \(P10\)"):
        open_series(path)


def test_mraw_header_that_does_not_fit_is_refused(tmp_path, frames):
    path = write_mraw(tmp_path / "rec.mraw", frames, color_bit=16)
    path.write_bytes(path.read_bytes()[:-2])
    with pytest.raises(OSError, match=r"rec\.mraw: header says 5 frame\(s\) of 96x64 "
                                      r"16-bit pixels from byte 0.*file ends at byte"):
        open_series(path)
    cih = tmp_path / "rec.cih"
    cih.write_text(cih.read_text().replace("Image Width : 96", "Image Width : 9x6"))
    with pytest.raises(OSError, match=r"rec\.cih: the header's 'Image Width' must be an "
                                      r"integer, got '9x6'"):
        open_series(path)
    cih.unlink()
    with pytest.raises(FileNotFoundError, match=r"rec\.cihx or rec\.cih must lie beside"):
        open_series(path)


def test_mraw_cihx_with_entities_and_colour_are_refused(tmp_path, frames):
    path = write_mraw(tmp_path / "rec.mraw", frames[:1], color_bit=16, header="cihx")
    cihx = tmp_path / "rec.cihx"
    text = cihx.read_bytes()
    cihx.write_bytes(text.replace(b"<cih>", b"<cih><!DOCTYPE x [<!ENTITY a 'b'>]>"))
    with pytest.raises(OSError, match=r"rec\.cihx declares XML entities"):
        open_series(path)
    cihx.write_bytes(text.replace(b"<type>Mono</type>", b"<type>Color</type>"))
    with pytest.raises(ValueError, match=r"rec\.mraw holds a colour \(Color\) record; "
                                         r"gridstrain reads grey records \(rec\.cihx"):
        open_series(path)


@pytest.mark.parametrize("header", ["cih", "cihx"])
def test_mraw_raw_data_is_grey_from_a_monochrome_model_only(tmp_path, frames, header):
    """A monochrome FASTCAM's header may call its frames ``Raw`` (the sensor's data as
    read out): grey levels. A colour model's raw data is a Bayer mosaic, and a model
    that does not say which it is cannot be taken for grey."""
    path = write_mraw(tmp_path / "rec.mraw", frames, color_bit=12, header=header,
                      color_type="Raw", camera="FASTCAM Nova S16 type 1100K-M-64GB")
    np.testing.assert_array_equal(open_series(path).read(3, dtype=None), frames[3])
    for camera in ("FASTCAM Mini AX200 type 900K-C-32GB", "FASTCAM test"):
        path = write_mraw(tmp_path / f"{len(camera)}.mraw", frames, color_bit=12,
                          header=header, color_type="Raw", camera=camera)
        with pytest.raises(ValueError, match=r"holds raw sensor data from a camera whose "
                                             r"model \(FASTCAM .*\) is not a monochrome "
                                             r"one .* Bayer mosaic"):
            open_series(path)


@pytest.mark.parametrize("header", ["cih", "cihx"])
def test_mraw_saved_every_nth_frame_has_the_times_of_those_frames(tmp_path, frames, header):
    """A record saved every 36th frame (PFV's save step): frame k is recorded frame
    start + 36 k, its time that over the record rate, and the saved frames' rate the
    record rate over 36."""
    path = write_mraw(tmp_path / "rec.mraw", frames, color_bit=16, frame_rate=60000,
                      start_frame=49300, save_step=36, header=header)
    s = open_series(path)
    np.testing.assert_allclose(s.times, (49300 + 36 * np.arange(N)) / 60000, rtol=1e-15)
    assert s.frame_rate == pytest.approx(60000 / 36, rel=1e-15)


_PHOTRON = Path(__file__).parent / "data" / "photron"


@pytest.mark.parametrize(("header", "shape", "n", "stored", "times"), [
    # saved every 36th frame at 60000 fps, from frame 49300
    ("sample_60k_16bit.cih", (368, 896), 12, 16, (49300 + 36 * np.arange(12)) / 60000),
    # a save step of 2500 beyond its 400 recorded frames: no time rather than a wrong one
    ("beam.cihx", (80, 1024), 4, 16, None),
    # a monochrome Nova S16's "Raw" colour type, packed 12-bit pixels, from frame 52
    ("ball_12bit.cihx", (384, 384), 15, 12, (52 + np.arange(15)) / 30000),
])
def test_headers_of_real_fastcam_records(tmp_path, header, shape, n, stored, times):
    """The headers of three records that FASTCAM cameras saved (tests/data/photron),
    with pixels of the sizes they declare: every header is read as its camera wrote it
    (binary preamble, keys, 12 significant bits), the frames come back bit for bit."""
    (tmp_path / header).write_bytes((_PHOTRON / header).read_bytes())
    frames = np.random.default_rng(0).integers(0, 4096, size=(n, *shape), dtype=np.uint16)
    path = (tmp_path / header).with_suffix(".mraw")
    path.write_bytes(b"".join(pack12(f) if stored == 12 else f.astype("<u2").tobytes()
                              for f in frames))
    s = open_series(path)
    assert (s.n_frames, s.shape, s.bit_depth) == (n, shape, 12)
    for k in (0, n - 1):
        np.testing.assert_array_equal(s.read(k, dtype=None), frames[k])
    if times is None:
        assert s.times is None
        assert s.frame_rate is None
        assert any("read without times" in n for n in said(s.notes, "input"))
    else:
        np.testing.assert_allclose(s.times, times, rtol=1e-15)
        assert not s.notes


def test_mraw_save_step_beyond_the_frames_recorded_gives_no_times(tmp_path, frames):
    """A header whose save step spans more frames than it says were recorded
    contradicts itself: the frames are read, but they get no time rather than a
    wrong one (``--frame-rate`` or a loads file's time column gives them)."""
    path = write_mraw(tmp_path / "rec.mraw", frames, color_bit=16, save_step=2500,
                      recorded=400, header="cihx")
    s = open_series(path, name="state")
    np.testing.assert_array_equal(s.read(2, dtype=None), frames[2])
    assert s.times is None
    assert s.frame_rate is None
    # and the user is told why, naming the series and the header
    (note,) = [n for n in said(s.notes, "input") if "without times" in n]
    assert note.startswith("state: rec.cihx gives a save step of 2500 over 400 recorded "
                           "frames")


def test_a_frame_above_the_memory_budget_is_refused_before_reading(tmp_path):
    path = write_mraw(tmp_path / "big.mraw", np.zeros((1, 256, 256), np.uint16),
                      color_bit=16)
    with memory_budget("100K"), pytest.raises(MemoryBudgetError, match=r"big\.mraw"):
        open_series(path)


def test_cli_refuses_a_truncated_record_in_one_line(tmp_path, frames):
    path = _cine(tmp_path, frames)
    path.write_bytes(path.read_bytes()[:-100])
    p = subprocess.run([sys.executable, "-m", "gridstrain.cli", "measure", str(path),
                        "--reference-frames", "1", "-o", str(tmp_path / "a.h5")],
                       capture_output=True, text=True)
    assert p.returncode != 0
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "rec.cine" in lines[0]
    assert "Traceback" not in p.stderr
    assert not (tmp_path / "a.h5").exists()


def test_record_frames_are_read_one_at_a_time(tmp_path, frames):
    """A damaged last image stops the read only when the loop reaches it: the frames
    before it were read one by one, not the whole record at once."""
    path = write_cine(tmp_path / "rec.cine", frames, real_bpp=12, times=None)
    (table,) = struct.unpack_from("<I", path.read_bytes(), 32)
    _patch(path, table + 8 * (N - 1), "<q", -1)
    it = open_series(path).frames(dtype=None)
    for k in range(N - 1):
        np.testing.assert_array_equal(next(it), frames[k])
    with pytest.raises(OSError, match=rf"rec\.cine: image {N - 1} is said to start at byte -1"):
        next(it)


def test_a_folder_reads_the_mraw_not_its_header(tmp_path, frames):
    write_mraw(tmp_path / "rec.mraw", frames, color_bit=12, header="cihx")
    s = open_series(tmp_path)
    assert s.paths == (tmp_path / "rec.mraw",)
    assert s.n_frames == N
