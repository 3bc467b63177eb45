"""Procedural scenes with exact per-Gaussian labels (:func:`make_scene`).

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
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..camera import Camera, look_at_orbit
from ..errors import ValidationError
from ..geometry import axis_angle, frame_for_up, rotation_between, unit_vector
from ..scene import GaussianScene, quat_multiply, quat_to_rotmat, rotmat_to_quat
from ..sh import SH_C0, num_sh_coeffs

__all__ = ["SyntheticScene", "make_scene"]

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))
_TANGENT_SIGMA = 0.7    # tangential std / sample spacing: neighbours overlap, no holes
_NORMAL_SIGMA = 0.1     # normal std / tangential std: flat surfels like a trained 3DGS
_OPACITY = 0.95


# ---------------------------------------------------------------------------
# surfels and primitives (local frame, +z up)
# ---------------------------------------------------------------------------
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
        from the local x axis, right-handed about ``up``; see
        :func:`seed2gs_inverse.camera.orbit_directions`) and elevation ``elevation_deg``
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
        # The directions equal camera.orbit_directions(up, frame[:, 0], az, el) up to
        # rounding; this form keeps the cameras bit-identical, so saved benchmark cases stay reproducible.
        dirs = []
        for i in range(n_views):
            az = np.radians(azimuth_deg + 360.0 * i / n_views)
            el = np.radians(elev[i])
            dirs.append(self.frame @ np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]))
        return look_at_orbit(c, np.array(dirs), dist, self.up, fov_y_deg, width, height,
                             names=[f"orbit_{i:03d}" for i in range(n_views)])

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
    n_per_object, n_ground, up, origin = _check_scene_args(seed, n_per_object, n_ground, ground,
                                                           ground_size, up, origin, scale, sh_degree)
    rng = np.random.default_rng(int(seed))
    # The draws from ``rng`` happen in this order (layout, objects 1..7, ground, SH): the same
    # arguments give the same arrays.
    lay = _layout(rng)
    parts, boxes = _object_parts(lay, n_per_object, rng)
    parts_0, boxes[0] = _ground_part(ground, n_ground, ground_size, rng)
    if parts_0 is not None:
        parts[0] = parts_0
    return _assemble(parts, boxes, int(sh_degree), rng, up, origin, float(scale), int(seed))


def _check_scene_args(seed, n_per_object, n_ground, ground, ground_size, up, origin, scale, sh_degree):
    """:func:`make_scene`'s arguments checked: ``(n_per_object, n_ground, unit up, origin)``."""
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
    up = unit_vector("up", up)
    origin = np.asarray(origin, dtype=np.float64)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise ValidationError(f"origin must be a finite 3-vector, got {np.asarray(origin).tolist()}")
    return n_per_object, n_ground, up, origin


_EZ = np.array([0.0, 0.0, 1.0])


def _placed(part, slot) -> _Part:
    """``part`` (object frame) yawed and moved to its ``slot`` ``(xy, yaw)`` of :func:`_layout`."""
    xy, yaw = slot
    return part.moved(axis_angle(_EZ, yaw), [xy[0], xy[1], 0.0])


def _yawed_box(slot, lo, hi) -> tuple:
    """Local AABB ``(lo, hi)`` of the box [lo, hi] (object frame) after the ``slot``'s yaw and shift."""
    xy, yaw = slot
    corners = np.array(np.meshgrid(*zip(lo, hi))).reshape(3, -1).T
    c = corners @ axis_angle(_EZ, yaw).T + [xy[0], xy[1], 0.0]
    return c.min(0), c.max(0)


def _object_parts(lay, n, rng) -> tuple:
    """Labels 1..7 in the local frame: ``({label: _Part}, {label: (lo, hi) box})``."""
    parts, boxes = {}, {}
    # 1 sphere: red, view-dependent colour (set after assembly).
    r_s = 0.3
    parts[1] = _placed(_sphere(n, r_s, [0, 0, r_s], rng, _const([0.8, 0.15, 0.1])), lay["sphere"])
    boxes[1] = _yawed_box(lay["sphere"], [-r_s, -r_s, 0], [r_s, r_s, 2 * r_s])
    # 2 box: checker texture.
    hb = np.array([0.3, 0.22, 0.2])
    parts[2] = _placed(_box(n, hb, [0, 0, hb[2]], rng,
                            _checker(0.1, [0.15, 0.3, 0.75], [0.95, 0.8, 0.2])), lay["box"])
    boxes[2] = _yawed_box(lay["box"], [-hb[0], -hb[1], 0], [hb[0], hb[1], 2 * hb[2]])
    _cup_parts(lay["cup"], n, rng, parts, boxes)
    parts[5], boxes[5] = _rod_part(lay["rod"], n)
    _can_parts(lay, n, rng, parts, boxes)
    return parts, boxes


def _cup_parts(slot, n, rng, parts, boxes) -> None:
    """3 cup: outer wall, inner wall, rim, inner floor; 4 contents: liquid + 3 balls (into ``parts``, ``boxes``)."""
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
    parts[3] = _placed(cup, slot)
    boxes[3] = _yawed_box(slot, [-rc, -rc, 0], [rc, rc, hc])
    r_liq, z_liq, r_ball = rc - tc - 0.01, 0.6 * hc, 0.055
    ball_xy = [(0.1, 0.0), (-0.05, 0.09), (-0.05, -0.09)]
    k = _split(n, [np.pi * r_liq ** 2] + [4 * np.pi * r_ball ** 2] * 3)
    contents = _Part.cat(
        [_disk(k[0], 0.0, r_liq, z_liq, [0, 0, 0], rng, _const([0.35, 0.2, 0.08]))]
        + [_sphere(k[i + 1], r_ball, [bx, by, z_liq + 0.02], rng, _const([1.0, 0.55, 0.1]))
           for i, (bx, by) in enumerate(ball_xy)])
    parts[4] = _placed(contents, slot)
    boxes[4] = _yawed_box(slot, [-r_liq, -r_liq, z_liq - r_ball + 0.02],
                          [r_liq, r_liq, z_liq + 0.02 + r_ball])


def _rod_part(slot, n) -> tuple:
    """5 rod: a thin chopstick slightly raised at one end, made of long Gaussians along its
    axis (3DGS represents thin structures this way); ``(part, box)``."""
    length, r_rod, z0, z1 = 0.8, 0.02, 0.03, 0.12
    n_rod = max(8, n // 8)
    axis = np.array([length, 0.0, z1 - z0])
    s = (np.arange(n_rod) + 0.5) / n_rod
    rod_means = np.array([-length / 2, 0.0, z0]) + s[:, None] * axis
    rot = rotation_between(np.array([1.0, 0, 0]), axis / np.linalg.norm(axis))
    step = np.linalg.norm(axis) / n_rod
    rod = _Part(rod_means, np.tile(rotmat_to_quat(rot), (n_rod, 1)),
                np.tile([max(0.8 * step, 1.5 * r_rod), 0.5 * r_rod, 0.5 * r_rod], (n_rod, 1)),
                np.tile([0.55, 0.35, 0.15], (n_rod, 1)))
    # The axis bounds the means: the box is the segment's extent.
    return _placed(rod, slot), _yawed_box(slot, [-length / 2, 0.0, z0], [length / 2, 0.0, z1])


def _can_stripes(p):
    band = np.floor(p[:, 2] / 0.05 + 1e-9).astype(np.int64) % 2
    return np.where(band[:, None] == 0, [0.1, 0.6, 0.2], [0.95, 0.95, 0.95])


def _can_parts(lay, n, rng, parts, boxes) -> None:
    """6, 7 cans: identical striped closed cylinders (same Gaussians, moved; into ``parts``, ``boxes``)."""
    r_can, h_can = 0.15, 0.35
    k = _split(n, [2 * np.pi * r_can * h_can, np.pi * r_can ** 2])
    can = _Part.cat([_cylinder_side(k[0], r_can, 0.0, h_can, [0, 0, 0], rng, _can_stripes),
                     _disk(k[1], 0.0, r_can, h_can, [0, 0, 0], rng, _const([0.7, 0.7, 0.72]))])
    for lab, key in ((6, "can 1"), (7, "can 2")):
        # The same yaw for both, so the twins are exact translated copies.
        xy, _ = lay[key]
        parts[lab] = can.moved(np.eye(3), [xy[0], xy[1], 0.0])
        boxes[lab] = (np.array([xy[0] - r_can, xy[1] - r_can, 0.0]),
                      np.array([xy[0] + r_can, xy[1] + r_can, h_can]))


def _ground_part(ground, n_ground, ground_size, rng) -> tuple:
    """0 ground: checker tiles of 0.5 with a little per-Gaussian colour noise; ``(part or None, box)``."""
    g = ground_size / 2
    part = None
    if ground:
        u, v, spacing = _grid2(n_ground, ground_size, ground_size, rng)
        p = np.stack([u - g, v - g, np.zeros_like(u)], 1)
        base = _checker(0.5, [0.35, 0.35, 0.33], [0.55, 0.55, 0.5])
        part = _surfels(p, np.tile(_EZ, (len(p), 1)), spacing,
                        lambda q: np.clip(base(q) + rng.uniform(-0.03, 0.03, (len(q), 1)), 0, 1))
    return part, (np.array([-g, -g, 0.0]), np.array([g, g, 0.0]))


_NAMES = {0: "ground", 1: "sphere", 2: "box", 3: "cup", 4: "cup contents", 5: "rod", 6: "can 1", 7: "can 2"}


def _assemble(parts, boxes, sh_degree, rng, up, origin, scale, seed) -> SyntheticScene:
    """The parts (local frame) as one scene in the world: ``x_world = origin + scale * F x_local``.

    The sphere (label 1) gets random view-dependent SH bands drawn here.
    """
    order = sorted(parts)
    allp = _Part.cat([parts[lab] for lab in order])
    labels = np.concatenate([np.full(len(parts[lab].means), lab, np.int32) for lab in order])
    k_sh = num_sh_coeffs(sh_degree)
    sh = np.zeros((len(labels), k_sh, 3))
    sh[:, 0, :] = (allp.rgb - 0.5) / SH_C0
    if k_sh > 1:
        on = labels == 1
        sh[on, 1:, :] = rng.normal(0.0, 0.08, (int(on.sum()), k_sh - 1, 3))
    local = GaussianScene(allp.means, allp.quats, np.log(allp.sigmas),
                          np.full(len(labels), np.log(_OPACITY / (1 - _OPACITY))), sh)
    frame = frame_for_up(up)
    scene = local.transformed(frame, origin, scale)
    lo = np.array([boxes[lab][0] for lab in range(8)])
    hi = np.array([boxes[lab][1] for lab in range(8)])
    return SyntheticScene(
        scene=scene, labels=labels, names=dict(_NAMES),
        centers=origin + scale * (0.5 * (lo + hi)) @ frame.T,
        half_extents=scale * 0.5 * (hi - lo), frame=frame, up=up.copy(), origin=origin.copy(),
        scale=scale, seed=seed,
        meta={"same_class": [(6, 7)], "container": {3: 4}, "thin": [5], "view_dependent": [1]})
