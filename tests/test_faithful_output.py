"""Scenes written back as PLY keep the input's property list, order and types."""

from __future__ import annotations

import dataclasses
import pickle

import cv2
import numpy as np
import plyfile
import pytest

import seed2gs_inverse.cli as cli
from _io_encoders import (encode_compressed_ply, encode_splat, encode_spz, random_scene, standard_columns,
                          write_ply_plyfile)
from seed2gs_inverse import edit
from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.io import read_scene, write_cameras, write_scene
from seed2gs_inverse.io.ply import standard_property_names
from seed2gs_inverse.raster import build_operator
from seed2gs_inverse.scene import GaussianScene
from seed2gs_inverse.synthetic import make_scene


def properties(path) -> list:
    """(name, numpy type code) of each vertex property, as plyfile reads the header."""
    ply = plyfile.PlyData.read(str(path))
    return [(p.name, np.dtype(p.val_dtype).str[1:]) for p in ply["vertex"].properties]


def records(path) -> np.ndarray:
    return plyfile.PlyData.read(str(path))["vertex"].data


def with_extras(rng, n=31, degree=1):
    return random_scene(rng, n=n, degree=degree,
                        extra={"label": rng.integers(0, 200, n).astype(np.uint8),
                               "weight": rng.normal(size=n).astype(np.float64)})


@pytest.mark.parametrize("normals", [False, True])
@pytest.mark.parametrize("degree", [0, 3])
def test_unmodified_scene_round_trips_byte_for_byte(tmp_path, rng, normals, degree):
    src = tmp_path / "in.ply"
    write_ply_plyfile(src, with_extras(rng, degree=degree), normals=normals)
    write_scene(tmp_path / "out.ply", read_scene(src))
    assert (tmp_path / "out.ply").read_bytes() == src.read_bytes()


def test_a_subset_of_a_file_without_normals_keeps_its_header(tmp_path, rng):
    src = tmp_path / "in.ply"
    write_ply_plyfile(src, with_extras(rng), normals=False)
    scene = read_scene(src)
    keep = rng.random(len(scene)) < 0.5
    write_scene(tmp_path / "part.ply", scene.subset(keep))
    assert properties(tmp_path / "part.ply") == properties(src)
    assert not any(name in ("nx", "ny", "nz") for name, _ in properties(tmp_path / "part.ply"))
    np.testing.assert_array_equal(records(tmp_path / "part.ply"), records(src)[keep])


def test_zero_normals_are_written_back_as_zeros_without_being_kept_as_arrays(tmp_path, rng):
    src = tmp_path / "in.ply"
    write_ply_plyfile(src, random_scene(rng, n=20, degree=2), normals=True)
    scene = read_scene(src)
    assert not scene.extra  # nothing held for the zeros
    part = scene.subset(np.arange(0, 20, 3))
    write_scene(tmp_path / "part.ply", part)
    assert properties(tmp_path / "part.ply") == properties(src)
    np.testing.assert_array_equal(records(tmp_path / "part.ply"), records(src)[::3])


def test_float64_and_another_order_are_kept(tmp_path, rng):
    scene = with_extras(rng, degree=1)
    src = tmp_path / "in.ply"
    order = rng.permutation(len(standard_columns(scene, normals=True)))
    write_ply_plyfile(src, scene, normals=True, order=order, dtype="f8")
    got = read_scene(src)
    write_scene(tmp_path / "out.ply", got.subset(np.arange(5, 25)))
    props = properties(tmp_path / "out.ply")
    assert props == properties(src)
    assert dict(props)["x"] == "f8" and dict(props)["label"] == "u1"
    np.testing.assert_array_equal(records(tmp_path / "out.ply"), records(src)[5:25])


def test_values_a_recorded_type_cannot_hold_fall_back_to_their_own_type(tmp_path, rng):
    scene = random_scene(rng, n=12)
    # opacity stored as small integers (a short), everything else float32
    scene = dataclasses.replace(scene, opacity_logits=rng.integers(-5, 5, 12).astype(np.float32))
    cols = standard_columns(scene, normals=False)
    rec = np.empty(12, dtype=[(name, "i2" if name == "opacity" else "f4") for name, _ in cols])
    for name, vals in cols:
        rec[name] = vals
    src = tmp_path / "in.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(rec, "vertex")]).write(str(src))
    got = read_scene(src)
    write_scene(tmp_path / "same.ply", got)
    assert dict(properties(tmp_path / "same.ply"))["opacity"] == "i2"
    halves = dataclasses.replace(got, opacity_logits=got.opacity_logits + 0.5)
    write_scene(tmp_path / "halves.ply", halves)
    props = properties(tmp_path / "halves.ply")
    assert [n for n, _ in props] == [n for n, _ in properties(src)]
    assert dict(props)["opacity"] == "f4"
    np.testing.assert_array_equal(records(tmp_path / "halves.ply")["opacity"], halves.opacity_logits)


@pytest.mark.parametrize("text,byte_order", [(True, "="), (False, ">")])
def test_ascii_and_big_endian_inputs_keep_their_property_list(tmp_path, rng, text, byte_order):
    src = tmp_path / "in.ply"
    write_ply_plyfile(src, with_extras(rng), normals=False, text=text, byte_order=byte_order)
    write_scene(tmp_path / "out.ply", read_scene(src))
    assert properties(tmp_path / "out.ply") == properties(src)
    assert b"binary_little_endian" in (tmp_path / "out.ply").read_bytes()[:40]


def test_edits_keep_the_layout(tmp_path, rng):
    src = tmp_path / "in.ply"
    write_ply_plyfile(src, with_extras(rng), normals=False)
    scene = read_scene(src)
    sel = np.arange(4)
    for i, out in enumerate([edit.remove(scene, sel), edit.duplicate(scene, sel, translation=[1, 0, 0]),
                             edit.move(scene, sel, translation=[0, 1, 0]),
                             edit.recolour(scene, sel, [1.0, 0.0, 0.0]), scene.copy(),
                             scene.transformed(translation=[0, 0, 1]),
                             pickle.loads(pickle.dumps(scene))]):
        write_scene(tmp_path / f"e{i}.ply", out)
        assert properties(tmp_path / f"e{i}.ply") == properties(src), i


def test_a_layout_that_no_longer_fits_falls_back_to_the_trainer_layout(tmp_path, rng):
    src = tmp_path / "in.ply"
    write_ply_plyfile(src, random_scene(rng, n=10, degree=1), normals=False)
    scene = read_scene(src)
    trainer = [(name, "f4") for name in standard_property_names(0)]
    lower = dataclasses.replace(scene, sh=scene.sh[:, :1].copy())  # another SH degree
    write_scene(tmp_path / "a.ply", lower)
    assert properties(tmp_path / "a.ply") == trainer
    tagged = dataclasses.replace(scene, extra={"tag": np.ones(10, np.int32)})  # another extra
    write_scene(tmp_path / "b.ply", tagged)
    assert properties(tmp_path / "b.ply") == [(n, "f4") for n in standard_property_names(1)] + [("tag", "i4")]
    other = read_scene(_write(tmp_path / "c.ply", random_scene(rng, n=3, degree=1), normals=True))
    assert GaussianScene.concat([scene, scene]).layout == scene.layout
    assert GaussianScene.concat([scene, other]).layout is None


def _write(path, scene, **kw):
    write_ply_plyfile(path, scene, **kw)
    return path


@pytest.mark.parametrize("name,encode", [
    ("s.splat", encode_splat), ("s.spz", encode_spz),
    ("s.compressed.ply", encode_compressed_ply)])
def test_other_formats_have_no_layout_and_write_the_trainer_layout(tmp_path, rng, name, encode):
    path = tmp_path / name
    path.write_bytes(encode(random_scene(rng, n=256)))
    scene = read_scene(path)
    assert scene.layout is None
    write_scene(tmp_path / "out.ply", scene)
    degree = scene.sh_degree
    assert properties(tmp_path / "out.ply") == [(n, "f4") for n in standard_property_names(degree)]


def test_a_malformed_layout_is_refused(rng):
    scene = random_scene(rng, n=3)
    with pytest.raises(ValidationError, match="layout"):
        dataclasses.replace(scene, layout=("x", "y"))
    assert dataclasses.replace(scene, layout=[["x", "f4"]]).layout == (("x", "f4"),)


def test_convert_keeps_the_input_header(tmp_path, rng, capsys, monkeypatch):
    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_scene",))
    src = _write(tmp_path / "in.ply", with_extras(rng), normals=False)
    assert cli.main(["convert", str(src), str(tmp_path / "out.ply")]) == 0, capsys.readouterr().err
    assert (tmp_path / "out.ply").read_bytes() == src.read_bytes()


@pytest.mark.shared_data
def test_real_scene_without_normals_round_trips_and_its_remainder_does_not_grow(shared_data, tmp_path):
    src = shared_data / "firepit_562k_sh0.ply"
    scene = read_scene(src)
    write_scene(tmp_path / "same.ply", scene)
    assert (tmp_path / "same.ply").read_bytes() == src.read_bytes()
    half = scene.subset(np.arange(0, len(scene), 2))
    write_scene(tmp_path / "half.ply", half)
    assert properties(tmp_path / "half.ply") == properties(src)
    head = src.read_bytes()[:4096].split(b"end_header\n")[0]
    body = (src.stat().st_size - len(head) - len(b"end_header\n")) // len(scene)
    assert (tmp_path / "half.ply").stat().st_size < len(head) + 16 + body * len(half)


def test_extract_outputs_keep_the_input_header(tmp_path, capsys, monkeypatch):
    """object.ply and remainder.ply of a file without normals have its header and its rows."""
    monkeypatch.setattr(cli, "_COMMAND_MODULES", ("_extract",))
    syn = make_scene(seed=0)
    cam = syn.reference_camera(96, 72)
    src = _write(tmp_path / "scene.ply", syn.scene, normals=False)
    write_cameras(tmp_path / "cameras.json", [cam])
    seed = (build_operator(syn.scene, cam).W @ (syn.labels == 1).astype(np.float32)).reshape(cam.image_shape)
    cv2.imwrite(str(tmp_path / "mask.png"), (seed > 0.5).astype(np.uint8) * 255)
    out = tmp_path / "out"
    rc = cli.main([str(a) for a in ["extract", src, "--camera", f"{tmp_path / 'cameras.json'}:0", "--mask",
                                    tmp_path / "mask.png", "-o", out, "--views", 4, "--no-progress"]])
    assert rc == 0, capsys.readouterr().err
    selected = np.load(out / "q.npy", allow_pickle=False) > 0.5
    assert 0 < selected.sum() < selected.size
    for part, rows in (("object", selected), ("remainder", ~selected)):
        assert properties(out / f"{part}.ply") == properties(src), part
        np.testing.assert_array_equal(records(out / f"{part}.ply"), records(src)[rows])
    assert (out / "object.ply").stat().st_size + (out / "remainder.ply").stat().st_size < src.stat().st_size + 4096


def test_the_trainer_layout_writes_normals_as_float32_unless_they_need_more(tmp_path, rng):
    exact = rng.normal(size=6).astype(np.float32).astype(np.float64)
    scene = random_scene(rng, n=6, extra={"nx": exact, "ny": exact + 2.0 ** -40, "nz": np.zeros(6)})
    write_scene(tmp_path / "n.ply", scene)
    types = dict(properties(tmp_path / "n.ply"))
    assert (types["nx"], types["ny"], types["nz"]) == ("f4", "f8", "f4")
    back = read_scene(tmp_path / "n.ply")
    for name in ("nx", "ny"):
        np.testing.assert_array_equal(back.extra[name], scene.extra[name])
