"""Stage 1 (project environment): the procedural scene the conformance run works on.

Writes into WORK/scene/: ``scene.ply`` and ``cameras.json`` (the reference
camera) for ``seed2gs extract``, ``reference.png`` (the reference view),
``clip.npz`` (a 5-frame clip: the reference view then 4 orbit views, float
RGB in [0, 1]) and ``seed.npy`` (the true mask of one object in the
reference view, the tracker's seed). The torch side reads only these
files, so both sides see identical pixels.

Usage: python tools/conformance/scene.py WORK
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

WIDTH, HEIGHT = 320, 240
OBJECT = "box"


def _raster():
    try:  # the operator-core redesign moves the rasterizer to seed2gs_inverse.raster
        from seed2gs_inverse.raster import build_operator, render
    except ImportError:
        from seed2gs_inverse.operators.render import build_operator, render
    return build_operator, render


def main(work: Path) -> None:
    from seed2gs_inverse.io import write_cameras, write_scene
    from seed2gs_inverse.synthetic import make_scene

    build_operator, render = _raster()
    out = work / "scene"
    out.mkdir(parents=True, exist_ok=True)
    syn = make_scene(seed=0)
    ref = syn.reference_camera(WIDTH, HEIGHT)
    orbit = syn.orbit_cameras(8, WIDTH, HEIGHT)[1:5]   # 4 views following the reference
    frames = [np.clip(render(syn.scene, c).rgb, 0.0, 1.0).astype(np.float32) for c in [ref] + orbit]
    # 8-bit round trip: every stage (ours, transformers, sam2) sees the same uint8 pixels
    frames = [np.round(f * 255.0).astype(np.uint8) for f in frames]
    label = syn.label_of(OBJECT)
    truth = (syn.labels == label).astype(np.float32)
    seed = (build_operator(syn.scene, ref).W @ truth).reshape(ref.image_shape) > 0.5
    write_scene(out / "scene.ply", syn.scene)
    write_cameras(out / "cameras.json", [ref])
    cv2.imwrite(str(out / "reference.png"), frames[0][:, :, ::-1])
    np.savez(out / "clip.npz", frames=np.stack(frames))
    np.save(out / "seed.npy", seed)
    print(f"scene: {len(syn.scene)} Gaussians, reference {WIDTH}x{HEIGHT}, "
          f"seed object {OBJECT!r} ({int(seed.sum())} px), clip of {len(frames)} frames -> {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
