"""The tile rasterizer over the operator core: images and operators ``W(c)`` of a frozen scene.

:func:`render` gives a view's image, :func:`build_operator` its
:class:`~seed2gs_inverse.operators.ViewOperator` from the same pass,
:func:`project_gaussians` the per-Gaussian screen-space quantities and
:func:`cone_cull` the Gaussians that can reach some pixels. A
:class:`FrozenScene` holds a scene's view-independent activations so that
many views of one scene compute them once. Semantics in
:mod:`seed2gs_inverse.raster.rasterize`; the Numba kernels are private
(``_kernels``).
"""

from .cull import cone_cull
from .frozen import FrozenScene
from .project import MODES, Projection, project_gaussians
from .rasterize import build_operator, render
from .renderer import Renderer  # many views of one frozen scene (the pipeline's); not in __all__
from ._kernels import compile_seconds  # the compile clock of the pipeline's stage timer; not in __all__

__all__ = ["render", "build_operator", "project_gaussians", "Projection", "cone_cull", "FrozenScene", "MODES"]
