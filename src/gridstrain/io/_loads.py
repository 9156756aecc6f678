"""Reading the load (and time) of each state from a test's CSV file (see :mod:`gridstrain.io`)."""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass

import numpy as np

from .._validation import as_path

_LOAD = re.compile(r"^load\s*\[\s*(?P<unit>[^\]]*?)\s*\]$", re.IGNORECASE)
_TIME = re.compile(r"^time\s*\[\s*(?P<unit>[^\]]*?)\s*\]$", re.IGNORECASE)


@dataclass(frozen=True, eq=False)
class LoadTable:
    """The loads (and times) of the states, one value per state in their order.

    Attributes
    ----------
    load : (n_states,) float64 ndarray
        In ``unit``.
    unit : str
        The unit of the load column's header (``load [kN]``: ``"kN"``).
    time : (n_states,) float64 ndarray or None
        Seconds, from a ``time [s]`` column.
    """

    load: np.ndarray
    unit: str
    time: np.ndarray | None

    def __post_init__(self):
        for a in (self.load, self.time):
            if a is not None:
                a.flags.writeable = False


def _number(text: str, path, row: int, column: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise ValueError(f"loads file {path}, row {row}: column {column!r} must hold a "
                         f"finite number, got {text!r}")
    return v


def read_loads(path, *, states, reference: str | None = None) -> LoadTable:
    """Read the load (and the time) of every state from a CSV file.

    The first line that is not blank or a ``#`` comment is the header. Columns
    (names compared case-insensitively, separated by commas, semicolons or tabs):

    - ``load [UNIT]`` (required; the unit in brackets, e.g. ``load [kN]``);
    - ``time [s]`` (optional, seconds);
    - ``state`` (optional): the name of the state each row gives, every state
      once, in any order (and, if ``reference`` is given, at most one row naming
      the reference, which is skipped). Without it, one row per state in the
      states' order.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.
    states : sequence of str
        The states' names, in the order measured
        (:attr:`gridstrain.results.SeriesResult.names` less the reference).
    reference : str, optional
        The reference's name: a row of a ``state`` column naming it (its load is
        usually zero) is allowed and skipped.

    Returns
    -------
    LoadTable

    Raises
    ------
    ValueError
        A header without a ``load [UNIT]`` column or its unit, a time column not
        in seconds, a row of another length or with a value that is not a finite
        number, a state named twice or unknown, or not one row per state: the
        message names the file and the row (rows numbered from 1 as a text
        editor shows the lines).
    """
    p = as_path(path, "loads")
    names = [str(s) for s in states]
    if not p.is_file():
        raise FileNotFoundError(f"loads file {p} does not exist")
    with open(p, newline="", encoding="utf-8-sig") as fh:
        lines = list(enumerate(fh.read().splitlines(), start=1))
    rows = [(n, line) for n, line in lines if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise ValueError(f"loads file {p} is empty: expected a header such as "
                         "'load [kN],time [s]' and one row per state")
    head_row, head = rows[0]
    delim = next((d for d in (",", ";", "\t") if d in head), ",")
    parsed = list(csv.reader([line for _, line in rows], delimiter=delim))
    header = [h.strip() for h in parsed[0]]
    cols = {}
    for k, h in enumerate(header):
        low = h.lower()
        if low == "state":
            cols["state"] = k
        elif _LOAD.match(h):
            cols["load"] = k
            unit = _LOAD.match(h)["unit"]
            if not unit:
                raise ValueError(f"loads file {p}, row {head_row}: the load column "
                                 f"{h!r} has an empty unit; write e.g. 'load [kN]'")
        elif _TIME.match(h):
            if _TIME.match(h)["unit"] != "s":
                raise ValueError(f"loads file {p}, row {head_row}: the time column must be "
                                 f"in seconds, 'time [s]', got {h!r}")
            cols["time"] = k
        elif low in ("load", "time") or low.startswith(("load ", "time ")):
            raise ValueError(f"loads file {p}, row {head_row}: column {h!r} has no unit; "
                             f"write its unit in brackets, e.g. '{low.split()[0]} "
                             f"[{'kN' if low.startswith('load') else 's'}]'")
    if "load" not in cols:
        raise ValueError(f"loads file {p}, row {head_row}: no 'load [UNIT]' column in the "
                         f"header {header}")
    body = list(zip((n for n, _ in rows[1:]), parsed[1:], strict=True))
    load = np.full(len(names), np.nan)
    time = np.full(len(names), np.nan) if "time" in cols else None
    if "state" not in cols and len(body) != len(names):
        raise ValueError(f"loads file {p}: {len(body)} row(s) of values for {len(names)} "
                         "state(s): give one row per state, in their order, or a 'state' "
                         "column naming them")
    index = {n: i for i, n in enumerate(names)}
    seen: dict[int, int] = {}
    skipped = False
    for k, (row, values) in enumerate(body):
        if len(values) != len(header):
            raise ValueError(f"loads file {p}, row {row}: {len(values)} value(s) for the "
                             f"{len(header)} column(s) of the header")
        if "state" in cols:
            name = values[cols["state"]].strip()
            if reference is not None and name == reference and name not in index \
                    and not skipped:
                skipped = True
                continue
            if name not in index:
                raise ValueError(f"loads file {p}, row {row}: state {name!r} is not one of "
                                 f"the states measured ({', '.join(names[:3])}"
                                 f"{', ...' if len(names) > 3 else ''})")
            i = index[name]
            if i in seen:
                raise ValueError(f"loads file {p}, row {row}: state {name!r} already given "
                                 f"in row {seen[i]}")
            seen[i] = row
        else:
            i = k
        load[i] = _number(values[cols["load"]].strip(), p, row, header[cols["load"]])
        if time is not None:
            time[i] = _number(values[cols["time"]].strip(), p, row, header[cols["time"]])
    if "state" in cols and len(seen) != len(names):
        missing = [n for i, n in enumerate(names) if i not in seen]
        raise ValueError(f"loads file {p}: no row for {len(missing)} state(s) "
                         f"({', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''})")
    return LoadTable(load=load, unit=_LOAD.match(header[cols["load"]])["unit"], time=time)
