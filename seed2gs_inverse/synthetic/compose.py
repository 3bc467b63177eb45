"""Composites: objects inserted into a scene with exact labels.

``compose(background, [(object_scene, pose), ...])`` moves each object with
:meth:`GaussianScene.transformed` (SH rotated with it), concatenates and
labels background Gaussians 0 and the k-th object k. :func:`pose_on_point`
stands an object upright on a surface point, which :func:`surface_point`
reads off a rendered depth map.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import ValidationError
from ..geometry import axis_angle, rotation_between, unit_vector
from ..scene import GaussianScene

if TYPE_CHECKING:
    from ..camera import Camera

__all__ = ["parse_pose", "compose", "pose_on_point", "surface_point"]


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



def height_range_scale(h, height=None, scale=None, quantile: float = 0.0) -> tuple[float, float]:
    """``(lo, s)``: the object's low height and the scale that gives it ``height``.

    ``h`` (M,) are the heights of an object's Gaussians along its up axis;
    ``lo``/``hi`` are their ``quantile`` / ``1 - quantile`` quantiles (min and
    max for 0). ``s = height / (hi - lo)`` when ``height`` is given, else
    ``scale`` (default 1). Shared by :func:`pose_on_point` and
    :func:`~seed2gs_inverse.synthetic.ground.place_object`.
    """
    lo, hi = np.quantile(h, [quantile, 1 - quantile]) if quantile > 0 else (h.min(), h.max())
    if height is not None:
        if not (np.isfinite(height) and height > 0):
            raise ValidationError(f"height must be positive, got {height!r}")
        if hi - lo <= 0:
            raise ValidationError("the object has no extent along object_up; pass scale instead of height")
        return float(lo), float(height) / (hi - lo)
    s = 1.0 if scale is None else float(scale)
    if not (np.isfinite(s) and s > 0):
        raise ValidationError(f"scale must be positive, got {scale!r}")
    return float(lo), s

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
    up, object_up = unit_vector("up", up), unit_vector("object_up", object_up)
    if not 0 <= quantile < 0.5:
        raise ValidationError(f"quantile must be in [0, 0.5), got {quantile}")
    if height is not None and scale is not None:
        raise ValidationError("give either height or scale, not both")
    means = object_scene.means.astype(np.float64)
    h = means @ object_up
    lo, s = height_range_scale(h, height, scale, quantile)
    rot = axis_angle(up, np.radians(yaw_deg)) @ rotation_between(object_up, up)
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
