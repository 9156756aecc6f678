"""Writing gridstrain's files: atomic writes, HDF5, CSV, TIFF series, output
folders; reading back its own HDF5 and noise files (see :mod:`gridstrain.io`)."""

from __future__ import annotations

import contextlib
import csv
import datetime
import errno
import functools
import hashlib
import io
import json
import os
import platform
import re
import secrets
import socket
import stat
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

import h5py
import numpy as np

from .._validation import as_path, check_int, check_mapping, check_name
from ._hdf5_attrs import _check_hdf5_metadata, _create_dataset, _dataset_arrays, _write_attrs
from ._series import _UNITS_ATTR

# --------------------------------------------------------------------------- output


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def check_destination(path, overwrite: bool, *, what: str = "output file",
                       how: str = "overwrite=True") -> Path:
    """The destination of :func:`atomic_path`, checked before anything is written.

    ``what`` names the file in the messages and ``how`` says how to allow replacing
    it (the command line passes ``--overwrite``).
    """
    dest = as_path(path, "path")
    parent = dest.parent
    if not parent.is_dir() and any(_parents_made):
        # a command's folders, made when it started, removed since by another run
        # that made them too and then failed: made again (and this run's to remove)
        make_directory(parent, parents=True)
    if not parent.is_dir():
        raise FileNotFoundError(f"output directory {parent} does not exist (for the {what} "
                                f"{dest})")
    if os.fspath(parent) not in _swept:  # what a killed run left there, once per process
        _swept.add(os.fspath(parent))
        sweep_temporary_files(parent)
    if dest.is_dir():
        raise IsADirectoryError(f"{what} {dest} is a directory")
    if dest.exists() and not overwrite:
        raise FileExistsError(f"{what} {dest} already exists (pass {how} to replace it)")
    return dest


# --------------------------------------------------------------------------- commits

# What this process commits to disk, told to the observers of watch_outputs() (the
# command line's transaction): ("file", path) once a file is renamed into place,
# ("dir", path) once a directory is made.
_observers: list = []
# One entry per watch_outputs block: whether a file's missing folders are made when it
# is written (the command line's, whose outputs' folders it makes anyway).
_parents_made: list[bool] = []


@contextlib.contextmanager
def watch_outputs(observer, *, make_parents: bool = False) -> Iterator[None]:
    """Call ``observer(kind, path)`` for every output committed inside the block.

    ``kind`` is ``"file"`` when :func:`atomic_path` has renamed a complete file
    onto ``path`` (every file gridstrain writes goes through it) and ``"dir"``
    when :func:`make_directory` has created the directory ``path``. The command
    line records them to remove them all if the run fails afterwards. With
    ``make_parents``, a file's folder missing when it is written is made again
    (:func:`check_destination`): another run that made the same new folder and then
    failed removed it while it was still empty.
    """
    _observers.append(observer)
    _parents_made.append(bool(make_parents))
    try:
        yield
    finally:
        _observers.remove(observer)
        _parents_made.pop()


def _committed(kind: str, path: Path) -> None:
    for observer in tuple(_observers):
        observer(kind, path)


def _refuse_dangling_link(path: Path, what: str) -> None:
    """Refuse ``path`` where it or a parent is a symbolic link to nothing: a folder
    made through it would appear wherever the link points."""
    for d in (path, *path.parents):
        if d.is_symlink() and not d.exists():
            raise FileNotFoundError(f"{what} {path}: {d} is a symbolic link to "
                                    f"{os.readlink(d)}, which does not exist")


def make_directory(path, *, parents: bool = False) -> Path:
    """Create the directory ``path`` if it is missing (with its missing parents if
    ``parents``), telling :func:`watch_outputs` of each directory created; refused
    through a symbolic link to nothing."""
    dest = as_path(path, "path")
    _refuse_dangling_link(dest, "folder")
    missing = []
    for d in (dest, *dest.parents):
        if d.is_dir() or d.is_symlink():
            break
        missing.append(d)
        if not parents:
            break
    for d in reversed(missing):
        try:
            d.mkdir()
        except FileExistsError:
            if not d.is_dir():
                raise
            continue
        _committed("dir", d)
    return dest


# --------------------------------------------------------------------------- temporary files

_swept: set[str] = set()



# --------------------------------------------------------------------------- temporary files


# A temporary file of atomic_path: ".NAME.PID-HOST-RANDOM.tmpSUFFIX". The process id
# and a tag of the machine let a later run tell the files of a process that died
# (killed, or its machine stopped) from those of one still writing.
_TMP_NAME = re.compile(r"\..+\.(\d+)-([0-9a-f]{8})-[0-9a-f]{12}\.tmp(\.[^./]*)?")


@functools.cache
def _host_tag() -> str:
    return hashlib.sha256(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:8]


def _temporary_name(dest: Path) -> Path:
    return dest.parent / (f".{dest.name}.{os.getpid()}-{_host_tag()}-"
                          f"{secrets.token_hex(6)}.tmp{dest.suffix}")


def _process_started(pid: int) -> float | None:
    """When process ``pid`` started (seconds since the epoch), where /proc says it."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        with open("/proc/stat", "rb") as fh:
            btime = next(int(line.split()[1]) for line in fh if line.startswith(b"btime"))
        return btime + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def _writer_gone(pid: int, written: float) -> bool:
    """Whether the process that last wrote a file at time ``written`` has ended: no
    process ``pid``, or one that started after the write (the id was reused)."""
    if pid == os.getpid() or os.name != "posix":
        # (on Windows os.kill would end the process, not probe it)
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # alive, another user's
        pass
    started = _process_started(pid)
    # /proc's boot time is whole seconds: a second of slack
    return started is not None and started > written + 1.0


def sweep_temporary_files(folder) -> list[Path]:
    """Remove the temporary files that dead gridstrain processes left in ``folder``.

    Only regular files of this user named as :func:`atomic_path` names them, made
    on this machine by a process that no longer runs (killed with SIGKILL, or lost
    with its machine), are removed. Called once per folder and process before the
    first file is written there.

    Returns
    -------
    list of pathlib.Path
        The files removed.
    """
    folder = as_path(folder, "folder")
    removed = []
    tag = _host_tag()
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        m = _TMP_NAME.fullmatch(e.name)
        if m is None or m.group(2) != tag:
            continue
        try:
            st = e.stat(follow_symlinks=False)
            if not stat.S_ISREG(st.st_mode) or st.st_uid != getattr(os, "getuid", int)() \
                    or not _writer_gone(int(m.group(1)), st.st_mtime):
                continue
            os.unlink(e.path)
        except OSError:
            continue
        removed.append(Path(e.path))
    return removed


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = False) -> Iterator[Path]:
    """Write a file atomically: yield a temporary path, rename it onto ``path``.

    The temporary path is in the destination directory (so that the final
    :func:`os.replace` is atomic) and does not exist yet: the block creates it. Its
    name holds the process id, so that the next run writing into that directory
    removes it if the process was killed before it could
    (:func:`sweep_temporary_files`). When
    the block completes, the file is flushed to disk and renamed onto ``path``;
    if the block raises, the temporary file is removed and ``path`` is untouched.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    overwrite : bool
        Replace an existing ``path``. Without it, an existing file raises
        ``FileExistsError`` both before the block and, if one appeared meanwhile,
        before the rename.

    Yields
    ------
    pathlib.Path
        Temporary file path, with the same extension as ``path``.

    Raises
    ------
    FileNotFoundError
        The destination directory does not exist, or the block created no file.
    FileExistsError
        ``path`` exists and ``overwrite`` is False.
    IsADirectoryError
        ``path`` is a directory.
    """
    dest = check_destination(path, overwrite)
    # a name that nothing else uses; the writer creates the file itself, with the
    # permissions it would give the destination
    tmp = _temporary_name(dest)
    try:
        yield tmp
        if not tmp.exists():
            raise FileNotFoundError(f"nothing was written to the temporary file for {dest}")
        _fsync(tmp)
        if not overwrite and dest.exists():
            raise FileExistsError(f"output file {dest} appeared while it was being "
                                  "written (pass overwrite=True to replace it)")
        os.replace(tmp, dest)
        _committed("file", dest)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        if isinstance(exc, OSError) and exc.errno in _SPACE_ERRORS:
            raise space_error(exc, dest) from None
        raise


# Write errors that mean "no room for this file": the disk or the quota is full, or
# the file outgrew a size limit (``ulimit -f``, the file system's maximum).
_SPACE_ERRORS = {e for e in (errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", None))
                 if e is not None}


def space_error(exc: OSError, path) -> OSError:
    """A one-line ``OSError`` for a write that ran out of room, naming ``path``.

    ``exc`` is the error of the failed write (ENOSPC, EFBIG or EDQUOT); the result
    keeps its errno and says what it means and what to do.
    """
    code = errno.errorcode.get(exc.errno, str(exc.errno))
    hint = {errno.EFBIG: "the file exceeds the size limit of this process or file "
                         "system (see `ulimit -f`)"}.get(exc.errno, "free some space or "
                                                                     "write elsewhere")
    err = OSError(f"cannot write {path}: {os.strerror(exc.errno).lower()} ({code}); "
                  f"nothing was written; {hint}")
    err.errno = exc.errno  # the message stays one plain line, the code stays testable
    return err


def provenance() -> dict:
    """Who wrote a file and when: the record every file of gridstrain carries.

    Returns
    -------
    dict
        ``gridstrain_version``, ``created`` (UTC, ISO 8601 to the second), and the
        versions of ``python``, ``numpy``, ``scipy`` and ``h5py`` and the
        ``platform``, the libraries whose arithmetic the numbers went through.
    """
    import scipy

    from .. import __version__

    return {
        "gridstrain_version": __version__,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "h5py": h5py.__version__,
        "platform": f"{sys.platform}-{platform.machine()}",
    }


def write_atomic(path, data, *, overwrite: bool = False) -> Path:
    """Write ``data`` (bytes, or a callable filling a binary file) to ``path`` atomically.

    The content is built in memory first and then written with ordinary file calls
    through :func:`atomic_path`, so that a full disk or a file size limit (ENOSPC,
    EDQUOT, EFBIG) raises one ``OSError`` naming ``path`` and leaves nothing
    behind, whatever library produced the bytes (HDF5, TIFF, PNG...).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; see :func:`atomic_path` for ``overwrite``.
    data : bytes-like or callable
        The file content, or ``fill(fh)`` writing it into a binary file object
        (an :class:`io.BytesIO`).
    overwrite : bool
        Replace an existing file.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    dest = as_path(path, "path")
    if callable(data):
        buf = io.BytesIO()
        data(buf)
        data = buf.getbuffer()
    view = memoryview(data).cast("B")
    with atomic_path(dest, overwrite=overwrite) as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            done = 0
            while done < len(view):
                done += os.write(fd, view[done:done + (1 << 24)])
        finally:
            os.close(fd)
    return dest



@contextlib.contextmanager
def hdf5_file(path, *, overwrite: bool = False) -> Iterator[h5py.File]:
    """An HDF5 file open for writing, put at ``path`` atomically when the block ends.

    The one place where gridstrain creates HDF5 files: :func:`write_hdf5` and
    :func:`gridstrain.results.save_result` fill the yielded file; if the block
    raises, nothing appears at ``path``. The file is built in memory (h5py's
    ``core`` driver, no backing store) and its bytes are written by
    :func:`write_atomic` when the block ends: the HDF5 library never writes to
    disk, so that a full disk or a file size limit is one ``OSError`` naming
    ``path`` (never a crash inside HDF5) and leaves nothing behind.

    Parameters
    ----------
    path : str or os.PathLike
        Destination (``.h5``).
    overwrite : bool
        Replace an existing file.

    Yields
    ------
    h5py.File
        A new, empty file in memory.
    """
    dest = check_destination(path, overwrite)  # refused before the file is built
    name = f"gridstrain-{os.getpid()}-{secrets.token_hex(8)}.h5"
    with h5py.File(name, "w", driver="core", backing_store=False) as h5:
        yield h5
        h5.flush()
        image = h5.id.get_file_image()
    write_atomic(dest, image, overwrite=overwrite)


class _FdFile(io.RawIOBase):
    """A binary file on a descriptor, read and written with this module's ``os`` calls
    only (so that every byte HDF5 writes goes through the same calls as
    :func:`write_atomic`'s).

    A write that fails (a full disk, a size limit, a signal's exception) is recorded
    and, like every write after it, reported to HDF5 as done: the library must
    never see a failing file (it would keep it open, and tear it down at exit from
    a closed descriptor); the writer raises the recorded error once HDF5 returns
    (:meth:`HDF5Stream.check`), and the file is discarded.
    """

    def __init__(self, path: Path):
        super().__init__()
        self.fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
        self.error: BaseException | None = None

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        return os.readv(self.fd, [b])

    def write(self, b) -> int:
        view = memoryview(b).cast("B")
        if self.error is None:
            try:
                done = 0
                while done < len(view):
                    done += os.write(self.fd, view[done:])
            except BaseException as exc:
                self.error = exc
        return len(view)

    def seek(self, offset: int, whence: int = 0) -> int:
        return os.lseek(self.fd, offset, whence)

    def tell(self) -> int:
        return os.lseek(self.fd, 0, os.SEEK_CUR)

    def truncate(self, size=None) -> int:
        size = self.tell() if size is None else size
        if self.error is None:
            os.ftruncate(self.fd, size)
        return size

    def close(self) -> None:
        if not self.closed:
            os.close(self.fd)
        super().close()


class HDF5Stream:
    """An HDF5 file being written to disk (see :func:`hdf5_stream`).

    Attributes
    ----------
    file : h5py.File
        The file to fill.
    """

    def __init__(self, file: h5py.File, raw: _FdFile):
        self.file = file
        self._raw = raw

    def check(self) -> None:
        """Raise the error of a write that failed since the file was opened."""
        if self._raw.error is not None:
            raise self._raw.error


@contextlib.contextmanager
def hdf5_stream(path, *, overwrite: bool = False) -> Iterator[HDF5Stream]:
    """An HDF5 file written to disk as it is filled, put at ``path`` atomically when
    the block ends.

    For files too large to build in memory (:func:`hdf5_file`): a result written
    state by state. The file goes to a temporary file next to ``path``
    (:func:`atomic_path`) through h5py's file-object driver, whose every write is
    an ``os.write`` of this module. A write that fails (a full disk, a file size
    limit, a signal) is raised as itself (one ``OSError`` naming ``path`` for lack
    of room) at the next :meth:`HDF5Stream.check` or when the block ends, and the
    temporary file is removed: nothing appears at ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Destination (``.h5`` or ``.nc``).
    overwrite : bool
        Replace an existing file.

    Yields
    ------
    HDF5Stream
        Its ``file`` is a new, empty :class:`h5py.File`.
    """
    with atomic_path(path, overwrite=overwrite) as tmp:
        raw = _FdFile(tmp)
        try:
            with h5py.File(raw, "w") as h5:
                stream = HDF5Stream(h5, raw)
                yield stream
                stream.check()
            stream.check()  # the last writes happen when the file closes
        finally:
            raw.close()


def write_hdf5(path, datasets: Mapping[str, np.ndarray], attrs: Mapping | None = None, *,
               groups: Mapping[str, Mapping] | None = None,
               units: Mapping[str, str] | None = None, overwrite: bool = False,
               compression: str | None = "gzip") -> Path:
    """Write arrays and metadata to an HDF5 file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination (``.h5``); see :func:`atomic_path` for ``overwrite``.
    datasets : dict of str to ndarray
        Arrays of booleans, integers, floats or complex numbers. A name may hold
        slashes (``"maps/u"``) to place the dataset in a group. Arrays of two or
        more elements are chunked, compressed and checksummed (Fletcher-32).
    attrs : dict, optional
        Attributes of the file (root group). Strings, numbers and numeric arrays
        are stored natively; lists, tuples, dicts and ``None`` as JSON text
        (decoded by :func:`read_hdf5`; tuples come back as lists).
    groups : dict of str to dict, optional
        Attributes of groups, by group path (``{"parameters": {"sigma": 5.0}}``),
        encoded as ``attrs``; the groups are created if no dataset creates them.
    units : dict of str to str, optional
        Unit of each named dataset (``{"maps/u": "px", "maps/eps_xx": "1"}``),
        stored as the dataset attribute ``units``.
    overwrite : bool
        Replace an existing file.
    compression : {"gzip", "lzf", None}
        Lossless filter: ``"gzip"`` (level 4, readable everywhere), ``"lzf"``
        (faster, h5py only) or ``None``.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    datasets = check_mapping(datasets, "datasets")
    attrs = check_mapping(attrs, "attrs", allow_none=True)
    groups = check_mapping(groups, "groups", allow_none=True)
    units = check_mapping(units, "units", allow_none=True)
    if compression not in ("gzip", "lzf", None):
        raise ValueError(f"compression must be one of 'gzip', 'lzf', None, got "
                         f"{compression!r}")
    # validate everything before creating any file
    arrays = _dataset_arrays(datasets)
    _check_hdf5_metadata(arrays, attrs, groups, units)
    dest = as_path(path, "path")
    with hdf5_file(dest, overwrite=overwrite) as h5:
        _write_attrs(h5, attrs, "attrs")
        for key, arr in arrays.items():
            dset = _create_dataset(h5, key, arr, compression)
            if key in units:
                dset.attrs[_UNITS_ATTR] = units[key]
        for g, gattrs in groups.items():
            _write_attrs(h5.require_group(g), gattrs, f"groups[{g!r}]")
    return dest



def _column_format(dtype: np.dtype, digits: int | None) -> str:
    if dtype.kind == "U":
        return "%s"
    if dtype.kind in "biu":
        return "%d"
    if digits is not None:
        return f"%.{digits}g"
    # shortest text that reads back to the same float64 (Python's repr); float32
    # needs 9 significant digits to round-trip
    return "%r" if dtype.itemsize >= 8 else "%.9g"


def write_csv(path, columns: Mapping[str, np.ndarray], *, overwrite: bool = False,
              digits: int | None = None, chunk_rows: int = 65536) -> Path:
    """Write named columns to a CSV file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination (``.csv``); see :func:`atomic_path` for ``overwrite``.
    columns : dict of str to array_like
        Arrays of one shape; each is flattened in C order (row by row for an
        (H, W) map) into one column. Booleans are written 0/1; text (a numpy
        ``str`` array, such as state names) as it is, quoted where needed.
    overwrite : bool
        Replace an existing file.
    digits : int, optional
        Significant digits of floats. By default values read back exactly: float64
        as the shortest round-trip decimal, float32 with 9 digits. NaN is ``nan``.
    chunk_rows : int
        Rows formatted at once: memory is bounded by this, not by the row count.

    Returns
    -------
    pathlib.Path
        ``path``.

    Notes
    -----
    Written by the standard library's :mod:`csv` writer (RFC 4180: comma-separated,
    a field holding a comma, a double quote or a line break enclosed in double
    quotes, a double quote doubled, ``QUOTE_MINIMAL``), UTF-8 without a byte-order
    mark, CRLF line ends; one header line holds the column names; no index
    column. ``pandas.read_csv`` and spreadsheets read it back as written.
    """
    columns = check_mapping(columns, "columns")
    if not columns:
        raise ValueError("columns must hold at least one column, got an empty dict")
    if digits is not None and not 1 <= check_int(digits, "digits") <= 17:
        raise ValueError(f"digits must be an integer in [1, 17] or None, got {digits!r}")
    chunk_rows = check_int(chunk_rows, "chunk_rows", minimum=1)
    names, arrays = [], []
    first = None
    for key, value in columns.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"column names must be non-empty strings, got {key!r}")
        arr = np.asarray(value)
        if arr.dtype.kind not in "biufU":
            raise TypeError(f"columns[{key!r}] must be a real numeric, boolean or text "
                            f"array, got dtype {arr.dtype}")
        if first is None:
            first = (key, arr.shape)
        elif arr.shape != first[1]:
            raise ValueError(f"columns[{key!r}] has shape {arr.shape}, expected "
                             f"{first[1]} like columns[{first[0]!r}]")
        names.append(key)
        arrays.append(arr.reshape(-1))
    formats = [_column_format(a.dtype, digits) for a in arrays]
    n = arrays[0].size
    dest = as_path(path, "path")
    with atomic_path(dest, overwrite=overwrite) as tmp, \
            open(tmp, "x", encoding="utf-8", newline="") as fh:
        # RFC 4180's CRLF: the writer then quotes a lone CR too ("\n" would not)
        writer = csv.writer(fh, quoting=csv.QUOTE_MINIMAL, lineterminator="\r\n")
        writer.writerow(names)
        for start in range(0, n, chunk_rows):
            # tolist gives Python ints and floats: "%r" of a float is then the
            # shortest exact decimal, and bools format as 0/1 through "%d"
            cols = [[f % v for v in a[start:start + chunk_rows].tolist()]
                    for f, a in zip(formats, arrays, strict=True)]
            writer.writerows(zip(*cols, strict=True))
    return dest



# --------------------------------------------------------------------------- directories

#: Name of the file listing what gridstrain wrote in an output directory.
MARKER_NAME = ".gridstrain"

# the digest of each listed file's content, by which a later run recognises it
_HASH = "sha256"
_HEX = re.compile(r"[0-9a-f]{64}")


def _digest(path: Path) -> tuple[int, str] | None:
    """``(size, sha256 hex digest)`` of the regular file ``path``, opened without
    following a symbolic link; None if it is not a regular file."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return None
        h = hashlib.sha256()
        while chunk := os.read(fd, 1 << 20):
            h.update(chunk)
        return int(st.st_size), h.hexdigest()
    finally:
        os.close(fd)


class OutputDirectory:
    """A directory of outputs in which gridstrain replaces only its own files.

    Every file written through :meth:`write` (or declared by :meth:`record`) is
    listed, with its size and the SHA-256 digest of its content, in a marker file
    (:data:`MARKER_NAME`, JSON) in the directory. A later run may replace those
    files, with ``overwrite``, if their content is unchanged; any other file of the
    planned names is never replaced, deleted or written over, whatever
    ``overwrite`` says. Files of other names are left alone.

    The directory is taken at its real path (symbolic links in ``path`` resolved
    once), and no symbolic link inside it is ever followed: a listed entry that is
    a link, or that is reached through a linked directory, or whose real path
    leaves the directory, is never deleted or replaced, and a planned file is
    never written through a linked directory.

    Parameters
    ----------
    path : str or os.PathLike
        The directory; created by :meth:`prepare` if missing.
    names : iterable of str
        Relative paths (``"maps.h5"``, ``"ref/frame000000.tif"``) this run will write.
    overwrite : bool
        Replace the files an earlier run wrote and listed in the marker (all of them,
        so that an earlier, longer series leaves no frame behind).
    exclusive : iterable of str
        Sub-directories that must hold gridstrain's files only (a folder of frames
        read back as a series: a foreign image there would join it).
    parents : bool
        Create missing parent directories (otherwise the parent must exist).
    adopt : bool
        Accept an existing, non-empty directory without a marker (the new files
        are then added beside the others). False refuses it.
    what : str
        What the directory is, for messages.

    Raises
    ------
    FileExistsError
        A planned file exists that gridstrain did not write (or whose content
        changed since), a listed or planned path goes through a symbolic link or
        out of the directory, a foreign file sits in an ``exclusive``
        sub-directory, or the directory holds an earlier run's files and
        ``overwrite`` is False.
    NotADirectoryError, FileNotFoundError
        ``path`` is a file, or its parent does not exist.

    Notes
    -----
    Every refusal happens on construction and again in :meth:`prepare`, before
    any file is touched.
    """

    def __init__(self, path, names, *, overwrite: bool = False, exclusive=(),
                 parents: bool = False, adopt: bool = True,
                 what: str = "output directory"):
        self.what = check_name(what, "what")
        given = as_path(path, what)
        _refuse_dangling_link(given, what)
        self.path = Path(os.path.realpath(given))
        self.names = tuple(self._rel(n) for n in names)
        self.exclusive = tuple(self._rel(d) for d in exclusive)
        self.overwrite = bool(overwrite)
        self.parents = bool(parents)
        self.adopt = bool(adopt)
        self._check()

    @property
    def marker(self) -> Path:
        """The marker file."""
        return self.path / MARKER_NAME

    def _rel(self, name) -> str:
        check_name(name, f"{self.what}: file names")
        parts = Path(name).parts
        if Path(name).is_absolute() or ".." in parts or name == MARKER_NAME:
            raise ValueError(f"{self.what}: {name!r} is not a plain relative file name")
        return Path(*parts).as_posix()

    def _linked(self, rel: str) -> Path | None:
        """The first component of ``rel`` (from the directory down) that is a
        symbolic link or leads out of the directory, or None."""
        f = self.path
        for part in rel.split("/"):
            f = f / part
            if f.is_symlink():
                return f
            if not f.exists():
                return None
        real = os.path.realpath(f)
        if os.path.commonpath([real, self.path]) != os.fspath(self.path):
            return f
        return None

    def _refuse_link(self, f: Path, listed: bool) -> FileExistsError:
        how = "listed in its marker" if listed else "planned"
        return FileExistsError(f"{f} ({how}) is a symbolic link or lies outside {self.path} "
                               "by one; gridstrain never deletes or writes through links "
                               f"(remove the link or choose another {self.what})")

    def _manifest(self) -> dict[str, dict]:
        if self.marker.is_symlink():
            raise ValueError(f"{self.marker} is a symbolic link, not a gridstrain "
                             f"manifest; refusing to write into {self.path} (move it away)")
        if not self.marker.is_file():
            return {}
        try:
            data = json.loads(self.marker.read_text(encoding="utf-8"))
            files = data["files"]
            out = {}
            for k, v in files.items():
                rel = self._rel(k)
                if isinstance(v, list) or v == {}:  # no digest: nothing to check content by
                    out[rel] = {}
                    continue
                if not (isinstance(v, dict) and isinstance(v.get("size"), int)
                        and isinstance(v.get(_HASH), str) and _HEX.fullmatch(v[_HASH])):
                    raise ValueError(k)
                out[rel] = {"size": v["size"], _HASH: v[_HASH]}
            return out
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            raise ValueError(f"{self.marker} is not a gridstrain manifest; refusing to "
                             f"write into {self.path} (move the file away)") from None

    def _listed_unchanged(self, rel: str, entry: dict) -> bool:
        """Whether listed ``rel`` exists (and is unchanged); raise where it is not
        gridstrain's to replace."""
        f = self.path / rel
        link = self._linked(rel)
        if link is not None:
            raise self._refuse_link(link, listed=True)
        if not f.exists():
            return False
        if not entry:
            raise FileExistsError(f"{f} is listed without a content digest (by an older "
                                  "gridstrain); refusing to replace it (move it away or "
                                  f"choose another {self.what})")
        if _digest(f) != (entry["size"], entry[_HASH]):
            raise FileExistsError(f"{f} has changed since gridstrain wrote it (its content "
                                  f"is not the one listed in {MARKER_NAME}); refusing to "
                                  f"replace it (move it away or choose another {self.what})")
        return True

    def _check(self) -> dict[str, dict]:
        """The earlier files to remove; raise on anything that is not ours."""
        p = self.path
        if p.exists() and not p.is_dir():
            raise NotADirectoryError(f"{self.what} {p} is a file")
        if not p.exists():
            if not self.parents and not p.parent.is_dir():
                raise FileNotFoundError(f"cannot create {self.what} {p}: its parent "
                                        f"{p.parent} does not exist")
            return {}
        if not self.adopt and not self.marker.exists() and any(p.iterdir()):
            raise FileExistsError(f"{self.what} {p} already exists and was not written by "
                                  "gridstrain (it has no .gridstrain marker); choose a new "
                                  "folder, nothing there is replaced")
        ours = {rel: entry for rel, entry in self._manifest().items()
                if self._listed_unchanged(rel, entry)}
        for rel in (*self.names, *self.exclusive):
            link = self._linked(rel)
            if link is not None:
                raise self._refuse_link(link, listed=False)
        for rel in self.names:
            f = p / rel
            if (f.exists() or f.is_symlink()) and rel not in ours:
                raise FileExistsError(f"{f} exists and was not written by gridstrain; "
                                      f"refusing to replace it (move it away or choose "
                                      f"another {self.what})")
        for d in self.exclusive:
            sub = p / d
            if sub.is_dir():
                for e in sorted(sub.iterdir()):
                    if not e.name.startswith(".") and f"{d}/{e.name}" not in ours:
                        raise FileExistsError(
                            f"{e} was not written by gridstrain, and {sub} must hold "
                            f"gridstrain's files only; move it away or choose another "
                            f"{self.what}")
            elif sub.exists():
                raise FileExistsError(f"{sub} exists and is not a directory; move it away "
                                      f"or choose another {self.what}")
        if ours and not self.overwrite:
            first = p / next(iter(ours))
            raise FileExistsError(f"{self.what} {p} holds the files of an earlier "
                                  f"gridstrain run ({first}...); pass --overwrite "
                                  "(overwrite=True) to replace them")
        return ours

    def prepare(self) -> None:
        """Create the directory; remove, with ``overwrite``, the earlier run's files.

        Only files listed in the marker, reached without a symbolic link and whose
        content is unchanged since are removed (each checked again just before);
        the marker is rewritten first, so that an interruption leaves no file
        unlisted.
        """
        ours = self._check()
        make_directory(self.path, parents=self.parents)
        for rel in {*self.names, *self.exclusive}:
            parent = (self.path / rel) if rel in self.exclusive else (self.path / rel).parent
            make_directory(parent, parents=True)
        for rel, entry in ours.items():
            if self._listed_unchanged(rel, entry):
                (self.path / rel).unlink()
        self._save({})

    def _save(self, files: dict) -> None:
        # the single outputs listed beside (record_outputs) are kept as they are
        _write_marker(self.path, files, _read_marker(self.path).get("outputs", {}))

    def record(self, *paths) -> None:
        """Add files written in the directory to the marker, with their content's digest."""
        files = self._manifest()
        for f in paths:
            rel = self._rel(Path(os.path.realpath(f)).relative_to(self.path).as_posix())
            found = None if self._linked(rel) else _digest(self.path / rel)
            if found is None:
                raise ValueError(f"{self.what}: {f} is not a regular file of {self.path}")
            files[rel] = {"size": found[0], _HASH: found[1]}
        self._save(files)

    def write(self, name: str, data) -> Path:
        """Write ``name`` with :func:`write_atomic` and list it in the marker."""
        rel = self._rel(name)
        link = self._linked(rel)
        if link is not None:
            raise self._refuse_link(link, listed=False)
        dest = write_atomic(self.path / rel, data, overwrite=False)
        self.record(dest)
        return dest


# --------------------------------------------------------------------------- single files

def _read_marker(directory: Path) -> dict:
    """The marker of ``directory`` as JSON ({} if none); refused if it is not one."""
    marker = Path(directory) / MARKER_NAME
    if marker.is_symlink():
        raise ValueError(f"{marker} is a symbolic link, not a gridstrain manifest")
    if not marker.is_file():
        return {}
    try:
        data = json.loads(marker.read_text(encoding="utf-8"))
        if not isinstance(data, dict) or not isinstance(data.get("files"), dict) or \
                not isinstance(data.get("outputs", {}), dict):
            raise ValueError(marker)
        return data
    except (OSError, ValueError):
        raise ValueError(f"{marker} is not a gridstrain manifest (move the file "
                         "away)") from None


def _write_marker(directory: Path, files: dict, outputs: dict) -> None:
    from .. import __version__

    data = {"gridstrain": __version__,
            "note": "files written by gridstrain, which replaces only these and only "
                    f"while their {_HASH} is unchanged",
            "files": files}
    if outputs:
        data["outputs"] = outputs
    write_atomic(Path(directory) / MARKER_NAME, json.dumps(data, indent=1).encode("utf-8"),
                 overwrite=True)


def record_outputs(paths) -> None:
    """List single output files gridstrain wrote in the marker of their folder.

    Each file (a result ``maps.h5``, a report, a gauge's CSV) is listed under
    ``"outputs"`` in the folder's :data:`MARKER_NAME` with its size and the SHA-256
    digest of its content, so that a later run may replace it, with ``overwrite``,
    while its content is unchanged (:func:`written_by_gridstrain`). Files that an
    :class:`OutputDirectory` lists already, links and files no longer there are
    left out.

    Parameters
    ----------
    paths : iterable of str or os.PathLike
        Files this process has just written.

    Raises
    ------
    ValueError
        A folder's marker is not a gridstrain manifest.
    OSError
        The marker cannot be written.
    """
    by_folder: dict[Path, list[str]] = {}
    listed: dict[Path, dict] = {}  # the files of output directories, by marker folder
    for f in paths:
        f = Path(os.path.realpath(Path(f).parent)) / Path(f).name
        if f.name == MARKER_NAME or _in_output_directory(f, listed):
            continue
        by_folder.setdefault(f.parent, []).append(f.name)
    for folder, names in by_folder.items():
        data = _read_marker(folder)
        outputs = dict(data.get("outputs", {}))
        for name in dict.fromkeys(names):
            found = _digest(folder / name)
            if found is not None:
                outputs[name] = {"size": found[0], _HASH: found[1]}
        _write_marker(folder, data.get("files", {}), outputs)


def _in_output_directory(f: Path, listed: dict) -> bool:
    """Whether the marker of ``f``'s folder, or of a folder above, lists ``f`` among
    the files of an :class:`OutputDirectory` (``ref/frame000000.tif``)."""
    for above in f.parents:
        if above not in listed:
            try:
                listed[above] = _read_marker(above).get("files", {})
            except ValueError:
                listed[above] = {}
        if f.relative_to(above).as_posix() in listed[above]:
            return True
    return False


def written_by_gridstrain(path) -> bool:
    """Whether ``path`` is a file gridstrain wrote and nobody changed since.

    True when the marker of its folder (:data:`MARKER_NAME`) lists it, among the
    files of an :class:`OutputDirectory` or the single outputs of
    :func:`record_outputs`, with the size and SHA-256 digest of its present content.
    A symbolic link, a file no marker lists, one whose content changed and a folder
    whose marker is not a gridstrain manifest give False.

    Parameters
    ----------
    path : str or os.PathLike
        An existing output file.

    Returns
    -------
    bool
    """
    f = as_path(path, "path")
    folder = Path(os.path.realpath(f.parent))
    try:
        data = _read_marker(folder)
    except ValueError:
        return False
    entry = data.get("outputs", {}).get(f.name) or data.get("files", {}).get(f.name)
    if not isinstance(entry, dict) or not isinstance(entry.get(_HASH), str):
        return False
    return _digest(folder / f.name) == (entry.get("size"), entry[_HASH])

