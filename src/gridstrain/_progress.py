"""Progress reporting for the command line (the library only calls callbacks).

Library functions accept ``progress``: a callable ``progress(fraction, message)``
with ``fraction`` in [0, 1]. The CLI passes :func:`bar` to draw it on stderr.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

Progress = Callable[[float, str], None]


def null_progress(fraction: float, message: str) -> None:
    """A progress callback that does nothing."""


def bar(*, quiet: bool = False, stream=None) -> Progress:
    """A progress callback drawing a one-line bar on ``stream`` (default stderr).

    Nothing is drawn when ``quiet`` or when the stream is not a terminal (a log
    file or a pipe would only collect carriage returns).
    """
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    if quiet or not (callable(isatty) and isatty()):
        return null_progress
    width = 30
    state = {"last": ""}

    def report(fraction: float, message: str) -> None:
        f = min(max(float(fraction), 0.0), 1.0)
        fill = round(f * width)
        line = f"\r[{'#' * fill}{'.' * (width - fill)}] {f:4.0%} {message[:60]:<60}"
        if line != state["last"]:
            stream.write(line)
            state["last"] = line
            if f >= 1.0:
                stream.write("\n")
            stream.flush()

    return report
