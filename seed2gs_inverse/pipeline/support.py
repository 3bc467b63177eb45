r"""The support surface under the object: the ground level the object rests on.

An object rests on something (a lawn, a table, a patio). In the orbit views
the model-free tracker copies labels along rendered depth and fills revealed
pixels from image neighbours; at the contact line (table legs standing in
grass, the shadowed ground between them) both can carry the object's label
onto the support, and the error then grows from view to view around the
orbit. The support is easy to recognise geometrically instead: a surface at
the support's level that faces along the orbit axis. :func:`support_surface`
finds that level, and the tracker labels such pixels background
(:class:`~seed2gs_inverse.frontend.model_free.GeometricTracker`,
``support_plane``).

The level
---------
With the orbit axis :math:`u` (unit, world up), the lift's centre :math:`o`
and radius :math:`R`, every Gaussian mean :math:`x_i` has a height and a
horizontal distance

.. math::

    h_i = u \cdot (x_i - o), \qquad r_i = \| x_i - o - h_i u \|.

The support's splats are taken in an annulus around the object's footprint,
where the support shows and the object does not: Gaussians outside G0 (the
lifted set of :func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`) with
``inner`` :math:`R \le r_i \le` ``outer`` :math:`R`, :math:`|h_i| \le 2R`,
opacity above ``min_opacity``, flat (smallest scale below 0.3 times the
middle one) and facing along the axis (:math:`|n_i \cdot u| \ge`
``min_alignment``, :math:`n_i` the axis of the smallest scale). Vertical
clutter (grass blades, fences) fails the last test. The level is their
median height :math:`\hat h` and its spread the normalised median absolute
deviation :math:`s = 1.4826\, \mathrm{med}_i |h_i - \hat h|`; the support
band reaches up to

.. math::

    t = \hat h + \max(\text{margin}\, R,\; 2 s),

and :attr:`SupportSurface.point` is :math:`o + t u`. The contact zone
reaches ``contact`` :math:`R` higher, within ``contact_reach`` :math:`R` of the axis
(:meth:`SupportSurface.contact_zone`):
there the object's base and the support meet within the z-test's reach of
each other, often in like colours (a shadowed base on gravel), so the
tracker does not copy background labels onto surfaces that do not face
along the axis (``GeometricTracker(contact_zone=)``). Fewer than
``min_splats`` such Gaussians, a level :math:`\hat h \ge 0` (not below
the object's centre: an axis pointing down) or a band top :math:`t \ge 0`
(a spread so wide that the band would take in the object's lower half): no
support surface (None),
and the tracker labels no pixel as support.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ValidationError
from ..geometry import unit_vector
from .up_axis import flat_normals

if TYPE_CHECKING:
    from ..scene import GaussianScene

__all__ = ["SupportSurface", "support_surface", "SUPPORT_DEFAULTS"]

#: Keywords of :func:`support_surface` that extract() passes (chosen on benchmarks/bench_extract.py).
SUPPORT_DEFAULTS = {"inner": 1.0, "outer": 2.0, "min_alignment": 0.9, "min_opacity": 0.3, "min_splats": 20,
                    "margin": 0.05, "contact": 0.75, "contact_reach": 1.5}


@dataclass(frozen=True)
class SupportSurface:
    """The support under the object: the band ``axis . (x - point) <= 0`` (module docstring).

    Attributes
    ----------
    axis : (3,) float64
        Unit world up (the orbit axis).
    point : (3,) float64
        A point on the top of the support band, :math:`o + t u`.
    level : float
        :math:`\\hat h`, the median height of the support's splats above the lift's centre.
    spread : float
        :math:`s`, their robust spread (normalised MAD).
    n_splats : int
        How many splats the level came from.
    contact_height, contact_radius : float
        The contact zone's height above ``point`` and its radius about the
        axis through it (scene units, >= 0).
    """

    axis: np.ndarray
    point: np.ndarray
    level: float
    spread: float
    n_splats: int
    contact_height: float = 0.0
    contact_radius: float = 0.0

    def contact_zone(self) -> tuple:
        """``(contact_height, contact_radius)``, as a tracker's ``contact_zone`` takes it."""
        return float(self.contact_height), float(self.contact_radius)

    def summary(self) -> dict:
        """JSON-ready fields (``report.json``)."""
        return {"axis": [float(v) for v in self.axis], "point": [float(v) for v in self.point],
                "level": float(self.level), "spread": float(self.spread), "n_splats": int(self.n_splats),
                "contact_height": float(self.contact_height), "contact_radius": float(self.contact_radius)}


def support_surface(scene: GaussianScene, support, center, radius: float, axis, *, inner: float = 1.0,
                    outer: float = 2.0, min_alignment: float = 0.9, min_opacity: float = 0.3, min_splats: int = 20,
                    margin: float = 0.05, contact: float = 0.0, contact_reach: float = 1.0) -> SupportSurface | None:
    """The support surface under the object, or None where no level shows (module docstring).

    Parameters
    ----------
    scene : GaussianScene
    support : (N,) bool
        G0, the lifted set (``SeedLift.g0``): left out, it is the object.
    center : (3,) float
        The lift's centre :math:`o`.
    radius : float
        The lift's radius :math:`R` (> 0).
    axis : (3,) float
        World up (normalised here).
    inner, outer : float
        The annulus, in :math:`R` (0 <= inner < outer).
    min_alignment : float
        :math:`|n_i \\cdot u|` a support splat needs, in (0, 1].
    min_opacity : float
        Nearly transparent splats are left out.
    min_splats : int
        Fewer support splats than this: None.
    margin : float
        The band reaches at least ``margin`` :math:`R` above the level.
    contact : float
        The contact zone's height above the band, in :math:`R` (>= 0; 0: none).
    contact_reach : float
        The contact zone's radius about the axis, in :math:`R` (>= 0).

    Returns
    -------
    SupportSurface or None

    Raises
    ------
    ValidationError
        A zero or non-finite axis, a centre that is not a finite 3-vector, a
        radius that is not positive, ``support`` not of the scene's size, or
        ``inner``/``outer``/``min_alignment``/``contact``/``contact_reach`` out of range.
    """
    u = unit_vector("support_surface axis", axis)
    o = np.asarray(center, dtype=np.float64).reshape(-1)
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise ValidationError(f"support_surface: center must be a finite 3-vector, got {center!r}")
    if not (np.isfinite(radius) and radius > 0):
        raise ValidationError(f"support_surface: radius must be positive, got {radius!r}")
    g0 = np.asarray(support, dtype=bool).reshape(-1)
    if g0.shape != (len(scene),):
        raise ValidationError(f"support_surface: support has {g0.size} entries, the scene {len(scene)} Gaussians")
    if not 0 <= inner < outer:
        raise ValidationError(f"support_surface: need 0 <= inner < outer, got {inner}, {outer}")
    if not 0 < min_alignment <= 1:
        raise ValidationError(f"support_surface: min_alignment must lie in (0, 1], got {min_alignment}")
    for name, v in (("contact", contact), ("contact_reach", contact_reach)):
        if not (np.isfinite(v) and v >= 0):
            raise ValidationError(f"support_surface: {name} must be a finite number >= 0, got {v!r}")
    rel = scene.means.astype(np.float64) - o
    h = rel @ u
    r = np.linalg.norm(rel - h[:, None] * u, axis=1)
    idx = np.flatnonzero(~g0 & (r >= inner * radius) & (r <= outer * radius) & (np.abs(h) <= 2.0 * radius)
                         & (np.asarray(scene.opacities) > min_opacity))
    if idx.size < min_splats:
        return None
    normals, flat = flat_normals(scene, idx)
    level_h = h[idx[flat & (np.abs(normals @ u) >= min_alignment)]]
    if level_h.size < min_splats:
        return None
    level = float(np.median(level_h))
    if level >= 0:
        # A level at or above the object's centre is nothing it rests on: the axis points down (a
        # y-up / y-down mix-up), and the band would take in the object itself.
        return None
    spread = 1.4826 * float(np.median(np.abs(level_h - level)))
    top = level + max(margin * radius, 2.0 * spread)
    if top >= 0:
        # A band that reaches the object's centre is no surface it rests on (the annulus of a large
        # object seen from above holds roofs and treetops around it, spread over its own height):
        # the tracker would label the object's lower half background.
        return None
    return SupportSurface(u, o + top * u, level, spread, int(level_h.size), float(contact * radius),
                          float(contact_reach * radius))
