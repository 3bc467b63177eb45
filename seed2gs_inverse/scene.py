"""GaussianScene: the arrays of a 3DGS scene, their activations and edits.

Storage follows the 3DGS trainer (and its PLY files): parameters are kept in
their *raw* form and activated on use.

===============  ==========  =================================================
array            shape       meaning
===============  ==========  =================================================
means            (N, 3)      centres, world frame, float32
quats            (N, 4)      rotations, w-first (w, x, y, z), not necessarily
                             unit length; normalised on use
log_scales       (N, 3)      log of the per-axis standard deviations
opacity_logits   (N,)        opacity before the sigmoid
sh               (N, K, 3)   SH coefficients, K = (deg+1)^2, DC first
extra            {name: (N,)} any other per-Gaussian property of the file
===============  ==========  =================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping, Sequence

import numpy as np

from .errors import ValidationError
from .sh import rotate_sh, sh_degree_from_coeffs

__all__ = ["GaussianScene", "quat_to_rotmat", "rotation_columns", "rotmat_to_quat", "quat_multiply"]


def _as_float32(name: str, value, shape_tail: tuple, n: int | None) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiu":
        raise ValidationError(f"scene array '{name}' has dtype {arr.dtype}; expected a real number type")
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    if arr.ndim != 1 + len(shape_tail) or tuple(arr.shape[1:]) != shape_tail:
        want = "(N" + "".join(f", {s}" for s in shape_tail) + ")"
        raise ValidationError(f"scene array '{name}' has shape {arr.shape}; expected {want}")
    if n is not None and arr.shape[0] != n:
        raise ValidationError(f"scene array '{name}' has {arr.shape[0]} rows; 'means' has {n}")
    bad = ~np.isfinite(arr)
    if bad.any():
        rows = np.unique(np.nonzero(bad.reshape(arr.shape[0], -1))[0])
        raise ValidationError(
            f"scene array '{name}' has non-finite values in {rows.size} of {arr.shape[0]} "
            f"Gaussians (first at index {rows[0]})")
    return arr


def _read_only(arr: np.ndarray) -> np.ndarray:
    """A read-only view of ``arr`` (no copy; the caller's array stays writeable)."""
    view = arr.view()
    view.flags.writeable = False
    return view


# The entries of the rotation matrix of a unit w-first quaternion, row after row: one place for both
# the whole matrices and the columns alone (the same products, so the same values).
_ROTATION_ENTRIES = (
    lambda w, x, y, z: 1 - 2 * (y * y + z * z), lambda w, x, y, z: 2 * (x * y - w * z),
    lambda w, x, y, z: 2 * (x * z + w * y),
    lambda w, x, y, z: 2 * (x * y + w * z), lambda w, x, y, z: 1 - 2 * (x * x + z * z),
    lambda w, x, y, z: 2 * (y * z - w * x),
    lambda w, x, y, z: 2 * (x * z - w * y), lambda w, x, y, z: 2 * (y * z + w * x),
    lambda w, x, y, z: 1 - 2 * (x * x + y * y),
)


def _unit_quats(quats) -> np.ndarray:
    """float64 quaternions normalised along the last axis."""
    q = np.asarray(quats, dtype=np.float64)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_to_rotmat(quats: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) float64 from w-first quaternions (normalised here)."""
    q = _unit_quats(quats)
    wxyz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([entry(*wxyz) for entry in _ROTATION_ENTRIES], axis=-1).reshape(q.shape[:-1] + (3, 3))


def rotation_columns(quats: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Column ``columns[i]`` of the rotation matrix of each quaternion ``quats[i]``, (M, 3) float64.

    Parameters
    ----------
    quats : (M, 4) array
        w-first quaternions (normalised here).
    columns : (M,) int array
        Each one 0, 1 or 2.

    Returns
    -------
    (M, 3) float64
        ``quat_to_rotmat(quats)[i, :, columns[i]]``, the same values, each
        computed for its column alone (no (M, 3, 3) matrices).

    Raises
    ------
    ValidationError
        ``quats`` is not (M, 4), or ``columns`` not M integers in 0..2.
    """
    q = _unit_quats(quats)
    cols = np.asarray(columns)
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValidationError(f"rotation_columns: quats must be an (M, 4) array, got shape {q.shape}")
    if cols.shape != (len(q),) or (cols.size and (cols.dtype.kind not in "iu" or cols.min() < 0 or cols.max() > 2)):
        raise ValidationError(f"rotation_columns: columns must be {len(q)} integers in 0..2 (one per "
                              f"quaternion), got {cols.dtype} of shape {cols.shape}")
    out = np.empty((len(q), 3))
    for k in range(3):
        at = np.flatnonzero(cols == k)
        wxyz = tuple(q[at, j] for j in range(4))
        for r in range(3):
            out[at, r] = _ROTATION_ENTRIES[3 * r + k](*wxyz)
    return out


def rotmat_to_quat(rot: np.ndarray) -> np.ndarray:
    """w-first unit quaternion (4,) of a single 3x3 rotation matrix."""
    m = np.asarray(rot, dtype=np.float64)
    # Shepperd's method: pick the largest diagonal combination for stability.
    tr = np.trace(m)
    cands = np.array([tr, m[0, 0], m[1, 1], m[2, 2]])
    k = int(np.argmax(cands))
    if k == 0:
        s = 2 * np.sqrt(1 + tr)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2 * np.sqrt(1 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2 * np.sqrt(1 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2 * np.sqrt(1 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of w-first quaternions (broadcasting)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def _check_rotation(rotation) -> np.ndarray:
    rot = np.asarray(rotation, dtype=np.float64)
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
        raise ValidationError(f"rotation must be a finite 3x3 matrix, got shape {rot.shape}")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5) or np.linalg.det(rot) < 0:
        raise ValidationError("rotation must be orthonormal with determinant +1 (a proper rotation)")
    return rot


def _check_layout(layout) -> tuple | None:
    """``layout`` as a tuple of ``(name, type code)`` string pairs, or ``None``."""
    if layout is None:
        return None
    try:
        pairs = tuple((name, code) for name, code in layout)
    except (TypeError, ValueError):
        pairs = None
    if pairs is None or not all(isinstance(name, str) and isinstance(code, str) for name, code in pairs):
        raise ValidationError(f"scene 'layout' must be a sequence of (name, type code) string pairs "
                              f"or None, got {layout!r:.80}")
    return pairs


@dataclass(eq=False, frozen=True)
class GaussianScene:
    """A frozen 3DGS scene. See the module docstring for the arrays.

    All arrays are validated (shape, real dtype, finite values) and stored as
    contiguous float32. ``extra`` keeps file properties this class does not
    interpret (e.g. ``nx, ny, nz`` or a trainer's custom fields) so they are
    written back unchanged.

    ``layout`` records the property list of the file the scene was read from,
    as ``((name, numpy type code), ...)`` in file order (e.g.
    ``(("x", "f4"), ...)``), or is ``None``. It holds names and types only,
    no values: a writer of the same format uses it to write the scene back
    with the same properties, order and types while it still fits the
    arrays. ``subset``, ``copy``, ``transformed`` and ``dataclasses.replace``
    carry it; ``concat`` keeps it only when every part has the same one.

    A scene is immutable once validated, so no NaN or shape error can slip
    in after the checks: the arrays are read-only views, ``extra`` is a
    read-only mapping and the attributes cannot be reassigned. To change
    values, build a new (re-validated) scene, e.g.
    ``dataclasses.replace(scene, means=new_means)`` or
    ``GaussianScene(means, ...)`` from writeable copies
    (``scene.means.copy()``). Arrays passed in that are already contiguous
    float32 are not copied: the scene holds read-only views of them, so
    writing through the caller's own reference afterwards would bypass the
    checks (pass copies if you keep modifying them).
    """

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    extra: dict = field(default_factory=dict)
    layout: tuple | None = None

    def __post_init__(self):
        means = _as_float32("means", self.means, (3,), None)
        n = means.shape[0]
        quats = _as_float32("quats", self.quats, (4,), n)
        zero = ~(quats != 0).any(axis=1)
        if zero.any():
            raise ValidationError(
                f"scene array 'quats' has {int(zero.sum())} zero-length quaternions "
                f"(first at index {int(np.argmax(zero))})")
        log_scales = _as_float32("log_scales", self.log_scales, (3,), n)
        opacity_logits = _as_float32("opacity_logits", self.opacity_logits, (), n)
        sh = np.asarray(self.sh)
        if sh.ndim != 3 or sh.shape[2] != 3:
            raise ValidationError(f"scene array 'sh' has shape {sh.shape}; expected (N, K, 3)")
        try:
            sh_degree_from_coeffs(sh.shape[1])
        except ValidationError as exc:
            raise ValidationError(f"scene array 'sh': {exc}") from None
        sh = _as_float32("sh", sh, tuple(sh.shape[1:]), n)
        extra_in = self.extra if self.extra is not None else {}
        if not isinstance(extra_in, Mapping):
            raise ValidationError(f"scene 'extra' must be a mapping of name -> (N,) array, "
                                  f"got {type(extra_in).__name__}")
        extra = {}
        for key, value in extra_in.items():
            arr = np.asarray(value)
            if arr.ndim != 1 or arr.shape[0] != n:
                raise ValidationError(f"extra property '{key}' has shape {arr.shape}; expected ({n},)")
            if arr.dtype.kind not in "fiub":
                raise ValidationError(f"extra property '{key}' has dtype {arr.dtype}; expected numbers")
            extra[str(key)] = _read_only(np.ascontiguousarray(arr))
        # frozen dataclass: the validated values are set once, here, and never again
        for name, arr in (("means", means), ("quats", quats), ("log_scales", log_scales),
                          ("opacity_logits", opacity_logits), ("sh", sh)):
            object.__setattr__(self, name, _read_only(arr))
        object.__setattr__(self, "extra", MappingProxyType(extra))
        object.__setattr__(self, "layout", _check_layout(self.layout))

    def __reduce__(self):
        # pickling (multiprocessing, joblib): rebuild through __init__, whose checks make the arrays
        # read-only and ``extra`` a read-only mapping again (a mappingproxy itself cannot be pickled)
        return (type(self), (self.means, self.quats, self.log_scales, self.opacity_logits, self.sh,
                             dict(self.extra), self.layout))

    # -- basic facts -------------------------------------------------------
    def __len__(self) -> int:
        return int(self.means.shape[0])

    def __repr__(self) -> str:
        return (f"GaussianScene(n={len(self)}, sh_degree={self.sh_degree}, "
                f"extra={sorted(self.extra)})")

    @property
    def sh_degree(self) -> int:
        """SH degree 0..3, from the number of coefficients."""
        return sh_degree_from_coeffs(self.sh.shape[1])

    # -- activations -------------------------------------------------------
    @property
    def opacities(self) -> np.ndarray:
        """Activated opacity ``sigmoid(opacity_logits)``, (N,) float32."""
        return self.opacities_at(slice(None))

    def opacities_at(self, rows) -> np.ndarray:
        """:attr:`opacities` at ``rows`` (any numpy index), computed at those rows alone: the same values."""
        # expit: no overflow warning for the -1e4 logits of pruned splats. Imported here because
        # scipy.special takes longer to import than the whole package, and every
        # ``import seed2gs_inverse`` (each CLI start) loads this module.
        from scipy.special import expit

        return expit(self.opacity_logits[rows].astype(np.float64)).astype(np.float32)

    @property
    def scales(self) -> np.ndarray:
        """Per-axis standard deviations ``exp(log_scales)``, (N, 3) float32."""
        return self.scales_at(slice(None))

    def scales_at(self, rows) -> np.ndarray:
        """:attr:`scales` at ``rows`` (any numpy index), computed at those rows alone: the same values."""
        return np.exp(self.log_scales[rows].astype(np.float64)).astype(np.float32)

    @property
    def rotations(self) -> np.ndarray:
        """Unit w-first quaternions, (N, 4) float32."""
        q = self.quats.astype(np.float64)
        return (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)

    def covariances(self) -> np.ndarray:
        """World covariances ``R S S^T R^T``, (N, 3, 3) float64."""
        rot = quat_to_rotmat(self.quats)
        m = rot * np.exp(self.log_scales.astype(np.float64))[:, None, :]
        return m @ np.swapaxes(m, 1, 2)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box of the means, ``(lo, hi)``."""
        if len(self) == 0:
            raise ValidationError("an empty scene has no bounds")
        return self.means.min(axis=0), self.means.max(axis=0)

    # -- edits -------------------------------------------------------------
    def __copy__(self) -> "GaussianScene":
        return self  # immutable: a shallow copy may share everything

    def __deepcopy__(self, memo) -> "GaussianScene":
        return self.copy()  # the read-only extra mapping cannot be deep-copied generically

    def copy(self) -> "GaussianScene":
        """A scene holding its own copies of the arrays (still read-only)."""
        return GaussianScene(self.means.copy(), self.quats.copy(), self.log_scales.copy(),
                             self.opacity_logits.copy(), self.sh.copy(),
                             {k: v.copy() for k, v in self.extra.items()}, self.layout)

    def subset(self, selection) -> "GaussianScene":
        """The Gaussians picked by an index array or a boolean mask of length N."""
        sel = np.asarray(selection)
        if sel.shape == (0,) and sel.dtype.kind == "f":  # an empty list: numpy makes it float64
            sel = sel.astype(np.int64)
        if sel.dtype == bool:
            if sel.shape != (len(self),):
                raise ValidationError(f"boolean selection has shape {sel.shape}; expected ({len(self)},)")
        elif sel.dtype.kind in "iu":
            if sel.ndim != 1:
                raise ValidationError(f"index selection must be 1-D, got shape {sel.shape}")
            if sel.size and (sel.min() < -len(self) or sel.max() >= len(self)):
                raise ValidationError(f"index selection out of range for a scene of {len(self)} Gaussians")
        else:
            raise ValidationError(f"selection must be a bool mask or integer indices, got dtype {sel.dtype}")
        return GaussianScene(self.means[sel], self.quats[sel], self.log_scales[sel],
                             self.opacity_logits[sel], self.sh[sel],
                             {k: v[sel] for k, v in self.extra.items()}, self.layout)

    @staticmethod
    def concat(scenes: Sequence["GaussianScene"]) -> "GaussianScene":
        """Concatenate scenes in order.

        SH degrees are unified to the highest one (missing bands are zero, so
        colours are unchanged). Extra properties present in every scene are
        kept; the others are dropped, since they cannot be filled honestly.
        """
        scenes = list(scenes)
        if not scenes:
            raise ValidationError("concat needs at least one scene")
        k = max(s.sh.shape[1] for s in scenes)
        shs = []
        for s in scenes:
            pad = np.zeros((len(s), k, 3), np.float32)
            pad[:, : s.sh.shape[1]] = s.sh
            shs.append(pad)
        common = set(scenes[0].extra)
        for s in scenes[1:]:
            common &= set(s.extra)
        keys = [key for key in scenes[0].extra if key in common]
        layouts = {s.layout for s in scenes}
        return GaussianScene(
            np.concatenate([s.means for s in scenes]),
            np.concatenate([s.quats for s in scenes]),
            np.concatenate([s.log_scales for s in scenes]),
            np.concatenate([s.opacity_logits for s in scenes]),
            np.concatenate(shs),
            {key: np.concatenate([s.extra[key] for s in scenes]) for key in keys},
            layouts.pop() if len(layouts) == 1 else None,
        )

    def transformed(self, rotation=None, translation=None, scale: float = 1.0) -> "GaussianScene":
        """The scene moved by ``x -> scale * R x + t``.

        Means are mapped, rotations are pre-multiplied by R (so covariances
        become ``s^2 R Sigma R^T``), log-scales shift by ``log s`` and SH
        coefficients are rotated band by band so that view-dependent colour
        follows the object: the moved scene seen along ``R d`` looks like the
        original seen along ``d``.
        """
        rot = np.eye(3) if rotation is None else _check_rotation(rotation)
        t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValidationError(f"translation must be a finite 3-vector, got {t!r}")
        if not (np.isfinite(scale) and scale > 0):
            raise ValidationError(f"scale must be a positive finite number, got {scale!r}")
        means = (scale * (self.means.astype(np.float64) @ rot.T) + t).astype(np.float32)
        turned = not np.array_equal(rot, np.eye(3))
        # without a rotation the stored quaternions (normalised or not) are kept bit for bit
        quats = (quat_multiply(rotmat_to_quat(rot), self.rotations.astype(np.float64)).astype(np.float32)
                 if turned else self.quats.copy())
        log_scales = (self.log_scales.copy() if scale == 1
                      else (self.log_scales.astype(np.float64) + np.log(scale)).astype(np.float32))
        sh = rotate_sh(self.sh, rot).astype(np.float32) if turned and self.sh.shape[1] > 1 else self.sh.copy()
        return GaussianScene(means, quats, log_scales, self.opacity_logits.copy(), sh,
                             {k: v.copy() for k, v in self.extra.items()}, self.layout)
