r"""Small rotation helpers shared by the pipeline (VAAS orbits) and the synthetic scenes.

Bottom layer: numpy, :mod:`seed2gs_inverse.errors` and :mod:`seed2gs_inverse._validation` only, so any module
may import it. All rotations are proper (``R^T R = I``, ``det R = +1``)
3x3 float64 matrices acting on column vectors, right-handed.

Rodrigues' formula
    The rotation by angle :math:`\theta` about the unit axis :math:`k` is

    .. math::

        R(k, \theta) = I + \sin\theta\, [k]_\times + (1 - \cos\theta)\, [k]_\times^2,

    where :math:`[k]_\times` is the cross-product matrix,
    :math:`[k]_\times v = k \times v`.

Rotation between two unit vectors
    The smallest rotation taking :math:`a` to :math:`b` turns about
    :math:`v = a \times b` by the angle between them; with
    :math:`c = a \cdot b` Rodrigues' formula becomes

    .. math::

        R = I + [v]_\times + \frac{[v]_\times^2}{1 + c},

    undefined at :math:`c = -1`, where any half turn about an axis
    perpendicular to :math:`a` will do: :math:`R = 2 n n^T - I`.
"""

from __future__ import annotations

import numpy as np

from ._validation import check_vector
from .errors import ValidationError

__all__ = ["unit_vector", "cross_matrix", "axis_angle", "rotation_between", "frame_for_up"]


def unit_vector(name: str, v) -> np.ndarray:
    """``v / |v|`` as float64, after checking it is a finite non-zero 3-vector.

    Parameters
    ----------
    name : str
        Argument name used in the error message.
    v : array_like, shape (3,)

    Raises
    ------
    ValidationError
        When ``v`` is not a finite 3-vector of non-zero length.
    """
    arr = check_vector(name, v, 3, nonzero=True)
    top = np.max(np.abs(arr))
    if top > 1e150:  # entries whose squares overflow: scale first
        arr = arr / top
    norm = np.linalg.norm(arr)
    if norm < 1e-12:
        raise ValidationError(f"'{name}' must be a finite non-zero 3-vector, got {v!r}")
    return arr / norm


def cross_matrix(v) -> np.ndarray:
    r"""The cross-product matrix :math:`[v]_\times` (3, 3), with :math:`[v]_\times w = v \times w`."""
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def axis_angle(axis, angle: float) -> np.ndarray:
    r"""Rotation by ``angle`` radians about the unit ``axis`` (right hand), Rodrigues' formula.

    :math:`R = I + \sin\theta [k]_\times + (1 - \cos\theta) [k]_\times^2`.
    ``axis`` must already be unit length (callers normalise once, outside
    their loops); it is not renormalised so that results stay bit-stable.
    """
    k = cross_matrix(axis)
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def rotation_between(a, b) -> np.ndarray:
    r"""Smallest rotation taking unit vector ``a`` to unit vector ``b``.

    :math:`R = I + [a \times b]_\times + [a \times b]_\times^2 / (1 + a \cdot b)`, with
    :math:`1 + a \cdot b = |a + b|^2 / 2` evaluated that way for obtuse pairs
    (``1 + c`` itself loses every digit as ``b`` nears ``-a``); for opposite
    vectors (:math:`|a + b|^2 / 2 < 10^{-20}`) a half turn
    :math:`2 n n^T - I` about the axis ``n`` perpendicular to ``a`` built
    from the world axis least aligned with ``a``. Near-opposite pairs are
    still ill-conditioned: the axis :math:`a \times b` carries an absolute
    rounding error of about :math:`10^{-16}`, so ``R`` (its ``R a - b`` and
    its orthonormality) is accurate to about :math:`10^{-16} / |a + b|`.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    # 1 + c loses its digits as b nears -a (b = -a + 1e-8 gave 1 + c = 0 and a
    # half turn 1e-8 off b); |a + b|^2 / 2, equal for unit vectors, keeps them.
    # Acute pairs keep 1 + c, so their bits are unchanged.
    den = 1.0 + c if c > -0.5 else 0.5 * float(np.dot(a + b, a + b))
    if den < 1e-20:
        # Opposite vectors (to 1e-10 rad): turn half a circle about any axis perpendicular to a.
        axis = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = cross_matrix(v)
    return np.eye(3) + vx + vx @ vx / den


def frame_for_up(up) -> np.ndarray:
    """World-from-local rotation whose third column is the unit vector ``up``.

    The local x axis is the world axis least aligned with ``up``, made
    orthogonal to it (Gram-Schmidt), and local y = up x x, so the frame is
    right-handed and ``up = -y`` gives local x = world x. ``up`` must be a
    unit vector (ValidationError otherwise: the frame would not be a rotation).
    """
    up = np.asarray(up, dtype=np.float64)
    if up.shape != (3,) or not np.all(np.isfinite(up)) or abs(np.linalg.norm(up) - 1) > 1e-6:
        raise ValidationError(f"frame_for_up: up must be a finite unit 3-vector, got {up.tolist()}")
    a = np.eye(3)[int(np.argmin(np.abs(up)))]
    x = a - np.dot(a, up) * up
    x /= np.linalg.norm(x)
    y = np.cross(up, x)
    return np.stack([x, y, up], axis=1)
