"""View-cone culling: which Gaussians can reach some pixels of a view (:func:`cone_cull`)."""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from ..scene import GaussianScene
from . import _kernels
from .frozen import FrozenScene, sigma3, unfreeze
from .project import camera_params

__all__ = ["cone_cull"]


def _roi_box(roi, camera: Camera) -> tuple:
    if roi is None:
        return (0, 0, camera.width, camera.height)
    arr = np.asarray(roi)
    if arr.shape != (4,) or arr.dtype.kind not in "iuf" or not np.all(np.isfinite(arr)):
        raise ValidationError(f"roi must be None or a box (x0, y0, x1, y1), got {roi!r}")
    x0, y0, x1, y1 = (float(v) for v in arr)
    if x0 >= x1 or y0 >= y1:
        raise ValidationError(f"roi box {(x0, y0, x1, y1)} is empty; need x0 < x1 and y0 < y1")
    return tuple(roi)


def cone_cull(scene, camera: Camera, roi=None, far: float | None = None) -> np.ndarray:
    """Indices of the Gaussians that can reach the pixels of ``roi`` in ``camera``.

    Keeps the Gaussians in front of the near plane whose centre lies within
    the cone through the roi's corner pixels, widened by the Gaussian's own
    3-sigma size ``s_i = 3 max_k exp(log_scale_ik)`` (world units): every
    Gaussian whose footprint reaches a roi pixel passes, so rasterizing the
    subset (``build_operator(..., subset=idx)``) gives the same roi pixels.
    With the view-frame position ``v = R x + t``, the cone axis ``a``
    through the roi centre, the half-angle ``theta`` to the farthest corner,
    ``t_a = v . a`` and ``perp = sqrt(|v|^2 - t_a^2)``, Gaussian ``i`` is kept when

    .. math::

        v_z > \\mathrm{near} - s_i, \\quad
        \\mathrm{perp} \\le t_a \\tan\\theta + s_i / \\cos\\theta + 10^{-6}, \\quad
        t_a - s_i \\le \\mathrm{far}.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        A :class:`~.frozen.FrozenScene` reuses its 3-sigma sizes.
    camera : Camera
    roi : None or (x0, y0, x1, y1)
        Pixel box (half-open); default the whole image.
    far : float, optional
        Also drop Gaussians whose depth along the cone axis exceeds ``far``
        plus their 3-sigma size; default no far cut.

    Returns
    -------
    (M,) int64
        Ascending scene indices.
    """
    if not isinstance(scene, (GaussianScene, FrozenScene)):
        raise ValidationError(f"scene must be a GaussianScene or FrozenScene, got {type(scene).__name__}")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
    if far is not None and (isinstance(far, bool) or not isinstance(far, (int, float, np.integer, np.floating))
                            or np.isnan(far)):
        raise ValidationError(f"far must be a number or None, got {far!r}")
    x0, y0, x1, y1 = _roi_box(roi, camera)
    scene, frozen = unfreeze(scene)
    s3 = frozen.sigma3 if frozen is not None else sigma3(scene)
    xs = (np.array([x0, x1, x1, x0], float) - camera.cx) / camera.fx
    ys = (np.array([y0, y0, y1, y1], float) - camera.cy) / camera.fy
    # Axis: through the roi centre; half-angle: to the farthest corner.
    axis = np.array([(0.5 * (x0 + x1) - camera.cx) / camera.fx, (0.5 * (y0 + y1) - camera.cy) / camera.fy, 1.0])
    axis /= np.linalg.norm(axis)
    corners = np.stack([xs, ys, np.ones(4)], 1)
    corners /= np.linalg.norm(corners, axis=1, keepdims=True)
    cos_a = float(np.clip((corners @ axis).min(), 1e-3, 1.0))
    tan_a = np.sqrt(max(1.0 - cos_a ** 2, 0.0)) / cos_a
    # One parallel pass over the scene (this runs for every orbit view of extract).
    keep = np.empty(len(scene), bool)
    _kernels.announce_compilation()
    _kernels.cone_cull(scene.means, camera_params(camera), axis, tan_a, cos_a, np.ascontiguousarray(s3),
                       np.inf if far is None else float(far), keep)
    return np.flatnonzero(keep).astype(np.int64, copy=False)
