"""Options and helpers shared by the sub-commands (command-line layer only)."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import signal
import stat
import sys
import threading
from pathlib import Path

from .._validation import check_positive
from ..io import check_destination
from ..phase import Lattice
from ..series import Option


def _grid_value(value, name):
    return value  # checked together, into a Lattice (lattice_option)


#: ``--pitch/--angle`` or ``--k1/--k2``: the grid given rather than detected.
LATTICE_OPTIONS = (
    Option("pitch", None, _grid_value, "", flag="--pitch", kind="float", metavar="PX",
           group="window", help="grid pitch, px (default: detected on the reference)"),
    Option("angle", None, _grid_value, "", flag="--angle", kind="float", metavar="DEG",
           group="window", help="grid angle, degrees (with --pitch; default 0)"),
    Option("k1", None, _grid_value, "", flag="--k1", kind="pair", metavar=("KX", "KY"),
           group="window",
           help="first wave vector, cycles/px (with --k2, instead of --pitch)"),
    Option("k2", None, _grid_value, "", flag="--k2", kind="pair", metavar=("KX", "KY"),
           group="window", help="second wave vector, cycles/px"),
)


def add_option(group, o: Option) -> None:
    """The flag of option ``o`` (a :class:`gridstrain.series.Option`), its value read as
    its kind says."""
    kw: dict = {"help": o.help}
    if o.metavar is not None:
        kw["metavar"] = o.metavar
    elif o.kind in ("choice", "method"):  # checked by the option, naming the flag
        kw["metavar"] = "{" + ",".join(o.choices) + "}"
    if o.kind == "bool":
        kw.update(action="store_true", default=None)
    elif o.kind in ("float", "int"):
        kw["type"] = float if o.kind == "float" else int
    elif o.kind == "method":
        kw["type"] = str.upper
    elif o.kind in ("pair", "pairs"):
        kw.update(type=float, nargs=2)
        if o.kind == "pairs":
            kw["action"] = "append"
    elif o.kind == "roi":
        kw.update(type=int, nargs=4)
    elif o.kind == "polygon":
        kw["nargs"] = "+"
    flags = ("-o", o.flag) if o.flag == "--output" else (o.flag,)
    group.add_argument(*flags, **kw)


def add_lattice_options(group) -> None:
    """``--pitch/--angle`` or ``--k1/--k2`` (automatic detection when absent)."""
    for o in LATTICE_OPTIONS:
        add_option(group, o)


def positive_option(opts: dict, name: str) -> None:
    """Refuse ``--name`` unless it is absent or a finite positive number."""
    if opts.get(name) is not None:
        check_positive(opts[name], f"--{name}")


def lattice_option(opts: dict) -> Lattice | None:
    """The lattice the options give, or None to detect it."""
    has_pitch = opts.get("pitch") is not None
    k1, k2 = opts.get("k1"), opts.get("k2")
    if has_pitch and (k1 is not None or k2 is not None):
        raise ValueError("give the grid either by --pitch (and --angle) or by --k1 and "
                         "--k2, not both")
    if (k1 is None) != (k2 is None):
        raise ValueError("--k1 and --k2 go together: give both wave vectors")
    if opts.get("angle") is not None and not has_pitch:
        raise ValueError("--angle needs --pitch")
    if has_pitch:
        positive_option(opts, "pitch")
        if opts["pitch"] <= 2:
            raise ValueError(f"--pitch must be above 2 px (the Nyquist limit), got "
                             f"{opts['pitch']:g}")
        return Lattice.from_pitch(opts["pitch"], angle=float(opts.get("angle") or 0.0))
    if k1 is not None:
        try:
            return Lattice(tuple(k1), tuple(k2))
        except ValueError as exc:
            raise ValueError(f"--k1/--k2: {exc}") from None
    return None


#: ``--overwrite``'s help, for a single output file (check_output_file says why not).
OVERWRITE_HELP = ("replace the file of that name if an earlier gridstrain run wrote it "
                  "and it is unchanged since (never another file)")


def make_folder(folder: Path, what: str) -> Path:
    """Create ``folder`` and its missing parents (``mkdir -p``) for an output (``what``
    names it in the message). Each folder made is recorded by the command's
    :class:`Outputs`, which removes it again, if still empty, when the run then fails:
    a refused or failed run leaves no folder behind."""
    from ..io import make_directory

    try:
        return make_directory(folder, parents=True)
    except FileNotFoundError as exc:  # through a symbolic link to nothing
        raise ValueError(f"cannot create the folder {folder} for the {what}: "
                         f"{str(exc).split(': ', 1)[-1]}") from None
    except (FileExistsError, NotADirectoryError) as exc:
        raise ValueError(f"cannot create the folder {folder} for the {what}: "
                         f"{exc.filename or folder} is a file, not a folder") from None
    except OSError as exc:
        raise ValueError(f"cannot create the folder {folder} for the {what}: "
                         f"{exc.strerror or exc}") from None


def png_option(value: str | None, flag: str = "--plot") -> Path | None:
    """A figure's file from the command line (written as PNG): its path, or None;
    another suffix refused naming ``flag`` (a PNG named .pdf or without a suffix
    opens as nothing)."""
    if value is None:
        return None
    path = Path(os.path.expanduser(value))
    if path.suffix.lower() != ".png":
        raise ValueError(f"{flag} must name a .png file (the figure is written as a "
                         f"PNG), got {value!r}")
    return path


def check_output_file(path: Path, what: str, overwrite: bool, inputs=frozenset()) -> None:
    """Refuse, before any work, an output that would fail or clobber at the end: with
    ``--overwrite``, a file that gridstrain did not write (or that changed since) is
    not replaced (:func:`gridstrain.io.written_by_gridstrain`). Its missing folders
    are created (:func:`make_folder`)."""
    from ..io import MARKER_NAME, written_by_gridstrain

    if path.resolve() in inputs:
        raise ValueError(f"{what} {path} is one of the input files; inputs are never "
                         "modified")
    make_folder(path.parent, what)
    check_destination(path, overwrite, what=what, how="--overwrite")
    if overwrite and (path.exists() or path.is_symlink()) and \
            not written_by_gridstrain(path):
        raise FileExistsError(
            f"{what} {path} exists and was not written by gridstrain (or has changed "
            f"since: its folder's {MARKER_NAME} does not list it with this content); "
            "--overwrite replaces only gridstrain's own outputs: move it away or choose "
            "another name")


@contextlib.contextmanager
def quiet_dask_logs():
    """Dask's own log records off while a command runs (restored after).

    A lost scheduler makes ``distributed`` log dozens of lines of tracebacks; the
    command says what happened in one line instead. Imports ``distributed``
    first, whose configuration sets the levels of its loggers on import.
    """
    with contextlib.suppress(ImportError):  # the command says which extra is missing
        import distributed  # noqa: F401
    names = [n for n in list(logging.root.manager.loggerDict)
             if n.split(".")[0] in ("distributed", "tornado")]
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", *names)]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


@contextlib.contextmanager
def _signals_ignored():
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


class Outputs:
    """The outputs a command commits, removed all together if it then fails.

    A transaction over the files of one run: inside ``with Outputs():`` every file
    gridstrain renames into place and every directory it creates is recorded
    (:func:`gridstrain.io._files.watch_outputs`); if the block raises (an error, a
    full disk half-way through the exports, SIGINT or SIGTERM), they are removed,
    newest first, before the exception goes on to become the command's one line.
    A file is removed only if it is still the one this run wrote (same device and
    inode), a directory only if it is empty.
    """

    def __init__(self):
        self.committed: list[tuple[str, Path, tuple[int, int] | None]] = []
        self._watch = None

    def _record(self, kind: str, path: Path) -> None:
        try:
            st = os.lstat(path)
        except OSError:
            return
        self.committed.append((kind, Path(path), (st.st_dev, st.st_ino)))

    def __enter__(self) -> Outputs:
        from ..io import watch_outputs

        self._watch = watch_outputs(self._record, make_parents=True)
        self._watch.__enter__()
        return self

    def __exit__(self, kind, exc, tb) -> None:
        self._watch.__exit__(None, None, None)
        # a reader that stops reading the command's printed lines (``| head -1``)
        # breaks no output: each is complete once renamed into place, and removing
        # one that replaced an earlier file (--overwrite) would lose both
        if exc is not None and not isinstance(exc, BrokenPipeError):
            self.rollback()
        else:
            self._list_as_ours()

    def _list_as_ours(self) -> None:
        """List the files of a successful run in their folders' markers, so that a
        later ``--overwrite`` may replace them (and nothing else)."""
        from ..io import record_outputs

        mine = []
        for kind, path, ident in self.committed:
            with contextlib.suppress(OSError):
                st = os.lstat(path)
                if kind == "file" and (st.st_dev, st.st_ino) == ident:
                    mine.append(path)
        # the outputs are complete; a marker that cannot be written costs only the
        # right to replace them later with --overwrite, which then says so
        with contextlib.suppress(OSError, ValueError):
            record_outputs(mine)

    def rollback(self) -> None:
        """Remove what was committed, newest first; SIGINT and SIGTERM wait meanwhile
        (ignored for the few milliseconds it takes), so that a second Ctrl-C cannot
        leave half the outputs behind."""
        with _signals_ignored():
            self._remove()

    def _remove(self) -> None:
        for kind, path, ident in reversed(self.committed):
            with contextlib.suppress(OSError):
                st = os.lstat(path)
                if (st.st_dev, st.st_ino) != ident:
                    continue  # replaced since by someone else: not ours to remove
                if kind == "dir" and stat.S_ISDIR(st.st_mode):
                    os.rmdir(path)  # fails, and stays, unless empty
                elif kind == "file" and stat.S_ISREG(st.st_mode):
                    os.unlink(path)
        self.committed.clear()


def xy_pairs(values, option: str) -> list[list[float]]:
    """``["x,y", ...]`` from the command line as ``[[x, y], ...]``; ``option`` names it."""
    out = []
    for v in values:
        try:
            x, y = (float(c) for c in v.split(","))
        except ValueError:
            raise ValueError(f"{option} vertices must be x,y pairs such as 10,20, got "
                             f"{v!r}") from None
        out.append([x, y])
    return out


def fmt(x: float) -> str:
    """A number for a table: 3 significant digits, NaN as '-'."""
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.3g}"


def print_json(obj) -> None:
    """Write ``obj`` as JSON on stdout."""
    json.dump(obj, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")
