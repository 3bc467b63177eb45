"""``seed2gs demo``: the toolkit on a built-in procedural scene with known truth."""

from __future__ import annotations

import numpy as np

__all__ = ["register"]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo", help="run on a built-in procedural scene with a known object",
        description="Build the procedural scene of seed2gs_inverse.synthetic and print its summary.")
    p.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    p.set_defaults(func=run)


def _summary(syn) -> list[str]:
    scene, labels = syn.scene, np.asarray(syn.labels)
    lo, hi = scene.bounds()
    lines = [f"procedural scene: N = {len(scene)} Gaussians, SH degree {scene.sh_degree}",
             f"bounds: min {np.round(lo, 3).tolist()}  max {np.round(hi, 3).tolist()}",
             "objects:"]
    for lab in np.unique(labels):
        name = dict(syn.names).get(int(lab), "background" if lab == 0 else f"object {lab}")
        lines.append(f"  {int(lab):3d}  {name:<20s} {int(np.sum(labels == lab)):7d} Gaussians")
    return lines


def run(args) -> int:
    from ..synthetic import make_scene

    syn = make_scene(seed=args.seed)
    print("\n".join(_summary(syn)))
    return 0
