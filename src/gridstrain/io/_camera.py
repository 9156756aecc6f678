"""The records of high-speed cameras: Phantom cine files and Photron MRAW files.

Both are read from their published layouts with plain file reads, one frame at a time
(never the whole record), and every number of their headers is checked against the
file before a frame is read: a header is data from outside, and a wrong size or offset
must be refused by name, never turned into frames.

Phantom cine (``.cine``, Vision Research), little-endian throughout
    CINEFILEHEADER (44 bytes at 0): ``Type`` "CI", ``Headersize`` 44, ``Compression``
    (0: grey or interpolated colour; 1 JPEG and 2 raw Bayer are refused), ``Version``
    1 (64-bit image offsets), ``FirstImageNo`` (number of the first stored image, the
    trigger's image being 0), ``ImageCount``, the offsets of the BITMAPINFOHEADER, of
    the SETUP and of the image offset table, and ``TriggerTime`` (TIME64).
    BITMAPINFOHEADER (40 bytes): ``biWidth``, ``biHeight`` (positive: rows stored
    bottom-up, as in a Windows bitmap), ``biBitCount`` (8 or 16 for a grey sensor),
    ``biCompression`` (0 plain; 1024 packed 12-bit, "P12L", two pixels in three
    bytes, rows top-down; 256 packed 10-bit "P10" is log-encoded through a camera
    table and refused). SETUP (``Mark`` "ST" at byte 140, ``Length`` at 142):
    ``FrameRate`` (uint32, fps) at 768, ``CFA`` at 808 (0: grey sensor; a colour
    filter array is refused), ``RealBPP`` (significant bits) at 896. Tagged blocks
    follow the SETUP up to the offset table (``BlockSize`` uint32, ``Type`` uint16,
    reserved uint16, data); the block of type 1002 ("time only") holds one TIME64 per
    stored image. The offset table holds one int64 per image, the offset of its
    annotation (``AnnotationSize`` uint32 counting itself, the annotation, and
    ``ImageSize`` uint32 as its last 4 bytes); the pixels follow it.

    TIME64 is a uint32 fraction of a second (in 2**-32 s) followed by uint32 seconds
    since 1970: a frame's time is its stamp less ``TriggerTime``, exact to 2**-32 s.
    Without a time block, frame ``k`` is at ``(FirstImageNo + k) / FrameRate``.

Photron MRAW (``.mraw``, with ``.cihx`` or ``.cih`` of the same name beside it)
    The ``.cih`` header is text, one ``Key : Value`` per line; the ``.cihx`` header
    holds an XML document ``<cih>...</cih>`` (after a binary preamble). Read from it:
    width, height, frame count, start frame (the number of the first frame, the
    trigger's being 0), record rate (fps), the save step (``Save Step`` in a ``.cih``,
    ``frameInfo/skipFrame`` in a ``.cihx``: every n-th recorded frame saved), the
    frames recorded (``Original Total Frame``, ``frameInfo/recordedFrame``), colour
    type, colour bit (8, 12 or 16 bits per stored pixel), effective bit depth and side,
    and the camera's model (``Camera Type``, ``deviceInfo/deviceName``). The colour
    type is ``Mono``, or ``Raw`` (the sensor's data as read out), which is grey only
    from a monochrome model (Photron's model code ``-M``, e.g. ``FASTCAM Nova S16
    type 1100K-M-64GB``): from a colour model, or one that does not say, it is a
    Bayer mosaic and is refused. The ``.mraw`` file is the frames one after the
    other, rows top-down, no header: 8-bit bytes, 16-bit little-endian words, or
    12-bit packed two pixels in three bytes with the most significant bits first
    (``AB CD EF`` holds ``0xABC`` and ``0xDEF``). Frame ``k`` is recorded frame
    ``start frame + k * save step``, at that number over the record rate; a save step
    that the frames recorded cannot hold (``(count - 1) * step`` beyond them) leaves
    the record without times rather than with wrong ones, and a reading note says so.

Times are checked before they are kept: a record rate outside 1e-3 to 1e10 fps (nan,
infinite, zero, negative, or a corrupt value such as 5e-324) or a time more than a day
from the trigger (a TriggerTime of 0 or of garbage puts the frames 1.7e9 or -4.3e9 s
away) is not a record's timing; the frames are then read without the header's times
(or, for a cine with a plausible FrameRate, timed by it instead of by its stamps), and a
reading note names the header field. No time is better than a wrong one.

Times are seconds from the trigger (negative before it), frames in the stored grey
levels (12-bit packed pixels unpacked into uint16, values unchanged), and the
significant bits (``RealBPP``, effective bit depth) given to the series as its bit
depth, which :func:`gridstrain.io.open_series` checks against the frames.
"""

from __future__ import annotations

import os
import re
import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._runtime import memory as _memory
from ._formats import FileInfo, ImageFormat, register_format

# Largest image side accepted from a header: larger sensors do not exist, and the
# bound keeps every product of header numbers far from overflow.
_MAX_SIDE = 1 << 16
# A .cih/.cihx header is a few kilobytes; anything much larger is not one.
_MAX_HEADER_BYTES = 1 << 20
# Tagged blocks after a cine's SETUP: a real file holds a handful.
_MAX_BLOCKS = 4096

_CINE_HEADER = struct.Struct("<2sHHHiIiIIII")  # 36 bytes, TriggerTime follows
_BITMAP = struct.Struct("<IiiHHIIiiII")  # 40 bytes
_SETUP_FIELDS = {"Mark": (140, "<2s"), "Length": (142, "<H"), "FrameRate": (768, "<I"),
                 "CFA": (808, "<I"), "RealBPP": (896, "<I")}
_SETUP_NEED = 900  # bytes of SETUP holding every field read
_TIME_ONLY_BLOCK = 1002
_P10, _P12L = 256, 1024
# A record's rate, fps: from one frame in about 17 minutes (time lapse) to beyond the
# fastest cameras (some 1e7 fps); outside, the header's number is not a rate.
_RATE_RANGE = (1e-3, 1e10)
# A frame's time from the trigger, s: high-speed records last seconds to minutes; a
# day away, the trigger time or the numbering of the header is not the record's.
_MAX_TIME_S = 86400.0


@dataclass(frozen=True)
class _Layout:
    """Where the frames of a camera record lie, and what its header says about them."""

    path: Path  # the file of the pixels
    size: int  # its size when read, bytes
    shape: tuple[int, int]  # (H, W), px
    n_frames: int
    stored: int  # bits per stored pixel: 8, 12 (packed) or 16
    bits: int  # significant bits
    bottom_up: bool  # rows stored from the bottom of the image
    frame_rate: float | None  # fps
    first_number: int  # number of the first frame, the trigger's being 0
    times: tuple[float, ...]  # s from the trigger, one per frame
    table: int | None = None  # a cine's image offset table; None: frames back to back
    note: str = ""  # why the header's times were not used (without the series' name)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.uint8 if self.stored == 8 else np.uint16)

    @property
    def frame_bytes(self) -> int:
        H, W = self.shape
        return H * W * self.stored // 8

    @property
    def trigger_frame(self) -> int | None:
        """Index of the trigger's frame in the record, if it was stored."""
        k = -self.first_number
        return k if 0 <= k < self.n_frames else None


# --------------------------------------------------------------------------- reading


def _read_exact(fh, offset: int, n: int, path: Path, what: str, name: str,
                into: np.ndarray | None = None) -> bytes | np.ndarray:
    """``n`` bytes at ``offset`` (into the array ``into`` of ``n`` bytes, if given)."""
    fh.seek(offset)
    if into is None:
        data = fh.read(n)
        got = len(data)
    else:
        data = into
        got = fh.readinto(memoryview(into).cast("B"))
    if got != n:
        raise OSError(f"{name}: {path}: {what} at byte {offset} needs {n} bytes but the "
                      f"file ends at byte {offset + got} (truncated file?)")
    return data


def _unpack12(raw: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Pixels of 12 bits packed two in three bytes, most significant bits first.

    The bytes ``AB CD EF`` hold ``0xABC`` and ``0xDEF``: the big-endian words read at
    bytes 0 and 1 of each triple, ``0xABCD >> 4`` and ``0xCDEF & 0xFFF``.
    """
    m = raw.size // 3
    first = np.ndarray((m,), dtype=">u2", buffer=raw, offset=0, strides=(3,))
    second = np.ndarray((m,), dtype=">u2", buffer=raw, offset=1, strides=(3,))
    out = np.empty((m, 2), dtype=np.uint16)
    np.right_shift(first, 4, out=out[:, 0])
    np.bitwise_and(second, 0x0FFF, out=out[:, 1])
    return out.reshape(shape)


def _read_frame(fh, at: int, layout: _Layout, k: int, name: str) -> np.ndarray:
    """Frame ``k``, whose bytes start at ``at``, as an (H, W) array the right way up."""
    H, W = layout.shape
    wide = layout.stored == 16
    stored = np.empty(layout.frame_bytes // 2 if wide else layout.frame_bytes,
                      dtype="<u2" if wide else "u1")
    _read_exact(fh, at, layout.frame_bytes, layout.path, f"frame {k}", name, into=stored)
    img = _unpack12(stored, (H, W)) if layout.stored == 12 else stored.reshape(H, W)
    img = img.astype(layout.dtype, copy=False)  # native byte order
    return img[::-1].copy() if layout.bottom_up else img


def _frame_offset(fh, layout: _Layout, k: int, name: str) -> int:
    """Byte where the pixels of frame ``k`` start, checked against the file."""
    path, n = layout.path, layout.frame_bytes
    if layout.table is None:
        return k * n
    (ptr,) = struct.unpack("<q", _read_exact(fh, layout.table + 8 * k, 8, path,
                                             f"the offset of image {k}", name))
    ann = None
    if 0 <= ptr <= layout.size - 4:
        (ann,) = struct.unpack("<I", _read_exact(fh, ptr, 4, path,
                                                 f"the AnnotationSize of image {k}", name))
    if ann is None or ann < 8 or ptr + ann + n > layout.size:
        raise OSError(f"{name}: {path}: image {k} is said to start at byte {ptr} (with an "
                      f"AnnotationSize of {ann}) and to hold {n} bytes, but the file ends at "
                      f"byte {layout.size}")
    (size,) = struct.unpack("<I", _read_exact(fh, ptr + ann - 4, 4, path,
                                              f"the ImageSize of image {k}", name))
    if size != n:
        raise OSError(f"{name}: {path}: the ImageSize of image {k} is {size} bytes, but "
                      f"{layout.shape[1]} x {layout.shape[0]} pixels of {layout.stored} "
                      f"bits take {n}")
    return ptr + ann


def _read_camera(path: Path, pages, wheres, name: str) -> Iterator[np.ndarray]:
    """Frames ``pages`` of the record ``path``, read one at a time from one open file."""
    layout = _layout(path, name)
    with open(path, "rb") as fh:
        if os.fstat(fh.fileno()).st_size != layout.size:
            raise OSError(f"{name}: {path} has changed since the series was opened (its "
                          f"size is no longer {layout.size} bytes)")
        for k in pages:
            yield _read_frame(fh, _frame_offset(fh, layout, k, name), layout, k, name)


# A parsed header, per file and per state of the file (size, modification time): the
# frames of a record are read long after the series was opened, maybe in another
# process, and each process parses the header once.
_LAYOUTS: dict[tuple, _Layout] = {}


def _scan_camera(path: Path, name: str, allow_bool: bool = False) -> FileInfo:
    """A record's frames from its header: its significant bits, its frame times."""
    lay = _layout(path, name)
    n = lay.n_frames
    return FileInfo(path, (lay.shape,) * n, (lay.dtype,) * n, (1,) * n, lay.bits,
                    times=lay.times, header_bits=True, note=lay.note)


def _layout(path: Path, name: str) -> _Layout:
    st = os.stat(path)
    key = (os.path.realpath(path), st.st_size, st.st_mtime_ns)
    found = _LAYOUTS.get(key)
    if found is None:
        found = _read_cine(path, st.st_size, name) if path.suffix.lower() == ".cine" \
            else _read_mraw(path, st.st_size, name)
        _check_frame_memory(found, name)
        if len(_LAYOUTS) > 64:
            _LAYOUTS.clear()
        _LAYOUTS[key] = found
    return found


def _check_frame_memory(layout: _Layout, name: str) -> None:
    H, W = layout.shape
    # the stored bytes, the unpacked uint16 words and their flipped copy
    _memory.check_fits(layout.frame_bytes + 3 * 2 * H * W,
                       what=f"{name}: decoding a frame of {layout.path} ({W} x {H} px of "
                       f"{layout.stored} bits, as its header declares)",
                       advice="check that the file is the camera's record; crop the frames, "
                       "or raise --memory-budget (memory_budget) if more memory is in fact "
                       "free")


def _check_side(value, field: str, path: Path, name: str) -> int:
    if not 0 < abs(value) <= _MAX_SIDE:
        raise OSError(f"{name}: {path}: the header's {field} is {value}; expected an image "
                      f"side of 1 to {_MAX_SIDE} px")
    return abs(value)


def _check_extent(layout: _Layout, start: int, name: str) -> None:
    """Refuse a record whose frames, as its header declares them, pass the file's end."""
    H, W = layout.shape
    end = start + layout.n_frames * layout.frame_bytes
    if end > layout.size:
        raise OSError(f"{name}: {layout.path}: header says {layout.n_frames} frame(s) of "
                      f"{W}x{H} {layout.stored}-bit pixels from byte {start}, up to byte "
                      f"{end}, but the file ends at byte {layout.size}")


def _check_bits(bits: int, stored: int, field: str, path: Path, name: str) -> int:
    if not 1 <= bits <= stored:
        raise OSError(f"{name}: {path}: the header's {field} is {bits}; expected 1 to "
                      f"{stored} significant bits in {stored}-bit pixels")
    return bits


def _stamp_times(times: np.ndarray, path: Path, name: str) -> tuple[float, ...]:
    if times.size > 1 and not np.all(np.diff(times) > 0):
        k = int(np.argmin(np.diff(times) > 0)) + 1
        raise OSError(f"{name}: {path}: the time stamp of image {k} is not after that of "
                      f"image {k - 1} (damaged time block?)")
    return tuple(float(t) for t in times)


def _rate_times(rate: float | None, first: int, n: int, step: int = 1
                ) -> tuple[float, ...]:
    """Frames ``first + k * step`` (k < n) over ``rate``, s; none without a rate (a
    rate checked by :func:`_plausible_rate`, so that no quotient overflows)."""
    if rate is None:
        return ()
    return tuple(float(t) for t in (first + step * np.arange(n, dtype=np.float64)) / rate)


def _plausible_rate(value: float) -> bool:
    """Whether a header's number can be a record's rate, fps (see the module)."""
    return bool(np.isfinite(value) and _RATE_RANGE[0] <= value <= _RATE_RANGE[1])


def _implausible_rate_note(field: str, value) -> str:
    lo, hi = _RATE_RANGE
    return (f"the header's {field} is {value}, not a record rate ({lo:g} to {hi:g} fps): "
            "the frames are read without times (give the frame rate, or the times in the "
            "loads file)")


def _far_times(times: tuple[float, ...]) -> float | None:
    """The time farthest from the trigger, s, if it is more than a day away (or not
    finite); None when every time is plausible."""
    if not times:
        return None
    t = np.asarray(times, dtype=np.float64)
    worst = float(t[np.argmax(np.where(np.isfinite(t), np.abs(t), np.inf))])
    return worst if not np.isfinite(worst) or abs(worst) > _MAX_TIME_S else None


# --------------------------------------------------------------------------- Phantom cine


def _read_cine(path: Path, size: int, name: str) -> _Layout:
    with open(path, "rb") as fh:
        head = fh.read(44)
        if len(head) < 44 or head[:2] != b"CI":
            raise OSError(f"{name}: {path} is not a Phantom cine file (no 44-byte "
                          f"CINEFILEHEADER starting with 'CI'; the file has {size} bytes)")
        (_, header_size, compression, version, _, _, first_no, count, off_bitmap,
         off_setup, off_table) = _CINE_HEADER.unpack_from(head)
        trig_frac, trig_sec = struct.unpack_from("<II", head, 36)
        if header_size != 44:
            raise OSError(f"{name}: {path}: the CINEFILEHEADER's Headersize is "
                          f"{header_size}, expected 44")
        if version != 1:
            raise OSError(f"{name}: {path}: cine Version {version}; gridstrain reads "
                          "version 1 (64-bit image offsets)")
        if compression != 0:
            what = {1: "a JPEG-compressed cine", 2: "an uninterpolated colour (raw Bayer) "
                    "cine"}.get(compression, f"a cine of Compression={compression}")
            raise ValueError(f"{name}: {path} is {what}; gridstrain reads grey cines "
                             "(export the record as 16-bit grey TIFF or cine from PCC)")
        if count < 1:
            raise OSError(f"{name}: {path}: the header's ImageCount is 0; no frame to read")
        table_end = off_table + 8 * count
        if table_end > size:
            raise OSError(f"{name}: {path}: header says {count} image offsets from byte "
                          f"{off_table} (OffImageOffsets), up to byte {table_end}, but the "
                          f"file ends at byte {size}")
        bm = _read_exact(fh, off_bitmap, 40, path, "the BITMAPINFOHEADER (OffImageHeader)",
                         name)
        (bi_size, width, height, _, bit_count, bi_compression, *_) = _BITMAP.unpack(bm)
        if bi_size < 40:
            raise OSError(f"{name}: {path}: the BITMAPINFOHEADER's biSize is {bi_size}, "
                          "expected at least 40")
        W = _check_side(width, "biWidth", path, name)
        H = _check_side(height, "biHeight", path, name)
        setup = _read_exact(fh, off_setup, 144, path, "the SETUP (OffSetup)", name)
        mark, length = (struct.unpack_from(_SETUP_FIELDS[k][1], setup, _SETUP_FIELDS[k][0])[0]
                        for k in ("Mark", "Length"))
        if mark != b"ST" or length < _SETUP_NEED or off_setup + length > off_table:
            raise OSError(f"{name}: {path}: the SETUP at byte {off_setup} has Mark {mark!r} "
                          f"and Length {length}; expected 'ST' and a length of at least "
                          f"{_SETUP_NEED} bytes ending before the image offsets "
                          f"(byte {off_table})")
        setup = _read_exact(fh, off_setup, _SETUP_NEED, path, "the SETUP", name)
        rate, cfa, real_bpp = (struct.unpack_from(_SETUP_FIELDS[k][1], setup,
                                                  _SETUP_FIELDS[k][0])[0]
                               for k in ("FrameRate", "CFA", "RealBPP"))
        if cfa != 0 or bit_count in (24, 48):
            raise ValueError(f"{name}: {path} is a colour cine (CFA={cfa}, biBitCount="
                             f"{bit_count}); gridstrain reads cines of grey sensors (export "
                             "grey frames, e.g. as TIFF, from PCC)")
        if bi_compression == _P10:
            raise ValueError(f"{name}: {path} holds packed 10-bit (P10) images, "
                             "log-encoded by the camera; gridstrain reads 8-bit, 16-bit and "
                             "packed 12-bit (P12L) cines: save the cine as 16-bit in PCC")
        if bi_compression == _P12L and bit_count in (12, 16):
            stored, bottom_up = 12, False  # packed images are stored top-down
        elif bi_compression == 0 and bit_count in (8, 16):
            stored, bottom_up = bit_count, height > 0
        else:
            raise OSError(f"{name}: {path}: the BITMAPINFOHEADER says biBitCount="
                          f"{bit_count} and biCompression={bi_compression}; gridstrain reads "
                          "grey 8 or 16-bit images (biCompression 0) and packed 12-bit "
                          f"images (biCompression {_P12L})")
        if stored == 12 and (H * W) % 2:
            raise OSError(f"{name}: {path}: packed 12-bit images of {W} x {H} px (an odd "
                          "number of pixels) cannot be stored two pixels in three bytes")
        bits = _check_bits(real_bpp, stored, "RealBPP", path, name)
        stamps = _cine_stamps(fh, off_setup + length, off_table, count, path, name)
    fps, times, note = _cine_times(stamps, (trig_sec, trig_frac), rate, first_no, count,
                                   path, name)
    layout = _Layout(path, size, (H, W), count, stored, bits, bottom_up,
                     fps, first_no, times, off_table, note=f"{path.name}: {note}" if note
                     else "")
    # the images must at least fit after the offset table
    _check_extent(layout, table_end, name)
    with open(path, "rb") as fh:
        _frame_offset(fh, layout, 0, name)
    return layout


def _cine_times(stamps: np.ndarray | None, trigger: tuple[int, int], rate: int,
                first_no: int, count: int, path: Path, name: str
                ) -> tuple[float | None, tuple[float, ...], str]:
    """A cine's frame rate (None if not plausible), its frames' times from the trigger,
    s (from the time stamps, else from FirstImageNo and FrameRate; none where they
    are not plausible, see the module) and the note saying why they were left out."""
    trig_sec, trig_frac = trigger
    fps, note = float(rate), ""
    if not _plausible_rate(fps):
        if rate > 0:
            note = _implausible_rate_note("FrameRate", rate)
        fps = None
    times: tuple[float, ...] = ()
    if stamps is not None:
        # seconds and fractions apart: a uint64 stamp less the trigger's may overflow
        sec = (stamps >> np.uint64(32)).astype(np.int64) - trig_sec
        frac = (stamps & np.uint64(0xFFFFFFFF)).astype(np.int64) - trig_frac
        times = _stamp_times(sec + frac / 2.0**32, path, name)
        far = _far_times(times)
        if far is not None:
            by = "timed by its FrameRate" if fps is not None else "read without times"
            note = (f"the header's TriggerTime ({trig_sec + trig_frac / 2.0**32:.10g} s "
                    f"since 1970) puts a frame {far:.3g} s from the trigger, more than a "
                    f"day: the time stamps are left out and the frames {by}")
            times = ()
    if not times:
        times = _rate_times(fps, first_no, count)
        far = _far_times(times)
        if far is not None:
            note = (f"the header's FirstImageNo ({first_no}) and FrameRate ({rate}) put a "
                    f"frame {far:.3g} s from the trigger, more than a day: the frames are "
                    "read without times")
            times = ()
    return fps, times, note


def _cine_stamps(fh, start: int, end: int, count: int, path: Path, name: str
                 ) -> np.ndarray | None:
    """The TIME64 of every image from the "time only" tagged block, or None."""
    at = start
    for _ in range(_MAX_BLOCKS):
        if at + 8 > end:
            return None
        block_size, kind, _ = struct.unpack("<IHH", _read_exact(fh, at, 8, path,
                                                               "a tagged block", name))
        if block_size < 8 or at + block_size > end:
            # not a block: what follows the SETUP is padding, or a block this file
            # does not hold in full; the time stamps are then taken as absent
            return None
        if kind == _TIME_ONLY_BLOCK:
            if block_size - 8 != 8 * count:
                raise OSError(f"{name}: {path}: the time block (type {kind}) at byte {at} "
                              f"holds {block_size - 8} bytes, expected 8 per image "
                              f"({8 * count})")
            fh.seek(at + 8)
            return np.fromfile(fh, dtype="<u8", count=count)
        at += block_size
    return None


# --------------------------------------------------------------------------- Photron MRAW


def _cih_path(path: Path, name: str) -> Path:
    for ext in (".cihx", ".cih", ".CIHX", ".CIH"):
        p = path.with_suffix(ext)
        if p.is_file():
            return p
    raise FileNotFoundError(f"{name}: {path} is a Photron MRAW record; its header "
                            f"{path.with_suffix('.cihx').name} or "
                            f"{path.with_suffix('.cih').name} must lie beside it")


def _read_header_text(cih: Path, name: str) -> bytes:
    n = os.path.getsize(cih)
    if n > _MAX_HEADER_BYTES:
        raise OSError(f"{name}: {cih} has {n} bytes; a Photron header holds a few "
                      "kilobytes (is it the header?)")
    return cih.read_bytes()


def _cih_fields(text: bytes) -> dict[str, str]:
    """``Key : Value`` lines of a ``.cih`` header."""
    out = {}
    for line in text.decode("latin-1").splitlines():
        key, sep, value = line.partition(" : ")
        if sep:
            out[key.strip()] = value.strip()
    return out


# the values read from a .cihx: XML path under <cih>, and the .cih key they stand for
_CIHX_FIELDS = {"frameInfo/totalFrame": "Total Frame", "frameInfo/startFrame": "Start Frame",
                "frameInfo/skipFrame": "Save Step",
                "frameInfo/recordedFrame": "Original Total Frame",
                "deviceInfo/deviceName": "Camera Type",
                "recordInfo/recordRate": "Record Rate(fps)",
                "imageDataInfo/resolution/width": "Image Width",
                "imageDataInfo/resolution/height": "Image Height",
                "imageDataInfo/colorInfo/type": "Color Type",
                "imageDataInfo/colorInfo/bit": "Color Bit",
                "imageDataInfo/effectiveBit/depth": "EffectiveBit Depth",
                "imageDataInfo/effectiveBit/side": "EffectiveBit Side",
                "imageFileInfo/fileFormat": "File Format"}


def _cihx_fields(text: bytes, cih: Path, name: str) -> dict[str, str]:
    """The ``.cih`` keys of the values in a ``.cihx`` header's XML."""
    start, end = text.find(b"<cih>"), text.rfind(b"</cih>")
    if start < 0 or end < start:
        raise OSError(f"{name}: {cih} holds no <cih>...</cih> document")
    doc = text[start:end + len(b"</cih>")]
    if re.search(rb"<!(DOCTYPE|ENTITY)", doc):
        raise OSError(f"{name}: {cih} declares XML entities; a Photron header has none")
    try:
        root = ET.fromstring(doc)
    except ET.ParseError as exc:
        raise OSError(f"{name}: {cih} is not well-formed XML ({exc})") from None
    out = {}
    for xpath, key in _CIHX_FIELDS.items():
        el = root.find(xpath)
        if el is not None and el.text is not None:
            out[key] = el.text.strip()
    return out


def _cih_int(fields: dict, key: str, cih: Path, name: str, default: int | None = None
             ) -> int:
    value = fields.get(key)
    if value is None and default is not None:
        return default
    if value is None or not re.fullmatch(r"[+-]?\d{1,12}", value):
        got = "nothing" if value is None else repr(value)
        raise OSError(f"{name}: {cih}: the header's {key!r} must be an integer, got {got}")
    return int(value)


# Photron's monochrome models carry "-M" in their model code ("... type 1100K-M-64GB")
_MONOCHROME_MODEL = re.compile(r"-M(-|\b)")


def _check_monochrome(fields: dict, path: Path, cih: Path, name: str) -> None:
    """Refuse an MRAW record whose pixels are not grey levels (see the module)."""
    colour = fields.get("Color Type", "Mono")
    if colour.lower() in ("mono", "monochrome"):
        return
    model = fields.get("Camera Type", "")
    if colour.lower() == "raw" and _MONOCHROME_MODEL.search(model):
        return
    what = (f"raw sensor data from a camera whose model ({model or 'not in the header'}) "
            "is not a monochrome one (Photron's model code -M): a colour sensor's Bayer "
            "mosaic") if colour.lower() == "raw" else f"a colour ({colour}) record"
    raise ValueError(f"{name}: {path} holds {what}; gridstrain reads grey records "
                     f"({cih.name}; export grey frames, e.g. as TIFF, from PFV)")


def _read_mraw(path: Path, size: int, name: str) -> _Layout:
    cih = _cih_path(path, name)
    text = _read_header_text(cih, name)
    fields = _cihx_fields(text, cih, name) if cih.suffix.lower() == ".cihx" \
        else _cih_fields(text)
    fmt = fields.get("File Format", "MRaw")
    if fmt.lower() != "mraw":
        raise OSError(f"{name}: {cih} describes a record in the {fmt!r} format, not MRaw")
    _check_monochrome(fields, path, cih, name)
    W = _check_side(_cih_int(fields, "Image Width", cih, name), "'Image Width'", cih, name)
    H = _check_side(_cih_int(fields, "Image Height", cih, name), "'Image Height'", cih, name)
    count = _cih_int(fields, "Total Frame", cih, name)
    start = _cih_int(fields, "Start Frame", cih, name, default=0)
    stored = _cih_int(fields, "Color Bit", cih, name)
    if stored not in (8, 12, 16):
        raise OSError(f"{name}: {cih}: the header's 'Color Bit' is {stored}; gridstrain "
                      "reads monochrome MRAW of 8, 12 (packed) or 16 bits")
    if stored == 12 and (H * W) % 2:
        raise OSError(f"{name}: {cih}: 12-bit frames of {W} x {H} px (an odd number of "
                      "pixels) cannot be packed two pixels in three bytes")
    bits = _check_bits(_cih_int(fields, "EffectiveBit Depth", cih, name, default=stored),
                       stored, "'EffectiveBit Depth'", cih, name)
    try:
        rate = float(fields.get("Record Rate(fps)", "nan"))
    except ValueError:
        rate = float("nan")
    if count < 1:
        raise OSError(f"{name}: {cih}: the header's 'Total Frame' is {count}; no frame to "
                      "read")
    step = _cih_int(fields, "Save Step", cih, name, default=1)
    if step < 1:
        raise OSError(f"{name}: {cih}: the header's save step is {step}; it counts the "
                      "recorded frames from one saved frame to the next (1 or more)")
    recorded = _cih_int(fields, "Original Total Frame", cih, name, default=-1)
    note = ""
    if not _plausible_rate(rate):
        rate_saved, times = None, ()
        note = f"{cih.name}: " + _implausible_rate_note(
            "'Record Rate(fps)'", fields.get("Record Rate(fps)"))
    elif step == 1 or recorded < 0 or (count - 1) * step < recorded:
        rate_saved, times = rate / step, _rate_times(rate, start, count, step)
        far = _far_times(times)
        if far is not None:
            rate_saved, times = None, ()
            note = (f"{cih.name}: the header's 'Start Frame' ({start}) and 'Record "
                    f"Rate(fps)' ({fields.get('Record Rate(fps)')}) put a frame {far:.3g} s "
                    "from the trigger, more than a day: the frames are read without times")
    else:  # the header contradicts itself: no time is better than a wrong one
        rate_saved, times = None, ()
        note = (f"{cih.name} gives a save step of {step} over {recorded} recorded frames, "
                f"which cannot hold its {count} saved frames: the frames are read without "
                "times (give the frame rate, or the times in the loads file)")
    layout = _Layout(path, size, (H, W), count, stored, bits, False, rate_saved,
                     start, times, note=note)
    _check_extent(layout, 0, name)
    if count * layout.frame_bytes != size:
        raise OSError(f"{name}: {path}: header {cih.name} says {count} frame(s) of {W}x{H} "
                      f"{stored}-bit pixels ({count * layout.frame_bytes} bytes) but the "
                      f"file has {size} bytes (a header of another record?)")
    return layout


# A record's layout (_Layout) says its frame rate and its trigger's frame.
register_format(ImageFormat("Phantom cine", (".cine",), _scan_camera, _read_camera,
                            kind="camera", magic=(b"CI",), stack=True, timing=_layout))
register_format(ImageFormat("Photron MRAW", (".mraw",), _scan_camera, _read_camera,
                            kind="camera", stack=True, timing=_layout))
