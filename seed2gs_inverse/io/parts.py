"""An object and its remainder as two scene files: :func:`write_parts`.

What ``seed2gs extract`` (through
:func:`~seed2gs_inverse.pipeline.outputs.save_extraction`) and ``seed2gs
split`` write: ``object.<fmt>`` holds the selected Gaussians and
``remainder.<fmt>`` the others, each in the scene's order, a PLY keeping the
input's property list (:attr:`~seed2gs_inverse.scene.GaussianScene.layout`).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .._selection import support_mask
from ..errors import ValidationError
from ..scene import GaussianScene
from .formats import write_scene

__all__ = ["write_parts", "PART_FORMATS"]

#: The formats :func:`write_parts` writes.
PART_FORMATS = ("ply", "splat")


def write_parts(directory, scene: GaussianScene, selected, fmt: str = "ply", *, shown=None) -> dict:
    """Write ``object.<fmt>`` (the Gaussians of ``selected``) and ``remainder.<fmt>`` (the others) into ``directory``.

    Parameters
    ----------
    directory : path
        An existing folder (usually the temporary folder of an atomic
        output, renamed when everything is written).
    scene : GaussianScene
    selected : bool (N,) or int indices
        The object.
    fmt : {"ply", "splat"}
        An empty part is not written as ``.splat`` (that format has no
        header, so an empty file could not be read back): a warning says so
        and its entry is None.
    shown : path, optional
        The folder's final path, which warnings name instead of ``directory``.

    Returns
    -------
    dict
        ``{"object": name or None, "remainder": name or None}``.

    Raises
    ------
    ValidationError
        A bad ``scene``, ``selected`` or ``fmt``.
    """
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"write_parts: scene must be a GaussianScene, got {type(scene).__name__}")
    if fmt not in PART_FORMATS:
        raise ValidationError(f"write_parts: fmt must be one of {', '.join(PART_FORMATS)}, got {fmt!r}")
    sel = support_mask(selected, len(scene), "selected")
    d = Path(directory)
    outputs = {}
    for part, keep in (("object", sel), ("remainder", ~sel)):
        if not np.any(keep) and fmt == "splat":
            warnings.warn(f"the {part} is empty (0 Gaussians): {part}.splat is not written (an empty .splat "
                          f"could not be read back; the outputs list it as none)", stacklevel=3)
            outputs[part] = None
            continue
        with warnings.catch_warnings(record=True) as caught:  # they name the temporary directory
            warnings.simplefilter("always")
            write_scene(d / f"{part}.{fmt}", scene.subset(keep))
        for w in caught:  # ... so say them again with the user's path
            text = str(w.message) if shown is None else str(w.message).replace(os.fspath(d), os.fspath(shown))
            warnings.warn(text, w.category, stacklevel=3)
        outputs[part] = f"{part}.{fmt}"
    return outputs
