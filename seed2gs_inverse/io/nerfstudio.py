"""nerfstudio ``transforms.json``.

``frames[i].transform_matrix`` is camera-to-world in OpenGL axes (x right,
y up, z back); its y and z columns are negated to get OpenCV axes.
Intrinsics ``fl_x, fl_y, cx, cy, w, h`` come from the frame or the top
level (``camera_angle_x`` is accepted in place of ``fl_x``, and
``camera_angle_y`` in place of ``fl_y``; without either ``fl_y = fl_x``).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import FormatError, ValidationError
from ._camera_common import camera_from_pose, camera_label, focal_from_angle, json_matrix, json_number
from ._common import fail, warn_caller

__all__ = ["read_transforms"]

_NS_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")
_NS_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")


def read_transforms(path, doc) -> list:
    """The cameras of a parsed nerfstudio ``transforms.json`` document ``doc`` (a dict with ``frames``) read from ``path``.

    Returns
    -------
    list of Camera
        One per frame, named by its ``file_path`` (else its index).

    Raises
    ------
    FormatError
        Missing or malformed keys, a camera model that is not a pinhole model.
    ValidationError
        Degenerate values; a ``transform_matrix`` whose last row is not ``[0, 0, 0, 1]``.

    Notes
    -----
    Lens distortion (``k1 .. k4``, ``p1``, ``p2``) is ignored with one warning.
    """
    frames = doc["frames"]
    if not isinstance(frames, list) or not frames:
        raise fail(path, "'frames' must be a non-empty list")
    cams = []
    distorted = 0
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise fail(path, f"frame {i} is a {type(frame).__name__}, not an object")
        name = str(frame.get("file_path", i))
        label = camera_label(path, i, name)

        def get(key, default=None):
            return frame[key] if key in frame else doc.get(key, default)

        model = get("camera_model", "OPENCV")
        if model not in _NS_MODELS:
            raise FormatError(f"{label}: camera model {model!r} is not a pinhole model "
                              f"(supported: {', '.join(_NS_MODELS)})")
        if get("w") is None or get("h") is None:
            raise FormatError(f"{label}: image size 'w' and 'h' are missing")
        w = json_number(label, "w", get("w"))
        h = json_number(label, "h", get("h"))
        if get("fl_x") is not None:
            fx = json_number(label, "fl_x", get("fl_x"))
        elif get("camera_angle_x") is not None:
            fx = focal_from_angle(label, "camera_angle_x", get("camera_angle_x"), w)
        else:
            raise FormatError(f"{label}: focal length 'fl_x' (or 'camera_angle_x') is missing")
        if get("fl_y") is not None:
            fy = json_number(label, "fl_y", get("fl_y"))
        elif get("camera_angle_y") is not None:
            fy = focal_from_angle(label, "camera_angle_y", get("camera_angle_y"), h)
        else:
            fy = fx
        cx = json_number(label, "cx", get("cx")) if get("cx") is not None else w / 2
        cy = json_number(label, "cy", get("cy")) if get("cy") is not None else h / 2
        if any(get(k) not in (None, 0, 0.0) for k in _NS_DISTORTION):
            distorted += 1
        if "transform_matrix" not in frame:
            raise FormatError(f"{label}: 'transform_matrix' is missing")
        m = json_matrix(label, "transform_matrix", frame["transform_matrix"], [(4, 4), (3, 4)])
        if not np.all(np.isfinite(m)):
            raise ValidationError(f"{label}: transform_matrix has non-finite values")
        if m.shape == (4, 4) and not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValidationError(f"{label}: transform_matrix last row must be [0, 0, 0, 1]")
        c2w = m[:3, :3] * np.array([1.0, -1.0, -1.0])  # OpenGL -> OpenCV camera axes
        cams.append(camera_from_pose(label, name, w, h, fx, fy, cx, cy, c2w, m[:3, 3]))
    if distorted:
        warn_caller(f"{os.fspath(path)}: lens distortion of {distorted} frames is ignored "
                    f"(pinhole projection is used)")
    return cams

