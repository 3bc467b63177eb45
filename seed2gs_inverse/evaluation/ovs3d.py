"""3D-OVS layout (Liu et al., "Weakly Supervised 3D Open-vocabulary Segmentation", NeurIPS 2023).

Dataset layout, as the official loader (``dataLoader/llff.py`` of
Kunhao-Liu/3D-OVS: its class docstring, ``read_classes_names`` and
``read_segmentation_maps``) reads it::

    DATA_DIR/<scene>/images/                           the images; their sorted order numbers the frames
    DATA_DIR/<scene>/segmentations/classes.txt         one class name per line
    DATA_DIR/<scene>/segmentations/<NN>/<class>.png    a mask of *every* class in annotated frame NN
    DATA_DIR/<scene>/sparse/                           COLMAP model (``sparse/0`` or ``sparse``)
    DATA_DIR/<scene>/poses_bounds.npy                  LLFF poses (not read: the COLMAP model has them)

The frame folder ``NN`` is image ``int(NN)`` of the sorted ``images/``
(the loader's ``idxes``, "the camera id"); its camera is the COLMAP camera
of that image. A mask pixel is the class where its grey level is 255: the
loader keeps ``(grey / 255.0).astype(int8)``, which is 1 only at 255. The
trained scenes are found in ``SCENE_DIR`` as for LERF-Mask.

Scoring is the LERF-Mask protocol of :mod:`.engine` (every class is one
query, extracted once and rendered into every annotated frame; IoU and
boundary IoU per frame, means over frames, classes, scenes). That is not
3D-OVS's own metric: the paper scores a semantic segmentation (one class per
pixel) by mIoU and accuracy. As a LERF-Mask query is scored only where it
has a mask, a class is scored only in the frames where its mask is not
empty, and a class empty in every frame is no query.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ValidationError
from .engine import (LerfScene, camera_at_size, check_output, evaluate_scenes, find_scene_file, image_stem,
                     read_gt_mask, read_scene_cameras, scene_names, seed_mode)

if TYPE_CHECKING:
    from ..camera import Camera

__all__ = ["read_3d_ovs", "evaluate_3d_ovs", "OVS_GT_THRESHOLD"]

#: Object where the grey level exceeds this: only 255 counts (module docstring).
OVS_GT_THRESHOLD = 254


def _classes(path: Path) -> list:
    """The sorted class names of ``classes.txt`` (as the loader sorts them); ValidationError when
    the file is not UTF-8, names no class or names one twice."""
    try:
        lines = path.read_text("utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise ValidationError(f"{path}: not a UTF-8 text file ({exc})") from None
    classes = [ln.strip() for ln in lines if ln.strip()]
    dup = sorted({c for c in classes if classes.count(c) > 1})
    if dup:
        raise ValidationError(f"{path}: class(es) listed twice: {dup}")
    if not classes:
        raise ValidationError(f"{path}: no class names")
    return sorted(classes)  # the loader sorts them


def _frame_camera(idx: int, images: list, cams: list, where: str) -> Camera:
    """The camera of image ``idx`` of the sorted ``images/`` (else of the sorted camera names)."""
    if images:
        if idx >= len(images):
            raise ValidationError(f"{where}: frame {idx} but images/ holds only {len(images)} images")
        name = images[idx]
        for c in cams:
            if c.name == name or image_stem(c.name or "") == image_stem(name):
                return c
        raise ValidationError(f"{where}: image {name} (frame {idx}) has no camera in the COLMAP model")
    if idx >= len(cams):
        raise ValidationError(f"{where}: frame {idx} but the scene has only {len(cams)} cameras")
    return cams[idx]


def read_3d_ovs(data_dir, scenes_dir, scenes=None) -> list:
    """The scenes of a 3D-OVS style dataset (layout in the module docstring).

    Parameters
    ----------
    data_dir : path
        Holds one folder per scene with ``segmentations/classes.txt``.
    scenes_dir : path
        Holds the trained scenes.
    scenes : list of str, optional
        Only these scenes (default: every folder with ``segmentations/classes.txt``).

    Returns
    -------
    list of LerfScene
        ``queries``: the classes with a non-empty mask in some frame;
        ``frames``: the annotated frames with a non-empty mask; ``gt``: the
        non-empty masks only.

    Raises
    ------
    ValidationError
        A bad ``classes.txt``, a frame folder that is no image number, a
        missing class mask, masks of one frame that differ in size, a frame
        without camera, or a scene whose masks are all empty.
    """
    data_dir, scenes_dir = Path(data_dir), Path(scenes_dir)
    names = scene_names(data_dir, scenes_dir, scenes, "segmentations/classes.txt",
                         "<scene>/segmentations/classes.txt (3D-OVS layout)")
    out = []
    for name in names:
        root = data_dir / name
        seg = root / "segmentations"
        classes = _classes(seg / "classes.txt")
        # hidden folders (.ipynb_checkpoints) are no frame; a frame is ASCII digits (str.isdigit takes "²")
        folders = sorted((p for p in seg.iterdir() if p.is_dir() and not p.name.startswith(".")),
                         key=lambda p: p.name)
        bad = [p.name for p in folders if not re.fullmatch(r"[0-9]+", p.name)]
        if bad:
            raise ValidationError(f"{seg}: frame folders must be image numbers (NN), found {bad}")
        if not folders:
            raise ValidationError(f"{seg}: no frame folders")
        folders.sort(key=lambda p: int(p.name))
        cams = sorted(read_scene_cameras(root, scenes_dir, name), key=lambda c: c.name or "")
        # the images in name order, as the official loader lists them; hidden files (.DS_Store) are no image
        images = sorted(p.name for p in (root / "images").iterdir()
                        if p.is_file() and not p.name.startswith(".")) if (root / "images").is_dir() else []
        gt, cameras, queries, frames = {}, {}, set(), []
        for fd in folders:
            f, shape = fd.name, None
            for c in classes:
                p = fd / f"{c}.png"
                if not p.is_file():
                    raise ValidationError(f"{p}: missing; every frame folder holds a mask of every class "
                                          f"in {seg / 'classes.txt'}")
                m = read_gt_mask(p, OVS_GT_THRESHOLD)
                if shape is not None and m.shape != shape:
                    raise ValidationError(f"{fd}: masks of one frame differ in size ({p.name} is "
                                          f"{m.shape[1]}x{m.shape[0]}, others {shape[1]}x{shape[0]})")
                shape = m.shape
                if m.any():
                    gt[(f, c)] = p
                    queries.add(c)
            if any(k[0] == f for k in gt):
                frames.append(f)
                cameras[f] = camera_at_size(_frame_camera(int(f), images, cams, f"{fd}"), shape, f"{fd}")
        if not queries:
            raise ValidationError(f"{seg}: every mask is empty (object pixels are 255)")
        out.append(LerfScene(name, find_scene_file(scenes_dir, name), frames, sorted(queries), cameras, gt,
                             gt_threshold=OVS_GT_THRESHOLD))
    return out


def evaluate_3d_ovs(data_dir, scenes_dir, output, *, oracle_seed: bool | None = None, models=None,
                    options=None, scenes=None, client=None, n_workers=None, resume: bool = True,
                    progress: bool | str | None = None, log=None) -> dict:
    """:func:`~seed2gs_inverse.evaluation.evaluate_lerf_mask` on a 3D-OVS style dataset.

    Parameters and return value as ``evaluate_lerf_mask``; the dataset is
    read by :func:`read_3d_ovs`, each class is a query (its name the text of
    a text query) and ``report.json``'s ``protocol`` says how it differs
    from 3D-OVS's own metric.
    """
    out = check_output(output)
    oracle = seed_mode(oracle_seed, models)
    dataset = read_3d_ovs(data_dir, scenes_dir, scenes)
    return evaluate_scenes(dataset, out, oracle_seed=oracle, models=models, options=options, client=client,
                           n_workers=n_workers, resume=resume, progress=progress, log=log,
                           protocol={"dataset": "3D-OVS", "gt": "grey == 255",
                                     "scored": "each class as one object, in the frames where its mask is "
                                               "not empty (not 3D-OVS's semantic-segmentation mIoU)"})
