"""The forward model: per-view sparse operators ``P = W q`` of a frozen scene.

``render``/``build_operator`` (the rasterizer) turn a scene and a camera into a
:class:`ViewOperator`; :class:`OperatorStack` stacks views, saves and loads them.
"""

from .operator import OperatorStack, ViewOperator, scene_fingerprint
from .render import Rendering, build_operator, frozen, render

__all__ = ["Rendering", "render", "build_operator", "frozen", "ViewOperator", "OperatorStack", "scene_fingerprint"]
