"""What a fused forward-BCE-adjoint sweep would save over the solver's evaluation (a measurement, not a feature).

weighted_bce evaluates its loss and gradient as two scipy passes over the
stack (``A q`` and ``A^T g``) with the per-pixel BCE in numpy between them.
Each weight is read twice. A sweep that, row by row, forms ``pred_u = W_u q``,
the BCE and ``g_u``, and adds ``W_u^T g_u`` at once reads each weight once.
It needs a compiled kernel, which ``solvers/`` may not import (the layers of
``docs/architecture.md``), so this benchmark writes one in Numba *here* to measure the
gain before anyone decides where such a kernel could live.

Scene and stack: bench_speed's extraction (``_common.default_extraction``:
the firepit with the unicorn, default settings). Printed, each the median of repeated runs on that stack,
with the load average:

* one forward and one transposed pass (the baseline of ``bench_speed``);
* the solver's evaluation as it runs today (``BCEObjective`` at a fixed
  ``q``: the forward pass, the numpy per-pixel BCE, the transposed pass);
* the fused sweep on the same two runs of views on two threads, for the
  default objective (binary masks, literal prediction ``p = A q``);
* the loss and gradient of the sweep against today's (relative error).

Usage::

    python benchmarks/bench_fused_bce.py [--repeat 15]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numba import njit
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import default_extraction, load_average, median_time  # noqa: E402

from seed2gs_inverse import _threads  # noqa: E402
from seed2gs_inverse.operators import _passes  # noqa: E402
from seed2gs_inverse.solvers._common import prepare  # noqa: E402
from seed2gs_inverse.solvers.weighted_bce import BCEObjective  # noqa: E402


@njit(nogil=True, cache=False)
def _sweep(indptr, indices, data, q, rows, sigma, shift, c, eps, out, rcs):
    """Rows ``rows`` of one view: ``out += W^T g`` with ``g`` from ``p = W q``; the clipped ``r`` into ``rcs``.

    The logarithms of the loss are left to numpy afterwards (one vectorised
    pass over ``rcs``): a scalar ``log`` per row costs more than the sweep saves.
    """
    for k in range(rows.size):
        u = rows[k]
        lo, hi = indptr[u], indptr[u + 1]
        acc = np.float32(0.0)
        for j in range(lo, hi):  # float32 sums in row order, as scipy's csr_matvec
            acc += data[j] * q[indices[j]]
        r = sigma[k] * float(acc) + shift[k]
        rc = min(max(r, eps), 1.0 - eps)
        rcs[k] = rc
        if rc == r:
            g = np.float32(c[k] / rc)
            for j in range(lo, hi):
                out[indices[j]] += data[j] * g


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=15)
    args = p.parse_args(argv)
    extraction = default_extraction("bench_fused_bce")
    if extraction is None:
        return 0
    scene, ex = extraction
    stack, masks = ex.operators, ex.masks
    problem = prepare(stack, masks, ex.lift.g0)
    obj = BCEObjective(problem)
    if not obj.binary:
        print("bench_fused_bce: the masks are not binary; the sweep here covers binary targets only. Skipped.")
        return 0
    n, views = problem.n_gaussians, len(stack)
    omega = np.ones(views)
    rng = np.random.default_rng(0)
    q = np.clip(problem.prior + 0.3 * rng.random(n), 0.05, 0.95)
    q32 = q.astype(np.float32)

    # Per view: its usable rows (local), the constants of r = sigma p + shift and c = -sigma w.
    offsets = stack.row_offsets()
    y = problem.y.astype(np.float64)
    per_view = []
    for v in range(views):
        lo, hi = np.searchsorted(obj.rows, [offsets[v], offsets[v + 1]])
        rows = obj.rows[lo:hi]
        yr = y[rows]
        sigma = 2.0 * yr - 1.0
        w = omega[v] * (1.0 if obj.s is None else obj.s[lo:hi]) / obj.Z  # s None: unit pixel weights
        per_view.append(((rows - offsets[v]).astype(np.int64), sigma, 1.0 - yr, -sigma * w))
    mats = [vw.W for vw in stack.views]
    halves = _passes._halves(mats)
    eps = obj.eps

    rcs = [np.empty(pv[0].size) for pv in per_view]

    def fused():
        outs = [np.zeros(n, np.float32) for _ in halves]
        sums = [0.0, 0.0]

        def run(k):
            for i in halves[k]:
                W = mats[i]
                rows, sigma, shift, c = per_view[i]
                _sweep(W.indptr, W.indices, W.data, q32, rows, sigma, shift, c, eps, outs[k], rcs[i])
                sums[k] += float(np.log(rcs[i]).sum())

        _threads.run_both(run, True)
        return -(sums[0] + sums[1]) / obj.Z, outs[0] + outs[1]

    r = rng.random(stack.shape[0]).astype(np.float32)
    with threadpool_limits(limits=1, user_api="blas"):
        fused()  # compile
        loss_ref, grad_ref = obj.loss_grad_q(q, omega)
        obj._q_last = None
        loss_f, grad_f = fused()
        t_fwd = median_time(lambda: stack.matvec(q32), args.repeat)
        t_adj = median_time(lambda: stack.rmatvec(r), args.repeat)

        def today():
            obj._q_last = None  # no reuse: a fresh point each time, as in the optimiser
            return obj.loss_grad_q(q, omega)

        t_today = median_time(today, args.repeat)
        t_fused = median_time(fused, args.repeat)
    two = t_fwd + t_adj
    err_g = float(np.abs(grad_f - grad_ref).max() / max(np.abs(grad_ref).max(), 1e-300))
    print(f"stack: {views} views, {stack.shape[0]:,} pixels x {n:,} Gaussians, nnz {stack.nnz:,}; "
          f"{obj.rows.size:,} usable pixels")
    print(f"two passes: A q {1e3 * t_fwd:.2f} ms + A^T r {1e3 * t_adj:.2f} ms = {1e3 * two:.2f} ms")
    print(f"today's evaluation (passes + numpy BCE): {1e3 * t_today:.2f} ms = {t_today / two:.2f}x two passes")
    print(f"fused sweep (two threads): {1e3 * t_fused:.2f} ms = {t_fused / two:.2f}x two passes "
          f"({t_fused / t_today:.2f}x the time of today's)")
    print(f"agreement: loss rel. error {abs(loss_f - loss_ref) / abs(loss_ref):.1e}, gradient max rel. error "
          f"{err_g:.1e}")
    print(f"load average at the end {load_average():.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
