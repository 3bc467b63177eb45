"""All-or-nothing output: write beside the target, then rename onto it.

Every writer of the toolkit (scene files, images, operator directories,
extraction outputs) goes through :func:`atomic_path`, so a failure at any
point leaves neither a partial file nor a half-written directory behind, and
an existing target is only replaced by a complete one.

A process killed while writing (SIGKILL, power loss) cannot remove its
temporary sibling. Temporaries are therefore named
``.NAME.HOST-PID-XXXXXXXX.tmp[.ext]`` (``.old`` for a replaced directory on
its way out), and the next write to the same target removes the ones that
are clearly abandoned (:func:`clean_stale_temps`) with a warning.

Concurrent writers of one target are kept apart by :func:`output_lock`: a
lock file ``.NAME.lock`` beside the target, held with ``fcntl.flock`` (an
exclusive create where there is no ``fcntl``) and holding the owner's PID
and host, so that a second writer stops at once with an error naming the
first. A write that must not replace anything (``replace=False``: a command
without ``--force``) is renamed into place with a rename that refuses an
existing target (:func:`rename_noreplace`), so a target that appears while
the output is being made is never replaced either.
"""

from __future__ import annotations

import ctypes
import errno
import fnmatch
import hashlib
import json
import os
import re
import shutil
import socket
import stat
import sys
import tempfile
import threading
import time
import warnings
from contextlib import ExitStack, contextmanager
from pathlib import Path

from .errors import ValidationError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: locks by exclusive create
    fcntl = None

__all__ = ["atomic_path", "write_files", "check_output_parent", "check_writable", "clean_stale_temps",
           "not_an_earlier_output", "OUTPUT_KINDS", "STALE_AGE_S", "output_lock", "lock_file",
           "rename_noreplace"]

#: A temporary whose creator cannot be checked (another host, or a name
#: without the host-pid tag) is abandoned after this long.
STALE_AGE_S = 24 * 3600

# Short tag of this host: a process id is only meaningful on the machine that
# made it (directories may be shared over a network file system).
_HOST = hashlib.sha1(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:6]


def _temp_prefix(name: str) -> str:
    return f".{name}.{_HOST}-{os.getpid()}-"


def _temp_pattern(name: str, suffix: str) -> re.Pattern:
    """Our temporaries for ``name``: mkstemp/mkdtemp's 8 random characters, with
    or without the host-pid tag (without it, only the age limit judges them)."""
    return re.compile(rf"^\.{re.escape(name)}\.(?:(?P<host>[0-9a-f]{{6}})-(?P<pid>[0-9]{{1,10}})-)?"
                      rf"[a-z0-9_]{{8}}\.(?:tmp(?:{re.escape(suffix)})?|old)\Z")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True  # another thread of this process may be writing the same target
    if os.name == "nt":
        return True  # os.kill(pid, 0) sends CTRL_C_EVENT there: rely on the age limit
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # exists (another user's), or not a pid we can judge: keep
    return True


def lock_file(target) -> Path:
    """The lock file of ``target``: ``.NAME.lock`` in the same directory."""
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    return parent / f".{target.name}.lock"


# Locks this process holds: lock file (absolute) -> [fd, depth, replace, pid]. Nested and
# repeated locks of one target by this process (a command, then its atomic write) share one.
_HELD: dict = {}
_HELD_GUARD = threading.Lock()
if hasattr(os, "register_at_fork"):
    # a forked child shares the parent's flock but is not its owner: it must take the lock anew (and fail)
    os.register_at_fork(after_in_child=_HELD.clear)


def _lock_owner(path: Path) -> str:
    """Who holds the lock file ``path``, in words ("PID 123", "PID 123 on host h", or unknown)."""
    for attempt in range(3):  # the owner writes its PID just after taking the lock
        try:
            text = path.read_text("utf-8", "replace")[:200].split()
        except OSError:
            text = []
        if text:
            pid, host = text[0], text[1] if len(text) > 1 else ""
            where = "" if host in ("", socket.gethostname()) else f" on host {host}"
            return f"PID {pid}{where}"
        time.sleep(0.02)
    return "a process whose PID could not be read"


def _busy(target, label, path: Path) -> ValidationError:
    return ValidationError(f"{label + ': ' if label else ''}{target} is being written by another seed2gs process "
                           f"({_lock_owner(path)}; lock file {path}): wait for it to finish, or choose "
                           f"another output")


def _take_lock(path: Path, target, label) -> int:
    """Take the lock file ``path``; its open descriptor (-1: locking is not supported there)."""
    me = f"{os.getpid()} {socket.gethostname()}\n".encode()
    for _ in range(20):  # retried only while earlier owners remove the file under us
        if fcntl is None:
            try:
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                words = path.read_text("utf-8", "replace").split() if path.is_file() else []
                if (len(words) >= 2 and words[0].isdigit() and words[1] == socket.gethostname()
                        and not _pid_alive(int(words[0]))):
                    path.unlink(missing_ok=True)  # a stale lock: its owner has exited
                    continue
                raise _busy(target, label, path) from None
            except OSError as exc:  # a read-only or full directory: said as the write itself would
                raise _naming(exc, target) from exc
            return _sign_lock(path, fd, me, target)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0),
                         0o644)
        except OSError as exc:  # a read-only or full directory: said as the write itself would
            raise _naming(exc, target) from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise _busy(target, label, path) from None
        except OSError:  # a file system without flock: go on unlocked (the rename still refuses to replace)
            os.close(fd)
            return -1
        # A lock file left by an exited owner is not locked: taken over here (stale). One its owner
        # removed between our open and our lock is another file than the one at ``path`` now: retry.
        try:
            now = os.stat(path, follow_symlinks=False)
        except FileNotFoundError:
            now = None
        mine = os.fstat(fd)
        if now is None or (now.st_ino, now.st_dev) != (mine.st_ino, mine.st_dev):
            os.close(fd)
            continue
        return _sign_lock(path, fd, me, target)
    raise _busy(target, label, path)


def _sign_lock(path: Path, fd: int, me: bytes, target) -> int:
    """Write ``me`` (``"PID HOST"``) into the lock file ``path`` just taken as ``fd``; ``fd``.

    If it cannot be written (a full disk), the lock is dropped (file removed,
    ``fd`` closed) and the OSError names ``target``.
    """
    try:
        os.ftruncate(fd, 0)
        os.write(fd, me)
    except OSError as exc:
        _drop_lock(path, fd)
        raise _naming(exc, target) from exc
    return fd


def _drop_lock(path: Path, fd: int) -> None:
    """Remove the lock file ``path`` (while still holding it, so no one else can be holding it) and close ``fd``."""
    if fd < 0:
        return
    try:
        now = os.stat(path, follow_symlinks=False)
        mine = os.fstat(fd)
        if (now.st_ino, now.st_dev) == (mine.st_ino, mine.st_dev):
            os.unlink(path)
    except OSError:
        pass
    os.close(fd)


@contextmanager
def output_lock(target, label: str | None = None, *, replace: bool | None = None):
    """Hold the lock of the output ``target`` for the duration of the block.

    Parameters
    ----------
    target : path-like
        The file or directory being written. Its directory must exist; the
        lock file is ``.NAME.lock`` there (:func:`lock_file`), holding
        ``"PID HOST"`` of the owner, and is removed on release.
    label : str, optional
        What the error names first (``"-o out"``), before the path.
    replace : bool, optional
        Whether :func:`atomic_path` writes of ``target`` inside the block
        may replace an existing target (None: as they are told).

    Raises
    ------
    ValidationError
        Another process holds the lock: the message names its PID (and host,
        when another). A lock file whose owner has exited is taken over.
    OSError
        The lock file cannot be created (``"<reason> while writing <target>"``).

    Notes
    -----
    The lock is taken with ``fcntl.flock``, which the operating system
    releases when its owner exits, however it exits; where there is no
    ``fcntl``, by an exclusive create, a stale file being recognised by its
    dead PID on this host. Within one process the lock is re-entrant (all
    threads share it). On a file system without ``flock`` the block runs
    unlocked.
    """
    path = lock_file(target)
    key = os.path.abspath(path)
    with _HELD_GUARD:
        held = _HELD.get(key)
        if held is None:
            held = _HELD[key] = [_take_lock(path, target, label), 0, replace]
        held[1] += 1
    try:
        yield path
    finally:
        with _HELD_GUARD:
            held[1] -= 1
            if held[1] == 0 and _HELD.get(key) is held:
                del _HELD[key]
                _drop_lock(path, held[0])


def _held_replace(target):
    """The ``replace`` of an enclosing :func:`output_lock` of ``target`` in this process (None: none said)."""
    with _HELD_GUARD:
        held = _HELD.get(os.path.abspath(lock_file(target)))
    return None if held is None else held[2]


_RENAME_NOREPLACE = 1
_AT_FDCWD = -100
_renameat2 = []  # [function or None], looked up on first use


def _libc_renameat2():
    if not _renameat2:
        fn = None
        if sys.platform.startswith("linux"):
            try:
                fn = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
            except OSError:
                fn = None
            if fn is not None:
                fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
                fn.restype = ctypes.c_int
        _renameat2.append(fn)
    return _renameat2[0]


def rename_noreplace(src, dst) -> None:
    """Rename ``src`` (a file or directory) to ``dst``, which must not exist; FileExistsError if it does.

    Atomic where the kernel and file system offer ``renameat2(RENAME_NOREPLACE)``
    (Linux). Elsewhere a file is hard-linked to ``dst`` (which fails on an
    existing one) and ``src`` removed; a directory is renamed after a check,
    and a rename never moves a directory onto a non-empty one.
    """
    src, dst = os.fspath(src), os.fspath(dst)
    fn = _libc_renameat2()
    if fn is not None:
        if fn(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), _RENAME_NOREPLACE) == 0:
            return
        err = ctypes.get_errno()
        if err not in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
            raise OSError(err, os.strerror(err), src, None, dst) if err != errno.EEXIST else \
                FileExistsError(err, os.strerror(err), dst)
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), dst)
    if not os.path.isdir(src):
        try:
            os.link(src, dst, follow_symlinks=False)
        except FileExistsError:
            raise
        except OSError:  # no hard links here (FAT, some network file systems): checked just above
            os.rename(src, dst)
            return
        os.unlink(src)
        return
    try:
        os.rename(src, dst)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), dst) from None
        raise


def clean_stale_temps(target, now: float | None = None) -> list:
    """Remove abandoned temporaries of earlier writes to ``target``; the paths removed.

    Only names of :func:`atomic_path`'s own pattern for this very target are
    considered, and only when clearly abandoned: made on this host by a
    process that has exited, or (creator unknown: other host, no host-pid
    tag) not modified for ``STALE_AGE_S`` seconds. A temporary of a
    running process -- a concurrent writer of the same target -- is never
    touched. Symbolic links are removed, never followed. A warning lists what
    was removed; errors while removing are ignored (another process may be
    cleaning up too).
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    pattern = _temp_pattern(target.name, target.suffix)
    now = time.time() if now is None else now
    removed = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for entry in entries:
        match = pattern.match(entry.name)
        if not match:
            continue
        try:
            st = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if match["pid"] is not None and match["host"] == _HOST:
            stale = not _pid_alive(int(match["pid"]))
        else:
            stale = now - st.st_mtime > STALE_AGE_S
        if not stale:
            continue
        if entry.name.endswith(".old") and not os.path.lexists(target):
            # killed between moving the old output aside and moving the new one in:
            # the .old directory holds the only copy of the previous output
            continue
        path = Path(entry.path)
        try:
            if stat.S_ISDIR(st.st_mode):
                shutil.rmtree(path)
            else:
                path.unlink()
        except FileNotFoundError:
            continue
        except OSError:
            continue
        removed.append(path)
    if removed:
        names = ", ".join(p.name for p in removed[:3]) + (", ..." if len(removed) > 3 else "")
        warnings.warn(f"removed {len(removed)} stale temporary "
                      f"{'entry' if len(removed) == 1 else 'entries'} left in {parent} by an "
                      f"interrupted write of {target.name}: {names}", stacklevel=3)
    return removed


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _replaced_mode(target: Path, directory: bool):
    """The permission bits of the file ``target`` that a write is about to replace (None: no such file).

    A replaced file keeps its mode, as an editor's save does: a read-only
    file the user replaced with ``--force`` was made writable (0644).
    """
    if directory:
        return None
    try:
        st = os.stat(target)
    except OSError:
        return None
    return stat.S_IMODE(st.st_mode) if stat.S_ISREG(st.st_mode) else None


@contextmanager
def atomic_path(target, directory: bool = False, *, replace: bool | None = None):
    """Yield a temporary sibling of ``target``; move it onto ``target`` on success.

    Parameters
    ----------
    target : path-like
        Final file or directory. Its parent must exist.
    directory : bool
        Yield an empty temporary directory instead of a file path. An existing
        ``target`` directory is replaced only after the new one is complete.
    replace : bool, optional
        Whether an existing ``target`` may be replaced. False: an existing
        target is an error before the block runs, and one that appears while
        it runs is not replaced either (the new output is discarded, with
        an error). None: as an enclosing :func:`output_lock` of ``target``
        says, else True.

    The temporary path gets the permissions a plain ``open``/``mkdir`` would
    (``mkstemp``/``mkdtemp`` create private ones), or those of the file it
    replaces. If the block raises, the
    temporary path is removed and the exception propagates. Abandoned
    temporaries of earlier, killed writes to the same target are removed
    first (:func:`clean_stale_temps`, with a warning). The write holds the
    target's :func:`output_lock` throughout.

    Raises
    ------
    ValidationError
        The parent directory is missing; another process holds the
        target's lock; or, without ``replace``, the target exists or
        appeared during the write.
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():  # say so with the caller's path, not with a temporary name inside it
        raise ValidationError(f"{target}: the directory {parent} does not exist (create it first)")
    with output_lock(target):
        if replace is None:
            replace = _held_replace(target) is not False
        if not replace and os.path.lexists(target):
            raise ValidationError(f"{target} exists; use --force to replace it")
        with _atomic_path_locked(target, parent, directory, replace) as tmp:
            yield tmp


@contextmanager
def _atomic_path_locked(target: Path, parent: Path, directory: bool, replace: bool):
    clean_stale_temps(target)
    prefix = _temp_prefix(target.name)
    try:
        if directory:
            tmp = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=parent))
            mode = 0o777
        else:
            # keep the extension: some writers (image libraries) choose the format by it
            fd, name = tempfile.mkstemp(prefix=prefix, suffix=".tmp" + target.suffix, dir=parent)
            os.close(fd)
            tmp = Path(name)
            mode = 0o666
    except OSError as exc:  # a read-only or full directory: name the target, not the temporary
        raise _naming(exc, target) from exc
    try:
        yield tmp
        os.chmod(tmp, _replaced_mode(target, directory) or mode & ~_umask())
        if not replace:
            try:
                rename_noreplace(tmp, target)
            except FileExistsError:
                raise ValidationError(f"{target} appeared while this output was being made (written by "
                                      f"another process?); it was not replaced and this output was discarded: "
                                      f"use --force to replace it, or choose another path") from None
        elif directory and target.exists():
            old = Path(tempfile.mkdtemp(prefix=prefix, suffix=".old", dir=parent))
            try:
                os.replace(target, old / "previous")
            except BaseException:
                old.rmdir()  # still empty: the target stays where it was
                raise
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException as exc:
        # a short write's cause is learnt from the partial file, so before it is removed
        short = _short_write(exc, tmp, target, directory)
        if directory:
            shutil.rmtree(tmp, ignore_errors=True)
        elif tmp.exists():
            tmp.unlink()
        if short is not None:
            raise short from exc
        if getattr(exc, "_seed2gs_target", None) is not None:
            # from an atomic write inside our temporary directory: name that file's final place
            inner = os.fspath(exc._seed2gs_target)
            raise _naming(exc, inner.replace(os.fspath(tmp), os.fspath(target), 1)) from exc.__cause__
        if isinstance(exc, OSError) and exc.errno is not None and (
                exc.filename is None or os.fspath(exc.filename).startswith(os.fspath(tmp))):
            # a full disk or a refused rename: name what was being written, not its temporary
            raise _naming(exc, target) from exc
        raise


def _naming(exc: OSError, target) -> OSError:
    """``exc`` again as ``"<reason> while writing <target>"``, of the errno's own OSError subclass
    (PermissionError, FileNotFoundError, ...), marked with its reason and target so that an
    enclosing write names its own final path instead."""
    reason = getattr(exc, "_seed2gs_reason", None) or exc.strerror or str(exc)
    err = OSError(exc.errno, f"{reason} while writing {target}") if exc.errno is not None else \
        OSError(f"{reason} while writing {target}")
    err._seed2gs_reason, err._seed2gs_target = reason, target
    return err


# numpy's message when the operating system accepts fewer bytes than asked (ndarray.tofile, np.save):
# it names neither the file nor the reason
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")


def _short_write(exc: BaseException, tmp: Path, target: Path, directory: bool) -> OSError | None:
    """The OSError naming the file and the operating system's cause of a short write; None for other errors.

    A write that stopped part-way without an errno (numpy's ``"N requested
    and M written"``) is retried for one byte on the partial file, which
    makes the operating system say why (``ENOSPC``, ``EDQUOT``, ``EFBIG``);
    if that byte goes through, a file system without free blocks is
    ``ENOSPC``. The file named is the target, or in a temporary directory the
    file written last, at its final place.
    """
    if not (isinstance(exc, OSError) and exc.errno is None and _SHORT_WRITE.fullmatch(str(exc).strip())):
        return None
    partial, final = tmp, target
    if directory:
        files = [p for p in tmp.rglob("*") if p.is_file() and not p.is_symlink()]
        partial = max(files, key=lambda p: p.stat().st_mtime_ns) if files else tmp / ".seed2gs-probe"
        final = target / partial.relative_to(tmp) if files else target
    cause = _probe_write(partial)
    if cause is None:
        try:
            full = os.statvfs(partial.parent).f_bavail == 0
        except (OSError, AttributeError):
            full = False
        cause = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)) if full else \
            OSError(f"the write stopped part-way ({exc}): the disk may be full or a file size limit reached")
    return _naming(cause, final)


def _probe_write(path: Path) -> OSError | None:
    """Append one byte to ``path`` (created if missing); the OSError the operating system gives, if any."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        try:
            os.write(fd, b"\0")
        finally:
            os.close(fd)
    except OSError as exc:
        if exc.errno is not None:
            return OSError(exc.errno, exc.strerror or os.strerror(exc.errno))
    return None


def write_files(items, *, replace: bool | None = None) -> None:
    """Write every ``(path, bytes)`` pair or none of them.

    All payloads are written to temporary files first; only when every one
    is complete are they renamed onto their targets. ``replace`` is
    :func:`atomic_path`'s.
    """
    items = [(Path(p), payload) for p, payload in items]
    with ExitStack() as stack:
        for path, payload in items:
            tmp = stack.enter_context(atomic_path(path, replace=replace))
            tmp.write_bytes(payload)


def check_writable(directory, label: str) -> None:
    """Raise a ValidationError ``"{label}: cannot write in {directory} (reason)"`` unless a file can be
    created in ``directory`` (checked with a probe file, removed at once): ``/proc``, a read-only mount
    or a missing permission fails here, before any work."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".seed2gs-write-check.", dir=directory)
    except OSError as exc:
        reason = exc.strerror or errno.errorcode.get(exc.errno, type(exc).__name__)
        raise ValidationError(f"{label}: cannot write in {directory} ({reason})") from None
    os.close(fd)
    os.unlink(probe)


def check_output_parent(path, option: str) -> Path:
    """Raise unless ``path``'s directory exists (call before expensive work).

    Writers never create missing parent directories: a typo in a path should
    fail at once, not after minutes of work or by leaving new directories.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ValidationError(f"{option} {path}: the directory {parent} does not exist")
    return path


#: The output directories the toolkit may replace, by kind: the marker file every such output
#: holds, a test that the marker is the toolkit's own (its JSON content), and the names written there.
OUTPUT_KINDS = {
    "extract": ("report.json", lambda d: isinstance(d, dict) and isinstance(d.get("outputs"), dict),
                ("report.json", "report.png", "report_masks.png", "q.npy", "object.*", "remainder.*",
                 # with --save-operators: the solve's inputs (solvers.inputs.FILES)
                 "solve.json", "operators", "masks", "init.npy", "graph.npz", "follow.npz", "islands.npy")),
    "operators": ("manifest.json", lambda d: isinstance(d, dict) and d.get("format") == "seed2gs-operators",
                  ("manifest.json", "view_*.npy")),
    "compare": ("comparison.json", lambda d: isinstance(d, dict) and isinstance(d.get("rows"), list),
                ("comparison.json", "comparison.csv", "comparison.png")),
    "split": ("split.json", lambda d: isinstance(d, dict) and d.get("command") == "split",
              ("split.json", "object.*", "remainder.*")),
}


def not_an_earlier_output(directory, kind: str) -> str | None:
    """Why the existing directory may not be replaced as an earlier output of ``kind``; None if it may.

    It may when it is empty, or when its marker file (:data:`OUTPUT_KINDS`:
    ``report.json`` of ``extract``, ``manifest.json`` of an operator
    directory, ``comparison.json`` of ``compare``, ``split.json`` of
    ``split``) is the
    toolkit's own and it holds nothing but the files of that output:
    replacing a directory must never take a user's other files with it (an
    empty ``{}`` named report.json, or notes added next to an earlier output).
    """
    d = Path(directory)
    names = sorted(e.name for e in d.iterdir())
    if not names:
        return None
    marker, is_ours, own = OUTPUT_KINDS[kind]
    try:
        ours = is_ours(json.loads((d / marker).read_text("utf-8")))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):  # deep nesting: RecursionError
        ours = False
    if not ours:
        return f"it is not empty and is not an earlier output (its {marker} is missing or not the toolkit's)"
    foreign = [n for n in names if not any(fnmatch.fnmatchcase(n, pat) for pat in own)]
    if foreign:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        return f"it holds files that are not part of such an output ({shown})"
    return None
