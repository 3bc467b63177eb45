"""Real spherical harmonics in the convention of the reference 3DGS code.

The basis ordering, signs and constants are those of ``eval_sh`` in the
original 3DGS trainer (``utils/sh_utils.py``) and of gsplat: coefficient 0 is
the DC term, then degree 1 (``-y, z, -x``), degree 2 and degree 3. A colour is
``sum_k basis_k(d) * sh[k] + 0.5``, clamped at 0 by the renderer, where ``d``
is the unit direction from the camera centre to the Gaussian mean.
"""

from __future__ import annotations

import numpy as np

from .errors import ValidationError

__all__ = ["SH_C0", "SH_C1", "SH_C2", "SH_C3", "num_sh_coeffs", "sh_degree_from_coeffs", "sh_basis",
           "eval_sh", "sh_to_rgb", "rgb_to_sh", "sh_rotation_matrices", "rotate_sh"]

SH_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
       -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
       0.3731763325901154, -0.4570457994644658, 1.445305721320277,
       -0.5900435899266435)
# Public names of the degree 1-3 constants (the rasterizer's kernels use them).
SH_C1, SH_C2, SH_C3 = _C1, _C2, _C3


def num_sh_coeffs(degree: int) -> int:
    """Number of coefficients per channel, ``(degree + 1) ** 2``."""
    return (int(degree) + 1) ** 2


def sh_degree_from_coeffs(k: int) -> int:
    """Inverse of :func:`num_sh_coeffs`; raises for counts that are not 1, 4, 9 or 16."""
    for deg in range(4):
        if num_sh_coeffs(deg) == k:
            return deg
    raise ValidationError(f"{k} SH coefficients per channel is not (deg+1)^2 for a degree 0..3")


def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """Evaluate the real SH basis at unit directions.

    Parameters
    ----------
    dirs : (M, 3) array
        Unit vectors (not re-normalised here).
    degree : int
        0..3.

    Returns
    -------
    (M, (degree+1)**2) float64 array.
    """
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    out = [np.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [_C2[0] * xy, _C2[1] * yz, _C2[2] * (2 * zz - xx - yy),
                _C2[3] * xz, _C2[4] * (xx - yy)]
    if degree >= 3:
        out += [_C3[0] * y * (3 * xx - yy), _C3[1] * xy * z,
                _C3[2] * y * (4 * zz - xx - yy), _C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
                _C3[4] * x * (4 * zz - xx - yy), _C3[5] * z * (xx - yy),
                _C3[6] * x * (xx - 3 * yy)]
    return np.stack(out, axis=1)


def eval_sh(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Colour of each Gaussian for its view direction, before the +0.5 offset.

    ``sh`` is (N, K, 3), ``dirs`` (N, 3) unit vectors; returns (N, 3) float64.
    """
    sh = np.asarray(sh)
    basis = sh_basis(dirs, sh_degree_from_coeffs(sh.shape[1]))
    return np.einsum("nk,nkc->nc", basis, sh)


def sh_to_rgb(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Renderer colour: ``max(eval_sh + 0.5, 0)``, (N, 3) float64."""
    return np.maximum(eval_sh(sh, dirs) + 0.5, 0.0)


def rgb_to_sh(rgb: np.ndarray) -> np.ndarray:
    """DC coefficient that reproduces a view-independent colour."""
    return (np.asarray(rgb, dtype=np.float64) - 0.5) / SH_C0


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def sh_rotation_matrices(rotation: np.ndarray, degree: int) -> list[np.ndarray]:
    """Per-band matrices ``D_l`` that rotate SH coefficients with the scene.

    A scene rotated by ``R`` must show at direction ``d`` the colour the
    original showed at ``R^T d``: ``c'(d) = c(R^T d)``. Each band is closed
    under rotation, so ``D_l`` is the exact solution of
    ``Y_l(d_k) D_l = Y_l(R^T d_k)`` over well-spread directions ``d_k``
    (least squares over 64 points, exact up to rounding).

    Returns a list of ``(2l+1, 2l+1)`` float64 matrices for l = 0..degree.
    """
    rot = np.asarray(rotation, dtype=np.float64)
    dirs = _fibonacci_sphere(64)
    y_dst = sh_basis(dirs, degree)
    y_src = sh_basis(dirs @ rot, degree)  # rows are (R^T d)^T
    mats = []
    for deg in range(degree + 1):
        sl = slice(deg * deg, (deg + 1) ** 2)
        mats.append(np.linalg.lstsq(y_dst[:, sl], y_src[:, sl], rcond=None)[0])
    return mats


def rotate_sh(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Rotate SH coefficients ``(N, K, 3)`` by the 3x3 rotation ``rotation``."""
    sh = np.asarray(sh)
    degree = sh_degree_from_coeffs(sh.shape[1])
    out = np.empty_like(sh)
    for deg, mat in enumerate(sh_rotation_matrices(rotation, degree)):
        sl = slice(deg * deg, (deg + 1) ** 2)
        out[:, sl, :] = np.einsum("ij,njc->nic", mat, sh[:, sl, :].astype(np.float64))
    return out
