"""What the library reports to its caller while it works: progress and findings (the
library only calls callbacks and returns records; bars and sentences are drawn at the
edge).

Findings live here, beside progress, because every part reports them (the kinematics'
fringe order, the series' checks, the uncertainty's bounds, the readers' frame gaps)
and this module imports nothing of gridstrain: any part may import it without a cycle.
A :class:`Finding` is a ``str`` (its sentence), so that results and files that store
sentences keep doing so, with its code, state and figures beside; :data:`FINDINGS` is
the one registry of codes, their severity and what to do about them. Callers select
findings by :attr:`Finding.code`, never by their words.

Library functions accept ``progress``: a callable ``progress(fraction, message)``
with ``fraction`` in [0, 1]. :func:`progress_bar` turns such calls into a ``tqdm``
bar with an estimated time left, for the command line and for library users::

    with gridstrain.progress_bar() as bar:
        result = gridstrain.measure_series(ref, states, progress=bar)
"""

from __future__ import annotations

import numbers
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from types import MappingProxyType

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


# --------------------------------------------------------------------------- findings

#: The severities, least to most serious: a ``note`` qualifies a figure, a
#: ``warning`` says a figure may be biased or a check could not run, a ``doubt`` says
#: a figure may be wrong (a fringe order not confirmed, another specimen).
SEVERITIES = ("note", "warning", "doubt")


@dataclass(frozen=True)
class FindingKind:
    """One code of :data:`FINDINGS`: its severity, what it means and what to do."""

    code: str
    severity: str
    meaning: str
    advice: str


def _kinds(*rows: tuple[str, str, str, str]) -> Mapping[str, FindingKind]:
    out = {}
    for code, severity, meaning, advice in rows:
        if severity not in SEVERITIES or code in out:
            raise ValueError(f"finding {code!r}: severity {severity!r} or a repeated code")
        out[code] = FindingKind(code, severity, meaning, advice)
    return MappingProxyType(out)


#: Every code a finding may carry.
FINDINGS = _kinds(
    ("fringe_order.unconfirmed", "doubt",
     "nothing confirms the state's whole number of periods",
     "pass --guess UX UY, add an intermediate state, or image printed features"),
    ("fringe_order.inherited", "doubt",
     "states followed from a state whose fringe order is not confirmed",
     "confirm the first state of the run (a guess or printed features)"),
    ("fringe_order.features_used", "warning",
     "image features fixed the state whole periods from the followed field",
     "check the load step: it was more than half a period"),
    ("fringe_order.corrected", "warning",
     "the warped-back image showed the measured field whole periods off; corrected",
     "none: the corrected field is the one returned"),
    ("jump.found", "warning",
     "the displacement jumps (a crack, an edge, a torn grid); the straddling pixels left out",
     "none, or a smaller sigma for a narrower band"),
    ("jump.part", "warning",
     "a part of the field cut off by a jump was corrected or left out",
     "pass a guess per part or an intermediate state"),
    ("pair.mismatch", "doubt",
     "the state's image does not show the reference's specimen",
     "check the files: another specimen, or a state out of its series"),
    ("aliasing.bound", "warning",
     "the grid's harmonics alias onto the carrier above the noise",
     "a sharper print, another pitch, or a larger sigma"),
    ("edges.partial", "warning",
     "the mask's outermost pixels show the grid only in part (the specimen's edge crosses "
     "them): the grid continued over them, their maps the continuation's",
     "none, or draw the mask one pixel inside the specimen's edge"),
    ("edges.harmonics", "warning",
     "the print's harmonics are not continued beyond the edges: the strain in the edge "
     "band is biased beyond what the std maps state",
     "a sinusoidal print, or leave out the edge band, or measure without --to-edges"),
    ("smoothing.bias", "warning",
     "the window's smoothing of strain gradients may exceed the noise",
     "a smaller sigma"),
    ("contrast.step", "warning",
     "the grid's contrast changes between the states (a stain, a shadow, a hole's edge): "
     "the displacement next to it may be biased beyond the noise",
     "mask the region, or light and prepare the specimen so that its contrast stays"),
    ("saturation", "warning", "clipped pixels in a series", "lower the exposure"),
    ("contrast.vibration", "note",
     "vibrations lower method A's averaged contrast", "method C"),
    ("vibration", "warning", "the frames' rigid shifts are large or not a translation",
     "steady the camera"),
    ("screening.flagged", "warning", "frames flagged by the screening",
     "check the named frames"),
    ("carrier.implausible", "doubt",
     "a state's grid is the reference's strained or turned beyond a plausible strain",
     "check that the images are of the same specimen and grid"),
    ("frames.gap", "warning",
     "the record's frame numbers have gaps, repeats or are out of order",
     "check the record"),
    ("noise.unavailable", "warning", "the noise could not be estimated",
     "give --noise or --noise-model"),
    ("noise.single_reference", "note", "one reference frame: no split-halves floor",
     "measure a second unloaded image as a state"),
    ("checks.sampled", "note",
     "states of a long record whose expensive checks were sampled, not run",
     "measure with fewer states, or the states in doubt, to check each"),
    ("modulus.units", "doubt",
     "a fitted Young's modulus no solid has (outside 100 Pa to 2 TPa): a unit's slip",
     "check the cross-section and its unit (--area-unit, mm2 by default) and the loads' "
     "unit"),
    ("input", "warning", "how the inputs were read or ordered", "none"),
    ("other", "warning", "a finding of a part that gives it no code of its own",
     "read its sentence"),
)


class Finding(str):
    """A finding: its sentence (this ``str``), with its :attr:`code` (one of
    :data:`FINDINGS`), the :attr:`state` it concerns (a series' name, or None for
    the run) and its :attr:`figures`. Immutable, like the sentence.

    Examples
    --------
    >>> f = Finding("fringe_order.unconfirmed", "s1: fringe order not confirmed",
    ...             state="s1", step=0.45)
    >>> f.code, f.severity, f.figures["step"], str(f)
    ('fringe_order.unconfirmed', 'doubt', 0.45, 's1: fringe order not confirmed')
    """

    code: str
    state: str | None
    figures: Mapping

    def __new__(cls, code: str, text: str, *, state: str | None = None, **figures):
        if code not in FINDINGS:
            raise ValueError(f"code must be one of gridstrain's finding codes "
                             f"({', '.join(FINDINGS)}), got {code!r}")
        self = super().__new__(cls, text)
        object.__setattr__(self, "code", code)
        object.__setattr__(self, "state", None if state is None else str(state))
        object.__setattr__(self, "figures", MappingProxyType(dict(figures)))
        return self

    def __setattr__(self, name, value):
        raise AttributeError(f"a Finding is immutable: cannot set {name!r}")

    def __reduce__(self):
        return _finding, (self.code, str(self), self.state, dict(self.figures))

    @property
    def severity(self) -> str:
        """``"note"``, ``"warning"`` or ``"doubt"`` (:data:`SEVERITIES`)."""
        return FINDINGS[self.code].severity

    @property
    def advice(self) -> str:
        return FINDINGS[self.code].advice

    def restated(self, text: str, *, state: str | None) -> Finding:
        """The same finding (its code and figures) as ``text`` said of ``state``: a
        part's finding said of the series or state it was made for."""
        return Finding(self.code, text, state=state, **self.figures)

    def record(self) -> dict:
        """``{"code", "state", "figures"}``: what a result file keeps beside the
        sentence (figures as plain numbers and strings)."""
        return {"code": self.code, "state": self.state,
                "figures": {k: _plain(v) for k, v in self.figures.items()}}


def _finding(code, text, state, figures):
    return Finding(code, text, state=state, **figures)


def _plain(v):
    """A figure as a file stores it: numbers, strings, None and lists of them."""
    if isinstance(v, str) or v is None:
        return v
    if isinstance(v, bool):
        return bool(v)
    if isinstance(v, numbers.Integral):
        return int(v)
    try:
        return float(v)
    except (TypeError, ValueError):
        return [_plain(x) for x in v]


def tally(findings) -> str:
    """How many findings of each severity, most serious first, with their codes:
    ``"1 doubt (fringe_order.unconfirmed), 2 warnings (aliasing.bound, saturation)"``;
    ``""`` for none. A plain sentence counts as code ``"other"``."""
    found = [as_finding(f, "other") for f in findings]
    parts = []
    for sev in reversed(SEVERITIES):
        codes = [f.code for f in found if f.severity == sev]
        if codes:
            names = ", ".join(dict.fromkeys(codes))
            parts.append(f"{len(codes)} {sev}{'s' if len(codes) > 1 else ''} ({names})")
    return ", ".join(parts)


def as_finding(text: str, code: str, state: str | None = None, **figures) -> Finding:
    """``text`` as a finding: itself when it is one already (its own code kept),
    else a :class:`Finding` of ``code``."""
    if isinstance(text, Finding):
        return text
    return Finding(code, text, state=state, **figures)


def findings_of(texts, code: str, state: str | None = None) -> list[Finding]:
    """Each sentence of ``texts`` as a finding (:func:`as_finding`)."""
    return [as_finding(t, code, state) for t in texts]
