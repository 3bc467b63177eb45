"""Helpers shared by the benchmark scripts, so that no benchmark imports another.

* :func:`load_average`, :func:`median_time`: the machine's load and a median wall time;
* :func:`same_run_baselines`: the units an extraction's timings are read in
  (one render, one forward and one transposed pass over its stack), measured now;
* :func:`firepit_unicorn_problem`, :func:`default_extraction`: the real scene
  of ``bench_speed.py`` (the firepit with the unicorn composited on the patio)
  and its extraction with default settings;
* :func:`parse_set`, :func:`extract_kwargs`: the ``--set KEY=VALUE`` options;
* :func:`alone_alpha_share`: how opaque a part of an object is rendered by itself.

A script imports this module as ``_common`` (its own folder is first on
``sys.path``); ``seed2gs_inverse`` comes from ``sys.path`` as that script set
it up (``bench_extract.py`` puts this checkout first).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from seed2gs_inverse.frontend.model_free import GeometricTracker
from seed2gs_inverse.io import read_camera, read_scene
from seed2gs_inverse.pipeline import extract
from seed2gs_inverse.pipeline.up_axis import estimate_up
from seed2gs_inverse.raster import build_operator, render
from seed2gs_inverse.synthetic import compose, pose_on_point

REPO = Path(__file__).resolve().parents[1]
#: The shared data of ``bench_speed.py`` and the benchmarks built on its extraction.
DATA = Path(os.environ.get("SEED2GS_DATA", REPO.parent / "shared" / "data"))

#: bench_extract.py's pose 0: overview pixel on the patio floor, unicorn yaw (deg), height.
POSE0 = ((400, 470), 20.0, 0.8)


def reset_peak() -> bool:
    """Reset this process's peak resident size (VmHWM); False where Linux does not allow it."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def load_average() -> float:
    """The one-minute load average (NaN where the platform has none)."""
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return float("nan")


def median_time(fn, repeat: int, clock=time.perf_counter) -> float:
    """Median seconds of ``repeat`` calls of ``fn()`` on ``clock`` (wall by default; ``time.process_time``: CPU)."""
    times = []
    for _ in range(repeat):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return float(np.median(times))


def same_run_baselines(scene, camera, stack=None, repeat: int = 3) -> dict:
    """Baselines to print next to an extraction's timings, measured now.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
    camera : Camera
        The render baseline's camera (960x540 in the benchmarks).
    stack : OperatorStack, optional
        The extraction's own operators: adds one forward pass ``A q`` and one
        transposed pass ``A^T r`` (random float32 vectors), through the
        stack's own ``matvec`` / ``rmatvec`` (the path the solvers use).
    repeat : int
        The render is the median of ``repeat`` runs, each pass the median of
        at least 15 (alternating forward and transposed), after one warm-up.

    Returns
    -------
    dict
        ``render_s``, ``render_cpu_s`` (the render's process CPU seconds:
        what it costs apart from the time other processes take the cores
        from it), ``load``; with ``stack`` also ``forward_s``,
        ``adjoint_s``, ``two_passes_s``, ``nnz``.
    """
    render(scene, camera)  # warm-up (kernel compilation when the cache is cold)
    out = {"render_s": median_time(lambda: render(scene, camera), repeat),
           "render_cpu_s": median_time(lambda: render(scene, camera), repeat, clock=time.process_time),
           "load": load_average()}
    if stack is not None:
        rng = np.random.default_rng(0)
        q = rng.random(stack.shape[1]).astype(np.float32)
        r = rng.random(stack.shape[0]).astype(np.float32)
        stack.matvec(q)
        stack.rmatvec(r)
        # Passes take milliseconds: many alternating samples, so that a passing slowdown of the
        # machine does not set the unit every solver ratio is expressed in.
        fwd, adj = [], []
        for _ in range(max(repeat, 15)):
            fwd.append(median_time(lambda: stack.matvec(q), 1))
            adj.append(median_time(lambda: stack.rmatvec(r), 1))
        out["forward_s"], out["adjoint_s"] = float(np.median(fwd)), float(np.median(adj))
        out["two_passes_s"] = out["forward_s"] + out["adjoint_s"]
        out["nnz"] = int(stack.nnz)
    return out


def alone_alpha_share(scene, cameras, part, whole) -> tuple:
    """How opaque a part of an object is by itself: ``(share, worst_view)``.

    ``part`` and ``whole`` are (N,) bool over ``scene`` (``part`` within
    ``whole``). Each is rendered alone from every camera; ``share`` is the
    part's alpha summed over the pixels and cameras over the whole's, and
    ``worst_view`` the largest share of one camera. With ``part`` the
    object's unselected Gaussians this is what an extraction leaves behind
    of it, inner and back layers included (they carry no compositing weight
    while the object stands in front of them). An empty ``part`` gives
    ``(0.0, 0.0)``.
    """
    if not np.any(part):
        return 0.0, 0.0
    alone_part, alone_whole = scene.subset(part), scene.subset(whole)
    kept = np.array([float(render(alone_part, c).alpha.sum()) for c in cameras])
    full = np.array([float(render(alone_whole, c).alpha.sum()) for c in cameras])
    return float(kept.sum() / max(full.sum(), 1e-12)), float(np.max(kept / np.maximum(full, 1e-12)))


def firepit_unicorn_problem(views_arg):
    """``(scene, truth, camera, seed, up, first_render_s)``: the firepit with the unicorn at :data:`POSE0`.

    ``truth`` is the unicorn's (N,) bool membership, ``seed`` its (H, W) bool
    mask in the overview camera (``W(c) 1_object > 0.5``), ``up`` the
    patio's estimated up and ``first_render_s`` the first render's seconds
    (kernel compilation included when the cache is cold). ``views_arg`` is unused.
    """
    firepit = read_scene(DATA / "firepit_562k_sh0.ply")
    unicorn = read_scene(DATA / "unicorn_49k_sh3.ply")
    cam = read_camera(DATA / "firepit_cameras.json:overview")
    t0 = time.perf_counter()
    base = render(firepit, cam)
    first = time.perf_counter() - t0
    up = estimate_up(firepit, cam)
    (px, py), yaw, height = POSE0
    ray = np.array([(px + 0.5 - cam.cx) / cam.fx, (py + 0.5 - cam.cy) / cam.fy, 1.0])
    anchor = cam.rotation.T @ (ray * float(base.depth[py, px]) - cam.translation)
    pose = pose_on_point(unicorn, anchor, up, object_up=(0.0, -1.0, 0.0), height=height, yaw_deg=yaw,
                         quantile=0.01)
    scene, labels = compose(firepit, [(unicorn, pose)], remove_overlap=True)
    truth = labels == 1
    uv, _ = cam.project(scene.means[truth])
    x0, y0 = np.floor(np.nanmin(uv, 0)).astype(int) - 4
    x1, y1 = np.ceil(np.nanmax(uv, 0)).astype(int) + 4
    roi = (max(x0, 0), max(y0, 0), min(x1, cam.width), min(y1, cam.height))
    op = build_operator(scene, cam, roi=roi)
    seed = (op.W @ truth.astype(np.float32)).reshape(cam.image_shape) > 0.5
    return scene, truth, cam, seed, up, first


def default_extraction(name: str, views: int = 24):
    """``(scene, extraction)``: the firepit + unicorn scene of :func:`firepit_unicorn_problem` and its extraction with
    default settings, for benchmarks of the later stages on a real stack (``name``, the benchmark, heads
    the messages). Prints the machine line first; without the real scenes it prints that the benchmark
    is skipped and returns None."""
    if not (DATA / "firepit_562k_sh0.ply").is_file():
        print(f"{name}: real scenes not found in {DATA}; set SEED2GS_DATA. Skipped.")
        return None
    print(f"machine: {os.cpu_count()} CPUs, load average {load_average():.1f}")
    scene, _, cam, seed, _, _ = firepit_unicorn_problem(views)
    return scene, extract(scene, cam, seed, n_views=views, progress=False)


def parse_set(items) -> dict:
    """``--set KEY=VALUE`` options as a dict: values parsed as JSON when they can be, else kept as strings."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise SystemExit(f"--set needs KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def extract_kwargs(options: dict, true_up=None) -> dict:
    """``extract()`` keywords from ``--set`` options: ``tracker.NAME`` builds a GeometricTracker, ``up=truth``."""
    opts = {k: v for k, v in options.items() if not k.startswith("tracker.")}
    if isinstance(opts.get("up"), str) and opts["up"] == "truth":
        if true_up is None:
            raise SystemExit("--set up=truth: this benchmark has no true up")
        opts["up"] = true_up
    tracker_kw = {k[len("tracker."):]: v for k, v in options.items() if k.startswith("tracker.")}
    if tracker_kw:
        opts["tracker"] = GeometricTracker(**tracker_kw)
    return opts
