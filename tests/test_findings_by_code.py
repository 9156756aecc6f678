"""The tests (and the package) select findings by their code, never by the words of
their sentences.

A selection such as ``[w for w in res.warnings if "jump" in w]`` keeps its meaning
only while the sentence keeps that word; asserted absent, it passes for good once the
sentence is reworded. Every selection from a result's warnings, a JSON summary's or a
series' reading notes goes through :func:`findings.said` (by code); words are
asserted only on what it selected. This test reads the syntax trees of the tests and
of the package's modules, and names every comprehension that filters warnings or
notes by a string's presence.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from findings import said
from gridstrain import Finding

HERE = Path(__file__).parent
# the containers whose items are findings (a result's, a JSON summary's, a series')
_FOUND = {"warnings", "notes"}


# calls that give back the findings they are given, reordered or counted
_SAME = {"sorted", "reversed", "list", "tuple", "set", "enumerate", "filter"}


def _is_found(node: ast.AST) -> bool:
    """Whether ``node`` is ``x.warnings``, ``x.notes``, ``x["warnings"]`` or
    ``x["notes"]``, a slice of one (``x.warnings[1:]``) or one given to ``sorted``,
    ``enumerate``, ``filter``... (not to ``zip``: a zip of sentences with their codes
    is how a JSON summary or a file's attributes are selected by code)."""
    if isinstance(node, ast.Attribute):
        return node.attr in _FOUND
    if isinstance(node, ast.Subscript):
        key = node.slice
        if isinstance(key, ast.Constant):
            return key.value in _FOUND
        return isinstance(key, ast.Slice) and _is_found(node.value)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
            and node.func.id in _SAME:
        return any(_is_found(a) for a in node.args)
    return False


# what a finding carries beside its sentence: a selection may test these by ``in``
_FIELDS = {"code", "state", "figures", "severity"}


def _sentence_of(node: ast.AST, names: set[str]) -> bool:
    """Whether ``node`` reads the sentence of a loop variable in ``names`` (``w``,
    ``w.lower()``, ``w[3:]``), not one of its fields (``w.code``)."""
    if isinstance(node, ast.Attribute) and node.attr in _FIELDS:
        return False
    if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute) \
            and node.value.attr in _FIELDS:
        return False
    if isinstance(node, ast.Name):
        return node.id in names
    return any(_sentence_of(c, names) for c in ast.iter_child_nodes(node))


def _by_words(test: ast.AST, names: set[str]) -> bool:
    """Whether ``test`` looks for something in the sentence of a loop variable
    (``"jump" in w``, ``t in w.lower()``, ``w.startswith(...)``)."""
    for n in ast.walk(test):
        if isinstance(n, ast.Compare) \
                and any(isinstance(op, ast.In | ast.NotIn) for op in n.ops) \
                and any(_sentence_of(c, names) for c in n.comparators):
            return True
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) \
                and n.func.attr in ("startswith", "endswith", "find", "count") \
                and _sentence_of(n.func.value, names):
            return True
    return False


def selections_by_words(source: str) -> list[int]:
    """The lines of ``source`` where a comprehension over findings keeps or tests its
    items by words: its condition (``if``) or its element (``any("x" in w for w in
    ...)``) looks into the sentence of its loop variable."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.For) and _is_found(node.iter):
            # a loop over findings whose body looks into their sentences
            names = {n.id for n in ast.walk(node.target) if isinstance(n, ast.Name)}
            if any(_by_words(b, names) for b in node.body):
                lines.append(node.lineno)
        if not isinstance(node, ast.ListComp | ast.GeneratorExp | ast.SetComp
                          | ast.DictComp):
            continue
        elt = (node.key, node.value) if isinstance(node, ast.DictComp) else (node.elt,)
        for gen in node.generators:
            names = {n.id for n in ast.walk(gen.target) if isinstance(n, ast.Name)}
            if _is_found(gen.iter) and (any(_by_words(c, names) for c in gen.ifs)
                                        or any(_by_words(e, names) for e in elt)):
                lines.append(node.lineno)
    return lines


def test_no_test_and_no_command_selects_findings_by_words():
    # the tests, and the package itself: the CLI, the report and the JSON summary
    # select findings by code too
    files = [*sorted(HERE.glob("test_*.py")),
             *sorted((HERE.parent / "src" / "gridstrain").rglob("*.py"))]
    found = {str(p.relative_to(HERE.parent)): lines for p in files
             if (lines := selections_by_words(p.read_text(encoding="utf-8")))}
    assert not found, f"findings selected by words, not by code (findings.said): {found}"


def test_the_check_sees_each_form_of_selection():
    # each form the conversion replaced, and what replaced it
    caught = ('[w for w in res.warnings if "jump" in w]',
              'any("alias" in w for w in res.warnings)',
              'not any(f"rows {a}" in w for w in summary["warnings"])',
              '[n for n in s.notes if "TriggerTime" in n]',
              '[w for w in summary["warnings"] if any(t in w.lower() for t in ("a", "b"))]',
              '[m for m in res.warnings if m.startswith(name + ":")]',
              'sum("not confirmed" in w for w in indep.warnings)',
              'all(w.startswith("1 of 8") for w in rotated.warnings[1:])',
              '[w for w in sorted(res.warnings) if "jump" in w]',
              '{w: 1 for w in res.warnings if "jump" in w}')
    for line in caught:
        assert selections_by_words(line) == [1], line
    loop = 'for w in res.warnings:\n    if "jump" in w:\n        n += 1\n'
    assert selections_by_words(loop) == [1]
    fine = ('said(res.warnings, "jump.found")',
            'any("rows" in w for w in said(res.warnings, "jump.found"))',
            '[w for w in res.warnings if w.code == "jump.found"]',
            '[w for w in res.warnings if w.code in ("jump.found", "jump.part")]',
            '[w for w in res.warnings if "s1" in w.state]',
            '"x" in res.warnings[0]',
            '[w for w, c in zip(s["warnings"], s["warning_codes"]) if c == "a" and "x" in w]')
    for line in fine:
        assert selections_by_words(line) == [], line


def test_said_selects_by_code_and_refuses_what_it_cannot_check():
    a = Finding("jump.found", "s1: the displacement jumps", state="s1")
    b = Finding("aliasing.bound", "s1: harmonics alias onto the carrier", state="s1")
    assert said([a, b], "jump.found") == [a]
    assert said([a, b], "jump.part") == []
    summary = {"warnings": [str(a), str(b)],
               "findings": [{"code": "jump.found"}, {"code": "aliasing.bound"}]}
    assert said(summary, "aliasing.bound") == [str(b)]
    with pytest.raises(ValueError, match=r"jump\.fund"):  # a misspelt code: never empty
        said([a], "jump.fund")
    with pytest.raises(AttributeError):  # a sentence without a code
        said(["s1: the displacement jumps"], "jump.found")
