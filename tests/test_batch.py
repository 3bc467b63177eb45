"""Batch extraction on Dask: same q as extract(), failures, resume, dead workers, the CLI.

Every Dask test shares one embedded 2-worker cluster (``dask_client`` in
conftest.py) and tiny procedural scenes.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest

import seed2gs_inverse as sgi
from seed2gs_inverse.batch import Job, extract_many, jobs_from_table, read_jobs
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.io import read_camera, read_scene, write_cameras, write_scene
from seed2gs_inverse.synthetic import make_scene, render_label_masks

from _batch_helpers import KillWorkerMask

OPTS = {"n_views": 4}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """Two procedural scenes on disk, a camera file and the sphere's mask, box and centre per scene."""
    import cv2

    d = tmp_path_factory.mktemp("batch_scenes")
    out = {"dir": d}
    for name, seed in (("a", 1), ("b", 2)):
        s = make_scene(seed=seed, n_per_object=40)
        write_scene(d / f"{name}.ply", s.scene)
        cam = s.reference_camera(96, 72)
        write_cameras(d / f"{name}_cams.json", [cam])
        m = render_label_masks(s.scene, [cam], s.object_mask("sphere"))[0] > 0.5
        cv2.imwrite(str(d / f"{name}_sphere.png"), m.astype(np.uint8) * 255)
        ys, xs = np.nonzero(m)
        out[name] = {"mask": m, "box": [int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1],
                     "click": [float(np.median(xs)), float(np.median(ys))], "camera": cam}
    return out


def _jobs(t):
    d = t["dir"]
    return [
        Job("a-mask", d / "a.ply", f"{d}/a_cams.json:reference", sgi.MaskPrompt(str(d / "a_sphere.png")), OPTS),
        Job("b-box", d / "b.ply", f"{d}/b_cams.json", sgi.BoxPrompt(t["b"]["box"]), OPTS),
        Job("a-box", d / "a.ply", f"{d}/a_cams.json", sgi.BoxPrompt(t["a"]["box"]),
            {**OPTS, "method": "voting"}),
        Job("b-mask", d / "b.ply", t["b"]["camera"], sgi.MaskPrompt(t["b"]["mask"]), OPTS),
    ]


def _sequential_q(job):
    """q of the plain, in-process extract() the job describes."""
    cam = job.camera if isinstance(job.camera, sgi.Camera) else read_camera(job.camera)
    return sgi.extract(read_scene(job.scene), cam, job.prompt, progress=False, **job.options).q


def test_extract_many_matches_sequential_extract_bit_for_bit(tiny, dask_client, tmp_path):
    jobs = _jobs(tiny)
    results = extract_many(jobs, dask_client, output=tmp_path / "res", progress=False)
    assert [r.name for r in results] == [j.name for j in jobs]
    assert all(r.status == "done" for r in results), [r.error for r in results]
    for job, r in zip(jobs, results):
        q = np.load(tmp_path / "res" / job.name / "q.npy")
        assert np.array_equal(q, r.load_q())
        ref = _sequential_q(job)
        assert q.dtype == ref.dtype and np.array_equal(q, ref), job.name
        for f in ("object.ply", "remainder.ply", "report.json", "report.png", "report_masks.png"):
            assert (tmp_path / "res" / job.name / f).is_file()
        assert r.n_selected == int((q > json.loads((tmp_path / "res" / job.name / "report.json")
                                                   .read_text())["threshold"]).sum())
    # Each worker read each scene at most once; every job ran on a Dask worker.
    reads = [(r.worker, r.scene) for r in results if not r.scene_cached]
    assert len(reads) == len(set(reads))
    assert all(r.worker.startswith("tcp://") for r in results)
    # Without an output folder q comes back in memory, identical.
    mem = extract_many(jobs[:1], dask_client, progress=False)
    assert mem[0].outdir is None and np.array_equal(mem[0].q, results[0].load_q())


def test_a_batch_is_one_task_group_named_by_job(tiny, dask_client):
    """The jobs go to the scheduler as one task group (which it queues itself once the group outgrows
    the cluster), each key still naming its job."""
    from dask.utils import key_split
    from distributed import get_task_stream

    jobs = _jobs(tiny)
    with get_task_stream(dask_client) as ts:
        res = extract_many(jobs, dask_client, progress=False)
    assert all(r.status == "done" for r in res), [r.error for r in res]
    keys = [t["key"] for t in ts.data]
    assert len(keys) == len(jobs)
    assert {key_split(k) for k in keys} == {"seed2gs-extract"}
    assert sorted(k[1] for k in keys) == sorted(j.name for j in jobs)


def test_summary_files_and_recorded_failures(tiny, dask_client, tmp_path):
    d = tiny["dir"]
    jobs = [Job("missing-scene", d / "nope.ply", f"{d}/a_cams.json", sgi.BoxPrompt(tiny["a"]["box"]), OPTS),
            Job("box-outside", d / "a.ply", f"{d}/a_cams.json", sgi.BoxPrompt([500, 500, 600, 600]), OPTS),
            *_jobs(tiny)[:2]]
    results = extract_many(jobs, dask_client, output=tmp_path / "res", progress=False)
    st = {r.name: r for r in results}
    assert st["missing-scene"].status == "failed"
    assert "FileNotFoundError" in st["missing-scene"].error and "nope.ply" in st["missing-scene"].error
    assert "scene file not found" in st["missing-scene"].error
    assert st["box-outside"].status == "failed"
    assert "ValidationError" in st["box-outside"].error and "outside" in st["box-outside"].error
    assert st["a-mask"].status == st["b-box"].status == "done"
    assert not (tmp_path / "res" / "missing-scene").exists() and not (tmp_path / "res" / "box-outside").exists()
    summary = json.loads((tmp_path / "res" / "summary.json").read_text())
    assert summary["counts"] == {"jobs": 4, "done": 2, "failed": 2, "resumed": 0}
    rows = list(csv.DictReader(open(tmp_path / "res" / "summary.csv")))
    assert [r["name"] for r in rows] == [j.name for j in jobs]
    by = {r["name"]: r for r in rows}
    assert by["box-outside"]["status"] == "failed" and "outside" in by["box-outside"]["error"]
    done = by["a-mask"]
    assert done["worker"].startswith("tcp://") and int(done["n_selected"]) > 0
    for stage in ("read", "render", "lift", "operators", "solve", "write"):
        assert float(done[f"seconds_{stage}"]) >= 0.0


def test_resume_skips_completed_jobs(tiny, dask_client, tmp_path):
    d = tiny["dir"]
    jobs = [*_jobs(tiny)[:2],
            Job("bad", d / "nope.ply", f"{d}/a_cams.json", sgi.BoxPrompt(tiny["a"]["box"]), OPTS)]
    first = extract_many(jobs, dask_client, output=tmp_path / "res", progress=False)
    assert [r.status for r in first] == ["done", "done", "failed"]
    stamp = {j.name: (tmp_path / "res" / j.name / "q.npy").stat().st_mtime_ns for j in jobs[:2]}
    again = extract_many(jobs, dask_client, output=tmp_path / "res", progress=False)
    assert [r.resumed for r in again] == [True, True, False]  # failed jobs run again
    assert [r.status for r in again] == ["done", "done", "failed"]
    assert {j.name: (tmp_path / "res" / j.name / "q.npy").stat().st_mtime_ns for j in jobs[:2]} == stamp
    assert again[0].n_selected == first[0].n_selected
    # A changed job description runs again; resume=False runs everything.
    changed = [jobs[0], Job(jobs[1].name, jobs[1].scene, jobs[1].camera, jobs[1].prompt, {"n_views": 3}), jobs[2]]
    third = extract_many(changed, dask_client, output=tmp_path / "res", progress=False)
    assert [r.resumed for r in third] == [True, False, False]
    assert (tmp_path / "res" / jobs[1].name / "q.npy").stat().st_mtime_ns != stamp[jobs[1].name]
    fourth = extract_many(changed[:1], dask_client, output=tmp_path / "res", progress=False, resume=False)
    assert not fourth[0].resumed


def test_jobs_file_defaults_overrides_and_relative_paths(tiny, tmp_path):
    d = tiny["dir"]
    eye = tiny["a"]["camera"].center.tolist()
    (tmp_path / "jobs.toml").write_text(f"""
[defaults]
scene = "{d}/a.ply"
camera = "{d}/a_cams.json:reference"
figure = false
[defaults.options]
n_views = 5
method = "voting"

[[jobs]]
name = "m"
mask = "{d}/a_sphere.png"

[[jobs]]
name = "p"
point = [{tiny['a']['click'][0]}, {tiny['a']['click'][1]}]
negative = [[1, 1]]
options = {{ n_views = 3 }}

[[jobs]]
name = "look"
scene = "../{tmp_path.name}/b.ply"
camera = {{ eye = {eye}, target = [0, 0, 0], width = 64, height = 48, fov = 50 }}
box = [10, 10, 40, 30]
format = "splat"
""")
    jobs = read_jobs(tmp_path / "jobs.toml")
    assert [j.name for j in jobs] == ["m", "p", "look"]
    assert jobs[0].options == {"n_views": 5, "method": "voting"} and jobs[0].figure is False
    assert jobs[1].options == {"n_views": 3, "method": "voting"}
    assert isinstance(jobs[1].prompt, sgi.PointPrompt) and list(jobs[1].prompt.labels) == [1, 0]
    assert jobs[2].scene == str((tmp_path / "b.ply").resolve()) and jobs[2].format == "splat"
    cam = jobs[2].read_camera()
    assert (cam.width, cam.height) == (64, 48) and np.allclose(cam.center, eye)
    assert jobs[0].extract_kwargs() == {"n_views": 5, "method": "voting", "progress": False}
    assert jobs[0].fingerprint() != jobs[1].fingerprint()


@pytest.mark.parametrize("body, words", [
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5,5]\noptions={n_veiws=3}',
     ["job 'x'", "n_veiws", "n_views"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5,5]\ntext="cup"', ["exactly one prompt"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\nbox=[0,0,5,5]', ["no 'camera'"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5]', ["x0, y0, x1, y1"]),
    ('[[jobs]]\nname="../x"\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5,5]', ["folder name"]),
    ('[defaults]\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5,5]\n[[jobs]]\nname="x"\n[[jobs]]\nname="x"',
     ["unique"]),
    ('[defaults]\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5,5]\n[[jobs]]\nname="Cup"\n[[jobs]]\nname="cup"',
     ["jobs[0]", "unique, also ignoring case"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5,5]\ncolour="red"', ["unknown key"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera={eye=[0,0,0],target=[0,0,1]}\nbox=[0,0,5,5]', ["width"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\npoint=[[50,78],[1]]', ["'point'", "[[50, 78], [1]]"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\npoint=[[5,7]]\nnegative=[[1,2],[3]]',
     ["'negative'", "[[1, 2], [3]]"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\npoint=[[5,7]]\nnegative=[1,2,3]',
     ["'negative' must be [x, y]", "[1, 2, 3]"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\npoint=[[5,7]]\nnegative="ab"', ["'negative'", "'ab'"]),
    ('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\npoint=[]', ["at least one click"]),
])
def test_jobs_file_errors_name_file_and_job(tmp_path, body, words):
    p = tmp_path / "jobs.toml"
    p.write_text(body)
    with pytest.raises((ValidationError, FormatError)) as exc:
        read_jobs(p)
    assert str(p) in str(exc.value)
    for w in words:
        assert w in str(exc.value)


def test_job_and_runner_arguments_are_validated(tiny):
    d = tiny["dir"]
    with pytest.raises(ValidationError, match="not a Job"):
        extract_many([{"name": "x"}], "sequential")
    j = _jobs(tiny)[0]
    with pytest.raises(ValidationError, match="unique"):
        extract_many([j, j], "sequential")
    with pytest.raises(ValidationError, match=r"ignoring case.*\['A-MASK', 'a-mask'\]"):
        extract_many([j, Job("A-MASK", j.scene, j.camera, j.prompt, OPTS)], "sequential")
    with pytest.raises(ValidationError, match="tcp://"):
        extract_many([j], "localhost:8786")
    with pytest.raises(ValidationError, match="prompt"):
        Job("x", d / "a.ply", "c.json", "a cup")
    with pytest.raises(ValidationError, match="progress"):
        jobs_from_table({"jobs": [{"name": "x", "scene": "s", "camera": "c", "box": [0, 0, 4, 4],
                                   "options": {"progress": True}}]})


def test_output_folders_no_batch_wrote_are_refused_and_kept(tiny, tmp_path):
    res = tmp_path / "res"
    (res / "a-mask").mkdir(parents=True)
    (res / "a-mask" / "mine.txt").write_text("keep")
    job = _jobs(tiny)[0]
    for resume in (True, False):
        with pytest.raises(ValidationError, match=r"a-mask, which no earlier batch there wrote"):
            extract_many([job], "sequential", output=res, progress=False, resume=resume)
    assert (res / "a-mask" / "mine.txt").read_text() == "keep"
    assert sorted(p.name for p in res.iterdir()) == ["a-mask"]
    other = tmp_path / "other"
    other.mkdir()
    (other / "summary.json").write_text('{"results": []}')
    with pytest.raises(ValidationError, match="not the summary of a seed2gs batch"):
        extract_many([job], "sequential", output=other, progress=False)
    assert (other / "summary.json").read_text() == '{"results": []}'
    (other / "summary.json").unlink()
    (other / "summary.csv").write_text("my,own,table\n")  # a user's table named like the batch's
    with pytest.raises(ValidationError, match=r"summary.csv is not the summary of a seed2gs batch"):
        extract_many([job], "sequential", output=other, progress=False)
    assert (other / "summary.csv").read_text() == "my,own,table\n"


def test_summary_keeps_earlier_jobs_and_a_failed_rerun_leaves_no_folder(tiny, tmp_path):
    jobs = _jobs(tiny)[:2]
    res = tmp_path / "res"
    extract_many(jobs[:1], "sequential", output=res, progress=False)
    extract_many(jobs[1:], "sequential", output=res, progress=False)

    def listed():
        return [(j["name"], j["status"]) for j in json.loads((res / "summary.json").read_text())["jobs"]]

    assert listed() == [("b-box", "done"), ("a-mask", "done")]
    assert [r.resumed for r in extract_many(jobs, "sequential", output=res, progress=False)] == [True, True]
    # resume=False replaces the folders the batch wrote
    rerun = extract_many(jobs[:1], "sequential", output=res, progress=False, resume=False)
    assert rerun[0].status == "done" and not rerun[0].resumed
    # ... but not a user's file put in one: refused before anything runs (it used to fail the job and
    # remove the folder with the file); a resumed job leaves its folder alone, so that run goes on
    (res / "a-mask" / "notes.txt").write_text("mine")
    with pytest.raises(ValidationError, match=r"job folder a-mask \(it holds files that are not part of such an "
                                              r"output \(notes.txt\)\) would be replaced"):
        extract_many(jobs[:1], "sequential", output=res, progress=False, resume=False)
    assert extract_many(jobs[:1], "sequential", output=res, progress=False)[0].resumed
    assert (res / "a-mask" / "notes.txt").read_text() == "mine"
    (res / "a-mask" / "notes.txt").unlink()
    # A re-run that fails takes the earlier result of that name away: the folders are what the summary
    # lists as done.
    bad = Job("a-mask", jobs[0].scene, jobs[0].camera, sgi.BoxPrompt([500, 500, 600, 600]), OPTS)
    r, = extract_many([bad], "sequential", output=res, progress=False)
    assert r.status == "failed" and r.outdir is None
    assert not (res / "a-mask").exists()
    assert listed() == [("a-mask", "failed"), ("b-box", "done")]
    assert sorted(p.name for p in res.iterdir() if not p.name.startswith(".")) == ["b-box", "summary.csv",
                                                                                   "summary.json"]
    # A folder made under the name of a job the summary lists as failed is the user's, not the batch's.
    (res / "a-mask").mkdir()
    (res / "a-mask" / "notes.txt").write_text("mine")
    with pytest.raises(ValidationError, match="a-mask, which no earlier batch there wrote"):
        extract_many(jobs[:1], "sequential", output=res, progress=False)
    assert (res / "a-mask" / "notes.txt").read_text() == "mine"
    # A folder a worker finished after the runner was interrupted (no summary line) is the batch's: its
    # report.json names the job, so the next run replaces it instead of refusing.
    report = json.loads((res / "b-box" / "report.json").read_text())
    assert report["batch"]["job"] == "b-box" and report["batch"]["fingerprint"] == jobs[1].fingerprint()
    (res / "summary.json").unlink()
    again = extract_many(jobs[1:], "sequential", output=res, progress=False)
    assert again[0].status == "done" and not again[0].resumed


def test_resume_runs_a_job_again_when_an_input_file_changed(tiny, tmp_path):
    import cv2

    mask = tmp_path / "m.png"
    m = tiny["a"]["mask"].astype(np.uint8) * 255
    cv2.imwrite(str(mask), m)
    job = Job("m", tiny["dir"] / "a.ply", f"{tiny['dir']}/a_cams.json", sgi.MaskPrompt(str(mask)), OPTS)
    res = tmp_path / "res"
    assert extract_many([job], "sequential", output=res, progress=False)[0].status == "done"
    assert extract_many([job], "sequential", output=res, progress=False)[0].resumed
    cv2.imwrite(str(mask), np.roll(m, 1, axis=1))  # the same path, another mask
    st = mask.stat()
    os.utime(mask, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    again = extract_many([job], "sequential", output=res, progress=False)[0]
    assert again.status == "done" and not again.resumed


def test_resume_and_the_scene_cache_notice_a_replaced_scene_file(tiny, tmp_path):
    """Another scene written to the same path: the job runs again (not resumed), the process's scene cache
    does not hand back the old arrays, and q is that of a fresh extract() of the new file."""
    import shutil

    scene = tmp_path / "s.ply"
    shutil.copy(tiny["dir"] / "a.ply", scene)
    job = Job("s", scene, f"{tiny['dir']}/a_cams.json", sgi.BoxPrompt(tiny["a"]["box"]), OPTS)
    res = tmp_path / "res"
    first = extract_many([job], "sequential", output=res, progress=False)[0]
    assert first.status == "done"
    q_first = first.load_q()
    assert extract_many([job], "sequential", output=res, progress=False)[0].resumed
    write_scene(scene, make_scene(seed=7, n_per_object=40).scene)
    st = scene.stat()
    os.utime(scene, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    again = extract_many([job], "sequential", output=res, progress=False)[0]
    assert again.status == "done" and not again.resumed and not again.scene_cached
    q = again.load_q()
    assert np.array_equal(q, _sequential_q(job))
    assert q.shape != q_first.shape or not np.array_equal(q, q_first)
    # A worker keeps its scenes between jobs (the sequential runner clears them after each call): a
    # replaced file is read again there too.
    from seed2gs_inverse.batch.worker import clear_scene_cache, run_job

    try:
        assert run_job(job).scene_cached is False
        assert run_job(job).scene_cached is True
        shutil.copy(tiny["dir"] / "a.ply", scene)
        st = scene.stat()
        os.utime(scene, ns=(st.st_atime_ns, st.st_mtime_ns + 2 * 10**9))
        back = run_job(job)
        assert back.status == "done" and back.scene_cached is False and np.array_equal(back.q, q_first)
    finally:
        clear_scene_cache()


def test_a_moved_results_directory_resumes_from_its_own_folders(tiny, tmp_path):
    """Resumed jobs point at the output this run was given, not where an earlier run wrote them; a run
    with every job resumed starts no cluster."""
    jobs = _jobs(tiny)[:2]
    first = tmp_path / "first"
    done = extract_many(jobs, "sequential", output=first, progress=False)
    q = [r.load_q() for r in done]
    moved = tmp_path / "moved"
    first.rename(moved)
    again = extract_many(jobs + [_jobs(tiny)[2]], "sequential", output=moved, progress=False)
    assert [r.resumed for r in again] == [True, True, False]
    for r, want in zip(again, q):
        assert r.outdir == str(moved / r.name) and np.array_equal(r.load_q(), want)
    only_first = extract_many(jobs[:1], None, output=moved, progress=False)  # no scheduler: would start one
    assert only_first[0].resumed and only_first[0].outdir == str(moved / jobs[0].name)
    doc = json.loads((moved / "summary.json").read_text())
    assert doc["meta"]["where"] == "nothing to run (every job resumed)"
    assert {d["name"]: d["outdir"] for d in doc["jobs"]} == {j.name: str(moved / j.name) for j in _jobs(tiny)[:3]}


def test_job_paths_become_absolute_and_values_are_checked_up_front(tiny, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    j = Job("x", "s.ply", "c.json:ref", sgi.MaskPrompt("m.png"), models="models.toml")
    assert j.scene == str(tmp_path / "s.ply") and j.camera == f"{tmp_path / 'c.json'}:ref"
    assert j.prompt.mask == str(tmp_path / "m.png") and j.models == str(tmp_path / "models.toml")
    box = sgi.BoxPrompt([0, 0, 4, 4])
    for kwargs, words in (({"options": {"n_views": "four"}}, "job 'x': options: n_views"),
                          ({"options": {"method": "nosuch"}}, "unknown solver method 'nosuch'"),
                          ({"prompt": sgi.TextPrompt("cup")}, "text prompt needs 'models'"),
                          ({"name": "summary.json"}, "taken by the batch")):
        args = {"name": "x", "scene": "s.ply", "camera": "c.json", "prompt": box, **kwargs}
        with pytest.raises(ValidationError, match=words):
            Job(**args)
    with pytest.raises(ValidationError, match="need x0 < x1"):  # a prompt is checked when made
        sgi.BoxPrompt([46, 35, 32, 22])
    p = tmp_path / "jobs.toml"
    p.write_text('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\nbox=[46,35,32,22]')
    with pytest.raises(ValidationError, match=r"job 'x' \(jobs\[0\]\): box .* is empty"):
        read_jobs(p)
    p.write_text('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json"\nbox=[0,0,5,5]\noptions={n_views=1}')
    with pytest.raises(ValidationError) as exc:
        read_jobs(p)
    assert str(exc.value).startswith(f"{p}: job 'x' (jobs[0]): options: n_views") and "job 'x': job" not in str(
        exc.value)
    job = _jobs(tiny)[0]
    with pytest.raises(ValidationError, match="n_workers must be"):
        extract_many([job], "sequential", n_workers=0)
    with pytest.raises(ValidationError, match="does not go with"):
        extract_many([job], "sequential", n_workers=2)


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_an_output_that_cannot_be_written_fails_before_any_job(tiny, tmp_path):
    with pytest.raises(ValidationError, match=r"output /proc/seed2gs-res: cannot write in /proc"):
        extract_many([_jobs(tiny)[0]], "sequential", output="/proc/seed2gs-res", progress=False)


def test_a_script_without_a_main_guard_gets_told_how_to_fix_it(tiny, tmp_path):
    """Embedded workers start by importing the user's script; one that calls extract_many at its top
    level must fail with the fix in the message, not with a screen of Dask tracebacks only."""
    import subprocess
    import sys

    job = _jobs(tiny)[0]
    script = tmp_path / "unguarded.py"
    script.write_text(
        "import seed2gs_inverse as sgi\n"
        f"job = sgi.Job('x', {job.scene!r}, {job.camera!r}, sgi.BoxPrompt({tiny['a']['box']!r}), {OPTS!r})\n"
        "sgi.extract_many([job], n_workers=1, progress=False)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=240, env=env,
                         cwd=tmp_path)
    assert run.returncode != 0
    assert "ValidationError: could not start the embedded Dask workers" in run.stderr
    assert "if __name__ == \"__main__\":" in run.stderr


def test_embedded_cluster_sizes_numba_threads(dask_client):
    info = dask_client.scheduler_info()["workers"]
    assert len(info) == 2 and all(w["nthreads"] == 1 for w in info.values())
    cores = len(os.sched_getaffinity(0))
    want = max(1, cores // 2)
    cap = os.environ.get("NUMBA_NUM_THREADS")
    if cap and cap.isdigit():
        want = min(want, int(cap))
    env = dask_client.run(lambda: (os.environ.get("NUMBA_NUM_THREADS"), os.environ.get("OMP_WAIT_POLICY")))
    assert set(env.values()) == {(str(want), "PASSIVE")}


def test_threads_per_worker_sets_the_workers_threads_and_is_checked():
    from seed2gs_inverse.batch import batch_client

    with batch_client(None, n_workers=1, threads_per_worker=3) as c:
        env = c.run(lambda: os.environ.get("NUMBA_NUM_THREADS"))
    assert list(env.values()) == ["3"]
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValidationError, match="threads_per_worker"):
            with batch_client(None, n_workers=1, threads_per_worker=bad):
                pass

def test_cli_batch_on_a_scheduler_address(tiny, dask_client, tmp_path, capsys):
    from seed2gs_inverse.cli import main

    d = tiny["dir"]
    (tmp_path / "jobs.toml").write_text(f"""
[defaults]
scene = "{d}/a.ply"
camera = "{d}/a_cams.json:reference"
options = {{ n_views = 4 }}
[[jobs]]
name = "sphere"
box = {tiny['a']['box']}
[[jobs]]
name = "broken"
box = [900, 900, 950, 950]
""")
    args = ["batch", str(tmp_path / "jobs.toml"), "-o", str(tmp_path / "res"), "--scheduler",
            dask_client.scheduler.address, "--no-progress"]
    assert main(args) == 1  # one job failed
    out, err = capsys.readouterr()
    assert "2 jobs: 1 done, 1 failed" in out and "broken: ValidationError" in err
    assert main(args) == 1
    out, _ = capsys.readouterr()
    assert "1 done (1 by an earlier run)" in out
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):  # nobody listens on port 1
        assert main(["batch", str(tmp_path / "jobs.toml"), "-o", str(tmp_path / "r2"), "--scheduler",
                     "tcp://127.0.0.1:1", "--no-progress"]) == 2
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err
    assert main(["batch", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "r3")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_killed_worker_job_is_retried_once(tiny, dask_client, tmp_path):
    # Last in this module: it kills three worker processes (their nannies restart them).
    # One killer per batch, so no other job shares a dying worker by chance.
    d = tiny["dir"]
    once, always = tmp_path / "once", tmp_path / "always"
    once.mkdir()
    always.mkdir()
    m = tiny["a"]["mask"]
    r1, = extract_many([Job("dies-once", d / "a.ply", f"{d}/a_cams.json",
                            KillWorkerMask(m, marker_dir=str(once), times=1), OPTS)],
                       dask_client, output=tmp_path / "res", progress=False)
    assert len(list(once.glob("killed-*"))) == 1
    assert r1.status == "done" and r1.attempts == 2
    ref = _sequential_q(Job("ref", d / "a.ply", f"{d}/a_cams.json", sgi.MaskPrompt(m), OPTS))
    assert np.array_equal(r1.load_q(), ref)
    r2, = extract_many([Job("dies-twice", d / "a.ply", f"{d}/a_cams.json",
                            KillWorkerMask(m, marker_dir=str(always), times=2), OPTS)],
                       dask_client, output=tmp_path / "res", progress=False)
    assert len(list(always.glob("killed-*"))) == 2  # tried twice, not more
    assert r2.status == "failed" and r2.attempts == 2 and "worker died" in r2.error
    summary = json.loads((tmp_path / "res" / "summary.json").read_text())
    # this run's job first, then the earlier run's, which the summary keeps
    assert [(j["name"], j["status"], j["attempts"]) for j in summary["jobs"]] == [("dies-twice", "failed", 2),
                                                                                 ("dies-once", "done", 2)]


def test_the_embedded_workers_ignore_ctrl_c(dask_client):
    """Ctrl-C reaches the whole process group; the workers leave it to the runner (one line, 'interrupted',
    instead of a traceback per worker), also those the nannies started again after the killed-worker test."""
    import signal

    dask_client.wait_for_workers(2, timeout=60)
    ignored = dask_client.run(lambda: signal.getsignal(signal.SIGINT) is signal.SIG_IGN)
    assert len(ignored) == 2 and all(ignored.values())


def test_camera_specs_split_as_read_camera_splits_them(tmp_path, monkeypatch):
    """A job's camera file (what resume stamps, what a relative path resolves against) is found by
    read_camera's rule: the longest existing prefix before a colon, so names may hold colons."""
    from seed2gs_inverse.io.cameras import split_camera_spec

    (tmp_path / "c.json").write_text("[]")
    (tmp_path / "sparse").mkdir()
    assert split_camera_spec(f"{tmp_path}/c.json:frame:1") == (f"{tmp_path}/c.json", "frame:1")
    assert split_camera_spec(f"{tmp_path}/sparse:img.png") == (f"{tmp_path}/sparse", "img.png")
    assert split_camera_spec(f"{tmp_path}/none.json:a") == (f"{tmp_path}/none.json", "a")
    assert split_camera_spec(f"{tmp_path}/c.json") == (f"{tmp_path}/c.json", None)
    elsewhere = tmp_path / "run"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # relative paths are the jobs file's, not the working directory's
    (tmp_path / "jobs.toml").write_text('[[jobs]]\nname="x"\nscene="s.ply"\ncamera="c.json:frame:1"\nbox=[0,0,4,4]')
    (job,) = read_jobs(tmp_path / "jobs.toml")
    assert job.camera == f"{tmp_path / 'c.json'}:frame:1"
    assert job.input_files()["camera"] == str(tmp_path / "c.json")


def test_the_dashboard_of_an_existing_scheduler_is_named_only_when_it_serves_its_page(monkeypatch):
    import threading
    import time
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    from seed2gs_inverse.batch.cluster import dashboard_address as _dashboard

    slow_started = [0.0]

    class Page(BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            if self.path == "/slow":  # headers a byte at a time: each read within a timeout of 2 s
                slow_started[0] = time.perf_counter()
                for byte in b"HTTP/1.0 200 OK\r\n":
                    self.wfile.write(bytes([byte]))
                    self.wfile.flush()
                    time.sleep(0.25)
                return
            self.send_response(200 if self.path == "/status" else 404)
            self.end_headers()

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Page)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_port}"

    class Client:  # an existing scheduler's client: no embedded cluster
        cluster = None

        def __init__(self, path):
            self.dashboard_link = base + path

        def scheduler_info(self):
            return {"services": {"dashboard": server.server_port}}  # listed even with --no-dashboard

    try:
        assert _dashboard(Client("/status")) == base + "/status"
        assert _dashboard(Client("/missing")) is None  # dask scheduler --no-dashboard answers 404
        monkeypatch.setenv("http_proxy", "http://127.0.0.1:9")  # a proxy that answers nothing: not asked
        monkeypatch.setenv("no_proxy", "")
        assert _dashboard(Client("/status")) == base + "/status"
        assert _dashboard(Client("/slow")) is None  # within the limit, however the server trickles
        assert 1.0 < time.perf_counter() - slow_started[0] < 2.9
        relative = Client("/status")
        relative.dashboard_link = "/user/me/proxy/8787/status"  # JupyterHub: given as configured
        assert _dashboard(relative) == "/user/me/proxy/8787/status"
    finally:
        server.shutdown()
        server.server_close()


def test_job_may_not_take_the_journal_name():
    # the runner appends finished jobs to summary.journal in the results directory: a job folder of
    # that name would collide with it, as one named summary.json would with the summary
    for name in ("summary.journal", "Summary.Journal"):
        with pytest.raises(ValidationError, match="taken by the batch"):
            Job(name, "s.ply", "c.json", sgi.BoxPrompt([0, 0, 4, 4]))
