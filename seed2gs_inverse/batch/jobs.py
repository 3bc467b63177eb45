"""Batch jobs: what one extraction of a batch needs, and the ``jobs.toml`` file.

A job names a scene file, a reference camera, a prompt and the options of
:func:`~seed2gs_inverse.pipeline.extract`. A jobs file lists many of them;
its ``[defaults]`` table applies to every job and a job overrides any of it
(the ``options`` tables are merged key by key)::

    [defaults]
    scene = "scenes/patio.ply"                 # paths are relative to this file
    camera = "scenes/cameras.json:overview"    # FILE[:NAME|INDEX] ...
    # camera = { eye = [0, -2, -6], target = [0, 0, 0], up = [0, -1, 0],
    #            fov = 50, width = 960, height = 540 }   # ... or a look-at
    format = "ply"                             # object/remainder files: ply or splat
    figure = true                              # report.png, report_masks.png in each job folder
    # models = "models.toml"                   # ONNX models (text prompts, SAM2 tracking)

    [defaults.options]                         # extract() keywords
    n_views = 24
    method = "weighted_bce"

    [[jobs]]
    name = "fire-pit"                          # the job's folder under results/
    box = [415, 250, 535, 338]                 # x0 y0 x1 y1, pixels of the camera

    [[jobs]]
    name = "table"
    point = [[590, 320]]                       # clicks on the object ...
    negative = [[480, 300]]                    # ... and off it
    options = { n_views = 12 }

    [[jobs]]
    name = "chair"
    mask = "masks/chair.png"                   # seed mask at the camera's resolution

    [[jobs]]
    name = "red-chair"
    text = "red chair"                         # needs models

Every error names the file and the job. Jobs are plain data: they travel to
the workers of a cluster, which must see the same paths (a shared file
system), so relative paths are made absolute against the jobs file.

A Dask worker imports this module on its event loop, when it unpickles a
job; so :class:`~seed2gs_inverse.pipeline.ExtractSettings`, which imports the
pipeline, is imported where the options are checked, in the process that
builds the jobs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..camera import Camera
from ..errors import FormatError, ValidationError
from ..frontend.prompts import BoxPrompt, MaskPrompt, PointPrompt, TextPrompt
from ..io import read_camera
from ..io.cameras import split_camera_spec
from ..io.tables import read_small_file, read_table
from .summary import JOURNAL

__all__ = ["Job", "read_jobs", "jobs_from_table", "extract_option_names", "PROMPT_KEYS"]

#: Keys of a job that give its prompt (exactly one per job).
PROMPT_KEYS = ("mask", "box", "point", "text")
_JOB_KEYS = ("name", "scene", "camera", "options", "models", "format", "figure", "negative", *PROMPT_KEYS)
_LOOK_AT_KEYS = {"eye", "target", "up", "fov", "width", "height"}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")  # whole name: fullmatch, never "$"
_FORMATS = ("ply", "splat")
# extract() keywords a job may not set: the runner owns them.
_RESERVED = {"progress", "grounder", "tracker", "settings"}
# Names of the runner's own files in the results directory, which no job folder may take.
_RESERVED_NAMES = {"summary.json", "summary.csv", JOURNAL}


def extract_option_names() -> tuple:
    """Names that a job's ``options`` table may hold: the keyword options of ``extract()``.

    Taken from ``ExtractSettings``, so the list never goes stale;
    ``progress`` and the other keywords the runner sets are left out.
    """
    from ..pipeline.settings import ExtractSettings  # deferred: see the module docstring

    return tuple(n for n in ExtractSettings.names() if n not in _RESERVED)


def _check_options(options, where: str) -> dict:
    """The options as a dict, once their names and values are known to be ones ``extract()`` accepts."""
    if not isinstance(options, Mapping):
        raise ValidationError(f"{where}: 'options' must be a table of extract() keywords, "
                              f"got {type(options).__name__}")
    valid = extract_option_names()
    unknown = sorted(k for k in options if k not in valid)
    if unknown:
        raise ValidationError(f"{where}: unknown option(s) {', '.join(map(repr, unknown))}; "
                              f"valid options: {', '.join(valid)}")
    from ..pipeline.settings import ExtractSettings  # deferred: see the module docstring

    try:  # the values too, here, rather than on a worker after the cluster started
        ExtractSettings().replace(**options)
    except ValidationError as exc:
        raise ValidationError(f"{where}: options: {exc}") from None
    return dict(options)


def _prompt_spec(prompt) -> dict:
    """JSON-ready description of a prompt (for summaries and the job fingerprint)."""
    if isinstance(prompt, MaskPrompt):
        if isinstance(prompt.mask, (str, os.PathLike)):
            return {"kind": "mask", "mask": os.fspath(prompt.mask)}
        arr = np.ascontiguousarray(np.asarray(prompt.mask))
        digest = hashlib.sha256(arr.tobytes() + str((arr.shape, arr.dtype.str)).encode()).hexdigest()
        return {"kind": "mask", "mask": f"array{list(arr.shape)} sha256:{digest[:16]}"}
    if isinstance(prompt, BoxPrompt):
        return {"kind": "box", "box": [float(v) for v in np.asarray(prompt.box, float).ravel()]}
    if isinstance(prompt, PointPrompt):
        labels = [1] * len(prompt.points) if prompt.labels is None else [int(v) for v in prompt.labels]
        return {"kind": "point", "points": np.asarray(prompt.points, float).reshape(-1, 2).tolist(),
                "labels": labels}
    if isinstance(prompt, TextPrompt):
        return {"kind": "text", "text": prompt.text}
    raise ValidationError(f"prompt must be a MaskPrompt, BoxPrompt, PointPrompt or TextPrompt, "
                          f"got {type(prompt).__name__}")


def _camera_spec(camera):
    """JSON-ready description of a job's camera: a Camera's record, a look-at table, or the spec string."""
    if isinstance(camera, Camera):
        return {"camera": camera.to_dict()}
    if isinstance(camera, Mapping):
        return dict(camera)
    return os.fspath(camera)


@dataclass(frozen=True)
class Job:
    """One extraction of a batch.

    Parameters
    ----------
    name : str
        Unique within the batch; the name of the job's output folder
        (letters, digits, ``. _ -``; not starting with ``.`` or ``-``).
    scene : str or Path
        Scene file (any format :func:`~seed2gs_inverse.io.read_scene` reads).
    camera : str, Camera or mapping
        ``"FILE[:NAME|INDEX]"`` (:func:`~seed2gs_inverse.io.read_camera`), a
        :class:`~seed2gs_inverse.camera.Camera`, or a look-at
        ``{eye, target, up, fov, width, height}`` (``up`` defaults to
        ``[0, -1, 0]``, ``fov`` to 60 degrees, vertical).
    prompt : MaskPrompt, BoxPrompt, PointPrompt or TextPrompt
    options : mapping
        Keyword options of :func:`~seed2gs_inverse.pipeline.extract`
        (:func:`extract_option_names`).
    models : str, optional
        Models configuration (text prompts, SAM2 tracking); with it the
        job uses its grounder and tracker, as ``seed2gs extract --models`` does.
    format : {"ply", "splat"}
        Format of ``object`` / ``remainder`` in the job folder.
    figure : bool
        Write ``report.png`` and ``report_masks.png`` too.
    """

    name: str
    scene: str
    camera: Any
    prompt: Any
    options: Mapping = field(default_factory=dict)
    models: str | None = None
    format: str = "ply"
    figure: bool = True

    def __post_init__(self):
        if not isinstance(self.name, str) or not _NAME.fullmatch(self.name):
            raise ValidationError(
                f"job name {self.name!r} is not a valid folder name: use 1-128 letters, digits, "
                f"'.', '_' or '-', starting with a letter or digit")
        where = f"job {self.name!r}"
        if self.name.lower() in _RESERVED_NAMES:
            raise ValidationError(f"{where}: the name is taken by the batch's own {self.name.lower()}; "
                                  f"choose another")
        if not isinstance(self.scene, (str, os.PathLike)) or not os.fspath(self.scene):
            raise ValidationError(f"{where}: 'scene' must be a file path, got {self.scene!r}")
        # Paths become absolute here, against this process's directory: the job may run in a
        # worker started elsewhere (a shared file system has the same absolute paths).
        object.__setattr__(self, "scene", os.path.abspath(os.fspath(self.scene)))
        if not isinstance(self.camera, (str, os.PathLike, Camera, Mapping)):
            raise ValidationError(f"{where}: 'camera' must be 'FILE[:NAME]', a Camera or a look-at table, "
                                  f"got {type(self.camera).__name__}")
        if isinstance(self.camera, Mapping):
            _look_at(self.camera, where)  # validate now, not on the worker
        elif not isinstance(self.camera, Camera):
            object.__setattr__(self, "camera", _resolve_camera(Path.cwd(), os.fspath(self.camera)))
        _prompt_spec(self.prompt)
        if isinstance(self.prompt, MaskPrompt) and isinstance(self.prompt.mask, (str, os.PathLike)):
            object.__setattr__(self, "prompt", dataclasses.replace(
                self.prompt, mask=os.path.abspath(os.fspath(self.prompt.mask))))
        object.__setattr__(self, "options", _check_options(self.options, where))
        if self.format not in _FORMATS:
            raise ValidationError(f"{where}: format must be one of {', '.join(_FORMATS)}, got {self.format!r}")
        if not isinstance(self.figure, bool):
            raise ValidationError(f"{where}: figure must be true or false, got {self.figure!r}")
        if self.models is not None:
            object.__setattr__(self, "models", os.path.abspath(os.fspath(self.models)))
        elif isinstance(self.prompt, TextPrompt):
            raise ValidationError(f"{where}: a text prompt needs 'models' (a models configuration with a "
                                  f"grounder, see docs/models.md); or give a mask, box or point prompt")

    # -- what the worker needs ------------------------------------------------
    def extract_kwargs(self) -> dict:
        """Keyword arguments of ``extract()`` for this job: its options, no progress bars.

        The one place where a job's ``options`` become extract keywords.
        """
        return {**self.options, "progress": False}

    def read_camera(self) -> Camera:
        """The reference camera (reads the camera file or builds the look-at)."""
        if isinstance(self.camera, Camera):
            return self.camera
        if isinstance(self.camera, Mapping):
            return _look_at(self.camera, f"job {self.name!r}")
        return read_camera(self.camera)

    # -- bookkeeping ----------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready description (the summary's ``job`` entry)."""
        return {"name": self.name, "scene": self.scene, "camera": _camera_spec(self.camera),
                "prompt": _prompt_spec(self.prompt), "options": _jsonable(self.options),
                "models": self.models, "format": self.format, "figure": self.figure}

    def input_files(self) -> dict:
        """The files the job reads, by role: ``scene``, ``camera`` (unless the camera is
        given in full), ``mask`` (a mask prompt's image) and ``models``."""
        files = {"scene": self.scene}
        if isinstance(self.camera, str):
            files["camera"] = _camera_file(self.camera)
        if isinstance(self.prompt, MaskPrompt) and isinstance(self.prompt.mask, (str, os.PathLike)):
            files["mask"] = os.fspath(self.prompt.mask)
        if self.models is not None:
            files["models"] = self.models
        return files

    def fingerprint(self) -> str:
        """SHA-256 of :meth:`to_dict`, the size and modification time of each of
        :meth:`input_files` and the models file's content: resume re-runs a job whose
        description changed, whose input files were replaced, or whose models configuration
        was edited in place."""
        d = self.to_dict()
        d["inputs"] = {role: _stamp(f) for role, f in self.input_files().items() if role != "models"}
        if self.models is not None:
            try:  # bounded: never blocks on a pipe or reads a device without end
                d["models_sha256"] = hashlib.sha256(read_small_file(self.models, "models configuration")).hexdigest()
            except (OSError, FormatError):
                d["models_sha256"] = None  # the job fails on it and is re-run next time
        text = json.dumps(d, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _stamp(path: str):
    """``[size, mtime_ns]`` of a file, None when it cannot be read (the job fails on it and runs again)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_size, st.st_mtime_ns]


def _camera_file(spec: str) -> str:
    """The file of a camera spec ``FILE[:NAME|INDEX]`` (the rule of ``read_camera``)."""
    return split_camera_spec(spec)[0]


def _jsonable(value):
    """``value`` with mappings, sequences and numpy values made JSON types (recursively)."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _vector(where, key, value, n=3) -> np.ndarray:
    """(n,) float64 of a look-at camera's ``key``; ValidationError unless ``n`` finite numbers."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ValidationError(f"{where}: camera '{key}' must be {n} finite numbers, got {value!r}")
    return arr


def _look_at(spec: Mapping, where: str) -> Camera:
    """The camera of a look-at table ``{eye, target, up, fov, width, height}``, checked key by key."""
    unknown = sorted(set(spec) - _LOOK_AT_KEYS)
    if unknown:
        raise ValidationError(f"{where}: unknown look-at camera key(s) {unknown}; "
                              f"use {', '.join(sorted(_LOOK_AT_KEYS))}")
    missing = [k for k in ("eye", "target", "width", "height") if k not in spec]
    if missing:
        raise ValidationError(f"{where}: look-at camera needs {', '.join(missing)}")
    size = []
    for key in ("width", "height"):
        v = spec[key]
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 0 < int(v) <= 16384:
            raise ValidationError(f"{where}: camera '{key}' must be a whole number in 1..16384, got {v!r}")
        size.append(int(v))
    fov = spec.get("fov", 60.0)
    if isinstance(fov, bool) or not isinstance(fov, (int, float)) or not 0 < float(fov) < 180:
        raise ValidationError(f"{where}: camera 'fov' must be in (0, 180) degrees, got {fov!r}")
    eye = _vector(where, "eye", spec["eye"])
    target = _vector(where, "target", spec["target"])
    up = _vector(where, "up", spec.get("up", (0.0, -1.0, 0.0)))
    try:
        return Camera.look_at(eye, target, up, float(fov), size[0], size[1], name="look-at")
    except ValidationError as exc:
        raise ValidationError(f"{where}: {exc}") from None


# ---------------------------------------------------------------------------
# jobs.toml
# ---------------------------------------------------------------------------
def _resolve(base: Path, value: str) -> str:
    """``value`` (``~`` expanded) as an absolute path, relative ones taken against ``base``."""
    p = Path(os.path.expanduser(value))
    return os.fspath(p if p.is_absolute() else (base / p).resolve())


def _resolve_camera(base: Path, value: str) -> str:
    """Absolute camera spec; the ``:NAME`` selector stays as given (split as ``read_camera`` splits it)."""
    path, selector = split_camera_spec(value, lambda s: os.path.exists(_resolve(base, s)))
    return _resolve(base, path) if selector is None else f"{_resolve(base, path)}:{selector}"


def _prompt_from_table(t: Mapping, where: str, base: Path):
    """The one prompt of a job table (``mask``, ``box``, ``point`` with ``negative``, or ``text``)."""
    given = [k for k in PROMPT_KEYS if k in t]
    if len(given) != 1:
        raise ValidationError(f"{where}: give exactly one prompt ({', '.join(PROMPT_KEYS)}), "
                              f"got {', '.join(given) if given else 'none'}")
    key = given[0]
    value = t[key]
    if "negative" in t and key != "point":
        raise ValidationError(f"{where}: 'negative' clicks go with a 'point' prompt")
    if key == "mask":
        if not isinstance(value, str) or not value:
            raise ValidationError(f"{where}: 'mask' must be an image file path")
        return MaskPrompt(_resolve(base, value))
    if key == "text":
        if not isinstance(value, str) or not value.strip():
            raise ValidationError(f"{where}: 'text' must be a non-empty string")
        return TextPrompt(value)
    if key == "box":
        box = _numbers(where, "box", value)
        if box.shape != (4,):
            raise ValidationError(f"{where}: 'box' must be [x0, y0, x1, y1], got {value!r}")
        return BoxPrompt(box.tolist())
    pos = _clicks(where, "point", value)
    neg = _clicks(where, "negative", t.get("negative", []))
    if len(pos) == 0:
        raise ValidationError(f"{where}: 'point' needs at least one click [x, y], got {value!r}")
    return PointPrompt(np.concatenate([pos, neg]).tolist(), [1] * len(pos) + [0] * len(neg))


def _clicks(where, key, value) -> np.ndarray:
    """(K, 2) clicks from ``[x, y]`` or ``[[x, y], ...]`` (K may be 0), the message naming ``key``."""
    arr = _numbers(where, key, value, flat=False)
    if arr.ndim == 1 and arr.size == 2:
        arr = arr[None]
    if arr.size == 0:
        return arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValidationError(f"{where}: '{key}' must be [x, y] or [[x, y], ...], got {value!r}")
    return arr


def _numbers(where, key, value, flat: bool = True) -> np.ndarray:
    """float64 array of a regular list of finite numbers (raveled when ``flat``)."""
    try:
        arr = np.asarray(value, dtype=np.float64)  # a ragged list is a ValueError too
    except (TypeError, ValueError):
        raise ValidationError(f"{where}: '{key}' must hold numbers in a regular list, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ValidationError(f"{where}: '{key}' must hold finite numbers, got {value!r}")
    return arr.ravel() if flat else arr


def jobs_from_table(table: Mapping, base=".", source: str = "jobs") -> list[Job]:
    """Jobs from a parsed jobs table (the layout of the module docstring).

    Parameters
    ----------
    table : mapping
        ``{"defaults": {...}, "jobs": [{...}, ...]}``.
    base : path
        Directory that relative paths are relative to.
    source : str
        Name used in error messages (the file).

    Returns
    -------
    list of Job
        In the order of ``jobs``.

    Raises
    ------
    FormatError
        The table's layout is wrong (unknown keys, no jobs, repeated names).
    ValidationError
        A job's values are wrong (the message names the file and the job).
    """
    base = Path(base)
    if not isinstance(table, Mapping):
        raise FormatError(f"{source}: expected a table with [defaults] and [[jobs]]")
    extra = sorted(set(table) - {"defaults", "jobs"})
    if extra:
        raise FormatError(f"{source}: unknown top-level key(s) {extra}; use [defaults] and [[jobs]]")
    defaults = table.get("defaults", {})
    if not isinstance(defaults, Mapping):
        raise FormatError(f"{source}: [defaults] must be a table")
    entries = table.get("jobs")
    if not isinstance(entries, list) or not entries:
        raise FormatError(f"{source}: no jobs; add [[jobs]] tables")
    for key in defaults:
        if key not in _JOB_KEYS or key == "name":
            raise FormatError(f"{source}: unknown key {key!r} in [defaults]; known keys: "
                              f"{', '.join(k for k in _JOB_KEYS if k != 'name')}")
    jobs, seen = [], {}
    for i, entry in enumerate(entries):
        if not isinstance(entry, Mapping):
            raise FormatError(f"{source}: jobs[{i}] must be a table")
        name = entry.get("name", f"job-{i:03d}")
        where = f"{source}: job {name!r} (jobs[{i}])"
        unknown = sorted(set(entry) - set(_JOB_KEYS))
        if unknown:
            raise FormatError(f"{where}: unknown key(s) {unknown}; known keys: {', '.join(_JOB_KEYS)}")
        if not isinstance(name, str):
            raise FormatError(f"{where}: 'name' must be a string")
        if name.casefold() in seen:  # folder names: one folder on a case-insensitive file system
            raise FormatError(f"{where}: the name is also used by jobs[{seen[name.casefold()]}]; names must be "
                              f"unique, also ignoring case")
        seen[name.casefold()] = i
        # A job's own prompt replaces the default one; options merge key by key.
        merged = {k: v for k, v in defaults.items()
                  if not (k in PROMPT_KEYS + ("negative",) and any(p in entry for p in PROMPT_KEYS))}
        merged.update(entry)
        if not all(isinstance(t.get("options", {}), Mapping) for t in (defaults, entry)):
            raise FormatError(f"{where}: 'options' must be a table of extract() keywords")
        opts = {**defaults.get("options", {}), **entry.get("options", {})}
        for key in ("scene", "camera"):
            if key not in merged:
                raise FormatError(f"{where}: no '{key}' (give it in the job or in [defaults])")
        try:
            if not isinstance(merged["scene"], str):
                raise ValidationError(f"{where}: 'scene' must be a file path string")
            camera = merged["camera"]
            if isinstance(camera, str):
                camera = _resolve_camera(base, camera)
            elif not isinstance(camera, Mapping):
                raise ValidationError(f"{where}: 'camera' must be 'FILE[:NAME]' or a look-at table")
            prompt = _prompt_from_table(merged, where, base)
            models = merged.get("models")
            if models is not None and not isinstance(models, str):
                raise ValidationError(f"{where}: 'models' must be a file path string")
            if models is not None and os.path.exists(_resolve(base, models)) \
                    and not os.path.isfile(_resolve(base, models)):
                raise ValidationError(f"{where}: models file {_resolve(base, models)} is not a regular file (a "
                                      f"directory, pipe or device); name the models configuration itself")
            if models is not None and not os.path.isfile(_resolve(base, models)):
                # checked here, once, rather than failing every job on a worker
                raise ValidationError(f"{where}: models file {_resolve(base, models)} not found "
                                      f"(a TOML or JSON models configuration, see docs/models.md)")
            jobs.append(Job(name=name, scene=_resolve(base, merged["scene"]), camera=camera, prompt=prompt,
                            options=opts,  # checked by Job (its messages are re-headed below)
                            models=None if models is None else _resolve(base, models),
                            format=merged.get("format", "ply"), figure=merged.get("figure", True)))
        except ValidationError as exc:
            msg = str(exc)
            if not msg.startswith(source):  # Job's own messages start with "job 'name': "
                own = f"job {name!r}: "
                msg = f"{where}: {msg[len(own):] if msg.startswith(own) else msg}"
            raise ValidationError(msg) from None
    return jobs


def read_jobs(path) -> list[Job]:
    """Read a ``jobs.toml`` (or ``.json`` with the same layout) file; see the module docstring.

    Raises
    ------
    FormatError, ValidationError
        As :func:`jobs_from_table`, or a file that cannot be read or parsed.
    """
    p = Path(path)
    table = read_table(p, "jobs file")
    return jobs_from_table(table, base=p.resolve().parent, source=os.fspath(p))
