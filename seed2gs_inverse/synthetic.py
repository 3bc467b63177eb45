"""Procedural scenes with ground truth, composites and mask noise models.

Everything accuracy is measured on stands on these: a scene made of Gaussians
whose per-Gaussian object labels are known exactly, composites that insert an
object (procedural or read from a file) into another scene and label the
inserted Gaussians, and noise models that corrupt supervision masks the way
a 2D tracker fails.

Scenes (:func:`make_scene`)
    A textured ground plane (label 0) and seven objects built in a local
    frame with ``+z`` up, then mapped to the world by
    ``x_world = origin + scale * F x_local``, where the rotation ``F`` takes
    local ``+z`` to the requested world ``up`` (default ``-y``, as in
    COLMAP-style captures). Surfaces are covered by Gaussians flattened
    along the normal (tangential standard deviation ``0.7`` times the sample
    spacing, normal one ``0.1`` times that), opacity 0.95, so objects render
    as solid surfaces like a trained 3DGS.

    ======  ============  ===============================================
    label   name          what makes it hard
    ======  ============  ===============================================
    0       ground        large textured background (checker)
    1       sphere        view-dependent colour (SH degree 1-3)
    2       box           checker texture
    3       cup           open cylinder shell + floor: a container ...
    4       cup contents  ... and the liquid and balls inside it
    5       rod           thin chopstick: few long anisotropic Gaussians
    6       can 1         two identical striped cans: same-class ...
    7       can 2         ... ambiguity (Gaussians equal up to translation)
    ======  ============  ===============================================

Composites (:func:`compose`, :func:`pose_on_point`)
    ``compose(background, [(object_scene, pose), ...])`` moves each object
    with :meth:`GaussianScene.transformed` (SH rotated with it), concatenates
    and labels background Gaussians 0 and the k-th object k.

Masks (:func:`masks_from_labels`, :func:`render_label_masks`, :func:`perturb_masks`)
    Masks are float arrays in [0, 1] of shape ``(H, W)``; NaN marks unknown
    pixels that carry no evidence. Ground-truth masks threshold the rendered
    object weight ``W(c) 1_object``; noise models stand in for tracking
    failures.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .camera import Camera
from .errors import ValidationError
from .scene import GaussianScene, quat_multiply, quat_to_rotmat, rotmat_to_quat
from .sh import SH_C0, num_sh_coeffs

__all__ = ["SyntheticScene", "make_scene", "compose", "pose_on_point", "parse_pose", "surface_point",
           "masks_from_labels", "render_label_masks", "perturb_masks", "NOISE_KINDS"]

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))
_TANGENT_SIGMA = 0.7    # tangential std / sample spacing: neighbours overlap, no holes
_NORMAL_SIGMA = 0.1     # normal std / tangential std: flat surfels like a trained 3DGS
_OPACITY = 0.95


# ---------------------------------------------------------------------------
# small geometry helpers
# ---------------------------------------------------------------------------
def _unit(name, v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-12:
        raise ValidationError(f"'{name}' must be a finite non-zero 3-vector, got {np.asarray(v).tolist()}")
    return v / np.linalg.norm(v)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``a`` to unit vector ``b`` (Rodrigues)."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-12:
        # Opposite vectors: turn half a circle about any axis perpendicular to a.
        axis = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` radians about the unit ``axis`` (right hand)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _frame_for_up(up: np.ndarray) -> np.ndarray:
    """World-from-local rotation whose third column is ``up``.

    The local x axis is the world axis least aligned with ``up``, made
    orthogonal to it, so ``up = -y`` gives local x = world x.
    """
    a = np.eye(3)[int(np.argmin(np.abs(up)))]
    x = a - np.dot(a, up) * up
    x /= np.linalg.norm(x)
    y = np.cross(up, x)
    return np.stack([x, y, up], axis=1)


def _quats_z_to(normals: np.ndarray) -> np.ndarray:
    """w-first quaternions rotating local ``+z`` onto each unit normal (M, 3).

    ``q = (1 + z.n, z x n)`` normalised is the half-angle rotation about
    ``z x n``; ``n = -z`` has no unique axis and gets a half turn about x.
    """
    n = np.asarray(normals, dtype=np.float64)
    q = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], axis=1)
    flip = q[:, 0] < 1e-9
    q[flip] = [0.0, 1.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@dataclass
class _Part:
    """Gaussians of one object in the local frame (float64 until assembly)."""

    means: np.ndarray
    quats: np.ndarray
    sigmas: np.ndarray     # (M, 3) standard deviations
    rgb: np.ndarray        # (M, 3) base colour in [0, 1]

    @staticmethod
    def cat(parts: Sequence["_Part"]) -> "_Part":
        return _Part(*(np.concatenate([getattr(p, f) for p in parts])
                       for f in ("means", "quats", "sigmas", "rgb")))

    def moved(self, rot: np.ndarray, t) -> "_Part":
        return _Part(self.means @ rot.T + np.asarray(t, dtype=np.float64),
                     quat_multiply(rotmat_to_quat(rot), self.quats), self.sigmas, self.rgb)


def _surfels(points, normals, spacing, rgb_fn) -> _Part:
    """Flattened Gaussians on a surface sampled at ``spacing``."""
    points = np.asarray(points, dtype=np.float64)
    st = _TANGENT_SIGMA * spacing
    sig = np.tile([st, st, _NORMAL_SIGMA * st], (len(points), 1))
    return _Part(points, _quats_z_to(normals), sig, rgb_fn(points))


def _sphere(n, radius, center, rng, rgb_fn) -> _Part:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = _GOLDEN_ANGLE * i
    d = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    # A random orientation per seed, so different seeds sample differently.
    d = d @ quat_to_rotmat(rng.normal(size=4)).T
    spacing = np.sqrt(4 * np.pi * radius ** 2 / n)
    return _surfels(np.asarray(center) + radius * d, d, spacing, rgb_fn)


def _grid2(n, len_u, len_v, rng):
    """About ``n`` jittered points in ``[0, len_u] x [0, len_v]``; returns (u, v, spacing)."""
    nu = max(1, int(round(np.sqrt(n * len_u / len_v))))
    nv = max(1, int(round(n / nu)))
    du, dv = len_u / nu, len_v / nv
    uu, vv = np.meshgrid((np.arange(nu) + 0.5) * du, (np.arange(nv) + 0.5) * dv, indexing="ij")
    u = uu.ravel() + rng.uniform(-0.2, 0.2, uu.size) * du
    v = vv.ravel() + rng.uniform(-0.2, 0.2, vv.size) * dv
    return np.clip(u, 0, len_u), np.clip(v, 0, len_v), float(np.sqrt(du * dv))


def _box(n, half, center, rng, rgb_fn) -> _Part:
    half = np.asarray(half, dtype=np.float64)
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]]) * 4
    parts = []
    for axis in range(3):
        i, j = [a for a in range(3) if a != axis]
        for sign in (-1.0, 1.0):
            m = max(1, int(round(n * areas[axis] / (2 * areas.sum()))))
            u, v, spacing = _grid2(m, 2 * half[i], 2 * half[j], rng)
            p = np.zeros((u.size, 3))
            p[:, i], p[:, j], p[:, axis] = u - half[i], v - half[j], sign * half[axis]
            nrm = np.zeros_like(p)
            nrm[:, axis] = sign
            parts.append(_surfels(p + center, nrm, spacing, rgb_fn))
    return _Part.cat(parts)


def _cylinder_side(n, radius, z0, z1, center, rng, rgb_fn, inward=False) -> _Part:
    u, v, spacing = _grid2(n, 2 * np.pi * radius, z1 - z0, rng)
    theta = u / radius
    nrm = np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], 1)
    p = np.stack([radius * nrm[:, 0], radius * nrm[:, 1], z0 + v], 1)
    return _surfels(p + center, -nrm if inward else nrm, spacing, rgb_fn)


def _disk(n, r0, r1, z, center, rng, rgb_fn) -> _Part:
    """Sunflower-sampled annulus ``r0 <= r <= r1`` at height ``z`` (a disk when r0 = 0)."""
    i = np.arange(n) + 0.5
    r = np.sqrt(r0 ** 2 + (r1 ** 2 - r0 ** 2) * i / n)
    theta = _GOLDEN_ANGLE * i + rng.uniform(0, 2 * np.pi)
    p = np.stack([r * np.cos(theta), r * np.sin(theta), np.full(n, float(z))], 1)
    nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
    spacing = np.sqrt(np.pi * (r1 ** 2 - r0 ** 2) / n)
    return _surfels(p + center, nrm, spacing, rgb_fn)


def _split(n, areas):
    """Integer counts (each >= 1) proportional to ``areas`` that sum to about ``n``."""
    areas = np.asarray(areas, dtype=np.float64)
    return [max(1, int(round(n * a / areas.sum()))) for a in areas]


def _const(rgb):
    rgb = np.asarray(rgb, dtype=np.float64)
    return lambda p: np.tile(rgb, (len(p), 1))


def _checker(cell, c0, c1):
    """3D checker of cubes of side ``cell``: on any plane it reads as a checker or stripes."""
    c0, c1 = np.asarray(c0, float), np.asarray(c1, float)

    def fn(p):
        # The epsilon keeps faces lying exactly on a cell boundary on one side.
        k = np.floor(p / cell + 1e-9).astype(np.int64).sum(axis=1) % 2
        return np.where(k[:, None] == 0, c0, c1)
    return fn


# ---------------------------------------------------------------------------
# scene
# ---------------------------------------------------------------------------
@dataclass(eq=False)
class SyntheticScene:
    """A procedural scene with exact per-Gaussian labels.

    Attributes
    ----------
    scene : GaussianScene
        All Gaussians, SH degree ``sh_degree``.
    labels : (N,) int32
        0 for the ground, ``1..L-1`` for the objects (see ``names``).
    names : dict[int, str]
        Label -> object name.
    centers : (L, 3) float64
        World centre of each label's bounding box (row = label).
    half_extents : (L, 3) float64
        Half sizes of each bounding box along the local axes ``frame[:, 0]``,
        ``frame[:, 1]``, ``frame[:, 2]`` (= ``up``), in world units. Every
        Gaussian mean of label k satisfies
        ``|frame^T (x - centers[k])| <= half_extents[k]`` componentwise.
    frame : (3, 3) float64
        World-from-local rotation; its columns are the local x, y and up axes.
    up : (3,) float64
        World up direction (third column of ``frame``).
    origin : (3,) float64
        World position of the local origin (ground centre).
    scale : float
        World units per local unit.
    seed : int
        The seed it was built with.
    meta : dict
        Which labels exercise which difficulty: ``same_class`` (pairs of
        identical objects), ``container`` ({container: contents}), ``thin``
        and ``view_dependent`` (lists of labels).
    """

    scene: GaussianScene
    labels: np.ndarray
    names: dict
    centers: np.ndarray
    half_extents: np.ndarray
    frame: np.ndarray
    up: np.ndarray
    origin: np.ndarray
    scale: float = 1.0
    seed: int = 0
    meta: dict = field(default_factory=dict)

    @property
    def radii(self) -> np.ndarray:
        """Bounding-sphere radius of each label's box, (L,)."""
        return np.linalg.norm(self.half_extents, axis=1)

    @property
    def n_labels(self) -> int:
        return int(self.centers.shape[0])

    def _check_label(self, label) -> int:
        if isinstance(label, str):
            for k, v in self.names.items():
                if v == label:
                    return int(k)
            raise ValidationError(f"no object named {label!r}; names are {sorted(self.names.values())}")
        lab = int(label)
        if lab not in self.names:
            raise ValidationError(f"label {label!r} is not in this scene; labels are {sorted(self.names)}")
        return lab

    def label_of(self, name) -> int:
        """The integer label of an object name (or the label itself, validated)."""
        return self._check_label(name)

    def object_mask(self, label) -> np.ndarray:
        """Boolean (N,) membership of one object (by label or name)."""
        return self.labels == self._check_label(label)

    def inside(self, label, points, tol: float = 1e-5) -> np.ndarray:
        """Whether world points (M, 3) lie in the bounding box of ``label`` (bool (M,))."""
        lab = self._check_label(label)
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        local = (p - self.centers[lab]) @ self.frame
        return np.all(np.abs(local) <= self.half_extents[lab] + tol, axis=1)

    def _objects_sphere(self):
        """Bounding sphere (centre, radius) of all object boxes (labels >= 1)."""
        corners = []
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        for lab in range(1, self.n_labels):
            corners.append(self.centers[lab] + (signs * self.half_extents[lab]) @ self.frame.T)
        corners = np.concatenate(corners)
        c = 0.5 * (corners.min(0) + corners.max(0))
        return c, float(np.linalg.norm(corners - c, axis=1).max())

    def orbit_cameras(self, n_views: int, width: int, height: int, elevation_deg=35.0,
                      azimuth_deg: float = -60.0, fov_y_deg: float = 50.0,
                      margin: float = 1.1) -> list[Camera]:
        """Cameras on a circle around the objects, all looking at their centre.

        View ``i`` sits at azimuth ``azimuth_deg + 360 i / n_views`` (measured
        from the local x axis about ``up``) and elevation ``elevation_deg``
        above the ground plane (a scalar or one value per view), at the
        distance where the objects' bounding sphere (times ``margin``) fits
        the narrower field of view. Image up is the scene's ``up``.
        """
        n_views = int(n_views)
        if n_views < 1:
            raise ValidationError(f"n_views must be >= 1, got {n_views}")
        elev = np.broadcast_to(np.asarray(elevation_deg, dtype=np.float64), (n_views,))
        if np.any(np.abs(elev) >= 89.0):
            raise ValidationError("elevation_deg must be within (-89, 89) degrees")
        c, r = self._objects_sphere()
        probe = Camera.from_fov(width, height, fov_y_deg)
        half = 0.5 * min(probe.fov_x, probe.fov_y)
        dist = margin * r / np.sin(half)
        cams = []
        for i in range(n_views):
            az = np.radians(azimuth_deg + 360.0 * i / n_views)
            el = np.radians(elev[i])
            d_local = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            eye = c + dist * (self.frame @ d_local)
            cams.append(Camera.look_at(eye, c, self.up, fov_y_deg, width, height,
                                       name=f"orbit_{i:03d}"))
        return cams

    def reference_camera(self, width: int, height: int, elevation_deg: float = 35.0,
                         azimuth_deg: float = -60.0, fov_y_deg: float = 50.0) -> Camera:
        """One camera that sees every object (the first of :meth:`orbit_cameras`)."""
        cam = self.orbit_cameras(1, width, height, elevation_deg, azimuth_deg, fov_y_deg)[0]
        return Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                      cam.world_to_camera, name="reference", near=cam.near)


def _layout(rng) -> dict:
    """Slot of each object on the ground: (x, y) in the local frame plus yaw.

    Slots are far enough apart (along x or y, beyond the half-sizes of the
    objects' yawed bounding boxes plus the jitter range) that neither the
    objects nor their declared boxes overlap for any seed.
    """
    slots = {"sphere": (-0.9, 0.5), "box": (0.0, 0.75), "cup": (0.8, 0.4),
             "rod": (-0.55, -0.6), "can 1": (0.3, -0.4), "can 2": (0.9, -0.5)}
    return {k: (np.array(v) + rng.uniform(-0.08, 0.08, 2), rng.uniform(0, 2 * np.pi))
            for k, v in slots.items()}


def make_scene(seed: int = 0, n_per_object: int = 400, n_ground: int | None = None,
               ground: bool = True, ground_size: float = 3.0, up=(0.0, -1.0, 0.0),
               origin=(0.0, 0.0, 0.0), scale: float = 1.0, sh_degree: int = 3) -> SyntheticScene:
    """Build the procedural test scene (deterministic given ``seed``).

    Parameters
    ----------
    seed : int
        Seeds sample jitter, object positions (within non-overlapping slots),
        yaw angles, the sphere's view-dependent SH and ground colour noise.
        The same arguments give bit-identical arrays.
    n_per_object : int
        About how many Gaussians each surface object gets (>= 20). The rod
        gets ``max(8, n_per_object // 8)`` long Gaussians along its axis.
    n_ground : int, optional
        Gaussians on the ground plane; default ``4 * n_per_object``.
    ground : bool
        Include the ground (label 0). Without it label 0 has no Gaussians.
    ground_size : float
        Side of the square ground, local units (objects span about 2.6).
    up : (3,) array
        World up direction (normalised here). Default ``-y`` (COLMAP-like).
    origin : (3,) array
        World position of the ground centre.
    scale : float
        World units per local unit: ``x_world = origin + scale * frame x_local``.
    sh_degree : int
        0..3. With degree >= 1 the sphere (label 1) gets random
        view-dependent coefficients (|c| ~ 0.08 per band); other objects
        have zero higher bands.

    Returns
    -------
    SyntheticScene
        With about ``6 n_per_object + n_ground`` Gaussians (default ~4000).
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValidationError(f"seed must be an integer, got {seed!r}")
    if int(n_per_object) < 20:
        raise ValidationError(f"n_per_object must be >= 20 so objects are closed surfaces, got {n_per_object}")
    n_per_object = int(n_per_object)
    n_ground = 4 * n_per_object if n_ground is None else int(n_ground)
    if ground and n_ground < 4:
        raise ValidationError(f"n_ground must be >= 4, got {n_ground}")
    if not (np.isfinite(ground_size) and ground_size >= 2.8):
        raise ValidationError(f"ground_size must be >= 2.8 so the objects stand on it, got {ground_size}")
    if not (np.isfinite(scale) and scale > 0):
        raise ValidationError(f"scale must be a positive finite number, got {scale!r}")
    if int(sh_degree) not in (0, 1, 2, 3):
        raise ValidationError(f"sh_degree must be 0, 1, 2 or 3, got {sh_degree!r}")
    up = _unit("up", up)
    origin = np.asarray(origin, dtype=np.float64)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise ValidationError(f"origin must be a finite 3-vector, got {np.asarray(origin).tolist()}")
    rng = np.random.default_rng(int(seed))
    lay = _layout(rng)
    n = n_per_object
    ez = np.array([0.0, 0.0, 1.0])

    def placed(part, key):
        xy, yaw = lay[key]
        return part.moved(_axis_angle(ez, yaw), [xy[0], xy[1], 0.0])

    parts, boxes = {}, {}   # label -> _Part; label -> (lo, hi) in the local frame

    def yawed_box(key, lo, hi):
        """Local AABB of the box [lo, hi] (object frame) after yaw + slot shift."""
        xy, yaw = lay[key]
        corners = np.array(np.meshgrid(*zip(lo, hi))).reshape(3, -1).T
        c = corners @ _axis_angle(ez, yaw).T + [xy[0], xy[1], 0.0]
        return c.min(0), c.max(0)

    # 1 sphere: red, view-dependent colour (set after assembly).
    r_s = 0.3
    parts[1] = placed(_sphere(n, r_s, [0, 0, r_s], rng, _const([0.8, 0.15, 0.1])), "sphere")
    boxes[1] = yawed_box("sphere", [-r_s, -r_s, 0], [r_s, r_s, 2 * r_s])
    # 2 box: checker texture.
    hb = np.array([0.3, 0.22, 0.2])
    parts[2] = placed(_box(n, hb, [0, 0, hb[2]], rng,
                           _checker(0.1, [0.15, 0.3, 0.75], [0.95, 0.8, 0.2])), "box")
    boxes[2] = yawed_box("box", [-hb[0], -hb[1], 0], [hb[0], hb[1], 2 * hb[2]])
    # 3 cup: outer wall, inner wall, rim, inner floor; 4 contents: liquid + 3 balls.
    rc, hc, tc = 0.25, 0.4, 0.02
    white = _const([0.92, 0.92, 0.88])
    a_cup = [2 * np.pi * rc * hc, 2 * np.pi * (rc - tc) * (hc - tc),
             np.pi * (rc ** 2 - (rc - tc) ** 2), np.pi * (rc - tc) ** 2]
    k = _split(n, a_cup)
    cup = _Part.cat([
        _cylinder_side(k[0], rc, 0.0, hc, [0, 0, 0], rng, white),
        _cylinder_side(k[1], rc - tc, tc, hc, [0, 0, 0], rng, _const([0.85, 0.85, 0.8]), inward=True),
        _disk(max(k[2], 12), rc - tc, rc, hc, [0, 0, 0], rng, white),
        _disk(k[3], 0.0, rc - tc, tc, [0, 0, 0], rng, white)])
    parts[3] = placed(cup, "cup")
    boxes[3] = yawed_box("cup", [-rc, -rc, 0], [rc, rc, hc])
    r_liq, z_liq, r_ball = rc - tc - 0.01, 0.6 * hc, 0.055
    ball_xy = [(0.1, 0.0), (-0.05, 0.09), (-0.05, -0.09)]
    k = _split(n, [np.pi * r_liq ** 2] + [4 * np.pi * r_ball ** 2] * 3)
    contents = _Part.cat(
        [_disk(k[0], 0.0, r_liq, z_liq, [0, 0, 0], rng, _const([0.35, 0.2, 0.08]))]
        + [_sphere(k[i + 1], r_ball, [bx, by, z_liq + 0.02], rng, _const([1.0, 0.55, 0.1]))
           for i, (bx, by) in enumerate(ball_xy)])
    parts[4] = placed(contents, "cup")
    boxes[4] = yawed_box("cup", [-r_liq, -r_liq, z_liq - r_ball + 0.02],
                         [r_liq, r_liq, z_liq + 0.02 + r_ball])
    # 5 rod: a thin chopstick slightly raised at one end, made of long
    # Gaussians along its axis (3DGS represents thin structures this way).
    length, r_rod, z0, z1 = 0.8, 0.02, 0.03, 0.12
    n_rod = max(8, n // 8)
    axis = np.array([length, 0.0, z1 - z0])
    s = (np.arange(n_rod) + 0.5) / n_rod
    rod_means = np.array([-length / 2, 0.0, z0]) + s[:, None] * axis
    rot = _rotation_between(np.array([1.0, 0, 0]), axis / np.linalg.norm(axis))
    step = np.linalg.norm(axis) / n_rod
    rod = _Part(rod_means, np.tile(rotmat_to_quat(rot), (n_rod, 1)),
                np.tile([max(0.8 * step, 1.5 * r_rod), 0.5 * r_rod, 0.5 * r_rod], (n_rod, 1)),
                np.tile([0.55, 0.35, 0.15], (n_rod, 1)))
    parts[5] = placed(rod, "rod")
    # The axis bounds the means: the box is the segment's extent.
    boxes[5] = yawed_box("rod", [-length / 2, 0.0, z0], [length / 2, 0.0, z1])
    # 6, 7 cans: identical striped closed cylinders (same Gaussians, moved).
    r_can, h_can = 0.15, 0.35

    def stripes(p):
        band = np.floor(p[:, 2] / 0.05 + 1e-9).astype(np.int64) % 2
        return np.where(band[:, None] == 0, [0.1, 0.6, 0.2], [0.95, 0.95, 0.95])
    k = _split(n, [2 * np.pi * r_can * h_can, np.pi * r_can ** 2])
    can = _Part.cat([_cylinder_side(k[0], r_can, 0.0, h_can, [0, 0, 0], rng, stripes),
                     _disk(k[1], 0.0, r_can, h_can, [0, 0, 0], rng, _const([0.7, 0.7, 0.72]))])
    for lab, key in ((6, "can 1"), (7, "can 2")):
        # The same yaw for both, so the twins are exact translated copies.
        xy, _ = lay[key]
        parts[lab] = can.moved(np.eye(3), [xy[0], xy[1], 0.0])
        boxes[lab] = (np.array([xy[0] - r_can, xy[1] - r_can, 0.0]),
                      np.array([xy[0] + r_can, xy[1] + r_can, h_can]))
    # 0 ground: checker tiles of 0.5 with a little per-Gaussian colour noise.
    g = ground_size / 2
    if ground:
        u, v, spacing = _grid2(n_ground, ground_size, ground_size, rng)
        p = np.stack([u - g, v - g, np.zeros_like(u)], 1)
        base = _checker(0.5, [0.35, 0.35, 0.33], [0.55, 0.55, 0.5])
        parts[0] = _surfels(p, np.tile(ez, (len(p), 1)), spacing,
                            lambda q: np.clip(base(q) + rng.uniform(-0.03, 0.03, (len(q), 1)), 0, 1))
    boxes[0] = (np.array([-g, -g, 0.0]), np.array([g, g, 0.0]))

    order = sorted(parts)
    allp = _Part.cat([parts[lab] for lab in order])
    labels = np.concatenate([np.full(len(parts[lab].means), lab, np.int32) for lab in order])
    k_sh = num_sh_coeffs(int(sh_degree))
    sh = np.zeros((len(labels), k_sh, 3))
    sh[:, 0, :] = (allp.rgb - 0.5) / SH_C0
    if k_sh > 1:
        on = labels == 1
        sh[on, 1:, :] = rng.normal(0.0, 0.08, (int(on.sum()), k_sh - 1, 3))
    local = GaussianScene(allp.means, allp.quats, np.log(allp.sigmas),
                          np.full(len(labels), np.log(_OPACITY / (1 - _OPACITY))), sh)
    frame = _frame_for_up(up)
    scene = local.transformed(frame, origin, float(scale))
    lo = np.array([boxes[lab][0] for lab in range(8)])
    hi = np.array([boxes[lab][1] for lab in range(8)])
    names = {0: "ground", 1: "sphere", 2: "box", 3: "cup", 4: "cup contents", 5: "rod",
             6: "can 1", 7: "can 2"}
    return SyntheticScene(
        scene=scene, labels=labels, names=names,
        centers=origin + scale * (0.5 * (lo + hi)) @ frame.T,
        half_extents=scale * 0.5 * (hi - lo), frame=frame, up=up.copy(), origin=origin.copy(),
        scale=float(scale), seed=int(seed),
        meta={"same_class": [(6, 7)], "container": {3: 4}, "thin": [5], "view_dependent": [1]})


# ---------------------------------------------------------------------------
# composites
# ---------------------------------------------------------------------------
def parse_pose(pose, what: str = "pose") -> tuple[np.ndarray, np.ndarray, float]:
    """``(R, t, s)`` of a similarity ``x -> s R x + t``.

    Accepts ``None`` (identity), a 4x4 matrix ``[[s R, t], [0, 0, 0, 1]]``,
    or a tuple ``(R, t)`` / ``(R, t, s)`` (``R`` may be None).
    """
    if pose is None:
        return np.eye(3), np.zeros(3), 1.0
    if isinstance(pose, (tuple, list)) and len(pose) in (2, 3) and not np.isscalar(pose[0]):
        rot = np.eye(3) if pose[0] is None else np.asarray(pose[0], dtype=np.float64)
        t = np.asarray(pose[1], dtype=np.float64)
        s = float(pose[2]) if len(pose) == 3 else 1.0
    else:
        m = np.asarray(pose, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValidationError(f"{what} must be a 4x4 matrix or an (R, t[, s]) tuple, got shape {m.shape}")
        if not np.all(np.isfinite(m)) or not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValidationError(f"{what}: a 4x4 pose must be finite with last row [0, 0, 0, 1]")
        det = np.linalg.det(m[:3, :3])
        if det <= 0:
            raise ValidationError(f"{what}: the 3x3 block has determinant {det:.3g}; "
                                  "it must be a positive scale times a rotation")
        s = float(np.cbrt(det))
        rot, t = m[:3, :3] / s, m[:3, 3]
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)) or \
            not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5) or np.linalg.det(rot) < 0:
        raise ValidationError(f"{what}: rotation is not a proper rotation (a uniform scale times "
                              "an orthonormal matrix with determinant +1 is required)")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValidationError(f"{what}: translation must be a finite 3-vector, got {t.tolist()}")
    if not (np.isfinite(s) and s > 0):
        raise ValidationError(f"{what}: scale must be positive and finite, got {s}")
    return rot, t, s


def compose(background, objects, remove_overlap: bool = False,
            margin: float = 0.0) -> tuple[GaussianScene, np.ndarray]:
    """Place objects into a background scene with exact labels.

    Parameters
    ----------
    background : GaussianScene or None
        The scene to insert into (its Gaussians get label 0). None for none.
    objects : sequence of (GaussianScene, pose)
        Each object in its own coordinates and its pose: a 4x4 similarity
        ``[[s R, t], [0 0 0 1]]``, an ``(R, t)`` or ``(R, t, s)`` tuple, or
        None. The object is moved by ``x -> s R x + t`` with
        :meth:`GaussianScene.transformed`, which also rotates Gaussian
        orientations and SH coefficients.
    remove_overlap : bool
        Delete background Gaussians whose means fall inside an object's
        bounding volume: the axis-aligned box of the object's means in its
        own coordinates, grown by ``margin`` (world units), carried by the
        pose. Useful when inserting into a real scene, where the object
        would otherwise be buried in whatever occupied that space. The
        background of the returned scene then has fewer Gaussians than the
        input.
    margin : float
        Growth of that box in world units (>= 0).

    Returns
    -------
    scene : GaussianScene
        Background (kept Gaussians, original order) followed by the objects
        in order. SH degrees are unified to the highest; extra properties
        survive only if every part has them (see ``GaussianScene.concat``).
    labels : (N,) int32
        0 for background Gaussians, k for the k-th object (1-based).
    """
    if background is not None and not isinstance(background, GaussianScene):
        raise ValidationError(f"background must be a GaussianScene or None, got {type(background).__name__}")
    objects = list(objects)
    if background is None and not objects:
        raise ValidationError("compose needs a background or at least one object")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValidationError(f"margin must be a non-negative finite number, got {margin!r}")
    placed, keep = [], None
    if background is not None:
        keep = np.ones(len(background), bool)
    for k, item in enumerate(objects, start=1):
        if not (isinstance(item, (tuple, list)) and len(item) == 2):
            raise ValidationError(f"objects[{k - 1}] must be an (object_scene, pose) pair")
        obj, pose = item
        if not isinstance(obj, GaussianScene):
            raise ValidationError(f"objects[{k - 1}]: object must be a GaussianScene, got {type(obj).__name__}")
        if len(obj) == 0:
            raise ValidationError(f"objects[{k - 1}] has no Gaussians")
        rot, t, s = parse_pose(pose, f"objects[{k - 1}] pose")
        placed.append(obj.transformed(rot, t, s))
        if remove_overlap and background is not None:
            local = (background.means.astype(np.float64) - t) @ rot / s
            lo, hi = obj.means.min(0) - margin / s, obj.means.max(0) + margin / s
            keep &= ~np.all((local >= lo) & (local <= hi), axis=1)
    parts, labels = [], []
    if background is not None:
        bg = background if keep.all() else background.subset(keep)
        parts.append(bg)
        labels.append(np.zeros(len(bg), np.int32))
    for k, p in enumerate(placed, start=1):
        parts.append(p)
        labels.append(np.full(len(p), k, np.int32))
    return GaussianScene.concat(parts), np.concatenate(labels)


def pose_on_point(object_scene: GaussianScene, anchor, up, object_up=(0.0, 0.0, 1.0),
                  height: float | None = None, scale: float | None = None,
                  yaw_deg: float = 0.0, quantile: float = 0.0) -> np.ndarray:
    """Similarity that stands an object on a point, upright.

    The object's own up axis ``object_up`` is turned onto the world ``up``
    (smallest rotation, then ``yaw_deg`` about ``up``), the object is scaled
    and translated so that its bottom centre lands on ``anchor``. Bottom
    centre = the median of the means, moved along ``object_up`` to the lowest
    projection ``lo`` of the means; height = ``hi - lo``. ``quantile`` trims
    stray Gaussians: ``lo, hi`` are the ``quantile`` and ``1 - quantile``
    quantiles of ``means . object_up`` instead of min and max.

    Parameters
    ----------
    object_scene : GaussianScene
    anchor : (3,) world point for the object's bottom centre.
    up : (3,) world up direction.
    object_up : (3,) up direction in the object's coordinates.
    height : float, optional
        Scale the object to this world height. Exclusive with ``scale``.
    scale : float, optional
        Explicit scale factor (default 1 when ``height`` is not given).
    yaw_deg : float
        Turn about ``up`` after aligning, degrees.
    quantile : float
        In [0, 0.5).

    Returns
    -------
    (4, 4) float64 matrix ``[[s R, t], [0, 0, 0, 1]]`` for :func:`compose`.
    """
    if not isinstance(object_scene, GaussianScene) or len(object_scene) == 0:
        raise ValidationError("object_scene must be a non-empty GaussianScene")
    anchor = np.asarray(anchor, dtype=np.float64)
    if anchor.shape != (3,) or not np.all(np.isfinite(anchor)):
        raise ValidationError(f"anchor must be a finite 3-vector, got {np.asarray(anchor).tolist()}")
    up, object_up = _unit("up", up), _unit("object_up", object_up)
    if not 0 <= quantile < 0.5:
        raise ValidationError(f"quantile must be in [0, 0.5), got {quantile}")
    if height is not None and scale is not None:
        raise ValidationError("give either height or scale, not both")
    means = object_scene.means.astype(np.float64)
    h = means @ object_up
    lo, hi = np.quantile(h, [quantile, 1 - quantile]) if quantile > 0 else (h.min(), h.max())
    if height is not None:
        if not (np.isfinite(height) and height > 0):
            raise ValidationError(f"height must be positive, got {height!r}")
        if hi - lo <= 0:
            raise ValidationError("the object has no extent along object_up; pass scale instead of height")
        s = float(height) / (hi - lo)
    else:
        s = 1.0 if scale is None else float(scale)
        if not (np.isfinite(s) and s > 0):
            raise ValidationError(f"scale must be positive, got {scale!r}")
    rot = _axis_angle(up, np.radians(yaw_deg)) @ _rotation_between(object_up, up)
    c = np.median(means, axis=0)
    bottom = c + (lo - c @ object_up) * object_up
    m = np.eye(4)
    m[:3, :3] = s * rot
    m[:3, 3] = anchor - s * rot @ bottom
    return m


def surface_point(camera: Camera, depth, pixel) -> np.ndarray:
    """World point seen at a pixel, from a rendered expected-depth image.

    Back-projects pixel ``(x, y)`` (integer indices; the ray goes through its
    centre ``(x + 0.5, y + 0.5)``) to view depth ``z = depth[y, x]``:
    ``X_cam = ((x + 0.5 - cx) z / fx, (y + 0.5 - cy) z / fy, z)``, then
    ``X = R^T (X_cam - t)``. With ``depth`` from
    :func:`seed2gs_inverse.raster.render` this is where to stand
    an object with :func:`pose_on_point` ("put it there" in a real scene).

    Parameters
    ----------
    camera : Camera
    depth : (H, W) array, the camera's expected depth (0 where empty)
    pixel : (x, y) integers

    Returns
    -------
    (3,) float64 world point.
    """
    d = np.asarray(depth)
    if d.shape != camera.image_shape:
        raise ValidationError(f"depth has shape {d.shape}; camera {camera.name!r} is {camera.image_shape}")
    try:
        x, y = (int(v) for v in pixel)
    except (TypeError, ValueError):
        raise ValidationError(f"pixel must be an (x, y) pair of integers, got {pixel!r}") from None
    if not (0 <= x < camera.width and 0 <= y < camera.height):
        raise ValidationError(f"pixel ({x}, {y}) is outside the {camera.width}x{camera.height} image")
    z = float(d[y, x])
    if not (np.isfinite(z) and z > 0):
        raise ValidationError(f"nothing is rendered at pixel ({x}, {y}) (depth {z}); pick a covered pixel")
    v = np.array([(x + 0.5 - camera.cx) * z / camera.fx, (y + 0.5 - camera.cy) * z / camera.fy, z])
    return camera.rotation.T @ (v - camera.translation)


# ---------------------------------------------------------------------------
# masks: ground truth from labels, and noise models
# ---------------------------------------------------------------------------
def _selection(selected, n: int) -> np.ndarray:
    sel = np.asarray(selected)
    if sel.ndim != 1 or sel.shape[0] != n:
        raise ValidationError(f"'selected' has shape {sel.shape}; expected ({n},), one entry per Gaussian")
    if sel.dtype == bool:
        return sel.astype(np.float32)
    if sel.dtype.kind not in "fiu" or not np.all(np.isfinite(sel)) or sel.min() < 0 or sel.max() > 1:
        raise ValidationError("'selected' must be boolean or numbers in [0, 1] (a membership per Gaussian)")
    return sel.astype(np.float32)


def masks_from_labels(operators, selected, threshold: float | None = 0.5) -> list[np.ndarray]:
    """Ground-truth masks of a set of Gaussians, one per view.

    For view c the object's rendered weight is ``P(c) = W(c) l`` with
    ``l`` the 0/1 (or soft) membership, i.e. the fraction of each pixel's
    colour that the object contributes, occlusions included. The mask is
    ``P(c) > threshold``.

    Parameters
    ----------
    operators : OperatorStack or sequence
        Anything :func:`~seed2gs_inverse.operators.as_stack` accepts:
        ``ViewOperator`` items, sparse matrices or ``(W, (H, W))`` pairs (W
        sparse or dense). Needs only numpy/scipy.
    selected : (N,) bool or float in [0, 1]
        Membership of each Gaussian.
    threshold : float or None
        None returns the soft weight ``P(c)`` itself (float32 in [0, 1]).

    Returns
    -------
    list of (H, W) float32 arrays with values 0/1 (or soft).
    """
    if threshold is not None and not (np.isfinite(threshold) and 0 <= threshold < 1):
        raise ValidationError(f"threshold must be in [0, 1) or None, got {threshold!r}")
    from .operators import as_stack  # numpy/scipy only

    if isinstance(operators, (list, tuple)) and not operators:
        raise ValidationError("masks_from_labels needs at least one view")
    stack = as_stack(operators)
    sel = _selection(selected, stack.n_gaussians)
    out = []
    for view in stack:
        p = np.asarray(view.W @ sel, dtype=np.float32).reshape(view.image_shape)
        out.append(np.clip(p, 0, 1) if threshold is None else (p > threshold).astype(np.float32))
    return out


def render_label_masks(scene: GaussianScene, cameras, selected,
                       threshold: float | None = 0.5) -> list[np.ndarray]:
    """Ground-truth masks of ``selected`` Gaussians seen by ``cameras``.

    Builds each view's operator with
    :func:`seed2gs_inverse.raster.build_operator` and applies
    :func:`masks_from_labels`. Use the operators directly when you have
    them already (building is the expensive part).
    """
    from .raster import build_operator  # the renderer sits above this module

    cams = list(cameras)
    if not cams:
        raise ValidationError("render_label_masks needs at least one camera")
    _selection(selected, len(scene))
    return masks_from_labels([build_operator(scene, c) for c in cams], selected, threshold)


NOISE_KINDS = ("dilate", "erode", "drift", "drop", "identity_switch", "salt")
_DEFAULT_FRACTION = {"dilate": 1.0, "erode": 1.0, "drift": 1.0, "salt": 1.0,
                     "drop": 0.25, "identity_switch": 0.25}


def _check_masks(masks, what="masks") -> list[np.ndarray]:
    if isinstance(masks, np.ndarray) and masks.ndim == 2:
        raise ValidationError(f"'{what}' must be a list of (H, W) masks (or an (V, H, W) array), "
                              "got a single 2-D array")
    out = []
    for v, m in enumerate(masks):
        a = np.asarray(m)
        if a.ndim != 2:
            raise ValidationError(f"{what}[{v}] has shape {a.shape}; a mask must be (H, W)")
        if a.dtype.kind not in "biuf":
            raise ValidationError(f"{what}[{v}] has dtype {a.dtype}; expected bool or float")
        a = a.astype(np.float32)
        known = a[~np.isnan(a)]
        if known.size and (np.any(~np.isfinite(known)) or known.min() < 0 or known.max() > 1):
            raise ValidationError(f"{what}[{v}] has values outside [0, 1] (NaN is the only "
                                  "allowed non-number, meaning unknown)")
        out.append(a)
    if not out:
        raise ValidationError(f"'{what}' is empty")
    return out


def _disk_footprint(radius: int) -> np.ndarray:
    r = np.arange(-radius, radius + 1)
    return (r[:, None] ** 2 + r[None, :] ** 2) <= radius * radius


def _shift(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """Move the content by (dy, dx) pixels; pixels moving in from outside are 0."""
    h, w = mask.shape
    out = np.zeros_like(mask)
    if abs(dy) >= h or abs(dx) >= w:
        return out
    out[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = \
        mask[max(-dy, 0):h - max(dy, 0), max(-dx, 0):w - max(dx, 0)]
    return out


def perturb_masks(masks, kind: str, rng=None, strength=None, fraction: float | None = None,
                  other_masks=None, views=None, direction=None, growth: str = "linear",
                  return_views: bool = False):
    """Corrupt supervision masks the way a 2D tracker fails.

    Masks are float arrays in [0, 1], NaN = unknown; the input is not
    modified. The views to corrupt are ``views`` if given, else
    ``round(fraction * V)`` views drawn without replacement by ``rng``.

    ==================  ===========================================  ================
    kind                effect on each chosen view                   strength
    ==================  ===========================================  ================
    ``dilate``          grey dilation (max over a disk): the         radius px (2)
                        boundary grows outwards
    ``erode``           grey erosion (min over a disk)               radius px (2)
    ``drift``           content shifted by d px along ``direction``  d px (4)
                        (angle in degrees, or a (dx, dy) vector;
                        random when None). ``growth="linear"``:
                        view i of V moves ``d i / (V-1)`` (the first
                        view is exact, the last off by d, like a
                        tracker drifting along a clip);
                        ``"constant"``: every chosen view moves d.
                        Pixels entering from the border are 0.
    ``drop``            every pixel NaN (the view is lost)           unused
    ``identity_switch`` replaced by ``other_masks[i]`` (the tracker  unused
                        jumped to another object)
    ``salt``            each known pixel flips ``m -> 1 - m`` with   p (0.05)
                        probability p
    ==================  ===========================================  ================

    Dilation and erosion leave NaN pixels NaN and treat them as background
    while filtering, so unknown regions never spread evidence.

    Parameters
    ----------
    masks : sequence of (H, W) arrays
    kind : str
        One of ``NOISE_KINDS``.
    rng : numpy Generator, int seed or None
        Randomness (view choice, salt, random direction). Pass one for
        reproducible results.
    strength : float, optional
        See the table.
    fraction : float, optional
        Fraction of views to corrupt; default 1 for dilate, erode, drift
        and salt, 0.25 for drop and identity_switch.
    other_masks : sequence of (H, W) arrays
        Required for ``identity_switch``: another object's masks, same
        number and shapes.
    views : sequence of int, optional
        Exactly which views to corrupt (overrides ``fraction``).
    direction : float or (2,) array, optional
        Drift direction (degrees from +x towards +y, image axes, or a
        ``(dx, dy)`` vector).
    growth : {"linear", "constant"}
        Drift profile along the clip.
    return_views : bool
        Also return the sorted indices of the corrupted views.

    Returns
    -------
    list of (H, W) float32 masks, and the view indices if ``return_views``.
    """
    from scipy import ndimage

    if kind not in NOISE_KINDS:
        raise ValidationError(f"unknown noise kind {kind!r}; choose one of {', '.join(NOISE_KINDS)}")
    masks = _check_masks(masks)
    n = len(masks)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    if views is not None:
        chosen = np.unique(np.asarray(views, dtype=np.int64).ravel())
        if chosen.size and (chosen.min() < -n or chosen.max() >= n):
            raise ValidationError(f"views {np.asarray(views).tolist()} out of range for {n} masks")
        chosen = np.unique(chosen % n)
    else:
        frac = _DEFAULT_FRACTION[kind] if fraction is None else float(fraction)
        if not (np.isfinite(frac) and 0 <= frac <= 1):
            raise ValidationError(f"fraction must be in [0, 1], got {fraction!r}")
        chosen = np.sort(rng.choice(n, size=int(round(frac * n)), replace=False))
    others = None
    if kind == "identity_switch":
        if other_masks is None:
            raise ValidationError("identity_switch needs other_masks: the masks of the object "
                                  "the tracker switches to")
        others = _check_masks(other_masks, "other_masks")
        if len(others) != n:
            raise ValidationError(f"other_masks has {len(others)} masks; masks has {n}")
    defaults = {"dilate": 2, "erode": 2, "drift": 4, "salt": 0.05}
    s = defaults.get(kind) if strength is None else strength
    if kind in ("dilate", "erode"):
        if not (float(s).is_integer() and s >= 0):
            raise ValidationError(f"{kind} strength is a radius in pixels (integer >= 0), got {s!r}")
        foot = _disk_footprint(int(s))
    elif kind == "salt":
        if not (np.isfinite(s) and 0 <= s <= 1):
            raise ValidationError(f"salt strength is a flip probability in [0, 1], got {s!r}")
    elif kind == "drift":
        if not (np.isfinite(s) and s >= 0):
            raise ValidationError(f"drift strength is a distance in pixels (>= 0), got {s!r}")
        if growth not in ("linear", "constant"):
            raise ValidationError(f"growth must be 'linear' or 'constant', got {growth!r}")
        if direction is None:
            direction = rng.uniform(0, 360)
        d = np.asarray(direction, dtype=np.float64)
        if d.ndim == 0:
            d = np.array([np.cos(np.radians(d)), np.sin(np.radians(d))])
        if d.shape != (2,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValidationError(f"direction must be an angle in degrees or a non-zero (dx, dy), got {direction!r}")
        d = d / np.linalg.norm(d)

    out = [m.copy() for m in masks]
    for i in chosen:
        m = masks[i]
        unknown = np.isnan(m)
        if kind in ("dilate", "erode"):
            filled = np.where(unknown, 0.0, m).astype(np.float32)
            op = ndimage.grey_dilation if kind == "dilate" else ndimage.grey_erosion
            # Outside the image is background for both, so erosion eats in from the border too.
            r = op(filled, footprint=foot, mode="constant", cval=0.0)
            out[i] = np.where(unknown, np.nan, r).astype(np.float32)
        elif kind == "drift":
            f = (i / (n - 1) if n > 1 else 1.0) if growth == "linear" else 1.0
            dx, dy = np.rint(s * f * d).astype(int)
            out[i] = _shift(m, int(dy), int(dx))
        elif kind == "drop":
            out[i] = np.full_like(m, np.nan)
        elif kind == "identity_switch":
            if others[i].shape != m.shape:
                raise ValidationError(f"other_masks[{i}] has shape {others[i].shape}; masks[{i}] has {m.shape}")
            out[i] = others[i].copy()
        else:  # salt
            flip = (rng.random(m.shape) < s) & ~unknown
            out[i] = np.where(flip, 1.0 - m, m).astype(np.float32)
    return (out, [int(i) for i in chosen]) if return_views else out
