"""Docstrings and comments state the contract: no measurements, machine loads,
benchmark case names, issue numbers or history. Those belong in CHANGELOG.md
and in the benchmarks' output; a docstring may point to the benchmark that
chose a default, by its script name.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "seed2gs_inverse"

#: (what, pattern): each is a sign of a lab notebook, not of a contract.
FORBIDDEN = [
    ("a machine load", re.compile(r"\bloads? (of )?\d+(\.\d+)?\b", re.I)),
    ("an issue number", re.compile(r"\bissues? #?\d+|(?<![\w&])#\d+\b", re.I)),
    ("a benchmark case name", re.compile(r"\b(firepit|garden|yard)-[a-z]+-\d+\b", re.I)),
    ("a benchmark score", re.compile(r"\b(m?B?IoU|accuracy|recall|precision)\b[^.\n]{0,40}?\b0\.\d{2,}", re.I)),
    ("a timing", re.compile(r"\b\d+(\.\d+)?\s?(ms|s|seconds|minutes)\b(?![-\w])(?=[^\n]{0,40}\b(on|against|vs|instead|took|measured)\b)",
                            re.I)),
    ("a history", re.compile(r"\b(used to|previously|no longer|was changed|before the fix|until now)\b", re.I)),
]


def _docstrings(tree):
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield node.body[0].lineno, doc


def _comments(source):
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string


def _offences(path: Path):
    source = path.read_text(encoding="utf-8")
    tree = ast.parse(source)
    texts = list(_docstrings(tree)) + list(_comments(source))
    for line, text in texts:
        for what, pattern in FORBIDDEN:
            m = pattern.search(text)
            if m:
                yield f"{path.relative_to(PACKAGE.parent)}:{line}: {what}: {m.group(0)!r}"


@pytest.mark.parametrize("what,pattern", FORBIDDEN, ids=[w for w, _ in FORBIDDEN])
def test_patterns_catch_examples(what, pattern):
    examples = {
        "a machine load": "measured at load 1.2-1.4",
        "an issue number": "asked for in issue 28",
        "a benchmark case name": "as on firepit-unicorn-29",
        "a benchmark score": "gives mIoU / mBIoU 0.974 / 0.917",
        "a timing": "took 3.1 s against 7.1 s measured",
        "a history": "the vote used to count twice",
    }
    assert pattern.search(examples[what])


def test_patterns_pass_contract_text():
    contract = ("Weights are float32 in [0, 1]; a pixel is object when W q > alpha / 2. "
                "The default was chosen by benchmarks/bench_extract.py. Rows are pixels "
                "(y * width + x); 16x16 tiles; the load factor of the table.")
    for what, pattern in FORBIDDEN:
        assert not pattern.search(contract), what


def test_package_docstrings_state_the_contract():
    offences = [o for path in sorted(PACKAGE.rglob("*.py")) for o in _offences(path)]
    assert not offences, "docstrings or comments that read like a lab notebook:\n" + "\n".join(offences)
