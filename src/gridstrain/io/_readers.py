"""Reading the files of a series: TIFF pages (packed, compressed, multi-page), PNG, BMP and
JPEG images through imageio, videos through PyAV, each registered as a format
(:mod:`gridstrain.io._formats`; the high-speed camera records in ``_camera``); each file
scanned once for its frames, shape, dtype and channels, and a source resolved to its files
in natural order.
"""

from __future__ import annotations

import contextlib
import glob
import logging
import os
import re
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import tifffile

from .._validation import (
    as_path,
)
from ._formats import (
    FileInfo,
    ImageFormat,
    check_suffix,
    is_readable_name,
    register_format,
    suffixes,
)

#: File name extensions read as images (compared case-insensitively). JPEG files are
#: read with a note: lossy compression adds noise the noise model does not describe.
IMAGE_EXTENSIONS = (".tif", ".tiff", ".png", ".bmp", ".jpg", ".jpeg")


#: Video files, read frame by frame through PyAV (the ``video`` extra), as the grey
#: levels of their luma plane (the luminance the codec stored).
VIDEO_EXTENSIONS = (".avi", ".mp4", ".mov", ".mkv")


# Video codecs that keep every grey level: any other adds compression artefacts.
_LOSSLESS_CODECS = {"rawvideo", "ffv1", "huffyuv", "ffvhuff", "utvideo", "png", "tiff",
                    "qtrle", "r210", "v210", "magicyuv"}


#: Weights of R, G, B in the luminance of colour frames: ITU-R BT.709 (the
#: primaries of sRGB, which most colour cameras and PNG/JPEG files use). Applied to
#: the stored values; an alpha channel is ignored.
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)


def natural_sort_key(text: str | os.PathLike) -> tuple:
    """Sort key ordering embedded numbers by value: ``frame2`` before ``frame10``.

    Letters compare case-insensitively; ties (``f01`` and ``f1``) are broken by the
    plain string so that the order is total and reproducible.
    """
    s = os.fspath(text)
    parts = re.split(r"(\d+)", s)
    # re.split with a capturing group alternates text (even) and digits (odd), so the
    # keys of two strings compare str with str and int with int, position by position.
    key = tuple(int(p) if i % 2 else p.casefold() for i, p in enumerate(parts))
    return (key, s)


def _page_layout(shape: tuple[int, ...], samples: int) -> tuple[tuple[int, ...], int, int]:
    """``((H, W) or the shape, channels, channel axis)`` of a page: colour pages have
    2 (grey and alpha), 3 (RGB) or 4 (RGBA) samples per pixel, last or first axis."""
    shape = tuple(int(v) for v in shape)
    if len(shape) == 3:
        n = samples if samples > 1 else shape[-1]
        if n in (2, 3, 4) and shape[-1] == n:
            return shape[:2], n, -1
        if samples in (2, 3, 4) and shape[0] == samples:
            return shape[1:], samples, 0
    return shape, 1, -1


def to_luminance(raw: np.ndarray, *, axis: int = -1) -> np.ndarray:
    """Grey levels of a colour frame: ``0.2126 R + 0.7152 G + 0.0722 B`` (BT.709).

    Parameters
    ----------
    raw : (H, W, C) or (C, H, W) ndarray
        ``C = 2`` (grey and alpha: the grey channel is returned), 3 (RGB) or 4
        (RGBA: alpha ignored), along ``axis``.
    axis : {-1, 0}
        The channel axis.

    Returns
    -------
    (H, W) float64 ndarray
        In the stored units of the channels. A fixed linear combination: the phase
        of the grid, which the method measures, is the same in every channel.
    """
    a = np.moveaxis(np.asarray(raw), axis, -1)
    if a.shape[-1] == 2:
        return a[..., 0].astype(np.float64)
    return a[..., :3].astype(np.float64) @ np.asarray(LUMINANCE_WEIGHTS)


def _check_page(shape: tuple[int, ...], samples: int, dtype: np.dtype | None, where: str,
                name: str, *, allow_bool: bool = False) -> None:
    """Refuse 1-D, 3-D and non-numeric pages, naming the file (colour is converted)."""
    shape, _, _ = _page_layout(shape, samples)
    if len(shape) > 2:
        raise ValueError(f"{name}: {where} is a 3-D page of shape {tuple(shape)}; each "
                         "frame must be a 2-D image (H, W)")
    if len(shape) < 2 or min(shape) <= 1:
        raise ValueError(f"{name}: {where} is 1-D (shape {tuple(shape)}); each frame must "
                         "be a 2-D image (H, W)")
    if dtype is None or dtype.kind not in ("buif" if allow_bool else "uif"):
        raise ValueError(f"{name}: {where} holds {dtype} pixels; expected unsigned/signed "
                         "integer or float grey levels")


def _describe(path: Path, page: int, n_pages: int) -> str:
    return f"{path} (page {page})" if n_pages > 1 else str(path)


class _TiffLog(logging.Handler):
    """Collects what tifffile logs (it reports damaged files as log warnings)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


@contextlib.contextmanager
def _tiff_log() -> Iterator[_TiffLog]:
    # tifffile's warnings are turned into errors by the callers: a damaged file is
    # never read "as well as possible" in silence
    logger = logging.getLogger("tifffile")
    handler = _TiffLog()
    propagate = logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate


def _check_tiff_log(log: _TiffLog, where: str, name: str) -> None:
    if log.messages:
        msg = log.messages[0].splitlines()[0] if log.messages[0] else ""
        msg = re.sub(r"^<[^>]*>\s*", "", msg) or "damaged file"
        raise OSError(f"{name}: {where} is damaged or truncated ({msg}); refusing to use "
                      "what remains of the file")


def _tiff_file(path: Path, name: str) -> tifffile.TiffFile:
    """``path`` opened as a TIFF file, its header checked; errors name the series."""
    try:
        with _tiff_log() as log:
            tif = tifffile.TiffFile(path)
        try:
            _check_tiff_log(log, str(path), name)
        except BaseException:
            tif.close()
            raise
    except (FileNotFoundError, PermissionError):
        raise  # the message names the path
    except OSError as exc:
        if str(exc).startswith(f"{name}:"):
            raise
        raise OSError(f"{name}: cannot read {path} as a TIFF file ({exc})") from exc
    except Exception as exc:
        raise OSError(f"{name}: cannot read {path} as a TIFF file ({exc})") from exc
    return tif


@contextlib.contextmanager
def _open_tiff(path: Path, name: str) -> Iterator[tifffile.TiffFile]:
    with _tiff_file(path, name) as tif:
        yield tif


def _read_tiff(path: Path, pages, wheres, name: str) -> Iterator[np.ndarray]:
    """The pages ``pages`` of ``path``, from the file this thread keeps open."""
    with _reading_tiff(path, name) as tif:
        for page, where in zip(pages, wheres, strict=True):
            yield _read_tiff_page(tif, page, where, name)


class _TiffCursor(threading.local):
    """The TIFF file read last by this thread, left open: a record's states read one
    page each, in order, and reopening the file would walk its chain of pages from
    the first every time (the cost of page ``n`` growing with ``n``). The file is
    opened again when it is another one, or when its size or time changed."""

    def __init__(self):
        self.key = self.tif = None

    def close(self) -> None:
        if self.tif is not None:
            self.tif.close()
        self.key = self.tif = None

    @contextlib.contextmanager
    def open(self, path: Path, name: str) -> Iterator[tifffile.TiffFile]:
        st = os.stat(path)
        key = (os.path.abspath(path), st.st_size, st.st_mtime_ns, st.st_ino)
        if key != self.key:
            self.close()
            self.tif = _tiff_file(path, name)
            self.key = key
        try:
            yield self.tif
        except Exception:
            self.close()  # a damaged page: the next read starts afresh
            raise


_TIFF_CURSOR = _TiffCursor()


def _reading_tiff(path: Path, name: str):
    """A context giving ``path``'s open TIFF file, kept open for the next read."""
    return _TIFF_CURSOR.open(path, name)


def _codec_hint(page, exc: Exception) -> str | None:
    """A message naming a compression this installation cannot decode, or None."""
    compression = getattr(page, "compression", None)
    if compression is None or int(compression) == 1:  # 1: no compression
        return None
    if isinstance(exc, ImportError) or "imagecodecs" in str(exc):
        codec = getattr(compression, "name", str(compression))
        return (f"its pages are {codec}-compressed and no decoder for {codec} is "
                "installed: pip install imagecodecs")
    return None


def _read_tiff_page(tif: tifffile.TiffFile, page: int, where: str, name: str) -> np.ndarray:
    try:
        with _tiff_log() as log:
            p = tif.pages[page]
            end = max((o + c for o, c in zip(p.dataoffsets, p.databytecounts, strict=False)),
                      default=0)
            if end > tif.filehandle.size:
                raise OSError(f"the page's data end at byte {end} but the file has "
                              f"{tif.filehandle.size} bytes (truncated file)")
            arr = p.asarray()
        _check_tiff_log(log, where, name)
        return arr
    except MemoryError:
        raise
    except Exception as exc:  # truncated data, unknown compression, bad offsets
        if str(exc).startswith(f"{name}:"):
            raise
        hint = _codec_hint(tif.pages[page], exc)
        raise OSError(f"{name}: cannot read {where}: {hint or exc}") from exc


class _VideoCursor:
    """One decoder left open on the video read last, so that frames read in order
    (one state after the other) are decoded once each; a frame before the cursor
    reopens the file."""

    def __init__(self):
        self.path = self.container = self.frames = None
        self.next = 0

    def close(self) -> None:
        if self.container is not None:
            self.container.close()
        self.path = self.container = self.frames = None
        self.next = 0

    def read(self, path: Path, pages: list[int], name: str) -> Iterator[np.ndarray]:
        """Yield the frames ``pages`` (increasing) one at a time, decoding on demand:
        a record of any length holds one decoded frame at a time. Another reader of
        the cursor may have moved it between two frames: it is then opened again."""
        for page in pages:
            if path != self.path or page < self.next:
                self.close()
                av = _av(name, path)
                self.container = av.open(str(path))
                st = self.container.streams.video[0]
                fmt, _ = _video_format(st)
                self.frames = (f.to_ndarray(format=fmt) for f in self.container.decode(st))
                self.path = path
            while True:
                arr = next(self.frames, None)
                if arr is None:
                    self.close()
                    raise OSError(f"{name}: {path} ends before frame {page}")
                self.next += 1
                if self.next - 1 == page:
                    yield arr
                    break


_CURSOR = _VideoCursor()


def close_readers() -> None:
    """Close the files left open for the next read (the calling thread's TIFF file,
    the video decoder): at the end of a run, so that no file stays held."""
    _TIFF_CURSOR.close()
    _CURSOR.close()


def _read_video(path: Path, pages: list[int], wheres, name: str) -> Iterator[np.ndarray]:
    """Yield the frames ``pages`` of the video ``path``, decoded as they are asked for."""
    try:
        yield from _CURSOR.read(path, pages, name)
    except (OSError, ValueError, MemoryError):
        raise
    except Exception as exc:
        _CURSOR.close()
        raise OSError(f"{name}: cannot decode {path} ({exc})") from exc


def _imageio():
    # imported on first use: only PNG and BMP need it, and it is slow to import
    import imageio.v3 as iio

    return iio


def _read_image(path: Path, pages, wheres, name: str) -> Iterator[np.ndarray]:
    """The single image of ``path``, through imageio, once per page asked."""
    for _ in pages:
        try:
            arr = np.asarray(_imageio().imread(path))
        except (FileNotFoundError, PermissionError, MemoryError):
            raise
        except Exception as exc:
            raise OSError(f"{name}: cannot read {path} as an image ({exc})") from exc
        yield arr


def _av(name: str, path: Path):
    try:
        import av
    except ImportError:
        raise ValueError(f"{name}: {path} is a video; reading it needs PyAV: pip install "
                         "'gridstrain[video]'") from None
    return av


def _video_format(stream) -> tuple[str, np.dtype]:
    """The grey format frames are converted to, and its pixel type: the luma plane,
    8 or 16 bits as the stream stores it."""
    fmt = stream.codec_context.format
    deep = fmt is not None and any(c.bits > 8 for c in fmt.components)
    return ("gray16le", np.dtype(np.uint16)) if deep else ("gray", np.dtype(np.uint8))


def _scan_video(path: Path, name: str, allow_bool: bool = False) -> FileInfo:
    """The frames of a video: counted by demuxing its packets (no decoding)."""
    av = _av(name, path)
    try:
        with av.open(str(path)) as c:
            if not c.streams.video:
                raise ValueError("no video stream")
            st = c.streams.video[0]
            shape = (int(st.codec_context.height), int(st.codec_context.width))
            _, dtype = _video_format(st)
            codec = st.codec_context.name
            pts = [pk.pts for pk in c.demux(st) if pk.size]
            n = len(pts)
            # presentation times, in display order (packets come in decoding order)
            times = () if not n or None in pts or st.time_base is None else tuple(
                float((t - min(pts)) * st.time_base) for t in sorted(pts))
    except (FileNotFoundError, PermissionError, MemoryError):
        raise
    except Exception as exc:
        raise OSError(f"{name}: cannot read {path} as a video ({exc})") from exc
    if n == 0 or min(shape) <= 1:
        raise OSError(f"{name}: {path} holds no readable video frame")
    return FileInfo(path, (shape,) * n, (dtype,) * n, (1,) * n, None, codec, times)


def _scan_tiff(path: Path, name: str, allow_bool: bool = False) -> FileInfo:
    """Read the headers of ``path`` (no pixel data) and check every page."""
    with _open_tiff(path, name) as tif:
        with _tiff_log() as log:
            n = len(tif.pages)
        _check_tiff_log(log, f"{path} from page {n} on" if n else str(path), name)
        if n == 0:
            raise OSError(f"{name}: {path} contains no readable image page "
                          "(corrupt TIFF?)")
        shapes, dtypes, channels = [], [], []
        bits = None
        for k in range(n):
            try:
                with _tiff_log() as log:
                    page = tif.pages[k]
                    shape, samples, dtype = page.shape, page.samplesperpixel, page.dtype
                    if k == 0:
                        bps = page.bitspersample
                        bits = int(bps[0] if isinstance(bps, tuple) else bps)
                    end = max((o + c for o, c in zip(page.dataoffsets,
                                                     page.databytecounts, strict=False)),
                              default=0)
            except MemoryError:
                raise
            except Exception as exc:
                raise OSError(f"{name}: cannot read page {k} of {path}: {exc}") from exc
            _check_tiff_log(log, _describe(path, k, n), name)
            if end > tif.filehandle.size:
                raise OSError(f"{name}: {_describe(path, k, n)} is truncated: "
                              f"its data end at byte {end} but the file has "
                              f"{tif.filehandle.size} bytes")
            _check_page(shape, samples, dtype, _describe(path, k, n), name,
                        allow_bool=allow_bool)
            hw, c, _ = _page_layout(shape, samples)
            shapes.append(hw)
            channels.append(c)
            dtypes.append(np.dtype(dtype))
    return FileInfo(path, tuple(shapes), tuple(dtypes), tuple(channels), bits)


def _scan_image(path: Path, name: str, allow_bool: bool = False) -> FileInfo:
    """The header of a PNG, BMP or JPEG file, through imageio."""
    try:
        props = _imageio().improps(path)
    except (FileNotFoundError, PermissionError, MemoryError):
        raise
    except Exception as exc:
        raise OSError(f"{name}: cannot read {path} as an image ({exc})") from exc
    shape = tuple(int(s) for s in props.shape)
    _check_page(shape, 1, np.dtype(props.dtype), str(path), name, allow_bool=allow_bool)
    hw, c, _ = _page_layout(shape, 1)
    return FileInfo(path, (hw,), (np.dtype(props.dtype),), (c,))


def _resolve_source(source, name: str) -> tuple[Path, ...]:
    """The ordered image files of ``source`` (see :func:`open_series`)."""
    if isinstance(source, list | tuple):
        if not source:
            raise ValueError(f"{name}: the list of image files is empty")
        paths = []
        for item in source:
            p = as_path(item, f"{name} list items")
            if not p.exists():
                raise FileNotFoundError(f"{name}: image file {p} does not exist")
            if p.is_dir():
                raise ValueError(f"{name}: {p} in the list is a directory; pass the "
                                 "directory itself, not inside a list")
            check_suffix(p, name)
            paths.append(p)
        return tuple(paths)

    p = as_path(source, name)
    if p.is_dir():
        entries = [e for e in p.iterdir() if e.is_file() and not e.name.startswith(".")]
        images = sorted((e for e in entries if is_readable_name(e)),
                        key=lambda e: natural_sort_key(e.name))
        if not images:
            others = f" ({len(entries)} other file(s) ignored)" if entries else ""
            raise ValueError(f"{name}: directory {p} holds no image file "
                             f"({', '.join(suffixes('image'))}){others}")
        return tuple(images)
    if p.is_file():
        check_suffix(p, name)
        return (p,)
    pattern = os.fspath(p)
    if re.search(r"[*?\[]", pattern):
        matches = [Path(m) for m in glob.glob(pattern)]
        files = [m for m in matches if m.is_file()]
        images = sorted((m for m in files if is_readable_name(m)), key=natural_sort_key)
        if not images:
            if files:
                raise ValueError(f"{name}: glob pattern {pattern!r} matches {len(files)} "
                                 f"file(s) but no image ({', '.join(suffixes('image'))})")
            raise FileNotFoundError(f"{name}: no file matches the glob pattern {pattern!r}")
        return tuple(images)
    raise FileNotFoundError(f"{name}: {p} does not exist")


# The formats of this module, in the order error messages list them.
register_format(ImageFormat("TIFF", (".tif", ".tiff"), _scan_tiff, _read_tiff, stack=True,
                            magic=(b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")))
register_format(ImageFormat("PNG", (".png",), _scan_image, _read_image,
                            magic=(b"\x89PNG\r\n\x1a\n",)))
register_format(ImageFormat("BMP", (".bmp",), _scan_image, _read_image, magic=(b"BM",)))
register_format(ImageFormat(
    "JPEG", (".jpg", ".jpeg"), _scan_image, _read_image, magic=(b"\xff\xd8\xff",),
    note="JPEG files; lossy compression adds block artefacts that the noise floor does not "
         "model: prefer TIFF or PNG"))
register_format(ImageFormat("video", VIDEO_EXTENSIONS, _scan_video, _read_video, kind="video",
                            stack=True, magic=(b"\x1aE\xdf\xa3", b"RIFF")))
