"""Small hand-built scenes for the pipeline tests (independent of synthetic.py).

A ground disc and a sphere (label 1) made of surface Gaussians flattened
along the surface normal, like a trained 3DGS; world up is ``up``.
"""

from __future__ import annotations

import numpy as np

from seed2gs_inverse import Camera, GaussianScene
from seed2gs_inverse.scene import rotmat_to_quat
from seed2gs_inverse.sh import rgb_to_sh


def _frame_quats(normals):
    qs = []
    for n in normals:
        a = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
        t1 = np.cross(n, a)
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        qs.append(rotmat_to_quat(np.stack([t1, t2, n], axis=1)))
    return np.array(qs)


def surface(points, normals, sigma, colors, thin=0.1, opacity=0.95):
    n = len(points)
    log_s = np.log(np.array([sigma, sigma, sigma * thin]))
    return GaussianScene(points, _frame_quats(normals), np.tile(log_s, (n, 1)),
                         np.full(n, np.log(opacity / (1 - opacity))), rgb_to_sh(colors)[:, None, :])


def sphere_scene(seed=0, n_sphere=900, n_ground=1600, up=(0.0, -1.0, 0.0), center=(0.0, 0.0, 0.0),
                 radius=0.5):
    """Ground disc (label 0) below a sphere resting on it (label 1); returns (scene, labels, info)."""
    rng = np.random.default_rng(seed)
    up = np.asarray(up, float) / np.linalg.norm(up)
    a = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 0, 1.0])
    e1 = np.cross(up, a); e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    c = np.asarray(center, float)
    # Fibonacci sphere.
    k = np.arange(n_sphere) + 0.5
    phi = np.arccos(1 - 2 * k / n_sphere)
    th = np.pi * (1 + 5 ** 0.5) * k
    dirs = np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    sp_pts = c + radius * dirs
    sp_col = np.where((np.floor(th / 1.0) % 2 == 0)[:, None], [0.9, 0.2, 0.1], [0.9, 0.7, 0.1])
    sig = radius * 2.2 / np.sqrt(n_sphere)
    sphere = surface(sp_pts, dirs, sig, sp_col)
    # Ground disc under it.
    g = int(np.sqrt(n_ground))
    s = np.linspace(-3, 3, g)
    gx, gy = np.meshgrid(s, s)
    gx = gx.ravel() + rng.normal(0, 0.01, g * g)
    gy = gy.ravel() + rng.normal(0, 0.01, g * g)
    g_pts = c - radius * up + gx[:, None] * e1 + gy[:, None] * e2
    checker = ((np.floor(gx / 0.5) + np.floor(gy / 0.5)) % 2 == 0)[:, None]
    g_col = np.where(checker, [0.3, 0.6, 0.3], [0.2, 0.4, 0.6])
    ground = surface(g_pts, np.tile(up, (g * g, 1)), 6.0 / g * 0.9, g_col)
    scene = GaussianScene.concat([ground, sphere])
    labels = np.r_[np.zeros(len(ground), bool), np.ones(len(sphere), bool)]
    return scene, labels, {"up": up, "e1": e1, "e2": e2, "center": c, "radius": radius}


def reference_camera(info, width=96, height=72, dist=3.0, elev_deg=20.0, azim_deg=0.0, fov=45.0,
                     target=None):
    up, e1, e2 = info["up"], info["e1"], info["e2"]
    el, az = np.radians(elev_deg), np.radians(azim_deg)
    horiz = np.cos(az) * e1 + np.sin(az) * e2
    tgt = info["center"] if target is None else np.asarray(target, float)
    eye = tgt + dist * (np.cos(el) * horiz + np.sin(el) * up)
    return Camera.look_at(eye, tgt, up, fov, width, height)
