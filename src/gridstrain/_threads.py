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
import functools
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
