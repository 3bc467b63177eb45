r"""The evaluation engine shared by every dataset layout.

A layout reader (:mod:`.lerf_mask`, :mod:`.ovs3d`) turns a dataset into a
list of :class:`LerfScene` records (frames, queries, cameras at the size of
the ground-truth masks, the trained scene file), using the helpers here to
find scene files and cameras and to read masks. :func:`evaluate_scenes`
then runs the protocol on those records:

1. every query becomes one batch :class:`~seed2gs_inverse.batch.Job`
   (:func:`lerf_jobs`), seeded by its ground-truth mask in its first
   annotated test frame (``oracle_seed``) or by its text, grounded in the
   first test frame;
2. the jobs run on the batch runner (:func:`~seed2gs_inverse.batch.extract_many`);
3. each test view is scored as one task (:func:`score_frame`): the object is
   rendered with the *full* scene, so occlusions count, and the predicted
   mask is

   .. math:: \hat M(c) = [\, W(c)\, s > 0.5 \,],

   with ``s`` the 0/1 selection ``q > tau`` of the job (``W(c) s`` is the
   share of each pixel's colour that the object contributes); IoU and
   boundary IoU against the ground truth come from :mod:`seed2gs_inverse.metrics`;
4. the report (:mod:`.report`) averages them as
   :func:`~seed2gs_inverse.metrics.protocol_mean` does (views -> query ->
   scene -> overall).

A Dask worker imports this module on its event loop, when it unpickles a
:func:`score_frame` task; so the rasterizer (and Numba) is imported inside
:func:`score_frame`, in the task's thread.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._atomic import atomic_path, write_files
from ..batch import Job, extract_many, open_layout, resolve_layout
from ..batch.summary import check_output_dir, read_summary
from ..batch.worker import cached_scene, clear_scene_cache, job_models
from ..camera import Camera
from ..errors import FormatError, ValidationError
from ..frontend.prompts import MaskPrompt, TextPrompt
from ..io import read_cameras
from ..io._common import warn_caller
from ..io.images import read_image
from ..metrics import boundary_iou, iou
from .report import QUERY_COLUMNS, csv_table, grid_png, remove_stale_masks, report_tables

__all__ = ["LerfScene", "read_gt_mask", "mask_image_shape", "natural_key", "image_stem", "find_scene_file",
           "read_scene_cameras", "camera_at_size", "scene_names", "seed_mode", "check_models", "check_output",
           "lerf_jobs", "score_frame", "evaluate_scenes", "REPORT_FILES"]


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


#: Image file extensions a camera's name may carry (stripped to match a frame or mask name).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".JPG", ".JPEG", ".PNG")


def natural_key(name: str) -> list:
    """Sort key that orders the digit runs of ``name`` as numbers (``frame_2`` before ``frame_10``)."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def read_gt_mask(path, threshold: int = 128) -> np.ndarray:
    """(H, W) bool ground truth: grey level (PIL ``convert("L")``) > ``threshold``.

    Parameters
    ----------
    path : path
        A mask image (any format PIL reads).
    threshold : int
        128 because that is how the LERF-Mask evaluator reads its masks.

    Returns
    -------
    (H, W) bool ndarray

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    FormatError
        ``path`` is no readable image, or declares more pixels than
        :data:`~seed2gs_inverse.io.images.MAX_IMAGE_PIXELS` (checked before
        any pixel is decoded).
    """
    return _read_mask_image(path, lambda im: np.asarray(im.convert("L")) > threshold)


def mask_image_shape(path) -> tuple:
    """(H, W) of a mask image, read from its header (errors as :func:`read_gt_mask`)."""
    return _read_mask_image(path, lambda im: (im.height, im.width))


def _read_mask_image(path, read):
    """``read(image)`` of the image file ``path``, bounded as :func:`~seed2gs_inverse.io.images.read_image`."""
    return read_image(path, read, "mask image")


def find_scene_file(scenes_dir: Path, name: str) -> Path:
    """The trained scene ``name`` in ``scenes_dir``.

    Looked for as ``<name>.ply``, ``<name>/point_cloud.ply``, then the 3DGS
    trainer's ``<name>/point_cloud/iteration_<N>/point_cloud.ply`` with the
    highest ``N``.

    Raises
    ------
    ValidationError
        None of these files exists (the message lists them).
    """
    cands = [scenes_dir / f"{name}.ply", scenes_dir / name / "point_cloud.ply"]
    its = sorted((scenes_dir / name / "point_cloud").glob("iteration_*/point_cloud.ply"),
                 key=lambda p: natural_key(p.parent.name))
    cands += its[::-1]
    for c in cands:
        if c.is_file():
            return c
    raise ValidationError(f"no trained scene for {name!r} in {scenes_dir}: expected {name}.ply, "
                          f"{name}/point_cloud.ply or {name}/point_cloud/iteration_<N>/point_cloud.ply")


def read_scene_cameras(data_scene: Path, scenes_dir: Path, name: str) -> list:
    """Every camera of the dataset scene ``data_scene`` (a list of :class:`~seed2gs_inverse.Camera`).

    Read from ``cameras.json`` or ``transforms.json`` there, else from its
    COLMAP model (``sparse/0``, ``sparse`` or the folder itself), else from
    the trained scene's ``<scenes_dir>/<name>/cameras.json``.

    Raises
    ------
    ValidationError
        No camera file in any of these places.
    """
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


def image_stem(name: str) -> str:
    """The base name of ``name`` without a known image extension (:data:`IMAGE_EXTENSIONS`)."""
    base = os.path.basename(name)
    for e in IMAGE_EXTENSIONS:
        if base.endswith(e):
            return base[: -len(e)]
    return base


def camera_at_size(cam: Camera, shape, where: str) -> Camera:
    """``cam`` rescaled to an image of ``shape`` = (H, W): intrinsics scaled by W / width and H / height.

    Raises
    ------
    ValidationError
        The aspect ratios differ by more than 2 % (``where`` starts the message).
    """
    h, w = shape
    sx, sy = w / cam.width, h / cam.height
    if abs(sx / sy - 1) > 0.02:
        raise ValidationError(f"{where}: mask size {w}x{h} does not have the aspect of the camera "
                              f"({cam.width}x{cam.height})")
    return Camera(w, h, cam.fx * sx, cam.fy * sy, cam.cx * sx, cam.cy * sy, cam.world_to_camera,
                  name=cam.name, near=cam.near)


def scene_names(data_dir: Path, scenes_dir: Path, scenes, marker: str, layout: str) -> list:
    """Sorted names of the folders of ``data_dir`` holding ``marker``, or the requested ``scenes``.

    Parameters
    ----------
    data_dir, scenes_dir : Path
        The dataset root and the folder of trained scenes (both must be directories).
    scenes : list of str or None
        The scenes asked for; None takes every folder with ``marker`` and
        warns about the others.
    marker : str
        Relative path that makes a folder a scene of the layout.
    layout : str
        The layout, as said in messages.

    Raises
    ------
    ValidationError
        A folder is missing, a requested scene has no ``marker``, or no scene is found.
    """
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


def _slug(text: str) -> str:
    s = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._-")
    return s or "query"


def seed_mode(oracle_seed, models) -> bool:
    """True for the oracle seed, False for text; None picks text exactly when ``models`` is given.

    Raises
    ------
    ValidationError
        ``oracle_seed=True`` with ``models``, or ``oracle_seed=False`` without.
    """
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
    given). Job names are ``<scene>--<query>`` made folder-safe (a suffix
    ``-2``, ``-3`` ... keeps them unique, also ignoring case).

    Parameters
    ----------
    scenes : list of LerfScene
    oracle_seed : bool or None
        As :func:`seed_mode`.
    models : path, optional
        Models configuration of the text queries.
    options : dict, optional
        ``extract()`` options of every job.

    Returns
    -------
    list of Job
        In the order of the scenes and, within each, of its queries.
    """
    oracle_seed = seed_mode(oracle_seed, models)
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
                gt_threshold: int = 128) -> list:
    """Predicted masks and scores of every query in one test view (a batch task).

    Builds the view's operator ``W(c)`` once over the full scene (read once
    per worker) and renders each query's selection ``s`` (``q > tau`` from
    the job folder) as ``W(c) s > 0.5``. Writes the predicted masks to
    ``pred_paths`` (PNG, 0/255) when given. Ground truth is read with
    :func:`read_gt_mask` at ``gt_threshold``.

    Parameters
    ----------
    scene_file : str
        The trained scene (read through the worker's scene cache).
    camera : Camera
        The test view, at the size of its ground-truth masks.
    queries, outdirs, gt_paths : list
        Per query: its name, its job folder (``q.npy``, ``report.json``) and
        its ground-truth mask in this view (None when it has none).
    pred_paths : list of path, optional
        Where to write each predicted mask.
    gt_threshold : int
        As :func:`read_gt_mask`.

    Returns
    -------
    list of dict
        ``{query, iou, biou, pred (H, W) bool}`` (iou/biou None without ground truth).

    Raises
    ------
    ValidationError
        A job's ``q.npy`` does not have one entry per Gaussian of the scene.
    FormatError
        A predicted mask could not be written.
    """
    from ..raster import build_operator  # deferred: see the module docstring

    scene, _, _ = cached_scene(os.fspath(scene_file))
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


#: What an evaluation writes at the top of its report directory (besides ``jobs/``, the batch's folder).
REPORT_FILES = ("report.json", "per_query.csv", "per_scene.csv", "grid.png", "masks")


def check_output(output) -> Path:
    """The report directory, checked: the run writes its files there only over an earlier evaluation's.

    A new or empty directory, or one without any of the report's files, is
    fine (other files are left alone). The report's own files
    (``report.json``, the tables, ``grid.png``) may be there only as an
    earlier evaluation's (its ``report.json``), which the run resumes;
    ``masks/`` alone also when ``jobs/summary.json`` is a batch summary (a
    run interrupted while scoring, before its report). Anything else would
    overwrite a user's files, and is refused.

    Raises
    ------
    ValidationError
        The directory cannot be written (:func:`~seed2gs_inverse.batch.summary.check_output_dir`),
        or it holds report files of no earlier evaluation.
    """
    out = check_output_dir(output)
    clash = [n for n in REPORT_FILES if (out / n).exists()] if out.is_dir() else []
    if clash:
        try:
            doc = json.loads((out / "report.json").read_text("utf-8"))
            ours = isinstance(doc, dict) and isinstance(doc.get("protocol"), dict) \
                and isinstance(doc.get("queries"), list)
        except (OSError, UnicodeDecodeError, ValueError, RecursionError):
            ours = False
        if not ours and clash == ["masks"] and (out / "jobs" / "summary.json").is_file():
            try:
                ours = bool(read_summary(out / "jobs"))
            except ValidationError:
                ours = False
        if not ours:
            raise ValidationError(f"output {out} holds {', '.join(clash)} of no earlier evaluation; the report "
                                  f"would overwrite {'it' if len(clash) == 1 else 'them'}: choose a new "
                                  f"directory (an earlier evaluation there is resumed)")
    return out


def evaluate_scenes(dataset, output, *, oracle_seed: bool | None = None, models=None, options=None,
                    client=None, n_workers=None, resume: bool = True, progress: bool | str | None = None,
                    log=None, protocol=None) -> dict:
    """Extract every query of scenes already read (any layout reader), score every test view, write the report.

    Parameters
    ----------
    dataset : list of LerfScene
        From :func:`~seed2gs_inverse.evaluation.read_lerf_mask` or
        :func:`~seed2gs_inverse.evaluation.read_3d_ovs`.
    output, oracle_seed, models, options, client, n_workers, resume, progress, log
        As :func:`~seed2gs_inverse.evaluation.evaluate_lerf_mask`.
    protocol : dict, optional
        Extra entries for the report's ``protocol`` record (dataset name, ground-truth rule).

    Returns
    -------
    dict
        The content of ``report.json``, as
        :func:`~seed2gs_inverse.evaluation.evaluate_lerf_mask` returns it.

    Raises
    ------
    ValidationError
        No scenes, a bad output directory, or a bad choice of seed (:func:`seed_mode`).
    FormatError
        ``models`` cannot be opened (:func:`check_models`).
    """
    out = check_output(output)
    oracle_seed = seed_mode(oracle_seed, models)
    if not dataset:
        raise ValidationError("no scenes to evaluate")
    try:
        if not oracle_seed:
            check_models(models)  # one clear error naming the file, before any job
        jobs = lerf_jobs(dataset, oracle_seed=oracle_seed, models=models, options=options)
        out.mkdir(exist_ok=True)
        out = out.resolve()
        job_of = dict(zip(((sc.name, q) for sc in dataset for q in sc.queries), jobs))
        results, tasks, scored = _extract_and_score(dataset, jobs, job_of, out, client=client, n_workers=n_workers,
                                                    resume=resume, progress=progress, log=log)
    finally:
        # This process is no worker: do not keep the scenes, nor the models check_models opened.
        clear_scene_cache()
    by_name = {r.name: r for r in results}
    per_frame = {}  # (scene, query) -> {frame: (iou, biou)}
    preds = {}
    for ((sc, f), _), recs in zip(tasks, scored):
        for r in recs:
            preds[(sc.name, f, r["query"])] = r["pred"]
            if r["iou"] is not None:
                per_frame.setdefault((sc.name, r["query"]), {})[f] = (r["iou"], r["biou"])
    failed = {r.name: r.error for r in results if not r.ok}
    remove_stale_masks(out / "masks", dataset, preds)
    report = report_tables(dataset, job_of, by_name, per_frame, oracle_seed)
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
             (out / "per_query.csv", csv_table(report["queries"], list(QUERY_COLUMNS))),
             (out / "per_scene.csv", csv_table(report["scenes"], ["scene", "miou", "mbiou", "n_queries",
                                                                  "n_failed"]))]
    png = grid_png(dataset, preds, per_frame,
                   {(sc.name, q) for sc in dataset for q in sc.queries if job_of[(sc.name, q)].name in failed})
    if png is not None:
        files.append((out / "grid.png", png))
    write_files(files)
    return report


def _extract_and_score(dataset, jobs, job_of, out: Path, *, client, n_workers, resume, progress, log) -> tuple:
    """Run ``jobs`` on the batch runner, then :func:`score_frame` on every test view, on one cluster.

    Returns ``(results, tasks, scored)``: the :class:`~seed2gs_inverse.batch.JobResult`
    of every job, the ``((scene, frame), args)`` of every scoring task (views
    with at least one done query), and each task's records.
    """
    n_tasks = sum(len(sc.frames) for sc in dataset)
    layout = resolve_layout(client, n_workers=n_workers, n_jobs=max(len(jobs), n_tasks))
    with open_layout(layout) as layout:
        c = layout.client
        results = extract_many(jobs, layout, output=out / "jobs", resume=resume, progress=progress, log=log)
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
    return results, tasks, scored
