"""Readers and writers for Gaussian splat scenes and camera files.

Scenes: :func:`read_scene` / :func:`write_scene` (``.ply``, ``.splat``
read and write; ``.compressed.ply`` and ``.spz`` read), :func:`detect_format`.
Cameras: :func:`read_cameras`, :func:`read_camera` (``FILE:NAME`` or
``FILE:INDEX``), :func:`write_cameras` (3DGS ``cameras.json``); one module
per format (``cameras_json``, ``colmap``, ``nerfstudio``) behind ``cameras``.
Masks: :func:`read_masks` (a directory of ``view_000.png|npy`` per-view masks).
Bad files raise :class:`~seed2gs_inverse.errors.FormatError` naming the file.
"""

from .cameras import read_camera, read_cameras, write_cameras
from .formats import READ_FORMATS, WRITE_FORMATS, detect_format, read_scene, write_scene
from .masks import read_masks

__all__ = ["read_scene", "write_scene", "detect_format", "read_cameras", "read_camera",
           "write_cameras", "read_masks", "READ_FORMATS", "WRITE_FORMATS"]
