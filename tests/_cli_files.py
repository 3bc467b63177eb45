"""The procedural scene the command-line tests extract from, written to disk with its camera and seed mask."""

from __future__ import annotations

import cv2
import numpy as np

from seed2gs_inverse.io import write_cameras, write_scene
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.synthetic import make_scene


def write_cli_files(d) -> dict:
    """``make_scene(seed=0)`` as ``d/scene.ply``, its 128x96 reference camera as ``d/cameras.json`` (camera 0)
    and the true seed of object 1 as ``d/mask.png``.

    Returns ``{"dir", "syn", "cam", "truth", "seed", "box", "point"}``: the box is the seed's bounding box
    grown by 3 px (x0, y0, x1, y1), the point its median pixel.
    """
    syn = make_scene(seed=0)
    cam = syn.reference_camera(128, 96)
    write_scene(d / "scene.ply", syn.scene)
    write_cameras(d / "cameras.json", [cam])
    truth = syn.labels == 1
    seed = (build_operator(syn.scene, cam).W @ truth.astype(np.float32)).reshape(cam.image_shape) > 0.5
    cv2.imwrite(str(d / "mask.png"), seed.astype(np.uint8) * 255)
    ys, xs = np.nonzero(seed)
    return {"dir": d, "syn": syn, "cam": cam, "truth": truth, "seed": seed,
            "box": [int(xs.min()) - 3, int(ys.min()) - 3, int(xs.max()) + 4, int(ys.max()) + 4],
            "point": [int(np.median(xs)), int(np.median(ys))]}
