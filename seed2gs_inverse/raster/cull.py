"""View-cone culling: which Gaussians can reach some pixels of a view (:func:`cone_cull`)."""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from ..scene import GaussianScene
from . import _kernels
from .frozen import FrozenScene, sigma3, unfreeze
from .project import EPS2D, camera_params
from .spatial import check_depth_cut, roi_box

__all__ = ["cone_cull"]


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

    Notes
    -----
    On a :class:`~.frozen.FrozenScene` the bound is evaluated only on the
    candidates of its spatial index
    (:meth:`~.spatial.SpatialIndex.view_candidates`, a superset of the
    Gaussians kept), so the cost follows the Gaussians near the view; the
    result is the same as the pass over every Gaussian that a
    :class:`~seed2gs_inverse.scene.GaussianScene` gets.
    """
    if not isinstance(scene, (GaussianScene, FrozenScene)):
        raise ValidationError(f"scene must be a GaussianScene or FrozenScene, got {type(scene).__name__}")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
    far, near = check_depth_cut("far", far), check_depth_cut("near", near)
    if spare is not None:
        spare = np.asarray(spare)
        if spare.dtype != bool or spare.shape != (len(scene),):
            raise ValidationError(f"spare must be None or a ({len(scene)},) bool mask of the scene's Gaussians, "
                                  f"got {spare.dtype} of shape {spare.shape}")
    x0, y0, x1, y1 = roi_box(roi, camera)
    scene, frozen = unfreeze(scene)
    s3 = frozen.sigma3 if frozen is not None else sigma3(scene)
    axis = np.array([(0.5 * (x0 + x1) - camera.cx) / camera.fx, (0.5 * (y0 + y1) - camera.cy) / camera.fy, 1.0])
    axis /= np.linalg.norm(axis)
    use_spare = spare is not None and near is not None
    if frozen is None:
        # One parallel pass over the scene, the near cut included.
        cand = None
        keep = np.empty(len(scene), bool)
    else:
        # The kernel on the index's candidates only (chunk order; sorted once kept), reading their
        # rows in place.
        cand = frozen.spatial.view_rows(camera, roi, far).astype(np.int64, copy=False)
        keep = np.empty(cand.size, bool)
        if cand.size == 0:  # (an empty rows array tells the kernel "every row")
            return cand
    _kernels.announce_compilation((_kernels._cone_cull,))
    _kernels.cone_cull(scene.means, np.zeros(0, np.int64) if cand is None else cand, camera_params(camera),
                       np.array([x0, y0, x1, y1]), np.ascontiguousarray(s3), EPS2D, axis,
                       np.inf if far is None else far, -np.inf if near is None else near,
                       np.ascontiguousarray(spare) if use_spare else np.zeros(0, bool), keep)
    idx = np.flatnonzero(keep).astype(np.int64, copy=False)
    return idx if cand is None else frozen.spatial.ascending(cand[idx])
