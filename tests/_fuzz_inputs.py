"""Generated configuration, jobs and report files for the fuzz tests and ``benchmarks/bench_fuzz.py``.

Each reader gets a valid document (:func:`make_case`) that generated edits
break in every way a hand edit or an attacker could: values replaced by
values of any JSON type (hostile strings, huge and non-finite numbers, deep
lists), keys deleted or added; the result is written as JSON or TOML. Raw
bytes (:func:`write_bytes`) exercise the parsers themselves.

:func:`outcome` runs one reader on one file and classifies what happened:
``"ok"``, ``"own"`` (a :class:`~seed2gs_inverse.errors.Seed2GSError`) or
``"foreign"`` (anything else: a defect).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import traceback
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

from hypothesis import strategies as st

from seed2gs_inverse.batch.jobs import read_jobs
from seed2gs_inverse.camera import Camera
from seed2gs_inverse.cli._extract import _from_report
from seed2gs_inverse.errors import Seed2GSError
from seed2gs_inverse.frontend.config import load_models, resolve_models

READERS = ("models", "jobs", "report")

HOSTILE_STRINGS = ["/dev/zero", "/", ".", "..", "", "a\x00b", "job\n", "exe", "ply", "splat", "mask", "box",
                   "point", "text", "sam2", "sam3", "vlm", "e.onnx", "scene.ply", "cameras.json:0",
                   "cameras.json:9", "~", "nan", "\udcff", "x" * 300]
KEYS = ["name", "scene", "camera", "options", "models", "format", "figure", "negative", "mask", "box", "point",
        "text", "path", "sha256", "fingerprint", "spec", "kind", "labels", "points", "iterations", "radius",
        "n_views", "method", "solver_options", "encoder", "decoder", "weights", "sources", "mask_model",
        "providers", "boxes", "coords", "eye", "target", "up", "fov", "width", "height", "run", "settings",
        "resolved", "jobs", "defaults", "sam2", "selector", "external", "onnxruntime", "up_cameras"]

scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(-10, 10), st.integers(), st.sampled_from([2 ** 31, 2 ** 63, -2 ** 63, 10 ** 40, 10 ** 400]),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 1e308, 0.5, 1.0]),
    st.text(max_size=12), st.sampled_from(HOSTILE_STRINGS),
)
keys = st.one_of(st.sampled_from(KEYS), st.text(max_size=8))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                       st.dictionaries(keys, inner, max_size=5)),
                      max_leaves=20)


class Deep:
    """Stands for ``depth`` nested lists until :func:`apply_edits` (so that its repr stays short)."""

    def __init__(self, depth: int):
        self.depth = depth

    def __repr__(self) -> str:
        return f"Deep({self.depth})"

    def expand(self):
        return json.loads("[" * self.depth + "]" * self.depth)


# deep nesting, which recursive parsers and validators must survive
deep = st.integers(1, 900).map(Deep)

edit = st.tuples(st.sampled_from(["replace", "replace", "delete", "add"]), st.integers(0, 10 ** 6),
                 keys, st.one_of(values, deep))
edits = st.lists(edit, min_size=1, max_size=4)
syntax = st.sampled_from(["json", "toml"])


def _slots(doc):
    """Every (container, key) inside ``doc``."""
    out, todo = [], [doc]
    while todo:
        node = todo.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for k, v in items:
            out.append((node, k))
            todo.append(v)
    return out


def apply_edits(doc, changes):
    """``doc`` (deep-copied) with the generated ``changes`` applied."""
    doc = copy.deepcopy(doc)
    for op, where, key, value in changes:
        if isinstance(value, Deep):
            value = value.expand()
        slots = _slots(doc)
        containers = [doc] + [c[k] for c, k in slots if isinstance(c[k], (dict, list))]
        if op == "add" or not slots:
            target = containers[where % len(containers)]
            if isinstance(target, dict):
                target[key] = value
            else:
                target.append(value)
            continue
        c, k = slots[where % len(slots)]
        if op == "delete":
            del c[k]
        else:
            c[k] = value
    return doc


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v if x is not None) + "]"
    return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml_value(x)}" for k, x in v.items() if x is not None) + "}"


def to_toml(doc: dict) -> str:
    """``doc`` as TOML, one ``key = inline value`` line per top-level key (None values are left out)."""
    return "".join(f"{json.dumps(str(k))} = {_toml_value(v)}\n" for k, v in doc.items() if v is not None)


def write_doc(folder: Path, doc, kind: str) -> Path:
    """``doc`` written as ``input.json`` or ``input.toml`` in ``folder`` (its text, whatever the doc)."""
    path = folder / f"input.{kind}"
    try:
        text = json.dumps(doc) if kind == "json" or not isinstance(doc, dict) else to_toml(doc)
        data = text.encode("utf-8", "surrogatepass")
    except (RecursionError, ValueError):
        data = b"[" * 5000
    path.write_bytes(data)
    return path


def write_bytes(folder: Path, blob: bytes, kind: str) -> Path:
    path = folder / f"input.{kind}"
    path.write_bytes(blob)
    return path


def make_case(folder: Path) -> dict:
    """The files a valid document refers to, in ``folder``, and one valid document per reader."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("scene.ply", "e.onnx", "d.onnx", "boxes.json", "models.toml"):
        (folder / name).write_bytes(b"")
    (folder / "mask.png").write_bytes(b"\x89PNG")
    cam = Camera.look_at([0, 0, -4], [0, 0, 0], [0, -1, 0], 50.0, 64, 48)
    (folder / "cameras.json").write_text(json.dumps([{
        "id": 0, "img_name": "c0", "width": 64, "height": 48, "position": [0, 0, -4],
        "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "fx": 50, "fy": 50}]))
    look = {"eye": [0, 0, -4], "target": [0, 0, 0], "up": [0, -1, 0], "fov": 50, "width": 64, "height": 48}
    jobs = {"defaults": {"scene": "scene.ply", "camera": look, "format": "ply", "figure": False,
                         "options": {"n_views": 4, "method": "weighted_bce"}},
            "jobs": [{"name": "a", "box": [1, 2, 30, 40]},
                     {"name": "b", "point": [[5, 6]], "negative": [[7, 8]], "options": {"n_views": 6}},
                     {"name": "c", "mask": "mask.png", "camera": "cameras.json:0"},
                     {"name": "d", "text": "red chair", "models": "models.toml"}]}
    models = {"sam2": {"encoder": "e.onnx", "decoder": "d.onnx", "mask_threshold": 0.0},
              "groundingdino": {"model": "e.onnx", "tokenizer": "boxes.json", "box_threshold": 0.3},
              "external": {"boxes": "boxes.json", "coords": "pixels"},
              "selector": {"weights": {"source": 0.25, "confidence": 0.5, "language": 0.25},
                           "sources": ["vlm"], "mask_model": "sam2"}}
    mask_sha = hashlib.sha256((folder / "mask.png").read_bytes()).hexdigest()
    report = {"run": {"scene": {"path": str(folder / "scene.ply"), "sha256": None, "fingerprint": "f" * 16},
                      "camera": {"spec": "cameras.json:0", "camera": json.loads(json.dumps(cam.to_dict()))},
                      "prompt": {"kind": "mask", "path": str(folder / "mask.png"), "sha256": mask_sha},
                      "models": None, "format": "ply", "up_cameras": {"path": str(folder / "cameras.json")}},
              "settings": {"n_views": 3, "method": "weighted_bce", "solver_options": {}},
              "resolved": {"solver_options": {"max_iter": 20}}}
    return {"models": models, "jobs": jobs, "report": report}


def _read_report(path):
    args = SimpleNamespace(from_report=str(path), scene=None, models=None, format=None, no_progress=True)
    scene, camera, spec, prompt, settings, models, fmt, run = _from_report(args)
    if models is not None:
        resolve_models(models)


READ = {"models": load_models, "jobs": read_jobs, "report": _read_report}


def outcome(reader: str, path: Path, memory_limit: int | None = None) -> tuple[str, str | None]:
    """(``"ok"`` | ``"own"`` | ``"foreign"``, the foreign exception's traceback) of reading ``path``.

    With ``memory_limit`` (bytes), a read whose peak traced memory exceeds
    it is ``"foreign"`` too.
    """
    if memory_limit is not None:
        tracemalloc.start()
    try:
        READ[reader](path)
        result = ("ok", None)
    except Seed2GSError:
        result = ("own", None)
    except Exception:  # noqa: BLE001 - anything else is what the fuzzing looks for
        result = ("foreign", traceback.format_exc())
    finally:
        if memory_limit is not None:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    if memory_limit is not None and peak > memory_limit:
        result = ("foreign", f"peak traced memory {peak} bytes > {memory_limit} reading {os.fspath(path)}")
    return result
