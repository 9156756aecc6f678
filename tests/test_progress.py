"""The progress bar (a tqdm bar behind a progress(fraction, message) callback)."""

import io
import threading

from gridstrain._progress import ProgressBar, bar, null_progress


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_bar_draws_on_a_terminal_only():
    term = _Terminal()
    report = bar(stream=term)
    report(1.0, "done")
    text = term.getvalue()
    assert "100% done" in text
    assert text.endswith("\n")
    pipe = io.StringIO()
    assert bar(stream=pipe) is null_progress
    pipe_report = bar(stream=pipe)
    pipe_report(1.0, "done")
    assert pipe.getvalue() == ""
    quiet = _Terminal()
    bar(stream=quiet, quiet=True)(1.0, "done")
    assert quiet.getvalue() == ""


def test_bar_shows_fraction_message_and_time_left():
    term = _Terminal()
    with ProgressBar(stream=term, mininterval=0) as report:
        report(0.5, "half")
        text = term.getvalue()
        assert "50% half" in text
        assert "<" in text  # elapsed<remaining
        report(0.25, "going back is drawn, not counted")
    report(1.0, "after close: ignored")
    assert "ignored" not in term.getvalue()
    assert term.getvalue().endswith("\n")


def test_bar_starts_no_thread_of_its_own():
    # tqdm's monitor thread would wake every 10 s on its own schedule and redraw
    # into whatever stream the bar had, possibly closed since: never started
    before = {t.ident for t in threading.enumerate()}
    term = _Terminal()
    with ProgressBar(stream=term, mininterval=0, miniters=5) as report:
        report(0.5, "half")
    report(1.0, "done")
    assert {t.ident for t in threading.enumerate()} <= before
    assert not any(t.name == "tqdm_monitor" for t in threading.enumerate())
    assert "50% half" in term.getvalue()
