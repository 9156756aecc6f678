"""The load and time of each state: from the result, or from a CSV file of the test rig."""

from __future__ import annotations

import numpy as np

from ..io import read_loads as io_read_loads


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


def read_loads(path, names, *, times=None, load_column: str | None = None,
               time_column: str | None = None, offset: float = 0.0
               ) -> tuple[np.ndarray, str, np.ndarray | None]:
    """Loads (and times) of a result's states from a testing machine's export
    (:func:`gridstrain.io.read_loads`; a row naming the reference is skipped).

    Parameters
    ----------
    path : str or os.PathLike
        The file: a load column with its unit, optionally a time column or a
        ``state`` column.
    names : sequence of str
        The result's names, ``("reference", state 0, ...)``.
    times : (n_states,) array_like, optional
        The states' times on the camera's clock, s (the result's own,
        :attr:`gridstrain.results.SeriesResult.time`): a log with a time column is
        joined to them by linear interpolation.
    load_column, time_column : str, optional
        The columns' names (default: recognised by name).
    offset : float
        The time on the log's clock at the camera's time zero, s.

    Returns
    -------
    load : (n_states,) float64 ndarray
    load_unit : str
    time : (n_states,) float64 ndarray or None
        s, on the camera's clock.
    """
    table = io_read_loads(path, states=list(names[1:]), reference=names[0], times=times,
                          load_column=load_column, time_column=time_column, offset=offset)
    return table.load, table.unit, table.time
