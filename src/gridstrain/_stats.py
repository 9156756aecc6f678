"""Order statistics of large maps.

``np.median`` partially sorts around both middle elements of an even-sized array;
on a 1040 x 1376 modulus or uncertainty map that costs 11 to 14 ms, against 1.5 ms
for one partial sort around the upper middle (numpy 2.4). The pipeline takes a
dozen such medians per state (the moduli, the uncertainty floors, the regions
without a grid), so :func:`median` takes the lower middle as the maximum of the
lower half instead. Most of them are of a boolean-mask gather, a fresh array that
``overwrite_input=True`` sorts in place rather than copying once more.
:func:`row_medians` does the same along the rows of a table.
"""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


def median(values, *, overwrite_input: bool = False) -> float:
    """``np.median`` of ``values`` (any shape, a view is fine).

    Equal to ``float(np.median(values))``: the mean of the two middle values of an
    even count (in a float's own precision, integers in float64), NaN if any value
    is NaN, NaN (without numpy's warning) when empty. ``values`` is not modified
    unless ``overwrite_input`` and it is a contiguous float array, which is then
    partially sorted in place instead of copied.
    """
    values = np.asarray(values)
    if values.dtype.kind != "f":  # integers: their middle pair summed in float64
        flat = values.astype(np.float64).reshape(-1)
    elif overwrite_input and values.flags.c_contiguous:
        flat = values.reshape(-1)
    else:
        flat = np.array(values, copy=True).reshape(-1)
    n = flat.size
    if n == 0:
        return float("nan")
    k = n // 2
    flat.partition(k)
    # a NaN sorts above every number: it is at k or above it
    if np.isnan(flat[k:]).any():
        return float("nan")
    if n % 2:
        return float(flat[k])
    return float((flat[:k].max() + flat[k]) / 2)


def row_medians(table: np.ndarray) -> np.ndarray:
    """``np.median(table, axis=-1)`` of a float array, partially sorting ``table`` in
    place (it is overwritten, as with ``overwrite_input=True``).

    One partial sort of each row around its upper middle, the lower middle the
    maximum of the lower half: 6 ms against 24 ms for ``np.median`` on the noise
    estimate's (8320, 300) table of tile periodograms. Rows holding a NaN give NaN.
    """
    n = table.shape[-1]
    if n == 0:
        return np.full(table.shape[:-1], np.nan)
    k = n // 2
    table.partition(k, axis=-1)
    mid = table[..., k]
    out = mid.copy() if n % 2 else (table[..., :k].max(axis=-1) + mid) / 2
    # a NaN sorts above every number: at k or above it in its row
    nan = np.isnan(table[..., k:]).any(axis=-1)
    if nan.any():
        out[nan] = np.nan
    return out
