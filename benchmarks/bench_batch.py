"""Batch extraction throughput: sequential vs a 1-worker and a 2-worker Dask cluster.

8 jobs over 2 scenes: 4 box prompts on the real firepit scene
(``firepit_562k_sh0.ply``, ``overview`` camera: fire pit, table, two chairs)
and 4 prompts (mask, box, point, box) on a procedural scene written to a
temporary folder, run three ways in the same process:

1. sequentially in this process (``extract_many(jobs, "sequential")``, no Dask),
2. on an embedded ``LocalCluster`` with 1 worker (as many threads as cores,
   like the sequential run: Dask's own overhead),
3. on an embedded ``LocalCluster`` with 1 worker of one thread (what each
   of 2 workers gets on 2 cores),
4. on an embedded ``LocalCluster`` with 2 workers,
5. (``--modes ...,2x2``) on 2 workers of two threads each: oversubscribed,
   so that one worker's single-threaded phases leave its core to the other.

``--jobs N`` keeps the first N of the 8 jobs (the firepit's first).
``--end-to-end seq,2,auto`` instead times ``seed2gs batch`` itself, in a
fresh process per layout, as a user runs it: ``--sequential``,
``--workers 2``, and no option (the layout the command chooses, whose
printed line is shown); these times include the cluster's start, every
worker's imports and the scene reads, which decide the default layout
(:func:`seed2gs_inverse.batch.choose_layout`).

The sequential run already uses both cores (the rasterizer's parallel
loops, the two-thread sparse passes), so 2 one-thread workers can beat it
at most by ``2 x (sequential wall) / (one-thread worker's wall)``; the
summary prints that bound next to the measured speed-up, and the 2-worker
speed-up over the one-thread worker (how the cluster itself scales).

Before each timed run one tiny job warms the workers (imports, Numba's
cached kernels); cluster start and warm-up are printed apart. Printed per
mode: wall time, jobs per minute, speed-up over sequential, Dask's overhead
per job (wall time x workers minus the time the tasks themselves took, per
job: scheduling, transfers, result handling; with 2 workers it also holds
the time one worker waits for the other's last job), scene reads per
worker and peak memory per worker, and whether every job's q equals the
sequential one bit for bit. The machine load (1-minute load average) is
printed before and after each run: on a shared machine the ratios move with it.

Usage: ``python benchmarks/bench_batch.py [--views 12] [--n-per-object 3000] [--jobs N]
[--end-to-end seq,2,auto]``
(needs ``../shared/data`` or ``$SEED2GS_DATA``; exits 0 with a message when
absent). ``NUMBA_NUM_THREADS`` should be unset (or the core count) so that the
sequential run may use every core too.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numba
import numpy as np

import seed2gs_inverse as sgi
from seed2gs_inverse.batch import Job, batch_client, extract_many, resolve_layout
from seed2gs_inverse.io import write_cameras, write_scene
from seed2gs_inverse.synthetic import make_scene, render_label_masks

DATA = Path(os.environ.get("SEED2GS_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))

# Boxes (x0, y0, x1, y1) in the 960x540 overview camera of firepit_cameras.json.
FIREPIT_BOXES = {"fire-pit": (415, 250, 535, 338), "table": (535, 278, 645, 368),
                 "chair-front": (470, 355, 578, 450), "chair-right": (660, 330, 840, 440)}


def _load() -> str:
    return "load average " + "/".join(f"{v:.1f}" for v in os.getloadavg()) + " (1/5/15 min)"


def make_jobs(tmp: Path, views: int, n_per_object: int):
    s = make_scene(seed=0, n_per_object=n_per_object)
    write_scene(tmp / "procedural.ply", s.scene)
    cam = s.reference_camera(640, 480)
    write_cameras(tmp / "procedural_cams.json", [cam])
    sphere = render_label_masks(s.scene, [cam], s.object_mask("sphere"))[0] > 0.5
    cv2.imwrite(str(tmp / "sphere.png"), sphere.astype(np.uint8) * 255)

    def box_of(label):
        m = render_label_masks(s.scene, [cam], s.object_mask(label))[0] > 0.5
        ys, xs = np.nonzero(m)
        return [int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1], (float(np.median(xs)),
                                                                                       float(np.median(ys)))

    opts = {"n_views": views}
    fp, fc = DATA / "firepit_562k_sh0.ply", f"{DATA / 'firepit_cameras.json'}:overview"
    jobs = [Job(f"firepit-{k}", fp, fc, sgi.BoxPrompt(b), opts, figure=False) for k, b in FIREPIT_BOXES.items()]
    pc = str(tmp / "procedural_cams.json")
    box_box, _ = box_of("box")
    can_box, _ = box_of("can 1")
    _, cup_click = box_of("cup")
    jobs += [Job("proc-sphere-mask", tmp / "procedural.ply", pc, sgi.MaskPrompt(str(tmp / "sphere.png")), opts,
                 figure=False),
             Job("proc-box-box", tmp / "procedural.ply", pc, sgi.BoxPrompt(box_box), opts, figure=False),
             Job("proc-cup-point", tmp / "procedural.ply", pc, sgi.PointPrompt([cup_click]), opts, figure=False),
             Job("proc-can-box", tmp / "procedural.ply", pc, sgi.BoxPrompt(can_box), opts, figure=False)]
    # The warm-up job has its own tiny scene, so the timed run's scene reads are all counted.
    w = make_scene(seed=1, n_per_object=40)
    write_scene(tmp / "warm.ply", w.scene)
    wcam = w.reference_camera(96, 72)
    warm = Job("warm-up", tmp / "warm.ply", wcam,
               sgi.MaskPrompt(render_label_masks(w.scene, [wcam], w.object_mask("sphere"))[0] > 0.5),
               {"n_views": 2}, figure=False)
    return jobs, warm, len(s.scene)


def run_mode(label, jobs, warm, out: Path, n_workers, threads=None):
    print(f"\n== {label}  [{_load()}]", flush=True)
    t0 = time.perf_counter()
    with batch_client("sequential" if n_workers is None else None, n_workers=n_workers,
                      threads_per_worker=threads) as c:
        t_start = time.perf_counter() - t0
        where = "sequential" if c is None else c
        t0 = time.perf_counter()
        w = extract_many([warm], where, progress=False)
        t_warm = time.perf_counter() - t0
        assert w[0].ok, w[0].error
        if c is not None:
            threads = c.run(lambda: os.environ.get("NUMBA_NUM_THREADS"))
            print(f"cluster start {t_start:.1f} s, warm-up {t_warm:.1f} s; NUMBA_NUM_THREADS per worker: "
                  f"{sorted(threads.values())}")
        else:
            print(f"warm-up {t_warm:.1f} s; numba threads {numba.get_num_threads()}")
        t0 = time.perf_counter()
        res = extract_many(jobs, where, output=out, resume=False, progress=False)
        wall = time.perf_counter() - t0
    failed = [r for r in res if not r.ok]
    for r in failed:
        print(f"  FAILED {r.name}: {r.error}")
    busy = sum(r.total_seconds for r in res)
    n_w = 1 if n_workers is None else n_workers
    per_worker = defaultdict(lambda: {"jobs": 0, "reads": [], "peak": 0.0})
    for r in res:
        pw = per_worker[r.worker]
        pw["jobs"] += 1
        if not r.scene_cached and r.n_gaussians is not None:
            pw["reads"].append(Path(r.scene).stem)
        pw["peak"] = max(pw["peak"], r.peak_rss_mb)
    what = "overhead" if n_w == 1 else "overhead + idle workers"
    print(f"wall {wall:.1f} s for {len(jobs)} jobs = {60 * len(jobs) / wall:.2f} jobs/min; task time "
          f"{busy:.1f} s; {what} per job {(wall * n_w - busy) / len(jobs):.2f} s "
          f"(wall x {n_w} worker(s) - task time)  [{_load()}]")
    for wk, pw in sorted(per_worker.items()):
        print(f"  worker {wk}: {pw['jobs']} jobs, scene reads {len(pw['reads'])} ({', '.join(pw['reads'])}), "
              f"peak memory {pw['peak']:.0f} MiB")
    for r in res:
        print(f"    {r.name:<18} {r.total_seconds:6.1f} s  read {r.seconds.get('read', 0):5.2f}  "
              f"operators {r.seconds.get('operators', 0):5.1f}  solve {r.seconds.get('solve', 0):5.1f}  "
              f"{r.n_selected} selected  on {r.worker}")
    return {"wall": wall, "busy": busy, "results": res, "n_workers": n_w}


def write_jobs_file(jobs, path: Path) -> None:
    """``jobs`` as a JSON jobs file for ``seed2gs batch`` (the layout of a jobs.toml)."""
    rows = []
    for j in jobs:
        d = j.to_dict()
        row = {"name": j.name, "scene": os.fspath(j.scene), "camera": d["camera"], "options": d["options"],
               "figure": j.figure}
        prompt = d["prompt"]
        row.update({"mask": prompt["mask"]} if prompt["kind"] == "mask" else {"box": prompt["box"]}
                   if prompt["kind"] == "box" else {"point": prompt["points"]})
        rows.append(row)
    path.write_text(json.dumps({"jobs": rows}, indent=1))


def run_end_to_end(jobs, tmp: Path, layouts) -> None:
    """Time ``seed2gs batch`` in a fresh process per layout; check that every layout gives the same q."""
    flags = {"seq": ["--sequential"], "2": ["--workers", "2"], "auto": []}
    jobs_file = tmp / "jobs.json"
    write_jobs_file(jobs, jobs_file)
    walls = {}
    for m in layouts:
        out = tmp / f"e2e_{m}"
        print(f"\n== seed2gs batch {' '.join(flags[m]) or '(default layout)'}  [{_load()}]", flush=True)
        t0 = time.perf_counter()
        run = subprocess.run([sys.executable, "-m", "seed2gs_inverse", "batch", str(jobs_file), "-o", str(out),
                              "--no-progress", *flags[m]], capture_output=True, text=True)
        walls[m] = time.perf_counter() - t0
        said = [ln for ln in run.stderr.splitlines() if ln.startswith("batch: ")]
        print(f"wall {walls[m]:.1f} s, exit {run.returncode}; {said[0] if said else 'no layout line'}  [{_load()}]")
        if run.returncode != 0:
            print(run.stdout + run.stderr)
    print("\n== summary (end to end)")
    ref = layouts[0]
    for m in layouts:
        differ = [j.name for j in jobs if (tmp / f"e2e_{m}" / j.name / "q.npy").is_file()
                  and not np.array_equal(np.load(tmp / f"e2e_{m}" / j.name / "q.npy"),
                                         np.load(tmp / f"e2e_{ref}" / j.name / "q.npy"))]
        print(f"{m:>4}: {walls[m]:.1f} s" + (f", x{walls[ref] / walls[m]:.2f} over {ref}; q identical: "
                                             f"{'NO (' + ', '.join(differ) + ')' if differ else 'yes'}"
                                             if m != ref else ""))
    print(f"[{_load()}]")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=12, help="views per VAAS clip (default 12)")
    p.add_argument("--n-per-object", type=int, default=3000, help="procedural scene size (default 3000)")
    p.add_argument("--modes", default="seq,1,1t,2",
                   help="which runs: seq, 1, 1t, 2, and 2x2 (2 workers of two threads each, not run by default); "
                        "default seq,1,1t,2")
    p.add_argument("--jobs", type=int, default=8, help="run the first N of the 8 jobs (default 8)")
    p.add_argument("--end-to-end", default=None, metavar="seq,2,auto",
                   help="time the seed2gs batch command per layout instead (fresh processes, cluster start "
                        "included): seq, 2 (workers) and auto (no option: the command's choice)")
    args = p.parse_args(argv)
    modes = [m.strip() for m in args.modes.split(",")]
    if not 1 <= args.jobs <= 8:
        p.error("--jobs must be between 1 and 8")
    e2e = None if args.end_to_end is None else [m.strip() for m in args.end_to_end.split(",")]
    if e2e is not None and (not e2e or any(m not in ("seq", "2", "auto") for m in e2e)):
        p.error("--end-to-end takes a comma-separated list of seq, 2 and auto")
    known = {"seq": ("sequential (this process, no Dask)", None, None),
             "1": ("LocalCluster, 1 worker", 1, None),
             "1t": ("LocalCluster, 1 worker of one thread", 1, 1),
             "2": ("LocalCluster, 2 workers", 2, None),
             "2x2": ("LocalCluster, 2 workers of two threads each (oversubscribed)", 2, 2)}
    unknown = [m for m in modes if m not in known]
    if unknown:
        p.error(f"unknown mode(s) {unknown}; choose from {', '.join(known)}")
    if not (DATA / "firepit_562k_sh0.ply").is_file():
        print(f"bench_batch: real scenes not found in {DATA}; set SEED2GS_DATA. Skipped.")
        return 0
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
          f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'unset')}; {_load()}")
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmpdir:
        tmp = Path(tmpdir)
        jobs, warm, n_proc = make_jobs(tmp, args.views, args.n_per_object)
        jobs = jobs[:args.jobs]
        n_fire = sum(j.name.startswith("firepit") for j in jobs)
        print(f"{len(jobs)} jobs: {n_fire} on firepit (561,997 Gaussians, 960x540 overview), {len(jobs) - n_fire} "
              f"on a procedural scene ({n_proc} Gaussians, 640x480); {args.views} views per clip")
        print(resolve_layout(None, n_jobs=len(jobs)).describe(len(jobs)).replace("batch:", "default layout:"))
        if e2e is not None:
            run_end_to_end(jobs, tmp, e2e)
            return 0
        runs = {}
        for m in modes:
            label, n_workers, threads = known[m]
            runs[m] = run_mode(label, jobs, warm, tmp / f"out_{m}", n_workers, threads)
        print("\n== summary")
        base = runs.get("seq")
        for m, r in runs.items():
            line = f"{m:>4}: {60 * len(jobs) / r['wall']:.2f} jobs/min"
            if base is not None and m != "seq":
                line += f", speed-up over sequential x{base['wall'] / r['wall']:.2f}"
                differ = [a.name for a, b in zip(base["results"], r["results"])
                          if a.ok and b.ok and not np.array_equal(a.load_q(), b.load_q())]
                line += f", q identical to sequential: {'NO (' + ', '.join(differ) + ')' if differ else 'yes'}"
            if m != "seq":
                what = "Dask overhead" if r["n_workers"] == 1 else "Dask overhead + idle workers"
                line += f", {what} {(r['wall'] * r['n_workers'] - r['busy']) / len(jobs):.2f} s/job"
            print(line)
        if "1t" in runs and "2" in runs:
            one, two = runs["1t"]["wall"], runs["2"]["wall"]
            print(f"   2 workers over one one-thread worker: x{one / two:.2f} (2 at most)")
            if base is not None:
                bound = 2 * base['wall'] / one
                print(f"   bound on 2 one-thread workers over sequential: 2 x {base['wall']:.1f} s / {one:.1f} s = "
                      f"x{bound:.2f} (the sequential run's own two threads take the rest); reached "
                      f"{100 * base['wall'] / two / bound:.0f}% of it")
        print(f"[{_load()}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
