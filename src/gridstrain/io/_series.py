"""Reading image series and masks (see :mod:`gridstrain.io`)."""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from itertools import groupby
from pathlib import Path

import numpy as np
import numpy.typing as npt

from .._progress import Finding
from .._runtime import memory as _memory
from .._validation import (
    as_path,
    check_callable,
    check_float_dtype,
    check_fraction,
    check_int,
    check_mask,
    check_name,
    check_shape,
    check_type,
)
from ._formats import FileInfo, check_suffix, format_named, scan_file
from ._readers import (
    _LOSSLESS_CODECS,
    _describe,
    _resolve_source,
    to_luminance,
)

# Number of leading frames inspected to recognise 12-bit data stored x16 in 16-bit
# files. A frame of N noisy pixels from a true 16-bit camera has probability
# 16**-N of holding only multiples of 16, so one frame would already do; three
# guard against a black first frame.
_DETECT_FRAMES = 3
_PCO_SCALE = 16

# Attribute listing which HDF5 attributes hold JSON text (lists, dicts, None), so
# that read_hdf5 can decode them and leave ordinary strings alone.
_JSON_ATTRS = "_json_attrs"
_UNITS_ATTR = "units"

_FloatDType = npt.DTypeLike


# --------------------------------------------------------------------------- series


@dataclass(frozen=True, repr=False)
class FrameSeries:
    """An ordered series of 2-D grey-level frames stored in image files.

    Built by :func:`open_series`, which checks every file; the frames themselves
    are read only when asked for, one at a time.

    Attributes
    ----------
    name : str
        Name used in error messages (``"reference"``, ``"deformed"``...).
    paths : tuple of pathlib.Path
        The files, in frame order (one file may hold several frames).
    shape : tuple of int
        ``(H, W)`` of every frame, px.
    dtype : numpy.dtype
        The stored pixel type.
    bit_depth : int or None
        Significant bits of the sensor: 8, 12 (12-bit data stored x16 in 16-bit
        files, or declared through ``open_series(bit_depth=...)``), 16, ...;
        the bits of the positive range for signed integers (15 for int16);
        ``None`` for float data.
    scale : int
        Raw value of one sensor grey level: 16 for 12-bit data stored x16 in
        16-bit files, otherwise 1.
    saturation_level : int or None
        Largest raw value the sensor can produce (255, 4095 * 16 = 65520, 4095,
        65535...); ``None`` for float data, whose saturation level is unknown.
    channels : int
        Samples per pixel in the files: 1 for grey frames; 2, 3 or 4 for colour
        frames (grey+alpha, RGB, RGBA), read as their luminance
        (:func:`to_luminance`, float64; ``dtype`` is then float64 and the bit
        depth and saturation level are those of one channel).
    notes : tuple of Finding
        What the user should know about how the frames were read (colour
        conversion, lossy JPEG compression), each a finding of code ``input``
        (:class:`gridstrain.Finding`, its sentence the ``str``); the pipeline records
        them in the result's warnings.
    """

    name: str
    paths: tuple[Path, ...]
    shape: tuple[int, int]
    dtype: np.dtype
    bit_depth: int | None
    scale: int
    saturation_level: int | None
    # (file index, page index, number of pages in that file) of every frame
    _frames: tuple[tuple[int, int, int], ...] = field(default=(), compare=True)
    # the name of each file's format (gridstrain.io._formats)
    _formats: tuple[str, ...] = field(default=(), compare=False)
    # each frame's time stamp in its file, s (videos that hold them), else ()
    _times: tuple[float, ...] = field(default=(), compare=False)
    channels: int = 1
    notes: tuple[Finding, ...] = ()
    # number of every frame in the series it was taken from (subset); () : 0, 1, ...
    _numbers: tuple[int, ...] = field(default=(), compare=True)

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return len(self._frames)

    @property
    def times(self) -> np.ndarray | None:
        """(n_frames,) time of each frame, s, where its file says it: from the first
        frame of a video; from the trigger in a camera record (Phantom cine, Photron
        MRAW; negative before it), its time stamps or its frame numbers over its frame
        rate. None otherwise."""
        return np.array(self._times, dtype=np.float64) if self._times else None

    @property
    def frame_rate(self) -> float | None:
        """Frames per second saved, from the header of a camera record (Phantom cine,
        Photron MRAW; the record rate over the save step of a record saved every n-th
        frame); else None."""
        timing = self._timing()
        return None if timing is None else timing.frame_rate

    @property
    def trigger_frame(self) -> int | None:
        """Index in this series of the frame taken at the trigger, from the header of
        a camera record holding every frame (its frame numbered 0); else None."""
        timing = self._timing()
        if timing is None:
            return None
        k = timing.trigger_frame
        pages = [page for _, page, _ in self._frames]
        return pages.index(k) if k in pages else None

    def _timing(self):
        """What the header of a single record says of its timing (its format's
        ``timing``), or None."""
        if len(self.paths) != 1 or not self._formats:
            return None
        fmt = format_named(self._formats[0])
        return None if fmt.timing is None else fmt.timing(self.paths[0], self.name)

    def __len__(self) -> int:
        return len(self._frames)

    def __repr__(self) -> str:
        first = self.paths[0] if self.paths else None
        return (f"FrameSeries(name={self.name!r}, n_frames={self.n_frames}, "
                f"shape={self.shape}, dtype={self.dtype}, bit_depth={self.bit_depth}, "
                f"scale={self.scale}, saturation_level={self.saturation_level}, "
                f"files={len(self.paths)}, first={str(first)!r})")

    def _index(self, i) -> int:
        i = check_int(i, "frame index", minimum=None)
        n = self.n_frames
        j = i + n if i < 0 else i
        if not 0 <= j < n:
            raise ValueError(f"{self.name}: frame index must be in [0, {n}) (or negative "
                             f"from the end), got {i}")
        return j

    def source_of(self, i: int) -> tuple[Path, int]:
        """File and page index holding frame ``i``."""
        f, page, _ = self._frames[self._index(i)]
        return self.paths[f], page

    def describe_frame(self, i: int) -> str:
        """``"frame i (file[, page k])"``, for messages (``i`` numbered in the
        series a :meth:`subset` was taken from)."""
        j = self._index(i)
        f, page, n_pages = self._frames[j]
        return f"frame {self._number(j)} ({_describe(self.paths[f], page, n_pages)})"

    def _number(self, j: int) -> int:
        return self._numbers[j] if self._numbers else j

    def subset(self, indices) -> FrameSeries:
        """The series of the frames ``indices`` only, in the order given.

        Messages keep naming each frame by its number in this series, so that a
        frame excluded or reported later is the one the user sees in the folder.

        Parameters
        ----------
        indices : sequence of int
            Frame indices, ``0 <= i < n_frames``, at least one.
        """
        idx = [self._index(i) for i in indices]
        if not idx:
            raise ValueError(f"{self.name}: a subset must keep at least one frame, got none")
        return dataclasses.replace(self, _frames=tuple(self._frames[j] for j in idx),
                                   _numbers=tuple(self._number(j) for j in idx))

    # -- reading

    def _iter_raw(self, indices: Iterable[int]) -> Iterator[tuple[str, np.ndarray]]:
        """Yield ``(description, raw frame)``, opening each file once per run."""
        locs = [(self._number(j), *self._frames[j]) for j in indices]
        for f, group in groupby(locs, key=lambda loc: loc[1]):
            path = self.paths[f]
            group = list(group)
            pages = [page for _, _, page, _ in group]
            wheres = [f"frame {j} ({_describe(path, page, n_pages)})"
                      for j, _, page, n_pages in group]
            # the frames read one at a time, as the loop asks
            frames = format_named(self._formats[f]).read(path, pages, wheres, self.name)
            with contextlib.closing(frames):
                for where, raw in zip(wheres, frames, strict=True):
                    yield where, self._checked(raw, where)

    def _checked(self, raw: np.ndarray, where: str) -> np.ndarray:
        if self.channels > 1 and raw.ndim == 3 and self.channels in (raw.shape[0],
                                                                     raw.shape[-1]):
            raw = to_luminance(raw, axis=-1 if raw.shape[:2] == self.shape else 0)
        if raw.shape != self.shape or raw.dtype != self.dtype:
            # headers were checked by open_series: the file changed since
            raise ValueError(f"{self.name}: {where} is now {raw.shape} {raw.dtype}, "
                             f"expected {self.shape} {self.dtype} (file changed since "
                             "the series was opened?)")
        if raw.dtype.kind == "f" and not np.all(np.isfinite(raw)):
            bad = int(np.count_nonzero(~np.isfinite(raw)))
            raise ValueError(f"{self.name}: {where} has {bad} NaN or infinite pixel(s); "
                             "frames must hold finite grey levels")
        return raw

    def _to_units(self, raw: np.ndarray, where: str, to_sensor_units: bool) -> np.ndarray:
        if to_sensor_units and self.scale != 1 and np.any(raw % self.scale):
            raise ValueError(f"{self.name}: {where} holds raw values that are not "
                             f"multiples of {self.scale}, unlike the first frames that "
                             f"set scale={self.scale}; open the series with "
                             "bit_depth=16 to read raw values")
        return raw

    def _convert(self, raw: np.ndarray, where: str, dtype: np.dtype | None,
                 to_sensor_units: bool) -> np.ndarray:
        raw = self._to_units(raw, where, to_sensor_units)
        s = self.scale if to_sensor_units else 1
        if dtype is None:
            return raw // s if s != 1 else raw
        out = raw.astype(dtype, copy=False)
        # dividing by a power of two is exact in floating point
        return out / dtype.type(s) if s != 1 else out

    def read(self, i: int, *, dtype: _FloatDType = np.float64,
             to_sensor_units: bool = False) -> np.ndarray:
        """Read frame ``i``.

        Parameters
        ----------
        i : int
            Frame index, ``0 <= i < n_frames`` (negative counts from the end).
        dtype : {numpy.float64, numpy.float32, None}
            Type of the returned array; ``None`` keeps the stored type.
        to_sensor_units : bool
            Divide the raw values by :attr:`scale` (sensor grey levels). Raises
            ``ValueError`` if the frame holds values that are not multiples of it.

        Returns
        -------
        (H, W) ndarray
            Grey levels, raw unless ``to_sensor_units``.
        """
        j = self._index(i)
        dt = check_float_dtype(dtype)
        gen = self._iter_raw([j])
        try:
            where, raw = next(gen)
        finally:
            gen.close()  # close the file now, not when the generator is collected
        return self._convert(raw, where, dt, bool(to_sensor_units))

    def frames(self, *, dtype: _FloatDType = np.float64, to_sensor_units: bool = False,
               start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
        """Iterate over the frames, one array alive at a time.

        Multi-page TIFFs are read page by page from one open file, so memory stays
        bounded by one frame whatever the series length.

        Parameters
        ----------
        dtype : {numpy.float64, numpy.float32, None}
            Type of the yielded arrays; ``None`` keeps the stored type.
        to_sensor_units : bool
            See :meth:`read`.
        start, stop : int
            Range of frame indices, as ``range(start, stop)`` (``stop=None``: to the
            end).

        Yields
        ------
        (H, W) ndarray
            A new array per frame (the caller may modify it).
        """
        dt = check_float_dtype(dtype)
        idx = self._range(start, stop)
        # a plain function returning a generator: arguments are checked on the call,
        # not on the first ``next``
        return (self._convert(raw, where, dt, bool(to_sensor_units))
                for where, raw in self._iter_raw(idx))

    def _range(self, start, stop) -> range:
        n = self.n_frames
        start = check_int(start, "start", minimum=None)
        stop = n if stop is None else check_int(stop, "stop", minimum=None)
        if not 0 <= start < stop <= n:
            raise ValueError(f"{self.name}: frame range must satisfy 0 <= start < stop <= "
                             f"{n}, got start={start}, stop={stop}")
        return range(start, stop)

    def mean(self, *, dtype: _FloatDType = np.float64, to_sensor_units: bool = False,
             start: int = 0, stop: int | None = None,
             progress: Callable[[float, str], None] | None = None) -> np.ndarray:
        """Pixel-wise mean of the frames, streamed.

        Frames are added one at a time into a float64 accumulator (exact for integer
        data up to 2**53 / 65535 ~ 1.4e11 frames of 16 bits), then divided once by
        the number of frames.

        Parameters
        ----------
        dtype : {numpy.float64, numpy.float32}
            Type of the result (the accumulation is float64 either way).
        to_sensor_units : bool
            Average in sensor grey levels (see :meth:`read`).
        start, stop : int
            Range of frames averaged, as in :meth:`frames`.
        progress : callable, optional
            ``progress(fraction, message)``, called once before the first frame
            and after each frame.

        Returns
        -------
        (H, W) ndarray of ``dtype``
            Mean grey level, raw unless ``to_sensor_units``.
        """
        dt = check_float_dtype(dtype, allow_none=False)
        check_callable(progress, "progress")
        idx = self._range(start, stop)
        acc = np.zeros(self.shape, dtype=np.float64)
        n = len(idx)
        if progress is not None:
            progress(0.0, f"{self.name}: averaging {n} frame(s)")
        for k, (where, raw) in enumerate(self._iter_raw(idx), start=1):
            self._to_units(raw, where, bool(to_sensor_units))
            np.add(acc, raw, out=acc)
            if progress is not None:
                progress(k / n, f"{self.name}: averaged frame {k}/{n}")
        acc /= n
        if to_sensor_units and self.scale != 1:
            # scaling by a power of two commutes with rounding: same bits as
            # averaging frames already divided by the scale
            acc /= self.scale
        return acc.astype(dt, copy=False)


def _depth(dtype: np.dtype, first: list[np.ndarray], declared: int | None, path: Path,
           name: str) -> tuple[int | None, int, int | None]:
    """``(bit_depth, scale, saturation_level)`` from the stored type and first frames."""
    if dtype.kind == "f":
        if declared is not None:
            raise ValueError(f"bit_depth applies to integer images; {path} holds {dtype} "
                             f"pixels, got bit_depth={declared!r}")
        return None, 1, None
    bits = 8 * dtype.itemsize
    if dtype.kind == "i":
        if declared is not None and declared != bits - 1:
            raise ValueError(f"bit_depth can only be declared for unsigned images; {path} "
                             f"holds {dtype} pixels, got bit_depth={declared!r}")
        return bits - 1, 1, int(np.iinfo(dtype).max)
    vmax = max(int(f.max()) for f in first)
    if declared is None:
        # 12-bit sensor data stored x16 in 16-bit files (PCO; the paper's Fig. 1)
        if bits == 16 and vmax > 0 and vmax <= 4095 * _PCO_SCALE and not any(
                np.any(f % _PCO_SCALE) for f in first):
            return 12, _PCO_SCALE, 4095 * _PCO_SCALE
        return bits, 1, int(np.iinfo(dtype).max)
    declared = check_int(declared, "bit_depth")
    if not 1 <= declared <= bits:
        raise ValueError(f"bit_depth must be an integer in [1, {bits}] for {dtype} images, "
                         f"got {declared!r}")
    if declared == bits:
        return bits, 1, int(np.iinfo(dtype).max)
    shift = 2 ** (bits - declared)
    top = 2**declared - 1
    # left-aligned (stored x shift) takes precedence: right-aligned noisy data are
    # multiples of the shift with negligible probability
    if vmax > 0 and vmax <= top * shift and not any(np.any(f % shift) for f in first):
        return declared, shift, top * shift
    if vmax <= top:
        return declared, 1, top
    raise ValueError(f"{name}: bit_depth={declared} does not fit {path}: values reach "
                     f"{vmax} > {top} and are not all multiples of {shift}")


def open_series(source, *, name: str = "series", bit_depth: int | None = None
                ) -> FrameSeries:
    """Open a series of grey-level frames from image files.

    Every file is opened and its header checked (size, pixel type, channels);
    pixel data are read later, one frame at a time, except the first few frames
    used to recognise the bit depth.

    Parameters
    ----------
    source : path, glob pattern or list of paths
        - an image file (``.tif``/``.tiff``/``.png``/``.bmp``): one frame, or one
          frame per page for a multi-page TIFF;
        - a directory: every image file in it, in natural order (``f2`` before
          ``f10``); files with other extensions, hidden files and sub-directories
          are ignored;
        - a string with ``*``, ``?`` or ``[`` that names no existing path: a glob
          pattern, matches in natural order of their full path, non-image matches
          ignored;
        - a video (``.avi``/``.mp4``/``.mov``/``.mkv``, the ``video`` extra): one
          frame per video frame;
        - a high-speed camera record: a Phantom cine (``.cine``) or a Photron MRAW
          (``.mraw``, its ``.cihx`` or ``.cih`` header beside it), one frame per
          recorded frame, grey records only;
        - a list or tuple of image files, read in the order given.
    name : str
        What the series is, for error messages (``"reference"``...).
    bit_depth : int, optional
        Significant bits of unsigned integer data, when known. By default a camera
        record's header gives them (``RealBPP``, ``EffectiveBit Depth``) and 16-bit
        files whose first frames hold only multiples of 16 are taken as 12-bit data
        stored x16 (``scale = 16``, saturation 65520); other files use their full
        range. ``bit_depth=12`` also accepts right-aligned 12-bit data (values up to
        4095, saturation 4095); ``bit_depth=16`` turns the detection off.

    Returns
    -------
    FrameSeries

    Raises
    ------
    FileNotFoundError
        A path does not exist, or a glob pattern matches nothing.
    OSError
        A file is not a readable image (corrupt or truncated TIFF...).
    ValueError
        No image in a directory; frames of different sizes or pixel types (the
        first offending file is named, with both values); colour, 1-D or 3-D
        images; a ``bit_depth`` that does not fit the data.

    Notes
    -----
    Frames are neither flipped nor rotated: ``frame[row, col]`` is the stored pixel,
    as in :mod:`gridstrain.conventions`. NaN checks of float data happen when the
    frames are read.

    Examples
    --------
    >>> series = open_series("run3/*.tif", name="deformed")  # doctest: +SKIP
    >>> mean = series.mean()  # doctest: +SKIP
    """
    name = check_name(name, "name")
    paths = _resolve_source(source, name)
    infos = [scan_file(p, name) for p in paths]
    ref = infos[0]
    stored, channels = ref.dtypes[0], ref.channels[0]
    frames = _frame_table(infos, name)
    # colour frames are read as their luminance, in float64
    dtype = np.dtype(np.float64) if channels > 1 else stored
    series = FrameSeries(name=name, paths=paths, shape=ref.shapes[0], dtype=dtype,
                         bit_depth=None, scale=1, saturation_level=None, _frames=frames,
                         _formats=tuple(info.format for info in infos),
                         _times=_frame_times(infos),
                         channels=channels, notes=_reading_notes(infos, channels, name))
    first = []
    if stored.kind == "u":
        n = min(_DETECT_FRAMES, series.n_frames)
        _check_decoded(paths[0], ref.shapes[0], stored, channels, n, name)
        first = [raw for _, raw in series._iter_raw(range(n))]
        if bit_depth is None and ref.bits is not None and (
                ref.header_bits or ref.bits < 8 * stored.itemsize):
            # packed data (10-bit, 12-bit TIFFs) and camera records say their depth
            bit_depth = ref.bits
    bits, scale, sat = _depth(stored, first, bit_depth, paths[0], name)
    return dataclasses.replace(series, bit_depth=bits, scale=scale, saturation_level=sat)


def split_frames(series: FrameSeries) -> list[FrameSeries]:
    """Every frame of ``series`` as a one-frame series of its own, in order.

    Each is named after its file's stem, with the page for a file of several pages
    (``"record[7]"``, pages numbered from 0); its messages still number the frame
    in ``series``. The bit depth found on ``series`` applies to every frame (one
    detection for the whole record), and its reading notes go with the first only.

    Parameters
    ----------
    series : FrameSeries

    Returns
    -------
    list of FrameSeries
        ``series.n_frames`` series of one frame, each holding one file.
    """
    check_type(series, "series", FrameSeries)
    out = []
    for j, (f, page, n_pages) in enumerate(series._frames):
        path = series.paths[f]
        name = f"{path.stem}[{page}]" if n_pages > 1 else path.stem
        out.append(dataclasses.replace(
            series, name=name, paths=(path,), _frames=((0, page, n_pages),),
            _formats=(series._formats[f],), _numbers=(series._number(j),),
            _times=(series._times[j],) if series._times else (),
            notes=series.notes if j == 0 else ()))
    return out


def _check_decoded(path: Path, shape, dtype: np.dtype, channels: int, n: int,
                   name: str) -> None:
    """Refuse, from its header, a file whose frames decode to more than the available
    memory (a small compressed file may declare an image of many gigabytes)."""
    H, W = shape
    frame = H * W * channels * dtype.itemsize
    _memory.check_fits(n * frame + 8 * H * W,
                       what=f"{name}: decoding {path} ({H} x {W} px of {dtype}, as its "
                       "header declares)",
                       advice="check that the file is the camera's image; crop the frames, "
                       "or raise --memory-budget (memory_budget) if more memory is in fact "
                       "free")


def _frame_times(infos: list[FileInfo]) -> tuple[float, ...]:
    """Every frame's time stamp, s, when every file holds them (a single video)."""
    if len(infos) != 1 or not infos[0].times:
        return ()
    return infos[0].times


def _frame_table(infos: list[FileInfo], name: str) -> tuple[tuple[int, int, int], ...]:
    """``(file index, page index, pages in that file)`` of every frame, once every page
    is checked to match the first one's channels, size and pixel type."""
    ref = infos[0]
    shape, stored, channels = ref.shapes[0], ref.dtypes[0], ref.channels[0]
    first = _describe(ref.path, 0, len(ref.shapes))
    frames = []
    for f, info in enumerate(infos):
        n_pages = len(info.shapes)
        for k, (s, d, c) in enumerate(zip(info.shapes, info.dtypes, info.channels,
                                          strict=True)):
            where = _describe(info.path, k, n_pages)
            if c != channels:
                raise ValueError(f"{name}: frames with different channels: {where} has {c} "
                                 f"per pixel but {first} has {channels}")
            if s != shape:
                raise ValueError(f"{name}: frames of different sizes: {where} is {s} but "
                                 f"{first} is {shape} (H, W)")
            if d != stored:
                raise ValueError(f"{name}: frames of different pixel types: {where} holds "
                                 f"{d} but {first} holds {stored}")
            frames.append((f, k, n_pages))
    return tuple(frames)


def _reading_notes(infos: list[FileInfo], channels: int, name: str) -> tuple[Finding, ...]:
    """What the user should know about how the frames are read (colour, JPEG, lossy
    video codecs, a camera header's times left out), as findings of code ``input``
    whose figure ``reading`` says which: ``"lossy codec"`` (with ``codecs``),
    ``"luma"``, ``"colour"`` (with ``channels``), ``"format"`` (with ``format``) or
    ``"file"`` (a file's own note, with ``file``)."""
    notes = []
    lossy = sorted({i.codec for i in infos if i.codec and i.codec not in _LOSSLESS_CODECS})
    if lossy:
        notes.append(Finding(
            "input", f"{name}: video frames compressed by the lossy codec(s) "
            f"{', '.join(lossy)}; compression artefacts add noise the noise floor "
            "does not model and may bias the phase: record with a lossless codec or as TIFF",
            state=name, reading="lossy codec", codecs=lossy))
    if any(i.codec for i in infos):
        notes.append(Finding("input", f"{name}: video frames read as the grey levels of "
                             "their luma plane", state=name, reading="luma"))
    if channels > 1:
        what = {2: "grey and alpha", 3: "RGB", 4: "RGBA"}[channels]
        how = ("the grey channel kept" if channels == 2 else "converted to luminance "
               "0.2126 R + 0.7152 G + 0.0722 B (ITU-R BT.709), alpha ignored")
        notes.append(Finding("input", f"{name}: colour frames ({what}), {how}", state=name,
                             reading="colour", channels=channels))
    formats = dict.fromkeys(i.format for i in infos)  # each once, in file order
    notes += [Finding("input", f"{name}: {format_named(f).note}", state=name,
                      reading="format", format=f) for f in formats if format_named(f).note]
    notes += [Finding("input", f"{name}: {i.note}", state=name, reading="file",
                      file=Path(i.path).name) for i in infos if i.note]
    return tuple(notes)


# --------------------------------------------------------------------------- saturation


def check_saturation(frame, series: FrameSeries, *, mask=None,
                     to_sensor_units: bool = False) -> float:
    """Fraction of the pixels of ``frame`` at the sensor's saturation level.

    Parameters
    ----------
    frame : (H, W) array_like
        A frame of ``series`` in raw grey levels, as returned by
        :meth:`FrameSeries.read` (or in sensor grey levels if ``to_sensor_units``).
    series : FrameSeries
        Gives the saturation level.
    mask : (H, W) bool array_like, optional
        Count only these pixels (the specimen; :mod:`gridstrain.conventions`).
    to_sensor_units : bool
        ``frame`` was read with ``to_sensor_units=True``.

    Returns
    -------
    float
        Saturated pixels (value >= saturation level) over counted pixels, in
        [0, 1]. Always 0.0 for float series, whose saturation level is unknown.
    """
    check_type(series, "series", FrameSeries)
    arr = np.asarray(frame)
    if arr.shape != series.shape:
        raise ValueError(f"frame must have the series shape {series.shape}, got {arr.shape}")
    m = None if mask is None else check_mask(mask, series.shape)
    if series.saturation_level is None:
        return 0.0
    level = series.saturation_level / (series.scale if to_sensor_units else 1)
    sat = arr >= level
    if m is None:
        return float(np.count_nonzero(sat)) / sat.size
    return float(np.count_nonzero(sat & m)) / int(np.count_nonzero(m))


def check_saturation_limit(frame, series: FrameSeries, *, max_fraction: float = 0.01,
                           mask=None, index: int | None = None,
                           to_sensor_units: bool = False) -> float:
    """Raise ``ValueError`` if more than ``max_fraction`` of ``frame`` is saturated.

    Saturated pixels clip the grid's sinusoidal profile: the phase there is biased
    and no averaging removes the bias. A few isolated pixels are harmless; a
    larger area calls for a shorter exposure or a mask.

    Parameters
    ----------
    frame, series, mask, to_sensor_units
        As in :func:`check_saturation`.
    max_fraction : float
        Largest acceptable fraction in [0, 1] (default 0.01, i.e. 1 %).
    index : int, optional
        Frame index in ``series``, to name the frame and its file in the message.

    Returns
    -------
    float
        The saturated fraction (at most ``max_fraction``), so that the caller can
        warn about any non-zero value.
    """
    max_fraction = check_fraction(max_fraction, "max_fraction")
    frac = check_saturation(frame, series, mask=mask, to_sensor_units=to_sensor_units)
    if frac > max_fraction:
        where = series.describe_frame(index) if index is not None else "a frame"
        level = series.saturation_level // (series.scale if to_sensor_units else 1)
        units = "sensor" if to_sensor_units else "raw"
        raise ValueError(f"{series.name}: {where} has {frac:.2%} saturated pixels ({units} "
                         f"value >= {level}), more than max_fraction="
                         f"{max_fraction:.2%}; shorten the exposure or mask the saturated "
                         "area")
    return frac


# --------------------------------------------------------------------------- mask


def read_mask(path, shape, *, name: str = "mask") -> np.ndarray:
    """Read a specimen mask from an image file: nonzero pixels are the specimen.

    Grey and 1-bit images: nonzero is the specimen. Colour masks drawn in a paint
    program: with an alpha channel that varies, the pixels that are not fully
    transparent are the specimen (a mask painted on a transparent layer);
    otherwise (RGB, or opaque RGBA) the pixels that are not black.

    Parameters
    ----------
    path : str or os.PathLike
        Single-page grey-level TIFF, PNG or BMP.
    shape : tuple of int
        Expected ``(H, W)``, the frames' shape.
    name : str
        What the mask is, for error messages.

    Returns
    -------
    (H, W) bool ndarray
        ``True`` on the specimen (:mod:`gridstrain.conventions`, Masks).
    """
    name = check_name(name, "name")
    p = as_path(path, name)
    shape = check_shape(shape, "shape")
    if not p.exists():
        raise FileNotFoundError(f"{name}: {p} does not exist")
    if p.is_dir():
        raise ValueError(f"{name}: {p} is a directory, expected an image file")
    check_suffix(p, name)
    info = scan_file(p, name, allow_bool=True)
    if len(info.shapes) != 1:
        raise ValueError(f"{name}: {p} has {len(info.shapes)} pages, expected a single "
                         "image")
    if info.shapes[0] != shape:
        raise ValueError(f"{name}: {p} has shape {info.shapes[0]}, expected {shape} (the "
                         "frames' shape (H, W))")
    _check_decoded(p, shape, info.dtypes[0], info.channels[0], 1, name)
    with contextlib.closing(format_named(info.format).read(p, [0], [str(p)], name)) as frames:
        arr = next(frames)
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: {p} has NaN or infinite pixels")
    c = info.channels[0]
    if c > 1:
        arr = np.moveaxis(arr, 0 if arr.shape[0] == c and arr.shape[1:] == shape else -1, -1)
        alpha = arr[..., -1] if c in (2, 4) else None
        if alpha is not None and alpha.min() != alpha.max():
            m = alpha != 0  # drawn on a transparent layer: the opaque pixels
        else:
            m = np.any(arr[..., :c - 1 if c in (2, 4) else c] != 0, axis=-1)
    else:
        m = arr != 0
    if not m.any():
        raise ValueError(f"{name}: {p} selects no pixel (every pixel is 0)")
    return m


def roi_mask(shape, *, rectangle=None, polygon=None) -> np.ndarray:
    """A region of interest as a mask: a rectangle, a polygon, or both (intersected).

    Parameters
    ----------
    shape : (2,) tuple of int
        ``(H, W)`` of the frames.
    rectangle : (4,) sequence of int, optional
        ``(x0, y0, x1, y1)``, px: columns ``x0 <= x < x1`` and rows
        ``y0 <= y < y1`` (:mod:`gridstrain.conventions`: x is the column).
    polygon : (N, 2) array_like, optional
        Vertices ``(x, y)``, px, ``N >= 3``; pixels whose centre is inside.

    Returns
    -------
    (H, W) bool ndarray
        ``True`` inside the region.
    """
    H, W = (int(v) for v in shape)
    m = np.ones((H, W), dtype=bool)
    if rectangle is not None:
        r = np.asarray(rectangle, dtype=float)
        if r.shape != (4,) or not np.all(np.isfinite(r)) or np.any(r != np.round(r)):
            raise ValueError(f"roi must be four integers x0 y0 x1 y1 (px), got "
                             f"{rectangle!r}")
        x0, y0, x1, y1 = (int(v) for v in r)
        if not (0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H):
            raise ValueError(f"roi {x0} {y0} {x1} {y1} must satisfy 0 <= x0 < x1 <= {W} "
                             f"and 0 <= y0 < y1 <= {H} (inside the {W} x {H} px image)")
        r_mask = np.zeros((H, W), dtype=bool)
        r_mask[y0:y1, x0:x1] = True
        m &= r_mask
    if polygon is not None:
        try:
            v = np.asarray(polygon, dtype=float)
        except (TypeError, ValueError):
            v = None
        if v is None or v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 \
                or not np.all(np.isfinite(v)):
            n = "?" if v is None or v.ndim != 2 else v.shape[0]
            raise ValueError(f"roi polygon must have at least 3 vertices (x, y), got {n}: "
                             f"{polygon!r}")
        from skimage.draw import polygon2mask

        p_mask = polygon2mask((H, W), v[:, ::-1])  # skimage wants (row, col) = (y, x)
        if not p_mask.any():
            raise ValueError(f"roi polygon holds no pixel of the {W} x {H} px image: "
                             f"{v.tolist()}")
        m &= p_mask
    if not m.any():
        raise ValueError("the rectangle and the polygon of the roi do not overlap")
    return m


