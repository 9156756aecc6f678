"""The load and time of each state: from the result, or from a CSV file of the test rig."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

from .._validation import as_path

_HEADER = re.compile(r"^\s*(state|load|time)\s*(?:\[\s*([^\]]*?)\s*\])?\s*$", re.IGNORECASE)


def _per_state(values, name: str, n: int) -> np.ndarray | None:
    """``values`` as ``(n,)`` float64; a leading reference entry (n + 1) is dropped."""
    if values is None:
        return None
    try:
        arr = np.array(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, one per loaded state, got "
                         f"{values!r}") from None
    if arr.size == n + 1:  # stored with the reference first
        arr = arr[1:]
    if arr.size != n:
        raise ValueError(f"{name} must hold one value per loaded state ({n}), got "
                         f"{arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    arr.flags.writeable = False
    return arr


def state_loads(result, *, load=None, load_unit=None, time=None):
    """``(load, load_unit, time)`` of the loaded states: given, else the result's own."""
    n = result.n_states
    if load is None:
        load = getattr(result, "load", None)
        load_unit = load_unit if load_unit is not None else getattr(result, "load_unit",
                                                                    None)
    if time is None:
        time = getattr(result, "time", None)
    load = _per_state(load, "load", n)
    time = _per_state(time, "time", n)
    if time is not None and np.any(np.diff(time) <= 0):
        raise ValueError(f"time must increase from state to state, got {time.tolist()}")
    return load, (load_unit if load is not None else None), time


def read_loads(path, names) -> tuple[np.ndarray, str | None, np.ndarray | None]:
    """Loads (and times) of the states from a CSV file.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file with a header: ``load [UNIT]``, optionally ``state`` (the
        states' names: rows are matched by name, and a row for the reference is
        dropped) and ``time [s]``. Without ``state``, one row per loaded state in
        order (or one more, the reference first).
    names : sequence of str
        The result's names, ``("reference", state 0, ...)``.

    Returns
    -------
    load : (n_states,) float64 ndarray
    load_unit : str or None
    time : (n_states,) float64 ndarray or None
        s.
    """
    p = as_path(path, "loads")
    try:
        text = Path(p).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise FileNotFoundError(f"loads file {p} does not exist") from None
    rows = [r for r in csv.reader(text.splitlines()) if any(c.strip() for c in r)]
    if not rows:
        raise ValueError(f"loads file {p} is empty; expected a header such as "
                         "'state,load [N],time [s]'")
    cols: dict[str, tuple[int, str | None]] = {}
    for j, h in enumerate(rows[0]):
        m = _HEADER.match(h)
        if m is None or m.group(1).lower() in cols:
            raise ValueError(f"loads file {p}: column {h!r} is not one of 'state', "
                             "'load [UNIT]', 'time [s]' (each once)")
        cols[m.group(1).lower()] = (j, m.group(2))
    if "load" not in cols:
        raise ValueError(f"loads file {p} has no 'load [UNIT]' column (header: "
                         f"{','.join(rows[0])})")
    if "time" in cols and (cols["time"][1] or "s") != "s":
        raise ValueError(f"loads file {p}: the time column must be in s, got "
                         f"[{cols['time'][1]}]")
    body = rows[1:]
    for k, r in enumerate(body, start=2):
        if len(r) != len(rows[0]):
            raise ValueError(f"loads file {p}, line {k}: {len(r)} fields, expected "
                             f"{len(rows[0])}")

    def numbers(key):
        j = cols[key][0]
        out = []
        for k, r in enumerate(body, start=2):
            try:
                v = float(r[j])
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise ValueError(f"loads file {p}, line {k}: {key} {r[j]!r} is not a "
                                 "finite number")
            out.append(v)
        return np.array(out)

    load = numbers("load")
    time = numbers("time") if "time" in cols else None
    states = list(names[1:])
    if "state" in cols:
        given = [r[cols["state"][0]].strip() for r in body]
        if given and given[0] == names[0] and names[0] not in states:
            given, load = given[1:], load[1:]
            time = None if time is None else time[1:]
        if sorted(given) != sorted(states):
            missing = sorted(set(states) - set(given))
            extra = sorted(set(given) - set(states))
            raise ValueError(f"loads file {p}: its states must be the result's, once each; "
                             f"missing {missing}, unknown or repeated {extra}")
        order = [given.index(s) for s in states]
        load = load[order]
        time = None if time is None else time[order]
    unit = cols["load"][1] or None
    load = _per_state(load, f"loads file {p}: load", len(states))
    time = _per_state(time, f"loads file {p}: time", len(states))
    return load, unit, time
