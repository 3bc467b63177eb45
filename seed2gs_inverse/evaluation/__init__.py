"""Benchmark evaluations that run through the batch runner.

:mod:`.lerf_mask`: the LERF-Mask protocol of Gaussian Grouping
(``seed2gs eval lerf-mask``).
"""

from .lerf_mask import LerfScene, evaluate_lerf_mask, lerf_jobs, read_gt_mask, read_lerf_mask, score_frame

__all__ = ["LerfScene", "evaluate_lerf_mask", "lerf_jobs", "read_gt_mask", "read_lerf_mask", "score_frame"]
