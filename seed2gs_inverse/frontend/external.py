"""Boxes produced elsewhere (a VLM such as Qwen3-VL run by the user) as a grounding source.

Either a callable ``fn(image, prompt)`` or a JSON file. Both give boxes as
a list whose items are ``{"box": [x0, y0, x1, y1], "score": s, "label": t}``
(score defaults to 1, label to the prompt) or bare ``[x0, y0, x1, y1]``
lists. A JSON file is either that list or an object

.. code-block:: json

    {"coords": "pixels", "boxes": [{"box": [120, 80, 260, 240], "score": 0.92}]}

with ``coords`` one of ``"pixels"`` (default), ``"unit"`` (fractions of the
width/height) or ``"per-mille"`` (0..1000, Qwen-VL's grounding grid), and an
optional ``"prompt"`` (the boxes are then used only for that prompt).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import FormatError, ValidationError
from ..io.tables import read_small_file
from ._imaging import as_box, as_rgb
from .base import Detection

__all__ = ["ExternalBoxes", "parse_boxes"]

_SCALES = {"pixels": None, "unit": 1.0, "per-mille": 1000.0}


def parse_boxes(items, shape_hw, prompt: str, coords: str = "pixels", where: str = "boxes") -> list[Detection]:
    """Validate box entries (module docstring format) into pixel Detections, best first."""
    if coords not in _SCALES:
        raise FormatError(f"{where}: coords must be one of {sorted(_SCALES)}, got {coords!r}")
    if not isinstance(items, (list, tuple)):
        raise FormatError(f"{where}: expected a list of boxes, got {type(items).__name__}")
    h, w = shape_hw
    out = []
    for k, item in enumerate(items):
        if isinstance(item, dict):
            box, score, label = item.get("box", item.get("bbox")), item.get("score", 1.0), item.get("label", prompt)
        else:
            box, score, label = item, 1.0, prompt
        try:
            b = np.asarray(box, dtype=np.float64).reshape(-1)
            score = float(score)
        except (TypeError, ValueError):
            raise FormatError(f"{where}[{k}]: box must be 4 numbers and score a number") from None
        if b.size != 4 or not np.isfinite(score) or not 0.0 <= score <= 1.0:
            raise FormatError(f"{where}[{k}]: expected box [x0, y0, x1, y1] and a score in [0, 1]")
        scale = _SCALES[coords]
        if scale is not None:
            b = b / scale * np.array([w, h, w, h])
        try:
            b = as_box(b, shape_hw, f"{where}[{k}]")
        except ValidationError as exc:
            raise FormatError(str(exc)) from None
        out.append(Detection(b, score, str(label)))
    return sorted(out, key=lambda d: -d.score)


class ExternalBoxes:
    """A grounding source whose boxes come from outside the toolkit.

    Parameters
    ----------
    source : callable or path
        ``fn(image, prompt) -> list`` of entries, or a JSON file.
    name : str
        Source name used by the selector (``"vlm"``: the paper's Qwen3-VL cue).
    coords : str
        Coordinate convention of a callable's boxes, and of a file's when the
        file names none (a file's own ``"coords"`` wins).
    """

    def __init__(self, source: Callable[..., Any] | str | Path, name: str = "vlm", coords: str = "pixels"):
        self.source = str(name)
        if coords not in _SCALES:  # an argument (a configuration file's value is checked with the file)
            raise ValidationError(f"{name}: coords must be one of {sorted(_SCALES)}, got {coords!r}")
        self.coords = coords
        if callable(source):
            self._fn, self._file = source, None
        else:
            self._fn, self._file = None, Path(source)
            # fail early on a malformed file: its entries too, in an image too large to clip any box
            items, file_coords, _ = self._load()
            parse_boxes(items, (2 ** 31, 2 ** 31), "", file_coords, str(self._file))

    def _load(self):
        """``(entries, coords, prompt or None)`` of the JSON file, or a FormatError naming it."""
        try:
            # bounded: a pipe, a device or a huge file is refused before it is read
            data = json.loads(read_small_file(self._file, "external boxes file").decode("utf-8"))
        except FileNotFoundError:
            raise FormatError(f"{self._file}: external boxes file not found") from None
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FormatError(f"{self._file}: not valid JSON ({exc})") from None
        if isinstance(data, dict):
            if "boxes" not in data:
                raise FormatError(f"{self._file}: expected a list of boxes or an object with 'boxes'")
            return data["boxes"], data.get("coords", self.coords), data.get("prompt")
        return data, self.coords, None

    def detect(self, image, prompt: str) -> list[Detection]:
        """The external boxes for ``prompt`` in pixel coordinates, best first."""
        img = as_rgb(image)
        if self._fn is not None:
            return parse_boxes(self._fn(img, prompt), img.shape[:2], prompt, self.coords,
                               f"{self.source} callable")
        items, coords, for_prompt = self._load()
        if for_prompt is not None and str(for_prompt).strip().lower() != str(prompt).strip().lower():
            return []
        return parse_boxes(items, img.shape[:2], prompt, coords, str(self._file))
