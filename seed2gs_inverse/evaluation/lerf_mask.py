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

from pathlib import Path

from ..camera import Camera
from ..errors import ValidationError
from ..io._common import warn_caller
from .engine import (LerfScene, camera_at_size, check_output, evaluate_scenes, find_scene_file, image_stem,
                     mask_image_shape, natural_key, read_scene_cameras, scene_names, seed_mode)

__all__ = ["read_lerf_mask", "evaluate_lerf_mask"]

#: LLFF hold-out: without ``images_train/``, every 8th camera (sorted by name) is a test camera.
_LLFF_HOLD = 8


def _frame_camera(frame: str, cams: list, test: list, where: str) -> Camera:
    """The camera of the frame folder ``frame``: by name (with or without the image extension),
    else, for an integer name ``k``, the k-th of the ``test`` cameras."""
    for c in cams:
        if c.name in (frame,) or image_stem(c.name or "") == frame:
            return c
    if frame.isdigit():
        k = int(frame)
        if k < len(test):
            return test[k]
        raise ValidationError(f"{where}: frame {frame!r} is test camera {k}, but the split has only "
                              f"{len(test)} test cameras")
    raise ValidationError(f"{where}: frame {frame!r} matches no camera name (and is not a test-camera index)")


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

    Returns
    -------
    list of LerfScene
        In the order of the scene names; frames without a mask image are left out.

    Raises
    ------
    ValidationError
        A scene without frames, masks or cameras, a frame that matches no
        camera, masks of one frame that differ in size, or two masks of one query.
    FormatError
        A mask file that is no readable image.
    """
    data_dir, scenes_dir = Path(data_dir), Path(scenes_dir)
    names = scene_names(data_dir, scenes_dir, scenes, "test_mask", "<scene>/test_mask/<frame>/<query>.png")
    out = []
    for name in names:
        root = data_dir / name
        if not (root / "test_mask").is_dir():
            raise ValidationError(f"{root / 'test_mask'}: not a folder; expected <frame>/<query>.png inside it")
        frames = sorted((p.name for p in (root / "test_mask").iterdir() if p.is_dir()), key=natural_key)
        if not frames:
            raise ValidationError(f"{root / 'test_mask'}: no frame folders")
        cams = sorted(read_scene_cameras(root, scenes_dir, name), key=lambda c: c.name or "")
        train = root / "images_train"
        if train.is_dir():
            train_names = {image_stem(p.name) for p in train.iterdir()}
            test = [c for c in cams if image_stem(c.name or "") not in train_names]
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
                shapes[p.name] = mask_image_shape(p)
            if len(set(shapes.values())) != 1:
                raise ValidationError(f"{where}: masks of one frame differ in size: {shapes}")
            cameras[f] = camera_at_size(_frame_camera(f, cams, test, where), next(iter(shapes.values())), where)
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
        out.append(LerfScene(name, find_scene_file(scenes_dir, name), frames, sorted(queries), cameras, gt))
    return out


def evaluate_lerf_mask(data_dir, scenes_dir, output, *, oracle_seed: bool | None = None, models=None,
                       options=None, scenes=None, client=None, n_workers=None, resume: bool = True,
                       progress: bool | str | None = None, log=None) -> dict:
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
        checked once before any job runs (:func:`~.engine.check_models`).
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
    out = check_output(output)
    oracle = seed_mode(oracle_seed, models)
    dataset = read_lerf_mask(data_dir, scenes_dir, scenes)
    return evaluate_scenes(dataset, out, oracle_seed=oracle, models=models, options=options, client=client,
                           n_workers=n_workers, resume=resume, progress=progress, log=log,
                           protocol={"dataset": "LERF-Mask", "gt": "grey > 128"})


