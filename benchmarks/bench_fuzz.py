"""Long fuzz run of the readers of models configurations, jobs files and reports.

Usage::

    python benchmarks/bench_fuzz.py [--n 10000] [--readers models,jobs,report] [--seed 0]

For each reader it reads ``--n`` generated inputs (three quarters edited
valid documents as JSON or TOML, one quarter arbitrary bytes; the
generators of ``tests/_fuzz_inputs.py``, which ``tests/test_fuzz_readers.py``
runs briefly) and prints how many inputs it read, how many were read,
refused with the toolkit's own error, or raised a foreign exception (the
defects), with the first foreign tracebacks, the wall time, the peak traced
memory of one read, and the machine's load average. Exits 1 if any
foreign exception was seen.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(1, str(REPO / "tests"))  # the generators shared with tests/test_fuzz_readers.py

from hypothesis import HealthCheck, Phase, given, seed as hypothesis_seed, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from _common import load_average  # noqa: E402
from _fuzz_inputs import READERS, apply_edits, edits, make_case, outcome, syntax, write_bytes, write_doc  # noqa: E402

MEMORY_LIMIT = 64 << 20


def run_reader(reader: str, n: int, seed: int, folder: Path, docs: dict) -> tuple[Counter, list]:
    counts, foreign = Counter(), []

    def record(path):
        result, trace = outcome(reader, path, MEMORY_LIMIT)
        counts[result] += 1
        if trace is not None and len(foreign) < 5:
            foreign.append(trace)

    opts = dict(deadline=None, database=None, phases=[Phase.generate],
                suppress_health_check=list(HealthCheck))
    n_bytes = n // 4

    @hypothesis_seed(seed)  # reproducible runs
    @settings(max_examples=n - n_bytes, **opts)
    @given(changes=edits, kind=syntax)
    def edited(changes, kind):
        record(write_doc(folder, apply_edits(docs[reader], changes), kind))

    @hypothesis_seed(seed)
    @settings(max_examples=n_bytes, **opts)
    @given(blob=st.binary(max_size=2000), kind=syntax)
    def raw(blob, kind):
        record(write_bytes(folder, blob, kind))

    edited()
    raw()
    return counts, foreign


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="generated inputs per reader (default 10000)")
    ap.add_argument("--readers", default=",".join(READERS), help="comma-separated subset of " + ", ".join(READERS))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    readers = [r for r in args.readers.split(",") if r]
    bad = 0
    print(f"load average at start: {load_average():.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        docs = make_case(folder)
        for reader in readers:
            t0 = time.perf_counter()
            counts, foreign = run_reader(reader, args.n, args.seed, folder, docs)
            total = sum(counts.values())
            print(f"{reader:>7}: {total} inputs, {counts['ok']} read, {counts['own']} refused with the toolkit's "
                  f"error, {counts['foreign']} foreign exceptions ({time.perf_counter() - t0:.1f} s)")
            for trace in foreign:
                print("    " + trace.strip().replace("\n", "\n    "))
            bad += counts["foreign"]
    print(f"load average at end: {load_average():.2f}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
