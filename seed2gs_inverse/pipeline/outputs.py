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
views with their masks), all or nothing. With ``save_operators`` it also receives the run's solve inputs
(:func:`~seed2gs_inverse.solvers.inputs.write_solve_inputs`: ``operators/``,
``masks/``, ``init.npy``, ``graph.npz``, ``follow.npz``, ``islands.npy`` and
``solve.json``), which
:func:`~seed2gs_inverse.solvers.inputs.load_solve_inputs` and ``seed2gs
solve --from-extraction`` read to reproduce ``q``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .._atomic import atomic_path
from .._output_paths import check_output
from ..errors import ValidationError
from ..graph import apply_follow
from ..io.parts import write_parts
from ..solvers.inputs import write_solve_inputs
from .report import masks_figure, report_figure, seed_summary

if TYPE_CHECKING:
    from .extraction import Extraction

__all__ = ["save_extraction", "solve_inputs_of"]


def save_extraction(extraction: Extraction, outdir: str | os.PathLike, fmt: str = "ply", *, force: bool = False,
                    figure: bool = True, run_info: dict | None = None, sections: dict | None = None,
                    save_operators: bool = False) -> Path:
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
    save_operators : bool
        Also write what the solve took (:func:`solve_inputs_of`): the
        operators, the masks, the prior, the graph and the settings, from
        which ``seed2gs solve OUT/operators OUT/masks --from-extraction OUT``
        reproduces ``q.npy`` exactly; ``report.json``'s ``outputs`` name
        them.

    Returns
    -------
    Path
        ``outdir``.

    Raises
    ------
    ValidationError
        ``outdir`` may not be written (see ``outdir``), or
        ``save_operators`` for an extraction whose regulariser's graph or
        faint Gaussians' matrix is not kept (``extraction.graph`` or
        ``extraction.follow`` is None; :func:`solve_inputs_of`).

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
    solve_inputs = solve_inputs_of(extraction) if save_operators else None
    with atomic_path(out, directory=True, replace=force) as tmp:
        outputs = write_parts(tmp, extraction.scene, extraction.selected, fmt, shown=out)
        np.save(tmp / "q.npy", np.asarray(extraction.q, np.float32), allow_pickle=False)
        if solve_inputs is not None:
            outputs.update(write_solve_inputs(tmp, **solve_inputs))
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


def solve_inputs_of(extraction: Extraction) -> dict:
    """The keywords of :func:`~seed2gs_inverse.solvers.inputs.write_solve_inputs` for an extraction's solve.

    The run's operators and masks, its method with the options it solved
    with (:meth:`~seed2gs_inverse.pipeline.settings.ExtractSettings.solver_kwargs`),
    the prior G0, ``min_evidence``, ``min_vote``, the smoothness used and its graph, the
    threshold, the faint Gaussians' ``follow`` matrix applied after the
    solve (``follow_faint``), and as ``islands`` the Gaussians whose ``q``
    the run then set to 0 (those where ``extraction.q`` differs from the
    solver's ``q`` with ``follow`` applied; an empty list with
    ``seed_connected``, None without).

    Raises
    ------
    ValidationError
        The extraction has no settings, or used the regulariser
        (``resolved["smoothness"] > 0``) without keeping its graph, or
        ``follow_faint`` or ``follow_weak`` without keeping its matrix.
    """
    s = extraction.settings
    if s is None:
        raise ValidationError("save_operators: the extraction holds no settings (ExtractSettings); it did not "
                              "come from extract()")
    smoothness = float(extraction.resolved.get("smoothness", s.smoothness or 0.0))
    if smoothness > 0 and extraction.graph is None:
        raise ValidationError("save_operators: the extraction used the regulariser (smoothness "
                              f"{smoothness:g}) but holds no graph (Extraction.graph); run extract() again")
    follows = s.follow_faint or s.follow_weak
    if follows and extraction.follow is None:
        raise ValidationError("save_operators: the extraction ran with follow_faint or follow_weak but holds no "
                              "follow matrix (Extraction.follow); run extract() again")
    solver_q = np.asarray(extraction.result.q, np.float32)
    if follows:
        solver_q = apply_follow(solver_q, extraction.follow)
    islands = np.flatnonzero(solver_q != np.asarray(extraction.q, np.float32)) if s.seed_connected else None
    return {"operators": extraction.operators, "masks": extraction.masks, "method": s.method,
            "options": s.solver_kwargs(), "init": extraction.lift.g0, "min_evidence": s.min_evidence,
            "min_vote": s.min_vote,
            "smoothness": smoothness, "graph": extraction.graph if smoothness > 0 else None,
            "follow": extraction.follow if follows else None, "islands": islands,
            "threshold": float(extraction.threshold)}
