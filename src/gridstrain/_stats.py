"""Order statistics of large maps.

``np.median`` partially sorts around both middle elements of an even-sized array,
several times the cost of one partial sort around the upper middle
(benchmarks/README.md). The pipeline takes a
dozen such medians per state (the moduli, the uncertainty floors, the regions
without a grid), so :func:`median` takes the lower middle as the maximum of the
lower half instead. Most of them are of a boolean-mask gather, a fresh array that
``overwrite_input=True`` sorts in place rather than copying once more. From
``_BRACKET_MIN`` values on, the two middle values are selected among the few values
that a sorted subsample brackets them with (:func:`_middle_pair`), read in three
passes over the data instead of a partial sort of all of it: the same two values.
:func:`middle_values` gives those two values themselves, for the medians of several
maps that are non-decreasing functions of one (the uncertainty floors).
:func:`row_medians` does the same along the rows of a table.
"""

from __future__ import annotations

import math

import numpy as np

__all__: list[str] = []

# Values from which the middle pair is bracketed by a subsample of about
# _BRACKET_SAMPLE values first; the bracket spans 3 sqrt(sample) of the subsample's
# ranks on each side of the middle, six times the spread of the middle's rank in it.
_BRACKET_MIN = 2**14
_BRACKET_SAMPLE = 2048


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
        values = values.astype(np.float64)
        overwrite_input = True
    if values.size == 0:
        return float("nan")
    lower, upper = middle_values(values, overwrite_input=overwrite_input)
    return float(upper) if values.size % 2 else float((lower + upper) / 2)


def middle_values(values, *, overwrite_input: bool = False) -> tuple:
    """``(lower, upper)``: the values of ranks ``(n - 1) // 2`` and ``n // 2`` of the
    ``n`` float ``values`` (the two middle ones of an even count, the middle one twice
    of an odd count), scalars of their dtype; NaN and NaN when a value is NaN or there
    is none. ``values`` as for :func:`median`.

    :func:`median` is ``upper`` of an odd count and ``(lower + upper) / 2`` of an even
    one: the median of ``f(values)``, ``f`` non-decreasing (a square root, a product
    by a positive number, each rounded), is ``f`` of these two, whose ranks ``f``
    keeps: one selection for the medians of several such maps of one quantity.
    """
    values = np.asarray(values)
    nan = (math.nan, math.nan)
    if values.size >= _BRACKET_MIN:
        flat = values.reshape(-1)  # a copy only if values is not contiguous
        if np.isnan(flat).any():
            return nan
        pair = _middle_pair(flat)
        if pair is not None:
            return (pair[1], pair[1]) if flat.size % 2 else pair
    if overwrite_input and values.flags.c_contiguous:
        flat = values.reshape(-1)
    else:
        flat = np.array(values, copy=True).reshape(-1)
    n = flat.size
    if n == 0:
        return nan
    k = n // 2
    flat.partition(k)
    # a NaN sorts above every number: it is at k or above it
    if np.isnan(flat[k:]).any():
        return nan
    if n % 2:
        return flat[k], flat[k]
    return flat[:k].max(), flat[k]


def _middle_pair(flat: np.ndarray):
    """The values of ranks ``n // 2 - 1`` and ``n // 2`` of ``flat`` (n values, no NaN),
    or None when the subsample's bracket misses them.

    A sorted strided subsample gives two values ``lo <= hi`` whose ranks in ``flat``
    should enclose the middle; counting the values below ``lo`` and gathering those
    in ``[lo, hi]`` (a few percent of them) says whether they do, and the middle
    pair is then selected among the gathered ones, offset by the count: exact
    order statistics whatever the subsample, which only sets the work.
    """
    n = flat.size
    k = n // 2
    sample = np.sort(flat[::max(1, n // _BRACKET_SAMPLE)])
    m = sample.size
    half = 3 * math.sqrt(m) + 2
    lo = sample[max(0, math.floor(k / n * m - half))]
    hi = sample[min(m - 1, math.ceil(k / n * m + half))]
    # no NaN: the values below lo are those not at or above it (one comparison fewer
    # over the data)
    inside = flat >= lo
    below = n - int(np.count_nonzero(inside))
    inside &= flat <= hi
    # np.compress gathers through the indices of the True values, found without a
    # branch per value: a boolean index branches on each, and the bracket's values lie
    # scattered through a noisy map (3 times as long on 100,000 values, numpy 2.4)
    among = np.compress(inside, flat)
    if not below <= k - 1 or not k < below + among.size:
        return None
    among.partition((k - 1 - below, k - below))
    return among[k - 1 - below], among[k - below]


def row_medians(table: np.ndarray) -> np.ndarray:
    """``np.median(table, axis=-1)`` of a float array, partially sorting ``table`` in
    place (it is overwritten, as with ``overwrite_input=True``).

    One partial sort of each row around its upper middle, the lower middle the
    maximum of the lower half (a fraction of ``np.median``'s time on the noise
    estimate's table of tile periodograms). Rows holding a NaN give NaN.
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


# A histogram pass narrows each wanted rank to one of this many bins; the values
# of the bins left are gathered once they number at most _GATHER (32 MiB).
_NARROW_BINS = 4096
_GATHER = 2**22


def streamed_percentiles(chunks, q, *, gather: int = _GATHER):
    """``(count, min, max, percentiles)`` of all the values that ``chunks()`` yields
    (1-D float64 arrays, finite), with memory for ``gather`` values, not for all.

    ``chunks`` is called once per pass over the data (a few: one for the count and
    the extremes, then histograms that narrow each order statistic the percentiles
    need to a bin, until the values of those bins fit in ``gather`` and are sorted).
    The percentiles are those of ``np.percentile(all, q)`` (linear interpolation
    between the two order statistics about rank ``(n - 1) q / 100``), from the same
    order statistics; NaN for no value.
    """
    qs = np.atleast_1d(np.asarray(q, dtype=np.float64))
    n, lo, hi = 0, math.inf, -math.inf
    for c in chunks():
        if c.size:
            n += c.size
            lo, hi = min(lo, float(c.min())), max(hi, float(c.max()))
    if n == 0:
        return 0, math.nan, math.nan, np.full(qs.shape, np.nan)
    h = (qs / 100) * (n - 1)
    below = np.floor(h).astype(np.int64)
    ranks = sorted({int(r) for b in below for r in (b, min(b + 1, n - 1))})
    found = _order_statistics(chunks, ranks, lo, hi, n, gather)
    a = np.array([found[int(b)] for b in below])
    b = np.array([found[min(int(b) + 1, n - 1)] for b in below])
    t = h - below
    # numpy's own interpolation (a + (b - a) t, from b's side when t >= 1/2)
    d = b - a
    out = np.where(t >= 0.5, b - d * (1 - t), a + d * t)
    return n, lo, hi, out


def _order_statistics(chunks, ranks, lo, hi, n, gather) -> dict:
    """The values at the 0-based ``ranks`` of the ``n`` values of ``chunks``, which
    span ``[lo, hi]``."""
    # each open rank: the closed interval its value lies in, and how many values lie
    # below the interval
    open_ = dict.fromkeys(ranks, (lo, hi, 0))
    found = {}
    for step in range(64):  # each pass divides an interval by _NARROW_BINS, or settles it
        boxes = sorted({(a, b) for a, b, _ in open_.values()})
        inside = [0] * len(boxes)
        low, high = [math.inf] * len(boxes), [-math.inf] * len(boxes)
        if step == 0:  # the whole span, counted already
            inside, low, high = [n], [lo], [hi]
        for c in chunks() if step else ():
            for j, (a, b) in enumerate(boxes):
                v = c[(c >= a) & (c <= b)]
                if v.size:
                    inside[j] += v.size
                    low[j], high[j] = min(low[j], float(v.min())), max(high[j], float(v.max()))
        # each interval shrunk to the values in it (none lie between its ends and
        # theirs): one value left, repeated or not, is the answer
        for r, (a, b, under) in list(open_.items()):
            j = boxes.index((a, b))
            if low[j] == high[j]:
                found[r] = low[j]
                del open_[r]
            else:
                open_[r] = (low[j], high[j], under)
        if not open_:
            return found
        boxes = [(low[j], high[j]) for j in range(len(boxes)) if low[j] < high[j]]
        if sum(inside) <= gather:
            kept = [[] for _ in boxes]
            for c in chunks():
                for j, (a, b) in enumerate(boxes):
                    kept[j].append(c[(c >= a) & (c <= b)])
            for r, (a, b, under) in open_.items():
                v = np.sort(np.concatenate(kept[boxes.index((a, b))]))
                found[r] = float(v[r - under])
            return found
        # a histogram of each interval; a value equal to an inner edge counts in the
        # bin above it, the top edge in the last bin
        edges = [_edges(a, b) for a, b in boxes]
        counts = [np.zeros(_NARROW_BINS, np.int64) for _ in boxes]
        for c in chunks():
            for j, (a, b) in enumerate(boxes):
                v = c[(c >= a) & (c <= b)]
                counts[j] += np.bincount(_bins(v, edges[j]), minlength=_NARROW_BINS)
        for r, (a, b, under) in list(open_.items()):
            j = boxes.index((a, b))
            cum = np.cumsum(counts[j])
            k = int(np.searchsorted(cum, r - under, side="right"))
            e = edges[j]
            top = b if k == _NARROW_BINS - 1 else float(e[k + 1])
            open_[r] = (float(e[k]), top, under + (int(cum[k - 1]) if k else 0))
    raise RuntimeError("the order statistics did not narrow")  # pragma: no cover


def _bins(v: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The bin of each of ``v`` (within the edges' span) among the uniform ``edges``:
    ``edges[k] <= v < edges[k + 1]``, the last bin closed. Computed from the spacing,
    then set right against the edges themselves (the rounding of either may differ
    by one bin), as ``np.histogram`` does."""
    m = edges.size - 1
    with np.errstate(all="ignore"):  # a span of subnormals or beyond the largest float
        scale = m / (edges[-1] - edges[0])
        x = (v - edges[0]) * scale if np.isfinite(scale) else np.zeros(v.shape)
    k = np.nan_to_num(x, nan=0.0, posinf=m - 1, neginf=0.0).astype(np.int64)
    np.clip(k, 0, m - 1, out=k)
    k -= v < edges[k]
    k += (v >= edges[k + 1]) & (k < m - 1)
    off = (v < edges[k]) | ((v >= edges[k + 1]) & (k < m - 1))
    if off.any():  # the arithmetic more than a bin out: by the edges alone
        k[off] = np.clip(np.searchsorted(edges, v[off], side="right") - 1, 0, m - 1)
    return k


def _edges(a: float, b: float) -> np.ndarray:
    """``_NARROW_BINS`` uniform bins from ``a`` to ``b``, increasing, even where
    ``b - a`` is beyond the largest float (as the maps of a damaged file may be)."""
    t = np.linspace(0.0, 1.0, _NARROW_BINS + 1)
    e = a * (1 - t) + b * t if math.isinf(b - a) else a + (b - a) * t
    e[0], e[-1] = a, b
    return np.maximum.accumulate(np.minimum(e, b))
