"""The loads (and times) of a result's states from a CSV file of the test rig."""

from __future__ import annotations

import numpy as np

from ..io import read_loads as io_read_loads


def read_loads(path, names, *, times=None, load_column: str | None = None,
               time_column: str | None = None, offset: float = 0.0
               ) -> tuple[np.ndarray, str, np.ndarray | None]:
    """Loads (and times) of a result's states from a testing machine's export
    (:func:`gridstrain.io.read_loads`; a row naming the reference is skipped, and so
    is a row naming a frame the record lacks, which that function's table says).

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
