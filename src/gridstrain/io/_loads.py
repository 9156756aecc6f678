"""Reading the load (and time) of each state from a testing machine's export (see
:mod:`gridstrain.io`).

A testing machine writes its log its own way: a preamble (specimen, operator,
date) above the header, a semicolon or a tab between columns and a decimal comma
in a German or French locale, units in the header (``Force (kN)``, ``Zeit [ms]``)
or on a line of their own below it, Windows-1252 or UTF-16 text, and a row every
10 ms while the camera takes one frame a second. :func:`read_loads` reads such a
file as it comes and gives one load (and time) per state; its Notes state the
rules.
"""

from __future__ import annotations

import codecs
import contextlib
import csv
import hashlib
import math
import os
import re
from dataclasses import dataclass, field

import numpy as np

from .._progress import Finding
from .._validation import as_path, check_finite
from ._numbering import _numbers_from_names

# a number as exports write it: a point or (with a non-comma delimiter) a comma as the
# decimal mark, an optional exponent; no thousands separator
_NUMBER = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")
# "Force (kN)", "Load [N]", "Zeit / ms", "Zeit in ms"
_WITH_UNIT = (re.compile(r"^(?P<name>.*?)\s*\[\s*(?P<unit>[^\]]*?)\s*\]$"),
              re.compile(r"^(?P<name>.*?)\s*\(\s*(?P<unit>[^)]*?)\s*\)$"),
              re.compile(r"^(?P<name>.*?\S)\s*/\s*(?P<unit>[^/\s]+)$"),
              re.compile(r"^(?P<name>.*?\S)\s+in\s+(?P<unit>\S+)$", re.IGNORECASE))
_MICRO = "\u00b5"  # the micro sign of cp1252 (0xB5); a Greek mu (U+03BC) reads as it

#: A force unit as written -> (the unit the loads are given in, factor to it).
FORCE_UNITS = {"N": ("N", 1.0), "kN": ("kN", 1.0), "KN": ("kN", 1.0), "kn": ("kN", 1.0),
               "MN": ("MN", 1.0), "mN": ("N", 1e-3), "daN": ("N", 10.0),
               "lbf": ("lbf", 1.0), "lb": ("lbf", 1.0), "lbs": ("lbf", 1.0),
               "kip": ("lbf", 1e3), "kips": ("lbf", 1e3), "kipf": ("lbf", 1e3)}
#: A time unit as written (compared in lower case) -> its factor to s.
TIME_UNITS = {"s": 1.0, "sec": 1.0, "secs": 1.0, "second": 1.0, "seconds": 1.0,
              "ms": 1e-3, "msec": 1e-3, f"{_MICRO}s": 1e-6, "us": 1e-6, "min": 60.0,
              "h": 3600.0, "hr": 3600.0}


@dataclass(frozen=True, eq=False)
class LoadTable:
    """The loads (and times) of the states, one value per state in their order.

    Attributes
    ----------
    load : (n_states,) float64 ndarray
        In ``unit``.
    unit : str
        ``"N"``, ``"kN"``, ``"MN"`` or ``"lbf"`` (see :data:`FORCE_UNITS`).
    time : (n_states,) float64 ndarray or None
        Seconds on the camera's clock: the ``times`` given to :func:`read_loads`,
        else the file's time column less the offset; None without either.
    source : dict
        How the loads were read, to be stored with the result: ``file``,
        ``sha256`` (of its bytes), ``encoding``, ``delimiter``, ``decimal``,
        ``header_row``, ``rows`` (of values), ``load_column`` and ``load_unit``
        (as in the file), ``load_factor`` (to ``unit``), ``time_column``,
        ``time_unit`` and ``time_factor`` (to s; None without a time column),
        ``offset_s`` and ``method``: ``"linear interpolation in time"``, ``"one
        row per state"`` or ``"state column"``.
    notes : tuple of Finding
        What the caller should say of the reading: the rows of a ``state`` column
        skipped because they name frames the record lacks (code ``input``, figures
        ``rows`` and ``states``; see :func:`read_loads`).
    """

    load: np.ndarray
    unit: str
    time: np.ndarray | None
    source: dict = field(default_factory=dict)
    notes: tuple = ()

    def __post_init__(self):
        for a in (self.load, self.time):
            if a is not None:
                a.flags.writeable = False


@dataclass(frozen=True)
class LoadsFile:
    """A testing machine's export and how to read it: what ``loads=`` takes.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    load_column, time_column : str, optional
        The columns' names (without their unit, or as written), compared
        case-insensitively; by default recognised by name (see
        :func:`read_loads`).
    offset : float
        The time on the log's clock at the camera's time zero, s (a log started
        0.2 s before the camera's trigger: 0.2).
    """

    path: object
    load_column: str | None = None
    time_column: str | None = None
    offset: float = 0.0

    def read(self, states, *, reference: str | None = None, times=None) -> LoadTable:
        """:func:`read_loads` of this file, with its options."""
        return read_loads(self.path, states=states, reference=reference, times=times,
                          load_column=self.load_column, time_column=self.time_column,
                          offset=self.offset)


# --------------------------------------------------------------------------- decoding

def _row_of(raw: bytes, index: int, encoding: str = "latin-1") -> int:
    """The line (from 1) of byte ``index`` of ``raw``, read in ``encoding``."""
    return raw[:index].decode(encoding, errors="replace").count("\n") + 1


def _decode(raw: bytes, p) -> tuple[str, str]:
    """``(text, encoding)``: UTF-8, UTF-16 with its byte-order mark, or cp1252."""
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        try:
            return raw.decode("utf-16"), "utf-16"
        except UnicodeDecodeError as exc:
            raise ValueError(f"loads file {p}, row {_row_of(raw, exc.start, 'utf-16')}: not "
                             "valid UTF-16 text (its byte-order mark says UTF-16)") from None
    if raw.startswith(codecs.BOM_UTF8):
        enc = "utf-8-sig"
    elif b"\x00" in raw:
        nul = _row_of(raw, raw.index(b"\x00"))
        raise ValueError(f"loads file {p}, row {nul}: holds "
                         "NUL bytes, as UTF-16 text without a byte-order mark or a binary "
                         "file does; save the export as UTF-8 (or UTF-16 with its "
                         "byte-order mark)")
    else:
        enc = "utf-8"
    with contextlib.suppress(UnicodeDecodeError):
        return raw.decode(enc), enc
    try:
        return raw.decode("cp1252"), "cp1252"
    except UnicodeDecodeError as exc:
        raise ValueError(f"loads file {p}, row {_row_of(raw, exc.start)}: byte "
                         f"0x{raw[exc.start]:02x} is neither UTF-8 nor Windows-1252 "
                         "(cp1252) text; save the export as UTF-8") from None


# --------------------------------------------------------------------------- parsing

def _is_number(text: str) -> bool:
    return bool(_NUMBER.match(text))


def _splitter(delimiter: str | None, p):
    """A function ``(row, line) -> fields`` (stripped) for ``delimiter`` (None: runs
    of white space) through the :mod:`csv` reader."""
    def split(row: int, line: str) -> list[str]:
        if delimiter is None:
            return line.split()
        try:
            return [f.strip() for f in next(csv.reader([line], delimiter=delimiter))]
        except csv.Error as exc:
            raise ValueError(f"loads file {p}, row {row}: {exc} (csv module; a field over "
                             f"{csv.field_size_limit() // 1024} KiB is no load or "
                             "time)") from None
    return split


def _header_cells(fields: list[str], line: str, delimiter: str | None) -> list[str]:
    """The header's cells: with white space between the columns, a name may hold one
    space ("Time (s)   Force (kN)": columns apart by two spaces or more, or a tab)."""
    if delimiter is None:
        wide = [c for c in re.split(r"\t|\s{2,}", line.strip()) if c]
        if len(wide) >= 2:
            return wide
    return fields


@dataclass
class _Layout:
    delimiter: str | None
    header_row: int
    header: list[str]
    units: list[str] | None
    body: list[tuple[int, str]]


def _is_text(fields: list[str]) -> bool:
    return any(fields) and not any(_is_number(f) for f in fields)


def _is_data(fields: list[str], n: int, text_columns: set[int]) -> bool:
    return len(fields) == n and any(_is_number(f) for f in fields) and all(
        not f or _is_number(f) or k in text_columns for k, f in enumerate(fields))


def _is_unit_like(cell: str) -> bool:
    """Whether a cell of a line of units can be a unit: empty, or one short token
    (``kN``, ``[s]``, ``µm/m``, ``°C``), no number."""
    t = _unit_cell(cell)
    return t is None or (len(t) <= 8 and not any(c.isspace() for c in t)
                         and not _is_number(t))


def _find_layout(lines: list[tuple[int, str]], p) -> _Layout:
    """The delimiter, header, line of units and rows of values (module docstring)."""
    head = lines[:2000]  # a preamble is tens of lines, never thousands
    # tab, ";", "," or white space between two columns or more; else one column (its
    # values with a decimal point, or, split at nothing, with a decimal comma)
    for delimiter, least in (("\t", 2), (";", 2), (",", 2), (None, 2), (",", 1),
                             ("\t", 1)):
        split = _splitter(delimiter, p)
        fields = [split(r, line) for r, line in head]
        best = None
        for i in range(len(head) - 1):
            cells = _header_cells(fields[i], head[i][1], delimiter)
            n = len(cells)
            if n < least or not _is_text(cells):
                continue
            text_columns = {k for k, f in enumerate(cells) if f.lower() == "state"}
            j = i + 1
            units = None
            # a line of units holds units only ("s;kN"), never a header's names with
            # their units ("Zeit [s];Kraft [kN]"), which a preamble line would take
            if _is_text(fields[j]) and len(fields[j]) == n and j + 1 < len(head) and \
                    all(_is_unit_like(f) for f in fields[j]):
                units, j = fields[j], j + 1
            run = 0
            while j + run < len(head) and _is_data(fields[j + run], n, text_columns):
                run += 1
            # a preamble of "name;value" pairs looks like a header and its rows: the
            # header is the one with the longest run of rows below it; of two with one
            # run (a header and its line of units, or a preamble line taking the
            # header for its units), the one naming a load or a time column
            names = sum(_looks_like(k, _name_and_unit(c)[0]) for c in cells
                        for k in ("load", "time"))
            if run and (best is None or (run, names) > best[0]):
                best = ((run, names), i, cells, units, j)
        if best is not None:
            _, i, cells, units, j = best
            return _Layout(delimiter, head[i][0], cells, units, lines[j:])
    raise ValueError(f"loads file {p}: no header line followed by a row of numbers (with "
                     "tab, ';', ',' or spaces between the columns); expected e.g. "
                     "'Time (s);Force (kN)' above the values")


# --------------------------------------------------------------------------- columns

def _name_and_unit(cell: str) -> tuple[str, str | None]:
    """``"Force (kN)"`` -> ``("Force", "kN")``; ``"Force"`` -> ``("Force", None)``."""
    for pattern in _WITH_UNIT:
        m = pattern.match(cell)
        if m and m["name"].strip():
            return m["name"].strip(), m["unit"].strip() or None
    return cell.strip(), None


def _unit_cell(text: str) -> str | None:
    """A cell of the line of units: ``kN``, ``[kN]`` or ``(kN)``."""
    t = text.strip().strip("[]()").strip()
    return t or None


def _words(name: str) -> list[str]:
    return [w for w in re.split(r"[^a-zäöüß]+", name.lower()) if w]


def _looks_like(kind: str, name: str) -> bool:
    words = _words(name)
    if kind == "load":
        return any(w in ("load", "force", "f") or w.endswith("kraft") for w in words)
    return any(w in ("time", "t", "zeit") or w.endswith("zeit") for w in words)


def _column(kind: str, given: str | None, names: list[str], cells: list[str], p,
            row: int, *, required: bool) -> int | None:
    """The index of the load or time column: the one named ``given``, else the one
    whose name says it."""
    option = f"{kind}_column (--{kind}-column)"
    if given is not None:
        want = str(given).strip().lower()
        found = [k for k, (n, c) in enumerate(zip(names, cells, strict=True))
                 if want in (n.lower(), c.lower())]
        if len(found) != 1:
            raise ValueError(f"loads file {p}, row {row}: {option} {given!r} names "
                             f"{'no' if not found else 'more than one'} column of the header "
                             f"{cells}")
        return found[0]
    found = [k for k, n in enumerate(names) if _looks_like(kind, n)]
    if len(found) > 1:
        raise ValueError(f"loads file {p}, row {row}: {len(found)} columns could be the "
                         f"{kind} ({', '.join(repr(cells[k]) for k in found)}); choose one "
                         f"with {option}")
    if not found and required:
        raise ValueError(f"loads file {p}, row {row}: no load column in the header {cells} "
                         f"(none named load, force or Kraft); choose one with {option}")
    return found[0] if found else None


def _unit(kind: str, unit: str | None, cell: str, p, row: int) -> tuple[str, float]:
    """``(unit as stored, factor from the file's values)`` of the load or time column."""
    table = FORCE_UNITS if kind == "load" else TIME_UNITS
    example = "'Force (kN)' or 'load [N]'" if kind == "load" else "'Time (s)' or 'Zeit [ms]'"
    if unit is None:
        raise ValueError(f"loads file {p}, row {row}: column {cell!r} has no unit; write "
                         f"it in the header, e.g. {example}")
    key = unit.replace("\u03bc", _MICRO)
    if kind == "time":
        key = key.lower()
    if key not in table:
        raise ValueError(f"loads file {p}, row {row}: the unit {unit!r} of column {cell!r} "
                         f"is not a {'force' if kind == 'load' else 'time'} unit gridstrain "
                         f"knows ({', '.join(table)})")
    return ("s", table[key]) if kind == "time" else table[key]


def _values(lay: _Layout, columns: dict[str, int], cells: list[str], p
            ) -> tuple[np.ndarray, dict[str, list[str]], dict[str, np.ndarray], bool]:
    """``(rows, texts, numbers, decimal comma)``: the row numbers of the values, the
    text of the used columns and the numbers of the numeric ones, by kind."""
    n = len(cells)
    rows = np.array([r for r, _ in lay.body], dtype=np.int64)
    texts: dict[str, list[str]] = {k: [] for k in columns}
    lines = (line for _, line in lay.body)
    parsed = (ln.split() for ln in lines) if lay.delimiter is None else \
        csv.reader(lines, delimiter=lay.delimiter)
    done = 0
    try:
        for done, fields in enumerate(parsed):
            if len(fields) != n:
                raise ValueError(f"loads file {p}, row {rows[done]}: {len(fields)} value(s) "
                                 f"for the {n} column(s) of the header (row "
                                 f"{lay.header_row})")
            for kind, k in columns.items():
                texts[kind].append(fields[k].strip())
    except csv.Error as exc:
        row = rows[done + 1] if texts["load"] else rows[0]
        raise ValueError(f"loads file {p}, row {row}: {exc} (csv module; a field over "
                         f"{csv.field_size_limit() // 1024} KiB is no load or time)") from None
    comma = False
    numbers = {}
    for kind, k in columns.items():
        if kind == "state":
            continue
        values = texts[kind]
        has_comma = any("," in t for t in values)
        try:
            numbers[kind] = np.array([t.replace(",", ".") for t in values] if has_comma
                                     else values, dtype=np.str_).astype(np.float64)
            ok = bool(np.all(np.isfinite(numbers[kind])))
        except ValueError:
            ok = False
        if not ok or (has_comma and lay.delimiter == ","):
            for row, t in zip(rows, values, strict=True):  # the first bad row, by name
                if not _is_number(t) or not math.isfinite(float(t.replace(",", "."))):
                    raise ValueError(f"loads file {p}, row {row}: column {cells[k]!r} must "
                                     f"hold a finite number, got {t!r}")
        comma = comma or has_comma
    return rows, texts, numbers, comma


def _refuse_constant(load: np.ndarray, cell: str, p) -> None:
    """A load column that never changes is the wrong column or a channel not recorded:
    no modulus could be fitted to it."""
    if load.size >= 2 and np.all(load == load[0]):
        what = "0 (all zero)" if load[0] == 0 else f"{load[0]:g} (constant)"
        raise ValueError(f"loads file {p}: every value of the load column {cell!r} is "
                         f"{what}; choose the column of the force with --load-column "
                         "(load_column) or check that the load channel was recorded")


def _refuse_backwards(time: np.ndarray, rows: np.ndarray, cell: str, p) -> None:
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"loads file {p}, row {rows[i + 1]}: the time goes backwards or "
                         f"stands still ({cell!r}: {time[i + 1]:.9g} s after {time[i]:.9g} s "
                         f"in row {rows[i]}); the times of a log must increase")


def read_loads(path, *, states, reference: str | None = None, times=None,
               load_column: str | None = None, time_column: str | None = None,
               offset: float = 0.0) -> LoadTable:
    """Read the load (and the time) of every state from a testing machine's export.

    The file is read as the machine wrote it (delimiter, decimal comma, preamble,
    units in the header, encoding: see Notes). A ``state``
    column names the state of each row (every state once, in any order; a row
    naming ``reference``, a frame the camera dropped or one before the first state
    is skipped and said: see Notes). Otherwise, with ``times`` and a time column,
    the log is joined to the states by time; else it holds one row per state, in
    their order.

    Parameters
    ----------
    path : str or os.PathLike
        The file (CSV, semicolon- or tab-separated, or columns apart by spaces).
    states : sequence of str
        The states' names, in the order measured
        (:attr:`gridstrain.results.SeriesResult.names` less the reference).
    reference : str, optional
        The reference's name: a row of a ``state`` column naming it is skipped.
    times : (n_states,) array_like, optional
        The states' times on the camera's clock, s (frame number over the frame
        rate, or the camera's time stamps). With a time column in the file, each
        state's load is the log's, linearly interpolated at ``times + offset``.
    load_column, time_column : str, optional
        The name of the load or time column (without its unit, or as written; case
        ignored). By default the column whose name says it.
    offset : float
        The time on the log's clock at the camera's time zero, s: a log started
        0.2 s before the camera's trigger has ``offset = 0.2``.

    Returns
    -------
    LoadTable
        The loads in N, kN, MN or lbf, the states' times in s, and how they were
        read (:attr:`LoadTable.source`, with the file's SHA-256).

    Raises
    ------
    ValueError
        A file that cannot be decoded or has no header above a row of numbers, a
        load column that is missing, ambiguous, without a known force unit,
        constant or all zero, a time that goes backwards, a row of another length
        or with a value that is not a finite number, a state named twice or
        unknown, a state outside the log's time span, or not one row per state:
        the message names the file and the row (rows numbered from 1 as a text
        editor shows the lines) or the state.
    FileNotFoundError
        ``path`` does not exist.

    Notes
    -----
    **How the file is read.**
    The bytes are decoded as UTF-8 (a byte-order mark skipped), UTF-16 with a
    byte-order mark, or else Windows-1252 (cp1252, the encoding of the exports of
    Windows software, where ``µ`` is one byte); anything else is refused naming the
    file and the row. Lines are split into fields by the standard library's
    :mod:`csv` reader (quotes, and its field-size limit of 128 KiB, turned into one
    line naming the row). The delimiter is the first of tab, ``;`` and ``,`` under
    which a header line is followed by a row of numbers with as many fields, else
    runs of white space. The header is the line of text (no field a number) with
    the longest run of such rows below it (a preamble of "name;value" lines has
    short ones), or one line of units and then the rows; the lines above it are the
    preamble and are skipped, as are blank lines and lines beginning with ``#``.
    With ``;``, tab or white space between the fields, a comma in a number is its
    decimal mark.

    **Columns and units.**
    The load column is the one named ``load_column``, else the one whose name
    holds ``load``, ``force``, ``Kraft`` or is ``F``; the time column the one named
    ``time_column``, else one holding ``time``, ``Zeit`` or named ``t``. Units are
    read from brackets or parentheses (``Load [N]``, ``Force (kN)``), a slash
    (``Zeit / ms``) or the line of units. Loads stay in N, kN, MN or lbf (mN and daN
    are converted to N, lb to lbf, kip to 1000 lbf); times are converted to s (from
    µs, ms, s, min, h).

    **Joining the log to the states.**
    With a ``state`` column, each row names its state. Where the states' names are
    the numbered frames of one record (``f011``, ``f012``..., one group of digits
    varying, written with as many digits), a row naming a frame of that numbering
    that was not measured is skipped, not refused, when its number lies before the
    last state's: a frame the camera dropped (``f014`` between ``f013`` and
    ``f015``) or one before the first state (the reference's own frames); the
    table's :attr:`~LoadTable.notes` name those rows. Any other name that is not a
    state's is refused, and every state needs its row. Otherwise, when the states'
    times on the camera's clock are known (``times``: the frame rate or the camera's
    time stamps) and the file has a time column, each state's load is the log's
    load linearly interpolated at ``time + offset`` on the log's clock, ``offset``
    being the log's time at the camera's time zero: a log started 0.2 s before the
    camera's trigger has ``offset = 0.2``. Otherwise the file holds one row per
    state, in their order, and its time column (less ``offset``) gives the states'
    times.

    Interpolation is linear between the two rows around each state's time, the
    exact load at a row's time: for rows ``h`` s apart its error is at most
    ``h**2 / 8 max|F''|`` (1.25e-5 s² times the load's second derivative for a
    100 Hz log), below the last digit of most exports. No extrapolation: a state
    before the first or after the last row is refused.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (d / "log.csv").write_text("Zeit [ms];Kraft [kN]\\n0;0,0\\n100;1,0\\n200;2,0\\n")
    >>> t = read_loads(d / "log.csv", states=["a", "b"], times=[0.05, 0.12], offset=0.0)
    >>> t.unit, t.load.tolist(), t.source["decimal"]
    ('kN', [0.5, 1.2], ',')
    """
    p = as_path(path, "loads")
    names = [str(s) for s in states]
    offset = check_finite(offset, "offset")
    if times is not None:
        times = np.array(times, dtype=np.float64).reshape(-1)
        if times.shape != (len(names),) or not np.all(np.isfinite(times)):
            raise ValueError(f"times must hold one finite time per state ({len(names)}), "
                             f"got {times.tolist()}")
    if not p.is_file():
        raise FileNotFoundError(f"loads file {p} does not exist")
    raw = p.read_bytes()
    text, encoding = _decode(raw, p)
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise ValueError(f"loads file {p} is empty: expected a header such as "
                         "'Time (s);Force (kN)' above the rows of values")
    lay = _find_layout(lines, p)
    cells, row = lay.header, lay.header_row
    parsed = [_name_and_unit(c) for c in cells]
    col_names = [n for n, _ in parsed]
    units = [u if u is not None or lay.units is None else _unit_cell(lay.units[k])
             for k, (_, u) in enumerate(parsed)]
    columns = {}
    states_at = [k for k, n in enumerate(col_names) if n.lower() == "state"]
    if states_at:
        columns["state"] = states_at[0]
    columns["load"] = _column("load", load_column, col_names, cells, p, row, required=True)
    ti = _column("time", time_column, col_names, cells, p, row,
                 required=time_column is not None)
    if ti is not None:
        if ti == columns["load"]:
            raise ValueError(f"loads file {p}, row {row}: the load and the time column are "
                             f"both {cells[ti]!r}; choose them with --load-column and "
                             "--time-column")
        columns["time"] = ti
    unit, load_factor = _unit("load", units[columns["load"]], cells[columns["load"]], p, row)
    time_factor = _unit("time", units[ti], cells[ti], p, row)[1] if ti is not None else None
    rows, texts, numbers, comma = _values(lay, columns, cells, p)
    load_log = numbers["load"] * load_factor
    time_log = numbers["time"] * time_factor if ti is not None else None
    _refuse_constant(load_log, cells[columns["load"]], p)
    notes: tuple = ()
    if "state" in columns:
        if times is not None and ti is not None:
            raise ValueError(f"loads file {p}: a 'state' column and a time column while the "
                             "states' times are known (the frame rate or the camera's time "
                             "stamps); give a log without a state column to join by time")
        load, time, notes = _by_state(names, reference, rows, texts["state"], load_log,
                                      time_log, p)
        method = "state column"
    elif times is not None and ti is not None:
        _refuse_backwards(time_log, rows, cells[ti], p)
        load = _interpolated(times, offset, time_log, load_log, names, p)
        time, method = times.copy(), "linear interpolation in time"
    else:
        if len(rows) != len(names):
            raise ValueError(
                f"loads file {p}: {len(rows)} row(s) of values for {len(names)} state(s): "
                "give one row per state, in their order, a 'state' column naming them, or "
                "a time column and the states' times (the frame rate) to join a log by time")
        if time_log is not None:
            _refuse_backwards(time_log, rows, cells[ti], p)
        load, time, method = load_log.copy(), None, "one row per state"
        if time_log is not None:
            time = time_log - offset
    if time is not None and "state" in columns:
        bad = np.flatnonzero(np.diff(time) <= 0)
        if bad.size:
            raise ValueError(f"loads file {p}: the time of state {names[bad[0] + 1]!r} "
                             f"({time[bad[0] + 1]:.9g} s) is not after that of "
                             f"{names[bad[0]]!r} ({time[bad[0]]:.9g} s); the states' times "
                             "must increase")
    if ti is None and offset != 0.0:
        raise ValueError(f"loads file {p}: offset (--loads-offset) {offset:g} s but no time "
                         "column to shift")
    source = {
        "file": os.path.abspath(p), "sha256": hashlib.sha256(raw).hexdigest(), "encoding": encoding,
        "delimiter": "whitespace" if lay.delimiter is None else
        "none (one column)" if len(lay.header) == 1 else lay.delimiter,
        "decimal": "," if comma else ".", "header_row": int(row), "rows": len(rows),
        "load_column": cells[columns["load"]], "load_unit": units[columns["load"]],
        "load_factor": float(load_factor),
        "time_column": cells[ti] if ti is not None else None,
        "time_unit": units[ti] if ti is not None else None,
        "time_factor": time_factor, "offset_s": float(offset), "method": method,
    }
    return LoadTable(load=load, unit=unit, time=time, source=source, notes=notes)


def _interpolated(times: np.ndarray, offset: float, time_log: np.ndarray,
                  load_log: np.ndarray, names: list[str], p) -> np.ndarray:
    """The log's load at each state's time on its clock (``times + offset``), linearly
    interpolated; a state outside the log's span refused by name."""
    at = times + offset
    lo, hi = float(time_log[0]), float(time_log[-1])
    # 1 ns: far below any log's period, far above the rounding of times + offset
    tol = 1e-9
    out = np.flatnonzero((at < lo - tol) | (at > hi + tol))
    if out.size:
        i = int(out[0])
        raise ValueError(f"loads file {p}: state {names[i]!r} at {times[i]:.9g} s on the "
                         f"camera's clock ({at[i]:.9g} s on the log's, offset {offset:g} s) "
                         f"lies outside the log's time span, {lo:.9g} to {hi:.9g} s"
                         + (f" ({out.size} state(s) outside)" if out.size > 1 else ""))
    return np.interp(np.clip(at, lo, hi), time_log, load_log)


def _by_state(names, reference, rows, labels, load_log, time_log, p):
    """Loads (and times) of a file whose ``state`` column names each row's state, and
    the finding naming the rows skipped as frames the record lacks (:func:`_lacked`)."""
    index = {n: i for i, n in enumerate(names)}
    load = np.full(len(names), np.nan)
    time = None if time_log is None else np.full(len(names), np.nan)
    seen: dict[int, int] = {}
    skipped = False
    lacked = _lacked(names)
    dropped: list[tuple[int, str]] = []
    before: list[tuple[int, str]] = []
    for k, (row, name) in enumerate(zip(rows, labels, strict=True)):
        if reference is not None and name == reference and name not in index \
                and not skipped:
            skipped = True
            continue
        where = None if name in index else lacked(name)
        if where is not None:
            (dropped if where == "dropped" else before).append((int(row), name))
            continue
        if name not in index:
            raise ValueError(f"loads file {p}, row {row}: state {name!r} is not one of "
                             f"the states measured ({', '.join(names[:3])}"
                             f"{', ...' if len(names) > 3 else ''})")
        i = index[name]
        if i in seen:
            raise ValueError(f"loads file {p}, row {row}: state {name!r} already given "
                             f"in row {seen[i]}")
        seen[i] = int(row)
        load[i] = load_log[k]
        if time is not None:
            time[i] = time_log[k]
    if len(seen) != len(names):
        missing = [n for i, n in enumerate(names) if i not in seen]
        raise ValueError(f"loads file {p}: no row for {len(missing)} state(s) "
                         f"({', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''})")
    return load, time, _lacked_notes(p, dropped, before)


def _lacked(names):
    """``lacked(label)``: ``"dropped"`` where ``label`` names a frame of the record
    whose numbered frames the states ``names`` are (one template, one group of digits
    varying: :func:`gridstrain.io._numbering._numbers_from_names`, each name as long
    as the others where theirs are) that no state is, between the first state's
    number and the last's; ``"before"`` below the first's; None otherwise (not of the
    numbering, or after the last state: refused by the caller)."""
    numbers = _numbers_from_names(list(names)) if len(names) >= 2 else None
    if numbers is None:
        return lambda label: None
    lengths = {len(n) for n in names}
    first, last = min(numbers), max(numbers)

    def lacked(label):
        if len(lengths) == 1 and len(label) not in lengths:
            return None  # f14 beside f011 ... f017: not written as their numbers
        # of the family when adding it leaves one group of digits varying
        with_label = _numbers_from_names([*names, label])
        n = None if with_label is None else with_label[-1]
        if n is None or n in numbers or n > last:
            return None
        return "dropped" if n > first else "before"

    return lacked


def _lacked_notes(p, dropped, before) -> tuple:
    """The finding naming the rows skipped as frames the record lacks."""
    if not dropped and not before:
        return ()

    def listed(pairs):
        more = ", ..." if len(pairs) > 5 else ""
        return (", ".join(n for _, n in pairs[:5]) + more + " (row(s) "
                + ", ".join(str(r) for r, _ in pairs[:5]) + more + ")")

    parts = []
    if dropped:
        parts.append(f"{len(dropped)} row(s) name frames the record lacks between its "
                     f"states (dropped by the camera?): {listed(dropped)}")
    if before:
        parts.append(f"{len(before)} row(s) name frames before its first state (the "
                     f"reference's?): {listed(before)}")
    skipped = sorted(dropped + before)  # in the file's order
    return (Finding("input", f"loads file {p.name}: " + "; ".join(parts)
                    + "; their loads are not used",
                    rows=[r for r, _ in skipped], states=[n for _, n in skipped]),)
