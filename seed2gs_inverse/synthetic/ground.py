r"""Procedural "ground with clutter" scenes with exact labels.

A test bed for whatever needs to know where "up" is and what rests on what:
the orbit axis (:mod:`seed2gs_inverse.pipeline.up_axis`), point prompts that
must return a whole object, and composite benchmarks.

Local frame and world frame
    Everything is built in a local frame with ``+z`` up and the ground near
    ``z = 0``, then mapped to the world by a rigid motion
    ``x_world = R x_local + t`` with ``R`` a uniformly random rotation (by
    seed), so no world axis is special. The true up is ``R e_z``.

Ground (label 0, ``"ground"``)
    A square of half-size ``extent`` covered by flat Gaussians whose normals
    follow the height field

    .. math::

        h(x, y) = a \left[\sin(k_1 x + \phi_1)\cos(k_2 y + \phi_2)
                  + \tfrac12 \sin(k_3 x + k_4 y + \phi_3)\right],

    with wavelengths of 2.5-6 (scene units are metres) and amplitude ``a =
    uneven`` (0: flat). The surface normal is
    :math:`n \propto (-\partial_x h, -\partial_y h, 1)`. The ground's mean
    plane is ``z = 0``: ``ground_point = t``, ``ground_normal = up``.

Clutter (label 1, ``"clutter"``): flat Gaussians that stand *vertical*
    grass blades (thin strips whose normals are horizontal, leaning at most
    15 degrees), a fence of planks, a wall, and bushes made of leaves whose
    normals are mostly horizontal. There are about twice as many vertical
    flat Gaussians as ground ones, so any "dominant normal" statistic of the
    splats points sideways, as on a real garden scan.

Objects (labels 2, 3, ...): resting on the ground, in contact
    ``"table"`` (round top, a skirt band below its rim and four legs),
    ``"box"``, ``"vase"`` (a surface of revolution with a floor), ``"plush"``
    (an ellipsoid body with a head). Each is built with its base at local
    ``z = 0`` and lowered onto the height field so that its lowest Gaussian
    centre touches it: :math:`\min_i (z_i - h(x_i, y_i)) = 0`. Colours are
    base colours times a fixed Lambertian shading
    :math:`0.45 + 0.55 \max(n \cdot \ell, 0)`, baked into the SH DC term as
    a trained 3DGS bakes its lighting (so a table top and its skirt differ
    in colour, as on real captures).

Surfels are flat Gaussians: tangential standard deviation ``0.7`` times the
sample spacing, normal one ``0.1`` times that, opacity 0.95.

:func:`place_object` stands any :class:`GaussianScene` (e.g. a real scan)
on the ground of a :class:`GroundScene` the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from ..geometry import rotation_between, unit_vector
from ..scene import GaussianScene, quat_to_rotmat
from ..sh import SH_C0
from .compose import height_range_scale

__all__ = ["GroundScene", "make_ground_scene", "place_object", "OBJECT_KINDS", "CLUTTER_KINDS",
           "random_rotation"]

#: Object kinds :func:`make_ground_scene` can build.
OBJECT_KINDS = ("table", "box", "vase", "plush")
#: Clutter kinds (all made of vertical flat Gaussians).
CLUTTER_KINDS = ("grass", "fence", "wall", "bushes")

_TANGENT = 0.7
_NORMAL = 0.1
_OPACITY = 0.95
_LIGHT = np.array([0.3, -0.4, 0.87]) / np.linalg.norm([0.3, -0.4, 0.87])
_FOOTPRINT = {"table": 0.36, "box": 0.25, "vase": 0.17, "plush": 0.2}


# ---------------------------------------------------------------------------
# geometry helpers
# ---------------------------------------------------------------------------
def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly distributed rotation matrix (normalised Gaussian quaternion)."""
    return quat_to_rotmat(rng.normal(size=4))


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _quats_from_frames(x_axis: np.ndarray, z_axis: np.ndarray) -> np.ndarray:
    """w-first quaternions of the rotations with columns ``(x, z cross x, z)``.

    ``z_axis`` (M, 3) unit normals; ``x_axis`` (M, 3) any vectors not parallel
    to them (made orthogonal here). Shepperd's method, vectorised.
    """
    z = z_axis / np.linalg.norm(z_axis, axis=1, keepdims=True)
    x = x_axis - np.sum(x_axis * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    m = np.stack([x, y, z], axis=2)  # columns
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)
    k = np.argmax(cand, axis=1)
    q = np.empty((len(m), 4))
    for case in range(4):
        i = k == case
        if not i.any():
            continue
        a = m[i]
        if case == 0:
            s = 2 * np.sqrt(1 + tr[i])
            q[i] = np.stack([0.25 * s, (a[:, 2, 1] - a[:, 1, 2]) / s, (a[:, 0, 2] - a[:, 2, 0]) / s,
                             (a[:, 1, 0] - a[:, 0, 1]) / s], 1)
        elif case == 1:
            s = 2 * np.sqrt(1 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2])
            q[i] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / s, 0.25 * s, (a[:, 0, 1] + a[:, 1, 0]) / s,
                             (a[:, 0, 2] + a[:, 2, 0]) / s], 1)
        elif case == 2:
            s = 2 * np.sqrt(1 + a[:, 1, 1] - a[:, 0, 0] - a[:, 2, 2])
            q[i] = np.stack([(a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 0, 1] + a[:, 1, 0]) / s, 0.25 * s,
                             (a[:, 1, 2] + a[:, 2, 1]) / s], 1)
        else:
            s = 2 * np.sqrt(1 + a[:, 2, 2] - a[:, 0, 0] - a[:, 1, 1])
            q[i] = np.stack([(a[:, 1, 0] - a[:, 0, 1]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s,
                             (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s], 1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _any_tangent(n: np.ndarray) -> np.ndarray:
    """A vector not parallel to each row of ``n``."""
    a = np.zeros_like(n)
    a[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    return a


@dataclass
class _Part:
    """Gaussians in the local frame (float64): means, quats, stds (M, 3), rgb."""

    means: np.ndarray
    quats: np.ndarray
    sigmas: np.ndarray
    rgb: np.ndarray

    @staticmethod
    def cat(parts) -> "_Part":
        parts = [p for p in parts if len(p.means)]
        return _Part(*(np.concatenate([getattr(p, f) for p in parts]) if parts else np.zeros((0, d))
                       for f, d in (("means", 3), ("quats", 4), ("sigmas", 3), ("rgb", 3))))

    def moved(self, rot: np.ndarray, t) -> "_Part":
        r = quat_to_rotmat(self.quats) if len(self.means) else np.zeros((0, 3, 3))
        r = rot @ r
        return _Part(self.means @ rot.T + np.asarray(t, float),
                     _quats_from_frames(r[:, :, 0], r[:, :, 2]), self.sigmas, self.rgb)

    def select(self, keep) -> "_Part":
        return _Part(self.means[keep], self.quats[keep], self.sigmas[keep], self.rgb[keep])


def _shade(rgb, normals) -> np.ndarray:
    """Base colour times the fixed Lambertian shading (two-sided for thin clutter)."""
    return np.clip(rgb * (0.45 + 0.55 * np.clip(normals @ _LIGHT, 0, 1))[:, None], 0, 1)


def _surfels(points, normals, spacing, rgb, tangents=None, sigmas=None) -> _Part:
    points = np.asarray(points, float)
    normals = np.asarray(normals, float)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    if sigmas is None:
        st = _TANGENT * np.broadcast_to(np.asarray(spacing, float), (len(points),))
        sigmas = np.stack([st, st, _NORMAL * st], 1)
    tangents = _any_tangent(normals) if tangents is None else tangents
    rgb = np.broadcast_to(np.asarray(rgb, float), points.shape)
    return _Part(points, _quats_from_frames(tangents, normals), np.asarray(sigmas, float),
                 _shade(rgb, normals))


def _jittered_grid(n, lo, hi, rng):
    """About ``n`` jittered points filling the box ``lo..hi`` (2-D); returns (u, v, spacing)."""
    lu, lv = hi[0] - lo[0], hi[1] - lo[1]
    nu = max(1, int(round(np.sqrt(n * lu / lv))))
    nv = max(1, int(round(n / nu)))
    du, dv = lu / nu, lv / nv
    uu, vv = np.meshgrid((np.arange(nu) + 0.5) * du, (np.arange(nv) + 0.5) * dv, indexing="ij")
    u = lo[0] + uu.ravel() + rng.uniform(-0.25, 0.25, uu.size) * du
    v = lo[1] + vv.ravel() + rng.uniform(-0.25, 0.25, vv.size) * dv
    return u, v, float(np.sqrt(du * dv))


# ---------------------------------------------------------------------------
# height field
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _HeightField:
    amplitude: float
    k: tuple
    phase: tuple

    def __call__(self, x, y):
        a, (k1, k2, k3, k4), (p1, p2, p3) = self.amplitude, self.k, self.phase
        return a * (np.sin(k1 * x + p1) * np.cos(k2 * y + p2) + 0.5 * np.sin(k3 * x + k4 * y + p3))

    def normal(self, x, y):
        a, (k1, k2, k3, k4), (p1, p2, p3) = self.amplitude, self.k, self.phase
        c3 = 0.5 * np.cos(k3 * x + k4 * y + p3)
        hx = a * (k1 * np.cos(k1 * x + p1) * np.cos(k2 * y + p2) + k3 * c3)
        hy = a * (-k2 * np.sin(k1 * x + p1) * np.sin(k2 * y + p2) + k4 * c3)
        n = np.stack([-hx, -hy, np.ones_like(hx)], -1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _height_field(amplitude, rng) -> _HeightField:
    k = tuple(2 * np.pi / rng.uniform(2.5, 6.0, 4))
    return _HeightField(float(amplitude), k, tuple(rng.uniform(0, 2 * np.pi, 3)))


# ---------------------------------------------------------------------------
# the scene record
# ---------------------------------------------------------------------------
@dataclass(eq=False)
class GroundScene:
    """A procedural ground scene with its exact truth.

    Attributes
    ----------
    scene : GaussianScene
    labels : (N,) int32
        Index into ``names``: 0 ground, 1 clutter, 2... objects.
    names : tuple of str
    up : (3,) float64
        True world up (``rotation @ e_z``).
    ground_point, ground_normal : (3,) float64
        A point of the ground's mean plane and its normal (``= up``).
    rotation : (3, 3), translation : (3,)
        ``x_world = rotation @ x_local + translation``.
    anchors : dict name -> (3,) world point
        Where each object touches the ground (its footprint centre, on the surface).
    heights : dict name -> float
        Object height above its anchor (local z extent of its means).
    """

    scene: GaussianScene
    labels: np.ndarray
    names: tuple
    up: np.ndarray
    ground_point: np.ndarray
    ground_normal: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    anchors: dict = field(default_factory=dict)
    heights: dict = field(default_factory=dict)
    _height_field: _HeightField | None = None
    _footprints: dict = field(default_factory=dict)

    @property
    def object_names(self) -> tuple:
        return tuple(self.names[2:])

    def label_of(self, name: str) -> int:
        if name not in self.names:
            raise ValidationError(f"no part named {name!r}; parts: {', '.join(self.names)}")
        return self.names.index(name)

    def object_mask(self, name: str) -> np.ndarray:
        """(N,) bool: the Gaussians of the named part."""
        return self.labels == self.label_of(name)

    def to_local(self, points) -> np.ndarray:
        """Local coordinates (ground frame, z up) of world points (M, 3)."""
        return (np.asarray(points, float) - self.translation) @ self.rotation

    def to_world(self, points) -> np.ndarray:
        return np.asarray(points, float) @ self.rotation.T + self.translation

    def ground_height(self, points) -> np.ndarray:
        """Height of world points above the ground *surface* (not its mean plane), (M,)."""
        p = self.to_local(np.atleast_2d(points))
        h = self._height_field(p[:, 0], p[:, 1]) if self._height_field is not None else 0.0
        return p[:, 2] - h

    def object_center(self, name: str) -> np.ndarray:
        """Centre of the named object's bounding box along ``up`` above its anchor (mid-height)."""
        return self.anchors[name] + 0.5 * self.heights[name] * self.up

    def camera(self, target, azimuth_deg: float, elevation_deg: float, distance: float,
               width: int = 320, height: int = 240, fov_y_deg: float = 50.0, name: str = "") -> Camera:
        """A level look-at camera (no roll) on a sphere about ``target``.

        ``target``: a world point or an object name (then its mid-height
        centre). Azimuth is measured about the true up from the local +x
        axis; elevation from the true ground plane (positive: looking down).
        """
        if isinstance(target, str):
            target = self.object_center(target)
        target = np.asarray(target, float)
        if target.shape != (3,) or not np.all(np.isfinite(target)):
            raise ValidationError(f"camera target must be a 3-vector or an object name, got {target!r}")
        if not (np.isfinite(distance) and distance > 0):
            raise ValidationError(f"camera distance must be positive, got {distance!r}")
        if not -89.0 <= float(elevation_deg) <= 89.0:
            raise ValidationError(f"elevation_deg must be in [-89, 89], got {elevation_deg!r}")
        az, el = np.radians(float(azimuth_deg)), np.radians(float(elevation_deg))
        d_local = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        eye = target + distance * (self.rotation @ d_local)
        return Camera.look_at(eye, target, self.up, fov_y_deg, width, height, name=name)

    def cameras(self, target, azimuths_deg, elevations_deg, distance: float, **kw) -> list:
        """:meth:`camera` for each (azimuth, elevation) pair (scalars broadcast)."""
        az, el = np.broadcast_arrays(np.atleast_1d(azimuths_deg), np.atleast_1d(elevations_deg))
        return [self.camera(target, a, e, distance, name=f"az{a:g}_el{e:g}", **kw)
                for a, e in zip(az.ravel(), el.ravel())]


# ---------------------------------------------------------------------------
# building blocks (local frame, +z up, base at z = 0)
# ---------------------------------------------------------------------------
def _disk(n, r, z, rng, rgb, normal_sign=1.0) -> _Part:
    i = np.arange(n) + 0.5
    rr = r * np.sqrt(i / n)
    th = np.pi * (3 - np.sqrt(5)) * i + rng.uniform(0, 2 * np.pi)
    p = np.stack([rr * np.cos(th), rr * np.sin(th), np.full(n, float(z))], 1)
    nrm = np.tile([0.0, 0.0, normal_sign], (n, 1))
    return _surfels(p, nrm, np.sqrt(np.pi * r * r / n), rgb)


def _cylinder(n, r, z0, z1, rng, rgb, center=(0.0, 0.0)) -> _Part:
    u, v, spacing = _jittered_grid(n, (0, z0), (2 * np.pi * r, z1), rng)
    th = u / r
    nrm = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], 1)
    p = np.stack([center[0] + r * nrm[:, 0], center[1] + r * nrm[:, 1], v], 1)
    return _surfels(p, nrm, spacing, rgb)


def _table(rng, n) -> _Part:
    r, h, skirt = 0.35, 0.55, 0.11
    white = np.array([0.93, 0.92, 0.88])
    parts = [_disk(int(0.42 * n), r, h, rng, white),
             _disk(int(0.2 * n), r, h - skirt, rng, white, -1.0),
             _cylinder(int(0.22 * n), r, h - skirt, h, rng, white)]
    for k in range(4):
        a = np.pi / 4 + k * np.pi / 2
        parts.append(_cylinder(int(0.04 * n), 0.025, 0.0, h - skirt, rng, white * 0.8,
                               center=(0.75 * r * np.cos(a), 0.75 * r * np.sin(a))))
    return _Part.cat(parts)


def _box(rng, n) -> _Part:
    half = np.array([0.2, 0.15, 0.14])
    center = np.array([0.0, 0.0, half[2]])
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
    parts = []
    for axis in range(3):
        i, j = [a for a in range(3) if a != axis]
        for sign in (-1.0, 1.0):
            m = max(4, int(round(n * areas[axis] / (2 * areas.sum()))))
            u, v, spacing = _jittered_grid(m, (-half[i], -half[j]), (half[i], half[j]), rng)
            p = np.zeros((u.size, 3))
            p[:, i], p[:, j], p[:, axis] = u, v, sign * half[axis]
            nrm = np.zeros_like(p)
            nrm[:, axis] = sign
            parts.append(_surfels(p + center, nrm, spacing, [0.75, 0.45, 0.2]))
    return _Part.cat(parts)


def _vase(rng, n) -> _Part:
    h = 0.42

    def radius(z):
        return 0.1 + 0.06 * np.sin(np.pi * z / h)

    u, v, spacing = _jittered_grid(int(0.85 * n), (0, 0), (2 * np.pi * 0.14, h), rng)
    th = u / 0.14
    r = radius(v)
    dr = 0.06 * np.pi / h * np.cos(np.pi * v / h)
    nrm = np.stack([np.cos(th), np.sin(th), -dr], 1)
    p = np.stack([r * np.cos(th), r * np.sin(th), v], 1)
    side = _surfels(p, nrm, spacing, [0.2, 0.35, 0.8])
    return _Part.cat([side, _disk(int(0.15 * n), 0.1, 0.0, rng, [0.2, 0.35, 0.8], -1.0)])


def _ellipsoid(n, radii, center, rng, rgb) -> _Part:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    th = np.pi * (3 - np.sqrt(5)) * i + rng.uniform(0, 2 * np.pi)
    d = np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    radii = np.asarray(radii, float)
    p = d * radii + np.asarray(center, float)
    nrm = d / radii
    area = 4 * np.pi * (np.prod(radii) ** (2 / 3))
    return _surfels(p, nrm, np.sqrt(area / n), rgb)


def _plush(rng, n) -> _Part:
    body = _ellipsoid(int(0.7 * n), (0.18, 0.14, 0.15), (0, 0, 0.15), rng, [0.85, 0.55, 0.7])
    head = _ellipsoid(int(0.3 * n), (0.1, 0.1, 0.1), (0.1, 0, 0.36), rng, [0.9, 0.65, 0.75])
    return _Part.cat([body, head])


_BUILDERS = {"table": _table, "box": _box, "vase": _vase, "plush": _plush}


# ---------------------------------------------------------------------------
# clutter (vertical flat Gaussians)
# ---------------------------------------------------------------------------
def _grass(rng, n_blades, extent, hf) -> _Part:
    """Blades: 3 stacked thin strips each; normals horizontal, lean <= 15 degrees."""
    xy = rng.uniform(-extent, extent, (n_blades, 2))
    az = rng.uniform(0, 2 * np.pi, n_blades)
    lean = np.radians(rng.uniform(0, 15, n_blades))
    lean_dir = rng.uniform(0, 2 * np.pi, n_blades)
    axis = np.stack([np.sin(lean) * np.cos(lean_dir), np.sin(lean) * np.sin(lean_dir), np.cos(lean)], 1)
    side = np.stack([np.cos(az), np.sin(az), np.zeros(n_blades)], 1)
    nrm = np.cross(axis, side)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    length = rng.uniform(0.08, 0.16, n_blades)
    base = np.column_stack([xy, hf(xy[:, 0], xy[:, 1])])
    parts = []
    for k in range(3):
        c = base + axis * (length * (k + 0.5) / 3)[:, None]
        seg = length / 3
        # Strip frame: x along the blade, z the normal; sigmas along, across, normal.
        sig = np.stack([0.5 * seg, np.full(n_blades, 0.004), np.full(n_blades, 0.0004)], 1)
        green = np.stack([rng.uniform(0.15, 0.3, n_blades), rng.uniform(0.45, 0.7, n_blades),
                          rng.uniform(0.1, 0.2, n_blades)], 1)
        parts.append(_surfels(c, nrm, None, green, tangents=axis, sigmas=sig))
    return _Part.cat(parts)


def _vertical_panel(n, p0, p1, z0, z1, rng, rgb, hf) -> _Part:
    """A vertical rectangle from ground point p0 to p1 (local xy), z from ground+z0 to ground+z1."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    length = np.linalg.norm(p1 - p0)
    u, v, spacing = _jittered_grid(n, (0, z0), (length, z1), rng)
    d = (p1 - p0) / length
    xy = p0 + u[:, None] * d
    p = np.column_stack([xy, hf(xy[:, 0], xy[:, 1]) + v])
    nrm = np.tile([-d[1], d[0], 0.0], (len(u), 1))
    return _surfels(p, nrm, spacing, rgb)


def _bush(rng, n, center_xy, radius, hf) -> _Part:
    """Leaves on a hemisphere-ish blob; normals horizontal +- 20 degrees."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = np.abs(d[:, 2])
    r = radius * rng.uniform(0.5, 1.0, n) ** (1 / 3)
    ground = hf(center_xy[0], center_xy[1])
    p = np.column_stack([center_xy[0] + r * d[:, 0], center_xy[1] + r * d[:, 1], ground + r * d[:, 2] * 1.2])
    az = rng.uniform(0, 2 * np.pi, n)
    tilt = np.radians(rng.uniform(-20, 20, n))
    nrm = np.stack([np.cos(az) * np.cos(tilt), np.sin(az) * np.cos(tilt), np.sin(tilt)], 1)
    leaf = rng.uniform(0.015, 0.03, n)
    sig = np.stack([leaf, 0.6 * leaf, 0.05 * leaf], 1)
    green = np.stack([rng.uniform(0.1, 0.25, n), rng.uniform(0.35, 0.55, n), rng.uniform(0.05, 0.15, n)], 1)
    return _surfels(p, nrm, None, green, sigmas=sig)


# ---------------------------------------------------------------------------
# assembly
# ---------------------------------------------------------------------------
def _to_gaussians(part: _Part) -> GaussianScene:
    n = len(part.means)
    sh = ((np.clip(part.rgb, 0, 1) - 0.5) / SH_C0)[:, None, :]
    return GaussianScene(part.means, part.quats, np.log(part.sigmas),
                         np.full(n, np.log(_OPACITY / (1 - _OPACITY))), sh)


def _layout(rng, kinds):
    """Footprint centres (local xy) and yaws: the first at the origin, the rest on a ring."""
    out = []
    start = rng.uniform(0, 2 * np.pi)
    for k, kind in enumerate(kinds):
        if k == 0:
            xy = np.zeros(2)
        else:
            a = start + 2 * np.pi * (k - 1) / max(len(kinds) - 1, 1) + rng.uniform(-0.3, 0.3)
            ring = _FOOTPRINT[kinds[0]] + _FOOTPRINT[kind] + rng.uniform(0.35, 0.6)
            xy = ring * np.array([np.cos(a), np.sin(a)])
        out.append((xy, rng.uniform(0, 2 * np.pi)))
    return out


def _rest_on(local_means: np.ndarray, hf, quantile: float = 0.0) -> float:
    """Vertical shift that makes ``min_i (z_i - h(x_i, y_i)) = 0`` (or its quantile)."""
    gap = local_means[:, 2] - hf(local_means[:, 0], local_means[:, 1])
    return -float(np.quantile(gap, quantile) if quantile > 0 else gap.min())


def make_ground_scene(seed: int = 0, objects=OBJECT_KINDS, clutter=CLUTTER_KINDS, *,
                      uneven: float = 0.03, extent: float = 3.0, density: float = 1.0,
                      n_per_object: int = 1500, rotate: bool = True) -> GroundScene:
    """A ground with vertical clutter and objects resting on it, in a random world pose.

    Parameters
    ----------
    seed : int
        Everything (layout, sampling, world rotation) is deterministic in it.
    objects : sequence of str
        Kinds from :data:`OBJECT_KINDS`, in label order (labels 2, 3, ...);
        a kind may repeat (named ``"box"``, ``"box_2"``, ...). The first
        stands at the local origin, the others on a ring around it.
    clutter : sequence of str
        Kinds from :data:`CLUTTER_KINDS` (may be empty).
    uneven : float
        Amplitude ``a`` of the height field (scene units; 0: flat ground).
    extent : float
        Half-size of the ground square.
    density : float
        Scales the number of ground and clutter Gaussians (1: about 6k
        ground and 27k vertical clutter Gaussians for ``extent = 3``).
    n_per_object : int
        Gaussians per object.
    rotate : bool
        Random world rotation and translation (True) or the identity.

    Returns
    -------
    GroundScene
    """
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise ValidationError(f"seed must be an integer, got {seed!r}") from None
    objects, clutter = tuple(objects), tuple(clutter)
    for kind in objects:
        if kind not in OBJECT_KINDS:
            raise ValidationError(f"unknown object kind {kind!r}; choose from {', '.join(OBJECT_KINDS)}")
    for kind in clutter:
        if kind not in CLUTTER_KINDS:
            raise ValidationError(f"unknown clutter kind {kind!r}; choose from {', '.join(CLUTTER_KINDS)}")
    for name, v, lo in (("uneven", uneven, 0.0), ("extent", extent, 1.0), ("density", density, 0.01)):
        if not (np.isfinite(v) and v >= lo) or (name != "uneven" and v <= 0):
            raise ValidationError(f"{name} must be a finite number >= {lo}, got {v!r}")
    if int(n_per_object) < 50:
        raise ValidationError(f"n_per_object must be >= 50, got {n_per_object!r}")
    rng = np.random.default_rng(seed)
    hf = _height_field(uneven, rng)
    ext = float(extent)

    # Objects first: clutter keeps out of their footprints.
    names = ["ground", "clutter"]
    obj_parts, anchors_local, heights, footprints = [], {}, {}, {}
    for kind, (xy, yaw) in zip(objects, _layout(rng, objects)):
        name = kind if kind not in names else f"{kind}_{sum(n.split('_')[0] == kind for n in names) + 1}"
        part = _BUILDERS[kind](rng, int(n_per_object)).moved(_rot_z(yaw), [xy[0], xy[1], 0.0])
        dz = _rest_on(part.means, hf)
        part.means[:, 2] += dz
        names.append(name)
        obj_parts.append(part)
        anchors_local[name] = np.array([xy[0], xy[1], hf(xy[0], xy[1])])
        heights[name] = float(np.ptp(part.means[:, 2]))
        footprints[name] = (xy, _FOOTPRINT[kind])

    # Ground.
    u, v, spacing = _jittered_grid(int(6000 * density * (ext / 3) ** 2), (-ext, -ext), (ext, ext), rng)
    gp = np.column_stack([u, v, hf(u, v)])
    tint = rng.uniform(0.85, 1.15, (len(u), 1))
    ground = _surfels(gp, hf.normal(u, v), spacing, np.clip(tint * [0.45, 0.38, 0.25], 0, 1))

    # Clutter.
    cl = []
    if "grass" in clutter:
        cl.append(_grass(rng, int(8000 * density * (ext / 3) ** 2), ext, hf))
    if "wall" in clutter:
        cl.append(_vertical_panel(int(1200 * density), (-0.9 * ext, 0.85 * ext), (0.9 * ext, 0.85 * ext),
                                  0.0, 1.5, rng, [0.75, 0.72, 0.68], hf))
    if "fence" in clutter:
        for k in range(12):
            y0 = -0.8 * ext + k * 1.5 * ext / 12
            cl.append(_vertical_panel(int(60 * density) + 4, (-0.85 * ext, y0), (-0.85 * ext, y0 + 0.1 * ext),
                                      0.0, 0.9, rng, [0.55, 0.4, 0.25], hf))
    if "bushes" in clutter:
        for _ in range(6):
            a, r = rng.uniform(0, 2 * np.pi), rng.uniform(0.55, 0.8) * ext
            cl.append(_bush(rng, int(300 * density), r * np.array([np.cos(a), np.sin(a)]), 0.3, hf))
    clutter_part = _Part.cat(cl) if cl else _Part.cat([])
    if len(clutter_part.means):
        keep = np.ones(len(clutter_part.means), bool)
        for xy, rad in footprints.values():
            keep &= np.linalg.norm(clutter_part.means[:, :2] - xy, axis=1) > rad + 0.05
        clutter_part = clutter_part.select(keep)

    parts = [ground, clutter_part] + obj_parts
    labels = np.concatenate([np.full(len(p.means), k if k < 2 else k, np.int32)
                             for k, p in enumerate(parts)])
    local = _Part.cat(parts)
    if rotate:
        rot = random_rotation(rng)
        t = rng.uniform(-2, 2, 3)
    else:
        rot, t = np.eye(3), np.zeros(3)
    world = local.moved(rot, t)
    up = rot[:, 2].copy()
    return GroundScene(_to_gaussians(world), labels, tuple(names), up, t.copy(), up.copy(), rot, t,
                       {k: a @ rot.T + t for k, a in anchors_local.items()}, heights, hf,
                       {k: (xy, r) for k, (xy, r) in footprints.items()})


def place_object(ground: GroundScene, obj: GaussianScene, at=(0.0, 0.0), *, object_up=(0.0, 0.0, 1.0),
                 height: float | None = None, scale: float | None = None, yaw_deg: float = 0.0,
                 quantile: float = 0.0, name: str = "object", clear_clutter: bool = True) -> GroundScene:
    """Stand an arbitrary object on the ground of ``ground``, in contact.

    The object is turned so that ``object_up`` (its own up, in its
    coordinates) becomes the ground's up, turned by ``yaw_deg`` about it,
    scaled (``height``: to that height along up; or ``scale``; default 1),
    its footprint centre (median of the means across up) moved over the
    local ground point ``at = (x, y)`` and lowered until its lowest Gaussian
    centre touches the ground surface: :math:`\\min_i (z_i - h(x_i, y_i)) = 0`
    (``quantile`` > 0 uses that quantile of the gaps instead, ignoring stray
    Gaussians below the object). The whole object moves rigidly with
    :meth:`GaussianScene.transformed`, so its SH colours turn with it.

    ``clear_clutter``: clutter Gaussians whose local xy lies within the
    object's footprint radius (+ 5 cm) are removed, so no grass grows through
    it. Returns a new :class:`GroundScene` with the object as the last label.
    """
    if not isinstance(ground, GroundScene):
        raise ValidationError(f"ground must be a GroundScene, got {type(ground).__name__}")
    if not isinstance(obj, GaussianScene) or len(obj) == 0:
        raise ValidationError("obj must be a non-empty GaussianScene")
    at = np.asarray(at, float)
    if at.shape != (2,) or not np.all(np.isfinite(at)):
        raise ValidationError(f"'at' must be a local ground point (x, y), got {np.asarray(at).tolist()}")
    if not 0 <= quantile < 0.5:
        raise ValidationError(f"quantile must be in [0, 0.5), got {quantile!r}")
    if height is not None and scale is not None:
        raise ValidationError("give either height or scale, not both")
    if name in ground.names:
        raise ValidationError(f"a part named {name!r} already exists; pass another name")
    obj_up = unit_vector("object_up", object_up)
    align = _rot_z(np.radians(yaw_deg)) @ rotation_between(obj_up, np.array([0.0, 0.0, 1.0]))
    p = obj.means.astype(np.float64) @ align.T
    _, s = height_range_scale(p[:, 2], height, scale, quantile)
    p = s * p
    shift = np.array([at[0], at[1], 0.0]) - np.array([*np.median(p[:, :2], axis=0), 0.0])
    p = p + shift
    hf = ground._height_field or _height_field(0.0, np.random.default_rng(0))
    shift[2] = _rest_on(p, hf, quantile)
    p[:, 2] += shift[2]
    # world = R_w (s A x + shift) + t_w
    rot = ground.rotation @ align
    moved = obj.transformed(rotation=rot, translation=ground.rotation @ shift + ground.translation, scale=s)
    keep = np.ones(len(ground.scene), bool)
    radius = float(np.max(np.linalg.norm(p[:, :2] - at, axis=1)))
    if quantile > 0:
        radius = float(np.quantile(np.linalg.norm(p[:, :2] - at, axis=1), 1 - quantile))
    if clear_clutter:
        local = ground.to_local(ground.scene.means)
        keep = ~((ground.labels == 1) & (np.linalg.norm(local[:, :2] - at, axis=1) <= radius + 0.05))
    base = ground.scene.subset(keep) if not keep.all() else ground.scene
    extra_keys = set(base.extra) & set(moved.extra)
    if set(base.extra) != extra_keys:
        base = GaussianScene(base.means, base.quats, base.log_scales, base.opacity_logits, base.sh)
    scene = GaussianScene.concat([base, moved])
    labels = np.concatenate([ground.labels[keep], np.full(len(moved), len(ground.names), np.int32)])
    anchor_local = np.array([at[0], at[1], float(hf(at[0], at[1]))])
    anchors = dict(ground.anchors)
    anchors[name] = ground.to_world(anchor_local[None])[0]
    heights = dict(ground.heights)
    heights[name] = float(np.ptp(p[:, 2]))
    fps = dict(ground._footprints)
    fps[name] = (at.copy(), radius)
    return GroundScene(scene, labels, ground.names + (name,), ground.up.copy(), ground.ground_point.copy(),
                       ground.ground_normal.copy(), ground.rotation.copy(), ground.translation.copy(),
                       anchors, heights, ground._height_field, fps)
