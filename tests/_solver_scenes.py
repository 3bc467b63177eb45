"""Small geometric test problems for the solver tests, built without the rasterizer.

Isotropic round splats seen by pinhole cameras on an orbit, composited front
to back by brute force (every pixel against every splat): ``W[u, i] =
alpha_i(u) prod_{j in front of i} (1 - alpha_j(u))``. The "object" is a blob
of splats at the origin; the background is a ring of splats around it and a
floor under it, so views see the object partly occluded.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.operators import OperatorStack, ViewOperator


def random_views(rng, n=40, views=4, h=5, w=6, density=0.25, nan=0.15, binary=False):
    """Random sparse float32 views with row sums <= 1 (compositing weights) and masks in [0, 1] (or 0/1 with
    ``binary``) with a share ``nan`` of NaN (unknown) pixels: ``(mats, masks)``."""
    mats, masks = [], []
    for _ in range(views):
        A = sp.random(h * w, n, density=density, random_state=rng, format="csr", dtype=np.float64)
        rs = np.asarray(A.sum(1)).ravel()
        scale = np.where(rs > 0, rng.uniform(0.3, 0.99, rs.size) / np.maximum(rs, 1e-12), 0)
        mats.append(sp.csr_matrix(sp.diags(scale) @ A, dtype=np.float32))
        m = rng.random((h, w)).astype(np.float32)
        if binary:
            m = (m > 0.5).astype(np.float32)
        m[rng.random((h, w)) < nan] = np.nan
        masks.append(m)
    return mats, masks


def splat_operator(points, radii, opacities, camera: Camera) -> sp.csr_matrix:
    """(H*W, N) float32 compositing weights of round splats (brute force)."""
    uv, z = camera.project(points)
    h, w = camera.image_shape
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    px = np.stack([xs.ravel(), ys.ravel()], 1)
    front = z > camera.near
    sigma = np.where(front, camera.fx * radii / np.where(front, z, 1.0), 1.0)
    uv = np.where(front[:, None], uv, 1e9)
    d2 = ((px[:, None, :] - uv[None, :, :]) ** 2).sum(-1)
    a = np.minimum(0.99, opacities[None, :] * np.exp(-0.5 * d2 / sigma[None, :] ** 2))
    a[a < 1.0 / 255.0] = 0.0
    a[:, ~front] = 0.0
    order = np.argsort(np.where(front, z, np.inf), kind="stable")
    a_s = a[:, order]
    T = np.cumprod(np.concatenate([np.ones((a.shape[0], 1)), 1.0 - a_s[:, :-1]], 1), axis=1)
    W = np.zeros_like(a)
    W[:, order] = a_s * T
    return sp.csr_matrix(W.astype(np.float32))


def blob_scene(seed=0, n_object=120, n_background=240):
    """(points, radii, opacities, labels) of an object blob inside a background ring and floor."""
    rng = np.random.default_rng(seed)
    obj = rng.normal(size=(n_object, 3))
    obj *= (0.35 * rng.random(n_object) ** (1 / 3) / np.linalg.norm(obj, axis=1))[:, None]
    n_ring = n_background // 2
    ang = rng.uniform(0, 2 * np.pi, n_ring)
    rad = rng.uniform(1.6, 2.4, n_ring)
    ring = np.stack([rad * np.cos(ang), rng.uniform(-0.3, 0.3, n_ring), rad * np.sin(ang)], 1)
    n_floor = n_background - n_ring
    floor = np.stack([rng.uniform(-1.5, 1.5, n_floor), np.full(n_floor, 0.45), rng.uniform(-1.5, 1.5, n_floor)], 1)
    points = np.concatenate([obj, ring, floor]).astype(np.float64)
    radii = np.concatenate([rng.uniform(0.05, 0.09, n_object), rng.uniform(0.06, 0.12, n_background)])
    opac = np.concatenate([rng.uniform(0.6, 0.95, n_object), rng.uniform(0.5, 0.95, n_background)])
    labels = np.zeros(len(points), dtype=bool)
    labels[:n_object] = True
    return points, radii, opac, labels


def orbit_cameras(n_views=12, width=64, height=48, distance=1.3, elevation_deg=25.0):
    """Cameras on a circle around the origin, looking at it ("up" is -y, as in COLMAP scenes)."""
    cams = []
    el = np.radians(elevation_deg)
    for k in range(n_views):
        az = 2 * np.pi * k / n_views
        eye = distance * np.array([np.cos(el) * np.cos(az), -np.sin(el), np.cos(el) * np.sin(az)])
        cams.append(Camera.look_at(eye, np.zeros(3), np.array([0.0, -1.0, 0.0]), 50.0, width, height,
                                   name=f"orbit_{k:02d}"))
    return cams


def blob_stack(seed=0, n_views=12, **kw) -> tuple:
    """(OperatorStack, labels, clean masks (W t / alpha > 0.5 where alpha > 0.5))."""
    points, radii, opac, labels = blob_scene(seed, **kw)
    views = [ViewOperator(splat_operator(points, radii, opac, c), c, c.image_shape) for c in orbit_cameras(n_views)]
    stack = OperatorStack(views, fingerprint=f"blob-{seed}")
    masks = [v.image(labels.astype(np.float32)) > 0.5 for v in stack]
    return stack, labels, masks
