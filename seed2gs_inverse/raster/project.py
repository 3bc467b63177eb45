"""Projection of Gaussians into a view: :func:`project_gaussians` (semantics in :mod:`.rasterize`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from ..scene import GaussianScene
from . import _kernels
from .frozen import FrozenScene, activations, unfreeze

__all__ = ["Projection", "project_gaussians", "MODES"]

MODES = ("classic", "antialiased")
EPS2D = _kernels.EPS2D  # the 2D dilation (px^2); defined with the kernels so that the spatial index shares it


class Projection(NamedTuple):
    """Per-Gaussian screen-space quantities of one view (see :mod:`.rasterize`).

    Attributes
    ----------
    means2d : (N, 2) float32
        Pixel coordinates of the projected means (0 where culled).
    conics : (N, 3) float32
        ``(a, b, c)`` of the inverse 2D covariance (0 where culled).
    radii : (N,) int32
        3-sigma radius in pixels; 0 marks a culled Gaussian.
    depths : (N,) float32
        View depth ``z`` of every Gaussian (also the culled ones).
    colors : (N, 3) float32
        View-dependent colour ``max(eval_sh + 0.5, 0)`` of every Gaussian.
    opacities : (N,) float32
        Opacity used for compositing (sigmoid of the logit, times the
        antialiasing compensation in mode "antialiased").
    """

    means2d: np.ndarray
    conics: np.ndarray
    radii: np.ndarray
    depths: np.ndarray
    colors: np.ndarray
    opacities: np.ndarray


def check_inputs(scene, camera, mode) -> tuple:
    """Validate ``(scene or FrozenScene, camera, mode)``; returns ``(scene, frozen or None)``."""
    if not isinstance(scene, (GaussianScene, FrozenScene)):
        raise ValidationError(f"scene must be a GaussianScene or FrozenScene, got {type(scene).__name__}")
    if len(scene) == 0:
        raise ValidationError("scene is empty (0 Gaussians): there is nothing to render")
    if not isinstance(camera, Camera):
        raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
    if mode not in MODES:
        raise ValidationError(f"mode must be one of {MODES}, got {mode!r}")
    return unfreeze(scene)


def camera_params(camera: Camera) -> _kernels.CameraParams:
    """The camera as the kernels' :class:`~._kernels.CameraParams` (float64 arrays)."""
    return _kernels.CameraParams(
        np.ascontiguousarray(camera.rotation, dtype=np.float64),
        np.ascontiguousarray(camera.translation, dtype=np.float64),
        np.ascontiguousarray(camera.center, dtype=np.float64),
        float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
        int(camera.width), int(camera.height), float(camera.near))


def project(scene, frozen, camera, mode, idx=None, tile_box=None) -> _kernels.Splats:
    """Run the projection kernel on the rows ``idx`` (default all) of ``scene``.

    Returns float64 arrays plus tile rectangles, one row per entry of ``idx``;
    rectangles are clipped to ``tile_box`` (default the whole tile grid).
    """
    if idx is None:
        idx = np.arange(len(scene), dtype=np.int64)
    n = idx.size
    if tile_box is None:
        tile_box = np.array([0, 0, (camera.width + _kernels.TILE - 1) // _kernels.TILE,
                             (camera.height + _kernels.TILE - 1) // _kernels.TILE], np.int64)
    _kernels.announce_compilation(_kernels.RENDER_KERNELS)
    act, act_rows = activations(scene, frozen, idx)
    out = _kernels.Splats(means2d=np.empty((n, 2)), conics=np.empty((n, 3)), radii=np.empty(n, np.int32),
                          depths=np.empty(n), colors=np.empty((n, 3)), opacities=np.empty(n),
                          support=np.empty((n, 3)), rects=np.empty((n, 4), np.int32))
    _kernels.project(idx, act_rows, scene.means, scene.sh, act, camera_params(camera), EPS2D,
                     mode == "antialiased", tile_box, out)
    return out


def project_gaussians(scene, camera, mode: str = "classic") -> Projection:
    """Project every Gaussian of ``scene`` into ``camera``.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
    camera : Camera
    mode : {"classic", "antialiased"}

    Returns
    -------
    Projection
        ``means2d, conics, radii, depths, colors, opacities`` as float32
        (radii int32); culled Gaussians have ``radii == 0``.
    """
    scene, frozen = check_inputs(scene, camera, mode)
    s = project(scene, frozen, camera, mode)
    f32 = np.float32
    return Projection(s.means2d.astype(f32), s.conics.astype(f32), s.radii, s.depths.astype(f32),
                      s.colors.astype(f32), s.opacities.astype(f32))
