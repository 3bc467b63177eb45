"""3DGS ``cameras.json``: the camera file the 3DGS trainer writes.

A list of ``{id, img_name, width, height, position, rotation, fx, fy}``
where ``rotation`` is the camera-to-world rotation written row by row and
``position`` the camera centre; the principal point is the image centre
unless ``cx``/``cy`` are given (an extension :func:`write_cameras` uses only
when needed). Entries in the ``Camera.to_dict`` layout are accepted too, as
is a single such object instead of a list (:func:`~seed2gs_inverse.io.cameras.read_cameras`
decides that).
"""

from __future__ import annotations

import json

from ..camera import Camera
from ..errors import FormatError, ValidationError
from ._camera_common import camera_from_pose, camera_label, json_matrix, json_number, without_camera_prefix
from ._common import atomic_write, fail

__all__ = ["read_entry", "write_cameras"]


def read_entry(path, index, entry) -> Camera:
    """The camera of entry ``index`` (a parsed JSON object) of the file ``path``.

    Its name is the first of ``img_name``, ``name``, ``id`` that is given,
    else the index. An entry with ``world_to_camera`` is read by
    :meth:`Camera.from_dict`.

    Raises
    ------
    FormatError
        Not an object, a name that is not a string or number, missing keys.
    ValidationError
        Degenerate values (see :func:`~seed2gs_inverse.io.cameras.read_cameras`).
    """
    if not isinstance(entry, dict):
        raise fail(path, f"camera {index} is a {type(entry).__name__}, not an object")
    # the first of img_name, name, id that is given (null counts as not given: no camera named "None")
    name = next((entry[k] for k in ("img_name", "name", "id") if entry.get(k) is not None), index)
    if isinstance(name, bool) or not isinstance(name, (str, int, float)):
        raise fail(path, f"camera {index}: its name must be a string or a number, got {str(name)[:60]!r}")
    name = str(name)
    label = camera_label(path, index, name)
    if "world_to_camera" in entry:
        try:
            cam = Camera.from_dict(entry)
        except ValidationError as exc:
            raise ValidationError(f"{label}: {without_camera_prefix(exc)}") from None
        return cam if cam.name else Camera.from_dict({**entry, "name": name})
    missing = [k for k in ("width", "height", "position", "rotation", "fx", "fy") if k not in entry]
    if missing:
        raise FormatError(f"{label}: missing keys {missing}")
    width = json_number(label, "width", entry["width"])
    height = json_number(label, "height", entry["height"])
    fx = json_number(label, "fx", entry["fx"])
    fy = json_number(label, "fy", entry["fy"])
    cx = json_number(label, "cx", entry["cx"]) if "cx" in entry else width / 2
    cy = json_number(label, "cy", entry["cy"]) if "cy" in entry else height / 2
    rot = json_matrix(label, "rotation", entry["rotation"], [(3, 3)])
    pos = json_matrix(label, "position", entry["position"], [(3,)])
    return camera_from_pose(label, name, width, height, fx, fy, cx, cy, rot, pos)


def write_cameras(path, cameras) -> None:
    """Write cameras as a 3DGS ``cameras.json`` file, atomically.

    Each entry is ``{id, img_name, width, height, position, rotation, fx,
    fy}`` with the camera-to-world rotation written row by row; ``cx`` and
    ``cy`` are added only when the principal point is not the image centre.
    Reading the file back gives the same cameras (``near`` is not stored,
    and a camera without a name comes back named by its id, ``camera_<i>``).
    """
    cams = list(cameras)
    if not cams:
        raise ValidationError("write_cameras: no cameras to write (the file could not be read back)")
    for i, cam in enumerate(cams):
        if not isinstance(cam, Camera):
            raise ValidationError(f"write_cameras: item {i} is a {type(cam).__name__}, not a Camera")
    entries = []
    for i, cam in enumerate(cams):
        entry = {"id": i, "img_name": cam.name or f"camera_{i}",
                 "width": cam.width, "height": cam.height,
                 "position": cam.center.tolist(),
                 "rotation": cam.rotation.T.tolist(),
                 "fx": cam.fx, "fy": cam.fy}
        if cam.cx != cam.width / 2 or cam.cy != cam.height / 2:
            entry.update(cx=cam.cx, cy=cam.cy)
        entries.append(entry)
    atomic_write(path, [json.dumps(entries, indent=1).encode("utf-8")])

