"""``seed2gs info`` and ``seed2gs convert``."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import plyfile
import pytest

import seed2gs_inverse.cli as cli
from _io_encoders import random_scene, standard_columns
from seed2gs_inverse.errors import FormatError
from seed2gs_inverse.io import read_scene, write_scene


@pytest.fixture(autouse=True)
def only_scene_commands(monkeypatch):
    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_scene",))


def run(argv, capsys):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_info_scene(tmp_path, rng, capsys):
    scene = random_scene(rng, n=25, degree=2, extra={"tag": np.arange(25, dtype=np.int32)})
    path = tmp_path / "s.ply"
    write_scene(path, scene)
    code, out, err = run(["info", path], capsys)
    assert code == 0 and err == ""
    assert "format:      ply" in out
    assert "gaussians:   25" in out
    assert "sh degree:   2" in out
    lo, hi = scene.bounds()
    assert f"bounds x:    [{lo[0]:.4g}, {hi[0]:.4g}]" in out
    assert "extra:       tag (int32)" in out


def test_info_cameras(tmp_path, capsys):
    entry = {"id": 0, "img_name": "front", "width": 64, "height": 48, "position": [1, 2, 3],
             "rotation": np.eye(3).tolist(), "fx": 50, "fy": 50}
    path = tmp_path / "cams.json"
    path.write_text(json.dumps([entry]))
    code, out, _ = run(["info", path], capsys)
    assert code == 0
    assert "cameras:     1" in out and "front" in out and "64x48" in out and "centre=(1, 2, 3)" in out


def test_convert_round_trip(tmp_path, rng, capsys):
    scene = random_scene(rng, n=30, degree=1)
    src = tmp_path / "in.ply"
    write_scene(src, scene)
    code, out, err = run(["convert", src, tmp_path / "out.splat"], capsys)
    assert code == 0
    assert "wrote" in out and "30 Gaussians" in out
    assert "warning:" in err and "SH bands 1-1" in err
    code, _, _ = run(["convert", tmp_path / "out.splat", tmp_path / "back.ply"], capsys)
    assert code == 0
    back = read_scene(tmp_path / "back.ply")
    np.testing.assert_array_equal(back.means, scene.means)


def test_convert_keeps_a_replaced_files_mode_and_refuses_its_own_input(tmp_path, rng, capsys):
    """--force made a read-only file writable (0444 -> 0644), and OUT could be IN itself."""
    scene = random_scene(rng, n=30, degree=1)
    src, out = tmp_path / "in.ply", tmp_path / "out.ply"
    write_scene(src, scene)
    write_scene(out, scene)
    os.chmod(out, 0o444)
    code, _, _ = run(["convert", src, out, "--force"], capsys)
    assert code == 0 and stat.S_IMODE(os.stat(out).st_mode) == 0o444
    before = src.read_bytes()
    code, _, err = run(["convert", src, src, "--force"], capsys)
    assert code == 2 and "is the input file" in err and src.read_bytes() == before


def test_convert_drop_nonfinite(tmp_path, rng, capsys):
    scene = random_scene(rng, n=5)
    cols = dict(standard_columns(scene))
    cols["opacity"] = cols["opacity"].copy()
    cols["opacity"][2] = np.nan
    rec = np.empty(5, dtype=[(n, "f4") for n in cols])
    for n, vals in cols.items():
        rec[n] = vals
    src = tmp_path / "nan.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(src))
    code, _, err = run(["convert", src, tmp_path / "o.ply"], capsys)
    assert code == 2 and "1 of 5 Gaussians" in err and "--drop-nonfinite" in err
    assert not (tmp_path / "o.ply").exists()
    code, _, err = run(["convert", "--drop-nonfinite", src, tmp_path / "o.ply"], capsys)
    assert code == 0 and "dropped 1 of 5" in err
    assert len(read_scene(tmp_path / "o.ply")) == 4


def test_errors_are_one_line_and_leave_no_output(tmp_path, rng, capsys):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nend_header\n1\n")
    code, out, err = run(["info", bad], capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("seed2gs info: error:") and "bad.ply" in err
    assert "Traceback" not in err
    code, _, err = run(["convert", bad, tmp_path / "out.ply"], capsys)
    assert code == 2 and err.startswith("seed2gs convert: error:")
    code, _, err = run(["convert", tmp_path / "missing.ply", tmp_path / "out.ply"], capsys)
    assert code == 2 and "no such file" in err
    good = tmp_path / "good.ply"
    write_scene(good, random_scene(rng, n=3))
    code, _, err = run(["convert", good, tmp_path / "out.spz"], capsys)
    assert code == 2 and "not supported" in err
    code, _, err = run(["convert", good, tmp_path / "nodir" / "out.ply"], capsys)
    assert code == 2 and "does not exist" in err and ".tmp" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.ply", "good.ply"]
    with pytest.raises(FormatError):
        cli.main(["--debug", "info", str(bad)])


@pytest.mark.parametrize("command", ["info", "convert"])
def test_help(command, capsys):
    # main() returns the status of --help (and of usage errors) instead of raising SystemExit
    assert cli.main([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert "usage: seed2gs " + command in out and "--drop-nonfinite" in out


def test_convert_removes_and_reports_stale_temps(tmp_path, rng, capsys):
    # what a SIGKILL during an earlier `seed2gs convert` into the same place leaves behind
    import subprocess
    import sys

    from seed2gs_inverse import _atomic

    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()  # a process id that no longer exists
    stale = tmp_path / f".o.ply.{_atomic._HOST}-{child.pid}-abcd1234.tmp.ply"
    stale.write_bytes(b"partial output")
    src = tmp_path / "s.ply"
    write_scene(src, random_scene(rng, n=5))
    code, _, err = run(["convert", src, tmp_path / "o.ply"], capsys)
    assert code == 0, err
    assert "seed2gs convert: warning: removed 1 stale temporary entry" in err and stale.name in err
    assert not stale.exists() and len(read_scene(tmp_path / "o.ply")) == 5
