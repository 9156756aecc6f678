"""The command line's progress bar."""

import io

from gridstrain._progress import bar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_bar_draws_on_a_terminal_only():
    term = _Terminal()
    report = bar(stream=term)
    report(0.5, "half")
    report(1.0, "done")
    text = term.getvalue()
    assert "50%" in text
    assert "100% done" in text
    assert text.endswith("\n")
    pipe = io.StringIO()
    bar(stream=pipe)(1.0, "done")
    assert pipe.getvalue() == ""
    quiet = _Terminal()
    bar(stream=quiet, quiet=True)(1.0, "done")
    assert quiet.getvalue() == ""
