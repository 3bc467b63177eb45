"""A scene's view-independent quantities, computed once and held by the caller (:class:`FrozenScene`)."""

from __future__ import annotations

import threading

import numpy as np

from ..errors import ValidationError
from ..scene import GaussianScene
from . import _kernels
from .spatial import SpatialIndex

__all__ = ["FrozenScene", "unfreeze", "activations", "sigma3"]


def _activate(scene, idx) -> _kernels.Activations:
    """Kernel ``activate`` on the rows ``idx``."""
    _kernels.announce_compilation(_kernels.RENDER_KERNELS)
    n = idx.size
    act = _kernels.Activations(np.empty((n, 9)), np.empty(n),
                               np.empty((n if scene.sh.shape[1] == 1 else 0, 3)))
    _kernels.activate(idx, scene.quats, scene.log_scales, scene.opacity_logits, scene.sh, act)
    return act


def sigma3(scene) -> np.ndarray:
    """(N,) float64 ``3 max_k exp(log_scale_k)``: each Gaussian's 3-sigma size in world units."""
    return 3.0 * scene.scales.max(axis=1).astype(np.float64)


class FrozenScene:
    """A :class:`~seed2gs_inverse.scene.GaussianScene` with its view-independent activations cached.

    Rendering many views of one unchanged scene recomputes, per call, the
    covariance factors ``M = R(q/|q|) diag(exp(s))`` (``Sigma = M M^T``), the
    opacities ``sigmoid(logit)``, for SH degree 0 the colours
    ``max(C0 sh_0 + 0.5, 0)``, and for culling the 3-sigma sizes
    ``3 max_k exp(s_k)``. A ``FrozenScene`` computes them once, for the
    whole scene, when it is made; :func:`~seed2gs_inverse.raster.render`,
    :func:`~seed2gs_inverse.raster.build_operator`,
    :func:`~seed2gs_inverse.raster.project_gaussians` and
    :func:`~seed2gs_inverse.raster.cone_cull` accept it wherever they take a
    scene and give bit-identical results. The caller holds it (no global
    cache) and promises not to change the scene's arrays while using it.

    Culling (:func:`~seed2gs_inverse.raster.cone_cull`), and through it
    :func:`~seed2gs_inverse.raster.render` and
    :func:`~seed2gs_inverse.raster.build_operator` without ``subset``,
    visit only the Gaussians of the chunks of :attr:`spatial` that can
    reach the view, so that Gaussians far from every view cost nothing per
    view.

    Parameters
    ----------
    scene : GaussianScene
        Non-empty.

    Examples
    --------
    >>> frozen = FrozenScene(scene)                               # doctest: +SKIP
    >>> ops = [build_operator(frozen, cam) for cam in cameras]    # doctest: +SKIP
    """

    def __init__(self, scene):
        if isinstance(scene, FrozenScene):
            scene = scene.scene
        if not isinstance(scene, GaussianScene):
            raise ValidationError(f"FrozenScene needs a GaussianScene, got {type(scene).__name__}")
        if len(scene) == 0:
            raise ValidationError("scene is empty (0 Gaussians): there is nothing to render")
        self.scene = scene
        self.activations = _activate(scene, np.arange(len(scene), dtype=np.int64))
        self.sigma3 = sigma3(scene)
        self._spatial: SpatialIndex | None = None
        self._spatial_lock = threading.Lock()

    @property
    def spatial(self) -> SpatialIndex:
        """The scene's :class:`~.spatial.SpatialIndex` of centres and 1-sigma sizes, built on first use.

        Kept for every later query; a frozen scene that never culls never
        builds it.
        """
        with self._spatial_lock:
            if self._spatial is None:
                self._spatial = SpatialIndex(self.scene.means, self.sigma3 / 3.0)
            return self._spatial

    def __len__(self) -> int:
        return len(self.scene)

    def __repr__(self) -> str:
        return f"FrozenScene({len(self)} Gaussians, SH degree {self.scene.sh_degree})"


def unfreeze(scene):
    """``(GaussianScene, FrozenScene or None)`` of a scene or a frozen scene (unchecked otherwise)."""
    if isinstance(scene, FrozenScene):
        return scene.scene, scene
    return scene, None


def activations(scene, frozen, idx) -> tuple:
    """``(Activations, rows)``: activations for the rows ``idx`` and the row of each in them.

    From ``frozen`` (whole scene, rows = ``idx``) when given, else computed
    for ``idx`` only (rows = ``0..len(idx)-1``); identical values either way.
    """
    if frozen is None:
        return _activate(scene, idx), np.arange(idx.size, dtype=np.int64)
    return frozen.activations, idx
