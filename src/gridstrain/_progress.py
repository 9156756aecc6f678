"""Progress reporting (the library only calls callbacks; bars are drawn at the edge).

Library functions accept ``progress``: a callable ``progress(fraction, message)``
with ``fraction`` in [0, 1]. :func:`progress_bar` turns such calls into a ``tqdm``
bar with an estimated time left, for the command line and for library users::

    with gridstrain.progress_bar() as bar:
        result = gridstrain.measure_series(ref, states, progress=bar)
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from functools import cache

Progress = Callable[[float, str], None]

# Steps of the bar: a fraction is shown to 0.1 %.
_STEPS = 1000
_FORMAT = "{bar:30} {percentage:3.0f}% {desc} [{elapsed}<{remaining}]"


def null_progress(fraction: float, message: str) -> None:
    """A progress callback that does nothing."""


class ProgressBar:
    """A ``progress(fraction, message)`` callback drawing a ``tqdm`` bar with an ETA.

    Parameters
    ----------
    stream : file-like, optional
        Where to draw (default ``sys.stderr``).
    **tqdm_options
        Passed to :class:`tqdm.tqdm` (``leave``, ``ncols``...).

    Notes
    -----
    The bar closes itself at ``fraction >= 1``; use it as a context manager (or
    call :meth:`close`) to end it early, after an error.
    """

    def __init__(self, *, stream=None, **tqdm_options):
        opts = {"total": _STEPS, "bar_format": _FORMAT, "leave": True,
                "file": sys.stderr if stream is None else stream,
                "dynamic_ncols": True} | tqdm_options
        self._bar = _bar_class()(**opts)
        self._done = 0

    def __call__(self, fraction: float, message: str) -> None:
        if self._bar.disable is None:  # closed
            return
        n = round(min(max(float(fraction), 0.0), 1.0) * _STEPS)
        self._bar.set_description_str(message[:50], refresh=False)
        if n > self._done:
            self._bar.update(n - self._done)
            self._done = n
        else:
            self._bar.refresh()
        if n >= _STEPS:
            self.close()

    def close(self) -> None:
        """End the bar's line."""
        if self._bar.disable is not None:
            self._bar.close()
            self._bar.disable = None

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@cache
def _bar_class():
    """tqdm's bar without its monitor thread: that thread wakes every 10 s to redraw
    stalled bars, on its own schedule, possibly into a stream that its writer has
    since closed. Every redraw of ours comes from a progress call."""
    from tqdm.auto import tqdm

    return type("GridstrainBar", (tqdm,), {"monitor_interval": 0})


def progress_bar(**tqdm_options) -> ProgressBar:
    """A progress callback drawing a ``tqdm`` bar on stderr (see :class:`ProgressBar`).

    Examples
    --------
    >>> import io
    >>> out = io.StringIO()
    >>> with progress_bar(stream=out) as bar:
    ...     bar(0.5, "half way")
    ...     bar(1.0, "done")
    >>> "100% done" in out.getvalue()
    True
    """
    stream = tqdm_options.pop("stream", None)
    return ProgressBar(stream=stream, **tqdm_options)


def bar(*, quiet: bool = False, stream=None) -> Progress:
    """The command line's bar on ``stream`` (default stderr): a :class:`ProgressBar`.

    Nothing is drawn when ``quiet`` or when the stream is not a terminal (a log
    file or a pipe would only collect carriage returns).
    """
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    if quiet or not (callable(isatty) and isatty()):
        return null_progress
    return ProgressBar(stream=stream)
