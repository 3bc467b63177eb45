"""Brute-force reference rasterizer for the tests (plain numpy, slow).

Written straight from the formulas of DESIGN.md "Conventions" without any
code of ``seed2gs_inverse.operators``: per pixel it walks *all* Gaussians in
depth order (not tile lists), and applies the tile-membership rule as an
explicit test of the pixel's tile against each Gaussian's tile rectangle.
"""

from __future__ import annotations

import numpy as np

from seed2gs_inverse.scene import GaussianScene
from seed2gs_inverse.sh import sh_to_rgb


def reference_projection(scene, cam, mode="classic"):
    """dict of float64 arrays: mean2d, conic, radius, z, color, opacity, valid, tile_lo, tile_hi."""
    R, t = cam.rotation, cam.translation
    xc = scene.means.astype(np.float64) @ R.T + t
    x, y, z = xc.T
    cov_cam = R @ scene.covariances() @ R.T
    tan_x, tan_y = cam.width / (2 * cam.fx), cam.height / (2 * cam.fy)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = z * np.clip(x / z, -(cam.cx / cam.fx + 0.3 * tan_x), (cam.width - cam.cx) / cam.fx + 0.3 * tan_x)
        ty = z * np.clip(y / z, -(cam.cy / cam.fy + 0.3 * tan_y), (cam.height - cam.cy) / cam.fy + 0.3 * tan_y)
        J = np.zeros((len(scene), 2, 3))
        J[:, 0, 0] = cam.fx / z
        J[:, 0, 2] = -cam.fx * tx / z ** 2
        J[:, 1, 1] = cam.fy / z
        J[:, 1, 2] = -cam.fy * ty / z ** 2
        cov2 = J @ cov_cam @ np.swapaxes(J, 1, 2)
        det0 = np.linalg.det(cov2)
        cov2 = cov2 + 0.3 * np.eye(2)
        det = np.linalg.det(cov2)
        opacity = 1 / (1 + np.exp(-scene.opacity_logits.astype(np.float64)))
        if mode == "antialiased":
            opacity = opacity * np.sqrt(np.maximum(det0 / det, 0))
        a, b, c = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]
        lam = 0.5 * (a + c) + np.sqrt(np.maximum(0.01, 0.25 * (a - c) ** 2 + b * b))
        radius = np.ceil(3 * np.sqrt(lam))
        mean2d = np.stack([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy], 1)
    valid = (z >= cam.near) & (det > 0)
    conic = np.zeros((len(scene), 3))
    inv = np.linalg.inv(np.where(valid[:, None, None], cov2, np.eye(2)))
    conic[:, 0], conic[:, 1], conic[:, 2] = inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]
    grid = np.array([-(-cam.width // 16), -(-cam.height // 16)])
    with np.errstate(invalid="ignore"):
        lo = np.clip(np.floor((mean2d - radius[:, None]) / 16), 0, grid)
        hi = np.clip(np.floor((mean2d + radius[:, None] + 15) / 16), 0, grid)
    valid &= np.all(hi > lo, axis=1)
    d = scene.means.astype(np.float64) - cam.center
    color = sh_to_rgb(scene.sh, d / np.linalg.norm(d, axis=1, keepdims=True))
    return dict(mean2d=mean2d, conic=conic, radius=np.where(valid, radius, 0), z=z, color=color,
                opacity=opacity, valid=valid, tile_lo=lo, tile_hi=hi)


def reference_render(scene, cam, mode="classic", background=(0, 0, 0)):
    """rgb (H,W,3), alpha (H,W), depth (H,W), dense W (H*W, N), all float64."""
    p = reference_projection(scene, cam, mode)
    H, Wd = cam.height, cam.width
    n = len(scene)
    order = np.argsort(p["z"], kind="stable")
    Wm = np.zeros((H * Wd, n))
    rgb = np.zeros((H, Wd, 3))
    alpha = np.zeros((H, Wd))
    depth = np.zeros((H, Wd))
    bg = np.asarray(background, dtype=np.float64)
    for py in range(H):
        for px in range(Wd):
            tile = np.array([px // 16, py // 16])
            member = p["valid"] & np.all((p["tile_lo"] <= tile) & (tile < p["tile_hi"]), axis=1)
            g = order[member[order]]
            dx = p["mean2d"][g, 0] - (px + 0.5)
            dy = p["mean2d"][g, 1] - (py + 0.5)
            A, B, C = p["conic"][g].T
            power = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
            with np.errstate(over="ignore"):
                a = np.minimum(0.99, p["opacity"][g] * np.exp(power))
            ok = (power <= 0) & (a >= 1 / 255)
            g, a = g[ok], a[ok]
            t_after = np.cumprod(1 - a)
            stop = np.flatnonzero(t_after < 1e-4)
            k = stop[0] if stop.size else a.size
            g, a = g[:k], a[:k]
            t_before = np.concatenate([[1.0], t_after[: k - 1]]) if k else np.zeros(0)
            w = a * t_before
            u = py * Wd + px
            Wm[u, g] = w
            T = t_before[-1] * (1 - a[-1]) if k else 1.0
            rgb[py, px] = w @ p["color"][g] + T * bg
            alpha[py, px] = w.sum()
            depth[py, px] = (w @ p["z"][g]) / w.sum() if k else 0.0
    return rgb, alpha, depth, Wm


def random_scene(seed, n=120, sh_degree=None, cam=None):
    """A small random scene exercising the corner cases around ``cam``.

    Anisotropic Gaussians in front of the camera (some partly off-screen),
    plus a few behind it, a few straddling the near plane and a few huge ones
    close to the camera far outside the field of view (Jacobian clamp).
    """
    rng = np.random.default_rng(seed)
    deg = int(rng.integers(0, 4)) if sh_degree is None else sh_degree
    k = (deg + 1) ** 2
    n_main = n - 12
    # Camera coordinates first, then mapped to world with the camera pose.
    pc = np.empty((n, 3))
    pc[:n_main, 2] = rng.uniform(1.5, 6.0, n_main)
    pc[:n_main, :2] = rng.normal(0, 0.7, (n_main, 2)) * pc[:n_main, 2:3]
    pc[n_main:n_main + 3] = rng.normal(0, 1, (3, 3)) - [0, 0, 3]            # behind
    pc[n_main + 3:n_main + 7, :2] = rng.normal(0, 0.01, (4, 2))
    pc[n_main + 3:n_main + 7, 2] = cam.near + np.array([-1e-3, 1e-3, 2e-2, 5e-2])  # near plane
    pc[n_main + 7:, 2] = rng.uniform(0.3, 1.0, 5)
    pc[n_main + 7:, :2] = rng.choice([-1, 1], (5, 2)) * rng.uniform(1.0, 2.0, (5, 2)) * pc[n_main + 7:, 2:3]
    means = (pc - cam.translation) @ cam.rotation  # R^T (pc - t)
    log_scales = rng.normal(-2.3, 0.6, (n, 3))
    log_scales[n_main + 3:n_main + 7] = -7.0
    log_scales[n_main + 7:] = rng.normal(-0.5, 0.3, (5, 3))
    quats = rng.normal(size=(n, 4))
    logits = rng.normal(0.5, 2.0, n)
    logits[n_main + 7:] = -1.5
    sh = rng.normal(0, 0.4, (n, k, 3))
    return GaussianScene(means, quats, log_scales, logits, sh)


def load_firepit(data_dir):
    """The firepit scene and its ``overview`` camera (near plane 0.2, as the reference image)."""
    from seed2gs_inverse.camera import Camera
    from seed2gs_inverse.io import read_camera, read_scene

    scene = read_scene(data_dir / "firepit_562k_sh0.ply")
    c = read_camera(f"{data_dir / 'firepit_cameras.json'}:overview")
    cam = Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.world_to_camera, c.name, near=0.2)
    return scene, cam
