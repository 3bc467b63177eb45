"""Options and messages that say the same thing the same way across commands."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

import seed2gs_inverse.cli as cli
from seed2gs_inverse.io import write_cameras, write_scene
from seed2gs_inverse.operators import OperatorStack
from seed2gs_inverse.synthetic import make_scene

REPO = Path(__file__).resolve().parents[1]


def _run(args, capsys):
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_operators_build_takes_force_and_still_the_deprecated_overwrite(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_operators",))
    syn = make_scene(seed=0)
    write_scene(tmp_path / "scene.ply", syn.scene)
    write_cameras(tmp_path / "cameras.json", [syn.reference_camera(32, 24)])
    base = ["operators", "build", tmp_path / "scene.ply", "--cameras", tmp_path / "cameras.json",
            "-o", tmp_path / "ops", "--no-progress"]
    assert _run(base, capsys)[0] == 0
    code, _, err = _run(base, capsys)
    assert code == 2 and "--force" in err and "--overwrite" not in err
    code, _, err = _run(base + ["--force"], capsys)
    assert code == 0 and "deprecated" not in err
    code, _, err = _run(base + ["--overwrite"], capsys)
    assert code == 0, err
    assert "'--overwrite' is deprecated; write --force" in err
    assert len(OperatorStack.load(tmp_path / "ops")) == 1
    code, helptext, _ = _run(["operators", "build", "--help"], capsys)
    assert code == 0
    assert "--force" in helptext and "--overwrite" not in helptext


def test_demo_summary_prints_bounds_rounded(capsys, monkeypatch):
    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_demo",))
    code, out, _ = _run(["demo", "--summary"], capsys)
    assert code == 0
    line = next(s for s in out.splitlines() if s.startswith("bounds:"))
    printed = [float(v) for v in re.findall(r"-?\d+\.\d+", line)]
    assert all(len(v.split(".")[1]) == 3 for v in re.findall(r"-?\d+\.\d+", line)), line
    means = np.asarray(make_scene(seed=0).scene.means, np.float64)
    np.testing.assert_allclose(printed, np.concatenate([means.min(0), means.max(0)]), atol=5e-4 + 1e-9)


def test_every_test_using_the_real_scenes_is_marked_shared_data(tmp_path):
    """``-m shared_data`` selects the tests that take the fixture, marked by hand or not."""
    probe = tmp_path / "test_probe.py"
    probe.write_text("import pytest\n\n"
                     "def test_reads(shared_data):\n    pass\n\n"
                     "@pytest.mark.shared_data\ndef test_marked(shared_data):\n    pass\n\n"
                     "@pytest.fixture\ndef firepit(shared_data):\n    return shared_data\n\n"
                     "def test_through_a_fixture(firepit):\n    pass\n\n"
                     "def test_own_data(tmp_path):\n    pass\n")
    (tmp_path / "conftest.py").write_text((REPO / "tests" / "conftest.py").read_text())
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    argv = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "-m", "shared_data",
            "-c", os.devnull, "-o", "markers=shared_data: real scenes", "--rootdir", str(tmp_path), str(probe)]
    proc = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    selected = sorted(line.split("::")[1] for line in proc.stdout.splitlines() if "::" in line)
    assert selected == ["test_marked", "test_reads", "test_through_a_fixture"], proc.stdout + proc.stderr
