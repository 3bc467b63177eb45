"""A tiny dataset in the exact LERF-Mask layout, built from procedural scenes.

Two scenes, each with the trained-scene file a user would supply:

``blocks``  cameras in ``cameras.json``; frame folders named after cameras.
``shelf``   a COLMAP text model (``sparse/0``) of 16 images and frame folders
            ``0`` and ``1``: the test cameras of the 3DGS LLFF split (every
            8th image sorted by name), i.e. images 0 and 8.

Ground truth is the rendered object weight ``W(c) 1_object > 0.5`` of the
procedural labels, written as 0/255 PNGs. Everything is deterministic.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from seed2gs_inverse.io import write_cameras, write_scene
from seed2gs_inverse.scene import rotmat_to_quat
from seed2gs_inverse.synthetic import make_scene, render_label_masks

W, H = 96, 72


def _png(path: Path, mask: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(os.fspath(path), mask.astype(np.uint8) * 255)


def _colmap_text(d: Path, cams) -> None:
    """COLMAP sparse model (PINHOLE, text) of ``cams``; image names frame_XX.png."""
    d.mkdir(parents=True, exist_ok=True)
    lines_c, lines_i = [], []
    for i, c in enumerate(cams):
        intr = " ".join(repr(float(v)) for v in (c.fx, c.fy, c.cx, c.cy))
        lines_c.append(f"{i + 1} PINHOLE {c.width} {c.height} {intr}")
        pose = " ".join(repr(float(v)) for v in (*rotmat_to_quat(c.rotation), *c.translation))
        lines_i.append(f"{i + 1} {pose} {i + 1} frame_{i:02d}.png")
        lines_i.append("")  # no 2D points
    (d / "cameras.txt").write_text("\n".join(lines_c) + "\n")
    (d / "images.txt").write_text("\n".join(lines_i) + "\n")


def build(root, names=None) -> dict:
    """Write ``root/data`` and ``root/scenes``; return what the answers need.

    ``names`` renames queries: ``{(scene, query): file stem}`` (the text a
    text-prompted evaluation sends to the grounder); the returned ``gt``
    uses the new names.

    Returns
    -------
    dict scene -> {"synthetic": SyntheticScene, "frames": {frame: Camera},
                   "truth": {frame: sphere mask}, "gt": {(frame, query): written mask}}
    """
    root = Path(root)
    data, scenes = root / "data", root / "scenes"
    out = {}
    # blocks: cameras.json, named frames
    s = make_scene(seed=3, n_per_object=60)
    cams = s.orbit_cameras(6, W, H, elevation_deg=40.0)
    (data / "blocks").mkdir(parents=True)
    scenes.mkdir(parents=True)
    write_cameras(data / "blocks" / "cameras.json", cams)
    write_scene(scenes / "blocks.ply", s.scene)
    frames = {c.name: c for c in cams[1:4]}
    truth = {f: render_label_masks(s.scene, [c], s.object_mask("sphere"))[0] > 0.5 for f, c in frames.items()}
    gt = {}
    for k, f in enumerate(frames):
        gt[(f, "sphere")] = truth[f]
        # "sphere top": the truth in the seed frame (so the extraction is the
        # same), only the rows above the mask's middle row in the others.
        top = truth[f].copy()
        if k > 0:
            rows = np.flatnonzero(truth[f].any(axis=1))
            top[(rows[0] + rows[-1]) // 2:] = False
        gt[(f, "sphere top")] = top
    names = dict(names or {})
    gt = {(f, names.get(("blocks", q), q)): m for (f, q), m in gt.items()}
    for (f, q), m in gt.items():
        _png(data / "blocks" / "test_mask" / f / f"{q}.png", m)
    out["blocks"] = {"synthetic": s, "truth": truth, "gt": gt, "frames": frames}
    # shelf: COLMAP model, index frames
    s2 = make_scene(seed=6, n_per_object=60)
    cams2 = s2.orbit_cameras(16, W, H, elevation_deg=35.0)
    _colmap_text(data / "shelf" / "sparse" / "0", cams2)
    (scenes / "shelf" / "point_cloud" / "iteration_7000").mkdir(parents=True)
    write_scene(scenes / "shelf" / "point_cloud" / "iteration_7000" / "point_cloud.ply", s2.scene)
    frames2 = {"0": cams2[0], "1": cams2[8]}
    truth2 = {f: render_label_masks(s2.scene, [c], s2.object_mask("sphere"))[0] > 0.5 for f, c in frames2.items()}
    gt2 = {(f, names.get(("shelf", "sphere"), "sphere")): m for f, m in truth2.items()}
    for (f, q), m in gt2.items():
        _png(data / "shelf" / "test_mask" / f / f"{q}.png", m)
    out["shelf"] = {"synthetic": s2, "truth": truth2, "gt": gt2, "frames": frames2}
    return out
