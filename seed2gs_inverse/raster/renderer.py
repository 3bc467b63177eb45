"""One frozen scene's renderings and operators, for a caller that needs many views of it (:class:`Renderer`)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from ._kernels import compile_seconds
from .cull import cone_cull
from .frozen import FrozenScene
from .rasterize import build_operator, render

if TYPE_CHECKING:
    from ..camera import Camera
    from ..operators import Rendering, ViewOperator
    from ..scene import GaussianScene

__all__ = ["Renderer"]


class Renderer:
    """Renders and operators ``W(c)`` of one frozen scene, in one rasterization mode.

    Holds a :class:`~seed2gs_inverse.raster.FrozenScene`, so the
    view-independent activations of the scene (covariance factors,
    opacities, SH-0 colours, 3-sigma sizes) are computed once for all the
    views of an extraction instead of per view (identical results).

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        The scene; ``renderer.scene`` keeps it. A
        :class:`~seed2gs_inverse.raster.FrozenScene` is used as it is, so
        that its activations and spatial index serve every renderer (and
        every extraction) made from it.
    mode : str
        Rasterization mode of every view (:data:`~seed2gs_inverse.raster.MODES`).

    Attributes
    ----------
    operator_seconds : float
        Wall seconds spent in :meth:`operator` so far, so that a caller can
        count them under its own stage; time spent compiling the kernels
        (:func:`~seed2gs_inverse.raster._kernels.compile_seconds`) is left
        out, as :class:`~seed2gs_inverse.progress.StageTimer` leaves it out.
    """

    def __init__(self, scene: GaussianScene | FrozenScene, mode: str = "classic"):
        self.frozen = scene if isinstance(scene, FrozenScene) else FrozenScene(scene)
        self.scene = self.frozen.scene
        self.mode = mode
        self.operator_seconds = 0.0

    def render(self, camera: Camera) -> Rendering:
        """The full rendering of ``camera``."""
        return render(self.frozen, camera, mode=self.mode)

    def operator(self, camera: Camera, roi: tuple | None = None, min_weight: float = 0.0, cull: bool = False,
                 far: float | None = None, near: float | None = None,
                 spare: np.ndarray | None = None) -> ViewOperator:
        """``W(camera)`` with its rendering, composited only in ``roi``.

        Parameters
        ----------
        camera : Camera
        roi : (x0, y0, x1, y1) int, optional
            Pixel box (exclusive max) to composite; None: the whole image.
        min_weight : float
            Weights below this are dropped (:func:`~seed2gs_inverse.raster.build_operator`).
        cull : bool
            Rasterize only the Gaussians that can reach the ``roi`` pixels
            (:func:`~seed2gs_inverse.raster.cone_cull`, cut at depth ``far``
            when given). W's columns stay scene indices, and the operator is
            the same when ``far`` and ``near`` are None.
        far : float, optional
            Depth beyond which the cull drops Gaussians.
        near : float, optional
            Depth before which the cull drops Gaussians (by their centres):
            the operator is then that of the scene without them, whose
            columns of W are empty.
        spare : (N,) bool, optional
            Gaussians the ``near`` cut leaves in place. ``far``, ``near``
            and ``spare`` act only with ``cull``.
        """
        t0, c0 = time.perf_counter(), compile_seconds()
        subset: np.ndarray | None = cone_cull(self.frozen, camera, roi, far, near, spare) if cull else None
        op = build_operator(self.frozen, camera, roi=roi, min_weight=min_weight, mode=self.mode, subset=subset)
        self.operator_seconds += time.perf_counter() - t0 - (compile_seconds() - c0)
        return op
