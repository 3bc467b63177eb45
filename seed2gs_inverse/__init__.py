"""seed2gs-inverse: extract one object from a frozen 3D Gaussian Splatting scene.

Public API only; implementation lives in the submodules.
"""

from .camera import Camera
from .errors import FormatError, Seed2GSError, ValidationError
from .scene import GaussianScene

__version__ = "0.1.0.dev0"

__all__ = ["Camera", "GaussianScene", "Seed2GSError", "FormatError", "ValidationError",
           "__version__"]
