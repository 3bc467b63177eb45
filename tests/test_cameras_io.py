"""Camera files: 3DGS cameras.json, COLMAP text/binary, nerfstudio transforms.json.

Poses are checked by projecting points whose image position follows from
the file's own convention (independent formulas, scipy rotations), not by
comparing with the reader's output.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from seed2gs_inverse.camera import Camera
from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.io import read_camera, read_cameras, write_cameras


def _entry(rot_c2w, pos, name="cam", w=64, h=48, fx=50.0, fy=55.0, **kw):
    return {"id": 0, "img_name": name, "width": w, "height": h, "position": list(map(float, pos)),
            "rotation": np.asarray(rot_c2w).tolist(), "fx": fx, "fy": fy, **kw}


def _write_json(path, doc):
    path.write_text(json.dumps(doc))
    return path


# --------------------------------------------------------------------------
# cameras.json

def test_cameras_json_convention(tmp_path, rng):
    rot = Rotation.random(random_state=3).as_matrix()  # camera-to-world: columns are camera axes
    pos = rng.normal(size=3)
    path = _write_json(tmp_path / "c.json", [_entry(rot, pos, name="a")])
    (cam,) = read_cameras(path)
    assert cam.name == "a" and (cam.width, cam.height) == (64, 48)
    assert (cam.cx, cam.cy) == (32, 24)  # principal point at the centre
    # 5 units ahead along the camera's z axis and 1 unit along its x axis
    point = pos + 5 * rot[:, 2] + 1 * rot[:, 0] - 0.5 * rot[:, 1]
    uv, z = cam.project(point[None])
    np.testing.assert_allclose(z, [5])
    np.testing.assert_allclose(uv[0], [32 + 50 / 5, 24 - 0.5 * 55 / 5])
    np.testing.assert_allclose(cam.center, pos, atol=1e-12)


def test_write_read_round_trip(tmp_path):
    cams = [Camera.look_at([1, 2, 3], [0, 0, 0], [0, -1, 0], 50, 64, 48, name="front"),
            Camera(80, 60, 70.0, 71.0, 41.5, 29.0,
                   Camera.look_at([-2, 0, 1], [0, 0.5, 0], [0, 0, 1], 40, 80, 60).world_to_camera,
                   name="")]
    path = tmp_path / "out.json"
    write_cameras(path, cams)
    doc = json.loads(path.read_text())
    assert doc[0]["img_name"] == "front" and "cx" not in doc[0]
    assert doc[1]["img_name"] == "camera_1" and doc[1]["cx"] == 41.5
    np.testing.assert_allclose(np.array(doc[0]["rotation"]), cams[0].rotation.T)  # c2w rows
    np.testing.assert_allclose(doc[0]["position"], cams[0].center)
    back = read_cameras(path)
    for a, b in zip(cams, back):
        np.testing.assert_allclose(b.world_to_camera, a.world_to_camera, atol=1e-12)
        assert (b.width, b.height, b.fx, b.fy, b.cx, b.cy) == (a.width, a.height, a.fx, a.fy, a.cx, a.cy)
    with pytest.raises(ValidationError):
        write_cameras(tmp_path / "bad.json", [cams[0], "nope"])
    with pytest.raises(ValidationError, match="no cameras"):
        write_cameras(tmp_path / "bad.json", [])
    assert not (tmp_path / "bad.json").exists()


def test_to_dict_objects_accepted(tmp_path):
    cam = Camera.look_at([0, 0, -3], [0, 0, 0], [0, -1, 0], 60, 32, 24, name="ref")
    single = _write_json(tmp_path / "one.json", cam.to_dict())
    got = read_camera(single)
    np.testing.assert_allclose(got.world_to_camera, cam.world_to_camera)
    assert got.name == "ref"
    listed = _write_json(tmp_path / "list.json", [cam.to_dict(), {**cam.to_dict(), "name": "b"}])
    assert [c.name for c in read_cameras(listed)] == ["ref", "b"]


def test_rounded_rotation_is_snapped_but_bad_one_rejected(tmp_path):
    rot = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix()
    path = _write_json(tmp_path / "r.json", [_entry(np.round(rot, 4), [0, 0, 0])])
    (cam,) = read_cameras(path)
    np.testing.assert_allclose(cam.rotation @ cam.rotation.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(cam.rotation.T, rot, atol=1e-4)
    bad = _write_json(tmp_path / "bad.json", [_entry(rot * 1.1, [0, 0, 0], name="scaled")])
    with pytest.raises(ValidationError, match=r"bad\.json: camera 0 \('scaled'\).*orthonormal"):
        read_cameras(bad)
    mirror = _write_json(tmp_path / "m.json", [_entry(rot @ np.diag([1, 1, -1]), [0, 0, 0])])
    with pytest.raises(ValidationError, match="determinant"):
        read_cameras(mirror)


@pytest.mark.parametrize("change, match", [
    ({"fx": 0.0}, "focal"),
    ({"fy": -3.0}, "focal"),
    ({"width": 0}, "width"),
    ({"height": 10.5}, "whole number"),
    ({"position": [0.0, float("nan"), 0.0]}, "non-finite"),
    ({"fx": float("inf")}, "fx"),
])
def test_degenerate_values(tmp_path, change, match):
    entry = _entry(np.eye(3), [0, 0, 0], name="e")
    entry.update(change)
    path = tmp_path / "d.json"
    path.write_text(json.dumps([_entry(np.eye(3), [0, 0, 0], name="ok"), entry]))
    with pytest.raises(ValidationError, match=match) as err:
        read_cameras(path)
    assert "d.json: camera 1 ('e')" in str(err.value)


@pytest.mark.parametrize("text, match", [
    ("{not json", "not valid JSON"),
    ("[]", "holds no cameras"),
    ("42", "expected a list"),
    ('[{"img_name": "x", "width": 4}]', "missing keys"),
    ('[{"img_name": "x", "width": "4", "height": 4, "fx": 1, "fy": 1, "position": [0,0,0], '
     '"rotation": [[1,0,0],[0,1,0],[0,0,1]]}]', "'width' must be a number"),
    ('[{"img_name": "x", "width": 4, "height": 4, "fx": 1, "fy": 1, "position": [0,0], '
     '"rotation": [[1,0,0],[0,1,0],[0,0,1]]}]', "'position' has shape"),
    ('[[1, 2]]', "not an object"),
])
def test_malformed_json(tmp_path, text, match):
    path = tmp_path / "m.json"
    path.write_text(text)
    with pytest.raises(FormatError, match=match) as err:
        read_cameras(path)
    assert "m.json" in str(err.value)


def test_read_camera_selection(tmp_path):
    entries = [_entry(np.eye(3), [i, 0, 0], name=n) for i, n in enumerate(["overview", "side", "7"])]
    path = _write_json(tmp_path / "cams.json", entries)
    assert read_camera(f"{path}:side").center[0] == 1
    assert read_camera(f"{path}:0").name == "overview"
    assert read_camera(f"{path}:-1").name == "7"
    assert read_camera(f"{path}:7").name == "7"  # a name wins over an index
    with pytest.raises(ValidationError, match="no camera named 'top'.*overview, side, 7"):
        read_camera(f"{path}:top")
    with pytest.raises(ValidationError, match="index 5 is out of range"):
        read_camera(f"{path}:5")
    with pytest.raises(ValidationError, match="holds 3 cameras; pick one"):
        read_camera(path)
    one = _write_json(tmp_path / "one.json", entries[:1])
    assert read_camera(one).name == "overview"
    with pytest.raises(FileNotFoundError):
        read_camera(tmp_path / "missing.json")
    with pytest.raises(FormatError, match="unknown camera file"):
        read_cameras(tmp_path / "cams.yaml")



def test_read_camera_names_with_colons_and_shared_names(tmp_path):
    """"cams.json:frame:1" read "cams.json:frame" as the file; a shared name picked the first camera."""
    entries = [_entry(np.eye(3), [i, 0, 0], name=n) for i, n in enumerate(["frame:1", "frame:2", "twin", "twin"])]
    path = _write_json(tmp_path / "cams.json", entries)
    assert read_camera(f"{path}:frame:2").center[0] == 1
    assert read_camera(f"{path}:1").name == "frame:2"
    with pytest.raises(ValidationError, match="no camera named 'frame:3'"):
        read_camera(f"{path}:frame:3")
    with pytest.raises(ValidationError, match=r"holds 2 cameras named 'twin' \(indices 2, 3\); pick one by index"):
        read_camera(f"{path}:twin")
    assert read_camera(f"{path}:3").center[0] == 3


# --------------------------------------------------------------------------
# COLMAP

_IMAGES = [  # image id, (qw, qx, qy, qz), t, camera id, name
    (3, Rotation.from_euler("xyz", [5, -30, 12], degrees=True), [0.1, -0.2, 2.0], 1, "b.png"),
    (1, Rotation.from_euler("xyz", [-20, 10, 3], degrees=True), [1.0, 0.5, 3.0], 2, "a.png"),
]


def _qvec(rotation):
    x, y, z, w = rotation.as_quat()  # scipy is scalar-last; COLMAP is w-first
    return [w, x, y, z]


def _write_colmap_text(d):
    d.mkdir(parents=True, exist_ok=True)
    (d / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        "1 PINHOLE 64 48 50.0 52.0 31.0 25.0\n"
        "2 SIMPLE_RADIAL 80 60 70.0 40.0 30.0 0.01\n"
        "9 OPENCV_FISHEYE 10 10 1 1 5 5 0 0 0 0\n")
    lines = ["# Image list with two lines of data per image:", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME"]
    for image_id, rot, t, cam, name in _IMAGES:
        lines.append(" ".join(map(str, [image_id, *_qvec(rot), *t, cam, name])))
        lines.append("" if image_id == 3 else "10.5 20.5 -1 11.0 3.0 42")
    (d / "images.txt").write_text("\n".join(lines) + "\n")


def _write_colmap_binary(d, fisheye_image=False):
    d.mkdir(parents=True, exist_ok=True)
    cams = struct.pack("<Q", 2)
    cams += struct.pack("<iiQQ4d", 1, 1, 64, 48, 50.0, 52.0, 31.0, 25.0)
    cams += struct.pack("<iiQQ4d", 2, 2, 80, 60, 70.0, 40.0, 30.0, 0.01)
    (d / "cameras.bin").write_bytes(cams)
    imgs = struct.pack("<Q", len(_IMAGES))
    for image_id, rot, t, cam, name in _IMAGES:
        imgs += struct.pack("<i7di", image_id, *_qvec(rot), *t, cam) + name.encode() + b"\0"
        imgs += struct.pack("<Q", 2) + struct.pack("<ddq", 1, 2, -1) * 2
    (d / "images.bin").write_bytes(imgs)


def _check_colmap(cams):
    assert [c.name for c in cams] == ["a.png", "b.png"]  # sorted by name, as the 3DGS trainer
    by_name = {c.name: c for c in cams}
    intr = {1: (64, 48, 50.0, 52.0, 31.0, 25.0), 2: (80, 60, 70.0, 70.0, 40.0, 30.0)}
    world = np.array([[0.3, -0.2, 1.5], [-1.0, 0.4, 2.5], [0.0, 0.0, 0.0]])
    for image_id, rot, t, cam_id, name in _IMAGES:
        cam = by_name[name]
        w, h, fx, fy, cx, cy = intr[cam_id]
        assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (w, h, fx, fy, cx, cy)
        xc = world @ rot.as_matrix().T + np.asarray(t)  # COLMAP: x_cam = R(q) X + t
        uv, z = cam.project(world)
        np.testing.assert_allclose(z, xc[:, 2], atol=1e-12)
        np.testing.assert_allclose(uv, np.stack([fx * xc[:, 0] / xc[:, 2] + cx,
                                                 fy * xc[:, 1] / xc[:, 2] + cy], 1), atol=1e-9)


def test_colmap_text(tmp_path):
    _write_colmap_text(tmp_path / "sparse" / "0")
    with pytest.warns(UserWarning, match="distortion of 1 images is ignored"):
        cams = read_cameras(tmp_path)  # the model is found in sparse/0
    _check_colmap(cams)
    with pytest.warns(UserWarning):
        _check_colmap(read_cameras(tmp_path / "sparse" / "0" / "images.txt"))


def test_colmap_binary(tmp_path):
    _write_colmap_binary(tmp_path)
    with pytest.warns(UserWarning, match="distortion"):
        _check_colmap(read_cameras(tmp_path / "cameras.bin"))
    with pytest.warns(UserWarning):
        assert read_camera(f"{tmp_path}:b.png").name == "b.png"


def test_colmap_binary_truncated_and_bad(tmp_path):
    _write_colmap_binary(tmp_path)
    data = (tmp_path / "images.bin").read_bytes()
    (tmp_path / "images.bin").write_bytes(data[:-10])
    with pytest.raises(FormatError, match=r"images\.bin: file is truncated"):
        read_cameras(tmp_path)
    (tmp_path / "images.bin").write_bytes(struct.pack("<Q", 10**15))  # huge count, no records
    with pytest.raises(FormatError, match="truncated"):
        read_cameras(tmp_path)
    (tmp_path / "images.bin").write_bytes(data + b"xx")
    with pytest.raises(FormatError, match="2 unexpected bytes"):
        read_cameras(tmp_path)
    (tmp_path / "images.bin").write_bytes(data)
    (tmp_path / "cameras.bin").write_bytes(struct.pack("<Q", 1) + struct.pack("<iiQQ", 1, 77, 4, 4))
    with pytest.raises(FormatError, match="unknown model id 77"):
        read_cameras(tmp_path)


def test_colmap_text_errors(tmp_path):
    _write_colmap_text(tmp_path)
    text = (tmp_path / "images.txt").read_text().replace(" 1 b.png", " 9 b.png")
    (tmp_path / "images.txt").write_text(text)
    with pytest.raises(FormatError, match="OPENCV_FISHEYE is not a pinhole model"):
        read_cameras(tmp_path)
    (tmp_path / "images.txt").write_text(text.replace(" 9 b.png", " 5 b.png"))
    with pytest.raises(FormatError, match="camera 5"):
        read_cameras(tmp_path)
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50 52 31\n")
    with pytest.raises(FormatError, match="takes 4 parameters"):
        read_cameras(tmp_path)
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 0 52 31 20\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 1 x.png\n\n")
    # named where the intrinsics are stored, not by the image that uses them
    with pytest.raises(ValidationError, match=r"cameras\.txt \(line 1\): camera 1 \(PINHOLE\): focal"):
        read_cameras(tmp_path)
    (tmp_path / "images.txt").unlink()
    with pytest.raises(FormatError, match="no COLMAP model"):
        read_cameras(tmp_path)


# --------------------------------------------------------------------------
# nerfstudio

def test_nerfstudio_opengl_axes(tmp_path):
    c2w_gl = np.eye(4)
    c2w_gl[:3, 3] = [1.0, 2.0, 3.0]  # camera at (1, 2, 3) looking down world -z, world +y up
    doc = {"fl_x": 40.0, "fl_y": 42.0, "cx": 30.0, "cy": 20.0, "w": 64, "h": 48,
           "frames": [{"file_path": "images/0.png", "transform_matrix": c2w_gl.tolist()},
                      {"file_path": "images/1.png", "transform_matrix": c2w_gl[:3].tolist(),
                       "fl_x": 80.0, "fl_y": 80.0}]}
    path = _write_json(tmp_path / "transforms.json", doc)
    cam0, cam1 = read_cameras(path)
    assert cam0.name == "images/0.png" and (cam0.fx, cam0.fy, cam0.cx, cam0.cy) == (40, 42, 30, 20)
    assert cam1.fx == 80
    points = np.array([[1.0, 2.0, -2.0],   # straight ahead, 5 units
                       [1.0, 3.0, -2.0],   # world up: above the image centre (smaller v)
                       [2.0, 2.0, -2.0]])  # world +x: right of the centre
    uv, z = cam0.project(points)
    np.testing.assert_allclose(z, [5, 5, 5])
    np.testing.assert_allclose(uv, [[30, 20], [30, 20 - 42 / 5], [30 + 40 / 5, 20]])


def test_nerfstudio_angle_and_errors(tmp_path):
    frame = {"file_path": "f", "transform_matrix": np.eye(4).tolist()}
    path = _write_json(tmp_path / "t.json", {"camera_angle_x": np.pi / 2, "w": 100, "h": 50,
                                              "frames": [frame]})
    (cam,) = read_cameras(path)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [50, 50, 50, 25])
    cases = [
        ({"fl_x": 10, "frames": [frame]}, FormatError, "'w' and 'h'"),
        ({"w": 10, "h": 10, "frames": [frame]}, FormatError, "focal length"),
        ({"fl_x": 10, "w": 10, "h": 10, "camera_model": "OPENCV_FISHEYE", "frames": [frame]},
         FormatError, "not a pinhole model"),
        ({"camera_angle_x": 0.0, "w": 10, "h": 10, "frames": [frame]}, ValidationError, "angle"),
        ({"fl_x": 10, "w": 10, "h": 10, "frames": []}, FormatError, "non-empty list"),
        ({"fl_x": 10, "w": 10, "h": 10, "frames": [{"file_path": "f"}]}, FormatError, "transform_matrix"),
        ({"fl_x": 10, "w": 10, "h": 10,
          "frames": [{"file_path": "f", "transform_matrix": (2 * np.eye(4)).tolist()}]},
         ValidationError, "last row"),
        ({"fl_x": 10, "w": 10, "h": 10,
          "frames": [{"file_path": "f", "transform_matrix": np.diag([2, 2, 2, 1.0]).tolist()}]},
         ValidationError, "orthonormal"),
    ]
    for doc, err, match in cases:
        _write_json(path, doc)
        with pytest.raises(err, match=match):
            read_cameras(path)
    _write_json(path, {"fl_x": 10, "w": 10, "h": 10, "k1": 0.2, "frames": [frame]})
    with pytest.warns(UserWarning, match="distortion of 1 frames"):
        read_cameras(path)


# --------------------------------------------------------------------------
# shared data

@pytest.mark.shared_data
def test_shared_firepit_cameras(shared_data):
    path = shared_data / "firepit_cameras.json"
    cams = read_cameras(path)
    assert [c.name for c in cams] == ["overview", "side_200", "side_290", "side_020", "side_110"]
    raw = json.loads(path.read_text())
    for cam, entry in zip(cams, raw):
        assert (cam.width, cam.height, cam.cx, cam.cy) == (960, 540, 480, 270)
        np.testing.assert_allclose(cam.center, entry["position"], atol=1e-12)
        np.testing.assert_allclose(cam.forward, np.array(entry["rotation"])[:, 2], atol=1e-12)
    overview = read_camera(f"{path}:overview")
    # "up" in these COLMAP-like scenes is roughly -y: the overview camera's image-up agrees
    assert overview.up[1] < -0.5


def test_directory_without_cameras_says_what_it_is(tmp_path):
    with pytest.raises(FormatError, match="no COLMAP model"):
        read_cameras(tmp_path)
    (tmp_path / "manifest.json").write_text("{}")
    with pytest.raises(FormatError, match="operators info"):
        read_cameras(tmp_path)


# --------------------------------------------------------------------------
# absurd values are refused on read, naming the file, camera and field (issue 12, items 3-4)

_HUGE = 10 ** 400  # a valid JSON integer far beyond float range


@pytest.mark.parametrize("change, match", [
    ({"width": 1e308}, "width must be at most 32768"),
    ({"height": 32769}, "height must be at most 32768"),
    ({"width": _HUGE}, "'width' is out of range"),
    ({"fx": _HUGE}, "'fx' is out of range"),
    ({"fx": -50.0}, "focal lengths must be positive"),
    ({"cx": float("inf")}, "cx is not finite"),
    ({"position": [_HUGE, 0, 0]}, "'position' holds a number out of range"),
    ({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0.1, 1]]}, "rotation is not orthonormal"),
    ({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}, "determinant"),
])
def test_absurd_cameras_json(tmp_path, change, match):
    entry = _entry(np.eye(3), [0, 0, 0], name="bad")
    entry.update(change)
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps([_entry(np.eye(3), [0, 0, 0], name="ok"), entry]))
    with pytest.raises(ValidationError, match=match) as err:
        read_cameras(path)
    assert str(err.value).startswith(f"{path}: camera 1 ('bad')")


def test_absurd_to_dict_entry(tmp_path):
    d = Camera(10, 10, 5.0, 5.0, 5.0, 5.0, name="v").to_dict()
    path = _write_json(tmp_path / "c.json", [{**d, "height": _HUGE}])
    with pytest.raises(ValidationError, match=r"c\.json: camera 0 \('v'\).*height must be at most"):
        read_cameras(path)


@pytest.mark.parametrize("change, match", [
    ({"w": _HUGE}, "'w' is out of range"),
    ({"h": 1e308}, "height must be at most 32768"),
    ({"fl_x": 0.0}, "focal lengths must be positive"),
    ({"fl_y": -1.0}, "focal lengths must be positive"),
    ({"cy": _HUGE}, "'cy' is out of range"),
])
def test_absurd_transforms_json(tmp_path, change, match):
    doc = {"fl_x": 40.0, "fl_y": 42.0, "cx": 30.0, "cy": 20.0, "w": 64, "h": 48,
           "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()},
                      {"file_path": "b.png", "transform_matrix": np.eye(4).tolist(), **change}]}
    path = _write_json(tmp_path / "transforms.json", doc)
    with pytest.raises(ValidationError, match=match) as err:
        read_cameras(path)
    assert str(err.value).startswith(f"{path}: camera 1 ('b.png')")


def test_transform_matrix_out_of_range(tmp_path):
    m = np.eye(4).tolist()
    m[0][3] = _HUGE
    path = _write_json(tmp_path / "transforms.json", {"fl_x": 40.0, "w": 64, "h": 48,
                                                      "frames": [{"transform_matrix": m}]})
    with pytest.raises(ValidationError, match="'transform_matrix' holds a number out of range"):
        read_cameras(path)


@pytest.mark.parametrize("line, error, match", [
    ("\u00b2 PINHOLE 64 48 50 52 31 25", FormatError, r"cameras\.txt: line 2: expected 'CAMERA_ID"),
    ("\u0663 PINHOLE 64 48 50 52 31 25", FormatError, r"cameras\.txt: line 2: .*whole number"),
    ("1 PINHOLE 1e308 48 50 52 31 25", ValidationError,
     r"cameras\.txt \(line 2\): camera 1 \(PINHOLE\): width must be at most 32768"),
    ("1 PINHOLE 64 48 -50 52 31 25", ValidationError, r"camera 1 \(PINHOLE\): focal"),
    ("1 PINHOLE 64 48 50 52 nan 25", ValidationError, r"camera 1 \(PINHOLE\): cx is not finite"),
])
def test_colmap_text_bad_cameras(tmp_path, line, error, match):
    (tmp_path / "cameras.txt").write_text(f"# header\n{line}\n", encoding="utf-8")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 1 x.png\n\n")
    with pytest.raises(error, match=match):
        read_cameras(tmp_path)


def test_colmap_text_bad_image_ids(tmp_path):
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50 52 31 25\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 \u00b2 x.png\n\n", encoding="utf-8")
    with pytest.raises(FormatError, match=r"images\.txt: line 1: .*whole-number ids"):
        read_cameras(tmp_path)


def test_colmap_binary_absurd_size(tmp_path):
    _write_colmap_binary(tmp_path)
    cams = struct.pack("<Q", 2)
    cams += struct.pack("<iiQQ4d", 1, 1, 2 ** 63, 48, 50.0, 52.0, 31.0, 25.0)
    cams += struct.pack("<iiQQ4d", 2, 2, 80, 60, 70.0, 40.0, 30.0, 0.01)
    (tmp_path / "cameras.bin").write_bytes(cams)
    with pytest.raises(ValidationError, match=r"cameras\.bin \(record 0\): camera 1 \(PINHOLE\): "
                                              r"width must be at most 32768"):
        read_cameras(tmp_path)


@pytest.mark.parametrize("form", ["text", "binary"])
def test_colmap_models_by_their_parameter_layout(tmp_path, form):
    """Each pinhole-like COLMAP model's parameters (COLMAP's camera_models.h): SIMPLE_PINHOLE (id 0)
    ``f, cx, cy``; PINHOLE (1) ``fx, fy, cx, cy``; SIMPLE_RADIAL (2) ``f, cx, cy, k``; RADIAL (3)
    ``f, cx, cy, k1, k2``; OPENCV (4) ``fx, fy, cx, cy, k1, k2, p1, p2``; every distortion 0 here."""
    models = [(0, "SIMPLE_PINHOLE", [60.0, 33.0, 21.0], (60.0, 60.0, 33.0, 21.0)),
              (1, "PINHOLE", [61.0, 66.0, 34.0, 22.0], (61.0, 66.0, 34.0, 22.0)),
              (2, "SIMPLE_RADIAL", [62.0, 35.0, 23.0, 0.0], (62.0, 62.0, 35.0, 23.0)),
              (3, "RADIAL", [55.0, 30.0, 22.0, 0.0, 0.0], (55.0, 55.0, 30.0, 22.0)),
              (4, "OPENCV", [50.0, 57.0, 31.0, 23.0, 0.0, 0.0, 0.0, 0.0], (50.0, 57.0, 31.0, 23.0))]
    if form == "text":
        (tmp_path / "cameras.txt").write_text("".join(f"{k + 1} {name} 64 48 {' '.join(map(str, p))}\n"
                                                      for k, name, p, _ in models))
        (tmp_path / "images.txt").write_text("".join(f"{k + 1} 1 0 0 0 0 0 0 {k + 1} im{k}.png\n\n"
                                                     for k, *_ in models))
    else:
        cams = struct.pack("<Q", len(models))
        imgs = struct.pack("<Q", len(models))
        for k, _, p, _ in models:
            cams += struct.pack(f"<iiQQ{len(p)}d", k + 1, k, 64, 48, *p)
            imgs += struct.pack("<i7di", k + 1, 1, 0, 0, 0, 0, 0, 0, k + 1) + f"im{k}.png".encode() + b"\0"
            imgs += struct.pack("<Q", 0)
        (tmp_path / "cameras.bin").write_bytes(cams)
        (tmp_path / "images.bin").write_bytes(imgs)
    got = {c.name: c for c in read_cameras(tmp_path)}
    for k, name, _, want in models:
        c = got[f"im{k}.png"]
        assert (c.fx, c.fy, c.cx, c.cy) == want, name


def test_colmap_images_txt_without_points_lines_and_duplicate_cameras(tmp_path):
    """An images.txt written without its POINTS2D lines lost every second image silently; a camera id
    given twice silently kept the last definition."""
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50 50 32 24\n")
    (tmp_path / "images.txt").write_text("".join(f"{i} 1 0 0 0 0 0 {i} 1 img{i}.png\n" for i in range(1, 5)))
    with pytest.raises(FormatError, match=r"images\.txt: line 2: expected the POINTS2D line .*'2 1 0 0 0 0 0 2 1 "):
        read_cameras(tmp_path)
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 1 1 a.png\n1 2\n")  # not (X, Y, ID) triples
    with pytest.raises(FormatError, match="line 2: expected the POINTS2D line"):
        read_cameras(tmp_path)
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 1 1 a.png\n1.5 2.5 -1 3 4 7\n2 1 0 0 0 0 0 2 1 b.png\n")
    assert [c.name for c in read_cameras(tmp_path)] == ["a.png", "b.png"]  # the last image may end the file
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50 50 32 24\n1 PINHOLE 640 480 500 500 320 240\n")
    with pytest.raises(FormatError, match=r"cameras\.txt: line 2: camera 1 is defined twice \(also line 1\)"):
        read_cameras(tmp_path)
    _write_colmap_binary(tmp_path / "bin")
    cams = (tmp_path / "bin" / "cameras.bin").read_bytes()
    twice = struct.pack("<Q", 3) + cams[8:] + cams[8:8 + struct.calcsize("<iiQQ4d")]
    (tmp_path / "bin" / "cameras.bin").write_bytes(twice)
    with pytest.raises(FormatError, match=r"cameras\.bin: record 2: camera 1 is defined twice \(also record 0\)"):
        read_cameras(tmp_path / "bin")


def test_json_types_and_index_selectors_are_strict(tmp_path):
    """Strings and booleans where numbers belong were converted silently (a width of "640" was refused, a
    position of ["1", "2", "3"] was not); a null img_name made a camera named "None"; "1_0" selected
    camera 10 and " 1 " camera 1."""
    good = {"id": 0, "img_name": "a", "width": 64, "height": 48, "position": [0, 0, 0],
            "rotation": np.eye(3).tolist(), "fx": 50, "fy": 50}
    path = tmp_path / "c.json"
    for key, value in (("position", ["1", "2", "3"]), ("rotation", [[True, False, False], [0, 1, 0], [0, 0, 1]])):
        path.write_text(json.dumps([{**good, key: value}]))
        with pytest.raises(FormatError, match=f"'{key}' must be a 3"):
            read_cameras(path)
    path.write_text(json.dumps([{**good, "img_name": None, "id": 7}]))
    assert read_cameras(path)[0].name == "7"
    path.write_text(json.dumps([{**good, "img_name": ["x"]}]))
    with pytest.raises(FormatError, match="its name must be a string or a number"):
        read_cameras(path)
    path.write_text(json.dumps([{**good, "img_name": f"v{i}"} for i in range(12)]))
    assert read_camera(f"{path}:10").name == "v10"
    assert read_camera(f"{path}:-1").name == "v11"
    for sel in ("1_0", " 1 ", "\uff11"):
        with pytest.raises(ValidationError, match="has no camera named"):
            read_camera(f"{path}:{sel}")


def test_colmap_cameras_answer_to_older_3dgs_trainers_names(tmp_path):
    """Sorted by the full COLMAP name, as the trainer's current reader does; older versions named
    cameras without folders up to the first dot ("a-1" for "images/a-1.png"), and FILE:NAME takes that."""
    d = tmp_path / "sparse"
    d.mkdir()
    (d / "cameras.txt").write_text("1 PINHOLE 64 48 50.0 52.0 31.0 25.0\n")
    rot = _qvec(Rotation.identity())
    lines = []
    for image_id, name in ((1, "images/a-1.png"), (2, "images/a.png"), (3, "images/b.jpg")):
        lines += [" ".join(map(str, [image_id, *rot, 0.0, 0.0, float(image_id), 1, name])), ""]
    (d / "images.txt").write_text("\n".join(lines) + "\n")
    cams = read_cameras(d)
    assert [c.name for c in cams] == ["images/a-1.png", "images/a.png", "images/b.jpg"]
    assert read_camera(f"{d}:a-1").name == "images/a-1.png"  # the older trainers' name
    assert read_camera(f"{d}:a").name == "images/a.png"
    assert read_camera(f"{d}:images/b.jpg").name == "images/b.jpg"
    assert read_camera(f"{d}:1").name == "images/a.png"
