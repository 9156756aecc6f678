"""Methods A and B on Dask: one machine's cores, or a cluster given its scheduler.

Needs the ``distributed`` extra (``pip install gridstrain[distributed]``: Dask's
arrays, its distributed scheduler and Zarr). The rest of gridstrain never imports
Dask; this module imports it inside its functions, so that ``import
gridstrain.series`` works without it and every function says what to install.

Stacks
    :func:`as_dask_stack` turns a series (anything :func:`gridstrain.io.open_series`
    opens, a :class:`gridstrain.io.FrameSeries`, a Zarr array or store, a NumPy or
    Dask array) into a lazy ``(T, H, W)`` Dask array with one task per frame (or
    per ``chunk_frames`` frames). Image files are read by the tasks themselves,
    through :class:`~gridstrain.io.FrameSeries`, with its checks (sizes, pixel
    types, NaN); on a cluster every worker must see the files at the same paths.

Method A (paper §2.2)
    :func:`mean_image_dask` averages the frames with a tree reduction in float64;
    :func:`method_a_dask` transforms the mean, as :func:`gridstrain.stacks.method_a`.

Method B (paper §2.3)
    :func:`method_b_dask` computes one windowed Fourier transform per task and
    returns the partial sums that :func:`gridstrain.stacks.method_b` accumulates
    (the sum of the unit phasors ``psi / |psi|``, of the moduli, of the phase
    derivatives, the AND of the valid maps); a tree reduction adds them
    ``split_every`` at a time, so that memory holds a few partial sums per
    worker, never every frame's maps. The result is that of
    :func:`gridstrain.stacks.method_b` up to the rounding of the additions, which
    happen in another order (about 1e-16 relative).

Series of load steps
    :func:`gridstrain.series.measure_series` takes ``scheduler=`` (see
    :func:`connect`): each series' one pass (:class:`gridstrain.stacks.accumulate.SeriesPass`:
    screening, shifts, statistics, the noise floor's halves, method B's or C's
    sums) runs in tasks of chunks of frames, merged on the workers; the same
    pass, and so the same result to the rounding of the sums, as on one machine.

Conventions are those of :mod:`gridstrain.conventions`.
"""

from __future__ import annotations

import contextlib
import itertools
import numbers
import os
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from .._runtime.threads import one_blas_thread
from .._validation import (
    check_float_dtype,
    check_int,
    check_mask,
    check_type,
    float_dtype,
)
from ..io import FrameSeries, open_series
from ..phase import DEFAULT_MARGIN, Lattice, Window, transform
from ..stacks import PhaseMean, StackResult, with_screening
from ..stacks.accumulate import SeriesPass
from ..stacks.screening import FrameProbe

__all__ = [
    "MissingDistributedError",
    "as_dask_stack",
    "connect",
    "mean_image_dask",
    "method_a_dask",
    "method_b_dask",
]

_INSTALL = ("install the distributed extra: pip install 'gridstrain[distributed]' "
            "(dask[array], distributed, zarr)")
# Partial sums added per task of the tree reductions. A method-B partial sum holds
# about 90 bytes per pixel (two complex128 phasor sums, two moduli, four
# derivatives, the valid map, the frame sum), 0.4 GB for a 2048 x 2048 camera: a
# reduction task holds 4 of them and their sum, 2 GB, which a worker can afford.
_SPLIT_EVERY = 4
# Tasks of a series' pass: enough to keep 16 worker threads busy on one series
# (every series of a run is submitted at once, so more threads still find work)
_PASS_TASKS = 16
# Frames per task at the least: each task makes and ships back its sums (80 bytes a
# pixel for method B's transforms, 48 for the pixel sums: 191 MB at 1040 x 1376),
# which costs as much as transforming about 3 frames (allocated, pickled, sent,
# added in the tree): fewer, larger tasks finish sooner (benchmarks/README.md, "Figures
# behind the code")
_MIN_CHUNK_FRAMES = 32


class MissingDistributedError(ImportError, ValueError):
    """Dask, ``distributed`` or Zarr is not installed.

    Both an ``ImportError`` (what it is) and a ``ValueError`` (so that the command
    line reports it as one line, like any bad option).
    """


def _dask():
    """``(dask, dask.array)``, or a clear error naming the extra to install."""
    try:
        import dask
        import dask.array as da
    except ImportError as exc:
        raise MissingDistributedError(f"gridstrain.series needs Dask, which cannot "
                                      f"be imported ({exc}): {_INSTALL}") from exc
    return dask, da


def _dask_config():
    """``dask.config``."""
    dask, _ = _dask()
    return dask.config


def _connect_timeout(timeout: float | None) -> float:
    """Seconds to wait for a scheduler: Dask's connection timeout, or ``timeout`` if
    shorter."""
    dask, _ = _dask()
    default = dask.utils.parse_timedelta(_dask_config().get("distributed.comm.timeouts.connect"),
                                         default="seconds")
    return default if timeout is None else min(float(timeout), default)


def _distributed():
    try:
        import distributed
    except ImportError as exc:
        raise MissingDistributedError(f"a Dask scheduler needs the 'distributed' package, "
                                      f"which cannot be imported ({exc}): {_INSTALL}") from exc
    return distributed


def _zarr():
    try:
        import zarr
    except ImportError as exc:
        raise MissingDistributedError(f"reading Zarr stores needs the 'zarr' package, "
                                      f"which cannot be imported ({exc}): {_INSTALL}") from exc
    return zarr


# --------------------------------------------------------------------------- client


def _local_workers() -> int:
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


@contextlib.contextmanager
def _without_inherited_trim(dask_value):
    """This process's environment without the ``MALLOC_TRIM_THRESHOLD_`` that a Dask
    nanny started earlier in it left there (a nanny writes its workers' variables into
    its own process's environment, which every later worker inherits), for the time
    the workers are spawned; a value of the user's own (another than Dask's) is kept."""
    name = "MALLOC_TRIM_THRESHOLD_"
    value = os.environ.get(name)
    if dask_value is None or value is None or value != str(dask_value):
        yield
        return
    del os.environ[name]
    try:
        yield
    finally:
        os.environ[name] = value


@contextlib.contextmanager
def connect(scheduler, *, n_workers: int | None = None,
            timeout: float | None = None) -> Iterator:
    """A ``distributed.Client`` for ``scheduler``, closed on exit if opened here.

    Parameters
    ----------
    scheduler : str or distributed.Client
        - the address of a running Dask scheduler, ``"tcp://HOST:PORT"`` (any
          address ``distributed.Client`` accepts; start one with ``dask scheduler``
          and workers with ``dask worker tcp://HOST:PORT``);
        - ``"local"``: a cluster on this machine, one single-threaded worker
          process per core, listening on the loopback interface only;
        - a ``distributed.Client``, used as is and left open.
    n_workers : int, optional
        Worker processes of a ``"local"`` cluster (default: the cores this process
        may use).
    timeout : float, optional
        Seconds to wait for the scheduler at an address, if shorter than Dask's
        connection timeout.

    Yields
    ------
    distributed.Client

    Raises
    ------
    MissingDistributedError
        ``distributed`` is not installed.
    OSError
        No scheduler answers at the address within Dask's connection timeout
        (``distributed.comm.timeouts.connect`` in the Dask configuration, 30 s by
        default), or within ``timeout`` if shorter.

    Notes
    -----
    Workers run gridstrain's functions and read the image files themselves: each
    must have gridstrain installed and see the files at the paths given here (a
    shared file system).
    """
    distributed = _distributed()
    if isinstance(scheduler, distributed.Client):
        yield scheduler
        return
    if not isinstance(scheduler, str) or not scheduler.strip():
        raise TypeError(f"scheduler must be 'local', a scheduler address such as "
                        f"'tcp://HOST:PORT' or a distributed.Client, got {scheduler!r}")
    address = scheduler.strip()
    if address == "local":
        n = _local_workers() if n_workers is None else n_workers
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
            raise ValueError(f"n_workers must be a positive integer, got {n_workers!r}")
        # Dask starts its workers with glibc's MALLOC_TRIM_THRESHOLD_ at 64 KiB, which
        # freezes the mmap threshold: every array of the transforms is then mapped
        # and unmapped afresh, which slows every transform down (benchmarks/README.md);
        # the workers of this cluster keep glibc's adaptive default.
        key = "distributed.nanny.pre-spawn-environ"
        configured = _dask_config().get(key, default={})
        environ = {k: v for k, v in configured.items() if k != "MALLOC_TRIM_THRESHOLD_"}
        # single-threaded processes: the transforms hold the GIL part of the time
        with _dask_config().set({key: environ}), \
                _without_inherited_trim(configured.get("MALLOC_TRIM_THRESHOLD_")):
            cluster = distributed.LocalCluster(n_workers=int(n), threads_per_worker=1,
                                               processes=True, host="127.0.0.1",
                                               # a free port: never the default 8787 (None
                                               # means 8787, and a second cluster on the
                                               # machine then raises a warning)
                                               dashboard_address=":0")
        with cluster, distributed.Client(cluster) as client:
            yield client
        return
    try:
        client = distributed.Client(address, timeout=_connect_timeout(timeout))
    except OSError as exc:
        raise OSError(f"scheduler: cannot reach a Dask scheduler at {address!r} ({exc}); "
                      "check the address and that `dask scheduler` runs there") from None
    except ValueError as exc:  # an address distributed cannot parse
        raise ValueError(f"scheduler must be 'local' or a scheduler address such as "
                         f"'tcp://HOST:PORT', got {address!r} ({exc})") from None
    with client:
        yield client


def _compute(graphs: Sequence, client):
    """Compute Dask collections together, on ``client`` when given."""
    dask, _ = _dask()
    if client is None:
        return dask.compute(*graphs)
    return dask.compute(*graphs, scheduler=client)


# --------------------------------------------------------------------------- stacks


def _check_split_every(split_every) -> int:
    if split_every is None:
        return _SPLIT_EVERY
    return check_int(split_every, "split_every", minimum=2)


def _check_chunk(chunk_frames) -> int:
    return check_int(chunk_frames, "chunk_frames", minimum=1)


def _is_zarr_path(p: Path) -> bool:
    return p.is_dir() and any((p / f).is_file() for f in ("zarr.json", ".zarray", ".zgroup"))


def _read_frames(series, start: int, stop: int, dtype) -> np.ndarray:
    """Frames ``start:stop`` of a FrameSeries, ``(n, H, W)`` (a task of the graph)."""
    return np.stack(list(series.frames(dtype=dtype, start=start, stop=stop)))


def _series_stack(series: FrameSeries, chunk: int, dtype: np.dtype | None):
    dask, da = _dask()
    # one key for the series: every task refers to it, no task carries a copy
    s = dask.delayed(series, pure=True)
    out_dtype = series.dtype if dtype is None else dtype
    H, W = series.shape
    read = dask.delayed(_read_frames, pure=True)
    blocks = []
    for start in range(0, series.n_frames, chunk):
        stop = min(start + chunk, series.n_frames)
        blocks.append(da.from_delayed(read(s, start, stop, dtype), shape=(stop - start, H, W),
                                      dtype=out_dtype))
    return da.concatenate(blocks, axis=0)


def as_dask_stack(source, *, chunk_frames: int = 1, dtype=None, name: str = "series",
                  bit_depth: int | None = None):
    """A series of frames as a lazy ``(T, H, W)`` Dask array.

    Parameters
    ----------
    source
        - a path, directory, glob pattern or list of image files, or a
          :class:`gridstrain.io.FrameSeries`: read with
          :func:`gridstrain.io.open_series`, one read task per chunk of frames
          (a multi-page TIFF is read page by page);
        - a Zarr array, or the path of a Zarr array (a directory holding
          ``zarr.json`` or ``.zarray``), frames along the first axis;
        - a ``(T, H, W)`` or ``(H, W)`` NumPy or Dask array of grey levels.
    chunk_frames : int
        Frames per chunk (per task). One by default: one task per frame.
    dtype : {None, numpy.float32, numpy.float64}
        ``None`` keeps the stored pixel type (raw grey levels).
    name : str
        What the series is, for error messages.
    bit_depth : int, optional
        Passed to :func:`gridstrain.io.open_series` for image files.

    Returns
    -------
    dask.array.Array
        ``(T, H, W)``, chunks ``(chunk_frames, H, W)``: whole frames, since each
        transform needs one.

    Raises
    ------
    MissingDistributedError
        Dask (or Zarr, for a Zarr source) is not installed.
    ValueError, TypeError, OSError
        As :func:`gridstrain.io.open_series`; arrays that are not 2-D or 3-D real
        grey levels of at least 8 x 8 pixels; a Zarr group instead of an array.
    """
    _, da = _dask()
    chunk = _check_chunk(chunk_frames)
    dt = check_float_dtype(dtype)
    if isinstance(source, FrameSeries):
        return _series_stack(source, chunk, dt)
    if isinstance(source, str | os.PathLike):
        p = Path(os.path.expanduser(os.fspath(source)))
        if _is_zarr_path(p):
            zarr = _zarr()
            try:
                source = zarr.open_array(p, mode="r")
            except Exception as exc:  # zarr's errors for a group, a bad store...
                raise ValueError(f"{name}: {p} is not a Zarr array ({exc}); for a group, "
                                 "give the path of the array inside it") from None
        else:
            return _series_stack(open_series(source, name=name, bit_depth=bit_depth),
                                 chunk, dt)
    elif isinstance(source, list | tuple):
        return _series_stack(open_series(source, name=name, bit_depth=bit_depth), chunk, dt)
    if isinstance(source, da.Array):
        arr = source
    elif _is_zarr_array(source):
        arr = da.from_zarr(source)
    elif isinstance(source, np.ndarray):
        arr = da.from_array(source, chunks=(chunk, *source.shape[1:])
                            if source.ndim == 3 else source.shape)
    else:
        raise TypeError(f"{name} must be a path, a glob pattern, a list of image files, "
                        f"a FrameSeries, a Zarr array or a NumPy/Dask array, got "
                        f"{type(source).__name__}")
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"{name} must be a (T, H, W) stack or one (H, W) frame, got shape "
                         f"{arr.shape}")
    if arr.dtype == bool or arr.dtype.kind not in "uif":
        raise TypeError(f"{name} must hold real grey levels, got dtype {arr.dtype}")
    if arr.shape[0] < 1 or min(arr.shape[1:]) < 8:
        raise ValueError(f"{name} must hold frames of at least 8 x 8 pixels, got shape "
                         f"{arr.shape}")
    if dt is not None:
        arr = arr.astype(dt)
    return arr.rechunk((chunk, -1, -1))


def _is_zarr_array(obj) -> bool:
    try:
        import zarr
    except ImportError:
        return False
    return isinstance(obj, zarr.Array)


def _stack(stack, name: str = "frames"):
    """``stack`` as a Dask array of whole frames (anything as_dask_stack takes)."""
    _, da = _dask()
    if isinstance(stack, da.Array) and stack.ndim == 3 \
            and len(stack.chunks[1]) == 1 and len(stack.chunks[2]) == 1:
        if stack.dtype == bool or stack.dtype.kind not in "uif":
            raise TypeError(f"{name} must hold real grey levels, got dtype {stack.dtype}")
        return stack
    return as_dask_stack(stack, name=name)


# --------------------------------------------------------------------------- method A


def mean_image_dask(stack, *, split_every: int | None = None):
    """Mean of a stack's frames by a tree reduction, lazily.

    Parameters
    ----------
    stack : dask.array.Array or anything :func:`as_dask_stack` takes
        ``(T, H, W)`` frames, grey levels.
    split_every : int, optional
        Chunks added per task of the reduction tree (default 4).

    Returns
    -------
    dask.array.Array
        ``(H, W)`` float64, ``v_bar = (1/T) sum_t v_t``, grey levels: accumulated in
        float64 whatever the frames' type, as :func:`gridstrain.stacks.mean_image`.
        Call ``.compute()`` (or compute it with other graphs).
    """
    arr = _stack(stack)
    k = _check_split_every(split_every)
    return arr.astype(np.float64).mean(axis=0, dtype=np.float64, split_every=k)


def _method_a_result(mean: np.ndarray, lattice, window: Window, mask, n: int,
                     dtype=np.float64) -> StackResult:
    # the float64 mean transformed in the frames' precision (gridstrain.conventions)
    maps = transform(mean.astype(dtype, copy=False), lattice, window, mask=mask)
    return StackResult(maps=maps, n_frames=n, method="A", mean_image=mean)


def _check_common(lattice, sigma, mask, margin, shape) -> tuple[Window, np.ndarray | None]:
    """The window, checked against the lattice, and the mask."""
    check_type(lattice, "lattice", Lattice)
    window = Window.for_lattice(lattice, sigma=sigma, margin=margin)
    return window, None if mask is None else check_mask(mask, shape)


def method_a_dask(stack, lattice: Lattice, *, sigma: float | None = None, mask=None,
                  margin: float = DEFAULT_MARGIN, split_every: int | None = None,
                  screen: bool = True, client=None, compute: bool = True):
    """Method A on Dask: the transform of the tree-reduced mean image (paper §2.2).

    Parameters
    ----------
    stack : dask.array.Array or anything :func:`as_dask_stack` takes
        ``(T, H, W)`` frames, grey levels.
    lattice : Lattice
        Wave vectors of the grid.
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen.
    margin : float
        Invalid band along borders and mask edges, in units of ``sigma``.
    split_every : int, optional
        Chunks added per task of the reduction tree (default 4).
    screen : bool
        Probe every frame in the tasks that read it (about 2 ms a megapixel frame)
        and name the frames the screening flags in the result's ``warnings`` and
        ``screening``, as :func:`gridstrain.stacks.method_a` does.
    client : distributed.Client, optional
        Where to compute (default: Dask's current scheduler).
    compute : bool
        False: return a ``dask.delayed`` object, to compute with other graphs.

    Returns
    -------
    StackResult or dask.delayed.Delayed
        As :func:`gridstrain.stacks.method_a`, to the rounding of the sum.
    """
    dask, _ = _dask()
    arr = _stack(stack)
    window, m = _check_common(lattice, sigma, mask, margin, arr.shape[1:])
    mean = mean_image_dask(arr, split_every=split_every)
    # the transform runs where the mean is (one task): no round trip of the image
    graph = dask.delayed(_method_a_result, pure=True)(mean, lattice, window, m,
                                                      int(arr.shape[0]),
                                                      float_dtype(arr.dtype))
    if screen:
        # the chunks' own keys: each chunk is read once for the mean and the probe
        graph = _screened(graph, arr.to_delayed(optimize_graph=False).ravel(), lattice,
                          arr.shape[1:], _check_split_every(split_every))
    return _compute([graph], client)[0] if compute else graph


def _block_records(block: np.ndarray, lattice: Lattice) -> list:
    """The screening's records of the frames of ``block``, in order (one task)."""
    probe = FrameProbe(lattice, block.shape[1:])
    return [probe(np.asarray(frame)) for frame in block]


def _joined(*parts) -> list:
    """The records of consecutive chunks, in order (a node of a reduction tree)."""
    return [r for part in parts for r in part]


def _screened_result(res: StackResult, lattice: Lattice, shape, records) -> StackResult:
    """``res`` with the screening of its frames' ``records``, in frame order."""
    return with_screening(res, records, FrameProbe(lattice, shape))


def _screened(graph, blocks, lattice: Lattice, shape, split_every: int):
    """``graph``'s result with the screening of the frames of ``blocks``; the
    records (a few hundred bytes a frame) gathered by a tree like the sums."""
    dask, _ = _dask()
    leaf = dask.delayed(_block_records, pure=True)
    parts = [leaf(block, lattice) for block in blocks]
    records = _tree(parts, _joined, split_every)
    return dask.delayed(_screened_result, pure=True)(graph, lattice, tuple(shape), records)


# --------------------------------------------------------------------------- method B


def _block_sums(block: np.ndarray, lattice, window: Window, mask) -> PhaseMean:
    """Method B's sums over the frames of ``block``, one transform at a time (one
    task)."""
    acc = PhaseMean()
    for frame in block:
        acc.add_frame(frame, lattice, window, mask=mask)
    if acc.n == 0:
        raise ValueError("frames must hold at least one image, got none")
    return acc


def _merged(*parts):
    """Sum of partial sums (a node of a reduction tree: method B's sums or series'
    passes, anything with a ``merge``); the inputs are not changed."""
    acc = parts[0]
    for p in parts[1:]:
        acc = acc.merge(p)
    return acc


def _method_b_result(acc: PhaseMean) -> StackResult:
    """gridstrain.stacks.method_b's result from the sums over every frame."""
    return acc.result()


def _tree(parts: list, combine, split_every: int):
    """Reduce delayed ``parts`` with ``combine``, ``split_every`` at a time."""
    dask, _ = _dask()
    node = dask.delayed(combine, pure=True)
    while len(parts) > 1:
        parts = [node(*parts[i:i + split_every]) if len(parts[i:i + split_every]) > 1
                 else parts[i] for i in range(0, len(parts), split_every)]
    return parts[0]


def _method_b_graph(arr, lattice, window: Window, mask, split_every, screen: bool = False):
    dask, _ = _dask()
    # one key for the mask: the tasks refer to it instead of each carrying a copy
    m = None if mask is None else dask.delayed(mask, pure=True)
    leaf = dask.delayed(_block_sums, pure=True)
    blocks = arr.to_delayed().ravel()
    parts = [leaf(block, lattice, window, m) for block in blocks]
    graph = dask.delayed(_method_b_result, pure=True)(_tree(parts, _merged, split_every))
    # the probe reads the chunks the sums read (the same keys: one read each)
    return _screened(graph, blocks, lattice, arr.shape[1:], split_every) if screen \
        else graph


def method_b_dask(stack, lattice: Lattice, *, sigma: float | None = None, mask=None,
                  margin: float = DEFAULT_MARGIN, split_every: int | None = None,
                  screen: bool = True, client=None, compute: bool = True):
    """Method B on Dask: one transform per task, the sums tree-reduced (paper §2.3).

    Parameters
    ----------
    stack : dask.array.Array or anything :func:`as_dask_stack` takes
        ``(T, H, W)`` frames, grey levels; one task per chunk of frames (one frame
        per chunk from :func:`as_dask_stack` by default).
    lattice : Lattice
        Wave vectors of the grid.
    sigma : float, optional
        Window standard deviation, px (default: the pitch).
    mask : (H, W) bool array_like, optional
        True on the specimen.
    margin : float
        Invalid band along borders and mask edges, in units of ``sigma``.
    split_every : int, optional
        Partial sums added per task of the reduction tree (default 4).
    screen : bool
        Probe every frame in the tasks that read it and name the frames the
        screening flags in the result's ``warnings`` and ``screening``, as
        :func:`gridstrain.stacks.method_b` does.
    client : distributed.Client, optional
        Where to compute (default: Dask's current scheduler).
    compute : bool
        False: return a ``dask.delayed`` object, to compute with other graphs.

    Returns
    -------
    StackResult or dask.delayed.Delayed
        As :func:`gridstrain.stacks.method_b`, to the rounding of the sums.

    Notes
    -----
    Each task transforms its frames one at a time and returns the sums method B
    needs; memory holds at most ``split_every`` partial sums per reduction task
    (about 90 bytes per pixel each) and never the frames' maps together.
    """
    arr = _stack(stack)
    window, m = _check_common(lattice, sigma, mask, margin, arr.shape[1:])
    k = _check_split_every(split_every)
    graph = _method_b_graph(arr, lattice, window, m, k, screen=bool(screen))
    return _compute([graph], client)[0] if compute else graph


# --------------------------------------------------------------------------- states


# --------------------------------------------------------------------------- pipeline


def _first_frame(series) -> np.ndarray:
    return next(iter(series.frames(dtype=np.float64, start=0, stop=1)))


class _Pending:
    """A submitted computation and the scattered data it reads.

    The scattered data stay on the workers as long as this object lives (a
    ``distributed.Future`` released by its last reference may be deleted before
    the tasks that read it have run).
    """

    def __init__(self, future, scattered, what: str = "a series"):
        self._future = future
        self._scattered = scattered
        self._what = what

    def result(self, timeout: float | None = None):
        """The result, waiting at most ``timeout`` seconds (None: for ever)."""
        try:
            return self._future.result(timeout=timeout)
        except TimeoutError:
            if not self._future.done():
                raise TimeoutError(
                    f"the Dask cluster returned no result for {self._what} within "
                    f"{timeout:g} s; check that its workers run (or raise --timeout)"
                    ) from None
            raise
        finally:
            self._future = self._scattered = None


def _scatter(client, obj, deadline: float | None = None, what: str = "a series"):
    """``obj`` sent to every worker, within ``deadline`` (a ``time.monotonic()``
    instant; None: no limit).

    Sent once to the cluster, not with every task; a key of its own (hash=False)
    so that releasing it cannot release an equal object scattered by another call.
    Copied to every worker (broadcast): a worker lost mid-run takes no input with
    it, and Dask reruns its tasks on the others. A worker that stops answering
    while the data are sent would hold ``Client.scatter`` for ever (its own
    ``timeout`` bounds only the wait for workers): the whole call is bounded here.
    """
    if obj is None:
        return None
    if deadline is None:
        return client.scatter(obj, hash=False, broadcast=True)
    left = deadline - time.monotonic()
    try:
        if left <= 0:
            raise TimeoutError
        # the wait for workers keeps the client's own timeout; the whole call, the
        # sending included, ends at the deadline
        return client.sync(client._scatter, obj, hash=False, broadcast=True,
                           callback_timeout=left)
    except TimeoutError:
        if time.monotonic() < deadline:  # Dask's own (no worker joined in time...)
            raise
        raise TimeoutError(f"the Dask cluster did not take the data of {what} within the "
                           "timeout; check that its workers run (or raise --timeout)"
                           ) from None


def _chunk_pass(series, start: int, stop: int, plan, origin) -> SeriesPass:
    """One task: the pass over frames ``start:stop`` of ``series``."""
    acc = SeriesPass(plan, origin)
    with one_blas_thread():  # a worker's BLAS threads would spin on the others' cores
        # the frames as stored, as the local pass reads them
        for k, frame in enumerate(series.frames(dtype=None, start=start, stop=stop)):
            acc.add(start + k, frame)
    return acc



def _submit_pass(client, series, plan, *, timeout: float | None = None) -> _Pending:
    """Submit the pass over ``series`` (:class:`gridstrain.stacks.accumulate.SeriesPass`),
    in chunks of frames merged on the workers (internal).

    ``result()`` gives the merged pass, as one pass over all the frames on this
    machine gives it (to the rounding of sums added in another order). The first
    frame, the origin of every chunk's sums, is read here. Sending the series'
    inputs to the workers takes at most ``timeout`` seconds (None: no limit).
    """
    dask, _ = _dask()
    origin = _first_frame(series)
    deadline = None if timeout is None else time.monotonic() + timeout
    what = getattr(series, "name", "a series")
    s, p, o = (_scatter(client, x, deadline, what) for x in (series, plan, origin))
    leaf = dask.delayed(_chunk_pass, pure=True)
    parts = [leaf(s, a, b, p, o) for a, b in _frame_chunks(series.n_frames)]
    total = _tree(parts, _merged, _SPLIT_EVERY)
    return _Pending(client.compute(total), (s, p, o),
                    f"the pass over {getattr(series, 'name', 'a series')}")


def _frame_chunks(n_frames: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of consecutive chunks of frames: at most :data:`_PASS_TASKS`,
    of :data:`_MIN_CHUNK_FRAMES` frames at least (a series shorter than that is one
    chunk).

    Each task sums its chunk on the worker and ships one set of float64 sums
    (80 bytes a pixel) back, not one per frame: with one frame per task the
    reduction moved T sets through the network and two workers were barely faster
    than one. The chunks depend on the number of frames only, never on the
    cluster's size at the moment: the graph, and so the order of the sums and the
    result bit for bit, is the same however many workers are alive (one that dies
    and is restarted changes nothing).
    """
    k = max(1, min(n_frames // _MIN_CHUNK_FRAMES, _PASS_TASKS))
    bounds = np.linspace(0, n_frames, k + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in itertools.pairwise(bounds) if b > a]


def _check_scheduler(scheduler):
    """``scheduler`` if it is None, a non-empty string or a distributed.Client.

    Called before any work, so that a missing extra is reported at once.
    """
    if scheduler is None:
        return None
    distributed = _distributed()
    if isinstance(scheduler, distributed.Client) \
            or (isinstance(scheduler, str) and scheduler.strip()):
        return scheduler
    raise TypeError(f"scheduler must be None, 'local', a scheduler address such as "
                    f"'tcp://HOST:PORT' or a distributed.Client, got {scheduler!r}")
