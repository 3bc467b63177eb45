"""Speed of one extraction next to same-run baselines.

Scene: the firepit (562k Gaussians) with the unicorn composited at pose 0 of
``bench_extract.py`` (the seed is the truth rendered into the overview
camera, 960x540). Each repeat runs ``extract()`` once and measures, in the
same run and on the same machine state:

* the baselines: one 960x540 render of the overview camera, and one sparse
  pass ``A q`` and one transposed pass ``A^T r`` over the extraction's own
  operator stack (what every solver iteration costs at least);
* per-stage seconds of the extraction and the ratio extraction / render;
  the same ratio in process CPU seconds (``time.process_time``) is printed
  beside it: on a shared machine other processes take the cores from both
  at different moments, which moves the wall ratio far more than the CPU
  one (with ``NUMBA_NUM_THREADS=1`` the two agree on a quiet machine);
* the solve: weighted_bce ms per iteration (all of the method's own
  seconds over its iterations: the set-up, i.e. the objective, the start
  and the first view weights, included) and per function evaluation
  against two passes, the set-up apart, its iteration and evaluation
  counts, and its time per iteration split into the sparse products inside
  the solve, the per-pixel work, the set-up and the rest (L-BFGS-B's own
  work and the glue), each in units of two passes (the graph regulariser
  that ``solve`` runs after the method is printed apart); voting's own
  seconds (the median of 15 calls, as the passes are medians of 15 samples)
  against one transposed pass, and the whole ``solve()`` call (validating
  the masks and the known weight ``A^T k`` that every method shares)
  beside it;
* the peak resident memory of the extraction (``VmHWM`` reset before it
  through ``/proc/self/clear_refs`` where Linux allows, else the process
  peak from ``getrusage``);
* held-out accuracy (five object-centric views the pipeline never rendered:
  2D mIoU / mBIoU, and 3D IoU of the membership), so a speed change that
  costs accuracy shows;
* the load average at the start and at the end.

Medians over ``--repeat`` runs are printed last (weighted_bce's ratio with its range over the
runs). ``--competing-load`` runs ``--repeat`` more extractions beside two
busy-loop processes (stopped by their process ids at the end), prints the
medians of those, and each stage's slow-down against the quiet runs beside a
render's (the aim: the operators stage slows no more than a render).

The scene, the baselines and the ``--set`` options come from ``_common.py``
(:func:`~_common.same_run_baselines` is the baseline measurement on its own,
which ``bench_extract.py`` prints too).

Usage::

    python benchmarks/bench_speed.py [--repeat 3] [--views N] [--competing-load] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import time

import numpy as np
from _common import (DATA, extract_kwargs, firepit_unicorn_problem, load_average, parse_set, reset_peak,
                     same_run_baselines)

from seed2gs_inverse import Camera
from seed2gs_inverse.metrics import boundary_iou, iou, membership_scores
from seed2gs_inverse.pipeline import ExtractSettings, extract
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.solvers import solve


def _peak_rss_gb(reset_ok: bool) -> float:
    """Peak resident memory in GiB: VmHWM since the reset, else the process peak."""
    if reset_ok:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 2 ** 20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20


def _held_out(center, up, forward, dist, w=480, h=270):
    """Five object-centric look-at cameras around ``center`` at ``dist`` that the pipeline never renders."""
    e1 = forward - (forward @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    cams = []
    for az, el in [(160, 25), (200, 45), (250, 35), (110, 55), (20, 30)]:
        a, e = np.radians(az), np.radians(el)
        d = np.cos(e) * (np.cos(a) * e1 + np.sin(a) * e2) + np.sin(e) * up
        cams.append(Camera.look_at(center + dist * d, center, up, 50, w, h))
    return cams


def _busy_load(n: int) -> list:
    """``n`` busy-loop processes (stopped by the caller)."""
    code = "while True:\n    pass\n"
    return [subprocess.Popen([sys.executable, "-c", code]) for _ in range(n)]


def _accuracy(scene, truth, up, cam, selected):
    """(held-out mIoU, mBIoU, 3D IoU) of the selection ``selected`` against ``truth``."""
    centre = scene.means[truth].astype(np.float64).mean(0)
    size = np.linalg.norm(scene.means[truth] - centre, axis=1).max()
    ious, bious = [], []
    for hc in _held_out(centre, up, cam.forward, 4.0 * size):
        hop = build_operator(scene, hc)
        t = (hop.W @ truth.astype(np.float32)).reshape(hop.image_shape) > 0.5
        if t.sum() < 20:
            continue
        pm = (hop.W @ selected.astype(np.float32)).reshape(hop.image_shape) > 0.5
        ious.append(iou(pm, t))
        bious.append(boundary_iou(pm, t))
    return float(np.mean(ious)), float(np.mean(bious)), float(membership_scores(selected, truth)["iou"])


def run_once(scene, truth, cam, seed, up, views: int, method: str, accuracy: bool, options=None) -> dict:
    """One extraction with its baselines, solver ratios, peak memory and (optionally) accuracy.

    ``options``: further ``extract()`` keywords (``--set``).
    """
    load0 = load_average()
    reset_ok = reset_peak()
    t0, c0 = time.perf_counter(), time.process_time()
    ex = extract(scene, cam, seed, n_views=views, method=method, progress=False, **(options or {}))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = _peak_rss_gb(reset_ok)
    stack, masks = ex.operators, ex.masks
    base = same_run_baselines(scene, cam, stack)
    two, adj = base["two_passes_s"], base["adjoint_s"]
    res = ex.result
    it = max(int(res.iterations), 1)
    nfev = int(res.info.get("function_evaluations", it))
    # voting takes milliseconds: the median of as many calls as the pass baselines take samples
    votes = [solve(stack, masks, method="voting") for _ in range(15)]
    vote = votes[0]
    vote_s = float(np.median([v.info["seconds_method"] for v in votes]))
    row = {"wall_s": wall, "cpu_s": cpu, "render_cpu_s": base["render_cpu_s"],
           "stages": dict(ex.seconds), "render_s": base["render_s"], "two_passes_s": two,
           "forward_s": base["forward_s"], "adjoint_s": adj, "nnz": base["nnz"], "n_views": len(stack),
           "iterations": int(res.iterations), "nfev": nfev, "solve_s": float(res.seconds),
           "method_s": float(res.info["seconds_method"]), "smoothing_s": float(res.info["seconds_smoothing"]),
           "ms_per_iter": 1e3 * res.info["seconds_method"] / it,
           "ms_per_feval": 1e3 * res.info["seconds_method"] / max(nfev, 1),
           "setup_ms": 1e3 * res.info.get("seconds_setup", float("nan")),
           "feval_over_two": (res.info["seconds_method"] - res.info.get("seconds_setup", float("nan")))
           / max(nfev, 1) / two,
           "iter_over_two": res.info["seconds_method"] / it / two,
           # the method's seconds after the set-up, split: sparse products, per-pixel work, the rest
           # (L-BFGS-B's own work, the reweighting, glue), each per iteration and in units of two passes
           **{f"{part}_over_two": float(sec) / it / two for part, sec in (
               ("passes", res.info.get("seconds_passes", np.nan)),
               ("pixels", res.info.get("seconds_pixels", np.nan)),
               ("setup", res.info.get("seconds_setup", np.nan)),
               ("rest", res.info["seconds_method"] - res.info.get("seconds_setup", np.nan)
                - res.info.get("seconds_passes", np.nan) - res.info.get("seconds_pixels", np.nan)))},
           "voting_s": vote_s, "voting_solve_s": float(np.median([v.seconds for v in votes])),
           "voting_over_adj": vote_s / adj,
           "peak_rss_gb": peak, "peak_is_extraction_only": reset_ok, "load_start": load0,
           "selected": int(ex.selected.sum()), "vote_selected": int(vote.selected().sum())}
    if accuracy:
        row["miou"], row["mbiou"], row["iou3d"] = _accuracy(scene, truth, up, cam, ex.selected)
    row["load_end"] = load_average()
    return row


def _split(r) -> str:
    """weighted_bce's seconds per iteration by part, in units of two passes of the same run."""
    return ("passes {passes_over_two:.2f} + per-pixel {pixels_over_two:.2f} + set-up {setup_over_two:.2f} "
            "+ optimiser and rest {rest_over_two:.2f}".format(**r))


def _print_row(k, r):
    """The lines of run ``k``."""
    st = r["stages"]
    acc = (f" | held-out mIoU {r['miou']:.3f} mBIoU {r['mbiou']:.3f} 3D IoU {r['iou3d']:.3f}"
           if "miou" in r else "")
    print(f"run {k}: extraction {r['wall_s']:.2f} s = {r['wall_s'] / r['render_s']:.1f} renders "
          f"(render {r['render_s']:.3f} s); CPU {r['cpu_s']:.2f} s = "
          f"{r['cpu_s'] / r['render_cpu_s']:.1f} renders' CPU ({r['render_cpu_s']:.3f} s) | "
          + ", ".join(f"{a} {b:.2f}" for a, b in st.items()))
    print(f"  stack {r['n_views']} views, nnz {r['nnz'] / 1e6:.1f} M: A q {1e3 * r['forward_s']:.1f} ms, "
          f"A^T r {1e3 * r['adjoint_s']:.1f} ms | weighted_bce {r['iterations']} it, {r['nfev']} evals, "
          f"{r['method_s']:.2f} s (+ regulariser {r['smoothing_s']:.2f} s), {r['ms_per_iter']:.1f} ms/it = "
          f"{r['iter_over_two']:.2f} x two passes (set-up {r['setup_ms']:.0f} ms; after it "
          f"{r['feval_over_two']:.2f} x two passes per evaluation) = {_split(r)} | "
          f"voting {1e3 * r['voting_s']:.1f} ms = "
          f"{r['voting_over_adj']:.2f} x one A^T pass (solve() {1e3 * r['voting_solve_s']:.1f} ms)")
    print(f"  peak RSS {'of the extraction' if r['peak_is_extraction_only'] else 'of the process'} "
          f"{r['peak_rss_gb']:.2f} GB | selected {r['selected']}{acc} | load {r['load_start']:.1f} -> "
          f"{r['load_end']:.1f}")
    sys.stdout.flush()


def _print_slowdown(quiet: list, loaded: list) -> None:
    """Print the medians' ratios, loaded over quiet: a render, the extraction and each stage."""
    def med(rows, key, stage=False):
        return float(np.median([r["stages"][key] if stage else r[key] for r in rows]))

    render = med(loaded, "render_s") / med(quiet, "render_s")
    ops = med(loaded, "operators", True) / max(med(quiet, "operators", True), 1e-9)
    stages = ", ".join(f"{k} {med(loaded, k, True) / max(med(quiet, k, True), 1e-9):.2f}x"
                       for k in quiet[0]["stages"] if med(quiet, k, True) >= 0.05)
    print(f"\nunder the competing load (medians, loaded over quiet): a 960x540 render {render:.2f}x, extraction "
          f"{med(loaded, 'wall_s') / med(quiet, 'wall_s'):.2f}x; stages: {stages} [aim: operators <= the render's "
          f"slow-down: {'met' if ops <= render else 'not met'}]")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--views", type=int, default=ExtractSettings().n_views,
                   help="views per VAAS clip (default: extract's)")
    p.add_argument("--method", default="weighted_bce")
    p.add_argument("--no-accuracy", action="store_true", help="skip the held-out scores")
    p.add_argument("--competing-load", action="store_true", help="also run beside two busy-loop processes and print the slow-downs")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="extract() keyword as in bench_extract.py, e.g. --set min_weight=0 (repeatable)")
    args = p.parse_args(argv)
    options = parse_set(args.set)
    if not (DATA / "firepit_562k_sh0.ply").is_file():
        print(f"bench_speed: real scenes not found in {DATA}; set SEED2GS_DATA. Skipped.")
        return 0
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'default')}, load average {load_average():.1f}")
    print(f"extract options: {options or 'defaults'}")
    scene, truth, cam, seed, up, first = firepit_unicorn_problem(args.views)
    print(f"first render of the process (includes kernel compilation when the cache is cold): {first:.2f} s")

    def runs(loaded: bool) -> list:
        busy = _busy_load(2) if loaded else []
        print(f"{'with' if busy else 'without'} a competing 2-process busy loop")
        out = []
        try:
            for k in range(args.repeat):
                out.append(run_once(scene, truth, cam, seed, up, args.views, args.method, not args.no_accuracy,
                                    extract_kwargs(options)))
                _print_row(k, out[-1])
        finally:
            for b in busy:
                b.kill()
                b.wait()
        return out

    # --competing-load: the quiet runs first, then the loaded ones, and how much each stage slowed
    quiet = runs(False)
    rows = runs(True) if args.competing_load else quiet
    if args.competing_load:
        _print_slowdown(quiet, rows)
    med = {k: float(np.median([r[k] for r in rows])) for k in rows[0] if isinstance(rows[0][k], (int, float))}
    stages = {k: float(np.median([r["stages"][k] for r in rows])) for k in rows[0]["stages"]}
    print(f"\nmedian of {len(rows)}: extraction {med['wall_s']:.2f} s = {med['wall_s'] / med['render_s']:.1f} x "
          f"one 960x540 render ({med['render_s']:.3f} s) [aim <= 12x on a quiet machine]; CPU {med['cpu_s']:.2f} s "
          f"= {med['cpu_s'] / med['render_cpu_s']:.1f} x the render's ({med['render_cpu_s']:.3f} s); per stage: "
          + ", ".join(f"{a} {b:.2f}" for a, b in stages.items()))
    spread = [r["iter_over_two"] for r in rows]
    print(f"  weighted_bce {med['ms_per_iter']:.1f} ms/it = {med['iter_over_two']:.2f} x two passes "
          f"({1e3 * med['two_passes_s']:.1f} ms; {min(spread):.2f}-{max(spread):.2f} over the runs; no aim: the "
          f"passes are bandwidth-bound), {med['iterations']:.0f} it, {med['nfev']:.0f} evals, "
          f"set-up {med['setup_ms']:.0f} ms, then {med['feval_over_two']:.2f} x two passes per evaluation; "
          f"per iteration {_split(med)}; "
          f"voting {med['voting_over_adj']:.2f} x one A^T pass [aim <= 1.2] "
          f"(solve() {1e3 * med['voting_solve_s']:.1f} ms); "
          f"peak RSS {med['peak_rss_gb']:.2f} GB "
          f"[aim <= 2]" + (f"; held-out mIoU {med['miou']:.3f} mBIoU {med['mbiou']:.3f} 3D IoU {med['iou3d']:.3f}"
                           if "miou" in med else ""))
    print(f"  load average {rows[0]['load_start']:.1f} at the start, {rows[-1]['load_end']:.1f} at the end "
          f"(2 cores; other work on the machine inflates wall times, the ratios less)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
