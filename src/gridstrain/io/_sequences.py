"""A test as a sequence of states: every frame its own state, in natural order.

gridstrain's model is the paper's: a reference *series* and loaded *series*, each a
static state imaged ``T`` times and averaged (:mod:`gridstrain.series`). A lab's
test is often a *sequence* instead: one image per load step or per camera frame (a
tensile test photographed every few seconds, a high-speed record of hundreds of
frames). :func:`state_inputs` turns what the user gives into the states to measure:

- ``each_frame=True``: every frame of the state inputs (a folder, a glob, a list
  of files, a multi-page TIFF, a ``(T, H, W)`` array) is a state of its own, named
  after its file (and its page in a file of several, ``"record[7]"``);
- ``reference_frames=N``: the reference is the first ``N`` frames of the record
  (averaged, for records that start static) and the states are the frames after;
- natural order: explicit files whose names form one numbered family
  (``frame_1.tif frame_10.tif frame_2.tif``, as a shell expands ``frame_*.tif``)
  are put in natural order (``frame_2`` before ``frame_10``), unless
  ``keep_order=True``. Folders and globs are read in natural order already
  (:func:`gridstrain.io.natural_sort_key`).

The order used is recorded (:data:`STATE_ORDERS`): ``"natural"``, ``"reordered"``
(explicit files put in natural order from the order given) or ``"given"`` (the
order the user listed, kept).
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._progress import Finding
from .._validation import check_int
from ._readers import natural_sort_key
from ._series import FrameSeries, open_series, split_frames

__all__ = ["STATE_ORDERS", "StateInputs", "natural_order", "state_inputs"]

#: What :attr:`StateInputs.order` (and ``SeriesResult.state_order``) may say.
STATE_ORDERS = ("natural", "reordered", "given")


@dataclass(frozen=True, eq=False)
class StateInputs:
    """The states to measure, once expanded and ordered by :func:`state_inputs`.

    Attributes
    ----------
    reference : FrameSeries, ndarray or None
        The reference taken from the record (``reference_frames``), else None.
    states : tuple
        One entry per loaded state, in the order measured: a
        :class:`gridstrain.io.FrameSeries`, an array, or a source as given.
    order : {"natural", "reordered", "given"}
        The order used (see the module docstring).
    permutation : tuple of int or None
        With ``"reordered"``, the index in the order given of each state.
    warnings : tuple of str
        What the user should know (a reordering, and how to keep the order given).
    """

    reference: object
    states: tuple
    order: str
    permutation: tuple[int, ...] | None
    warnings: tuple[str, ...]

    @property
    def n_states(self) -> int:
        """Number of loaded states."""
        return len(self.states)


def _is_file_path(item) -> bool:
    if not isinstance(item, str | os.PathLike):
        return False
    p = Path(os.path.expanduser(os.fspath(item)))
    return not re.search(r"[*?\[]", p.name) and p.is_file()


def _family(paths: list[Path]) -> bool:
    """Whether the files form one numbered family: one folder, one name pattern
    with its numbers taken out, and a number in every name."""
    if len(paths) < 2 or not all(re.search(r"\d", p.name) for p in paths):
        return False
    return len({p.parent for p in paths}) == 1 and \
        len({re.sub(r"\d+", "#", p.name) for p in paths}) == 1


def natural_order(sources, *, keep_order: bool = False) -> tuple[list, str, tuple | None,
                                                                 list[str]]:
    """``sources`` in the order they are measured, and how that order came about.

    Parameters
    ----------
    sources : sequence
        The states (or frames) as given: paths, globs, folders, lists, arrays...
    keep_order : bool
        Keep explicit files in the order given even when it is not natural.

    Returns
    -------
    (list, str, tuple of int or None, list of Finding)
        The sources in order; ``"natural"``, ``"reordered"`` or ``"given"``; the
        permutation applied (index in ``sources`` of each, or None); warnings, each a
        finding of code ``input`` (:class:`gridstrain.Finding`).
    """
    items = list(sources)
    if not all(_is_file_path(s) for s in items):
        return items, "given", None, []
    paths = [Path(os.path.expanduser(os.fspath(s))) for s in items]
    if not _family(paths):
        return items, "given", None, []
    perm = sorted(range(len(items)), key=lambda i: natural_sort_key(paths[i].name))
    if perm == list(range(len(items))):
        return items, "natural", None, []
    first = ", ".join(paths[i].name for i in range(min(3, len(paths))))
    if keep_order:
        return items, "given", None, [Finding(
            "input", f"the {len(items)} files are kept in the order given ({first}, ...: "
            "keep_order=True, --keep-order), which is not their natural order")]
    natural = ", ".join(paths[i].name for i in perm[:3])
    return [items[i] for i in perm], "reordered", tuple(perm), [Finding(
        "input", f"the {len(items)} files were given in the order {first}, ... (a shell's "
        f"sort) and are measured in natural order, {natural}, ...; keep_order=True "
        "(--keep-order) keeps the order given", permutation=list(perm))]


def _unique(series: list) -> list:
    """The one-frame series with their names made unique (``" (2)"``...)."""
    seen = {"reference": 1}
    out = []
    for s in series:
        if not isinstance(s, FrameSeries):
            out.append(s)
            continue
        base = name = s.name
        while name in seen:
            seen[base] = seen.get(base, 1) + 1
            name = f"{base} ({seen[base]})"
        seen[name] = 1
        out.append(s if name == s.name else dataclasses.replace(s, name=name))
    return out


def _frames_of(source, name: str, bit_depth, keep_order: bool) -> list:
    """Every frame of one input as a one-frame state."""
    if isinstance(source, np.ndarray):
        return list(source) if source.ndim == 3 else [source]
    if isinstance(source, list | tuple) and source:
        source, _, _, _ = natural_order(source, keep_order=keep_order)
    series = source if isinstance(source, FrameSeries) else \
        open_series(source, name=name, bit_depth=bit_depth)
    return split_frames(series)


def _as_list(states) -> list:
    if isinstance(states, FrameSeries | np.ndarray | str | os.PathLike):
        return [states]
    if isinstance(states, Sequence) and not isinstance(states, bytes):
        if not states:
            raise ValueError("states must hold at least one loaded state, got none")
        return list(states)
    raise TypeError(f"states must be a series or a list of series, got "
                    f"{type(states).__name__}")


def state_inputs(states, *, each_frame: bool = False, reference_frames: int | None = None,
                 keep_order: bool = False, bit_depth: int | None = None) -> StateInputs:
    """The loaded states to measure: expanded, one per frame, and in natural order.

    Parameters
    ----------
    states : series or sequence of series
        As for :func:`gridstrain.series.measure_series`.
    each_frame : bool
        Every frame of every input is a state of its own (a folder, a glob, a
        list of files, a multi-page TIFF, a ``(T, H, W)`` array); a list of
        files given as the states is opened as one record (one bit-depth
        detection).
    reference_frames : int, optional
        The reference is the first ``reference_frames`` frames of the record,
        which must lie in its first input; the states are the frames after them.
        Implies ``each_frame``.
    keep_order : bool
        Keep explicit files in the order given (see :func:`natural_order`).
    bit_depth : int, optional
        Passed to :func:`gridstrain.io.open_series`.

    Returns
    -------
    StateInputs
    """
    items = _as_list(states)
    items, order, perm, warnings = natural_order(items, keep_order=keep_order)
    if reference_frames is not None:
        reference_frames = check_int(reference_frames, "reference_frames", minimum=1)
        each_frame = True
    if not each_frame:
        return StateInputs(None, tuple(items), order, perm, tuple(warnings))
    if order == "given" and not perm and len(items) == 1:
        order = "natural"  # one folder, glob or file: its frames in natural order
    if all(_is_file_path(s) for s in items) and len(items) > 1:
        items = [list(items)]  # one record: one bit-depth detection, one name family
    frames, n_first = [], None
    for k, src in enumerate(items):
        name = Path(os.fspath(src)).name if isinstance(src, str | os.PathLike) else \
            "record" if isinstance(src, list | tuple) else ""
        got = _frames_of(src, name or f"state {k}", bit_depth, keep_order)
        if n_first is None:
            n_first = len(got)
        frames.extend(got)
    reference = None
    if reference_frames is not None:
        if reference_frames >= len(frames):
            raise ValueError(f"reference_frames must leave at least one state: the record "
                             f"has {len(frames)} frame(s), got {reference_frames}")
        if reference_frames > n_first:
            raise ValueError(f"reference_frames must lie in the record's first input "
                             f"({n_first} frame(s)), got {reference_frames}")
        reference = _reference(frames[:reference_frames])
        frames = frames[reference_frames:]
    return StateInputs(reference, tuple(_unique(frames)), order, None, tuple(warnings))


def _reference(frames: list):
    """The first frames of the record as one series, named "reference"."""
    if isinstance(frames[0], np.ndarray):
        return np.stack(frames)
    f0 = frames[0]
    table, numbers, paths, formats, times = [], [], [], [], []
    for s in frames:
        path = s.paths[0]
        if path not in paths:
            paths.append(path)
            formats.append(s._formats[0])
        _, page, n_pages = s._frames[0]
        table.append((paths.index(path), page, n_pages))
        numbers.append(s._numbers[0])
        times.extend(s._times)
    return dataclasses.replace(f0, name="reference", paths=tuple(paths), _frames=tuple(table),
                               _formats=tuple(formats), _numbers=tuple(numbers),
                               _times=tuple(times) if len(times) == len(frames) else ())
