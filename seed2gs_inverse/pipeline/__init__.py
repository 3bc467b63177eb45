"""Algorithm 1 of the paper: seed lift, VAAS orbits and ``extract()``."""

from .extract import Extraction, extract
from .settings import ExtractSettings
from .seed_lift import SeedLift, seed_lift
from .point_object import PointObject, point_object_mask
from .report import report_figure
from .up_axis import UpEstimate, estimate_up, estimate_up_axis
from .vaas import ClipFrame, VAASPlan, flat_orbit, orbit_cameras, run_vaas, spiral_orbit, vaas_amplitude

__all__ = ["extract", "Extraction", "ExtractSettings", "seed_lift", "SeedLift", "ClipFrame", "VAASPlan", "flat_orbit",
           "spiral_orbit", "orbit_cameras", "run_vaas", "vaas_amplitude", "estimate_up", "report_figure",
           "estimate_up_axis", "UpEstimate", "point_object_mask", "PointObject"]
