"""Helpers shared by the camera-file readers: labels, JSON numbers, rotations, Camera building.

Everything here is private to ``io``: the public entry points are in
``cameras.py``. Every message starts with a label naming the file and the
camera entry (:func:`camera_label`).
"""

from __future__ import annotations

import math
import os
import re

import numpy as np

from ..camera import Camera
from ..errors import FormatError, ValidationError

__all__: list[str] = []

#: Largest ``|R R^T - I|`` accepted as a rotation (then projected onto SO(3)):
#: rotations written as rounded text are orthonormal only to about this much.
ORTHO_SNAP = 1e-3


def camera_label(path, index, name) -> str:
    """``"PATH: camera INDEX ('NAME')"``, the start of every message about one camera entry."""
    return f"{os.fspath(path)}: camera {index}" + (f" ('{name}')" if name else "")


def json_number(label, key, value) -> float:
    """``value`` as a float when it is a JSON number (not a bool, not a string), else FormatError.

    Raises
    ------
    FormatError
        Not a number.
    ValidationError
        A JSON integer beyond float's range (JSON integers have no size limit).
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FormatError(f"{label}: '{key}' must be a number, got {str(value)[:60]!r}")
    try:
        return float(value)
    except OverflowError:
        raise ValidationError(f"{label}: '{key}' is out of range ({str(value)[:20]}... has "
                              f"{len(str(value))} digits)") from None


def json_matrix(label, key, value, shapes) -> np.ndarray:
    """``value`` as a float64 array whose shape is one of ``shapes``, else FormatError."""
    want = " or ".join("x".join(map(str, sh)) for sh in shapes)

    def numbers(v) -> bool:  # JSON numbers only: numpy would also take "1" and true
        if isinstance(v, list):
            return all(numbers(x) for x in v)
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    if not numbers(value):
        raise FormatError(f"{label}: '{key}' must be a {want} array of numbers, got {str(value)[:60]}")
    try:
        arr = np.array(value, dtype=np.float64)
    except OverflowError:  # a JSON integer beyond float range
        raise ValidationError(f"{label}: '{key}' holds a number out of range") from None
    except (TypeError, ValueError):
        raise FormatError(f"{label}: '{key}' must be a {want} array of numbers") from None
    if arr.shape not in shapes:
        raise FormatError(f"{label}: '{key}' has shape {arr.shape}; expected {want}")
    return arr


def focal_from_angle(label, key, angle, size) -> float:
    """Focal length ``size / (2 tan(angle / 2))`` in pixels of a field-of-view ``angle`` in radians."""
    angle = json_number(label, key, angle)
    if not 0 < angle < math.pi:
        raise ValidationError(f"{label}: '{key}' must be an angle in (0, pi) radians, got {angle}")
    return 0.5 * size / math.tan(0.5 * angle)


def proper_rotation(label, rot: np.ndarray) -> np.ndarray:
    """``rot`` if it is a rotation up to :data:`ORTHO_SNAP` (then snapped to SO(3) by SVD); else ValidationError."""
    if not np.all(np.isfinite(rot)):
        raise ValidationError(f"{label}: rotation has non-finite values")
    err = np.abs(rot @ rot.T - np.eye(3)).max()
    det = np.linalg.det(rot)
    if err > ORTHO_SNAP or det <= 0:
        raise ValidationError(f"{label}: rotation is not orthonormal with determinant +1 "
                              f"(|R R^T - I| = {err:.2e}, det = {det:.4f})")
    u, _, vt = np.linalg.svd(rot)
    return u @ vt


def check_whole_size(label, width, height) -> None:
    """Raise a ValidationError unless ``width`` and ``height`` are finite whole numbers."""
    for key, v in (("width", width), ("height", height)):
        if not (math.isfinite(v) and float(v).is_integer()):
            raise ValidationError(f"{label}: {key} must be a whole number, got {v}")


def camera_from_pose(label, name, width, height, fx, fy, cx, cy, c2w_rot, center) -> Camera:
    """Build and validate a Camera from its camera-to-world rotation (3, 3) and centre (3,)."""
    center = np.asarray(center, dtype=np.float64)
    if not np.all(np.isfinite(center)):
        raise ValidationError(f"{label}: camera position has non-finite values")
    rot = proper_rotation(label, np.asarray(c2w_rot, dtype=np.float64)).T  # world-to-camera
    w2c = np.eye(4)
    w2c[:3, :3] = rot
    w2c[:3, 3] = -rot @ center
    check_whole_size(label, width, height)
    try:
        return Camera(int(width), int(height), fx, fy, cx, cy, w2c, name=name)
    except ValidationError as exc:
        raise ValidationError(f"{label}: {without_camera_prefix(exc)}") from None


def without_camera_prefix(exc) -> str:
    """Camera's message without its own "camera 'NAME': " prefix (the label says it)."""
    return re.sub(r"^camera( '[^']*')?: ", "", str(exc), count=1)
