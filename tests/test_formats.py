"""The registry of image formats: a format is one module and one registration.

A toy format, written and read here with numpy alone, is registered by the test and
must then be read by :func:`gridstrain.io.open_series` like the built-in ones, with no
other change to gridstrain.
"""

from __future__ import annotations

import struct
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest
from numpy.testing import assert_array_equal

from gridstrain.io import (
    ImageFormat,
    open_series,
    read_mask,
    register_format,
    split_frames,
    unregister_format,
)
from gridstrain.io._formats import FileInfo

_MAGIC = b"TOY1"
_HEAD = struct.Struct("<4sHHHd")  # magic, H, W, frames, frames per second


def _write_toy(path, frames, fps=250.0):
    frames = np.asarray(frames, dtype="<u2")
    T, H, W = frames.shape
    path.write_bytes(_HEAD.pack(_MAGIC, H, W, T, fps) + frames.tobytes())


def _header(path, name):
    magic, H, W, T, fps = _HEAD.unpack(path.read_bytes()[:_HEAD.size])
    if magic != _MAGIC:
        raise OSError(f"{name}: {path} is not a toy record")
    return H, W, T, fps


def _scan(path, name, allow_bool=False):
    H, W, T, fps = _header(path, name)
    return FileInfo(path, ((H, W),) * T, (np.dtype(np.uint16),) * T, (1,) * T,
                    times=tuple(k / fps for k in range(T)))


def _read(path, pages, wheres, name):
    H, W, T, _ = _header(path, name)
    data = np.fromfile(path, dtype="<u2", offset=_HEAD.size).reshape(T, H, W)
    for k in pages:
        yield data[k].astype(np.uint16)


def _timing(path, name):
    _, _, _, fps = _header(path, name)
    return SimpleNamespace(frame_rate=fps, trigger_frame=0)


@pytest.fixture
def toy():
    fmt = register_format(ImageFormat("toy record", (".toy",), _scan, _read, kind="camera",
                                      magic=(_MAGIC,), stack=True, timing=_timing))
    yield fmt
    unregister_format("toy record")


def _frames(n, shape=(20, 28), seed=0):
    # full 16-bit range: no 12-bit x16 detection, the values read as stored
    return np.random.default_rng(seed).integers(0, 65536, (n, *shape)).astype(np.uint16)


def test_a_registered_format_is_read_by_open_series(toy, tmp_path):
    frames = _frames(5)
    _write_toy(tmp_path / "rec.toy", frames, fps=250.0)
    s = open_series(tmp_path / "rec.toy", name="toy")
    assert (s.n_frames, s.shape, s.dtype) == (5, (20, 28), np.uint16)
    # every frame as stored, in order, read one at a time through the toy reader
    for k, frame in enumerate(s.frames(dtype=None)):
        assert_array_equal(frame, frames[k])
    assert_array_equal(s.read(3, dtype=None), frames[3])
    # the header's timing, through the format's timing capability
    assert s.frame_rate == 250.0
    assert s.trigger_frame == 0
    assert_array_equal(s.times, np.arange(5) / 250.0)
    # a frame split off its record keeps its format
    one = split_frames(s)[2]
    assert_array_equal(one.read(0, dtype=None), frames[2])


def test_a_registered_format_joins_folders_and_messages(toy, tmp_path):
    for k in range(3):
        _write_toy(tmp_path / f"part{k + 1}.toy", _frames(2, seed=k))
    (tmp_path / "notes.txt").write_text("not an image")
    s = open_series(tmp_path, name="toy")
    assert s.n_frames == 6
    assert_array_equal(s.read(4, dtype=None), _frames(2, seed=2)[0])
    # the suffixes listed for an unreadable file include the new one, under its kind
    (tmp_path / "frame.gif").write_bytes(b"GIF89a")
    with pytest.raises(ValueError, match=r"camera records .*\.toy"):
        open_series(tmp_path / "frame.gif")


def test_unregistered_formats_are_no_longer_read(tmp_path):
    path = tmp_path / "rec.toy"
    _write_toy(path, _frames(2))
    register_format(ImageFormat("toy record", (".toy",), _scan, _read))
    unregister_format("toy record")
    with pytest.raises(ValueError, match=r"has extension '\.toy'"):
        open_series(path)


def test_registration_refuses_clashes_and_bad_declarations():
    with pytest.raises(ValueError, match=r"suffix '\.tif' of 'my tiff' is read as 'TIFF'"):
        register_format(ImageFormat("my tiff", (".TIF",), _scan, _read))
    with pytest.raises(ValueError, match="'TIFF' is already registered"):
        register_format(ImageFormat("TIFF", (".tif2",), _scan, _read))
    with pytest.raises(ValueError, match="suffixes must be"):
        ImageFormat("toy", ("toy",), _scan, _read)
    with pytest.raises(ValueError, match="kind must be one of"):
        ImageFormat("toy", (".toy",), _scan, _read, kind="film")
    with pytest.raises(TypeError, match="read must be callable"):
        ImageFormat("toy", (".toy",), _scan, None)
    with pytest.raises(TypeError, match="fmt must be"):
        register_format("toy")
    with pytest.raises(ValueError, match="no format named 'film'"):
        unregister_format("film")


def test_a_misnamed_file_is_named_by_its_leading_bytes(tmp_path):
    # a PNG saved as .tif: the TIFF reader refuses it, and the message says what it is
    img = np.arange(12 * 16, dtype=np.uint8).reshape(12, 16)
    path = tmp_path / "frame.tif"
    iio.imwrite(path, img, extension=".png")
    with pytest.raises(OSError, match=r"cannot read .*frame\.tif as a TIFF file.*first bytes "
                                      r"are those of a PNG file"):
        open_series(path)


def test_a_mask_is_read_through_its_format(toy, tmp_path):
    m = np.zeros((1, 20, 28), dtype=np.uint16)
    m[0, 4:12, 5:20] = 1
    _write_toy(tmp_path / "mask.toy", m)
    assert_array_equal(read_mask(tmp_path / "mask.toy", (20, 28)), m[0] > 0)
