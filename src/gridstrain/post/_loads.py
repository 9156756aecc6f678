"""The loads (and times) of a result's states from a CSV file of the test rig."""

from __future__ import annotations

import numpy as np

from ..io import read_loads as io_read_loads


def read_loads(path, names) -> tuple[np.ndarray, str, np.ndarray | None]:
    """Loads (and times) of a result's states from a CSV file
    (:func:`gridstrain.io.read_loads`; a row naming the reference is skipped).

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file: ``load [UNIT]``, optionally ``state`` and ``time [s]``.
    names : sequence of str
        The result's names, ``("reference", state 0, ...)``.

    Returns
    -------
    load : (n_states,) float64 ndarray
    load_unit : str
    time : (n_states,) float64 ndarray or None
        s.
    """
    table = io_read_loads(path, states=list(names[1:]), reference=names[0])
    return table.load, table.unit, table.time
