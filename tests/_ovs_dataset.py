"""A tiny dataset in the 3D-OVS layout (official dataLoader/llff.py), built from a procedural scene.

One scene ``room`` (the procedural scene of seed 6, 16 orbit cameras):

    data/room/images/frame_00.png ... frame_15.png      (1x1 placeholders: only their order matters)
    data/room/sparse/0/{cameras,images}.txt             COLMAP text model, image i = camera i
    data/room/segmentations/classes.txt                 lamp, rod, sphere, sphere top (shuffled)
    data/room/segmentations/{00,04,08,12}/<class>.png   every class in every frame
    scenes/room.ply

``sphere`` and ``rod`` are the rendered objects (``W(c) 1_object > 0.5``);
``sphere top`` is the sphere in frame 00 and only its upper half elsewhere;
``lamp`` is empty in every frame (not a query); the rod's mask is empty in
frame 04 (not scored there). Frame 08's ``sphere`` mask carries a block of
grey 200 away from the sphere: not object under 3D-OVS's rule (only 255).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from _lerf_dataset import H, W, _colmap_text, _png
from seed2gs_inverse.io import write_scene
from seed2gs_inverse.synthetic import make_scene, render_label_masks

FRAMES = ("00", "04", "08", "12")
GREY_BLOCK = (slice(2, 7), slice(2, 7))   # frame 08, sphere.png: grey 200 here


def build(root) -> dict:
    """Write ``root/data`` and ``root/scenes``; return ``{"truth": {(frame, class): mask}, "cameras": [...]}``.

    ``truth`` holds what each mask means (object pixels, the grey block left
    out), for every class and frame, empty masks included.
    """
    import cv2

    root = Path(root)
    scene_dir = root / "data" / "room"
    s = make_scene(seed=6, n_per_object=60)
    cams = s.orbit_cameras(16, W, H, elevation_deg=35.0)
    _colmap_text(scene_dir / "sparse" / "0", cams)
    (scene_dir / "images").mkdir(parents=True)
    for i in range(len(cams)):
        assert cv2.imwrite(str(scene_dir / "images" / f"frame_{i:02d}.png"), np.zeros((1, 1), np.uint8))
    (root / "scenes").mkdir(parents=True)
    write_scene(root / "scenes" / "room.ply", s.scene)
    seg = scene_dir / "segmentations"
    seg.mkdir()
    (seg / "classes.txt").write_text("sphere top\nsphere\nlamp\nrod\n")
    truth = {}
    for f in FRAMES:
        cam = cams[int(f)]
        sphere = render_label_masks(s.scene, [cam], s.object_mask("sphere"))[0] > 0.5
        rod = render_label_masks(s.scene, [cam], s.object_mask("rod"))[0] > 0.5
        top = sphere.copy()
        if f != FRAMES[0]:
            rows = np.flatnonzero(sphere.any(axis=1))
            top[(rows[0] + rows[-1]) // 2:] = False
        truth[(f, "sphere")] = sphere
        truth[(f, "sphere top")] = top
        truth[(f, "rod")] = rod if f != "04" else np.zeros_like(rod)
        truth[(f, "lamp")] = np.zeros_like(rod)
        for c in ("sphere", "sphere top", "rod", "lamp"):
            _png(seg / f / f"{c}.png", truth[(f, c)])
    # a grey (not 255) block in one mask: background for 3D-OVS
    p = seg / "08" / "sphere.png"
    img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    assert not img[GREY_BLOCK].any()
    img[GREY_BLOCK] = 200
    assert cv2.imwrite(str(p), img)
    return {"truth": truth, "cameras": cams, "synthetic": s}
