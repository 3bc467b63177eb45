"""Pinhole cameras in the OpenCV convention.

Axes: x right, y down, z forward (the camera looks along +z). A camera is its
image size, intrinsics ``fx, fy, cx, cy`` in pixels and the 4x4 rigid
``world_to_camera`` transform. Pixel ``(x, y)`` covers ``[x, x+1) x [y, y+1)``
and has its centre at ``(x + 0.5, y + 0.5)`` (gsplat convention), so a point
at camera coordinates ``(X, Y, Z)`` lands at ``(fx X/Z + cx, fy Y/Z + cy)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._validation import as_real
from .errors import ValidationError
from .geometry import axis_angle, unit_vector

__all__ = ["Camera", "MAX_IMAGE_SIDE", "look_at_orbit", "orbit_directions"]


#: Largest image side accepted (pixels). Larger sizes come from corrupt files
#: and would make rendering allocate terabytes.
MAX_IMAGE_SIDE = 32768


def _show(v) -> str:
    """A short rendering of a possibly enormous number for error messages."""
    try:
        return repr(v) if abs(v) < 1e15 else f"{float(v):.3g}"
    except OverflowError:
        return f"an integer of {len(str(abs(int(v))))} digits"


def _real(label, attr, value) -> float:
    """``value`` as a finite float, else ValidationError naming the camera and field."""
    v = as_real(value)
    if v is None:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValidationError(f"{label}: {attr} must be a number, got {value!r}")
        raise ValidationError(f"{label}: {attr} is not finite ({_show(value)})")
    return v


def _finite(name, value, shape=None):
    arr = np.asarray(value, dtype=np.float64)
    if shape is not None and arr.shape != shape:
        raise ValidationError(f"camera {name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValidationError(f"camera {name} has non-finite values: {arr.tolist()}")
    return arr


@dataclass(frozen=True, eq=False)
class Camera:
    """An OpenCV pinhole camera.

    Parameters
    ----------
    width, height : int
        Image size in pixels, 1 to ``MAX_IMAGE_SIDE`` (32768).
    fx, fy, cx, cy : float
        Intrinsics in pixels, finite; ``fx, fy > 0``.
    world_to_camera : (4, 4) array
        Rigid transform ``[R t; 0 1]``, finite, with ``R`` orthonormal
        (``|R R^T - I| <= 1e-4``) and ``det R = +1``.
    name : str
        Free-form label (file entry, view index), used in error messages.
    near : float
        Near clipping distance; Gaussians with view depth below it are culled.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: np.ndarray = field(default_factory=lambda: np.eye(4))
    name: str = ""
    near: float = 0.01

    def __post_init__(self):
        label = f"camera '{self.name}'" if self.name else "camera"
        for attr in ("width", "height"):
            v = getattr(self, attr)
            whole = isinstance(v, (int, np.integer)) or (
                isinstance(v, (float, np.floating)) and float(v).is_integer())
            if isinstance(v, bool) or not whole:
                raise ValidationError(f"{label}: {attr} must be an integer, got {v!r}")
            # compare before converting: int(1e308) or a 400-digit JSON integer is valid Python
            if v <= 0:
                raise ValidationError(f"{label}: {attr} must be positive, got {_show(v)}")
            if v > MAX_IMAGE_SIDE:
                raise ValidationError(f"{label}: {attr} must be at most {MAX_IMAGE_SIDE} pixels "
                                      f"(a corrupt file?), got {_show(v)}")
            object.__setattr__(self, attr, int(v))
        for attr in ("fx", "fy", "cx", "cy", "near"):
            object.__setattr__(self, attr, _real(label, attr, getattr(self, attr)))
        if self.fx <= 0 or self.fy <= 0:
            raise ValidationError(f"{label}: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.near <= 0:
            raise ValidationError(f"{label}: near plane must be positive, got {self.near}")
        try:
            m = np.asarray(self.world_to_camera, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise ValidationError(f"{label}: world_to_camera must be a 4x4 array of numbers") from None
        if m.shape != (4, 4):
            raise ValidationError(f"{label}: world_to_camera must be 4x4, got shape {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ValidationError(f"{label}: world_to_camera has non-finite values")
        rot = m[:3, :3]
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4) or np.linalg.det(rot) <= 0:
            raise ValidationError(
                f"{label}: world_to_camera rotation is not orthonormal with det +1 "
                f"(|R R^T - I| = {np.abs(rot @ rot.T - np.eye(3)).max():.2e}, det = {np.linalg.det(rot):.4f})")
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValidationError(f"{label}: world_to_camera last row must be [0, 0, 0, 1], got {m[3].tolist()}")
        m = m.copy()
        m.setflags(write=False)
        object.__setattr__(self, "world_to_camera", m)

    # -- constructors ------------------------------------------------------
    @classmethod
    def from_fov(cls, width, height, fov_y_deg, world_to_camera=None, **kw) -> "Camera":
        """Square pixels, principal point at the image centre, vertical field of view."""
        fov = float(fov_y_deg)
        if not 0 < fov < 180:
            raise ValidationError(f"fov_y_deg must be in (0, 180), got {fov}")
        f = 0.5 * int(height) / np.tan(np.radians(fov) / 2)
        w2c = np.eye(4) if world_to_camera is None else world_to_camera
        return cls(int(width), int(height), f, f, width / 2, height / 2, w2c, **kw)

    @classmethod
    def look_at(cls, eye, target, up, fov_y_deg: float, width: int, height: int, **kw) -> "Camera":
        """A camera at ``eye`` looking at ``target`` with image "up" along ``up``.

        ``up`` is a world direction that appears upwards in the image (camera
        -y); it only needs to be non-parallel to the viewing direction.
        """
        eye = _finite("eye", eye, (3,))
        target = _finite("target", target, (3,))
        up = _finite("up", up, (3,))
        unit_vector("up", up)  # refuses a zero up
        fwd = target - eye
        if np.linalg.norm(fwd) < 1e-12:
            raise ValidationError("look_at: eye and target coincide")
        z = fwd / np.linalg.norm(fwd)
        x = np.cross(z, up)  # camera x = down x forward = forward x up
        m = np.max(np.abs(up))  # the sine of the angle, whatever |up| is (scaled: no overflow)
        if np.linalg.norm(x / m) < 1e-6 * np.linalg.norm(up / m):  # within 1e-6 rad: no image right
            raise ValidationError("look_at: 'up' is parallel to the viewing direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        rot = np.stack([x, y, z])  # rows: camera axes in world coordinates
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ eye
        return cls.from_fov(width, height, fov_y_deg, w2c, **kw)

    @classmethod
    def from_camera_to_world(cls, width, height, fx, fy, cx, cy, camera_to_world, **kw) -> "Camera":
        c2w = _finite("camera_to_world", camera_to_world, (4, 4))
        if not np.allclose(c2w[3], [0, 0, 0, 1]):  # a scale or projective row would be dropped here
            raise ValidationError(f"camera_to_world last row must be [0, 0, 0, 1], got {c2w[3].tolist()}")
        rot = c2w[:3, :3]
        w2c = np.eye(4)
        w2c[:3, :3] = rot.T
        w2c[:3, 3] = -rot.T @ c2w[:3, 3]
        return cls(width, height, fx, fy, cx, cy, w2c, **kw)

    # -- derived quantities ---------------------------------------------------
    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation R (3, 3)."""
        return self.world_to_camera[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        """World-to-camera translation t (3,)."""
        return self.world_to_camera[:3, 3]

    @property
    def camera_to_world(self) -> np.ndarray:
        c2w = np.eye(4)
        c2w[:3, :3] = self.rotation.T
        c2w[:3, 3] = self.center
        return c2w

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, ``-R^T t``."""
        return -self.rotation.T @ self.translation

    @property
    def forward(self) -> np.ndarray:
        """Viewing direction (+z of the camera) in world coordinates."""
        return self.rotation[2].copy()

    @property
    def up(self) -> np.ndarray:
        """World direction that points up in the image (-y of the camera)."""
        return -self.rotation[1]

    @property
    def right(self) -> np.ndarray:
        return self.rotation[0].copy()

    @property
    def image_shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    @property
    def fov_x(self) -> float:
        """Horizontal field of view in radians."""
        return 2 * np.arctan(self.width / (2 * self.fx))

    @property
    def fov_y(self) -> float:
        """Vertical field of view in radians."""
        return 2 * np.arctan(self.height / (2 * self.fy))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def world_to_view(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame coordinates (M, 3) float64 of world points (M, 3)."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim not in (1, 2) or p.shape[-1] != 3:
            raise ValidationError(f"points must be an (M, 3) array, got shape {p.shape}")
        return p @ self.rotation.T + self.translation

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (M, 2) and view depths (M,) of world points.

        Points behind the camera get non-finite pixel coordinates.
        """
        if np.ndim(points) != 2:  # world_to_view also takes a lone (3,) point; this returns (M, 2) and (M,)
            raise ValidationError(f"points must be an (M, 3) array, got shape {np.shape(points)}; "
                                  f"for one point pass [point]")
        v = self.world_to_view(points)
        z = v[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * v[:, 0] / z + self.cx, self.fy * v[:, 1] / z + self.cy], 1)
        uv[z <= 0] = np.nan
        return uv, z

    def scaled(self, factor: float) -> "Camera":
        """The same view at ``factor`` times the resolution (intrinsics scaled)."""
        f = float(factor)
        if not (np.isfinite(f) and f > 0):
            raise ValidationError(f"scale factor must be positive, got {factor!r}")
        w = max(1, int(round(self.width * f)))
        h = max(1, int(round(self.height * f)))
        sx, sy = w / self.width, h / self.height
        return Camera(w, h, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy,
                      self.world_to_camera, self.name, self.near)

    def with_pose(self, world_to_camera) -> "Camera":
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy,
                      world_to_camera, self.name, self.near)

    # -- serialisation (no pickle) ---------------------------------------------
    def to_dict(self) -> dict:
        return {"name": self.name, "width": self.width, "height": self.height,
                "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "near": self.near, "world_to_camera": self.world_to_camera.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        if not isinstance(d, dict):
            raise ValidationError(f"camera description must be a mapping, got {type(d).__name__}")
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "world_to_camera") if k not in d]
        if missing:
            raise ValidationError(f"camera description lacks {missing}")
        try:
            return cls(d["width"], d["height"], d["fx"], d["fy"], d["cx"], d["cy"],
                       d["world_to_camera"], str(d.get("name", "")), d.get("near", 0.01))
        except (TypeError, ValueError, OverflowError) as exc:
            if isinstance(exc, ValidationError):
                raise
            raise ValidationError(f"camera description is malformed: {exc}") from None

    def __repr__(self) -> str:
        c = np.round(self.center, 3).tolist()
        return (f"Camera(name={self.name!r}, {self.width}x{self.height}, fx={self.fx:.2f}, "
                f"fy={self.fy:.2f}, cx={self.cx:.2f}, cy={self.cy:.2f}, center={c})")



def orbit_directions(axis, start, azimuths, elevations) -> np.ndarray:
    r"""Unit directions from an orbit centre to views at given azimuths and elevations.

    .. math::

        d_k = \cos\epsilon_k\, R(u, \alpha_k)\, s + \sin\epsilon_k\, u,

    with ``u = axis`` (unit), ``s = start`` (a unit vector perpendicular to
    ``u``: azimuth 0), :math:`R(u, \alpha)` the right-handed rotation about
    ``u`` (:func:`seed2gs_inverse.geometry.axis_angle`), azimuths
    :math:`\alpha_k` and elevations :math:`\epsilon_k` (above the plane
    perpendicular to ``u``) in radians. Returns (n, 3) float64.
    """
    u = _finite("orbit axis", axis, (3,))
    s = _finite("orbit start", start, (3,))
    # the preconditions are checked, not repaired: a repair would move the callers' orbits by a rounding
    if abs(np.linalg.norm(u) - 1) > 1e-6 or abs(np.linalg.norm(s) - 1) > 1e-6 or abs(u @ s) > 1e-6:
        raise ValidationError(f"orbit: axis and start must be unit vectors, start perpendicular to the axis; got "
                              f"|axis| = {np.linalg.norm(u):.6g}, |start| = {np.linalg.norm(s):.6g}, "
                              f"axis . start = {u @ s:.3g}")
    az = np.asarray(azimuths, dtype=np.float64).ravel()
    el = np.asarray(elevations, dtype=np.float64).ravel()
    if az.shape != el.shape:
        raise ValidationError(f"orbit: {az.size} azimuths but {el.size} elevations")
    out = np.empty((az.size, 3))
    for k, (a, e) in enumerate(zip(az, el)):
        out[k] = np.cos(e) * (axis_angle(u, a) @ s) + np.sin(e) * u
    return out


def look_at_orbit(center, directions, distance: float, up, fov_y_deg: float, width: int, height: int,
                  names=None) -> list:
    r"""Cameras at ``center + distance * directions[k]``, each looking at ``center``.

    The orbit helper of both the VAAS clips
    (:func:`seed2gs_inverse.pipeline.vaas.orbit_cameras`, directions from
    :func:`orbit_directions`) and the synthetic scenes
    (:meth:`seed2gs_inverse.synthetic.SyntheticScene.orbit_cameras`).

    Parameters
    ----------
    center : (3,) array
        What every camera looks at.
    directions : (n, 3) array
        Unit directions from ``center`` to the eyes.
    distance : float
        Distance of every eye from ``center``.
    up : (3,) array
        World direction that appears upwards in every image (:meth:`Camera.look_at`).
    fov_y_deg, width, height
        Intrinsics, as :meth:`Camera.from_fov`.
    names : sequence of str or None
        Camera names (default empty).

    Returns
    -------
    list of Camera
    """
    o = _finite("orbit center", center, (3,))
    dirs = _finite("orbit directions", directions).reshape(-1, 3)
    if names is not None and len(names) != len(dirs):
        raise ValidationError(f"orbit: {len(dirs)} views but {len(names)} names")
    return [Camera.look_at(o + distance * d, o, up, fov_y_deg, width, height,
                           **({} if names is None else {"name": names[k]})) for k, d in enumerate(dirs)]
