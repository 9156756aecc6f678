"""The thread pools of the libraries gridstrain calls.

The per-frame products of a pass over a series (the screening's carrier sums, the
rigid-shift probe, the batched sums of the mean and variance) are small BLAS
calls. OpenBLAS runs them on its own threads, which then spin while waiting for
the next call and take the cores that the frames' transforms need: on 2 cores,
method B on 2 threads of gridstrain's ran no faster than on 1 (7.1 s against 6.7 s
for 100 frames of 1040 x 1376) until BLAS was kept on the calling thread (4.1 s).
:func:`gridstrain.pipeline.measure_series` keeps it there throughout: its
kinematics, noise and uncertainty products are small or memory bound too, and with
the libraries' defaults a pair cost a third more CPU time for the same wall time.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import sys
from collections.abc import Iterator


@functools.cache
def _controller():
    # imported and built once: it lists the process's loaded BLAS libraries
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS on the calling thread only, inside the block (restored after it).

    The setting is the process's: enter it from the thread that starts the frame
    loop, before its worker threads start.
    """
    with _controller().limit(limits=1, user_api="blas"):
        yield


# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
# the ceilings of glibc's own sliding thresholds (64-bit): DEFAULT_MMAP_THRESHOLD_MAX,
# and the trim threshold it pairs with it (twice the mmap threshold)
_MMAP_THRESHOLD = 32 * 2**20
_TRIM_THRESHOLD = 2 * _MMAP_THRESHOLD


def command_malloc() -> bool:
    """Tune glibc's malloc for the command's own process; True where it was set.

    Two settings, made before any thread starts:

    - **One arena for every thread.** Each thread that allocates gets an arena of
      its own by default, and the blocks freed there stay with it. Method B's
      transforming threads start anew for each series, so that a run's resident
      memory grew with its number of states: 1405 MiB with 3 loaded states against
      1282 MiB with 1 (50 frames of 2048 x 2048, ``benchmarks/bench_states.py``),
      and 1308 against 1220 MiB with one arena, for the same time (the threads
      allocate little: their scratch arrays are reused).
    - **glibc's thresholds at their ceilings from the start.** By default a block
      above 128 KiB is mapped for itself and unmapped when freed; glibc raises that
      threshold, up to 32 MiB, only as such blocks are freed, and gives back the
      heap's top above twice the threshold. A measurement allocates and frees maps
      of a few to tens of MiB all along, so that until the thresholds had climbed
      each new map was mapped again and faulted in page by page. Starting them at
      32 and 64 MiB, a 1040 x 1376 pair (``benchmarks/bench_pair.py``) took
      56,000 page faults instead of 71,000 and 2.10 s of CPU instead of 2.26 s
      (means of 5 runs). Maps of 2048 x 2048 and above are still mapped and
      unmapped, and at most 64 MiB of free heap is kept, so that the memory given
      back by paging and by dropping a state's maps is given back as before. (Kept
      without bound, 3 loaded states of ``benchmarks/bench_states.py`` peaked 10 %
      above 1.)

    The library leaves its host process's allocator alone. Only where the C
    library is glibc (elsewhere nothing is changed and False is returned).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    ok = bool(mallopt(_M_ARENA_MAX, 1))
    # the trim threshold only with the mmap threshold: set alone, it would freeze
    # the mmap threshold at its 128 KiB start
    if mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD):
        mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD)
    return ok
