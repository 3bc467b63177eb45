"""The operator core: per-view sparse operators ``P = W q`` of a frozen scene.

:class:`ViewOperator` (one view) and :class:`OperatorStack` (a vertical stack
of views, saved and loaded without pickle) are ``scipy.sparse.linalg``
linear operators; :func:`as_stack` turns any accepted "operators" input into
a stack and :func:`dottest` checks an operator against its adjoint. This
package needs only numpy and scipy: the rasterizer that builds operators
from a scene lives in :mod:`seed2gs_inverse.raster`.
"""

from .dottest import dottest
from .stack import OperatorStack, as_stack
from .store import scene_fingerprint
from .view import Rendering, ViewOperator

__all__ = ["ViewOperator", "OperatorStack", "Rendering", "as_stack", "dottest", "scene_fingerprint"]
