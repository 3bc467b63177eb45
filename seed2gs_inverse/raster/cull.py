"""View-cone culling: which Gaussians can reach some pixels of a view (:func:`cone_cull`)."""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from ..scene import GaussianScene
from . import _kernels
from .frozen import FrozenScene, sigma3, unfreeze
from .project import EPS2D, camera_params

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


def cone_cull(scene, camera: Camera, roi=None, far: float | None = None, near: float | None = None,
              spare: np.ndarray | None = None) -> np.ndarray:
    """Indices of the Gaussians that can reach the pixels of ``roi`` in ``camera``.

    A conservative bound on the footprint the rasterizer gives each Gaussian,
    so that rasterizing the subset (``build_operator(..., subset=idx)``)
    gives the same roi pixels and the same ``W`` there. Kept are the
    Gaussians in front of the near plane (the projection drops the others)
    whose projected centre ``m`` lies within ``r`` pixels of the roi box,

    .. math::

        r = \\sqrt{2 \\ln 255}\\, \\sqrt{\\lambda_{max}(J J^T)\\, s_i^2 + \\epsilon_{2D}} + 2,

    with ``J`` the projection's (clamped) EWA Jacobian at the Gaussian's
    centre, ``s_i = max_k exp(log_scale_ik)`` and ``epsilon_2D`` its 2D
    dilation (0.3 px^2): the 2D covariance's largest eigenvalue is at most
    ``lambda_max(J J^T) s_i^2 + epsilon_2D``, and a pixel passes the alpha
    test ``o exp(-d^T Q d / 2) >= 1/255`` only within ``d^T Q d <= 2 ln 255``
    of it. (A bound in 3D, the centre within the view cone widened by
    ``3 s_i``, missed Gaussians close to the camera and off axis, whose
    affine footprint is much wider than their projected 3-sigma ball.)

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        A :class:`~.frozen.FrozenScene` reuses its 3-sigma sizes.
    camera : Camera
    roi : None or (x0, y0, x1, y1)
        Pixel box (half-open); default the whole image.
    far : float, optional
        Also drop Gaussians whose depth ``t_a`` along the axis of the cone
        through the roi's centre exceeds ``far`` plus their 3-sigma size,
        ``t_a - 3 s_i > far``; default no far cut.
    near : float, optional
        Also drop Gaussians whose centre lies in front of depth ``near``
        along the same axis, ``t_a < near``; default no near cut. Unlike
        ``far`` this is not conservative: the subset renders the scene
        without the Gaussians cut (a virtual view through what stands in
        front), not the same pixels.
    spare : (N,) bool, optional
        Gaussians the near cut leaves in place (the ground the object
        stands on, so that no cut edge of it shows next to the object).

    Returns
    -------
    (M,) int64
        Ascending scene indices.
    """
    if not isinstance(scene, (GaussianScene, FrozenScene)):
        raise ValidationError(f"scene must be a GaussianScene or FrozenScene, got {type(scene).__name__}")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
    for name, v in (("far", far), ("near", near)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                              or np.isnan(v)):
            raise ValidationError(f"{name} must be a number or None, got {v!r}")
    if spare is not None:
        spare = np.asarray(spare)
        if spare.dtype != bool or spare.shape != (len(scene),):
            raise ValidationError(f"spare must be None or a ({len(scene)},) bool mask of the scene's Gaussians, "
                                  f"got {spare.dtype} of shape {spare.shape}")
    x0, y0, x1, y1 = (float(v) for v in _roi_box(roi, camera))
    scene, frozen = unfreeze(scene)
    s3 = frozen.sigma3 if frozen is not None else sigma3(scene)
    axis = np.array([(0.5 * (x0 + x1) - camera.cx) / camera.fx, (0.5 * (y0 + y1) - camera.cy) / camera.fy, 1.0])
    axis /= np.linalg.norm(axis)
    # One parallel pass over the scene (this runs for every orbit view of extract), the near cut included.
    keep = np.empty(len(scene), bool)
    _kernels.announce_compilation((_kernels._cone_cull,))
    _kernels.cone_cull(scene.means, camera_params(camera), np.array([x0, y0, x1, y1]), np.ascontiguousarray(s3),
                       EPS2D, axis, np.inf if far is None else float(far), -np.inf if near is None else float(near),
                       np.zeros(0, bool) if spare is None or near is None else np.ascontiguousarray(spare), keep)
    return np.flatnonzero(keep).astype(np.int64, copy=False)
