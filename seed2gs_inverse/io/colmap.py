"""COLMAP sparse models: ``cameras`` + ``images``, text (``.txt``) or binary (``.bin``).

Images hold the world-to-camera rotation as a w-first quaternion and the
translation; cameras the model and its parameters. Pinhole-like models
(SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV) give ``fx, fy, cx,
cy``; their distortion is ignored with a warning (undistort the images with
COLMAP for exact results). Cameras are sorted by their COLMAP image name, as
the 3DGS trainer's reader sorts them and names them in its ``cameras.json``
(:func:`~seed2gs_inverse.io.cameras.trainer_name` gives the name other 3DGS
trainers use).
"""

from __future__ import annotations

import os
import re
import struct
from typing import TYPE_CHECKING

import numpy as np

from ..camera import Camera
from ..errors import FormatError, ValidationError
from ..scene import quat_to_rotmat
from ._camera_common import camera_from_pose, check_whole_size, without_camera_prefix
from ._common import fail, warn_caller

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["read_model", "read_model_dir"]

# model id -> (name, number of parameters); from COLMAP's camera_models.h.
_COLMAP_MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4),
                  3: ("RADIAL", 5), 4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8),
                  6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
                  9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
                  11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16)}
_COLMAP_NPARAMS = {name: n for name, n in _COLMAP_MODELS.values()}


def _colmap_intrinsics(label, model, params):
    """fx, fy, cx, cy and whether distortion is non-zero, for pinhole-like models."""
    p = list(params)
    if model == "SIMPLE_PINHOLE":
        return p[0], p[0], p[1], p[2], False
    if model == "PINHOLE":
        return p[0], p[1], p[2], p[3], False
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        return p[0], p[0], p[1], p[2], any(v != 0 for v in p[3:])
    if model == "OPENCV":
        return p[0], p[1], p[2], p[3], any(v != 0 for v in p[4:])
    raise FormatError(f"{label}: COLMAP camera model {model} is not a pinhole model; undistort "
                      f"the images first (colmap image_undistorter)")


def _check_intrinsics(label, width, height, fx, fy, cx, cy) -> None:
    """Validate image size and intrinsics where they are stored (Camera's own checks)."""
    check_whole_size(label, width, height)
    try:
        Camera(int(width), int(height), fx, fy, cx, cy)
    except ValidationError as exc:
        raise ValidationError(f"{label}: {without_camera_prefix(exc)}") from None


def read_model_dir(d: Path) -> list:
    """The cameras of the COLMAP model in directory ``d`` (or in ``d/sparse/0``, ``d/sparse``), binary first.

    Raises
    ------
    FormatError
        No model there (a saved operator directory is named as such).
    """
    for sub in (d, d / "sparse" / "0", d / "sparse"):
        for ext in (".bin", ".txt"):
            if (sub / f"cameras{ext}").is_file() and (sub / f"images{ext}").is_file():
                return read_model(sub, ext)
    if (d / "manifest.json").is_file():
        raise fail(d, "this is a saved operator directory, not cameras; use 'seed2gs operators info'")
    raise fail(d, "directory holds no COLMAP model (cameras + images, .bin or .txt, "
                  "also looked in sparse/0 and sparse)")


def read_model(d: Path, ext: str) -> list:
    """The cameras of the COLMAP model ``d/cameras{ext}`` + ``d/images{ext}`` (``ext``: ``".txt"`` or ``".bin"``).

    Returns
    -------
    list of Camera
        One per image, sorted and named by the COLMAP image name.

    Raises
    ------
    FormatError
        A missing or malformed file, an image of an unknown camera, a camera model that is not pinhole-like.
    ValidationError
        Degenerate values (non-finite pose, zero quaternion, bad intrinsics).

    Notes
    -----
    An image's pose is the world-to-camera rotation ``R`` (from the w-first
    quaternion) and translation ``t``: the camera-to-world rotation is
    ``R^T`` and the centre ``-R^T t``. Distortion of pinhole-like models is
    ignored with one warning.
    """
    cam_path, img_path = d / f"cameras{ext}", d / f"images{ext}"
    for p in (cam_path, img_path):
        if not p.is_file():
            raise fail(p, "missing: a COLMAP model needs both cameras and images files")
    if ext == ".bin":
        intr = _colmap_cameras_bin(cam_path)
        images = _colmap_images_bin(img_path)
    else:
        intr = _colmap_cameras_txt(cam_path)
        images = _colmap_images_txt(img_path)
    if not images:
        raise fail(img_path, "holds no images")
    cams = []
    distorted = 0
    for index, (image_id, qvec, tvec, cam_id, name) in enumerate(sorted(images, key=lambda r: r[4])):
        label = f"{os.fspath(img_path)}: image {image_id} ('{name}')"
        if cam_id not in intr:
            raise FormatError(f"{label}: refers to camera {cam_id}, which {cam_path.name} lacks")
        model, width, height, params, where = intr[cam_id]
        fx, fy, cx, cy, dist = _colmap_intrinsics(label, model, params)
        _check_intrinsics(f"{os.fspath(cam_path)} ({where}): camera {cam_id} ({model})",
                          width, height, fx, fy, cx, cy)
        distorted += dist
        q = np.asarray(qvec, dtype=np.float64)
        t = np.asarray(tvec, dtype=np.float64)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            raise ValidationError(f"{label}: pose has non-finite values")
        if np.linalg.norm(q) < 1e-12:
            raise ValidationError(f"{label}: rotation quaternion has zero length")
        rot = quat_to_rotmat(q)  # world-to-camera
        cams.append(camera_from_pose(label, name, width, height, fx, fy, cx, cy, rot.T, -rot.T @ t))
    if distorted:
        warn_caller(f"{os.fspath(cam_path)}: lens distortion of {distorted} images is ignored "
                    f"(pinhole projection is used)")
    return cams


# COLMAP ids are 32-bit unsigned; str.isdigit() would accept '²' (and int() then fail)
_ID_RE = re.compile(r"^[0-9]{1,10}$")


def _text_lines(path):
    with open(path, "rb") as fh:
        raw = fh.read()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise fail(path, "not a text file (invalid UTF-8)") from None
    return text.splitlines()


def _floats(path, lineno, words):
    try:
        return [float(w) for w in words]
    except ValueError:
        raise fail(path, f"line {lineno}: expected numbers, got {' '.join(words)!r}") from None


def _colmap_cameras_txt(path) -> dict:
    out = {}
    for lineno, line in enumerate(_text_lines(path), 1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if len(words) < 4 or not _ID_RE.match(words[0]):
            raise fail(path, f"line {lineno}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...' "
                             f"with CAMERA_ID a whole number, got {line.strip()[:60]!r}")
        model = words[1]
        if model not in _COLMAP_NPARAMS:
            raise fail(path, f"line {lineno}: unknown camera model {model!r}")
        if len(words) != 4 + _COLMAP_NPARAMS[model]:
            raise fail(path, f"line {lineno}: model {model} takes {_COLMAP_NPARAMS[model]} "
                             f"parameters, found {len(words) - 4}")
        size = _floats(path, lineno, words[2:4])
        cam_id = int(words[0])
        if cam_id in out:
            raise fail(path, f"line {lineno}: camera {cam_id} is defined twice (also {out[cam_id][4]}); "
                             "camera ids are unique")
        out[cam_id] = (model, size[0], size[1], _floats(path, lineno, words[4:]), f"line {lineno}")
    return out


def _colmap_images_txt(path) -> list:
    lines = _text_lines(path)
    out = []
    i = 0
    while i < len(lines):
        words = lines[i].split()
        lineno = i + 1
        i += 1
        if not words or words[0].startswith("#"):
            continue
        # IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME; the next line lists
        # the 2-D points (possibly empty) and is skipped.
        if len(words) < 10 or not _ID_RE.match(words[0]) or not _ID_RE.match(words[8]):
            raise fail(path, f"line {lineno}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME' "
                             f"with whole-number ids, got {lines[i - 1].strip()[:60]!r}")
        vals = _floats(path, lineno, words[1:8])
        out.append((int(words[0]), vals[:4], vals[4:], int(words[8]), " ".join(words[9:])))
        if i < len(lines):
            _points2d_line(path, i + 1, lines[i])
        i += 1
    return out


def _points2d_line(path, lineno: int, line: str) -> None:
    """Check that the line after an image line is its POINTS2D list ``X Y POINT3D_ID ...`` (possibly empty).

    Without the check, a file written without those lines would lose every second image silently.
    """
    words = line.split()
    ok = len(words) % 3 == 0
    if ok:  # the first triple is enough to tell an image line (a name, ids) from points
        try:
            [float(w) for w in words[:3]]
        except ValueError:
            ok = False
    if not ok:
        raise fail(path, f"line {lineno}: expected the POINTS2D line of the image above ('X Y POINT3D_ID ...', "
                         f"possibly empty), got {line.strip()[:60]!r}; each image line is followed by one")


class _Reader:
    """Bounds-checked little-endian reads from a bytes buffer."""

    def __init__(self, path, data: bytes):
        self.path, self.data, self.pos = path, data, 0

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise fail(self.path, f"file is truncated at byte {self.pos} "
                                  f"(needs {size} more bytes, {len(self.data) - self.pos} left)")
        vals = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return vals

    def skip(self, nbytes: int):
        if self.pos + nbytes > len(self.data):
            raise fail(self.path, f"file is truncated at byte {self.pos} "
                                  f"(a record claims {nbytes} more bytes)")
        self.pos += nbytes

    def cstring(self) -> str:
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise fail(self.path, f"file is truncated: unterminated image name at byte {self.pos}")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise fail(self.path, f"image name at byte {self.pos} is not valid UTF-8") from None

    def done(self):
        if self.pos != len(self.data):
            raise fail(self.path, f"{len(self.data) - self.pos} unexpected bytes after the last record")


def _read_bytes(path) -> bytes:
    with open(path, "rb") as fh:
        return fh.read()


def _colmap_cameras_bin(path) -> dict:
    r = _Reader(path, _read_bytes(path))
    (count,) = r.take("<Q")
    out = {}
    for record in range(count):
        cam_id, model_id, width, height = r.take("<iiQQ")
        if model_id not in _COLMAP_MODELS:
            raise fail(path, f"camera {cam_id} has unknown model id {model_id}")
        model, nparams = _COLMAP_MODELS[model_id]
        if cam_id in out:
            raise fail(path, f"record {record}: camera {cam_id} is defined twice (also {out[cam_id][4]}); "
                             "camera ids are unique")
        out[cam_id] = (model, float(width), float(height), list(r.take(f"<{nparams}d")),
                       f"record {record}")
    r.done()
    return out


def _colmap_images_bin(path) -> list:
    r = _Reader(path, _read_bytes(path))
    (count,) = r.take("<Q")
    out = []
    for _ in range(count):
        image_id, qw, qx, qy, qz, tx, ty, tz, cam_id = r.take("<idddddddi")
        name = r.cstring()
        (npoints,) = r.take("<Q")
        r.skip(24 * npoints)  # (x, y, point3D_id) per 2-D point; not needed
        out.append((image_id, [qw, qx, qy, qz], [tx, ty, tz], cam_id, name))
    r.done()
    return out
