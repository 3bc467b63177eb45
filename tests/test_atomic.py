"""All-or-nothing output helper."""

import os
import stat

import pytest

from seed2gs_inverse._atomic import atomic_path, write_files


def test_file_appears_only_when_complete(tmp_path):
    target = tmp_path / "a.png"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            assert tmp.suffix == ".png" and tmp.parent == tmp_path
            tmp.write_bytes(b"partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with atomic_path(target) as tmp:
        tmp.write_bytes(b"done")
    assert target.read_bytes() == b"done"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask


def test_directory_replaces_old_one_only_on_success(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(KeyError):
        with atomic_path(target, directory=True) as tmp:
            (tmp / "new.txt").write_text("new")
            raise KeyError("boom")
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    assert (target / "old.txt").read_text() == "old"
    with atomic_path(target, directory=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in target.iterdir()) == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o777 & ~umask  # not mkdtemp's private 0700


def test_write_files_all_or_nothing(tmp_path):
    class Boom:
        def __len__(self):
            raise RuntimeError("unencodable")

    with pytest.raises(TypeError):
        write_files([(tmp_path / "a.bin", b"a"), (tmp_path / "b.bin", Boom())])
    assert list(tmp_path.iterdir()) == []
    write_files([(tmp_path / "a.bin", b"a"), (tmp_path / "b.bin", b"b")])
    assert (tmp_path / "a.bin").read_bytes() == b"a" and (tmp_path / "b.bin").read_bytes() == b"b"
