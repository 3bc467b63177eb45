"""The 2D front end: it supplies the seed mask m* and the supervision masks Y(c).

Model-free pieces (prompts, the geometric tracker) work with no files at all;
the learned pieces run ONNX files the user supplies (see ``docs/models.md``).
"""

from .base import Candidate, Detection, Grounder, Tracker
from .config import NO_MODELS_NOTICE, ModelSet, load_models, resolve_models
from .external import ExternalBoxes
from .grounding_dino import GroundingDINO
from .owlvit import OWLViT
from .sam2 import SAM2ImagePredictor, SAM2VideoTracker
from .sam3 import SAM3
from .selector import QDSAM3Selector, query_type
from .tokenizer import BertTokenizer, ClipTokenizer

__all__ = [
    "Candidate", "Detection", "Grounder", "Tracker",
    "load_models", "resolve_models", "ModelSet", "NO_MODELS_NOTICE",
    "QDSAM3Selector", "query_type", "SAM2ImagePredictor", "SAM2VideoTracker",
    "GroundingDINO", "SAM3", "OWLViT", "ExternalBoxes", "BertTokenizer", "ClipTokenizer",
]
