"""Writing a series of frames as numbered TIFF files, each written atomically.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import tifffile

from .._validation import as_path, check_int
from ._files import make_directory, write_atomic


def write_tiff_series(directory, frames: Iterable, *, prefix: str = "frame",
                      dtype=np.uint16, start: int = 0, digits: int | None = None,
                      overwrite: bool = False) -> tuple[Path, ...]:
    """Write frames as numbered single-page TIFFs, as a camera fills a folder.

    Parameters
    ----------
    directory : str or os.PathLike
        Destination folder, created if missing (its parent must exist).
    frames : iterable of (H, W) array_like
        Grey levels; consumed one at a time (a generator keeps memory low).
    prefix : str
        File name prefix: ``{prefix}{number}.tif``.
    dtype : {numpy.uint16, numpy.uint8, numpy.float32, numpy.float64}
        Stored type. Integer types round to the nearest grey level and refuse
        values outside their range (clip beforehand to simulate saturation; multiply
        12-bit values by 16 beforehand to mimic PCO files).
    start : int
        Number of the first file.
    digits : int, optional
        Zero-padded width of the numbers; default: enough for ``len(frames)``, at
        least 4 (6 when ``frames`` has no length).
    overwrite : bool
        Replace existing files of the same names.

    Returns
    -------
    tuple of pathlib.Path
        The files written, in order. Each is written atomically; if a frame is
        refused, the files written before it stay.
    """
    if not isinstance(prefix, str) or "/" in prefix or os.sep in prefix:
        raise ValueError(f"prefix must be a file name prefix without path separators, "
                         f"got {prefix!r}")
    try:
        dt = np.dtype(dtype)
    except TypeError:
        dt = None
    allowed = tuple(np.dtype(t) for t in (np.uint8, np.uint16, np.float32, np.float64))
    if dt not in allowed:
        raise ValueError(f"dtype must be one of uint8, uint16, float32, float64, got "
                         f"{dtype!r}")
    start = check_int(start, "start", minimum=0)
    if digits is None:
        digits = max(4, len(str(start + len(frames) - 1))) if hasattr(frames, "__len__") \
            else 6
    else:
        digits = check_int(digits, "digits", minimum=1)
    folder = as_path(directory, "directory")
    if not folder.is_dir():
        if not folder.parent.is_dir():
            raise FileNotFoundError(f"cannot create directory {folder}: its parent "
                                    f"{folder.parent} does not exist")
        make_directory(folder)
    written = []
    for k, frame in enumerate(frames):
        arr = np.asarray(frame)
        label = f"frames[{k}]"
        if arr.ndim != 2 or arr.dtype.kind not in "buif":
            raise ValueError(f"{label} must be a 2-D numeric array, got {arr.dtype} "
                             f"array of shape {arr.shape}")
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise ValueError(f"{label} has NaN or infinite values")
        if dt.kind == "u":
            if arr.dtype.kind == "f":
                arr = np.rint(arr)
            lo, hi = np.iinfo(dt).min, np.iinfo(dt).max
            if arr.size and (arr.min() < lo or arr.max() > hi):
                raise ValueError(f"{label} has values in [{arr.min()}, {arr.max()}], "
                                 f"outside the {dt} range [{lo}, {hi}]")
        out = arr.astype(dt, copy=False)
        dest = folder / f"{prefix}{start + k:0{digits}d}.tif"
        write_atomic(dest, lambda fh, out=out: tifffile.imwrite(fh, out,
                                                                photometric="minisblack"),
                     overwrite=overwrite)
        written.append(dest)
    return tuple(written)
