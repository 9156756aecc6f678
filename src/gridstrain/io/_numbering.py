"""The frame numbers of a record saved one file per frame, and the breaks in them.

A camera's software numbers the files of a record (``f000.tif``, ``f001.tif``...): the
number is the frame's place in the acquisition. A frame the software failed to save
leaves a gap (``f014``, ``f016``), a file copied twice or renamed leaves a repeated
number, and files listed by hand may come out of order. Counting the files instead of
reading their numbers would put every frame after a gap one frame early in time; so the
numbers are read from the names and every break is named.

The number of a file is the one group of digits of its name that varies across the
record's files, once the files are seen to form one numbered family (one folder, one
name pattern with the digits taken out, every name holding the same groups). Files
whose names vary in more than one group (a date and a counter) give no numbers.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

from .._progress import Finding

__all__ = ["FrameGap", "RecordNumbering", "record_numbering"]

#: What :attr:`FrameGap.kind` may say.
GAP_KINDS = ("missing", "off step", "out of order")


def _runs(numbers, step: int = 1) -> tuple[tuple[int, int], ...]:
    """Sorted ``numbers`` as runs ``(first, last)`` of consecutive numbers ``step``
    apart."""
    runs: list[list[int]] = []
    for n in sorted(numbers):
        if runs and n == runs[-1][1] + step:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    return tuple((a, b) for a, b in runs)


def _listed(runs, step: int = 1) -> str:
    """``"15, 30-34, 101"``: every number named, runs of three or more as ranges."""
    out = []
    for a, b in runs:
        if b - a >= 2 * step:
            out.append(f"{a}-{b}")
        else:
            out.extend(str(v) for v in range(a, b + 1, step))
    return ", ".join(out)


@dataclass(frozen=True)
class FrameGap:
    """A break in a record's numbering: a finding whose sentence is its ``str()``.

    Attributes
    ----------
    kind : {"missing", "off step", "out of order"}
        ``"missing"``: numbers on the record's step between its first and last frame
        that no file holds (a dropped frame); ``"off step"``: files whose number is not
        on that step; ``"out of order"``: files measured after a file of a higher
        number.
    runs : tuple of (int, int)
        The numbers concerned, every one of them, as runs ``(first, last)``
        (inclusive; ``step`` apart for ``"missing"``, 1 apart otherwise).
    files : tuple of str
        For ``"missing"``, the files on either side of the first gap; otherwise the
        files concerned (names, as in the folder).
    step : int
        The record's step between consecutive numbers (the most common one).
    """

    kind: str
    runs: tuple[tuple[int, int], ...]
    files: tuple[str, ...]
    step: int

    @property
    def count(self) -> int:
        """How many numbers the break concerns."""
        by = self.step if self.kind == "missing" else 1
        return sum((b - a) // by + 1 for a, b in self.runs)

    def __str__(self) -> str:
        n = self.count
        listed = _listed(self.runs, self.step if self.kind == "missing" else 1)
        files = ", ".join(self.files[:5]) + (", ..." if len(self.files) > 5 else "")
        if self.kind == "missing":
            every = f" (every {self.step})" if self.step > 1 else ""
            return (f"the record's file numbers skip {listed}{every}, the first after "
                    f"{self.files[0]} and before {self.files[1]}: {n} frame(s) missing "
                    "(dropped by the camera?); each state is numbered, and timed by a frame "
                    "rate, by its file's number")
        if self.kind == "off step":
            return (f"the record's file numbers step by {self.step} but {n} file(s) are off "
                    f"that step (number(s) {listed}: {files}); each state is numbered, and "
                    "timed by a frame rate, by its file's number")
        return (f"{n} file(s) of the record come after a file of a higher number (number(s) "
                f"{listed}: {files}); they are measured in the order given, each numbered, and "
                "timed by a frame rate, by its own file's number")


@dataclass(frozen=True)
class RecordNumbering:
    """The frame number of every file of a record, and the breaks in them.

    Attributes
    ----------
    numbers : tuple of int
        The number of each frame, in the order measured.
    step : int
        The most common difference between consecutive numbers, in increasing order
        (1 for a record saved whole; 5 for every fifth frame saved under its camera
        number).
    gaps : tuple of FrameGap
        The breaks: missing numbers, numbers off the step, files out of order.
    """

    numbers: tuple[int, ...]
    step: int
    gaps: tuple[FrameGap, ...]

    @property
    def warnings(self) -> tuple[Finding, ...]:
        """One finding per break (code ``frames.gap``), its sentence the break's."""
        return tuple(Finding("frames.gap", str(g), kind=g.kind, step=g.step,
                             runs=[list(r) for r in g.runs]) for g in self.gaps)


def _numbers_from_names(names: list[str]) -> list[int] | None:
    """The one varying group of digits of each name, or None (see the module)."""
    if len({re.sub(r"\d+", "#", n) for n in names}) != 1:
        return None
    groups = [re.findall(r"\d+", n) for n in names]
    if not groups[0]:
        return None
    varying = [i for i in range(len(groups[0])) if len({g[i] for g in groups}) > 1]
    if len(varying) != 1:
        return None
    return [int(g[varying[0]]) for g in groups]


def record_numbering(paths) -> RecordNumbering | None:
    """The frame numbers of a record of one file per frame, read from the file names.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        The record's files, in the order measured (the reference's frames first when
        they come from the record).

    Returns
    -------
    RecordNumbering or None
        None where the files do not form one numbered family (fewer than two files,
        several folders or name patterns, or names varying in more than one group of
        digits): their place in the list is then their only number.

    Raises
    ------
    ValueError
        Where two files carry the same number (``f14.tif`` and ``f014.tif``, or a file
        listed twice): which of them is which frame cannot be known, and neither the
        order nor the times can be trusted.

    Examples
    --------
    >>> r = record_numbering(["f013.tif", "f014.tif", "f016.tif", "f017.tif"])
    >>> r.numbers
    (13, 14, 16, 17)
    >>> print(r.gaps[0])  # doctest: +ELLIPSIS
    the record's file numbers skip 15, the first after f014.tif and before f016.tif: ...
    """
    files = [Path(p) for p in paths]
    if len(files) < 2 or len({p.parent for p in files}) != 1:
        return None
    names = [p.name for p in files]
    numbers = _numbers_from_names(names)
    if numbers is None:
        return None
    seen = Counter(numbers)
    twice = sorted(n for n, c in seen.items() if c > 1)
    if twice:
        same = [nm for nm, n in zip(names, numbers, strict=True) if n == twice[0]]
        raise ValueError(f"the record's files repeat frame number(s) "
                         f"{_listed(_runs(twice))} ({', '.join(same)} for {twice[0]}): "
                         "which file is which frame cannot be known, so neither the order "
                         "nor the times can be trusted; keep one file per number")
    ordered = sorted(numbers)
    diffs = Counter(b - a for a, b in pairwise(ordered))
    # the most common step; a tie goes to the smallest
    step = min(diffs, key=lambda d: (-diffs[d], d))
    by_number = dict(zip(numbers, names, strict=True))
    gaps = []
    lo = ordered[0]
    off = [n for n in ordered if (n - lo) % step]
    if off:
        gaps.append(FrameGap("off step", _runs(off), tuple(by_number[n] for n in off), step))
    # the missing numbers as runs between consecutive files on the step (never listed
    # one by one: a gap may span millions of numbers)
    on = [n for n in ordered if not (n - lo) % step]
    holes = [(a + step, b - step) for a, b in pairwise(on) if b - a > step]
    if holes:
        first = holes[0][0] - step
        after = min(n for n in on if n > first)
        gaps.append(FrameGap("missing", tuple(holes), (by_number[first], by_number[after]),
                             step))
    late = []
    top = numbers[0]
    for n in numbers[1:]:
        if n < top:
            late.append(n)
        top = max(top, n)
    if late:
        gaps.append(FrameGap("out of order", _runs(late), tuple(by_number[n] for n in late),
                             step))
    return RecordNumbering(tuple(numbers), step, tuple(gaps))
