"""Writers of Phantom cine and Photron MRAW records, numpy only, from the published
layouts and independent of gridstrain's readers. Their assumptions:

Phantom cine (Vision Research's "Cine file format"), every number little-endian:

- CINEFILEHEADER, 44 bytes at 0: Type "CI" (2 bytes), Headersize 44, Compression 0,
  Version 1 (uint16 each), FirstMovieImage, TotalImageCount, FirstImageNo, ImageCount,
  OffImageHeader, OffSetup, OffImageOffsets (32 bits each, FirstImageNo signed), then
  TriggerTime as a TIME64: uint32 fraction of a second in units of 2**-32 s, then
  uint32 seconds since 1970-01-01 UTC.
- BITMAPINFOHEADER, 40 bytes: biSize 40, biWidth, biHeight (int32), biPlanes 1,
  biBitCount (uint16), biCompression (0 plain, 1024 packed 12-bit "P12L"),
  biSizeImage, two resolutions, two colour counts.
- SETUP (here 13484 bytes, zero but for): Mark "ST" at byte 140, Length (uint16) at
  142, FrameRate (uint32, fps) at 768, CFA (uint32, 0 for a grey sensor) at 808,
  RealBPP (uint32, significant bits) at 896.
- Tagged blocks right after the SETUP: BlockSize (uint32, counting its 8-byte head),
  Type (uint16), reserved (uint16), data. An exposure block (type 1003, one uint32 per
  image) that a reader must step over, then the "time only" block (type 1002, one
  TIME64 per image).
- The image offset table: one int64 per image, the offset of its annotation block:
  AnnotationSize (uint32, counting itself, the annotation and the ImageSize that
  ends it), annotation bytes, ImageSize (uint32); the pixels follow.
- Plain images are stored bottom-up (the last row of the image first), as in a
  Windows bitmap with a positive height; packed 12-bit images top-down, two pixels
  in three bytes, most significant bits first.

Photron MRAW:

- ``NAME.cih``: text, one ``Key : Value`` per line (the keys of Photron FASTCAM
  Viewer's header, e.g. ``Record Rate(fps)``, ``Total Frame``, ``Start Frame``,
  ``Image Width``, ``Image Height``, ``Color Type``, ``Color Bit``,
  ``EffectiveBit Depth``, ``EffectiveBit Side``, ``File Format``, ``Save Step``,
  ``Original Total Frame``, ``Camera Type``); or ``NAME.cihx``: a few bytes of binary
  preamble then an XML document ``<cih>`` with the same values under
  ``recordInfo/recordRate``, ``frameInfo/totalFrame``, ``frameInfo/startFrame``,
  ``frameInfo/skipFrame``, ``frameInfo/recordedFrame``, ``deviceInfo/deviceName``,
  ``imageDataInfo/resolution/width|height``, ``imageDataInfo/colorInfo/type|bit``,
  ``imageDataInfo/effectiveBit/depth|side``, ``imageFileInfo/fileFormat``. Frame ``k``
  is recorded frame ``Start Frame + k * Save Step``. Assumed from the headers of
  three records of FASTCAM SA-Z and Nova S16 cameras (pyMRAW's sample data): a
  monochrome model's ``.cihx`` may give the colour type ``Raw``.
- ``NAME.mraw``: the frames one after the other, rows top-down, no header; 8-bit
  bytes, 16-bit little-endian words, or 12-bit pixels packed two in three bytes
  with the most significant bits first (pixels ``0xABC, 0xDEF`` are bytes
  ``AB CD EF``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

SETUP_LENGTH = 13484
P12L = 1024

_HEADER = np.dtype({"names": ["type", "headersize", "compression", "version",
                              "first_movie", "total", "first_no", "count", "off_bitmap",
                              "off_setup", "off_table", "trig_frac", "trig_sec"],
                    "formats": ["S2", "<u2", "<u2", "<u2", "<i4", "<u4", "<i4", "<u4",
                                "<u4", "<u4", "<u4", "<u4", "<u4"],
                    "offsets": [0, 2, 4, 6, 8, 12, 16, 20, 24, 28, 32, 36, 40],
                    "itemsize": 44})
_BITMAP = np.dtype({"names": ["size", "width", "height", "planes", "bit_count",
                              "compression", "size_image"],
                    "formats": ["<u4", "<i4", "<i4", "<u2", "<u2", "<u4", "<u4"],
                    "offsets": [0, 4, 8, 12, 14, 16, 20], "itemsize": 40})
_SETUP = np.dtype({"names": ["mark", "length", "frame_rate", "cfa", "real_bpp"],
                   "formats": ["S2", "<u2", "<u4", "<u4", "<u4"],
                   "offsets": [140, 142, 768, 808, 896], "itemsize": SETUP_LENGTH})


def pack12(frame: np.ndarray) -> bytes:
    """Pixels (< 4096) packed two in three bytes, most significant bits first."""
    v = np.asarray(frame, dtype=np.uint32).reshape(-1, 2)
    word = (v[:, 0] << 12) | v[:, 1]  # 24 bits: the pair, first pixel high
    return np.stack([word >> 16, (word >> 8) & 0xFF, word & 0xFF], axis=1).astype(
        np.uint8).tobytes()


def _time64(seconds: float | int) -> int:
    return round(seconds * 2**32)


def write_cine(path, frames, *, real_bpp: int, bit_count: int = 16, packed: bool = False,
               frame_rate: int = 1000, first_number: int = 0, trigger=1_700_000_000.25,
               times=None, cfa: int = 0, compression: int = 0, annotation: int = 24
               ) -> Path:
    """Write ``frames`` ((n, H, W) uint8 or uint16) as a grey Phantom cine.

    ``times`` (s from the trigger, one per frame) are written in a time block; None
    writes no time block. ``trigger`` is the trigger's time, s since 1970. Every
    image carries ``annotation`` bytes of annotation.
    """
    frames = np.asarray(frames)
    n, H, W = frames.shape
    images = [pack12(f) if packed else np.ascontiguousarray(f[::-1]).astype(
        "<u1" if bit_count == 8 else "<u2").tobytes() for f in frames]
    blocks = bytearray()
    exposure = np.full(n, 12345, dtype="<u4").tobytes()
    blocks += np.array([8 + len(exposure)], "<u4").tobytes() + np.array([1003, 0], "<u2"
                                                                         ).tobytes()
    blocks += exposure
    if times is not None:
        t0 = _time64(trigger)
        stamps = np.array([t0 + _time64(t) for t in times], dtype=np.uint64)
        words = np.stack([stamps & 0xFFFFFFFF, stamps >> 32], axis=1).astype("<u4")
        blocks += np.array([8 + 8 * n], "<u4").tobytes() + np.array([1002, 0], "<u2"
                                                                    ).tobytes()
        blocks += words.tobytes()
    off_setup = 44 + 40
    off_table = off_setup + SETUP_LENGTH + len(blocks)
    first_image = off_table + 8 * n
    ann_size = 8 + annotation
    pointers = first_image + np.arange(n, dtype=np.int64) * (ann_size + len(images[0]))

    head = np.zeros(1, _HEADER)
    trig = _time64(trigger)
    head[0] = (b"CI", 44, compression, 1, first_number, n, first_number, n, 44, off_setup,
               off_table, trig & 0xFFFFFFFF, trig >> 32)
    bitmap = np.zeros(1, _BITMAP)
    bitmap[0] = (40, W, H, 1, bit_count, P12L if packed else 0, len(images[0]))
    setup = np.zeros(1, _SETUP)
    setup[0] = (b"ST", SETUP_LENGTH, frame_rate, cfa, real_bpp)
    with open(path, "wb") as fh:
        fh.write(head.tobytes() + bitmap.tobytes() + setup.tobytes() + bytes(blocks))
        fh.write(pointers.astype("<i8").tobytes())
        for img in images:
            fh.write(np.array([ann_size], "<u4").tobytes() + bytes(range(annotation))
                     + np.array([len(img)], "<u4").tobytes() + img)
    return Path(path)


def write_mraw(path, frames, *, color_bit: int, effective_bit: int | None = None,
               side: str = "Lower", frame_rate: float = 20000, start_frame: int = 0,
               header: str = "cih", color_type: str = "Mono", save_step: int = 1,
               recorded: int | None = None,
               camera: str = "FASTCAM SA-Z type 2100K-M-64GB") -> Path:
    """Write ``frames`` ((n, H, W)) as ``path`` (``.mraw``) and its ``.cih``/``.cihx``;
    ``recorded``: the frames recorded (default: those the saved ones span)."""
    frames = np.asarray(frames)
    n, H, W = frames.shape
    path = Path(path)
    with open(path, "wb") as fh:
        for f in frames:
            if color_bit == 12:
                fh.write(pack12(f))
            else:
                fh.write(f.astype("<u1" if color_bit == 8 else "<u2").tobytes())
    eff = color_bit if effective_bit is None else effective_bit
    recorded = (n - 1) * save_step + 1 if recorded is None else recorded
    rate = f"{frame_rate:g}"
    if header == "cih":
        lines = ["#Camera Information Header", "Date : 2026/11/27", "Time : 12:00",
                 f"Camera Type : {camera}", f"Record Rate(fps) : {rate}",
                 f"Shutter Speed(s) : 1/{rate}", f"Total Frame : {n}",
                 f"Original Total Frame : {recorded}", f"Start Frame : {start_frame}",
                 f"Save Step : {save_step}",
                 "Correct Trigger Frame : 0", f"Image Width : {W}", f"Image Height : {H}",
                 f"Color Type : {color_type}", f"Color Bit : {color_bit}",
                 "File Format : MRaw", f"EffectiveBit Depth : {eff}",
                 f"EffectiveBit Side : {side}", "Comment Text : ", "", "END"]
        path.with_suffix(".cih").write_bytes(("\r\n".join(lines)).encode("ascii"))
    else:
        xml = (f'<?xml version="1.0" encoding="UTF-8"?>\n<cih>\n'
               f"<fileInfo><date>2026/11/27</date></fileInfo>\n"
               f"<recordInfo><recordRate>{rate}</recordRate>"
               f"<shutterSpeed>1/{rate}</shutterSpeed></recordInfo>\n"
               f"<frameInfo><recordedFrame>{recorded}</recordedFrame>"
               f"<totalFrame>{n}</totalFrame><startFrame>{start_frame}</startFrame>"
               f"<skipFrame>{save_step}</skipFrame></frameInfo>\n"
               f"<deviceInfo><deviceName>{camera}</deviceName></deviceInfo>\n"
               f"<imageDataInfo><resolution><width>{W}</width><height>{H}</height>"
               f"</resolution><colorInfo><type>{color_type}</type><bit>{color_bit}</bit>"
               f"</colorInfo><effectiveBit><depth>{eff}</depth><side>{side}</side>"
               f"</effectiveBit></imageDataInfo>\n"
               f"<imageFileInfo><fileFormat>MRaw</fileFormat></imageFileInfo>\n</cih>\n")
        path.with_suffix(".cihx").write_bytes(b"\x00\x01\x02\x03" + xml.encode("utf-8"))
    return path
