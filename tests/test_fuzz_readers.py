"""Fuzzing the readers of models configurations, jobs files and reports (``--from-report``).

Valid documents are edited at random (values of any JSON type, hostile
strings and numbers, deep nesting, keys deleted or added) and written as
JSON or TOML; arbitrary bytes go through the parsers. Every input must be
read or refused with a :class:`~seed2gs_inverse.errors.Seed2GSError`,
never another exception, with the peak traced memory of one read below
:data:`MEMORY_LIMIT` (the inputs are small).

The default run is short; ``benchmarks/bench_fuzz.py`` runs at least
10,000 generated inputs per reader.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings

from _fuzz_inputs import READERS, edits, make_case, outcome, syntax, apply_edits, write_bytes, write_doc
from hypothesis import strategies as st

MEMORY_LIMIT = 64 << 20

FAST = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                       HealthCheck.data_too_large])


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz_readers")
    return folder, make_case(folder)


@pytest.mark.parametrize("reader", READERS)
def test_the_valid_documents_are_read(cases, reader):
    """The documents the edits start from are valid ones (so the edits reach every check)."""
    folder, docs = cases
    for kind in ("json",) if reader == "report" else ("json", "toml"):  # reports are JSON whatever the name
        result, trace = outcome(reader, write_doc(folder, docs[reader], kind))
        assert result in ("ok", "own") and trace is None
        if reader != "models":  # the models' ONNX files are empty placeholders: refused when opened
            assert result == "ok", (reader, kind)


@pytest.mark.parametrize("reader", READERS)
@FAST
@given(changes=edits, kind=syntax)
def test_edited_documents_give_only_own_errors(cases, reader, changes, kind):
    folder, docs = cases
    path = write_doc(folder, apply_edits(docs[reader], changes), kind)
    result, trace = outcome(reader, path, MEMORY_LIMIT)
    assert result != "foreign", f"{reader} {kind} {changes!r}:\n{trace}"


@pytest.mark.parametrize("reader", READERS)
@FAST
@given(blob=st.binary(max_size=400), kind=syntax)
def test_arbitrary_bytes_give_only_own_errors(cases, reader, blob, kind):
    folder, _ = cases
    result, trace = outcome(reader, write_bytes(folder, blob, kind), MEMORY_LIMIT)
    assert result != "foreign", f"{reader} {kind} {blob!r}:\n{trace}"
