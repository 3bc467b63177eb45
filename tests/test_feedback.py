"""What long commands say while they run: stage lines off a terminal, --quiet, compile time, caps, the axis.

Stage lines and job lines are checked against the seconds and statuses the
runs record (report.json, summary.json); the compile clock against a Numba
function compiled here; the caps against the views' actual sizes.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from numba import njit

import seed2gs_inverse.cli as cli
from _cli_files import write_cli_files
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.pipeline import extract
from seed2gs_inverse.pipeline.extraction import STAGES
from seed2gs_inverse.progress import Feedback, Progress, StageTimer, notice
from seed2gs_inverse.raster import compile_seconds

REPO = Path(__file__).resolve().parents[1]
#: A stage line: ``seed2gs: render 0.12 s``.
STAGE_LINE = re.compile(r"^seed2gs: (\w+) (\d+\.\d\d) s$")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return write_cli_files(tmp_path_factory.mktemp("feedback"))


def _run(args) -> int:
    return cli.main([str(a) for a in args])


def _extract_args(files, out, *extra):
    d = files["dir"]
    return ["extract", d / "scene.ply", "--camera", f"{d / 'cameras.json'}:0", "--mask", d / "mask.png",
            "-o", out, "--views", 3, "--up", "0,-2,0", *extra]


def test_off_a_terminal_each_stage_says_one_line_with_its_seconds(files, capsys, tmp_path):
    """stderr captured (not a terminal): one line per stage as it ends, with the seconds report.json records;
    the caps and the orbit axis used are printed with the result and recorded."""
    out = tmp_path / "lines"
    assert _run(_extract_args(files, out, "--orbit-scale", 2, "--max-view-pixels", 3000,
                              "--max-reference-pixels", 6000)) == 0
    std = capsys.readouterr()
    rep = json.loads((out / "report.json").read_text())
    lines = [m.groups() for m in map(STAGE_LINE.match, std.err.splitlines()) if m]
    # every stage once, in the order they end (the orbit views' operators end with the orbit views)
    assert [name for name, _ in lines] == ["render", "grounding", "lift", "vaas", "operators", "tracking",
                                           "solve", "write"]
    for name, seconds in lines[:-1]:
        assert float(seconds) == pytest.approx(rep["seconds"][name], abs=0.0051), name
    assert "\r" not in std.err  # no bars
    # the caps: printed, recorded, and the sizes the run used
    caps = rep["resolved"]["caps"]
    orbit, ref = caps["orbit_views"], caps["reference_view"]
    w, h = orbit["size"]
    assert f"orbit views {w}x{h}: --orbit-scale 2 capped by --max-view-pixels 3000" in std.out
    assert orbit["asked"] == 2.0 and orbit["limit"] == 3000 and orbit["scale"] == rep["resolved"]["view_scale"]
    cam = files["cam"]
    assert (w, h) == cam.scaled(orbit["scale"]).image_shape[::-1] and w * h <= 3000 + w + h
    rw, rh = ref["size"]
    assert f"reference view {rw}x{rh} for the seed lift: the camera's 128x96 capped by " \
           f"--max-reference-pixels 6000" in std.out
    assert ref["camera_size"] == [128, 96] and rw * rh <= 6000 + rw + rh and ref["scale"] < 1.0
    assert rep["resolved"]["reference_scale"] == ref["scale"]
    # the orbit axis used, and how it was chosen
    assert "orbit axis 0.000,-1.000,0.000 (--up 0.000,-2.000,0.000: as given)" in std.out


def test_quiet_says_nothing_on_stderr(files, capsys, tmp_path):
    assert _run(_extract_args(files, tmp_path / "quiet", "--quiet")) == 0
    std = capsys.readouterr()
    assert std.err == ""
    assert "extracted" in std.out and "orbit axis" in std.out  # the result is not feedback
    assert json.loads((tmp_path / "quiet" / "report.json").read_text())["resolved"]["caps"] == {}


def test_max_view_pixels_sets_the_orbit_views_size(files, capsys):
    """Python API: the orbit views follow the cap; the default progress off a terminal says no stage lines."""
    syn, cam, seed = files["syn"], files["cam"], files["seed"]
    sizes = {}
    for cap in (1000, 2500):
        ex = extract(syn.scene, cam, seed, n_views=2, up="camera", orbit_scale=1.0, max_view_pixels=cap)
        shapes = {op.image_shape for op in ex.operators[1:]}  # view 0 is the reference view
        assert len(shapes) == 1
        (h, w), = shapes
        assert w * h <= cap + w + h and ex.resolved["caps"]["orbit_views"]["size"] == [w, h]
        sizes[cap] = w * h
    assert sizes[1000] < sizes[2500]
    assert not [ln for ln in capsys.readouterr().err.splitlines() if STAGE_LINE.match(ln)]


def test_cap_options_are_validated_and_belong_to_the_run(files, capsys, tmp_path):
    out = tmp_path / "never"
    assert _run(_extract_args(files, out, "--max-view-pixels", 10)) == 2
    assert "--max-view-pixels must be in 64..16,777,216, got 10" in capsys.readouterr().err
    assert _run(_extract_args(files, out, "--max-reference-pixels", 2 ** 30)) == 2
    assert "--max-reference-pixels must be in 64..67,108,864" in capsys.readouterr().err
    assert _run(["extract", "--from-report", tmp_path / "r.json", "-o", out, "--max-view-pixels", 5000]) == 2
    assert "cannot be combined with --max-view-pixels" in capsys.readouterr().err
    assert not out.exists()


def test_the_help_says_which_up_and_render_prints_it(files, capsys, tmp_path):
    for args, words in ((["extract", "--help"], ("orbit axis", "--look-up")),
                        (["render", "--help"], ("the camera's up", "Not an orbit axis"))):
        assert _run(args) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert all(w in text for w in words), (args, text)
    d = files["dir"]
    assert _run(["render", d / "scene.ply", "--look-at", "0,-1,-4", "0,0,0", "--up", "0,-2,0", "--size", "32x24",
                 "-o", tmp_path / "v.png"]) == 0
    # the up given, made perpendicular to the view direction: the image's up
    f = np.array([0.0, 1.0, 4.0]) / np.sqrt(17.0)
    up = np.array([0.0, -1.0, 0.0]) - (np.array([0.0, -1.0, 0.0]) @ f) * f
    up /= np.linalg.norm(up)
    assert f"camera's image up {','.join(f'{v:.3f}' for v in up)})" in capsys.readouterr().out


# -- the compile clock ----------------------------------------------------------------------------
def test_stage_timer_leaves_compile_time_out_of_the_stage(capsys):
    """A fake compile clock: what it counts during a block is the compile entry, not the stage's, and is
    said on its own line before the stage's line."""
    clock = {"t": 0.0}

    def compile_clock():
        return clock["t"]

    timer = StageTimer(("render", "lift"), compile_clock=compile_clock, feedback=Feedback("lines"))
    t0 = time.perf_counter()
    with timer("render"):
        time.sleep(0.05)  # "compiling": it took real time, as a compilation does
        clock["t"] += 0.05
    outer = time.perf_counter() - t0
    with timer("lift"):
        pass
    assert list(timer.seconds) == ["render", "lift", "compile"]
    assert timer.seconds["compile"] == 0.05
    assert 0.0 <= timer.seconds["render"] <= outer - 0.05
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("seed2gs: compiled the rasterizer kernels in 0.1 s") and "render" in err[0]
    assert STAGE_LINE.match(err[1]).groups()[0] == "render" and STAGE_LINE.match(err[2]).groups()[0] == "lift"
    assert len(err) == 3  # the lift compiled nothing: no compile line
    with pytest.raises(RuntimeError), timer("lift"):
        raise RuntimeError("a stage that fails says no line")
    assert capsys.readouterr().err == ""


def test_stage_timer_says_a_stage_of_several_blocks_once(capsys):
    timer = StageTimer(STAGES, feedback=Feedback("lines"))
    with timer("operators", last=False):
        pass
    with timer("vaas", last=False):
        pass
    assert capsys.readouterr().err == ""
    timer.move("vaas", "operators", 0.0)
    timer.finish("vaas")
    timer.finish("operators")
    names = [STAGE_LINE.match(ln).groups()[0] for ln in capsys.readouterr().err.splitlines()]
    assert names == ["vaas", "operators"] and "compile" not in timer.seconds  # no clock, no compile entry


def test_the_compile_clock_counts_a_compilation_once_in_its_own_thread():
    @njit(cache=False)
    def twice(x):
        return 2 * x

    before = compile_seconds()
    assert twice(3) == 6  # compiles now, in this thread
    compiled = compile_seconds() - before
    assert compiled > 0.0
    assert twice(4) == 8 and compile_seconds() - before == compiled  # compiled already: nothing more

    seen = []
    th = threading.Thread(target=lambda: seen.append(compile_seconds()))
    th.start()
    th.join()
    assert seen[0] == 0.0  # another thread's clock: this thread's compilation is not its


def test_feedback_modes_and_notices(capsys, monkeypatch):
    assert Feedback.of(True).mode == "bars" and Feedback.of(False).mode == "quiet"
    assert Feedback.of("lines").mode == "lines"
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False, raising=False)
    assert Feedback.of(None).mode == "notes"
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    assert Feedback.of(None).mode == "bars"
    for bad in ("quiet", 1, "yes"):
        with pytest.raises(ValidationError, match="progress must be None, True, False, 'bars' or 'lines'"):
            Feedback.of(bad)
    notice("said")  # no run in progress: said
    with Feedback("quiet").active():
        notice("not said")
        with Feedback("lines").active():
            notice("said again")
    assert capsys.readouterr().err == "seed2gs: said\nseed2gs: said again\n"


def test_a_stage_without_steps_shows_its_time(capsys, monkeypatch):
    monkeypatch.setattr(Progress, "DELAY", 0.0)
    monkeypatch.setattr(Progress, "TICK", 0.01)
    with Progress("render", True, steps=False):
        time.sleep(0.05)  # the ticker redraws meanwhile
    err = capsys.readouterr().err
    assert "render: 00:00" in err and "it/s" not in err


# -- the demo and the batch --------------------------------------------------------------------
def test_demo_off_a_terminal_says_its_stages(tmp_path):
    """stderr a pipe (another process): the demo's own stages and extract's, one line each."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "seed2gs_inverse", "demo", "--views", "3", "--size", "64", "48"]
    run = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    names = [m.group(1) for m in map(STAGE_LINE.match, run.stderr.splitlines()) if m]
    assert names == ["scene", "render", "grounding", "lift", "vaas", "operators", "tracking", "solve", "scoring"]
    quiet = subprocess.run(cmd + ["--quiet"], env=env, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert quiet.returncode == 0 and quiet.stderr == "" and "held-out views" in quiet.stdout


def _jobs_file(files, path) -> Path:
    d = files["dir"]
    path.write_text(f"""
[defaults]
scene = "{d}/scene.ply"
camera = "{d}/cameras.json:0"
options = {{ n_views = 3, up = "camera" }}
[[jobs]]
name = "sphere"
box = {files['box']}
[[jobs]]
name = "broken"
box = [900, 900, 950, 950]
""")
    return path


def test_batch_says_one_line_per_job_with_its_status(files, capsys, tmp_path):
    jobs = _jobs_file(files, tmp_path / "jobs.toml")
    assert _run(["batch", jobs, "-o", tmp_path / "res", "--sequential"]) == 1
    err = capsys.readouterr().err
    summary = {j["name"]: j for j in json.loads((tmp_path / "res" / "summary.json").read_text())["jobs"]}
    lines = [ln for ln in err.splitlines() if ln.startswith("seed2gs: [")]
    assert len(lines) == 2
    done = summary["sphere"]
    compiled = done["seconds"]["compile"]  # the job's, left out of its stages
    assert lines[0] == (f"seed2gs: [1/2] job sphere: done in {done['total_seconds']:.1f} s "
                        f"({done['n_selected']:,} of {done['n_gaussians']:,} Gaussians, {done['n_views']} views"
                        + (f"; {compiled:.1f} s compiling the kernels" if compiled > 0 else "") + ")")
    assert lines[1].startswith("seed2gs: [2/2] job broken: failed after ") and summary["broken"]["error"] in lines[1]
    # quiet: nothing while it runs; the failed job is still said at the end (an error)
    assert _run(["batch", jobs, "-o", tmp_path / "res2", "--sequential", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert err.splitlines() == [f"  broken: {summary['broken']['error']}"]
