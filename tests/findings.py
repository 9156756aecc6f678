"""A result's findings selected by their code (:data:`gridstrain.FINDINGS`), never by
the words of their sentences.

A test that looks for a sentence's words keeps passing when the sentence is reworded
only by luck, and one that asserts their absence (``not any("jump" in w ...)``) can no
longer fail once the words change: selected by code, both stay tests. The sentence's
words are asserted after the selection, where a test means to check what it says.
"""

from __future__ import annotations

from gridstrain import FINDINGS


def said(found, *codes: str) -> list[str]:
    """The sentences among ``found`` whose code is one of ``codes``, in order.

    ``found``: a result's warnings (:class:`gridstrain.Finding`, each with its code), or
    a command's JSON summary (its ``"warnings"`` and ``"findings"``, index by index). A
    code that gridstrain does not have is an error, so that a misspelt code cannot make
    an absence pass; a warning without a code is one too (``AttributeError``).
    """
    unknown = [c for c in codes if c not in FINDINGS]
    if not codes or unknown:
        raise ValueError(f"codes must be some of gridstrain's finding codes, got {codes!r}")
    if isinstance(found, dict):
        texts, records = found["warnings"], found["findings"]
        return [t for t, f in zip(texts, records, strict=True) if f["code"] in codes]
    return [w for w in found if w.code in codes]
