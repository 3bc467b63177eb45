"""Algorithm 1 of the paper: ``extract()`` over named stages, with seed lift and VAAS orbits.

:mod:`~.extract` runs the stages of :mod:`~.stages` and returns an
:class:`Extraction` (:mod:`~.extraction`), whose files
:func:`save_extraction` writes (:mod:`~.outputs`); :mod:`~.seed_lift`, :mod:`~.vaas`,
:mod:`~.up_axis`, :mod:`~.support`, :mod:`~.completion` and
:mod:`~.point_object` hold the algorithms the stages call, :mod:`~.settings`
every option and :mod:`~.report` the report figure.
"""

from .extract import extract
from .extraction import Extraction
from .outputs import save_extraction
from .settings import ExtractSettings
from .seed_lift import SeedLift, seed_lift
from .point_object import PointObject, point_object_mask
from .report import report_figure
from .up_axis import UpEstimate, estimate_up, estimate_up_axis
from .vaas import ClipFrame, VAASPlan, flat_orbit, orbit_cameras, run_vaas, spiral_orbit, vaas_amplitude

__all__ = ["extract", "Extraction", "save_extraction", "ExtractSettings", "seed_lift", "SeedLift", "ClipFrame",
           "VAASPlan", "flat_orbit", "spiral_orbit", "orbit_cameras", "run_vaas", "vaas_amplitude", "estimate_up",
           "report_figure", "estimate_up_axis", "UpEstimate", "point_object_mask", "PointObject"]
