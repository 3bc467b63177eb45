"""LERF-Mask evaluation (Gaussian Grouping protocol) in one call.

Dataset layout (as distributed by Gaussian Grouping)::

    DATA_DIR/<scene>/test_mask/<frame>/<query>.png   ground truth, non-zero = object
    DATA_DIR/<scene>/sparse/0/...                     COLMAP model (or cameras.json)
    DATA_DIR/<scene>/images_train/                    optional: the training images

and one trained 3DGS scene per scene, supplied by the user, found in
``SCENE_DIR`` as ``<scene>.ply``, ``<scene>/point_cloud.ply`` or the 3DGS
trainer's ``<scene>/point_cloud/iteration_<N>/point_cloud.ply`` (highest N).
Cameras come from ``DATA_DIR/<scene>`` (COLMAP model or ``cameras.json``), else
from ``SCENE_DIR/<scene>/cameras.json``.

A ``<frame>`` folder is matched to a camera by name (with or without the
image extension); an integer name ``k`` is the k-th *test* camera of the
3DGS split (cameras sorted by image name; the test cameras are those not in
``images_train`` when that folder exists, else every 8th camera, LLFF hold-out).
Each frame's camera is rescaled to the size of its ground-truth masks.

Protocol: every query is extracted once. With ``oracle_seed`` (the paper's
"fixed GT-oracle seed") the reference is the first test frame that has the
query's mask and the seed is that mask. With text (``models``) the query
text, the mask file's stem, is grounded in the first test frame, whatever
its masks, as Gaussian Grouping's ``render_lerf_mask.py`` grounds every
prompt in the first test view (choosing the frame by its ground truth would
hand the grounder a hint). The object is then rendered into every test view with the *full* scene, so
occlusions count: the predicted mask is ``W(c) s > 0.5`` with ``s`` the 0/1
selection (the share of each pixel's colour that the object contributes).
Ground truth is read as Gaussian Grouping's evaluator does (grey level after
``PIL convert("L")`` above 128), IoU and boundary IoU come from
:mod:`seed2gs_inverse.metrics`, and the means follow
:func:`~seed2gs_inverse.metrics.protocol_mean` (views -> query -> scene ->
overall). ``miou_heldout`` additionally leaves out the seed frame.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import FormatError, ValidationError
from ..io._common import warn_caller

__all__ = ["LerfScene", "read_lerf_mask", "read_gt_mask", "lerf_jobs", "evaluate_lerf_mask", "evaluate_scenes",
           "score_frame", "check_models"]

_LLFF_HOLD = 8
_IMAGE_EXT = (".png", ".jpg", ".jpeg", ".JPG", ".JPEG", ".PNG")


@dataclass
class LerfScene:
    """One scene of the dataset: its frames, queries, cameras and scene file.

    Attributes
    ----------
    name : str
    scene_file : Path
    frames : list of str
        Test frame folder names, in natural order (``2`` before ``10``).
    queries : list of str
        Every query (mask file stem) of any frame, sorted.
    cameras : dict frame -> Camera
        At the resolution of the frame's ground-truth masks.
    gt : dict (frame, query) -> Path
    gt_threshold : int
        A ground-truth pixel is object where its grey level exceeds this
        (128 for LERF-Mask; 254 for 3D-OVS, whose loader keeps only 255).
    """

    name: str
    scene_file: Path
    frames: list
    queries: list
    cameras: dict
    gt: dict = field(default_factory=dict)
    gt_threshold: int = 128
    _seeds: dict = field(default_factory=dict, repr=False, compare=False)

    def seed_frame(self, query: str) -> str:
        """The first frame whose ground-truth mask of ``query`` marks the object (not empty).

        Raises
        ------
        ValidationError
            No frame has a mask of ``query``, or every one is empty (the files are named).
        """
        if query not in self._seeds:
            have = [f for f in self.frames if (f, query) in self.gt]
            if not have:
                raise ValidationError(f"scene {self.name}: no frame has a mask of {query!r}")
            self._seeds[query] = next((f for f in have if self.read_gt(f, query).any()), None)
            if self._seeds[query] is None:
                files = ", ".join(str(self.gt[(f, query)]) for f in have[:3]) + (" ..." if len(have) > 3 else "")
                raise ValidationError(f"scene {self.name}: every ground-truth mask of {query!r} is empty "
                                      f"({files}); the oracle seed needs a frame that marks the object")
        return self._seeds[query]

    def reference_frame(self, query: str, oracle_seed: bool) -> str:
        """Where ``query`` is extracted from: :meth:`seed_frame` for the oracle seed,
        the first test frame for a text query (module docstring)."""
        return self.seed_frame(query) if oracle_seed else self.frames[0]

    def read_gt(self, frame: str, query: str) -> np.ndarray:
        """(H, W) bool ground truth of ``query`` in ``frame``."""
        return read_gt_mask(self.gt[(frame, query)], self.gt_threshold)


def _natural(name: str):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def read_gt_mask(path, threshold: int = 128) -> np.ndarray:
    """(H, W) bool ground truth: grey level (PIL ``convert("L")``) > ``threshold``.

    128 is how the LERF-Mask evaluator reads its masks.
    """
    return _read_mask_image(path, lambda im: np.asarray(im.convert("L")) > threshold)


def _image_shape(path) -> tuple:
    """(H, W) of a mask image from its header."""
    return _read_mask_image(path, lambda im: (im.height, im.width))


def _read_mask_image(path, read):
    """``read(image)`` of the image file ``path`` (PIL); FormatError naming the file when it is no image."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return read(im)
    except FileNotFoundError:
        raise FileNotFoundError(2, "No such file", os.fspath(path)) from None
    except (UnidentifiedImageError, OSError) as exc:
        raise FormatError(f"{path}: not a readable mask image ({exc})") from None


def _scene_file(scenes_dir: Path, name: str) -> Path:
    cands = [scenes_dir / f"{name}.ply", scenes_dir / name / "point_cloud.ply"]
    its = sorted((scenes_dir / name / "point_cloud").glob("iteration_*/point_cloud.ply"),
                 key=lambda p: _natural(p.parent.name))
    cands += its[::-1]
    for c in cands:
        if c.is_file():
            return c
    raise ValidationError(f"no trained scene for {name!r} in {scenes_dir}: expected {name}.ply, "
                          f"{name}/point_cloud.ply or {name}/point_cloud/iteration_<N>/point_cloud.ply")


def _cameras(data_scene: Path, scenes_dir: Path, name: str) -> list:
    from ..io import read_cameras

    for src in (data_scene / "cameras.json", data_scene / "transforms.json"):
        if src.is_file():
            return read_cameras(src)
    for sub in (data_scene / "sparse" / "0", data_scene / "sparse", data_scene):
        if any((sub / f"cameras{e}").is_file() for e in (".bin", ".txt")):
            return read_cameras(sub)
    if (scenes_dir / name / "cameras.json").is_file():
        return read_cameras(scenes_dir / name / "cameras.json")
    raise ValidationError(f"{data_scene}: no cameras (a COLMAP model in sparse/0, cameras.json, or "
                          f"{scenes_dir / name / 'cameras.json'})")


def _stem(name: str) -> str:
    base = os.path.basename(name)
    for e in _IMAGE_EXT:
        if base.endswith(e):
            return base[: -len(e)]
    return base


def _frame_camera(frame: str, cams: list, test: list, where: str) -> Camera:
    for c in cams:
        if c.name in (frame,) or _stem(c.name or "") == frame:
            return c
    if frame.isdigit():
        k = int(frame)
        if k < len(test):
            return test[k]
        raise ValidationError(f"{where}: frame {frame!r} is test camera {k}, but the split has only "
                              f"{len(test)} test cameras")
    raise ValidationError(f"{where}: frame {frame!r} matches no camera name (and is not a test-camera index)")


def _at_size(cam: Camera, shape, where: str) -> Camera:
    h, w = shape
    sx, sy = w / cam.width, h / cam.height
    if abs(sx / sy - 1) > 0.02:
        raise ValidationError(f"{where}: mask size {w}x{h} does not have the aspect of the camera "
                              f"({cam.width}x{cam.height})")
    return Camera(w, h, cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy, cam.world_to_camera,
                  name=cam.name, near=cam.near)


def _scene_names(data_dir: Path, scenes_dir: Path, scenes, marker: str, layout: str) -> list:
    """Sorted names of the folders of ``data_dir`` holding ``marker``, or the requested ``scenes``."""
    for d, what in ((data_dir, "DATA_DIR"), (scenes_dir, "--scenes")):
        if not d.is_dir():
            raise ValidationError(f"{what} {d} is not a directory")
    names = sorted(p.name for p in data_dir.iterdir() if (p / marker).exists())
    if scenes is None and names:
        skipped = sorted(p.name for p in data_dir.iterdir()
                         if p.is_dir() and not p.name.startswith(".") and p.name not in names)
        if skipped:
            warn_caller(f"{data_dir}: skipping {', '.join(skipped)}: no {marker} (not a {layout} scene)")
    if scenes is not None:
        missing = sorted(set(scenes) - set(names))
        if missing:
            raise ValidationError(f"{data_dir}: no scene(s) {missing} with {marker}; found {names}")
        names = [n for n in names if n in set(scenes)]
    if not names:
        hint = (f"; {data_dir} is itself a scene: give the folder that holds it"
                if (data_dir / marker).exists() else "")
        raise ValidationError(f"{data_dir}: no {layout} found{hint}")
    return names


#: The mask images a frame folder is read for (case-insensitive); other files are skipped with a warning.
_MASK_SUFFIXES = (".png", ".jpg", ".jpeg")


def read_lerf_mask(data_dir, scenes_dir, scenes=None) -> list:
    """The scenes of a LERF-Mask style dataset (layout in the module docstring).

    Parameters
    ----------
    data_dir : path
        Holds one folder per scene with ``test_mask/``.
    scenes_dir : path
        Holds the trained scenes.
    scenes : list of str, optional
        Only these scenes (default: every folder with ``test_mask``).
    """
    data_dir, scenes_dir = Path(data_dir), Path(scenes_dir)
    names = _scene_names(data_dir, scenes_dir, scenes, "test_mask", "<scene>/test_mask/<frame>/<query>.png")
    out = []
    for name in names:
        root = data_dir / name
        if not (root / "test_mask").is_dir():
            raise ValidationError(f"{root / 'test_mask'}: not a folder; expected <frame>/<query>.png inside it")
        frames = sorted((p.name for p in (root / "test_mask").iterdir() if p.is_dir()), key=_natural)
        if not frames:
            raise ValidationError(f"{root / 'test_mask'}: no frame folders")
        cams = sorted(_cameras(root, scenes_dir, name), key=lambda c: c.name or "")
        train = root / "images_train"
        if train.is_dir():
            train_names = {_stem(p.name) for p in train.iterdir()}
            test = [c for c in cams if _stem(c.name or "") not in train_names]
        else:
            test = [c for i, c in enumerate(cams) if i % _LLFF_HOLD == 0]
        gt, cameras, queries = {}, {}, set()
        for f in frames:
            where = f"{root / 'test_mask' / f}"
            present = [p for p in (root / "test_mask" / f).iterdir() if p.is_file() and not p.name.startswith(".")]
            files = sorted(p for p in present if p.suffix.lower() in _MASK_SUFFIXES)
            skipped = sorted(p.name for p in present if p.suffix.lower() not in _MASK_SUFFIXES)
            if skipped:
                warn_caller(f"{where}: {len(skipped)} file(s) skipped, not a mask image "
                            f"({', '.join(_MASK_SUFFIXES)}): {', '.join(skipped[:5])}"
                            + (" ..." if len(skipped) > 5 else ""))
            if not files:
                continue
            shapes = {}
            for p in files:
                q = p.stem
                if (f, q) in gt:
                    raise ValidationError(f"{where}: two masks for the query {q!r} ({gt[(f, q)].name} and "
                                          f"{p.name}); keep one")
                gt[(f, q)] = p
                queries.add(q)
                shapes[p.name] = _image_shape(p)
            if len(set(shapes.values())) != 1:
                raise ValidationError(f"{where}: masks of one frame differ in size: {shapes}")
            cameras[f] = _at_size(_frame_camera(f, cams, test, where), next(iter(shapes.values())), where)
        frames = [f for f in frames if f in cameras]
        if not frames:
            raise ValidationError(f"{root / 'test_mask'}: no mask images in its frame folders (read: "
                                  f"{', '.join(_MASK_SUFFIXES)}); expected <frame>/<query>.png")
        by_case = {}
        for q in sorted(queries):
            by_case.setdefault(q.casefold(), []).append(q)
        for same in (v for v in by_case.values() if len(v) > 1):
            warn_caller(f"{root / 'test_mask'}: queries {' and '.join(map(repr, same))} differ only in case "
                        f"and are scored as different objects; if they are one, rename the mask files")
        out.append(LerfScene(name, _scene_file(scenes_dir, name), frames, sorted(queries), cameras, gt))
    return out


def _slug(text: str) -> str:
    s = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._-")
    return s or "query"


def _seed_mode(oracle_seed, models) -> bool:
    """True for the oracle seed, False for text; None picks text exactly when ``models`` is given."""
    if oracle_seed is None:
        return models is None
    if oracle_seed and models is not None:
        raise ValidationError("oracle_seed=True seeds every query with its ground-truth mask, and models "
                              "are for text queries: give one of the two (--oracle-seed or --models FILE)")
    if not oracle_seed and models is None:
        raise ValidationError("text queries need a grounding model: give models (--models FILE), "
                              "or use the oracle seed (--oracle-seed)")
    return bool(oracle_seed)


def check_models(models) -> None:
    """Open a models configuration once, before any job runs, and check it can ground text.

    Raises
    ------
    FormatError
        The file does not exist, is not a valid configuration, or one of its
        ONNX files does not match its role (message names the file).
    ValidationError
        It configures no text-grounding source.
    """
    from ..batch.worker import job_models

    grounder, _ = job_models(models)  # opened in this process's cache: a sequential run reuses it
    if grounder is None:
        raise ValidationError(f"{models}: configures no text-grounding source; text queries need "
                              f"[groundingdino], [owlvit], [sam3] with a language_encoder, or [external] "
                              f"(see docs/models.md)")


def lerf_jobs(scenes, oracle_seed: bool | None = None, models=None, options=None) -> list:
    """One batch :class:`~seed2gs_inverse.batch.Job` per (scene, query).

    The reference camera is :meth:`LerfScene.reference_frame`'s; the prompt
    the ground-truth mask there (``oracle_seed``) or the query text (needs
    ``models``; ``oracle_seed=None`` means text exactly when ``models`` is
    given). Job names are ``<scene>--<query>`` made folder-safe.
    """
    from ..batch import Job
    from ..frontend.prompts import MaskPrompt, TextPrompt

    oracle_seed = _seed_mode(oracle_seed, models)
    jobs, names = [], set()
    for sc in scenes:
        for q in sc.queries:
            f = sc.reference_frame(q, oracle_seed)
            name = f"{_slug(sc.name)}--{_slug(q)}"
            k = 2
            # two queries that differ only in punctuation, or in case (one folder on macOS / Windows)
            while name.casefold() in names:
                name, k = f"{_slug(sc.name)}--{_slug(q)}-{k}", k + 1
            names.add(name.casefold())
            prompt = MaskPrompt(sc.read_gt(f, q)) if oracle_seed else TextPrompt(q)
            jobs.append(Job(name=name, scene=os.fspath(sc.scene_file.resolve()), camera=sc.cameras[f],
                            prompt=prompt, options=dict(options or {}),
                            models=None if oracle_seed else os.fspath(models), figure=False))
    return jobs


def score_frame(scene_file, camera: Camera, queries: list, outdirs: list, gt_paths: list, pred_paths=None,
                gt_threshold: int = 128):
    """Predicted masks and scores of every query in one test view (a batch task).

    Builds the view's operator ``W(c)`` once over the full scene (read once
    per worker) and renders each query's selection ``s`` (``q > tau`` from
    the job folder) as ``W(c) s > 0.5``. Writes the predicted masks to
    ``pred_paths`` (PNG, 0/255) when given. Ground truth is read with
    :func:`read_gt_mask` at ``gt_threshold``.

    Returns
    -------
    list of dict
        ``{query, iou, biou, pred (H, W) bool}`` (iou/biou None without ground truth).
    """
    from .. import build_operator
    from .._atomic import atomic_path
    from ..batch.worker import _scene
    from ..metrics import boundary_iou, iou

    scene, _, _ = _scene(os.fspath(scene_file))
    W = build_operator(scene, camera).W
    out = []
    for k, (query, outdir, gt_path) in enumerate(zip(queries, outdirs, gt_paths)):
        outdir = Path(outdir)
        q = np.load(outdir / "q.npy", allow_pickle=False)
        with open(outdir / "report.json") as fh:
            tau = float(json.load(fh)["threshold"])
        if q.shape != (len(scene),):
            raise ValidationError(f"{outdir / 'q.npy'} has {q.shape[0]} entries, the scene {len(scene)}")
        sel = (q > tau).astype(np.float32)
        pred = (np.asarray(W @ sel) > 0.5).reshape(camera.image_shape)
        rec = {"query": query, "iou": None, "biou": None, "pred": pred}
        if gt_path is not None:
            gt = read_gt_mask(gt_path, gt_threshold)
            rec["iou"], rec["biou"] = float(iou(pred, gt)), float(boundary_iou(pred, gt))
        if pred_paths is not None:
            import cv2

            p = Path(pred_paths[k])
            p.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(p) as tmp:
                if not cv2.imwrite(os.fspath(tmp), pred.astype(np.uint8) * 255):
                    raise FormatError(f"{p}: could not write the PNG")
        out.append(rec)
    return out


# ---------------------------------------------------------------------------
# the whole evaluation
# ---------------------------------------------------------------------------
def evaluate_lerf_mask(data_dir, scenes_dir, output, *, oracle_seed: bool | None = None, models=None,
                       options=None, scenes=None, client=None, n_workers=None, resume: bool = True,
                       progress: bool | None = None, log=None) -> dict:
    """Extract every query of a LERF-Mask style dataset, score every test view, write the report.

    Parameters
    ----------
    data_dir, scenes_dir : path
        See :func:`read_lerf_mask`.
    output : path
        Report directory (created; its parent must exist): ``per_query.csv``,
        ``per_scene.csv``, ``report.json``, ``grid.png``, the predicted
        masks in the dataset's layout (``masks/<scene>/<frame>/<query>.png``,
        readable by Gaussian Grouping's own evaluator) and the batch job
        folders with their summary (``jobs/``, so a re-run resumes).
    oracle_seed : bool, optional
        True: seed each query with its ground-truth mask in its first frame.
        False: ground the query text with ``models``. Default: text exactly
        when ``models`` is given.
    models : path, optional
        Models configuration for text queries (docs/models.md); opened and
        checked once before any job runs (:func:`check_models`).
    options : dict, optional
        ``extract()`` options for every query.
    scenes : list of str, optional
        Only these scenes.
    client, n_workers, resume, progress, log
        As :func:`~seed2gs_inverse.batch.extract_many`; the scoring runs on
        the same cluster, one task per test view.

    Returns
    -------
    dict
        The content of ``report.json``: ``overall`` (miou, mbiou),
        ``scenes`` (per scene), ``queries`` (per query, with per-frame
        scores) and ``failed`` jobs.
    """
    out = _check_output(output)
    oracle = _seed_mode(oracle_seed, models)
    dataset = read_lerf_mask(data_dir, scenes_dir, scenes)
    return evaluate_scenes(dataset, out, oracle_seed=oracle, models=models, options=options, client=client,
                           n_workers=n_workers, resume=resume, progress=progress, log=log,
                           protocol={"dataset": "LERF-Mask", "gt": "grey > 128"})


#: What an evaluation writes at the top of its report directory (besides ``jobs/``, the batch's folder).
_REPORT_FILES = ("report.json", "per_query.csv", "per_scene.csv", "grid.png", "masks")


def _check_output(output) -> Path:
    """The report directory, checked: the run writes its files there only over an earlier evaluation's.

    A new or empty directory, or one without any of the report's files, is
    fine (other files are left alone). The report's own files
    (``report.json``, the tables, ``grid.png``) may be there only as an
    earlier evaluation's (its ``report.json``), which the run resumes;
    ``masks/`` alone also when ``jobs/summary.json`` is a batch summary (a
    run interrupted while scoring, before its report). Anything else would
    overwrite a user's files, and is refused.
    """
    from ..batch.runner import _read_summary, check_output_dir

    out = check_output_dir(output)
    clash = [n for n in _REPORT_FILES if (out / n).exists()] if out.is_dir() else []
    if clash:
        try:
            doc = json.loads((out / "report.json").read_text("utf-8"))
            ours = isinstance(doc, dict) and isinstance(doc.get("protocol"), dict) \
                and isinstance(doc.get("queries"), list)
        except (OSError, UnicodeDecodeError, ValueError, RecursionError):
            ours = False
        if not ours and clash == ["masks"] and (out / "jobs" / "summary.json").is_file():
            try:
                ours = bool(_read_summary(out / "jobs"))
            except ValidationError:
                ours = False
        if not ours:
            raise ValidationError(f"output {out} holds {', '.join(clash)} of no earlier evaluation; the report "
                                  f"would overwrite {'it' if len(clash) == 1 else 'them'}: choose a new "
                                  f"directory (an earlier evaluation there is resumed)")
    return out


def evaluate_scenes(dataset, output, *, oracle_seed: bool | None = None, models=None, options=None,
                    client=None, n_workers=None, resume: bool = True, progress: bool | None = None,
                    log=None, protocol=None) -> dict:
    """The evaluation of :func:`evaluate_lerf_mask` on scenes already read (any layout reader).

    Parameters
    ----------
    dataset : list of LerfScene
        From :func:`read_lerf_mask` or :func:`~seed2gs_inverse.evaluation.read_3d_ovs`.
    output, oracle_seed, models, options, client, n_workers, resume, progress, log
        As :func:`evaluate_lerf_mask`.
    protocol : dict, optional
        Extra entries for the report's ``protocol`` record (dataset name, ground-truth rule).

    Returns
    -------
    dict
        As :func:`evaluate_lerf_mask`.
    """
    from .._atomic import write_files
    from ..batch import batch_client, extract_many
    from ..batch.worker import clear_scene_cache
    from ..metrics import protocol_mean

    out = _check_output(output)
    oracle_seed = _seed_mode(oracle_seed, models)
    if not dataset:
        raise ValidationError("no scenes to evaluate")
    try:
        if not oracle_seed:
            check_models(models)  # one clear error naming the file, before any job
        jobs = lerf_jobs(dataset, oracle_seed=oracle_seed, models=models, options=options)
        out.mkdir(exist_ok=True)
        out = out.resolve()
        job_of = {}
        it = iter(jobs)
        for sc in dataset:
            for q in sc.queries:
                job_of[(sc.name, q)] = next(it)
        n_tasks = sum(len(sc.frames) for sc in dataset)
        with batch_client(client, n_workers=n_workers, n_jobs=max(len(jobs), n_tasks)) as c:
            results = extract_many(jobs, "sequential" if c is None else c, output=out / "jobs",
                                   resume=resume, progress=progress, log=log)
            by_name = {r.name: r for r in results}
            tasks = []  # (scene, frame, queries) per test view
            for sc in dataset:
                for f in sc.frames:
                    qs = [q for q in sc.queries if by_name[job_of[(sc.name, q)].name].ok]
                    if not qs:
                        continue
                    args = (os.fspath(sc.scene_file.resolve()), sc.cameras[f], qs,
                            [by_name[job_of[(sc.name, q)].name].outdir for q in qs],
                            [sc.gt.get((f, q)) for q in qs],
                            [os.fspath(out / "masks" / sc.name / f / f"{q}.png") for q in qs],
                            sc.gt_threshold)
                    tasks.append(((sc, f), args))
            if c is None:
                scored = [score_frame(*a) for _, a in tasks]
            else:
                futs = [c.submit(score_frame, *a, pure=False) for _, a in tasks]
                scored = c.gather(futs)
    finally:
        # This process is no worker: do not keep the scenes, nor the models check_models opened.
        clear_scene_cache()
    per_frame = {}  # (scene, query) -> {frame: (iou, biou)}
    preds = {}
    for ((sc, f), _), recs in zip(tasks, scored):
        for r in recs:
            preds[(sc.name, f, r["query"])] = r["pred"]
            if r["iou"] is not None:
                per_frame.setdefault((sc.name, r["query"]), {})[f] = (r["iou"], r["biou"])
    failed = {r.name: r.error for r in results if not r.ok}
    _remove_stale_masks(out / "masks", dataset, preds)
    report = _tables(dataset, job_of, by_name, per_frame, protocol_mean, oracle_seed)
    report["failed"] = failed
    report["protocol"] = {**dict(protocol or {}),
                          "seed": ("ground-truth mask of the query's first annotated test frame" if oracle_seed
                                   else "query text, grounded in the first test frame"),
                          "models": None if models is None else os.path.abspath(os.fspath(models)),
                          "prediction": "W(c) s > 0.5 over the full scene (occlusion-aware)",
                          "boundary_dilation_ratio": 0.02, "options": dict(options or {})}
    report["protocol"].setdefault("gt", "grey > 128")
    try:  # a report of fewer scenes replaces a fuller one: say so (the job folders all stay)
        before = {d["scene"] for d in json.loads((out / "report.json").read_text("utf-8"))["scenes"]}
    except (OSError, ValueError, KeyError, TypeError):
        before = set()
    dropped = sorted(before - {sc.name for sc in dataset})
    if dropped:
        warnings.warn(f"{out / 'report.json'}: the report now covers {', '.join(sc.name for sc in dataset)} only; "
                      f"the earlier one also had {', '.join(dropped)} (their extractions stay in jobs/ and are "
                      f"reused by a run over every scene)", stacklevel=2)
    files = [(out / "report.json", json.dumps(report, indent=1).encode("utf-8")),
             (out / "per_query.csv", _csv(report["queries"], list(QUERY_COLUMNS))),
             (out / "per_scene.csv", _csv(report["scenes"], ["scene", "miou", "mbiou", "n_queries",
                                                             "n_failed"]))]
    png = _grid(dataset, preds, per_frame,
                {(sc.name, q) for sc in dataset for q in sc.queries if job_of[(sc.name, q)].name in failed})
    if png is not None:
        files.append((out / "grid.png", png))
    write_files(files)
    return report


#: Columns of ``per_query.csv``. ``prompt`` is the query text or ``gt-mask``;
#: ``grounded_by`` / ``grounding_score`` name the source (and its selector
#: score) of the candidate that became the seed of a text query.
QUERY_COLUMNS = ("scene", "query", "miou", "mbiou", "miou_heldout", "n_frames", "seed_frame", "prompt",
                 "grounded_by", "grounding_score", "n_selected", "status", "error")


def _grounding(result) -> tuple:
    """(source, score) of the seed candidate of a done text job, from its report.json."""
    if not result.ok or result.outdir is None:
        return None, None
    try:
        with open(Path(result.outdir) / "report.json") as fh:
            cands = json.load(fh).get("prompt", {}).get("candidates") or []
    except (OSError, ValueError):
        return None, None
    if not cands:
        return None, None
    return cands[0].get("source"), cands[0].get("score")


def _tables(dataset, job_of, by_name, per_frame, protocol_mean, oracle_seed=True) -> dict:
    queries, iou_in, biou_in = [], {}, {}
    for sc in dataset:
        for q in sc.queries:
            r = by_name[job_of[(sc.name, q)].name]
            frames = per_frame.get((sc.name, q), {})
            seed = sc.reference_frame(q, oracle_seed)
            source, score = (None, None) if oracle_seed else _grounding(r)
            row = {"scene": sc.name, "query": q, "job": r.name, "status": r.status, "error": r.error,
                   "seed_frame": seed, "prompt": "gt-mask" if oracle_seed else q,
                   "grounded_by": source, "grounding_score": score,
                   "n_selected": r.n_selected, "n_frames": len(frames),
                   "frames": {f: {"iou": v[0], "biou": v[1]} for f, v in frames.items()}}
            if r.ok and frames:
                row["miou"] = float(np.mean([v[0] for v in frames.values()]))
                row["mbiou"] = float(np.mean([v[1] for v in frames.values()]))
                held = [v[0] for f, v in frames.items() if f != seed]
                row["miou_heldout"] = float(np.mean(held)) if held else None
            else:
                # A failed query scores 0 on each of its frames, as an empty
                # prediction would, so failures cannot raise the mean.
                n = sum((f, q) in sc.gt for f in sc.frames)
                row["miou"] = row["mbiou"] = 0.0
                row["miou_heldout"] = None
                frames = {f: (0.0, 0.0) for f in sc.frames if (f, q) in sc.gt}
                row["n_frames"] = n
            iou_in.setdefault(sc.name, {})[q] = [v[0] for v in frames.values()]
            biou_in.setdefault(sc.name, {})[q] = [v[1] for v in frames.values()]
            queries.append(row)
    miou, miou_scene, _ = protocol_mean(iou_in)
    mbiou, mbiou_scene, _ = protocol_mean(biou_in)
    scenes = [{"scene": sc.name, "miou": miou_scene[sc.name], "mbiou": mbiou_scene[sc.name],
               "n_queries": len(sc.queries),
               "n_failed": sum(not by_name[job_of[(sc.name, q)].name].ok for q in sc.queries)}
              for sc in dataset]
    return {"overall": {"miou": miou, "mbiou": mbiou}, "scenes": scenes, "queries": queries}


def _csv(rows, cols) -> bytes:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([("" if r.get(c) is None else (f"{r[c]:.6f}" if isinstance(r[c], float) else r[c]))
                    for c in cols])
    return buf.getvalue().encode("utf-8")


def _remove_stale_masks(masks_dir: Path, dataset, preds) -> None:
    """Delete the predicted masks an earlier run left for this run's scenes that this run did not write.

    A query that failed this time, or that the dataset no longer has, must
    not leave an earlier prediction for a scorer reading ``masks/``. Masks
    of scenes outside this run stay, as their job folders do.
    """
    for sc in dataset:
        root = masks_dir / sc.name
        if not root.is_dir():
            continue
        for frame_dir in [d for d in root.iterdir() if d.is_dir()]:
            for png in frame_dir.glob("*.png"):
                if (sc.name, frame_dir.name, png.stem) not in preds:
                    png.unlink()
            if not any(frame_dir.iterdir()):
                frame_dir.rmdir()


def _grid(dataset, preds, per_frame, failed=frozenset()):
    """PNG bytes: one row per query, one column per test frame; truth vs prediction.

    Each cell overlays the two masks: green = both, red = predicted only,
    blue = missed (truth only); the title gives the frame's IoU, or says that
    the query failed (``failed``: its ``(scene, query)`` pairs; scored 0
    where it has truth).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    rows = [(sc, q) for sc in dataset for q in sc.queries]
    n_cols = max((len(sc.frames) for sc in dataset), default=0)
    if not rows or not n_cols:
        return None
    fig, axes = plt.subplots(len(rows), n_cols, figsize=(2.4 * n_cols, 2.0 * len(rows)), squeeze=False)
    for i, (sc, q) in enumerate(rows):
        for j in range(n_cols):
            ax = axes[i, j]
            ax.set_xticks([])
            ax.set_yticks([])
            if j >= len(sc.frames):
                ax.axis("off")
                continue
            f = sc.frames[j]
            pred = preds.get((sc.name, f, q))
            gt = sc.read_gt(f, q) if (f, q) in sc.gt else None
            shape = (pred if pred is not None else gt).shape if (pred is not None or gt is not None) else (8, 8)
            img = np.full((*shape, 3), 0.12, np.float32)
            p = pred if pred is not None else np.zeros(shape, bool)
            g = gt if gt is not None else np.zeros(shape, bool)
            img[p & g] = (0.2, 0.8, 0.2)
            img[p & ~g] = (0.9, 0.2, 0.2)
            img[~p & g] = (0.2, 0.4, 0.9)
            ax.imshow(img, interpolation="nearest")
            s = per_frame.get((sc.name, q), {}).get(f)
            if (sc.name, q) in failed:
                title = "failed" + (", IoU 0" if gt is not None else "")
            else:
                title = "no truth" if s is None else f"IoU {s[0]:.2f}"
            ax.set_title(f"{f}: {title}", fontsize=7)
            if j == 0:
                ax.set_ylabel(f"{sc.name}\n{q}", fontsize=7)
    fig.suptitle("green: both, red: predicted only, blue: missed", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return buf.getvalue()
