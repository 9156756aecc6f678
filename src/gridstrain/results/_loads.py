"""The load and time of each state of a result: given, else the result's own."""

from __future__ import annotations

import numpy as np


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
