"""A one-page picture of an extraction (``report.png`` of ``seed2gs extract``) and the seed's size.

The seed is the part of Algorithm 1 a user controls; a partial one (a table
top clicked, its skirt left out) gives a partial object. :func:`seed_summary`
measures it against the object that was extracted, and the report shows
both, so a partial seed is seen at once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from ..raster import render

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .extraction import Extraction

__all__ = ["report_figure", "seed_summary"]

SEED_COLOR = (1.0, 0.15, 0.1)
BOX_COLOR = (0.1, 0.9, 0.3)


def _overlay(rgb, mask, color=SEED_COLOR, a=0.5):
    img = np.clip(np.asarray(rgb, np.float64), 0, 1).copy()
    if mask is None:
        return img
    m = np.asarray(mask, np.float64)
    unknown = np.isnan(m)
    m = np.nan_to_num(m)[..., None]
    img = (1 - a * m) * img + a * m * np.asarray(color)
    img[unknown] = 0.5 * img[unknown] + 0.25
    return img


def _box(mask):
    """``(x0, y0, x1, y1)`` (exclusive max) of a boolean mask's pixels, or None."""
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        return None
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def _object_rendering(ex: Extraction) -> tuple:
    """The selected Gaussians rendered alone from the reference camera (cached on the extraction)."""
    cached = getattr(ex, "_object_rendering", None)
    if cached is None:
        cam = ex.reference_camera
        obj = ex.object_scene()
        if len(obj):
            r = render(obj, cam, mode=ex.settings.mode)  # as every rendering of the run
            cached = (r.rgb, r.alpha)
        else:
            cached = (np.zeros(cam.image_shape + (3,), np.float32), np.zeros(cam.image_shape, np.float32))
        ex._object_rendering = cached
    return cached


def seed_summary(extraction: Extraction) -> dict:
    """How large the seed ``m*`` is next to the extracted object, in the reference view.

    The object's silhouette is where the selected Gaussians, rendered alone
    from the reference camera, have alpha > 0.5; its box is the silhouette's
    bounding box.

    Returns
    -------
    dict
        ``seed_pixels``, ``seed_box`` (x0, y0, x1, y1, exclusive max),
        ``object_pixels`` (silhouette), ``object_box``, ``object_box_size``
        (w, h), ``share_of_object_box`` = seed pixels / box area,
        ``share_of_object`` = |seed and silhouette| / |silhouette| (how much
        of the visible object the seed covers) and ``share_outside_object`` =
        |seed - silhouette| / |seed|. Shares are None without an object.
    """
    seed = np.asarray(extraction.seed_mask, bool)
    _, alpha = _object_rendering(extraction)
    sil = alpha > 0.5
    n_seed, n_obj = int(seed.sum()), int(sil.sum())
    box = _box(sil)
    out = {"seed_pixels": n_seed, "seed_box": _box(seed), "object_pixels": n_obj, "object_box": box,
           "object_box_size": None, "share_of_object_box": None, "share_of_object": None,
           "share_outside_object": None}
    if box is not None:
        w, h = box[2] - box[0], box[3] - box[1]
        out.update(object_box_size=[w, h], share_of_object_box=n_seed / float(w * h),
                   share_of_object=float((seed & sil).sum()) / n_obj,
                   share_outside_object=float((seed & ~sil).sum()) / max(n_seed, 1))
    return out


def _crop(img, box, margin=0.15, fill=0.5):
    """``img`` cut to ``box`` grown by ``margin`` of its size (padded with grey beyond the image)."""
    x0, y0, x1, y1 = box
    mx, my = int(np.ceil(margin * (x1 - x0))) + 2, int(np.ceil(margin * (y1 - y0))) + 2
    return _window(img, x0 - mx, y0 - my, x1 + mx, y1 + my, fill)


def _window(img, x0, y0, x1, y1, fill=0.5):
    """The pixels ``[y0:y1, x0:x1]`` of ``img``, with ``fill`` where the window leaves the image."""
    h, w = img.shape[:2]
    out = np.full((y1 - y0, x1 - x0) + img.shape[2:], fill, np.float64)
    sx0, sy0, sx1, sy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = img[sy0:sy1, sx0:sx1]
    return out


def _orbit_window(camera, center, radius, scale=2.0):
    """A square pixel window around the projection of the sphere (center, scale * radius).

    The same ``scale`` for every view gives every orbit panel the same zoom
    on the object, whatever the view's resolution or field of view.
    """
    z = float(camera.world_to_view(np.asarray(center, float)[None])[0, 2])
    uv, _ = camera.project(np.asarray(center, float)[None])
    half = max(scale * float(radius) * max(camera.fx, camera.fy) / max(z, 1e-6), 4.0)
    half = min(half, 4.0 * max(camera.width, camera.height))
    u, v = float(uv[0, 0]), float(uv[0, 1])
    return (int(np.floor(u - half)), int(np.floor(v - half)), int(np.ceil(u + half)), int(np.ceil(v + half)))


def _square(img, size=200):
    return cv2.resize(np.ascontiguousarray(img, np.float32), (size, size), interpolation=cv2.INTER_AREA
                      if img.shape[0] > size else cv2.INTER_LINEAR)


def _rect(ax: Axes, box, color, ls="-"):
    from matplotlib.patches import Rectangle

    x0, y0, x1, y1 = box
    ax.add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, ec=color, lw=1.2, ls=ls))


def report_figure(extraction: Extraction, n_strip: int = 8) -> Figure:
    """Figure: the seed on the reference, the object alone (cropped to it), the remainder, orbit views.

    Row 1 (large panels): the reference canvas ``I_r`` with the seed ``m*``
    (red) and the object's box (green, :func:`seed_summary`); the object
    rendered alone from the reference camera, cropped to its box, with the
    seed's outline; the remainder. Rows 2-3: ``n_strip`` supervision views
    evenly spread over the clips with their tracked masks (red; grey =
    unknown), each cut to the same window around the lifted object (the
    projection of the sphere ``(o, 2 extent)``, the default ``zoom_margin``
    of the orbit views), so every view shows
    the object at the same zoom. Returns a matplotlib Figure not attached to
    pyplot (save it with ``fig.savefig``).
    """
    from matplotlib.figure import Figure
    from matplotlib.gridspec import GridSpec

    ex = extraction
    cam = ex.reference_camera
    summary = seed_summary(ex)
    obj_rgb, obj_alpha = _object_rendering(ex)
    rem = ex.remainder_scene()
    rem_img = render(rem, cam, mode=ex.settings.mode).rgb if len(rem) else np.zeros(cam.image_shape + (3,), np.float32)
    n = min(int(n_strip), len(ex.views))
    picks = np.unique(np.linspace(0, len(ex.views) - 1, n).round().astype(int)) if n else np.zeros(0, int)
    per_row = 4
    strip_rows = int(np.ceil(len(picks) / per_row))
    aspect = cam.height / cam.width
    top_h = 4.4 * aspect + 0.5
    fig = Figure(figsize=(13.2, top_h + 3.5 * strip_rows + 0.6))
    gs = GridSpec(1 + strip_rows, 12, figure=fig, height_ratios=[top_h] + [3.5] * strip_rows)

    ax = fig.add_subplot(gs[0, 0:4])
    ax.imshow(_overlay(ex.reference.rgb, ex.seed_mask))
    if summary["object_box"] is not None:
        _rect(ax, summary["object_box"], BOX_COLOR, "--")
    share = summary["share_of_object_box"]
    ax.set_title(f"reference + seed: {summary['seed_pixels']:,} px"
                 + ("" if share is None else f" = {share:.0%} of the object's box (green)"), fontsize=9)
    ax.axis("off")

    ax = fig.add_subplot(gs[0, 4:8])
    box = summary["object_box"]
    if box is not None:
        crop = _crop(obj_rgb, box)
        seed_crop = _crop(np.asarray(ex.seed_mask, np.float64), box, fill=0.0)
        ax.imshow(np.clip(crop, 0, 1))
        ax.contour(seed_crop, levels=[0.5], colors=[SEED_COLOR], linewidths=1.0)
        cov = summary["share_of_object"]
        ax.set_title(f"object ({int(ex.selected.sum()):,} Gaussians); seed (red) covers {cov:.0%}", fontsize=9)
    else:
        ax.imshow(np.clip(obj_rgb, 0, 1))
        ax.set_title(f"object ({int(ex.selected.sum()):,} Gaussians; not visible here)", fontsize=9)
    ax.axis("off")

    ax = fig.add_subplot(gs[0, 8:12])
    ax.imshow(np.clip(rem_img, 0, 1))
    ax.set_title("remainder", fontsize=9)
    ax.axis("off")

    for j, i in enumerate(picks):
        op = ex.operators[int(i)]
        vcam = op.camera if getattr(op, "camera", None) is not None else ex.views[int(i)]
        win = _orbit_window(vcam, ex.lift.center, ex.lift.radius)
        rgb = op.rendering.rgb
        if rgb.shape == ex.reference.rgb.shape and np.array_equal(vcam.world_to_camera, cam.world_to_camera):
            rgb = ex.reference.rgb  # the reference view's operator is composited only around the seed
        img = _window(_overlay(rgb, ex.masks[int(i)]), *win)
        r, c = divmod(j, per_row)
        ax = fig.add_subplot(gs[1 + r, 3 * c:3 * c + 3])
        ax.imshow(np.clip(_square(img), 0, 1))
        ax.set_title(f"{ex.clips[int(i)]} view {int(i)}", fontsize=8)
        ax.axis("off")
    s = ex.seconds
    fig.suptitle(f"{ex.settings.method if ex.settings is not None else ''}: {len(ex.views)} views, "
                 f"V={ex.vaas.visibility:.2f}, A={ex.vaas.amplitude_deg:.1f} deg, "
                 f"{sum(s.values()):.1f} s", fontsize=10)
    fig.tight_layout()
    return fig
