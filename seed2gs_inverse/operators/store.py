"""Saving and loading stacks of view operators (no pickle), and the scene fingerprint.

Layout::

    DIR/manifest.json            {"format": "seed2gs-operators", "version": 1,
                                  "n_gaussians": N, "fingerprint": "...",
                                  "views": [{"camera": {...}, "image_shape": [H, W],
                                             "nnz": nnz, "files": {"data": ...,
                                             "indices": ..., "indptr": ...,
                                             ["rgb" | "alpha" | "depth" | "n_contrib"]: ...}}]}
    DIR/view_000_data.npy ...    one .npy per array

A view saved with some of the rendering arrays loads with a
:class:`~seed2gs_inverse.operators.view.Rendering` holding those (the others
``None``).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from .._atomic import atomic_path, not_an_earlier_output
from ..camera import Camera
from ..errors import FormatError, ValidationError
from ..io._common import npy_header
from ..scene import GaussianScene
from .view import RENDER_FIELDS, Rendering, ViewOperator, rendering_problem

__all__ = ["save", "load", "check_target", "scene_fingerprint", "FORMAT_NAME", "FORMAT_VERSION"]

FORMAT_NAME = "seed2gs-operators"
FORMAT_VERSION = 1
_CSR_FILES = ("data", "indices", "indptr")
# Loading bounds: W's columns are int32-indexable scene Gaussians and a view
# is a camera image (the camera readers' limit of 32,768 px a side).
_MAX_GAUSSIANS = np.iinfo(np.int32).max
_MAX_SIDE = 32768


def scene_fingerprint(scene) -> str:
    """Short content hash identifying a scene, stored with saved operators.

    SHA-256 over the Gaussian count and the raw bytes of every array that
    ``W(c)`` depends on: means, quaternions, log-scales and opacity logits,
    truncated to 16 hex digits. Colours (SH) are deliberately left out: the
    compositing weights do not depend on them, so a recoloured scene can use
    the same operators. Each array is read once (44 bytes per Gaussian in float32).

    Parameters
    ----------
    scene : GaussianScene or FrozenScene

    Returns
    -------
    str
        16 lowercase hex digits.
    """
    scene = _geometry(scene, "scene_fingerprint")
    h = hashlib.sha256()
    h.update(f"n={len(scene)};geometry+opacity;".encode())
    for arr in (scene.means, scene.quats, scene.log_scales, scene.opacity_logits):
        h.update(memoryview(np.ascontiguousarray(arr, dtype=np.float32)).cast("B"))
    return h.hexdigest()[:16]


def _geometry(scene, what: str) -> GaussianScene:
    """The GaussianScene of ``scene``: itself, or the one a :class:`~seed2gs_inverse.raster.FrozenScene`
    holds (taken by its ``scene`` attribute: this layer does not import the rasterizer)."""
    inner = getattr(scene, "scene", scene)
    if not isinstance(inner, GaussianScene):
        raise ValidationError(f"{what}: scene must be a GaussianScene or a FrozenScene, got {type(scene).__name__}")
    return inner


def save(views, fingerprint, directory, overwrite: bool = False) -> Path:
    """Write ``views`` (ViewOperator list) to ``directory`` (manifest.json + one .npy per array).

    The files are written into a temporary sibling directory that is
    renamed into place at the end, so a failure leaves nothing partial.

    Parameters
    ----------
    views : sequence of ViewOperator
    fingerprint : str or None
    directory : path
        Must not exist, or be empty, or (with ``overwrite=True``) be an
        existing operator directory, which is replaced.
    overwrite : bool
        Replace an existing operator directory.

    Returns
    -------
    Path of the directory.
    """
    target = check_target(directory, overwrite)
    _check_space(views, target)
    # without overwrite, an empty directory found by check_target is the only thing replaced
    with atomic_path(target, directory=True, replace=overwrite or target.exists()) as tmp:
        entries = []
        for i, v in enumerate(views):
            W = v.W
            files = {}
            arrays = {"data": np.asarray(W.data, dtype=np.float32),
                      "indices": np.asarray(W.indices), "indptr": np.asarray(W.indptr)}
            idx_dtype = np.int64 if (arrays["indptr"].dtype == np.int64 or W.nnz > np.iinfo(np.int32).max) \
                else np.int32
            arrays["indices"] = arrays["indices"].astype(idx_dtype, copy=False)
            arrays["indptr"] = arrays["indptr"].astype(idx_dtype, copy=False)
            if v.rendering is not None:
                for key in RENDER_FIELDS:
                    val = getattr(v.rendering, key)
                    if val is not None:
                        arrays[key] = np.asarray(val)
            for key, arr in arrays.items():
                fname = f"view_{i:03d}_{key}.npy"
                np.save(tmp / fname, arr, allow_pickle=False)
                files[key] = fname
            entries.append({"camera": v.camera.to_dict() if v.camera is not None else None,
                            "image_shape": list(v.image_shape), "nnz": int(W.nnz), "files": files})
        manifest = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "n_gaussians": int(views[0].n_gaussians),
                    "fingerprint": fingerprint, "views": entries}
        with open(tmp / "manifest.json", "w", encoding="utf-8") as fh:
            json.dump(manifest, fh, indent=1)
    return target


def _check_space(views, target: Path) -> None:
    """Raise before writing when the file system of ``target`` cannot hold the stack (with 5% to spare)."""
    need = 0
    for v in views:
        need += v.W.data.nbytes + v.W.indices.nbytes + v.W.indptr.nbytes
        if v.rendering is not None:
            need += sum(np.asarray(a).nbytes for a in (getattr(v.rendering, k) for k in RENDER_FIELDS)
                        if a is not None)
    parent = target.resolve().parent
    free = shutil.disk_usage(parent).free
    room = 1.05 * need + 2 ** 20  # + headers and the manifest
    if room > free:
        raise ValidationError(f"{target}: the operators need {_size(need)} ({_size(room)} with room to spare) but "
                              f"{parent} has {_size(free)} free; free space, save elsewhere, or build fewer or "
                              f"smaller views")


def _size(n: float) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.1f} MB" if n >= 1e6 else f"{n / 1e3:.0f} kB"


def check_target(directory, overwrite: bool = False) -> Path:
    """Raise unless :func:`save` may write to ``directory`` (call it before expensive work).

    Allowed: a missing or empty directory, or an operator directory with
    ``overwrite=True``; never a non-empty directory of something else, nor
    an operator directory that also holds other files.
    """
    target = Path(directory)
    if target.exists():
        if not target.is_dir():
            raise ValidationError(f"{target}: exists and is not a directory")
        if any(target.iterdir()):
            why = not_an_earlier_output(target, "operators")
            if why is not None:
                raise ValidationError(f"{target}: exists and {why}; choose another output directory")
            if not overwrite:
                raise ValidationError(f"{target}: an operator directory already exists; "
                                      "replace it with overwrite=True (seed2gs operators build --force)")
    elif not (target.parent if str(target.parent) else Path(".")).is_dir():
        raise ValidationError(f"{target}: the parent directory {target.parent} does not exist")
    return target


def load(directory, mmap: bool = True, scene=None) -> tuple:
    """Read the views written by :func:`save`: ``(list of ViewOperator, fingerprint)``.

    Everything is validated before use: manifest format and version, the
    camera descriptions, array dtypes and shapes, ``indptr`` (starts at 0,
    non-decreasing, ends at nnz), column indices in ``[0, N)`` and finite,
    non-negative weights. Nothing is unpickled.

    Parameters
    ----------
    directory : path
    mmap : bool
        Memory-map the arrays (read-only) instead of reading them. The
        package's passes only read them; scipy calls that canonicalise a
        matrix in place (``W.max()``, ``W > t``, ``W.sum_duplicates()``: the
        rows are stored in compositing order, not column order) raise
        ``ValueError`` on a read-only map: use ``W.copy()`` or ``mmap=False``
        for those.
    scene : GaussianScene or FrozenScene, optional
        When given, the stack must have been built from this scene (same
        Gaussian count and :func:`scene_fingerprint`).

    Raises
    ------
    FormatError
        The directory is not a valid operator directory (the message names
        the file).
    ValidationError
        ``scene`` does not match the stack.
    """
    d = Path(directory)
    mpath = d / "manifest.json"
    if not d.is_dir():
        raise FormatError(f"{d}: not a directory; expected an operator directory with manifest.json")
    if not mpath.is_file():
        raise FormatError(f"{d}: no manifest.json; not an operator directory (build one with "
                          "'seed2gs operators build')")
    try:
        with open(mpath, "r", encoding="utf-8") as fh:
            manifest = json.load(fh)
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError, and ints of > 4300 digits
        raise FormatError(f"{mpath}: not valid JSON ({exc})") from None
    except RecursionError:
        raise FormatError(f"{mpath}: not an operator manifest (nested too deeply to read)") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT_NAME:
        raise FormatError(f"{mpath}: not a seed2gs operator manifest (format field must be '{FORMAT_NAME}')")
    version = manifest.get("version")
    if not _is_int(version) or version != FORMAT_VERSION:
        raise FormatError(f"{mpath}: unsupported format version {version!r}; this reader knows "
                          f"version {FORMAT_VERSION}")
    n = manifest.get("n_gaussians")
    if not _is_int(n) or not 0 < n <= _MAX_GAUSSIANS:
        raise FormatError(f"{mpath}: n_gaussians must be an integer in [1, {_MAX_GAUSSIANS}], got {n!r}")
    fingerprint = manifest.get("fingerprint")
    if fingerprint is not None and not isinstance(fingerprint, str):
        raise FormatError(f"{mpath}: fingerprint must be a string or null")
    entries = manifest.get("views")
    if not isinstance(entries, list) or not entries:
        raise FormatError(f"{mpath}: 'views' must be a non-empty list")
    if scene is not None:
        scene = _geometry(scene, f"{d}")
        if len(scene) != n:
            raise ValidationError(f"{d}: operators were built for {n} Gaussians but the scene has "
                                  f"{len(scene)}; rebuild the operators for this scene")
        fp = scene_fingerprint(scene)
        if fingerprint is None:
            raise ValidationError(f"{d}: the stack was saved without a scene fingerprint, so it cannot be "
                                  f"checked against a scene; load it without scene=, or save it with "
                                  f"OperatorStack(views, fingerprint=scene_fingerprint(scene))")
        if fingerprint != fp:
            raise ValidationError(f"{d}: scene fingerprint {fingerprint} does not match the given scene "
                                  f"({fp}); the operators belong to another scene")
    return [_load_view(d, mpath, i, e, n, mmap) for i, e in enumerate(entries)], fingerprint


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _load_array(d: Path, mpath: Path, label: str, files: dict, key: str, mmap: bool):
    fname = files.get(key)
    if not isinstance(fname, str) or not fname or Path(fname).name != fname or fname in (".", ".."):
        raise FormatError(f"{mpath}: {label} has an invalid file name for '{key}': {fname!r}")
    path = d / fname
    if not path.is_file():
        raise FormatError(f"{path}: missing ({label}, array '{key}')")
    if path.is_symlink() and d.resolve() not in path.resolve().parents:
        raise FormatError(f"{path}: a link to {path.resolve()}, outside the operator directory ({label}, "
                          f"'{key}'); operator directories must hold their own files")
    npy_header(path, f"{path} ({label}, '{key}')")
    try:
        arr = np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None)
    except (ValueError, OSError, EOFError) as exc:
        raise FormatError(f"{path}: not a readable .npy array ({label}, '{key}'): {exc}") from None
    if not isinstance(arr, np.ndarray):  # e.g. an .npz archive under a .npy name
        getattr(arr, "close", lambda: None)()
        raise FormatError(f"{path}: not a .npy array ({label}, '{key}'; found {type(arr).__name__})")
    return arr


def _load_view(d: Path, mpath: Path, i: int, entry, n: int, mmap: bool) -> ViewOperator:
    label = f"view {i}"
    if not isinstance(entry, dict):
        raise FormatError(f"{mpath}: {label} entry must be a mapping")
    camera = None
    if entry.get("camera") is not None:
        try:
            camera = Camera.from_dict(entry["camera"])
        except (ValidationError, TypeError, ValueError, OverflowError) as exc:
            raise FormatError(f"{mpath}: {label}: bad camera ({exc})") from None
    shape = entry.get("image_shape")
    if (not isinstance(shape, list) or len(shape) != 2
            or not all(_is_int(s) and 0 < s <= _MAX_SIDE for s in shape)):
        raise FormatError(f"{mpath}: {label}: image_shape must be two integers in [1, {_MAX_SIDE}], "
                          f"got {shape!r}")
    shape = tuple(shape)
    if camera is not None and camera.image_shape != shape:
        raise FormatError(f"{mpath}: {label}: image_shape {shape} differs from its camera's {camera.image_shape}")
    files = entry.get("files")
    if not isinstance(files, dict):
        raise FormatError(f"{mpath}: {label}: 'files' must be a mapping")
    data, indices, indptr = (_load_array(d, mpath, label, files, k, mmap) for k in _CSR_FILES)
    rows = shape[0] * shape[1]
    nnz = entry.get("nnz")
    where = f"{d / files['data']} ({label})"
    if data.dtype != np.float32 or data.ndim != 1:
        raise FormatError(f"{where}: weights must be 1-D float32, got {data.dtype} {data.shape}")
    for arr, key in ((indices, "indices"), (indptr, "indptr")):
        if arr.dtype not in (np.int32, np.int64) or arr.ndim != 1:
            raise FormatError(f"{d / files[key]} ({label}): {key} must be 1-D int32/int64, "
                              f"got {arr.dtype} {arr.shape}")
    if indices.shape != data.shape or nnz != data.shape[0]:
        raise FormatError(f"{where}: nnz mismatch (manifest {nnz!r}, data {data.shape[0]}, "
                          f"indices {indices.shape[0]})")
    if indptr.shape[0] != rows + 1:
        raise FormatError(f"{d / files['indptr']} ({label}): indptr has {indptr.shape[0]} entries, "
                          f"expected {rows + 1} for image {shape}")
    if indptr[0] != 0 or indptr[-1] != data.shape[0] or np.any(np.diff(indptr) < 0):
        raise FormatError(f"{d / files['indptr']} ({label}): indptr must start at 0, never decrease "
                          f"and end at nnz={data.shape[0]}")
    if data.size:
        if int(indices.min()) < 0 or int(indices.max()) >= n:
            raise FormatError(f"{d / files['indices']} ({label}): column indices must lie in [0, {n})")
        if _has_duplicate_columns(indices, indptr, n):
            raise FormatError(f"{d / files['indices']} ({label}): a row lists the same column twice; "
                              "each Gaussian has one weight per pixel")
    if indices.dtype != indptr.dtype:
        raise FormatError(f"{d / files['indices']} ({label}): indices and indptr must share one dtype")
    W = sp.csr_matrix((data, indices, indptr), shape=(rows, n), copy=False)
    rendering = None
    extra = {k: _load_array(d, mpath, label, files, k, mmap) for k in RENDER_FIELDS if k in files}
    if extra:
        for k, arr in extra.items():
            problem = rendering_problem(k, arr, shape)
            if problem:
                raise FormatError(f"{d / files[k]} ({label}): {problem}")
        rendering = Rendering(**extra)
    try:  # the view checks its weights (finite, in [0, 1]) itself: the error names the file too
        return ViewOperator(W, camera, shape, rendering)
    except ValidationError as exc:  # its message starts with the view's label, which `where` already has
        raise FormatError(f"{where}: {str(exc).split(': ', 1)[-1]}") from None


def _has_duplicate_columns(indices, indptr, n: int) -> bool:
    """Whether some row of the CSR structure lists a column twice.

    Sorts the (row, column) keys once, O(nnz log nnz): rows are stored in
    compositing order, not column order, so scipy's canonical-format test
    does not apply.
    """
    counts = np.diff(np.asarray(indptr, dtype=np.int64))
    rows = np.repeat(np.arange(counts.size, dtype=np.int64), counts)
    keys = np.sort(rows * np.int64(n) + np.asarray(indices, dtype=np.int64))
    return bool(np.any(keys[1:] == keys[:-1]))
