"""The image formats a series is read from, one registration each.

A format is the module that reads it and one call of :func:`register_format`: its name,
its file suffixes, its leading bytes, how its headers are scanned and its frames read,
and what it can hold (several frames, frame times). :func:`~gridstrain.io.open_series`,
:func:`~gridstrain.io.read_mask` and the listing of a folder find a file's format here by
its suffix and name no format themselves.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validation import check_type

__all__ = ["ImageFormat", "register_format", "unregister_format"]

# How error messages group the suffixes: "supported image files are ..., videos ...,
# and camera records ..."
KINDS = ("image", "video", "camera")

# Leading bytes read to name a file's true format when it fails to read as its suffix says.
_SNIFF_BYTES = 16


@dataclass(frozen=True)
class FileInfo:
    """What a format's scan found in one file's headers (no pixel data read)."""

    path: Path
    shapes: tuple[tuple[int, int], ...]  # one per frame
    dtypes: tuple[np.dtype, ...]
    channels: tuple[int, ...] = ()  # samples per pixel of each frame (1: grey)
    bits: int | None = None  # significant bits the header states, if it does
    codec: str | None = None  # a video's codec
    # frame times: a video's, s from its first frame; a camera record's, s from the trigger
    times: tuple[float, ...] = ()
    # the header's bits are the camera's significant bits, not a storage width
    header_bits: bool = False
    note: str = ""  # what the user should know of how its header was read
    format: str = ""  # the name of the format that scanned it (set by scan_file)


@dataclass(frozen=True)
class ImageFormat:
    """One image format gridstrain reads series from.

    Attributes
    ----------
    name : str
        Unique name (``"TIFF"``, ``"Phantom cine"``), stored with each file of a series.
    suffixes : tuple of str
        File name suffixes, lower case with the dot (``".tif"``); compared
        case-insensitively, each claimed by one format.
    scan : callable
        ``scan(path, name, allow_bool) -> FileInfo``: the file's frames, their shapes,
        pixel types and channels from its headers, every frame checked; ``name`` is
        the series' for messages, ``allow_bool`` accepts 1-bit pages (masks).
    read : callable
        ``read(path, pages, wheres, name)``: an iterator over the frames ``pages``
        (increasing indices) of ``path`` as raw arrays, one at a time; ``wheres``
        describes each frame for messages.
    kind : {"image", "video", "camera"}
        How error messages list the suffix.
    magic : tuple of bytes
        Leading bytes of the format's files (any one of them), to name the true
        format of a file misnamed by its suffix.
    stack : bool
        A file may hold several frames.
    timing : callable, optional
        ``timing(path, name)`` of a format whose header states its frame times: an
        object with ``frame_rate`` (frames saved per second, or None) and
        ``trigger_frame`` (index of the trigger's frame, or None).
    note : str
        What a user should know of frames read from such files, given once per series.
    """

    name: str
    suffixes: tuple[str, ...]
    scan: Callable[..., FileInfo]
    read: Callable[..., Iterator[np.ndarray]]
    kind: str = "image"
    magic: tuple[bytes, ...] = ()
    stack: bool = False
    timing: Callable | None = None
    note: str = ""

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        suffixes = (self.suffixes,) if isinstance(self.suffixes, str) else self.suffixes
        suffixes = tuple(suffixes)
        if not suffixes or not all(isinstance(s, str) and s.startswith(".") and len(s) > 1
                                   for s in suffixes):
            raise ValueError(f"suffixes must be file name suffixes such as '.tif', got "
                             f"{self.suffixes!r}")
        object.__setattr__(self, "suffixes", tuple(s.lower() for s in suffixes))
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {', '.join(map(repr, KINDS))}, got "
                             f"{self.kind!r}")
        for attr in ("scan", "read"):
            if not callable(getattr(self, attr)):
                raise TypeError(f"{attr} must be callable, got "
                                f"{type(getattr(self, attr)).__name__}")
        if self.timing is not None and not callable(self.timing):
            raise TypeError(f"timing must be callable or None, got "
                            f"{type(self.timing).__name__}")
        if not all(isinstance(m, bytes) and m for m in self.magic):
            raise ValueError(f"magic must be a tuple of non-empty bytes, got {self.magic!r}")


# In registration order: the order error messages list the suffixes in.
_FORMATS: dict[str, ImageFormat] = {}


def register_format(fmt: ImageFormat, *, replace: bool = False) -> ImageFormat:
    """Make gridstrain read the files of ``fmt`` (see :class:`ImageFormat`).

    ``replace=True`` replaces a format registered under the same name. A suffix
    another format claims is refused. Returns ``fmt``.
    """
    check_type(fmt, "fmt", ImageFormat)
    if fmt.name in _FORMATS and not replace:
        raise ValueError(f"fmt: a format named {fmt.name!r} is already registered (pass "
                         "replace=True to replace it)")
    for other in _FORMATS.values():
        clash = set(other.suffixes) & set(fmt.suffixes)
        if other.name != fmt.name and clash:
            raise ValueError(f"fmt: suffix {sorted(clash)[0]!r} of {fmt.name!r} is read "
                             f"as {other.name!r} already")
    _FORMATS[fmt.name] = fmt
    return fmt


def unregister_format(name: str) -> None:
    """Stop reading the files of the format registered as ``name``."""
    if name not in _FORMATS:
        raise ValueError(f"name: no format named {name!r} is registered; registered: "
                         f"{', '.join(_FORMATS)}")
    del _FORMATS[name]


def format_of(path: Path) -> ImageFormat | None:
    """The format that reads ``path``, by its suffix; None when none does."""
    suffix = path.suffix.lower()
    for fmt in _FORMATS.values():
        if suffix in fmt.suffixes:
            return fmt
    return None


def format_named(name: str) -> ImageFormat:
    """The format registered as ``name`` (that of a file of an open series)."""
    try:
        return _FORMATS[name]
    except KeyError:
        raise ValueError(f"the image format {name!r} of this series is no longer "
                         "registered") from None


def suffixes(kind: str) -> tuple[str, ...]:
    """The suffixes of the formats of ``kind``, in registration order."""
    return tuple(s for fmt in _FORMATS.values() if fmt.kind == kind for s in fmt.suffixes)


def is_readable_name(path: Path) -> bool:
    """Whether a registered format reads files named like ``path``."""
    return format_of(path) is not None


def check_suffix(path: Path, name: str) -> None:
    """Refuse a file no registered format reads, listing the suffixes that are read."""
    if not is_readable_name(path):
        raise ValueError(f"{name}: {path} has extension {path.suffix!r}; supported image "
                         f"files are {', '.join(suffixes('image'))}, videos "
                         f"{', '.join(suffixes('video'))}, and camera records "
                         f"{', '.join(suffixes('camera'))}")


def _sniff(path: Path) -> ImageFormat | None:
    """The format whose leading bytes ``path`` starts with, or None."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    except OSError:
        return None
    for fmt in _FORMATS.values():
        if any(head.startswith(m) for m in fmt.magic):
            return fmt
    return None


def scan_file(path: Path, name: str, *, allow_bool: bool = False) -> FileInfo:
    """The headers of ``path`` read by its format (its suffix checked before), every
    frame checked. A file that its format cannot read but whose leading bytes are
    another format's is named as such."""
    fmt = format_of(path)
    try:
        info = fmt.scan(path, name, allow_bool)
    except OSError as exc:
        other = _sniff(path) if type(exc) is OSError else None
        if other is not None and other is not fmt:
            raise OSError(f"{exc}; its first bytes are those of a {other.name} file "
                          f"({', '.join(other.suffixes)})") from exc
        raise
    return dataclasses.replace(info, format=fmt.name)
