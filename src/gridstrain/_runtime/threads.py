"""The thread pools of the libraries gridstrain calls, and gridstrain's own ordered
map over threads (:func:`map_bounded`).

The per-frame products of a pass over a series (the screening's carrier sums, the
rigid-shift probe, the batched sums of the mean and variance) are small BLAS
calls. OpenBLAS runs them on its own threads, which then spin while waiting for
the next call and take the cores that the frames' transforms need: on 2 cores,
method B on 2 threads of gridstrain's ran no faster than on 1 (7.1 s against 6.7 s
for 100 frames of 1040 x 1376) until BLAS was kept on the calling thread (4.1 s).
:func:`gridstrain.series.measure_series` keeps it there throughout: its
kinematics, noise and uncertainty products are small or memory bound too, and with
the libraries' defaults a pair cost a third more CPU time for the same wall time.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor


@functools.cache
def _controller():
    # imported and built once: it lists the BLAS libraries loaded by then, so the FFT
    # implementation is loaded first (MKL, with the mkl extra, brings its own
    # threads, which the limit must reach too)
    from threadpoolctl import ThreadpoolController

    from . import fft as _fft

    _fft.name()
    return ThreadpoolController()


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS on the calling thread only, inside the block (restored after it).

    The setting is the process's: enter it from the thread that starts the frame
    loop, before its worker threads start.
    """
    with _controller().limit(limits=1, user_api="blas"):
        yield


def _set_before_numpy(name: str, value: str) -> bool:
    """Set the environment variable ``name``, read by numpy or the libraries it loads
    when they load, unless numpy is loaded already or the environment gives it; True
    where it was set."""
    if "numpy" in sys.modules or name in os.environ:
        return False
    os.environ[name] = value
    return True


def blas_on_one_thread_from_start() -> bool:
    """Have the BLAS libraries that numpy and scipy load start with one thread, unless
    the environment already names a number; True where it was set (numpy not yet
    imported, no such variable given).

    OpenBLAS starts its threads when it loads, one less than the cores, and they spin
    for work for a while: numpy's and scipy's copies cost about 0.07 s and 0.1 s of
    CPU time in every process on 2 cores, for nothing, since
    :func:`one_blas_thread` keeps a measurement's BLAS calls on the calling thread
    anyway. Only for the command's own process, before numpy is imported, like
    :func:`one_malloc_arena`; the processes it starts inherit the setting.
    """
    # read by OpenBLAS (numpy's and scipy's wheels each load a copy) when it loads
    return _set_before_numpy("OPENBLAS_NUM_THREADS", "1")


# The kernel's rule for huge pages that a program asks for (madvise): "madvise" and
# "defer+madvise" compact memory while the program waits, to serve them
_THP_DEFRAG = "/sys/kernel/mm/transparent_hugepage/defrag"
_STALLING = ("madvise", "defer+madvise")


def _thp_stalls(setting: str) -> bool:
    """Whether the kernel's THP ``defrag`` setting (the text of its file, the chosen
    one in brackets) compacts memory synchronously for the pages advised huge."""
    chosen = setting[setting.find("[") + 1:setting.find("]")] if "[" in setting else ""
    return chosen in _STALLING


def no_huge_page_stalls_from_start() -> bool:
    """Have numpy not advise huge pages for its large arrays where the kernel would
    stall to serve them, unless the environment already says; True where it was set
    (numpy not yet imported, ``NUMPY_MADVISE_HUGEPAGE`` not given, and the kernel's
    ``transparent_hugepage/defrag`` one that compacts memory synchronously).

    numpy advises huge pages for every array of 4 MiB and more (its documented
    ``NUMPY_MADVISE_HUGEPAGE``). Where the kernel then compacts memory while the
    program waits (``madvise``, ``defer+madvise``), a measurement, which allocates
    and frees maps of the image's size, pays it in system time: for a 1040 x 1376
    pair, 0.83 to 1.21 s over 8 runs against 0.60 to 0.67 s without the advice, for
    0.05 to 0.14 s more user time. A heap block advised once stays advised when
    glibc hands it out again (:func:`keep_freed_memory`). Only for the command's own
    process, like :func:`one_malloc_arena`.
    """
    try:
        with open(_THP_DEFRAG) as f:
            setting = f.read()
    except OSError:  # not Linux, or no transparent huge pages
        return False
    return _thp_stalls(setting) and _set_before_numpy("NUMPY_MADVISE_HUGEPAGE", "0")


# glibc's mallopt parameters (malloc.h): the largest number of malloc arenas, the size
# from which a block is mapped on its own, the free top of the heap kept before trimming
_M_ARENA_MAX = -8
_M_MMAP_THRESHOLD = -3
_M_TRIM_THRESHOLD = -1
# Blocks below this are served from the heap: 32 MiB, the highest glibc's own threshold
# reaches on 64-bit, so that a complex map of a 1040 x 1376 frame (22.9 MB) is one of
# them; larger ones are mapped and unmapped as before (a 2048 x 2048 float64 map and
# up). The top of the heap is trimmed past 128 MiB: 64 MiB held fewer than 3 such
# maps, and their pages went back to the system between two stages (308,000 page
# faults a pair against 244,000).
_MMAP_THRESHOLD = 32 * 2**20
_TRIM_THRESHOLD = 128 * 2**20


def _mallopt():
    """glibc's ``mallopt``, or None elsewhere."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return mallopt


def one_malloc_arena() -> bool:
    """Have glibc's malloc serve every thread from one arena; True where it was set.

    Each thread that allocates gets an arena of its own by default, and the blocks
    freed there stay with it. Method B's transforming threads start anew for each
    series, so that a run's resident memory grew with its number of states: 1405
    MiB with 3 loaded states against 1282 MiB with 1 (50 frames of 2048 x 2048,
    ``benchmarks/bench_states.py``), and 1308 against 1220 MiB with one arena, for
    the same time (the threads allocate little: their scratch arrays are reused).
    The command line sets it for its own process, before any thread starts; the
    library leaves its host process's allocator alone. Only where the C library is
    glibc (elsewhere nothing is changed and False is returned).
    """
    mallopt = _mallopt()
    return mallopt is not None and bool(mallopt(_M_ARENA_MAX, 1))


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep the blocks freed below 32 MiB for the next ones, up to
    128 MiB at the top of its heap; True where it was set.

    A state of a long record allocates a hundred maps of its frame's size and frees
    them. By default glibc maps such blocks one by one until its threshold has grown
    past them, and gives the top of its heap back to the system as soon as 2 such
    blocks lie free there: every state then touches fresh pages, each one faulted in
    and zeroed by the kernel (system time that grows with the number of states). Kept,
    they are reused; the resident peak is the same (what is kept was in use just
    before).
    Only for the command's own process, like :func:`one_malloc_arena`.
    """
    mallopt = _mallopt()
    return mallopt is not None and bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)) \
        and bool(mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))


def map_bounded(fn: Callable, items: Iterable, workers: int) -> Iterator:
    """``map(fn, items)`` on ``workers`` threads, yielding in order, with at most
    ``workers`` items in flight (scipy.fft, numpy's large array operations and the
    compiled loops release the GIL, so the transforms of several frames, or the
    blocks of rows of one map, overlap)."""
    if workers == 1:
        yield from map(fn, items)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending: deque = deque()
        for item in items:
            while len(pending) >= workers:
                yield pending.popleft().result()
            pending.append(pool.submit(fn, item))
        while pending:
            yield pending.popleft().result()


#: Maps of fewer pixels run their compiled loops' blocks, and an image its two wave
#: vectors' transforms, on the calling thread alone: on a 250 x 400 state a helper
#: thread cost more CPU than it saved wall time (0.6 to 0.9 ms of the kinematics' 17
#: ms, about 0.9 ms of the phase maps' 7.5 ms: handing each block over, the data's
#: cache lines moving between cores); a 512 x 512 map and larger keep the cores.
THREADED_PIXELS = 2**18

_POOLS: dict[tuple[int, int], ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _shared_pool(threads: int) -> ThreadPoolExecutor:
    """A pool of ``threads`` threads kept for this process's life (a process forked
    from this one makes its own: the threads do not cross a fork)."""
    key = (os.getpid(), threads)
    with _POOLS_LOCK:
        pool = _POOLS.get(key)
        if pool is None:
            pool = _POOLS[key] = ThreadPoolExecutor(max_workers=threads,
                                                    thread_name_prefix="gridstrain")
        return pool


def stop_shared_pools() -> None:
    """Stop this process's kept pools (:func:`map_leaves`'), once their threads are
    done: the end of a process that will not wait for them."""
    with _POOLS_LOCK:
        pools = [p for (pid, _), p in _POOLS.items() if pid == os.getpid()]
        _POOLS.clear()
    for pool in pools:
        pool.shutdown(wait=True)


def map_leaves(fn: Callable, items: Iterable, workers: int) -> list:
    """``[fn(item) for item in items]`` on up to ``workers`` threads: the calling
    thread and ``workers - 1`` threads of a pool kept between calls.

    For short jobs called many times (the kinematics' blocks of rows, the two wave
    vectors of a transform), where starting threads for each call would cost a
    good part of the job. Each thread takes the next item until none is left, so the
    caller is never slower than alone when the pool's threads are busy with other
    callers; the results are in the items' order whichever thread computed them.
    ``fn`` must not itself call :func:`map_leaves` (a leaf: compiled loops, FFTs),
    or it could wait for a thread that waits for it. The first exception raised is
    raised again once every thread has stopped.
    """
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        return [fn(item) for item in items]
    results: list = [None] * len(items)
    failed: list[BaseException] = []
    lock = threading.Lock()
    order = iter(range(len(items)))

    def take() -> None:
        while not failed:
            with lock:
                i = next(order, None)
            if i is None:
                return
            try:
                results[i] = fn(items[i])
            except BaseException as exc:
                failed.append(exc)
                return

    helpers = [_shared_pool(workers - 1).submit(take)
               for _ in range(min(workers, len(items)) - 1)]
    take()
    for f in helpers:
        if not f.cancel():  # one that has not started finds nothing left: not waited for
            f.result()
    if failed:
        raise failed[0]
    return results
