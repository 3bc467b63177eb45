"""Concurrent writers: output locks, writes that never replace without --force, batch summaries and journal.

The races are made deterministic: another process holds a lock (and says so on
its stdout) while this one tries to write, and a target "appears during the
run" by being created inside the writing block. The batch tests replace the
runner's ``run_job`` by a stand-in that writes a job folder at once.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import seed2gs_inverse as sgi
from seed2gs_inverse._atomic import atomic_path, lock_file, output_lock, write_files
from seed2gs_inverse.batch import Job, extract_many, runner
from seed2gs_inverse.batch.summary import JOURNAL, read_summary, write_summary
from seed2gs_inverse.batch.worker import JobResult
from seed2gs_inverse.cli import main
from seed2gs_inverse.errors import ValidationError

REPO = Path(__file__).resolve().parents[1]
CAM = {"eye": [0, 0, -3], "target": [0, 0, 0], "width": 8, "height": 8}

HOLDER = textwrap.dedent("""
    import sys
    from seed2gs_inverse._atomic import atomic_path, output_lock
    target, how = sys.argv[1], sys.argv[2]
    if how == "lock":
        ctx = output_lock(target)
        ctx.__enter__()
    else:  # a writer in the middle of its atomic write
        ctx = atomic_path(target, directory=True, replace=False)
        tmp = ctx.__enter__()
        (tmp / "who").write_text("first")
    print("held", flush=True)
    sys.stdin.read()  # until the test closes our stdin
    ctx.__exit__(None, None, None)
""")


def _holder(target, how="lock"):
    """A process holding ``target``'s lock (``how="lock"``) or in the middle of writing it; started and ready."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(target), how], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True, env=env)
    assert p.stdout.readline().strip() == "held"
    return p


def _release(p):
    p.stdin.close()
    assert p.wait(timeout=30) == 0


def _leftovers(parent: Path, name: str):
    return sorted(e.name for e in parent.iterdir() if e.name.startswith(f".{name}."))


def test_a_second_writer_of_one_output_stops_at_once_naming_the_first(tmp_path):
    out = tmp_path / "out"
    first = _holder(out, "write")
    try:
        with pytest.raises(ValidationError, match=rf"is being written by another seed2gs process \(PID {first.pid}"):
            with atomic_path(out, directory=True, replace=False) as tmp:
                (tmp / "who").write_text("second")
    finally:
        _release(first)
    # the first writer's result is in place, whole; nothing of the second is left
    assert (out / "who").read_text() == "first"
    assert _leftovers(tmp_path, "out") == []


def test_seed2gs_extract_stops_before_any_work_while_another_writes_its_output(tmp_path, capsys):
    out = tmp_path / "out"
    first = _holder(out)
    try:
        code = main(["extract", str(tmp_path / "missing.ply"), "--point", "1", "2", "-o", str(out)])
    finally:
        _release(first)
    err = capsys.readouterr().err
    assert code != 0
    assert f"PID {first.pid}" in err and "-o " in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("directory", [True, False])
def test_a_target_that_appears_during_the_write_is_not_replaced_without_force(tmp_path, directory):
    out = tmp_path / ("out" if directory else "q.npy")
    with pytest.raises(ValidationError, match="appeared while this output was being made.*not replaced"):
        with atomic_path(out, directory=directory, replace=False) as tmp:
            if directory:
                (tmp / "mine").write_text("new")
                out.mkdir()
                (out / "theirs").write_text("keep")
            else:
                tmp.write_bytes(b"new")
                out.write_bytes(b"keep")
    assert (out / "theirs").read_text() == "keep" if directory else out.read_bytes() == b"keep"
    assert _leftovers(tmp_path, out.name) == []  # the discarded output and the lock are gone


def test_an_empty_directory_that_appears_is_not_replaced_either(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ValidationError, match="appeared"):
        with atomic_path(out, directory=True, replace=False) as tmp:
            (tmp / "mine").write_text("new")
            out.mkdir()
    assert list(out.iterdir()) == []


def test_write_files_and_an_enclosing_lock_without_force_refuse_an_existing_target(tmp_path):
    out = tmp_path / "a.bin"
    out.write_bytes(b"keep")
    with pytest.raises(ValidationError, match="exists; use --force"):
        write_files([(out, b"new")], replace=False)
    with output_lock(out, "OUT a.bin", replace=False):  # as `seed2gs convert` holds it around write_scene
        with pytest.raises(ValidationError, match="exists; use --force"):
            with atomic_path(out) as tmp:
                tmp.write_bytes(b"new")
    assert out.read_bytes() == b"keep"
    write_files([(out, b"new")], replace=True)  # --force
    assert out.read_bytes() == b"new"
    assert _leftovers(tmp_path, "a.bin") == []


def test_a_stale_lock_of_an_exited_process_is_taken_over_and_removed(tmp_path):
    out = tmp_path / "out"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock = lock_file(out)
    lock.write_text(f"{dead.pid} {os.uname().nodename}\n")
    with atomic_path(out, directory=True, replace=False) as tmp:
        assert lock.read_text().split()[0] == str(os.getpid())  # now ours
        (tmp / "x").write_text("1")
    assert (out / "x").read_text() == "1"
    assert not lock.exists()


# --- batches ---------------------------------------------------------------------------------------

@pytest.fixture
def fake_jobs(tmp_path, monkeypatch):
    """Jobs over a dummy scene, and a runner whose run_job writes the job's folder at once."""
    scene = tmp_path / "s.ply"
    scene.write_text("not read")
    cam = CAM
    calls = []

    def fake_run_job(job, output=None, attempt=1):
        calls.append(job.name)
        folder = Path(output) / job.name
        folder.mkdir()
        (folder / "report.json").write_text(json.dumps({"batch": {"job": job.name}, "outputs": {}}))
        return JobResult(name=job.name, status="done", scene=os.fspath(job.scene), fingerprint=job.fingerprint(),
                         outdir=os.fspath(folder), seconds={"read": 0.0})

    monkeypatch.setattr(runner, "run_job", fake_run_job)

    def jobs(*names):
        return [Job(n, scene, cam, sgi.BoxPrompt([0, 0, 4, 4])) for n in names]

    return jobs, calls


def test_a_second_batch_into_a_locked_results_directory_stops_naming_the_first(tmp_path, fake_jobs):
    jobs, calls = fake_jobs
    res = tmp_path / "res"
    res.mkdir()
    first = _holder(res / "summary.json")
    try:
        with pytest.raises(ValidationError, match=rf"output .*being written by another seed2gs process "
                                                  rf"\(PID {first.pid}"):
            extract_many(jobs("b1"), "sequential", output=res, progress=False)
    finally:
        _release(first)
    assert calls == [] and sorted(p.name for p in res.iterdir()) == []


def test_the_summary_keeps_the_jobs_another_writer_recorded_meanwhile(tmp_path, fake_jobs, monkeypatch):
    jobs, calls = fake_jobs
    res = tmp_path / "res"
    inner = runner.run_job

    def run_and_meanwhile_another_batch_records_its_job(job, output=None, attempt=1):
        if job.name == "a1":  # another batch's job lands in the summary while this batch runs
            other = JobResult(name="b1", status="done", scene="elsewhere.ply", fingerprint="f")
            write_summary(Path(output), [other], {"n_jobs": 1})
        return inner(job, output, attempt)

    monkeypatch.setattr(runner, "run_job", run_and_meanwhile_another_batch_records_its_job)
    extract_many(jobs("a1", "a2"), "sequential", output=res, progress=False)
    doc = json.loads((res / "summary.json").read_text())
    assert sorted(j["name"] for j in doc["jobs"]) == ["a1", "a2", "b1"]
    assert doc["counts"]["jobs"] == 3
    with open(res / "summary.csv", newline="") as fh:
        assert sorted(r["name"] for r in csv.DictReader(fh)) == ["a1", "a2", "b1"]


KILLED_RUN = textwrap.dedent("""
    import json, os, signal, sys
    from pathlib import Path
    import seed2gs_inverse as sgi
    from seed2gs_inverse.batch import Job, extract_many, runner
    from seed2gs_inverse.batch.worker import JobResult
    res, scene = Path(sys.argv[1]), sys.argv[2]
    def fake(job, output=None, attempt=1):
        if job.name == "j3":
            os.kill(os.getpid(), signal.SIGKILL)  # killed while running the third job
        folder = Path(output) / job.name
        folder.mkdir()
        (folder / "report.json").write_text(json.dumps({"batch": {"job": job.name}, "outputs": {}}))
        return JobResult(name=job.name, status="done", scene=scene, fingerprint=job.fingerprint(),
                         outdir=str(folder))
    runner.run_job = fake
    cam = {"eye": [0, 0, -3], "target": [0, 0, 0], "width": 8, "height": 8}
    extract_many([Job(n, scene, cam, sgi.BoxPrompt([0, 0, 4, 4])) for n in ("j1", "j2", "j3")],
                 "sequential", output=res, progress=False)
""")


def test_a_killed_batch_leaves_its_journal_and_the_next_run_folds_it(tmp_path, fake_jobs):
    jobs, calls = fake_jobs
    res = tmp_path / "res"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    p = subprocess.run([sys.executable, "-c", KILLED_RUN, str(res), str(tmp_path / "s.ply")], env=env,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == -9, p.stderr
    # the two finished jobs are in the journal, one line each (the summary is written at the end)
    lines = (res / JOURNAL).read_text().splitlines()
    assert [json.loads(x)["name"] for x in lines] == ["j1", "j2"]
    assert sorted(read_summary(res)) == ["j1", "j2"]
    # the next run folds the journal, resumes j1 and j2, runs j3, and leaves one consistent summary
    results = extract_many(jobs("j1", "j2", "j3"), "sequential", output=res, progress=False)
    assert [r.resumed for r in results] == [True, True, False] and calls == ["j3"]
    assert not (res / JOURNAL).exists()
    doc = json.loads((res / "summary.json").read_text())
    assert [j["name"] for j in doc["jobs"]] == ["j1", "j2", "j3"]
    assert not lock_file(res / "summary.json").exists()


def test_seed2gs_convert_without_force_keeps_an_output_that_appears_while_it_runs(tmp_path, monkeypatch, capsys):
    from seed2gs_inverse.cli import _scene
    from seed2gs_inverse.io import read_scene, write_scene
    from seed2gs_inverse.synthetic import make_scene

    src, out = tmp_path / "in.ply", tmp_path / "out.splat"
    write_scene(src, make_scene(seed=1, n_per_object=20).scene)

    def read_while_another_process_writes_out(path, **kw):
        out.write_bytes(b"theirs")  # OUT appears after the command checked it
        return read_scene(path, **kw)

    monkeypatch.setattr(_scene, "read_scene", read_while_another_process_writes_out)
    assert main(["convert", str(src), str(out)]) != 0
    assert "exists; use --force" in capsys.readouterr().err
    assert out.read_bytes() == b"theirs"
    assert _leftovers(tmp_path, out.name) == []


def test_a_lock_whose_owner_line_cannot_be_written_is_released(tmp_path, monkeypatch):
    # a full disk can refuse the few bytes of "PID HOST" in the new lock file: the error names the
    # output, and neither the descriptor (holding the lock) nor the lock file may outlive it
    target = tmp_path / "out"
    real_write = os.write
    me = f"{os.getpid()} ".encode()

    def full_disk(fd, data):
        if bytes(data).startswith(me):
            raise OSError(28, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", full_disk)
    with pytest.raises(OSError, match=f"No space left on device while writing {target}"):
        with output_lock(target):
            pass
    monkeypatch.setattr(os, "write", real_write)
    assert not lock_file(target).exists()
    with output_lock(target):  # not "being written by another seed2gs process" (this one)
        assert lock_file(target).exists()
    assert not lock_file(target).exists()
