"""All-or-nothing output helper."""

import os
import signal
import stat
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from seed2gs_inverse import _atomic
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


# --------------------------------------------------------------------------
# temporaries left by a killed writer are cleaned up by the next write (issue 12, item 8)

_KILLED_WRITER = """
import os, signal, sys
from pathlib import Path
from seed2gs_inverse._atomic import atomic_path
target, directory = Path(sys.argv[1]), sys.argv[2] == "dir"
with atomic_path(target, directory=directory) as tmp:
    if directory:
        (tmp / "object.ply").write_bytes(b"x" * 1000)
    else:
        tmp.write_bytes(b"x" * 1000)
    print(tmp, flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
"""


def _killed_write(target, directory):
    proc = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(target),
                           "dir" if directory else "file"], capture_output=True, text=True,
                          cwd=os.getcwd(), env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    tmp = Path(proc.stdout.strip())
    assert tmp.exists() and tmp.name.startswith(f".{target.name}.")
    return tmp


@pytest.mark.parametrize("directory", [True, False])
def test_sigkilled_temp_removed_by_next_write(tmp_path, directory):
    target = tmp_path / ("OUT" if directory else "out.ply")
    tmp = _killed_write(target, directory)
    unrelated = [tmp_path / ".OUT.notes", tmp_path / "OUT.tmp", tmp_path / ".other.ply.abcdefgh.tmp"]
    for p in unrelated:
        p.write_text("keep")
    with pytest.warns(UserWarning, match=r"removed 1 stale temporary entry .* interrupted write"):
        with atomic_path(target, directory=directory) as new:
            (new / "a").write_text("new") if directory else new.write_text("new")
    assert not tmp.exists()
    assert all(p.exists() for p in unrelated)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [target.name] + [p.name for p in unrelated])


def test_temps_of_running_writers_are_kept(tmp_path):
    target = tmp_path / "OUT"
    # a concurrent writer that is still running (a live child process)
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = tmp_path / f".OUT.{_atomic._HOST}-{child.pid}-abcd1234.tmp"
        live.mkdir()
        own = tmp_path / f".OUT.{_atomic._HOST}-{os.getpid()}-abcd1234.tmp"  # another thread
        own.mkdir()
        other_host = tmp_path / f".OUT.000000-{child.pid + 1}-abcd1234.tmp"
        other_host.mkdir()
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert _atomic.clean_stale_temps(target) == []
        assert live.exists() and own.exists() and other_host.exists()
    finally:
        child.kill()
        child.wait()
    # the child is gone now: its temporary is abandoned; the other host's waits for the age limit
    with pytest.warns(UserWarning, match="removed 1 stale"):
        assert _atomic.clean_stale_temps(target) == [live]
    assert own.exists() and other_host.exists()


def test_temps_without_creator_are_removed_only_when_old(tmp_path):
    target = tmp_path / "scene.ply"
    legacy = tmp_path / ".scene.ply.k2j4_x9a.tmp.ply"  # the naming before process ids
    legacy.write_bytes(b"partial")
    assert _atomic.clean_stale_temps(target) == []
    old = time.time() - _atomic.STALE_AGE_S - 60
    os.utime(legacy, (old, old))
    link_target = tmp_path / "precious"
    link_target.write_text("keep")
    link = tmp_path / ".scene.ply.aaaaaaaa.tmp"
    link.symlink_to(link_target)
    os.utime(link, (old, old), follow_symlinks=False)
    with pytest.warns(UserWarning, match="removed 2 stale"):
        removed = _atomic.clean_stale_temps(target)
    assert sorted(removed) == sorted([legacy, link])
    assert link_target.read_text() == "keep"  # links are removed, never followed


def test_old_directory_kept_when_it_holds_the_only_copy(tmp_path):
    target = tmp_path / "OUT"  # killed between the two renames: no OUT, a .old with the previous
    old_dir = tmp_path / ".OUT.000000-1-abcd1234.old"
    (old_dir / "previous").mkdir(parents=True)
    stamp = time.time() - _atomic.STALE_AGE_S - 60
    os.utime(old_dir, (stamp, stamp))
    assert _atomic.clean_stale_temps(target) == []
    target.mkdir()
    with pytest.warns(UserWarning):
        assert _atomic.clean_stale_temps(target) == [old_dir]


def test_errors_name_the_target_not_its_temporary(tmp_path, monkeypatch):
    import errno

    from seed2gs_inverse.errors import ValidationError

    with pytest.raises(ValidationError, match=r"x\.ply: the directory .*nodir does not exist"):
        with atomic_path(tmp_path / "nodir" / "x.ply"):
            pass
    target = tmp_path / "out.bin"
    with pytest.raises(OSError) as exc:
        with atomic_path(target) as tmp:
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp))  # what a full disk raises
    assert exc.value.errno == errno.ENOSPC and str(target) in str(exc.value) and ".tmp" not in str(exc.value)
    assert list(tmp_path.iterdir()) == []
    # A directory that cannot be moved aside (here: a rename refused) stays, and no '.old' is left.
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "keep").write_text("x")
    real = os.replace

    def refuse(src, dst):
        if os.fspath(src) == os.fspath(tmp_path / "d"):
            raise OSError(errno.EBUSY, "Device or resource busy", os.fspath(src))
        return real(src, dst)

    monkeypatch.setattr(_atomic.os, "replace", refuse)
    with pytest.raises(OSError, match="busy"):
        with atomic_path(tmp_path / "d", directory=True) as tmp:
            (tmp / "new").write_text("y")
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
    assert (tmp_path / "d" / "keep").read_text() == "x"


def test_nested_and_refused_writes_name_the_final_file_once(tmp_path, monkeypatch):
    import errno

    out = tmp_path / "out"
    with pytest.raises(OSError) as exc:
        with atomic_path(out, directory=True) as tmpdir:
            with atomic_path(tmpdir / "remainder.ply") as tmp:  # as extract writes its folder
                raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    msg = str(exc.value)
    assert exc.value.errno == errno.ENOSPC and msg.count("while writing") == 1, msg
    with pytest.raises(PermissionError, match=r"Permission denied while writing .*out$"):  # the errno's class
        with atomic_path(out, directory=True) as tmpdir:
            raise OSError(errno.EACCES, "Permission denied", str(tmpdir / "x"))
    assert f"while writing {out / 'remainder.ply'}" in msg and ".tmp" not in msg
    assert list(tmp_path.iterdir()) == []

    def refuse(*args, **kwargs):  # what a read-only directory answers (root ignores permission bits)
        raise OSError(errno.EROFS, "Read-only file system", os.fspath(tmp_path / ".x.ply.tmp"))

    monkeypatch.setattr(_atomic.tempfile, "mkstemp", refuse)
    with pytest.raises(OSError, match=r"Read-only file system while writing .*x\.ply$") as exc:
        with atomic_path(tmp_path / "x.ply"):
            pass
    assert ".tmp" not in str(exc.value)
