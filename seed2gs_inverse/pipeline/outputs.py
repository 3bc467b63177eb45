"""An extraction's files (:func:`save_extraction`): what ``seed2gs extract``, ``demo`` and the batch write.

``OUTDIR`` receives ``object.<fmt>`` and ``remainder.<fmt>`` (the selected
Gaussians and the rest), ``q.npy`` (float32 q), ``report.json``
(:meth:`~seed2gs_inverse.pipeline.extraction.Extraction.report`, whose
``remainder_share`` says how much of the object's alpha the remainder
keeps at its place, with the seed's size and the writer's own sections)
and two pictures: ``report.png``
(:func:`~seed2gs_inverse.pipeline.report.report_figure`: the object alone
from several directions, the remainder around the hole, the seed) and
``report_masks.png``
(:func:`~seed2gs_inverse.pipeline.report.masks_figure`: the supervision
views with their masks), all or nothing.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .._atomic import atomic_path
from .._output_paths import check_output
from ..io import write_scene
from .report import masks_figure, report_figure, seed_summary

if TYPE_CHECKING:
    from .extraction import Extraction

__all__ = ["save_extraction"]


def save_extraction(extraction: Extraction, outdir: str | os.PathLike, fmt: str = "ply", *, force: bool = False,
                    figure: bool = True, run_info: dict | None = None, sections: dict | None = None) -> Path:
    """Write ``object.<fmt>``, ``remainder.<fmt>``, ``q.npy``, ``report.json`` (and the pictures) into ``outdir``.

    Parameters
    ----------
    extraction : Extraction
        What :func:`~seed2gs_inverse.pipeline.extract` returned.
    outdir : path
        The output directory. Its parent must exist; an existing
        ``outdir`` is replaced only with ``force``, and only when it is
        empty or an earlier output of this kind
        (:func:`~seed2gs_inverse._output_paths.check_output`, whose
        messages name the path ``-o``).
    fmt : {"ply", "splat"}
        Format of the object and remainder scenes. An empty part is not
        written as ``.splat`` (that format could not be read back): a
        warning says so and ``report.json``'s ``outputs`` give None.
    force : bool
        Replace an existing ``outdir``.
    figure : bool
        Also write ``report.png`` (the result:
        :func:`~seed2gs_inverse.pipeline.report.report_figure`) and
        ``report_masks.png`` (the supervision masks:
        :func:`~seed2gs_inverse.pipeline.report.masks_figure`).
    run_info : dict, optional
        The report's ``run`` section (what ``seed2gs extract
        --from-report`` reads).
    sections : dict, optional
        More top-level sections of the writer's own (``batch``: the
        batch job; ``demo``: the demo's arguments).

    Returns
    -------
    Path
        ``outdir``.

    Notes
    -----
    Everything goes to a temporary directory next to ``outdir`` that is
    renamed at the end, so a failure leaves no partial output. The write
    holds ``outdir``'s lock (:func:`~seed2gs_inverse._atomic.output_lock`:
    another process writing it is an error), and without ``force`` an
    ``outdir`` that appears meanwhile is not replaced (an error; nothing is
    left behind).
    ``report.json`` is :meth:`~seed2gs_inverse.pipeline.extraction.Extraction.report` with ``seed``
    (:func:`~seed2gs_inverse.pipeline.report.seed_summary`), ``outputs``
    and the given sections.
    """
    out = check_output(outdir, "-o", directory=True, force=force, kind="extract")
    with atomic_path(out, directory=True, replace=force) as tmp:
        outputs = {}
        for part, subset in (("object", extraction.object_scene()), ("remainder", extraction.remainder_scene())):
            if len(subset) == 0 and fmt == "splat":
                # .splat has no header: an empty file could not be read back as a scene
                warnings.warn(f"the {part} is empty (0 Gaussians): {part}.splat is not written "
                              f"(report.json's outputs say so); q.npy and report.json are", stacklevel=2)
                outputs[part] = None
                continue
            with warnings.catch_warnings(record=True) as caught:  # they name the temporary directory
                warnings.simplefilter("always")
                write_scene(tmp / f"{part}.{fmt}", subset)
            for w in caught:  # ... so say them again with the user's path
                warnings.warn(str(w.message).replace(os.fspath(tmp), os.fspath(out)), w.category, stacklevel=2)
            outputs[part] = f"{part}.{fmt}"
        np.save(tmp / "q.npy", np.asarray(extraction.q, np.float32), allow_pickle=False)
        report = extraction.report()
        report["seed"] = seed_summary(extraction)
        report["outputs"] = {**outputs, "q": "q.npy"}
        if run_info is not None:
            report["run"] = run_info
        report.update(sections or {})
        with open(tmp / "report.json", "w") as fh:
            json.dump(report, fh, indent=2)
        if figure:
            # zlib level 3: half the encoding time of the default 6 for 7-10 % larger files
            png = {"dpi": 100, "pil_kwargs": {"compress_level": 3}}
            report_figure(extraction).savefig(tmp / "report.png", **png)
            masks_figure(extraction).savefig(tmp / "report_masks.png", **png)
    return out
