"""Hostile configuration, jobs and report files: one-line errors of the toolkit, never a hang or a traceback.

* The TOML/JSON reader refuses pipes, devices and directories before
  reading, and files over its size limit (``io.tables.MAX_TABLE_BYTES``).
* ``seed2gs extract --from-report`` checks the whole report (every field's
  type, the format, the paths) before any work, naming the key.
* A short write (a full disk) names the user's file and the operating
  system's cause.
* Job names are checked whole: a trailing newline is not a valid name.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

import seed2gs_inverse.cli as cli
import seed2gs_inverse.pipeline as pipeline
from seed2gs_inverse import _atomic
from seed2gs_inverse._atomic import atomic_path
from seed2gs_inverse.batch.jobs import Job, read_jobs
from seed2gs_inverse.batch.summary import fold_journal, read_summary
from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.frontend.config import load_models
from seed2gs_inverse.frontend.prompts import BoxPrompt
from seed2gs_inverse.io import write_scene
from seed2gs_inverse.io.tables import MAX_TABLE_BYTES, read_table
from seed2gs_inverse.operators import scene_fingerprint
from seed2gs_inverse.scene import GaussianScene

REPO = Path(__file__).resolve().parents[1]


# -- special and oversized files -----------------------------------------------------------------
@contextmanager
def _pipe(fifo: Path, seconds: float = 3.0):
    """Make the FIFO ``fifo``; while the block runs, open it for writing after ``seconds`` and close it:
    a reader blocked on it gets end-of-file (so a reader that hangs on pipes fails the test instead of
    hanging it)."""
    os.mkfifo(fifo)

    def poke():
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        except OSError:  # no reader: nothing is blocked
            return
        os.close(fd)

    timer = threading.Timer(seconds, poke)
    timer.start()
    try:
        yield fifo
    finally:
        timer.cancel()


@pytest.mark.parametrize("name", ["jobs.toml", "models.json"])
def test_a_pipe_is_refused_without_reading(tmp_path, name):
    fifo = tmp_path / name
    with _pipe(fifo):
        with pytest.raises(FormatError, match="not a regular file") as info:
            read_table(fifo, "jobs file")
    assert str(fifo) in str(info.value)


def test_directories_pipes_and_oversized_files_as_jobs_models_and_reports(tmp_path, capsys):
    fifo = tmp_path / "pipe.toml"
    with _pipe(fifo):
        with pytest.raises(FormatError, match="not a regular file"):
            read_jobs(fifo)
        with pytest.raises(FormatError, match="not a regular file"):
            load_models(fifo)
        with pytest.raises(FormatError, match="not a regular file"):
            read_jobs(tmp_path)  # a directory
        assert cli.main(["extract", "--from-report", str(fifo), "-o", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "not a regular file" in err and str(fifo) in err
    big = tmp_path / "big.toml"
    with open(big, "wb") as fh:  # sparse: no disk used
        fh.truncate(MAX_TABLE_BYTES + 1)
    with pytest.raises(FormatError, match=f"more than the {MAX_TABLE_BYTES} bytes") as info:
        read_table(big, "jobs file")
    assert str(big) in str(info.value)
    assert read_table(_write(tmp_path / "ok.toml", "a = 1\n")) == {"a": 1}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


_DEV_ZERO = r"""
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))  # /dev/zero read to the end would pass this
from seed2gs_inverse.errors import Seed2GSError
from seed2gs_inverse.batch.jobs import read_jobs
from seed2gs_inverse.frontend.config import load_models
for fn in (read_jobs, load_models):
    try:
        fn("/dev/zero")
    except Seed2GSError as exc:
        assert "/dev/zero" in str(exc) and "not a regular file" in str(exc), exc
    else:
        raise SystemExit(f"{fn.__name__} read /dev/zero")
print("ok")
"""


@pytest.mark.skipif(not os.path.exists("/dev/zero") or sys.platform != "linux", reason="needs Linux /dev/zero")
def test_dev_zero_is_refused_in_bounded_memory():
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, "-c", _DEV_ZERO], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]


# -- --from-report ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A scene file and a valid report of a box-prompt run on it (as extract writes one)."""
    d = tmp_path_factory.mktemp("report")
    rng = np.random.default_rng(0)
    n = 50
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    scene = GaussianScene(rng.normal(size=(n, 3)).astype(np.float32), quats,
                          np.full((n, 3), -3.0, np.float32), np.zeros(n, np.float32),
                          rng.random((n, 1, 3)).astype(np.float32))
    write_scene(d / "scene.ply", scene)
    cam = Camera.look_at([0, 0, -4], [0, 0, 0], [0, -1, 0], 50.0, 64, 48)
    report = {"run": {"scene": {"path": str(d / "scene.ply"), "sha256": None,
                                "fingerprint": scene_fingerprint(scene), "n_gaussians": n},
                      "camera": {"spec": None, "camera": json.loads(json.dumps(cam.to_dict()))},
                      "prompt": {"kind": "box", "box": [10.0, 10.0, 40.0, 30.0], "iterations": 5, "alpha_min": 0.05},
                      "models": None, "format": "ply", "up_cameras": None},
              "settings": {"n_views": 3}, "resolved": {"solver_options": {}}}
    return {"dir": d, "scene": scene, "report": report}


class _Stop(ValidationError):
    pass


@pytest.fixture
def no_work(monkeypatch):
    """Replace the extraction by a stub that records its calls and stops the command."""
    calls = []

    def stub(*args, **kwargs):
        calls.append(args)
        raise _Stop("stopped before the extraction (test stub)")

    monkeypatch.setattr(pipeline, "extract", stub, raising=False)
    return calls


def _edited(recorded, tmp_path, edit) -> Path:
    rep = json.loads(json.dumps(recorded["report"]))
    edit(rep)
    path = tmp_path / "report.json"
    path.write_text(json.dumps(rep))
    return path


def _set(path: str, value):
    def edit(rep):
        *keys, last = path.split(".")
        d = rep
        for k in keys:
            d = d[k]
        d[last] = value
    return edit


def test_the_valid_report_reaches_the_extraction(recorded, tmp_path, capsys, no_work):
    rep = _edited(recorded, tmp_path, lambda r: None)
    assert cli.main(["extract", "--from-report", str(rep), "-o", str(tmp_path / "o")]) == 2
    assert len(no_work) == 1 and "test stub" in capsys.readouterr().err


@pytest.mark.parametrize("key,value,match", [
    ("run.scene.path", ["a.ply"], "run.scene.path must be a file path (a non-empty string), got a list of 1"),
    ("resolved", "abc", 'resolved must be a section (a JSON object), got "abc"'),
    ("run.models", 3, "run.models must be a file path (a non-empty string), got 3"),
    ("run.format", "exe", 'run.format must be one of ply, splat, got "exe"'),
    ("run.camera.spec", 7, "run.camera.spec must be a camera spec"),
    ("run.camera.camera", {"width": 1}, "run.camera.camera: camera description lacks"),
    ("run.prompt", {"kind": "box", "box": "1 2 3 4"}, "run.prompt.box must be a list of 4 finite numbers"),
    ("run.prompt", {"kind": "box", "box": [1, 2, 3, 4], "iterations": 1e308}, "run.prompt.iterations must be a whole"),
    ("run.prompt", {"kind": "point", "points": [[1, 2]], "labels": [1], "color_tol": 0.1, "depth_tol": 0.1,
                    "radius": "3", "iterations": 5, "alpha_min": 0.05}, "run.prompt.radius must be a whole number"),
    ("run.prompt", {"kind": "text"}, "run.prompt.text is missing"),
    ("run.prompt", {"kind": "exe"}, "run.prompt.kind must be one of mask, box, point, text"),
    ("run.prompt", {"kind": "mask", "path": "/dev/zero"}, "/dev/zero: not a regular file"),
    ("run.up_cameras", {"path": None}, "run.up_cameras.path is missing"),
    ("settings", {"n_views": "many"}, "settings: n_views"),
    ("resolved", {"solver_options": [1]}, "resolved.solver_options must be a section"),
    ("run.scene.fingerprint", 12, "run.scene.fingerprint must be a string"),
    ("run.scene.path", "/dev/zero", "/dev/zero: not a regular file"),
])
def test_a_crafted_report_is_refused_up_front_naming_the_key(recorded, tmp_path, capsys, no_work, key, value, match):
    rep = _edited(recorded, tmp_path, _set(key, value))
    out = tmp_path / "o"
    assert cli.main(["extract", "--from-report", str(rep), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and match in err, err
    assert f"--from-report {rep}" in err or "/dev/zero" in err
    assert ".tmp" not in err and not no_work and not out.exists()  # before any work, nothing written


def test_the_models_file_of_a_report_is_read_bounded(recorded, tmp_path, capsys, no_work):
    fifo = tmp_path / "models.toml"
    rep = _edited(recorded, tmp_path, _set("run.models", str(fifo)))
    with _pipe(fifo):
        assert cli.main(["extract", "--from-report", str(rep), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{fifo}: not a regular file" in err and not no_work


def test_a_report_without_a_fingerprint_says_what_was_not_checked(recorded, tmp_path, capsys, no_work):
    other = tmp_path / "other.ply"
    write_scene(other, recorded["scene"].subset(np.arange(len(recorded["scene"])) % 2 == 0))  # other geometry
    rep = _edited(recorded, tmp_path, lambda r: (_set("run.scene.fingerprint", None)(r),
                                                 _set("run.scene.sha256", "0" * 64)(r)))
    assert cli.main(["extract", str(other), "--from-report", str(rep), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "same geometry" not in err and "records no geometry fingerprint" in err
    assert "was not checked" in err and len(no_work) == 1
    # neither recorded: says that nothing could be compared
    rep = _edited(recorded, tmp_path, _set("run.scene.fingerprint", None))
    assert cli.main(["extract", str(other), "--from-report", str(rep), "-o", str(tmp_path / "o")]) == 2
    assert "records neither its sha256 nor its geometry fingerprint" in capsys.readouterr().err
    # a recorded fingerprint is still checked: the other geometry is refused
    rep = _edited(recorded, tmp_path, lambda r: None)
    assert cli.main(["extract", str(other), "--from-report", str(rep), "-o", str(tmp_path / "o")]) == 2
    assert "not the recorded scene" in capsys.readouterr().err and len(no_work) == 2


# -- short writes ------------------------------------------------------------------------------
def test_a_full_disk_during_q_npy_names_the_file_and_the_cause(tmp_path, monkeypatch):
    """numpy reports a short write as "N requested and M written"; the error names q.npy and ENOSPC."""
    real_save = np.save

    def short_save(file, arr, **kw):  # the partial file a full disk leaves, and numpy's own message
        with open(file, "wb") as fh:
            fh.write(b"\x93NUMPY" + b"\0" * 100)
        raise OSError("3065 requested and 992 written")

    probed = []

    def full_disk(path):  # the probe write meets the full disk as the real one did
        probed.append(path)
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "save", short_save)
    monkeypatch.setattr(_atomic, "_probe_write", full_disk)
    out = tmp_path / "out"
    with pytest.raises(OSError) as info:
        with atomic_path(out, directory=True) as tmp:
            (tmp / "report.json").write_text("{}")
            np.save(tmp / "q.npy", np.zeros(3000, np.float32))
    monkeypatch.setattr(np, "save", real_save)
    msg = str(info.value)
    assert info.value.errno == errno.ENOSPC and "No space left on device" in msg, msg
    assert f"while writing {out / 'q.npy'}" in msg and "requested" not in msg and ".tmp" not in msg
    assert [p.name for p in probed] == ["q.npy"]  # the partial file, the one written last
    assert list(tmp_path.iterdir()) == []


_FSIZE = r"""
import resource, signal, sys
import numpy as np
from seed2gs_inverse._atomic import atomic_path
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (100_000, 100_000))  # writes past 100 kB are refused
try:
    with atomic_path(sys.argv[1], directory=True) as tmp:
        np.save(tmp / "q.npy", np.zeros(1_000_000, np.float32))
except OSError as exc:
    print(exc.errno, exc)
"""


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_FSIZE and SIGXFSZ as on Linux")
def test_a_real_short_write_names_the_file_and_the_operating_systems_cause(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPENBLAS_NUM_THREADS": "1"}
    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-c", _FSIZE, str(out)], env=env, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip() == f"{errno.EFBIG} [Errno {errno.EFBIG}] {os.strerror(errno.EFBIG)} while writing {out / 'q.npy'}"
    assert list(tmp_path.iterdir()) == []


# -- names checked whole --------------------------------------------------------------------
def test_a_job_name_ending_in_a_newline_is_refused(tmp_path):
    jobs = tmp_path / "jobs.toml"
    jobs.write_text('[[jobs]]\nname = "job\\n"\nscene = "s.ply"\ncamera = { eye = [0, 0, -4], target = [0, 0, 0], '
                    'width = 64, height = 48 }\nbox = [1, 2, 30, 40]\n')
    with pytest.raises(ValidationError, match="not a valid folder name"):
        read_jobs(jobs)
    with pytest.raises(ValidationError, match="not a valid folder name"):
        Job("job\n", "s.ply", {"eye": [0, 0, -4], "target": [0, 0, 0], "width": 64, "height": 48},
            BoxPrompt([1, 2, 30, 40]))


def test_a_file_with_a_newline_after_a_temporary_name_is_not_taken_for_one(tmp_path):
    target = tmp_path / "out.ply"
    mine = tmp_path / ".out.ply.abcdefgh.tmp.ply\n"  # a user's file, not a temporary of ours
    mine.write_text("keep")
    os.utime(mine, (0, 0))  # old enough to be removed if it were taken for an abandoned temporary
    assert _atomic.clean_stale_temps(target) == []
    assert mine.exists()


def test_a_mask_folder_ignores_a_name_with_a_trailing_newline(tmp_path):
    from seed2gs_inverse.io import read_masks

    np.save(tmp_path / "view_000.npy", np.zeros((4, 5), np.float32))
    (tmp_path / "view_001.npy\n").write_bytes((tmp_path / "view_000.npy").read_bytes())  # not a mask's name
    assert len(read_masks(tmp_path)) == 1


def test_files_named_inside_configurations_are_checked_to_be_regular(tmp_path):
    fifo = tmp_path / "boxes.json"
    os.mkfifo(fifo)
    unblocked = []

    def poke():
        try:
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            unblocked.append(True)  # a reader was blocked on the pipe
        except OSError:
            pass

    timer = threading.Timer(3.0, poke)  # (a reader blocked on the pipe fails the test instead of hanging it)
    timer.start()
    try:
        cfg = _write(tmp_path / "models.toml", f'[external]\nboxes = "{fifo}"\n')
        with pytest.raises(FormatError, match=r"\[external\] boxes = .*boxes.json is not a regular file"):
            load_models(cfg)
        # a job's fingerprint hashes its models file: bounded, never blocked by a pipe
        job = Job("a", "s.ply", {"eye": [0, 0, -4], "target": [0, 0, 0], "width": 64, "height": 48},
                  BoxPrompt([1, 2, 30, 40]), models=str(fifo))
        job.fingerprint()
    finally:
        timer.cancel()
    assert not unblocked
    jobs = _write(tmp_path / "jobs.toml", f'[[jobs]]\nname = "a"\nscene = "s.ply"\nmodels = "{fifo}"\n'
                  'camera = {{ eye = [0, 0, -4], target = [0, 0, 0], width = 64, height = 48 }}\nbox = [1, 2, 30, 40]\n'
                  .replace("{{", "{").replace("}}", "}"))
    with pytest.raises(ValidationError, match="is not a regular file"):
        read_jobs(jobs)


def test_an_external_boxes_file_that_is_a_pipe_or_too_large_is_refused(tmp_path):
    """The external boxes file is read bounded too: a pipe is refused without blocking, a huge file by size."""
    from seed2gs_inverse.frontend.external import ExternalBoxes
    from seed2gs_inverse.io.tables import MAX_TABLE_BYTES

    with _pipe(tmp_path / "boxes.json") as fifo, pytest.raises(FormatError, match="not a regular file"):
        ExternalBoxes(fifo).detect(np.zeros((8, 8, 3), np.uint8), "x")
    big = tmp_path / "big.json"
    with open(big, "wb") as f:  # sparse: its size is refused before a byte is read
        f.truncate(MAX_TABLE_BYTES + 1)
    with pytest.raises(FormatError, match="big.json"):
        ExternalBoxes(big).detect(np.zeros((8, 8, 3), np.uint8), "x")


@pytest.mark.parametrize("name", ["summary.journal", "summary.json"])
def test_a_pipe_in_a_batch_folder_is_refused_without_reading(tmp_path, name):
    # the runner reads its journal and summary back from the results folder at the start of each run
    fifo = tmp_path / name
    with _pipe(fifo):
        with pytest.raises(ValidationError, match="not a regular file") as info:
            read_summary(tmp_path)
        if name == "summary.journal":  # the journal a killed run left is folded in first
            with pytest.raises(ValidationError, match="not a regular file"):
                fold_journal(tmp_path)
    assert str(fifo) in str(info.value)
