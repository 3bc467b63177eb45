"""Declared dependencies match what the package imports (issue 12, item 16)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    tomllib = pytest.importorskip("tomli")


def _project():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _names(requirements):
    import re

    return {re.split(r"[<>=!~;\[ ]", r, maxsplit=1)[0].strip().lower(): r for r in requirements}


def _imported_top_level_modules():
    found = {}
    for path in (ROOT / "seed2gs_inverse").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                mods = [node.module]
            else:
                continue
            for m in mods:
                found.setdefault(m.split(".")[0], path.relative_to(ROOT))
    return found


def test_plyfile_is_a_test_dependency_only():
    project = _project()
    assert "plyfile" not in _names(project["dependencies"])
    assert "plyfile" in _names(project["optional-dependencies"]["test"])
    imported = _imported_top_level_modules()
    assert "plyfile" not in imported, f"{imported.get('plyfile')} imports plyfile"


def test_tomli_declared_for_python_310():
    imported = _imported_top_level_modules()
    assert "tomli" in imported  # the TOML fallback of frontend/config.py
    req = _names(_project()["dependencies"]).get("tomli")
    assert req is not None, "tomli is imported on Python 3.10 but not declared"
    marker = req.split(";", 1)[1].replace(" ", "").replace('"', "'")
    assert marker == "python_version<'3.11'"
