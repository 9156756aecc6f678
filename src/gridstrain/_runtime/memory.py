"""The memory a run may use, and the memory it will need: refusing before allocating.

A measurement's memory is known before a single pixel is decoded: the frames' shape
and pixel type come from the files' headers (:func:`gridstrain.io.open_series`), and
the arrays the method holds grow with the number of pixels. The memory available
is the smallest of the system's (``MemAvailable`` in ``/proc/meminfo``) and of
the control group's limit less its usage (cgroup v2 ``memory.max`` and
``memory.current``, cgroup v1 ``memory.limit_in_bytes`` and
``memory.usage_in_bytes``; the reclaimable page cache, ``inactive_file``, counted
as available), or the budget set by :func:`memory_budget` (``gridstrain measure
--memory-budget 3G``).

:func:`check_fits` refuses, with one :class:`MemoryBudgetError` that says how much
is needed, how much is available and what to do, a need above it: so that a run
too large for its machine ends with a message instead of being killed by the
system (the out-of-memory killer gives no message and no chance to clean up).
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import re
from collections.abc import Iterator
from pathlib import Path

__all__ = ["MemoryBudgetError", "available_memory", "check_fits", "measurement_bytes",
           "memory_budget", "parse_size", "resident_memory"]

# The peak resident memory of one measurement whose states are written as they are
# measured, per pixel of a frame, by method, in bytes, above a fixed part (the
# interpreter, numpy, scipy and its FFT library, h5py): fitted to the peak resident
# memory of `gridstrain measure` at several frame sizes (benchmarks/bench_budget.py)
# and rounded up, so that the estimate lies above each measured peak.
_PER_PIXEL = {"A": 280, "B": 300, "C": 380}
_BASE = 280 * 2**20
# what each loaded state adds when every state's maps are held to the end (phase
# maps stored with --phase-maps, or a result kept in memory): the complex moduli
# and phase derivatives of both carriers, the displacement, strain and
# uncertainty maps
_PER_HELD_STATE = 480

_UNITS = {"": 1, "B": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
_SIZE = re.compile(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*([KMGT]?)(?:I?B)?\s*", re.IGNORECASE)

_budget: contextvars.ContextVar[int | None] = contextvars.ContextVar(
    "gridstrain_memory_budget", default=None)


class MemoryBudgetError(MemoryError):
    """A run refused before allocating: it needs more memory than is available.

    The message is one line: what needs how much, how much is available (and
    where that figure comes from) and what to do.
    """


def parse_size(text, *, name: str = "memory budget") -> int:
    """Bytes in a size written ``3G``, ``500M``, ``1.5GiB``, ``2048K`` or ``1000000``.

    Units are binary (K = 1024 bytes, M = 1024**2, G = 1024**3, T = 1024**4), with or
    without a trailing ``B`` or ``iB``.
    """
    if isinstance(text, int) and not isinstance(text, bool) and text > 0:
        return text
    m = _SIZE.fullmatch(text) if isinstance(text, str) else None
    if m is None or float(m.group(1)) <= 0:
        raise ValueError(f"{name} must be a positive size such as 3G, 500M or 2048K, got "
                         f"{text!r}")
    return int(float(m.group(1)) * _UNITS[m.group(2).upper()])


def format_size(nbytes: float) -> str:
    """``3.2 GiB``, ``512 MiB``: a size for a message."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} bytes"


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except (OSError, UnicodeDecodeError):
        return None
    return None if text in ("", "max") else int(text) if text.isdigit() else None


def _inactive_file(stat_file: Path, key: str) -> int:
    try:
        for line in stat_file.read_text().splitlines():
            k, _, v = line.partition(" ")
            if k == key and v.strip().isdigit():
                return int(v)
    except OSError:
        pass
    return 0


def _proc_kib(path: str, key: str) -> int | None:
    """Bytes of the ``key: N kB`` line of a /proc file, or None."""
    try:
        with open(path, encoding="ascii") as fh:
            return 1024 * next(int(line.split()[1]) for line in fh if line.startswith(key))
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def _cgroup_paths() -> tuple[str | None, str | None]:
    """``(v2 path, v1 memory path)`` of this process's control group."""
    v2 = v1 = None
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return None, None
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        if parts[0] == "0" and parts[1] == "":
            v2 = parts[2]
        elif "memory" in parts[1].split(","):
            v1 = parts[2]
    return v2, v1


def _cgroup_free(root: Path, group: str | None, limit: str, usage: str,
                 inactive: str) -> int | None:
    """The least ``limit - usage + inactive_file`` over the group and its ancestors
    (each level's limit holds), or None where no level sets a limit."""
    if not root.is_dir():
        return None
    rel = Path((group or "/").lstrip("/"))
    dirs = [root / rel, *[root / p for p in rel.parents]]
    if not (root / rel).is_dir():
        dirs = [root]  # a container sees its own group at the root of the mount
    best = None
    for d in dirs:
        cap, used = _read_int(d / limit), _read_int(d / usage)
        if cap is None or used is None or cap >= 2**60:  # v1 writes "no limit" as ~2**63
            continue
        free = max(0, cap - used + _inactive_file(d / "memory.stat", inactive))
        best = free if best is None else min(best, free)
    return best


def available_memory() -> tuple[int, str]:
    """The memory this process may still use, in bytes, and where the figure comes from.

    Returns
    -------
    (int, str)
        The smallest of: the budget set by :func:`memory_budget`; the control
        group's limit less its usage (cgroup v2, then v1); ``MemAvailable`` of
        ``/proc/meminfo``. Where none can be read, ``(2**63 - 1, "unknown")``.
    """
    budget = _budget.get()
    if budget is not None:
        return budget, "the memory budget"
    found = []
    v2, v1 = _cgroup_paths()
    free = _cgroup_free(Path("/sys/fs/cgroup"), v2, "memory.max", "memory.current",
                        "inactive_file") if v2 is not None else None
    if free is not None:
        found.append((free, "the cgroup's memory.max"))
    free = _cgroup_free(Path("/sys/fs/cgroup/memory"), v1, "memory.limit_in_bytes",
                        "memory.usage_in_bytes", "total_inactive_file")
    if free is not None:
        found.append((free, "the cgroup's memory.limit_in_bytes"))
    free = _proc_kib("/proc/meminfo", "MemAvailable:")
    if free is not None:
        found.append((free, "MemAvailable"))
    if not found:
        return 2**63 - 1, "unknown"
    return min(found)


@contextlib.contextmanager
def memory_budget(size) -> Iterator[int | None]:
    """Inside the block, :func:`check_fits` compares needs with ``size`` instead of the
    available memory.

    Parameters
    ----------
    size : int, str or None
        Bytes, or a size such as ``"3G"`` (:func:`parse_size`); None keeps the
        available memory.
    """
    value = None if size is None else parse_size(size)
    token = _budget.set(value)
    try:
        yield value
    finally:
        _budget.reset(token)


def check_fits(nbytes: float, *, what: str, advice: str | None = None) -> None:
    """Refuse, before allocating, a need of ``nbytes`` above the available memory.

    Parameters
    ----------
    nbytes : float
        Bytes the step will hold at its peak.
    what : str
        What needs them, for the message (``"decoding page 0 of big.tif (60000 x
        60000 uint16)"``).
    advice : str, optional
        What to do, for the message; default: set a larger ``--memory-budget`` if
        more memory is in fact free.

    Raises
    ------
    MemoryBudgetError
        ``nbytes`` exceeds :func:`available_memory`.
    """
    if not math.isfinite(nbytes) or nbytes < 0:
        raise ValueError(f"nbytes must be a finite size in bytes, got {nbytes!r}")
    free, source = available_memory()
    if nbytes <= free:
        return
    tail = advice or "raise --memory-budget (memory_budget) if more memory is in fact free"
    raise MemoryBudgetError(f"{what} needs about {format_size(nbytes)} more memory, "
                            f"{format_size(free)} available ({source}); {tail}")


def resident_memory() -> int:
    """Bytes this process holds now (``VmRSS``), 0 where the system does not say."""
    return _proc_kib("/proc/self/status", "VmRSS:") or 0


def measurement_bytes(shape, *, method: str = "A", n_states: int = 1,
                      held_states: bool = False) -> int:
    """Estimated peak resident memory of a measurement of frames of ``shape``.

    Parameters
    ----------
    shape : (2,) tuple of int
        ``(H, W)`` of the frames.
    method : {"A", "B", "C"}
    n_states : int
        Loaded states.
    held_states : bool
        Every state's maps are held until the end (phase maps stored, or the
        result kept in memory) rather than written as each is measured.

    Returns
    -------
    int
        Bytes, the whole process's: a fixed part for the interpreter and the
        libraries plus a figure per pixel of a frame, calibrated on the measured
        peaks of ``gridstrain measure`` (``benchmarks/bench_budget.py``).
    """
    H, W = (int(v) for v in shape)
    per_pixel = _PER_PIXEL.get(str(method).upper(), max(_PER_PIXEL.values()))
    if held_states:
        per_pixel += _PER_HELD_STATE * max(int(n_states), 1)
    return int(_BASE + per_pixel * H * W)
