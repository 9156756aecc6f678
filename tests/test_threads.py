"""BLAS kept on the calling thread inside the frame loops (gridstrain._runtime.threads)."""

from __future__ import annotations

import platform
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from gridstrain import Lattice
from gridstrain._runtime import fft as _fft
from gridstrain._runtime import threads as _threads
from gridstrain.stacks import method_b


def _blas_threads() -> list[int]:
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_blas_runs_on_one_thread_inside_the_block_and_as_before_after_it():
    np.dot(np.ones((64, 64)), np.ones((64, 64)))  # BLAS loaded
    _fft.name()  # and the FFT implementation (MKL's threads with the mkl extra)
    before = _blas_threads()
    with _threads.one_blas_thread():
        assert all(n == 1 for n in _blas_threads())
    assert _blas_threads() == before


def test_method_b_keeps_blas_on_one_thread_while_it_reads_frames():
    seen = []
    lat = Lattice.from_pitch(5.0)
    yy, xx = np.mgrid[0:64, 0:64].astype(float)
    img = 1000 * (1 + 0.4 * np.cos(2 * np.pi * xx / 5) + 0.4 * np.cos(2 * np.pi * yy / 5))

    def frames():
        for _ in range(3):
            seen.append(_blas_threads())  # read inside the loop
            yield img
    before = _blas_threads()
    method_b(frames(), lat, workers=2)
    assert seen
    assert all(n == 1 for threads in seen for n in threads)
    assert _blas_threads() == before


def test_measure_series_keeps_blas_on_one_thread_throughout(monkeypatch):
    # its kinematics, noise and uncertainty products too, not only the frame loops:
    # OpenBLAS's idle threads would spin between them (a third more CPU for a pair)
    import gridstrain.kinematics.tracking as gp
    from gridstrain.series import measure_series

    seen = []
    inner = gp.deformation

    def spy(*args, **kwargs):
        seen.append(_blas_threads())
        return inner(*args, **kwargs)

    monkeypatch.setattr(gp, "deformation", spy)
    lat = Lattice.from_pitch(5.0)
    yy, xx = np.mgrid[0:96, 0:96].astype(float)

    def grid(u):
        return 1000 * (1 + 0.4 * np.cos(2 * np.pi * (xx - u) / 5)
                       + 0.4 * np.cos(2 * np.pi * yy / 5))

    before = _blas_threads()
    measure_series(grid(0.0), grid(0.2), lattice=lat, guess=(0.0, 0.0))
    assert seen
    assert all(n == 1 for threads in seen for n in threads)
    assert _blas_threads() == before


def test_the_command_serves_its_threads_from_one_malloc_arena(monkeypatch):
    import gridstrain.cli as cli

    if platform.libc_ver()[0] == "glibc":  # glibc takes the settings (in a process of its own)
        out = subprocess.run([sys.executable, "-c", "from gridstrain._runtime.threads import "
                              "one_malloc_arena as f, keep_freed_memory as g; "
                              "print(f(), g())"],
                             capture_output=True, text=True, check=True)
        assert out.stdout.split() == ["True", "True"]
    calls = []
    monkeypatch.setattr(cli, "blas_on_one_thread_from_start",
                        lambda: calls.append("blas") or True)
    monkeypatch.setattr(cli, "no_huge_page_stalls_from_start",
                        lambda: calls.append("pages") or True)
    monkeypatch.setattr(cli, "one_malloc_arena", lambda: calls.append("arena") or True)
    monkeypatch.setattr(cli, "keep_freed_memory", lambda: calls.append("keep") or True)
    monkeypatch.setattr(sys, "argv", ["gridstrain", "--help"])
    with pytest.raises(SystemExit):
        cli.main()  # the command's own process
    assert calls == ["blas", "pages", "arena", "keep"]
    with pytest.raises(SystemExit):
        cli.main(["--help"])  # called from Python: the host's allocator is left alone
    assert calls == ["blas", "pages", "arena", "keep"]


_BLAS_AT_START = (
    "import os, sys; from gridstrain._runtime.threads import blas_on_one_thread_from_start as f; "
    "set_ = f(); import numpy, scipy.linalg; from threadpoolctl import threadpool_info; "
    "print(set_, sorted({p['num_threads'] for p in threadpool_info() "
    "if p['internal_api'] == 'openblas'}))")


@pytest.mark.parametrize("given", [None, "2"])
def test_the_command_starts_openblas_on_one_thread_unless_told(given):
    # in a process of its own: OpenBLAS reads the variable once, when numpy loads it
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    out = subprocess.run([sys.executable, "-c", _BLAS_AT_START], env=env,
                         capture_output=True, text=True, check=True).stdout.split(maxsplit=1)
    if given is None:
        assert out[0] == "True"
        assert out[1].strip() in ("[1]", "[]")  # [] where numpy's BLAS is not OpenBLAS
    else:  # the user's own setting is kept
        assert out[0] == "False"
        assert out[1].strip() in ("[2]", "[]")


def test_openblas_is_left_alone_once_numpy_is_loaded(monkeypatch):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    assert "numpy" in sys.modules  # this module imported it: the variable is read already
    assert not _threads.blas_on_one_thread_from_start()
    import os

    assert "OPENBLAS_NUM_THREADS" not in os.environ


def test_map_leaves_keeps_the_items_order_and_raises_the_first_error():
    import threading
    import time

    def slow_square(i):
        time.sleep(0.002 * (i % 3))  # threads finish out of order
        return i * i, threading.current_thread().name

    out = _threads.map_leaves(slow_square, range(12), 3)
    assert [v for v, _ in out] == [i * i for i in range(12)]

    def fails(i):
        if i == 5:
            raise ValueError("item 5")
        return i

    with pytest.raises(ValueError, match="item 5"):
        _threads.map_leaves(fails, range(8), 2)
    # the pool is still usable after a failure
    assert _threads.map_leaves(lambda i: -i, range(4), 2) == [0, -1, -2, -3]


def test_map_leaves_callers_progress_while_the_pool_is_busy():
    # a caller takes items itself: one whose pool thread is held by another caller's
    # job still finishes all of its items, without waiting for that thread
    import threading
    import time

    held, release = threading.Event(), threading.Event()

    def job(i):
        if threading.current_thread().name.startswith("gridstrain"):
            held.set()
            release.wait(10)
        else:
            time.sleep(0.05)  # the caller is slow: the pool thread takes an item
        return i

    blocker = threading.Thread(target=_threads.map_leaves, args=(job, range(2), 2))
    blocker.start()
    try:
        assert held.wait(5)
        assert _threads.map_leaves(lambda i: 2 * i, range(5), 2) == [0, 2, 4, 6, 8]
    finally:
        release.set()
        blocker.join()


@pytest.mark.parametrize(("setting", "stalls"), [
    ("always defer defer+madvise [madvise] never\n", True),
    ("always defer [defer+madvise] madvise never\n", True),
    ("always [defer] defer+madvise madvise never\n", False),
    ("[always] defer defer+madvise madvise never\n", False),
    ("always defer defer+madvise madvise [never]\n", False),
    ("", False),
])
def test_huge_pages_are_not_advised_where_the_kernel_stalls_for_them(tmp_path, setting,
                                                                    stalls):
    # in a process of its own, with the kernel's setting from a file of the test's:
    # numpy reads NUMPY_MADVISE_HUGEPAGE once, when it is imported
    import os

    defrag = tmp_path / "defrag"
    defrag.write_text(setting)
    code = ("import sys; from gridstrain._runtime import threads as t; "
            f"t._THP_DEFRAG = {str(defrag)!r}; s = t.no_huge_page_stalls_from_start(); "
            "import numpy as np; c = np._core if hasattr(np, '_core') else np.core; "
            "print(s, c.multiarray._get_madvise_hugepage())")
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out[0] == str(stalls)
    if stalls:
        assert out[1] == "False"
    # told otherwise by the environment, it is left alone
    env["NUMPY_MADVISE_HUGEPAGE"] = "1"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["False", "True"]
