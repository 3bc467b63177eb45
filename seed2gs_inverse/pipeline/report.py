"""A one-page picture of an extraction (``report.png`` of ``seed2gs extract``)."""

from __future__ import annotations

import numpy as np

__all__ = ["report_figure"]


def _overlay(rgb, mask, color=(1.0, 0.15, 0.1), a=0.5):
    img = np.clip(np.asarray(rgb, np.float64), 0, 1).copy()
    if mask is None:
        return img
    m = np.asarray(mask, np.float64)
    unknown = np.isnan(m)
    m = np.nan_to_num(m)[..., None]
    img = (1 - a * m) * img + a * m * np.asarray(color)
    img[unknown] = 0.5 * img[unknown] + 0.25
    return img


def report_figure(extraction, n_strip: int = 8):
    """Figure: reference render with the seed, orbit views with their masks, the object alone.

    Row 1: the reference canvas ``I_r`` with the seed ``m*`` (red), the
    object rendered alone from the reference camera, and the remainder.
    Row 2: ``n_strip`` supervision views evenly spread over the clips with
    their tracked masks (red; grey = unknown). Returns a matplotlib Figure
    not attached to pyplot (save it with ``fig.savefig``).
    """
    from matplotlib.figure import Figure

    from ..raster import render

    ex = extraction
    cam = ex.reference_camera
    obj = ex.object_scene()
    obj_img = render(obj, cam).rgb if len(obj) else np.zeros(cam.image_shape + (3,), np.float32)
    rem = ex.remainder_scene()
    rem_img = render(rem, cam).rgb if len(rem) else np.zeros(cam.image_shape + (3,), np.float32)
    n = min(int(n_strip), len(ex.views))
    picks = np.unique(np.linspace(0, len(ex.views) - 1, n).round().astype(int))
    ncols = max(3, len(picks))
    fig = Figure(figsize=(2.2 * ncols, 2.2 * 2 * cam.height / cam.width + 1.2))
    top = [(_overlay(ex.reference.rgb, ex.seed_mask), "reference + seed"),
           (obj_img, f"object ({int(ex.selected.sum())} Gaussians)"),
           (rem_img, "remainder")]
    for j, (img, title) in enumerate(top):
        ax = fig.add_subplot(2, ncols, j + 1)
        ax.imshow(np.clip(img, 0, 1))
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    for j, i in enumerate(picks):
        op = ex.operators[int(i)]
        ax = fig.add_subplot(2, ncols, ncols + j + 1)
        ax.imshow(_overlay(op.rendering.rgb, ex.masks[int(i)]))
        ax.set_title(f"{ex.clips[int(i)]} {int(i)}", fontsize=7)
        ax.axis("off")
    s = ex.seconds
    fig.suptitle(f"{ex.settings.method if ex.settings is not None else ''}: {len(ex.views)} views, "
                 f"V={ex.vaas.visibility:.2f}, A={ex.vaas.amplitude_deg:.1f} deg, "
                 f"{sum(s.values()):.1f} s", fontsize=9)
    fig.tight_layout()
    return fig
