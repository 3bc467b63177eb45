"""The forward model of a frozen 3DGS scene as a sparse linear operator.

For one camera, alpha compositing of N Gaussians is linear in any
per-Gaussian quantity ``x``: pixel ``u`` shows ``sum_i w_i(u) x_i`` with
the compositing weight ``w_i(u) = alpha_i(u) T_i(u)`` (opacity times the
transmittance left in front of Gaussian i). ``sgi.build_operator`` renders
once and keeps those weights as ``W`` (CSR, pixels x Gaussians, rows in
row-major pixel order ``u = y * width + x``). This script checks the
identities that make ``W`` the renderer,

    W @ 1       == alpha              (accumulated opacity)
    W @ colors  == rgb                (black background)
    W @ z       == depth * alpha      (expected depth)
    <W x, y>    == <x, W^T y>         (the adjoint is right: dot test)

then uses a stack of views as a ``scipy.sparse.linalg.LinearOperator`` to
recover a per-Gaussian quantity from images with LSQR, and shows what
``min_weight`` (dropping tiny weights) trades for speed.

Run with no arguments on the procedural scene, or on a real one::

    python examples/operator_identities.py --scene firepit.ply --camera firepit_cameras.json:overview
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.sparse.linalg import lsqr

import seed2gs_inverse as sgi


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", help="scene file; default: the procedural scene")
    p.add_argument("--camera", help="camera FILE:NAME or FILE:INDEX (needed with --scene)")
    p.add_argument("--size", type=int, nargs=2, default=(128, 96), metavar=("W", "H"),
                   help="synthetic mode: image size (default 128 96)")
    p.add_argument("--scale", type=float, default=0.5,
                   help="with --scene: resolution factor of the camera (default 0.5)")
    p.add_argument("--views", type=int, default=8, help="synthetic mode: orbit views for the LSQR part (default 8)")
    args = p.parse_args(argv)
    if args.scene and not args.camera:
        p.error("--scene needs --camera FILE:NAME")
    return args


def report(name, got, want, tol):
    """Print the largest deviation of an identity and whether it holds to float32 precision."""
    err = float(np.max(np.abs(np.asarray(got, np.float64) - np.asarray(want, np.float64))))
    print(f"  {name:<28s} max |diff| = {err:.2e}  {'ok' if err <= tol else 'FAILED'}")
    return err <= tol


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.scene:
        scene = sgi.read_scene(args.scene)
        camera = sgi.read_camera(args.camera).scaled(args.scale)
        cams = [camera]  # one real view; LSQR below then fits what that view sees
    else:
        syn = sgi.make_scene(seed=0, sh_degree=0)  # degree 0: colours are view-independent
        scene = syn.scene
        cams = syn.orbit_cameras(args.views, *args.size)
        camera = cams[0]
    n = len(scene)
    print(f"{n} Gaussians, camera {camera.name!r} {camera.width}x{camera.height}")

    # -- one view: W and the rendering of the same pass ----------------------
    t0 = time.perf_counter()
    op = sgi.build_operator(scene, camera)
    W, r = op.W, op.rendering
    print(f"W: {W.shape[0]} pixels x {W.shape[1]} Gaussians, {W.nnz} non-zeros "
          f"({W.nnz / W.shape[0]:.1f} per pixel), built in {time.perf_counter() - t0:.2f} s")

    # Per-Gaussian colour and view depth as the rasterizer sees them in this view.
    proj = sgi.project_gaussians(scene, camera)
    ok = True
    print("identities (float32 precision):")
    ok &= report("W @ 1 == alpha", W @ np.ones(n, np.float32), r.alpha.ravel(), 1e-5)
    ok &= report("W @ colors == rgb", W @ proj.colors, r.rgb.reshape(-1, 3), 1e-5)
    # Relative tolerance for depth: the values scale with the scene.
    zmax = float(np.abs(r.depth).max()) or 1.0
    ok &= report("W @ z == depth * alpha (rel)", (W @ proj.depths) / zmax, (r.depth * r.alpha).ravel() / zmax, 1e-5)

    # Dot test: W and its adjoint (rmatvec) agree for random vectors. The
    # ViewOperator is a scipy LinearOperator: matvec returns the flat
    # (H*W,) rendering (op.image(x) the (H, W) picture), rmatvec takes one.
    rng = np.random.default_rng(0)
    x, y = rng.standard_normal(n), rng.standard_normal(op.n_pixels)
    lhs, rhs = float(np.vdot(op.matvec(x), y)), float(x @ op.rmatvec(y))
    rel = abs(lhs - rhs) / max(abs(lhs), abs(rhs))
    print(f"  dot test <Wx, y> = {lhs:.6g}, <x, W^T y> = {rhs:.6g}, relative diff {rel:.1e}  "
          f"{'ok' if rel < 1e-5 else 'FAILED'}")
    ok &= rel < 1e-5

    # -- many views: a LinearOperator, and an inverse problem ----------------
    # Recover each Gaussian's red channel from the red channel of the
    # rendered images: b = A g with A the stacked operators. Gaussians that
    # no pixel sees are not determined, so score only the well-seen ones.
    stack = sgi.OperatorStack([op] + [sgi.build_operator(scene, c) for c in cams[1:]])
    A = stack.as_linear_operator()
    g_true = proj.colors[:, 0].astype(np.float64)
    b = np.concatenate([v.rendering.rgb[..., 0].ravel() for v in stack])
    t0 = time.perf_counter()
    g, istop, itn = lsqr(A, b, atol=1e-8, btol=1e-8, iter_lim=300)[:3]
    seen = stack.column_sums() > 0.5
    print(f"LSQR on {len(stack)} views ({A.shape[0]}x{A.shape[1]}): {itn} iterations, "
          f"{time.perf_counter() - t0:.2f} s, relative residual {np.linalg.norm(A @ g - b) / np.linalg.norm(b):.1e}")
    print(f"  well-seen Gaussians (sum of weights > 0.5): {int(seen.sum())} of {n}; "
          f"median |g - g_true| there {np.median(np.abs(g - g_true)[seen]):.1e}")

    # -- min_weight: fewer non-zeros, W @ 1 falls short of alpha -------------
    # Each dropped entry is < min_weight, so per pixel
    # 0 <= alpha - W @ 1 <= (number dropped) * min_weight.
    print("min_weight trade-off (this view):")
    print(f"  {'min_weight':>10s} {'nnz':>10s} {'nnz %':>6s} {'max(alpha - W1)':>16s} {'matvec ms':>10s}")
    ones = np.ones(n, np.float32)
    for mw in (0.0, 1e-3, 1e-2, 5e-2):
        Wm = sgi.build_operator(scene, camera, min_weight=mw).W
        t0 = time.perf_counter()
        for _ in range(20):
            a = Wm @ ones
        ms = (time.perf_counter() - t0) / 20 * 1e3
        short = float(np.max(r.alpha.ravel() - a))
        print(f"  {mw:10g} {Wm.nnz:10d} {100 * Wm.nnz / W.nnz:6.1f} {short:16.2e} {ms:10.3f}")
    print("all identities hold" if ok else "SOME IDENTITIES FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
