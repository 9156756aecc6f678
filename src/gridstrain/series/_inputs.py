"""The inputs of a series measurement: frames in memory or on disk as series, the guesses of
the fringe order, the states' names, the mask, the loads and times, each checked against
the others before a frame is transformed.
"""

from __future__ import annotations

import numbers
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._progress import findings_of
from .._runtime import memory as _memory
from .._validation import (
    check_choice,
    check_mask,
)
from ..io import FrameSeries, StateInputs, open_series, read_mask, record_numbering
from ..phase import Lattice
from ..phase.window import min_side
from ..stacks.accumulate import motion_sums_bytes
from ..uncertainty import contrast_step_bytes


class _ArraySeries:
    """Frames held in memory, behaving like a :class:`gridstrain.io.FrameSeries`."""

    bit_depth = None
    scale = 1
    saturation_level = None
    paths: tuple = ()

    def __init__(self, data, name: str):
        arr = np.asarray(data)
        if arr.dtype == bool or arr.dtype.kind not in "uif":
            raise TypeError(f"{name} must hold real grey levels, got dtype {arr.dtype}")
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[0] < 1:
            raise ValueError(f"{name} must be one (H, W) frame or a (T, H, W) stack, got "
                             f"shape {np.shape(data)}")
        if min(arr.shape[1:]) < 8:
            raise ValueError(f"{name} frames must be at least 8 x 8 pixels, got "
                             f"{arr.shape[1:]}")
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} has NaN or infinite pixels; frames must hold finite "
                             "grey levels")
        self.name = name
        self.dtype = arr.dtype
        self.shape = (int(arr.shape[1]), int(arr.shape[2]))
        self._data = arr
        self._numbers = np.arange(arr.shape[0])  # frames kept, numbered in ``data``
        if arr.dtype.kind in "ui":  # the container's ceiling, for the screening
            self.saturation_level = int(np.iinfo(arr.dtype).max)

    @property
    def n_frames(self) -> int:
        return int(self._numbers.size)

    def __len__(self) -> int:
        return self.n_frames

    def _number(self, j: int) -> int:
        return int(self._numbers[j])

    def describe_frame(self, i: int) -> str:
        return f"frame {self._number(i)}"

    def subset(self, indices) -> _ArraySeries:
        out = object.__new__(_ArraySeries)
        out.__dict__.update(self.__dict__)
        out._numbers = self._numbers[np.asarray(indices, dtype=int)]
        return out

    def frames(self, *, dtype=np.float64, start: int = 0, stop: int | None = None):
        return (np.array(self._data[t], dtype=dtype) for t in self._numbers[start:stop])

    def mean(self, *, start: int = 0, stop: int | None = None, progress=None):
        sub = self._numbers[start:stop]
        acc = np.zeros(self.shape)
        for t in sub:
            acc += self._data[t]
        return acc / len(sub)


def _as_series(source, name: str, bit_depth):
    if isinstance(source, FrameSeries):
        return source
    if isinstance(source, np.ndarray):
        return _ArraySeries(source, name)
    if isinstance(source, str | os.PathLike | list | tuple):
        return open_series(source, name=name, bit_depth=bit_depth)
    raise TypeError(f"{name} must be a FrameSeries, a path, a glob pattern, a list of "
                    f"files or an array of frames, got {type(source).__name__}")


def _check_one_guess(guess, what: str):
    """One state's guess: "auto", None, a finite (u_x, u_y) pair or a (2, H, W) field."""
    if isinstance(guess, str):
        check_choice(guess, what, ("auto",))
        return guess
    if guess is None:
        return None
    try:
        g = np.asarray(guess, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be 'auto', None, a (u_x, u_y) pair or a (2, H, W) "
                         f"field in px, got {guess!r}") from None
    if not (g.shape == (2,) or (g.ndim == 3 and g.shape[0] == 2)) \
            or not np.all(np.isfinite(g)):
        raise ValueError(f"{what} must be 'auto', None, a finite (u_x, u_y) pair or a "
                         f"finite (2, H, W) field in px, got shape {g.shape}")
    return (float(g[0]), float(g[1])) if g.shape == (2,) else g


def _is_per_state(guess) -> bool:
    """A sequence of per-state guesses, rather than one pair (numbers) or one field."""
    if isinstance(guess, str) or guess is None or isinstance(guess, np.ndarray):
        return False
    if isinstance(guess, Sequence):
        return not all(isinstance(v, numbers.Real) and not isinstance(v, bool)
                       for v in guess)
    return False


def _check_guess(guess, n_states: int, order: str) -> list:
    """One guess per state ("auto", None, a pair or a field).

    A single guess fixes the first state in series order (the others follow it) and
    every state in independent order.
    """
    if _is_per_state(guess):
        if len(guess) != n_states:
            raise ValueError(f"guess must hold one entry per loaded state ({n_states}), "
                             f"got {len(guess)}")
        return [_check_one_guess(g, f"guess[{i}]") for i, g in enumerate(guess)]
    g = _check_one_guess(guess, "guess")
    if order == "series":
        return [g] + ["auto"] * (n_states - 1)
    return [g] * n_states


def _guess_parameter(guess):
    """The guess as given, JSON-friendly (a field is recorded as "field")."""
    if _is_per_state(guess):
        return [_guess_parameter(g) for g in guess]
    if isinstance(guess, str) or guess is None:
        return guess
    g = np.asarray(guess, dtype=float)
    return [float(g[0]), float(g[1])] if g.shape == (2,) else "field"


def _source_name(source, i: int) -> str:
    """A state's name from its folder or file (``"state i"`` for arrays)."""
    if isinstance(source, FrameSeries):
        return source.name
    if isinstance(source, list | tuple) and source \
            and all(isinstance(p, str | os.PathLike) for p in source):
        paths = [Path(os.fspath(p)) for p in source]
        parents = {p.parent for p in paths}
        if len(paths) > 1 and len(parents) == 1 and paths[0].parent.name:
            return paths[0].parent.name
        return paths[0].stem or f"state {i}"
    if isinstance(source, str | os.PathLike):
        p = Path(os.path.expanduser(os.fspath(source)))
        if p.is_dir():
            return p.resolve().name or f"state {i}"
        if any(ch in p.name for ch in "*?[") and p.parent.name \
                and not any(ch in str(p.parent) for ch in "*?["):
            return p.parent.name  # "run3/*.tif": the folder names the state
        return p.stem or f"state {i}"
    return f"state {i}"


def state_names(states) -> list[str]:
    """Names of the loaded states, after their folder or file stem, made unique.

    Arrays are named ``"state i"``; a name that repeats (or ``"reference"``) gets
    ``" (2)"``, ``" (3)"``... appended.
    """
    seen = {"reference": 1}
    out = []
    for i, src in enumerate(states):
        base = _source_name(src, i)
        name = base
        while name in seen:
            seen[base] = seen.get(base, 1) + 1
            name = f"{base} ({seen[base]})"
        seen[name] = 1
        out.append(name)
    return out


def _glob_warning(series) -> list[str]:
    """Warn when a shell glob seems to have made every frame a state of its own: the
    reference and every state are single frames of one folder, numbered alike."""
    if len(series) < 3 or not all(isinstance(s, FrameSeries) for s in series):
        return []
    if any(s.n_frames != 1 or len(s.paths) != 1 for s in series):
        return []
    if len({Path(s.paths[0]).resolve().parent for s in series}) != 1:
        return []
    # numbered frames of one acquisition (img_001, img_002...), not ref/load1/load2
    if len({re.sub(r"\d+", "#", Path(s.paths[0]).stem) for s in series}) != 1:
        return []
    folder = Path(series[0].paths[0]).parent
    return [f"the reference and all {len(series) - 1} states are single frames of one "
            f"folder ({folder}): if they are frames of one series, the shell expanded an "
            f"unquoted glob; quote it (\"{folder}/*.tif\") or pass the folder, and give "
            "each state its own folder or quoted glob"]


def _check_fit(shape, sigma, margin: float, guesses=()) -> None:
    """Refuse, before any frame is read, a window or a guess that cannot fit the frames."""
    H, W = shape
    if sigma is not None and min(H, W) < min_side(sigma, margin):
        top = (min(H, W) - 1) / (2 * margin)
        raise ValueError(f"sigma must be at most {top:.4g} px for frames of {H} x {W} px "
                         f"(the window and its invalid band of margin = {margin:g} sigmas "
                         f"on each side must leave a pixel), got {sigma:.4g}")
    for guess in guesses:
        if isinstance(guess, tuple) and (abs(guess[0]) >= W or abs(guess[1]) >= H):
            raise ValueError(f"guess must lie within the frame, |u_x| < {W} px and |u_y| < "
                             f"{H} px (a larger displacement leaves no pixel of the specimen "
                             f"to compare), got ({guess[0]:g}, {guess[1]:g})")


def _check_pitch_fits(shape, pitch: float, margin: float) -> None:
    """Refuse frames too small for a window of one pitch and its invalid band."""
    H, W = shape
    need = min_side(pitch, margin)
    if min(H, W) < need:
        raise ValueError(f"the frames ({H} x {W} px) are too small for the grid's pitch "
                         f"({pitch:.3g} px): a window of sigma >= the pitch with its band "
                         f"of margin = {margin:g} sigmas needs frames of at least {need} x "
                         f"{need} px")


def _specimen_mask(mask, shape) -> np.ndarray:
    """The mask given as an image file or an array, checked against the frames."""
    if isinstance(mask, str | os.PathLike):
        return read_mask(mask, shape)
    return check_mask(mask, shape)


def _file_numbers(series: list, *, from_record: bool):
    """The record's numbering from its file names (:func:`gridstrain.io.record_numbering`),
    the reference's frames first where they come from the record; None where the states
    are not one file each (pages of a file, frames of a video or camera record, arrays)."""
    record = series if from_record else series[1:]
    paths = []
    for s in record:
        if not isinstance(s, FrameSeries) or len(s.paths) != s.n_frames:
            return None
        paths.extend(s.paths)
    return record_numbering(paths)


def _loads_and_times(loads, frame_rate, series: list, *, each_frame: bool,
                     first_frame: int) -> tuple[dict, list[str]]:
    """``load``, ``load_unit``, ``time`` and ``load_source`` of the result, checked
    against the states before any frame is read, and the warnings on the record's
    numbering.

    A record of one file per frame is numbered by its file names: a missing,
    off-step or out-of-order number is named in a warning, and with ``frame_rate``
    each state's time is its number less the record's first over the rate (so that
    a dropped frame shifts no later state). Repeated numbers are refused. The states'
    times come from the record (the frame rate, else a video's time stamps); a loads
    file with a time column is then joined to them by time
    (:func:`gridstrain.io.read_loads`), else its time column gives them.
    """
    names = [s.name for s in series[1:]]
    time = None
    numbering = _file_numbers(series, from_record=first_frame > 0) if each_frame else None
    notes = findings_of(numbering.warnings, "frames.gap") if numbering is not None else []
    if frame_rate is not None:  # positive, with each_frame: checked at the door
        rate = frame_rate
        if numbering is not None:
            n = np.array(numbering.numbers, dtype=np.float64)
            time = (n[len(n) - len(names):] - n.min()) / rate
        else:
            time = (np.arange(len(names), dtype=np.float64) + first_frame) / rate
    elif each_frame:
        # the camera's own time stamps, where the file holds them (videos)
        stamps = [getattr(s, "times", None) for s in series[1:]]
        if all(t is not None and t.size == 1 for t in stamps):
            time = np.concatenate(stamps)
    load = unit = source = None
    if loads is not None:
        from ..io import LoadsFile

        if isinstance(loads, str | os.PathLike | LoadsFile):
            spec = loads if isinstance(loads, LoadsFile) else LoadsFile(loads)
            # a row naming the reference is skipped, as when a result is read
            table = spec.read(names, reference=series[0].name, times=time)
            notes += table.notes  # the rows skipped as frames the record lacks
            load, unit, source = table.load, table.unit, dict(table.source)
            time = table.time if time is None else time
        else:
            load = np.array(loads, dtype=np.float64)
            if load.shape != (len(names),) or not np.all(np.isfinite(load)):
                raise ValueError(f"loads must hold one finite number per loaded state "
                                 f"({len(names)}), got shape {load.shape}")
    return {"load": load, "load_unit": unit, "time": time, "load_source": source}, notes


def _check_memory(series: list, *, method: str, held: bool) -> None:
    """Refuse, before the first frame is transformed, a measurement whose estimated
    peak exceeds the memory available (:mod:`gridstrain._runtime.memory`)."""
    n_states = len(series) - 1
    peak = _memory.measurement_bytes(series[0].shape, method=method, n_states=n_states,
                                     held_states=held)
    # the pass over the longest series: the sums of its variance's harmonic terms
    # (gridstrain.stacks.accumulate), on top of the calibrated 4-frame figures
    peak += motion_sums_bytes(series[0].shape, max(s.n_frames for s in series))
    # the sampled checks' contrast-step bound, made while a state's transforms are
    # held: its temporaries on top (the calibrated figures predate it)
    peak += contrast_step_bytes(series[0].shape)
    H, W = series[0].shape
    advice = ("measure a smaller region (crop the frames), fewer states at once"
              + (", each state written as measured (an output file, without "
                 "--phase-maps)" if held else "")
              + ", or --memory-budget (memory_budget) if more memory is in fact free")
    # the interpreter and libraries, part of the estimate, are loaded already: what
    # the process holds counts against that fixed part (never against the pixels')
    fixed = _memory.measurement_bytes((0, 0))
    _memory.check_fits(peak - min(_memory.resident_memory(), fixed),
                       what=f"measuring {n_states} state(s) of {H} x {W} px with method "
                       f"{method} (estimated peak {_memory.format_size(peak)})",
                       advice=advice)


def _inputs(reference, given: StateInputs, guess, mask, *, bit_depth, order: str,
            sigma: float | None, margin: float, lattice: Lattice | None
            ) -> tuple[list, list, np.ndarray]:
    """The series (reference first), one guess per state and the mask, checked
    against each other."""
    if reference is None:
        raise TypeError("reference must be a series, a path or an array of frames, got "
                        "None (None only with reference_frames)")
    ref = _as_series(reference, "reference", bit_depth)
    raw_states = list(given.states)
    if given.permutation is not None and _is_per_state(guess):
        if len(guess) != len(raw_states):
            raise ValueError(f"guess must hold one entry per loaded state "
                             f"({len(raw_states)}), got {len(guess)}")
        guess = [guess[i] for i in given.permutation]  # in the order measured
    guesses = _check_guess(guess, len(raw_states), order)
    series = [ref] + [_as_series(s, name, bit_depth)
                      for s, name in zip(raw_states, state_names(raw_states), strict=True)]
    for s in series[1:]:
        if s.shape != ref.shape:
            raise ValueError(f"{s.name}: frames are {s.shape} (H, W) but the reference "
                             f"frames are {ref.shape}")
    _check_fit(ref.shape, sigma, margin, guesses)
    if lattice is not None:
        _check_pitch_fits(ref.shape, lattice.pitch, margin)
    m = _specimen_mask(mask, ref.shape)
    for i, g in enumerate(guesses):
        if isinstance(g, np.ndarray) and g.shape != (2, *ref.shape):
            raise ValueError(f"guess for {series[i + 1].name} must be a (u_x, u_y) pair or "
                             f"a field of shape {(2, *ref.shape)}, got shape {g.shape}")
    return series, guesses, m
