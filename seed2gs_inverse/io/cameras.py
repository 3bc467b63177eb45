"""Camera files: which format a path holds, and picking one camera by name or index.

All readers return :class:`~seed2gs_inverse.camera.Camera` objects in the
OpenCV convention (x right, y down, z forward) with ``name`` set from the
file, so cameras can be picked by name (:func:`read_camera`). One module per
format reads it:

``cameras.json`` (written by the 3DGS trainer)
    :mod:`.cameras_json`; also the format :func:`write_cameras` writes.
COLMAP sparse model (``cameras`` + ``images``, ``.txt`` or ``.bin``)
    :mod:`.colmap`. ``FILE:NAME`` also takes the name older 3DGS trainers
    gave a COLMAP image (:func:`trainer_name`: the file name without folders
    up to the first dot; their order differs for names such as ``a.png``
    and ``a-1.png``).
nerfstudio ``transforms.json``
    :mod:`.nerfstudio`.

Malformed files raise FormatError; degenerate values (non-positive focal
length or size, non-orthonormal rotation, non-finite numbers) raise
ValidationError. Both messages name the file and the camera entry.
Rotations that are orthonormal only to about 1e-3 (values rounded when
written as text) are projected onto the nearest rotation.
"""

from __future__ import annotations

import json
import os
import re
import struct
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import Seed2GSError, ValidationError
from . import cameras_json, colmap, nerfstudio
from ._common import check_regular, fail
from .cameras_json import write_cameras

if TYPE_CHECKING:
    from ..camera import Camera

__all__ = ["read_cameras", "read_camera", "write_cameras"]


def read_cameras(path) -> list:
    """Read every camera of a camera file or COLMAP model.

    Parameters
    ----------
    path : str or Path
        A ``.json`` file (3DGS ``cameras.json``, nerfstudio
        ``transforms.json`` or ``Camera.to_dict`` objects), a COLMAP
        ``cameras``/``images`` file (``.txt`` or ``.bin``; its partner is
        looked up next to it) or a directory holding a COLMAP model (also
        ``sparse/0`` or ``sparse`` below it).

    Returns
    -------
    list of Camera
        With ``name`` set from the file (``img_name``, image name or
        ``file_path``). See the module docstring for each layout.
    """
    try:
        return _read_cameras(Path(path))
    except Seed2GSError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, OverflowError, RecursionError,
            struct.error) as exc:
        # Last line of defence: an unforeseen corruption must still surface as
        # the documented error type, naming the file.
        raise fail(path, f"cannot read the cameras ({type(exc).__name__}: {exc})") from None


def _read_cameras(p: Path) -> list:
    """The cameras of ``p``, by what it is: a COLMAP directory or file, or a JSON file of either layout."""
    if p.is_dir():
        return colmap.read_model_dir(p)
    if not p.exists() and ":" in p.name and Path(str(p).rsplit(":", 1)[0]).exists():
        raise fail(p, "no such file; FILE:NAME picks one camera where one is expected (--camera), but here "
                      "every camera of a file is read: give the file alone")
    if p.name.lower() in ("cameras.txt", "images.txt", "cameras.bin", "images.bin"):
        return colmap.read_model(p.parent, p.suffix.lower())
    if p.suffix.lower() != ".json":
        raise fail(p, "unknown camera file (expected a .json file, a COLMAP cameras/images "
                      "file or a directory holding a COLMAP model)")
    check_regular(p, "camera file")
    with open(p, "rb") as fh:
        raw = fh.read()
    try:
        doc = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        raise fail(p, f"not valid JSON ({exc})") from None
    if isinstance(doc, dict) and "frames" in doc:
        return nerfstudio.read_transforms(p, doc)
    if isinstance(doc, dict):
        doc = [doc]
    if not isinstance(doc, list):
        raise fail(p, "expected a list of cameras (3DGS cameras.json) or an object with "
                      "'frames' (nerfstudio transforms.json)")
    if not doc:
        raise fail(p, "holds no cameras")
    return [cameras_json.read_entry(p, i, entry) for i, entry in enumerate(doc)]


def split_camera_spec(spec, exists=os.path.exists) -> tuple:
    """``(FILE, NAME or INDEX or None)`` of a camera spec ``FILE[:NAME|INDEX]``, as :func:`read_camera` reads it.

    A spec that exists is a file (or COLMAP directory) alone. Otherwise the
    file is the longest prefix before a colon that exists, so names may hold
    colons (``"cams.json:frame:1"``); with none, the last colon (a read then
    names that missing file). ``exists`` lets a caller resolve relative
    paths its own way.
    """
    spec = os.fspath(spec)
    if exists(spec) or ":" not in spec:
        return spec, None
    cuts = [i for i, ch in enumerate(spec) if ch == ":"]
    cut = next((i for i in reversed(cuts) if exists(spec[:i])), cuts[-1])
    return spec[:cut], spec[cut + 1:]


def trainer_name(name: str) -> str:
    """Older 3DGS trainers' ``image_name`` of an image file name: no folders, up to the first dot."""
    return os.path.basename(name).split(".")[0]


def read_camera(spec) -> Camera:
    """One camera from ``"FILE"``, ``"FILE:NAME"`` or ``"FILE:INDEX"``.

    A name matches the camera's ``name`` (it may hold colons: the file is the
    longest existing path before one; a name several cameras share is an
    error), else its :func:`trainer_name`; otherwise an integer selects by
    position (negative counts from the end). Without a selector the file
    must hold exactly one camera.
    Example: ``read_camera("cams.json:overview")``.
    """
    path, selector = split_camera_spec(spec)
    cams = read_cameras(path)
    names = ", ".join(c.name or str(i) for i, c in enumerate(cams[:10]))
    names += ", ..." if len(cams) > 10 else ""
    if selector is None:
        if len(cams) == 1:
            return cams[0]
        raise ValidationError(f"{path} holds {len(cams)} cameras; pick one with {path}:NAME or "
                              f"{path}:INDEX (names: {names})")
    named = [i for i, cam in enumerate(cams) if cam.name == selector]
    if not named:  # older 3DGS trainers' name of a COLMAP image ("images/a.png" is "a" in their cameras.json)
        named = [i for i, cam in enumerate(cams) if cam.name and trainer_name(cam.name) == selector]
    if len(named) > 1:
        raise ValidationError(f"{path} holds {len(named)} cameras named '{selector}' (indices "
                              f"{', '.join(map(str, named[:10]))}); pick one by index, {path}:INDEX")
    if named:
        return cams[named[0]]
    # an index is plain ASCII digits (int() would also read "1_0" as 10 and " 1 " or full-width digits)
    if not re.fullmatch(r"-?[0-9]+", selector):
        raise ValidationError(f"{path} has no camera named '{selector}' (names: {names})")
    index = int(selector)
    if not -len(cams) <= index < len(cams):
        raise ValidationError(f"{path} holds {len(cams)} cameras; index {index} is out of range")
    return cams[index]

