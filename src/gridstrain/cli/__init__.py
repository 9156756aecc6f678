"""The ``gridstrain`` command line.

Each sub-command lives in a module ``gridstrain.cli.<name>`` exposing
``register(subparsers)``, which adds its parser and sets ``func`` to a callable
``func(args) -> int``. User errors (``ValueError``, ``TypeError``, ``OSError``,
a full disk included) become one line on stderr and exit code 2; the library
itself never prints. So do a lack of memory (a run refused by the memory budget
says how much it needs) and a failing Dask cluster. SIGINT (exit 130) and SIGTERM
(exit 143) unwind the stack like an exception, from the moment :func:`main` starts,
so that every temporary file is removed before the one-line message; a file size
limit (SIGXFSZ, ``ulimit -f``) is an error of the write, not a kill. A command that
fails or is interrupted removes every output it had completed
(:class:`gridstrain.cli._common.Outputs`): its outputs are all there, or none.

Only the module of the sub-command being run is imported: ``gridstrain --help``
lists the sub-commands from the one-line summaries below, without importing the
numerical core, h5py or matplotlib.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import importlib
import importlib.util
import os
import signal
import sys
import threading

from .. import __version__
from .._runtime.threads import (
    blas_on_one_thread_from_start,
    keep_freed_memory,
    no_huge_page_stalls_from_start,
    one_malloc_arena,
    stop_shared_pools,
)

# sub-command -> the one-line summary its module's parser declares (a test checks
# that they agree)
_COMMANDS = {
    "animate": "an animation (GIF, MP4) of a map over the states on fixed colour limits",
    "demo": "simulate a tensile test with a testing machine's log and measure it",
    "export": "write a result file as MATLAB, CSV, ParaView (VTK) or NetCDF files",
    "gauge": "virtual strain gauge and extensometer: mean strain of every state with its "
             "std",
    "history": "strain rate, velocity and acceleration of a gauge over time, smoothed, with "
               "std",
    "identify": "Young's modulus and Poisson's ratio of a heterogeneous test by the "
                "virtual fields method, with their intervals",
    "measure": "displacement and strain maps from image series",
    "modulus": "Young's modulus and Poisson's ratio with their intervals, from a gauge and "
               "the loads",
    "noise": "estimate the camera noise (and vibrations) from a static stack or a single "
             "image",
    "plot": "figures of a result file: maps of every state, strain history",
    "report": "a self-contained HTML report of a result file",
    "reproduce": "re-run the paper's synthetic experiments (RMSE vs T, methods A and B)",
    "stress-gauge": "Young's modulus at high strain rate from an impact record: stress from "
                    "the accelerations",
}


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser(commands=None) -> argparse.ArgumentParser:
    """The top-level parser.

    ``commands``: the sub-commands whose parsers are built in full (their modules
    imported); the others are listed by their summary only. Default: all of them.
    """
    parser = _Parser(prog="gridstrain",
                     description="Displacement and strain maps with the grid method.")
    parser.add_argument("--version", action="version", version=f"gridstrain {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_Parser)
    for name, summary in _COMMANDS.items():
        module = f"gridstrain.cli.{name.replace('-', '_')}"
        if commands is not None and name not in commands:
            if importlib.util.find_spec(module) is not None:
                sub.add_parser(name, help=summary, add_help=False)
            continue
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue
        mod.register(sub)
    return parser


class Terminated(BaseException):
    """Raised in the main thread by SIGTERM, so that clean-ups run (exit 143)."""


# The signal this command received, if any: an interrupt that lands inside an
# import or a C extension can surface as another error (a module whose
# initialisation was interrupted raises ImportError); the signal decides the outcome.
_received: list[int] = []


def _interrupt(signum, frame):
    # a second signal must not break the clean-up the first one started
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, signal.SIG_IGN)
    _received.append(signum)
    raise KeyboardInterrupt if signum == signal.SIGINT else Terminated


def _as_signal(exc: BaseException) -> None:
    """Raise the received signal's exception in place of ``exc``, if a signal came."""
    if _received and not isinstance(exc, KeyboardInterrupt | Terminated):
        raise (KeyboardInterrupt if _received[0] == signal.SIGINT else Terminated)() \
            from None


# An interrupt raised while Python runs a callback whose exceptions it ignores (a
# weak reference's or a __del__ run by the garbage collector) would be printed and
# dropped, and the command would go on: such an interrupt is raised again by a
# timer signal (SIGALRM) as soon as the callback has returned.
_dropped: list[type[BaseException]] = []


def _again(signum, frame):
    if _dropped:
        raise _dropped.pop()


def _catch_dropped(previous):
    def hook(unraisable):
        exc = unraisable.exc_value
        if isinstance(exc, KeyboardInterrupt | Terminated) and hasattr(signal, "setitimer"):
            _dropped.append(type(exc))
            signal.setitimer(signal.ITIMER_REAL, 0.001)
            return
        previous(unraisable)

    return hook


@contextlib.contextmanager
def _signals():
    """SIGINT and SIGTERM raise; SIGXFSZ is ignored (the write fails with EFBIG)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _received.clear()
    wanted = {signal.SIGINT: _interrupt, signal.SIGTERM: _interrupt}
    if hasattr(signal, "SIGXFSZ"):
        wanted[signal.SIGXFSZ] = signal.SIG_IGN
    if hasattr(signal, "setitimer"):
        wanted[signal.SIGALRM] = _again
    old = {s: signal.signal(s, h) for s, h in wanted.items()}
    hook = sys.unraisablehook
    sys.unraisablehook = _catch_dropped(hook)
    try:
        yield
    finally:
        sys.unraisablehook = hook
        if hasattr(signal, "setitimer"):
            signal.setitimer(signal.ITIMER_REAL, 0)
        _dropped.clear()
        for s, h in old.items():
            signal.signal(s, h)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _is_dask_error(exc: BaseException) -> bool:
    """An error of the Dask cluster itself (lost scheduler, killed workers...)."""
    import asyncio
    import concurrent.futures

    mod = type(exc).__module__ or ""
    if mod.split(".")[0] in ("distributed", "tornado") \
            or isinstance(exc, concurrent.futures.CancelledError | asyncio.CancelledError):
        return True
    # a connection that failed inside distributed's client (a builtin OSError)
    tb = exc.__traceback__
    while tb is not None and isinstance(exc, OSError):
        if f"{os.sep}distributed{os.sep}" in tb.tb_frame.f_code.co_filename:
            return True
        tb = tb.tb_next
    return False


def entry(*, own_process: bool = True) -> None:
    """Entry point of the ``gridstrain`` console script and of ``python -m gridstrain``
    (and ``gridstrain.cli``): :func:`main`, then the end of the process.

    In a process of the command's own (``own_process``: the console script, or ``python
    -m`` started by the interpreter itself, :func:`started_by_dash_m`) it ends once its
    outputs are closed and its output streams flushed: Python's exit handlers run
    (:mod:`atexit`: temporary folders, weak finalizers), then the process exits without
    the interpreter's teardown of every module and of the compiled loops' libraries
    (0.3 s of CPU after a 1040 x 1376 pair, a tenth of its measurement). Otherwise (a
    caller's ``runpy``, ``python -i``), and where that cannot be known safe (a stream
    that fails to flush, a thread still running, an interpreter without
    :func:`atexit._run_exitfuncs`), it raises SystemExit as usual.
    """
    rc = main()
    if not own_process or sys.flags.interactive:
        sys.exit(rc)
    stop_shared_pools()
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
    except (OSError, ValueError):  # reported by the interpreter's own exit, as always
        sys.exit(rc)
    others = [t for t in threading.enumerate()
              if t is not threading.main_thread() and t.is_alive() and not t.daemon]
    if others or run_exit_handlers is None:
        sys.exit(rc)
    run_exit_handlers()
    for stream in (sys.stdout, sys.stderr):  # what a handler printed
        with contextlib.suppress(OSError, ValueError, AttributeError):
            stream.flush()
    os._exit(int(rc))


def started_by_dash_m() -> bool:
    """Whether this process's first Python frame is the interpreter's own ``python -m``
    (runpy's ``_run_module_as_main``): the module runs as the process's command, not
    inside a caller's program that ran it through :mod:`runpy`."""
    runpy = sys.modules.get("runpy")
    first = getattr(getattr(runpy, "_run_module_as_main", None), "__code__", None)
    frame = sys._getframe()
    while frame.f_back is not None:
        frame = frame.f_back
    return first is not None and frame.f_code is first


def main(argv=None) -> int:
    """The command line on ``argv`` (``sys.argv[1:]`` when None, the process then
    taken as the command's own: :func:`entry`); returns the exit status."""
    try:
        # from the first instant: a signal while the modules load is one line too
        with _signals():
            try:
                return _main(argv)
            except BaseException as exc:
                _as_signal(exc)
                raise
    except KeyboardInterrupt:
        print(f"{_where(argv)}: interrupted; no partial output left", file=sys.stderr)
        return 130
    except Terminated:
        print(f"{_where(argv)}: terminated (SIGTERM); no partial output left",
              file=sys.stderr)
        return 143


def _where(argv) -> str:
    argv = sys.argv[1:] if argv is None else argv
    command = next((a for a in argv if not a.startswith("-")), None)
    return f"gridstrain {command}" if command in _COMMANDS else "gridstrain"


def _own_process() -> None:
    """What the command sets in a process of its own, before numpy is imported: BLAS on
    one thread, no huge pages where the kernel would stall for them, one malloc arena,
    the freed blocks kept (:mod:`gridstrain._runtime.threads`)."""
    blas_on_one_thread_from_start()
    no_huge_page_stalls_from_start()
    one_malloc_arena()
    keep_freed_memory()


def _main(argv) -> int:
    if argv is None:  # the process is the command's own (not a caller's)
        argv = sys.argv[1:]
        _own_process()
    # the top level has no option taking a value: the first word is the sub-command
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser([command] if command in _COMMANDS else [])
    args = parser.parse_args(argv)
    where = f"gridstrain {args.command}"
    from ._common import Outputs

    try:
        # every output the command committed is removed if it then fails
        with Outputs():
            return int(args.func(args) or 0)
    except MemoryError as exc:
        _as_signal(exc)
        from .._runtime.memory import MemoryBudgetError

        if isinstance(exc, MemoryBudgetError):
            print(f"{where}: error: {_one_line(exc)}", file=sys.stderr)
        else:
            print(f"{where}: error: out of memory; use fewer or smaller frames, a smaller "
                  "--sigma, method A, or --scheduler to spread the work", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Terminated):
        raise
    except BrokenPipeError:
        # the reader of the printed lines went away; the outputs are kept (Outputs):
        # the rest of what would be printed goes nowhere, and the exit status is a
        # pipe's (128 + SIGPIPE)
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except BaseException as exc:
        _as_signal(exc)
        if isinstance(exc, SystemExit | GeneratorExit):
            raise
        # a lost connection is an OSError too: the cluster is named first
        if _is_dask_error(exc):
            print(f"{where}: error: the Dask cluster failed ({type(exc).__name__}: "
                  f"{_one_line(exc)}); check the scheduler and its workers",
                  file=sys.stderr)
            return 2
        if isinstance(exc, ValueError | TypeError | OSError):
            print(f"{where}: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
