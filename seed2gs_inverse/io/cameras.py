"""Camera files: 3DGS ``cameras.json``, COLMAP sparse models, nerfstudio ``transforms.json``.

All readers return :class:`~seed2gs_inverse.camera.Camera` objects in the
OpenCV convention (x right, y down, z forward) with ``name`` set from the
file, so cameras can be picked by name (:func:`read_camera`).

``cameras.json`` (written by the 3DGS trainer)
    a list of ``{id, img_name, width, height, position, rotation, fx, fy}``
    where ``rotation`` is the camera-to-world rotation written row by row and
    ``position`` the camera centre; the principal point is the image centre
    unless ``cx``/``cy`` are given (an extension this writer uses only when
    needed). Entries in the ``Camera.to_dict`` layout are accepted too, as is
    a single such object instead of a list.
COLMAP sparse model (``cameras`` + ``images``, ``.txt`` or ``.bin``)
    images hold the world-to-camera rotation as a w-first quaternion and the
    translation; cameras the model and its parameters. Pinhole-like models
    (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV) give ``fx, fy,
    cx, cy``; their distortion is ignored with a warning (undistort the
    images with COLMAP for exact results). Cameras are sorted by their
    COLMAP image name, as the 3DGS trainer's current reader sorts them and
    names them in its ``cameras.json``. Older versions named (and sorted)
    them by the file name without folders up to the first dot
    (:func:`trainer_name`; the orders differ for names such as ``a.png`` and
    ``a-1.png``): ``FILE:NAME`` takes that name too.
nerfstudio ``transforms.json``
    ``frames[i].transform_matrix`` is camera-to-world in OpenGL axes (x right,
    y up, z back); its y and z columns are negated to get OpenCV axes.
    Intrinsics ``fl_x, fl_y, cx, cy, w, h`` come from the frame or the top
    level (``camera_angle_x`` is accepted in place of ``fl_x``).

Malformed files raise FormatError; degenerate values (non-positive focal
length or size, non-orthonormal rotation, non-finite numbers) raise
ValidationError. Both messages name the file and the camera entry.
Rotations that are orthonormal only to about 1e-3 (values rounded when
written as text) are projected onto the nearest rotation.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import FormatError, Seed2GSError, ValidationError
from ..scene import quat_to_rotmat
from ._common import atomic_write, check_regular, fail, warn_caller

__all__ = ["read_cameras", "read_camera", "write_cameras"]

_ORTHO_SNAP = 1e-3


def _label(path, index, name) -> str:
    return f"{os.fspath(path)}: camera {index}" + (f" ('{name}')" if name else "")


def _number(label, key, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FormatError(f"{label}: '{key}' must be a number, got {str(value)[:60]!r}")
    try:
        return float(value)
    except OverflowError:  # JSON integers have no size limit
        raise ValidationError(f"{label}: '{key}' is out of range ({str(value)[:20]}... has "
                              f"{len(str(value))} digits)") from None


def _matrix(label, key, value, shapes) -> np.ndarray:
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


def _focal_from_angle(label, key, angle, size) -> float:
    angle = _number(label, key, angle)
    if not 0 < angle < math.pi:
        raise ValidationError(f"{label}: '{key}' must be an angle in (0, pi) radians, got {angle}")
    return 0.5 * size / math.tan(0.5 * angle)


def _proper_rotation(label, rot: np.ndarray) -> np.ndarray:
    """``rot`` if it is a rotation up to rounding (then snapped to SO(3)); else ValidationError."""
    if not np.all(np.isfinite(rot)):
        raise ValidationError(f"{label}: rotation has non-finite values")
    err = np.abs(rot @ rot.T - np.eye(3)).max()
    det = np.linalg.det(rot)
    if err > _ORTHO_SNAP or det <= 0:
        raise ValidationError(f"{label}: rotation is not orthonormal with determinant +1 "
                              f"(|R R^T - I| = {err:.2e}, det = {det:.4f})")
    u, _, vt = np.linalg.svd(rot)
    return u @ vt


def _camera(label, name, width, height, fx, fy, cx, cy, c2w_rot, center) -> Camera:
    """Build and validate a Camera from camera-to-world rotation and centre."""
    center = np.asarray(center, dtype=np.float64)
    if not np.all(np.isfinite(center)):
        raise ValidationError(f"{label}: camera position has non-finite values")
    rot = _proper_rotation(label, np.asarray(c2w_rot, dtype=np.float64)).T  # world-to-camera
    w2c = np.eye(4)
    w2c[:3, :3] = rot
    w2c[:3, 3] = -rot @ center
    for key, v in (("width", width), ("height", height)):
        if not (math.isfinite(v) and float(v).is_integer()):
            raise ValidationError(f"{label}: {key} must be a whole number, got {v}")
    try:
        return Camera(int(width), int(height), fx, fy, cx, cy, w2c, name=name)
    except ValidationError as exc:
        raise ValidationError(f"{label}: {_strip_camera(exc)}") from None


def _strip_camera(exc) -> str:
    """Camera's message without its own "camera 'NAME': " prefix (the label says it)."""
    return re.sub(r"^camera( '[^']*')?: ", "", str(exc), count=1)


# --------------------------------------------------------------------------
# dispatch

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
    if p.is_dir():
        return _read_colmap_dir(p)
    if not p.exists() and ":" in p.name and Path(str(p).rsplit(":", 1)[0]).exists():
        raise fail(p, "no such file; FILE:NAME picks one camera where one is expected (--camera), but here "
                      "every camera of a file is read: give the file alone")
    if p.name.lower() in ("cameras.txt", "images.txt", "cameras.bin", "images.bin"):
        return _read_colmap(p.parent, p.suffix.lower())
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
        return _read_nerfstudio(p, doc)
    if isinstance(doc, dict):
        doc = [doc]
    if not isinstance(doc, list):
        raise fail(p, "expected a list of cameras (3DGS cameras.json) or an object with "
                      "'frames' (nerfstudio transforms.json)")
    if not doc:
        raise fail(p, "holds no cameras")
    return [_read_json_entry(p, i, entry) for i, entry in enumerate(doc)]


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
    if not named:  # older 3DGS trainers' name of a COLMAP image ("images/a.png" was "a" in their cameras.json)
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


# --------------------------------------------------------------------------
# cameras.json

def _read_json_entry(path, index, entry) -> Camera:
    if not isinstance(entry, dict):
        raise fail(path, f"camera {index} is a {type(entry).__name__}, not an object")
    # the first of img_name, name, id that is given (null counts as not given: no camera named "None")
    name = next((entry[k] for k in ("img_name", "name", "id") if entry.get(k) is not None), index)
    if isinstance(name, bool) or not isinstance(name, (str, int, float)):
        raise fail(path, f"camera {index}: its name must be a string or a number, got {str(name)[:60]!r}")
    name = str(name)
    label = _label(path, index, name)
    if "world_to_camera" in entry:
        try:
            cam = Camera.from_dict(entry)
        except ValidationError as exc:
            raise ValidationError(f"{label}: {_strip_camera(exc)}") from None
        return cam if cam.name else Camera.from_dict({**entry, "name": name})
    missing = [k for k in ("width", "height", "position", "rotation", "fx", "fy") if k not in entry]
    if missing:
        raise FormatError(f"{label}: missing keys {missing}")
    width = _number(label, "width", entry["width"])
    height = _number(label, "height", entry["height"])
    fx = _number(label, "fx", entry["fx"])
    fy = _number(label, "fy", entry["fy"])
    cx = _number(label, "cx", entry["cx"]) if "cx" in entry else width / 2
    cy = _number(label, "cy", entry["cy"]) if "cy" in entry else height / 2
    rot = _matrix(label, "rotation", entry["rotation"], [(3, 3)])
    pos = _matrix(label, "position", entry["position"], [(3,)])
    return _camera(label, name, width, height, fx, fy, cx, cy, rot, pos)


# --------------------------------------------------------------------------
# nerfstudio transforms.json

_NS_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")
_NS_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")


def _read_nerfstudio(path, doc) -> list:
    frames = doc["frames"]
    if not isinstance(frames, list) or not frames:
        raise fail(path, "'frames' must be a non-empty list")
    cams = []
    distorted = 0
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise fail(path, f"frame {i} is a {type(frame).__name__}, not an object")
        name = str(frame.get("file_path", i))
        label = _label(path, i, name)

        def get(key, default=None):
            return frame[key] if key in frame else doc.get(key, default)

        model = get("camera_model", "OPENCV")
        if model not in _NS_MODELS:
            raise FormatError(f"{label}: camera model {model!r} is not a pinhole model "
                              f"(supported: {', '.join(_NS_MODELS)})")
        if get("w") is None or get("h") is None:
            raise FormatError(f"{label}: image size 'w' and 'h' are missing")
        w = _number(label, "w", get("w"))
        h = _number(label, "h", get("h"))
        if get("fl_x") is not None:
            fx = _number(label, "fl_x", get("fl_x"))
        elif get("camera_angle_x") is not None:
            fx = _focal_from_angle(label, "camera_angle_x", get("camera_angle_x"), w)
        else:
            raise FormatError(f"{label}: focal length 'fl_x' (or 'camera_angle_x') is missing")
        if get("fl_y") is not None:
            fy = _number(label, "fl_y", get("fl_y"))
        elif get("camera_angle_y") is not None:
            fy = _focal_from_angle(label, "camera_angle_y", get("camera_angle_y"), h)
        else:
            fy = fx
        cx = _number(label, "cx", get("cx")) if get("cx") is not None else w / 2
        cy = _number(label, "cy", get("cy")) if get("cy") is not None else h / 2
        if any(get(k) not in (None, 0, 0.0) for k in _NS_DISTORTION):
            distorted += 1
        if "transform_matrix" not in frame:
            raise FormatError(f"{label}: 'transform_matrix' is missing")
        m = _matrix(label, "transform_matrix", frame["transform_matrix"], [(4, 4), (3, 4)])
        if not np.all(np.isfinite(m)):
            raise ValidationError(f"{label}: transform_matrix has non-finite values")
        if m.shape == (4, 4) and not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValidationError(f"{label}: transform_matrix last row must be [0, 0, 0, 1]")
        c2w = m[:3, :3] * np.array([1.0, -1.0, -1.0])  # OpenGL -> OpenCV camera axes
        cams.append(_camera(label, name, w, h, fx, fy, cx, cy, c2w, m[:3, 3]))
    if distorted:
        warn_caller(f"{os.fspath(path)}: lens distortion of {distorted} frames is ignored "
                    f"(pinhole projection is used)")
    return cams


# --------------------------------------------------------------------------
# COLMAP

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
    for key, v in (("width", width), ("height", height)):
        if not (math.isfinite(v) and float(v).is_integer()):
            raise ValidationError(f"{label}: {key} must be a whole number, got {v}")
    try:
        Camera(int(width), int(height), fx, fy, cx, cy)
    except ValidationError as exc:
        raise ValidationError(f"{label}: {_strip_camera(exc)}") from None


def _read_colmap_dir(d: Path) -> list:
    for sub in (d, d / "sparse" / "0", d / "sparse"):
        for ext in (".bin", ".txt"):
            if (sub / f"cameras{ext}").is_file() and (sub / f"images{ext}").is_file():
                return _read_colmap(sub, ext)
    if (d / "manifest.json").is_file():
        raise fail(d, "this is a saved operator directory, not cameras; use 'seed2gs operators info'")
    raise fail(d, "directory holds no COLMAP model (cameras + images, .bin or .txt, "
                  "also looked in sparse/0 and sparse)")


def _read_colmap(d: Path, ext: str) -> list:
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
        cams.append(_camera(label, name, width, height, fx, fy, cx, cy, rot.T, -rot.T @ t))
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

    Without the check, a file written without those lines lost every second image silently.
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
