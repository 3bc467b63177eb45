"""The optional parts (pip extras): declared as extras, and a command that misses one names its pip install.

A missing package is simulated with ``sys.modules[name] = None`` (``import name`` then raises
ImportError), so the tests run in the full test environment.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from seed2gs_inverse._extras import EXTRAS, MissingExtraError, install_command
from seed2gs_inverse.errors import Seed2GSError

ROOT = Path(__file__).resolve().parents[1]

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    tomllib = pytest.importorskip("tomli")


def _pip(extra):
    return re.escape(f'pip install "seed2gs-inverse[{extra}]"')


def _provides(requirements):
    """Import names a list of requirements brings: ``dask[distributed]`` -> {dask, distributed}."""
    out = set()
    for r in requirements:
        m = re.match(r"\s*([A-Za-z0-9_.-]+)(?:\[([^\]]*)\])?", r)
        out.add(m.group(1).lower())
        out.update(e.strip().lower() for e in (m.group(2) or "").split(",") if e.strip())
    return out


def test_the_extras_are_declared_and_the_core_does_not_pull_them_in():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    core = _provides(project["dependencies"])
    for extra, modules in EXTRAS.items():
        assert set(modules) <= _provides(extras[extra]), (extra, extras[extra])
        assert not set(modules) & core, f"the core install pulls in {set(modules) & core} of '{extra}'"
    assert {"pyvista", "vtk", "onnxruntime", "tokenizers", "dask", "distributed"}.isdisjoint(core)
    # 'all' brings every extra, and 'test' (the README's test command) brings 'all'
    assert extras["all"] == [f"seed2gs-inverse[{','.join(EXTRAS)}]"]
    assert "seed2gs-inverse[all]" in extras["test"]


def test_the_readme_quickstart_installs_the_test_extra():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert "pip install . && seed2gs demo" in lines
    assert 'pip install ".[test]" && python -m pytest -q' in lines


def test_install_command_and_the_error_type():
    assert install_command("view") == 'pip install "seed2gs-inverse[view]"'
    with pytest.raises(KeyError, match="view, models, batch"):
        install_command("viewer")
    assert issubclass(MissingExtraError, ImportError) and issubclass(MissingExtraError, Seed2GSError)


def test_view_without_pyvista(monkeypatch, tmp_path, capsys):
    from seed2gs_inverse import viz
    from seed2gs_inverse.cli import main

    monkeypatch.setitem(sys.modules, "pyvista", None)
    with pytest.raises(MissingExtraError, match=_pip("view")):
        viz.require_pyvista()
    # said before the scene is read: this one does not exist
    assert main(["view", str(tmp_path / "absent.ply"), "--screenshot", str(tmp_path / "v.png")]) == 2
    err = capsys.readouterr().err
    assert "seed2gs view: error:" in err and 'pip install "seed2gs-inverse[view]"' in err
    assert not (tmp_path / "v.png").exists()


def test_models_without_onnxruntime_or_tokenizers(monkeypatch, tmp_path):
    from seed2gs_inverse.frontend._onnx import OnnxModel
    from seed2gs_inverse.frontend.config import load_models
    from seed2gs_inverse.frontend.tokenizer import BertTokenizer

    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    monkeypatch.setitem(sys.modules, "tokenizers", None)
    (tmp_path / "m.onnx").write_bytes(b"not read")
    with pytest.raises(MissingExtraError, match=_pip("models")) as info:
        OnnxModel(tmp_path / "m.onnx", "the SAM2 image encoder", [])
    assert "the SAM2 image encoder" in str(info.value)
    (tmp_path / "models.toml").write_text('[onnxruntime]\nproviders = ["CPUExecutionProvider"]\n')
    with pytest.raises(MissingExtraError, match=_pip("models")):
        load_models(tmp_path / "models.toml")
    (tmp_path / "vocab.txt").write_text("[UNK]\n[CLS]\n[SEP]\nchair\n")
    with pytest.raises(MissingExtraError, match=_pip("models")):
        BertTokenizer.from_file(tmp_path / "vocab.txt")


def test_batch_workers_without_dask(monkeypatch, tmp_path, capsys):
    from seed2gs_inverse.cli import main

    monkeypatch.setitem(sys.modules, "distributed", None)
    (tmp_path / "jobs.toml").write_text(
        '[[jobs]]\nname = "a"\nscene = "s.ply"\ncamera = { eye = [0, 0, -3], target = [0, 0, 0], up = [0, -1, 0], '
        'fov = 50, width = 64, height = 48 }\nbox = [1, 1, 9, 9]\n')
    assert main(["batch", str(tmp_path / "jobs.toml"), "-o", str(tmp_path / "res"), "--workers", "2",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "seed2gs batch: error: running jobs on Dask workers needs the 'batch' extra" in err
    assert 'pip install "seed2gs-inverse[batch]"' in err
    assert not (tmp_path / "res").exists()  # nothing ran, nothing written
    np.testing.assert_equal(sorted(p.name for p in tmp_path.iterdir()), ["jobs.toml"])
