"""Benchmark evaluations that run through the batch runner.

:mod:`.engine`: the protocol on scenes already read (jobs, scoring, report),
with :mod:`.report` writing its tables and figure; one module per dataset
layout reads the scenes: :mod:`.lerf_mask`, the LERF-Mask protocol of
Gaussian Grouping (``seed2gs eval lerf-mask``), and :mod:`.ovs3d`, the same
protocol on the 3D-OVS layout (``seed2gs eval 3d-ovs``).
"""

from .engine import LerfScene, check_models, evaluate_scenes, lerf_jobs, read_gt_mask, score_frame
from .lerf_mask import evaluate_lerf_mask, read_lerf_mask
from .ovs3d import evaluate_3d_ovs, read_3d_ovs

__all__ = ["LerfScene", "check_models", "evaluate_lerf_mask", "evaluate_scenes", "lerf_jobs", "read_gt_mask",
           "read_lerf_mask", "score_frame", "evaluate_3d_ovs", "read_3d_ovs"]
