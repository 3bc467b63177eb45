"""Algorithm 1 of the paper: ``extract()`` over named stages, with seed lift and VAAS orbits.

:mod:`~.extract` runs the stages of :mod:`~.stages` and returns an
:class:`Extraction` (:mod:`~.extraction`), whose files
:func:`save_extraction` writes (:mod:`~.outputs`); :mod:`~.seed_lift`, :mod:`~.vaas`,
:mod:`~.up_axis`, :mod:`~.support`, :mod:`~.completion`, :mod:`~.islands` and
:mod:`~.point_object` hold the algorithms the stages call, :mod:`~.settings`
every option and :mod:`~.report` the report figures.

The names are imported from their module on first use (PEP 562), as in the
package's own ``__init__``: the stages import the rasterizer and so Numba, and
``import seed2gs_inverse.pipeline.settings`` (the command line's parser needs
the settings' defaults) must not.
"""

from __future__ import annotations

from .. import _lazy

# public name -> module of this package that defines it
_LAZY = {
    "extract": "extract", "Extraction": "extraction", "save_extraction": "outputs", "ExtractSettings": "settings",
    "seed_lift": "seed_lift", "SeedLift": "seed_lift", "point_object_mask": "point_object",
    "PointObject": "point_object", "report_figure": "report", "masks_figure": "report", "UpEstimate": "up_axis",
    "estimate_up": "up_axis", "estimate_up_axis": "up_axis",
    **dict.fromkeys(["ClipFrame", "VAASPlan", "flat_orbit", "orbit_cameras", "run_vaas", "spiral_orbit",
                     "vaas_amplitude"], "vaas"),
}

__all__ = ["extract", "Extraction", "save_extraction", "ExtractSettings", "seed_lift", "SeedLift", "ClipFrame",
           "VAASPlan", "flat_orbit", "spiral_orbit", "orbit_cameras", "run_vaas", "vaas_amplitude", "estimate_up",
           "report_figure", "masks_figure", "estimate_up_axis", "UpEstimate", "point_object_mask", "PointObject"]


_lazy.install(__name__, _LAZY)
