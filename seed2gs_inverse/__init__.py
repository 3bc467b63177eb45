"""seed2gs-inverse: extract one object from a frozen 3D Gaussian Splatting scene.

A frozen scene makes every camera view a fixed sparse linear operator
``P(c) = W(c) q``; extraction is the box-constrained inverse problem of
finding per-Gaussian foreground probabilities ``q in [0, 1]^N`` from masks.

Public API only; implementation lives in the submodules::

    import seed2gs_inverse as sgi
    scene = sgi.read_scene("scene.ply")
    camera = sgi.read_camera("cameras.json:0")
    op = sgi.build_operator(scene, camera)          # op.W: (H*W, N) CSR
    result = sgi.solve([op], [mask], method="voting")
    ex = sgi.extract(scene, camera, sgi.MaskPrompt(mask))

The names of ``_LAZY`` are imported from their submodule on first use
(PEP 562). The deferral is deliberate: every submodule import, the
``seed2gs`` command's included, runs this file first, and importing the
rasterizer loads Numba and its compiled kernels. So ``import
seed2gs_inverse`` loads none of Numba, SciPy, OpenCV or the ONNX runtime,
and ``seed2gs --help`` no Numba, until something needs them.
"""

from __future__ import annotations

from . import _lazy
from .camera import Camera
from .errors import FormatError, Seed2GSError, ValidationError
from .scene import GaussianScene

__version__ = "0.1.0.dev0"

# public name -> submodule that defines it
_LAZY = {
    **dict.fromkeys(["read_scene", "write_scene", "detect_format", "read_cameras", "read_camera",
                     "write_cameras"], "io"),
    **dict.fromkeys(["render", "build_operator", "project_gaussians", "Projection", "FrozenScene", "cone_cull"],
                    "raster"),
    **dict.fromkeys(["Rendering", "ViewOperator", "OperatorStack", "as_stack", "dottest", "scene_fingerprint"],
                    "operators"),
    **dict.fromkeys(["solve", "available_methods", "SolveResult"], "solvers"),
    **dict.fromkeys(["load_solve_inputs", "SolveInputs"], "solvers.inputs"),
    **dict.fromkeys(["iou", "boundary_iou", "known_iou", "known_boundary_iou", "membership_scores"], "metrics"),
    **dict.fromkeys(["compare", "Comparison"], "comparison"),  # not "compare": the module would shadow the function
    **dict.fromkeys(["MaskPrompt", "BoxPrompt", "PointPrompt", "TextPrompt"], "frontend.prompts"),
    **dict.fromkeys(["extract", "Extraction", "ExtractSettings", "seed_lift"], "pipeline"),
    **dict.fromkeys(["remove", "move", "duplicate", "recolour"], "edit"),
    **dict.fromkeys(["make_scene", "compose", "masks_from_labels", "perturb_masks"], "synthetic"),
    **dict.fromkeys(["extract_many", "Job", "JobResult", "read_jobs"], "batch"),
}

__all__ = ["Camera", "GaussianScene", "Seed2GSError", "FormatError", "ValidationError",
           "__version__", *_LAZY]


_lazy.install(__name__, _LAZY)
