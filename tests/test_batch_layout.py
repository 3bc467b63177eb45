"""Where a batch runs: the layout rule, what is printed and recorded, and nothing left in the temporary folder."""

from __future__ import annotations

import json
import os
import sys
import tempfile

import numpy as np
import pytest
from PIL import Image

import seed2gs_inverse as sgi
from seed2gs_inverse._extras import MissingExtraError
from seed2gs_inverse.batch import Job, choose_layout, extract_many, open_layout, resolve_layout
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.io import write_cameras, write_scene
from seed2gs_inverse.synthetic import make_scene, render_label_masks

PIP_BATCH = 'pip install "seed2gs-inverse[batch]"'


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """One tiny job on disk: a procedural scene, its camera file and a mask prompt of its sphere."""
    d = tmp_path_factory.mktemp("layout_scene")
    s = make_scene(seed=3, n_per_object=40)
    write_scene(d / "s.ply", s.scene)
    cam = s.reference_camera(96, 72)
    write_cameras(d / "cams.json", [cam])
    mask = render_label_masks(s.scene, [cam], s.object_mask("sphere"))[0] > 0.5
    Image.fromarray(mask.astype(np.uint8) * 255).save(d / "sphere.png")
    return Job("sphere", d / "s.ply", f"{d}/cams.json", sgi.MaskPrompt(str(d / "sphere.png")), {"n_views": 4},
               figure=False)


# (jobs, cores) -> layout, written out by hand from the rule in the README ("Many objects, many scenes"):
# workers from 4 jobs, from 16 on a machine of at most 2 cores, never on one core.
RULE = [((0, 4), "sequential"), ((1, 16), "sequential"), ((3, 16), "sequential"), ((4, 16), "workers"),
        ((4, 3), "workers"), ((3, 2), "sequential"), ((15, 2), "sequential"), ((16, 2), "workers"),
        ((500, 2), "workers"), ((500, 1), "sequential")]


@pytest.mark.parametrize("jobs_cores, want", RULE)
def test_the_layout_rule(jobs_cores, want):
    assert choose_layout(*jobs_cores) == want


def test_the_rule_checks_its_counts():
    for bad in ((-1, 2), (3, 0), (2.5, 2), (3, True)):
        with pytest.raises(ValidationError, match="n_jobs|cores"):
            choose_layout(*bad)


def test_resolve_layout_sizes_what_the_rule_chooses_and_obeys_explicit_options(monkeypatch):
    monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
    seq = resolve_layout(None, n_jobs=3, cores=2)
    assert (seq.kind, seq.workers, seq.threads, seq.chosen) == ("sequential", 1, 2, True)
    many = resolve_layout(None, n_jobs=20, cores=8)
    assert (many.kind, many.workers, many.threads, many.chosen) == ("workers", 8, 1, True)
    few = resolve_layout(None, n_jobs=5, cores=12)  # one worker per job, the cores shared out
    assert (few.kind, few.workers, few.threads) == ("workers", 5, 2)
    # explicit options win over the rule
    asked = resolve_layout(None, n_workers=2, n_jobs=1, cores=2)
    assert (asked.kind, asked.workers, asked.threads, asked.chosen) == ("workers", 2, 1, False)
    assert resolve_layout(None, threads_per_worker=3, n_jobs=1, cores=2).kind == "workers"
    forced = resolve_layout("sequential", n_jobs=500, cores=8)
    assert (forced.kind, forced.chosen) == ("sequential", False)
    assert resolve_layout("tcp://10.0.0.1:8786", n_jobs=1, cores=2).kind == "cluster"
    # a NUMBA_NUM_THREADS set here caps the one process's threads as it caps each worker's
    monkeypatch.setenv("NUMBA_NUM_THREADS", "1")
    assert resolve_layout(None, n_jobs=3, cores=2).threads == 1
    assert resolve_layout(None, n_jobs=20, cores=8, n_workers=2).threads == 1


def test_the_printed_line_says_where_and_why():
    seq = resolve_layout(None, n_jobs=3, cores=2)
    line = seq.describe(3)
    assert line.startswith(f"batch: 3 jobs, sequential in one process with {seq.threads} thread")
    assert "(2 cores; chosen: worker processes pay off from 16 jobs on 2 cores)" in line
    workers = resolve_layout(None, n_jobs=20, cores=8)
    assert workers.describe(20).startswith("batch: 20 jobs, 8 Dask worker processes of 1 thread each (8 cores;")
    assert resolve_layout(None, n_workers=2, cores=2).describe(1).endswith("(2 cores; asked for)")


def test_without_dask_the_rule_falls_back_to_one_process_and_a_cluster_asked_for_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if the 'batch' extra were not installed
    fallback = resolve_layout(None, n_jobs=20, cores=8)
    assert fallback.kind == "sequential" and fallback.chosen
    assert PIP_BATCH in fallback.why and PIP_BATCH in fallback.describe(20)
    with pytest.raises(MissingExtraError, match=PIP_BATCH.replace("[", r"\[").replace("]", r"\]")):
        with open_layout(resolve_layout(None, n_workers=2, cores=2)):
            pass


def test_a_batch_prints_and_records_its_layout(job, tmp_path, capsys):
    from seed2gs_inverse.cli import main

    (tmp_path / "jobs.toml").write_text(f"""
[[jobs]]
name = "sphere"
scene = "{job.scene}"
camera = "{job.camera}"
mask = "{job.prompt.mask}"
options = {{ n_views = 4 }}
figure = false
""")
    assert main(["batch", str(tmp_path / "jobs.toml"), "-o", str(tmp_path / "res"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if ln.startswith("batch: "))
    assert line.startswith("batch: 1 job, sequential in one process with ")  # one job: never workers
    meta = json.loads((tmp_path / "res" / "summary.json").read_text())["meta"]
    assert meta["layout"]["kind"] == "sequential" and meta["layout"]["chosen"] is True
    assert meta["layout"]["why"] in line


def test_a_batch_leaves_the_temporary_folder_as_it_found_it(job, tmp_path, monkeypatch):
    """Dask's workers put a dask-scratch-space/ into the temporary folder and leave it there; a batch
    gives them a folder of its own and removes it (the spawned workers inherit TMPDIR)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    (tmp / "someone-else.txt").write_text("kept")
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr(tempfile, "tempdir", None)  # gettempdir() reads TMPDIR again
    assert tempfile.gettempdir() == str(tmp)
    seen = []
    res = extract_many([job], n_workers=1, output=tmp_path / "res", progress=False, log=seen.append)
    assert res[0].ok, res[0].error
    assert res[0].worker != "local"  # it ran on a Dask worker
    assert seen[0].startswith("batch: 1 job, 1 Dask worker process of ") and seen[0].endswith("; asked for)")
    assert sorted(os.listdir(tmp)) == ["someone-else.txt"]
    assert json.loads((tmp_path / "res" / "summary.json").read_text())["meta"]["layout"]["kind"] == "workers"
    again = extract_many([job], "sequential", output=tmp_path / "res2", progress=False)
    assert sorted(os.listdir(tmp)) == ["someone-else.txt"]
    assert np.array_equal(again[0].load_q(), res[0].load_q())  # either layout, the same q
