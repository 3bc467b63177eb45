"""The pictures of an extraction (``report.png`` and ``report_masks.png`` of ``seed2gs extract``) and the seed's size.

:func:`report_figure` shows the result: the selected Gaussians rendered
alone from several directions about the object (a low one and one from
behind among them), each zoomed so the object fills its tile; the remainder
around the hole, in the reference view and from behind; and the seed
outlined on the reference. :func:`masks_figure` shows how it was reached:
the supervision views with their masks, for diagnosis.

The seed is the part of Algorithm 1 a user controls; a partial one (a table
top clicked, its skirt left out) gives a partial object, and a seed that
grew too far gives too much. :func:`seed_summary` measures the seed against
the object that was extracted, in the reference view.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from .._validation import check_int
from ..camera import Camera, look_at_orbit, orbit_directions
from ..raster import Renderer, render
from .seed_lift import _extent

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .extraction import Extraction

__all__ = ["report_figure", "masks_figure", "seed_summary", "OBJECT_VIEWS", "OBJECT_FILL", "REMAINDER_FILL"]

SEED_COLOR = (1.0, 0.15, 0.1)
OBJECT_COLOR = (0.1, 0.9, 0.3)

#: The directions of report.png's object tiles: ``(azimuth, elevation, label)``, degrees about the orbit
#: axis through the object's centre; azimuth 0 faces the reference camera, elevation 0 is level with the centre.
OBJECT_VIEWS = ((0.0, 30.0, "reference side"), (90.0, 30.0, ""), (180.0, 30.0, "behind"),
                (270.0, 30.0, ""), (45.0, 10.0, "low"), (0.0, 75.0, "from above"))

#: Share of a tile's longer side the object's robust extent fills (object tiles; the remainder's wider view).
OBJECT_FILL, REMAINDER_FILL = 0.85, 0.4


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

    The object's silhouette ``S`` is where the selected Gaussians, rendered
    alone from the reference camera at its full resolution, have alpha >
    0.5; its box is the silhouette's bounding box.

    Returns
    -------
    dict
        ``seed_pixels`` ``|m*|``, ``seed_box`` (x0, y0, x1, y1, exclusive
        max), ``object_pixels`` ``|S|``, ``object_box``, ``object_box_size``
        (w, h), ``share_of_object_box`` = ``|m*|`` / box area,
        ``share_of_object`` = ``|m* & S| / |S|`` (the share of the
        object's silhouette the seed covers), ``growth_beyond_seed`` =
        ``|S - m*| / |m*|`` (how far the selection grew beyond the seed,
        in units of the seed's own area: 0 when the object is the seed,
        2.0 when it renders three times the seed's area) and
        ``share_outside_object`` = ``|m* - S| / |m*|`` (the part of the
        seed the selection left out). Shares are None without an object.
        ``grown_from_pixels``: when the seed itself was grown from a click
        to a whole object in 3D (a point prompt in ``"object"`` mode), the
        pixels of the click's region it grew from; else None.
        ``dropped_pixels``: when a box prompt's GrabCut seed was cleaned to
        the box's main object, the pixels of other objects and of the ground
        it left out; else None.

    Notes
    -----
    A seed grown from a click covers most of the object whatever it grew
    into (a helmet grown to a whole upper body), so the shares above look
    normal; ``grown_from_pixels`` against ``seed_pixels`` shows the growth.
    """
    seed = np.asarray(extraction.seed_mask, bool)
    _, alpha = _object_rendering(extraction)
    sil = alpha > 0.5
    n_seed, n_obj = int(seed.sum()), int(sil.sum())
    box = _box(sil)
    out = {"seed_pixels": n_seed, "seed_box": _box(seed), "object_pixels": n_obj, "object_box": box,
           "object_box_size": None, "share_of_object_box": None, "share_of_object": None,
           "growth_beyond_seed": None, "share_outside_object": None, "grown_from_pixels": None,
           "dropped_pixels": None}
    info = getattr(extraction, "prompt_info", None) or {}
    if info.get("kind") == "point" and info.get("mode") == "object":
        out["grown_from_pixels"] = int(info["patch_pixels"])
    if info.get("kind") == "box" and info.get("cleaned") is True:
        out["dropped_pixels"] = int(info["n_dropped_pixels"])
    if box is not None:
        w, h = box[2] - box[0], box[3] - box[1]
        out.update(object_box_size=[w, h], share_of_object_box=n_seed / float(w * h),
                   share_of_object=float((seed & sil).sum()) / n_obj,
                   growth_beyond_seed=float((sil & ~seed).sum()) / max(n_seed, 1),
                   share_outside_object=float((seed & ~sil).sum()) / max(n_seed, 1))
    return out


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


def _backdrop(shape, square=16):
    """A grey checkerboard ``shape + (3,)``: what a render shows where nothing is (see-through parts show it)."""
    ys, xs = np.indices(shape)
    light = ((ys // square + xs // square) % 2).astype(np.float32)
    return np.repeat((0.28 + 0.12 * light)[..., None], 3, axis=2)


def _on_backdrop(rendering) -> np.ndarray:
    """A rendering (black background, premultiplied) composited over :func:`_backdrop`."""
    a = np.asarray(rendering.alpha, np.float32)[..., None]
    return np.clip(rendering.rgb + (1.0 - a) * _backdrop(a.shape[:2]), 0.0, 1.0)


def _axis(ex) -> np.ndarray:
    """The run's orbit axis (``resolved["up"]``), or the reference camera's image-up when none was recorded."""
    up = (getattr(ex, "resolved", None) or {}).get("up")
    u = np.asarray(ex.reference_camera.up if up is None else up, np.float64)
    return u / np.linalg.norm(u)


def _orbit_frame(ex, obj) -> tuple:
    """``(center, radius, axis, e1, distance)`` of the report's cameras about the object.

    The centre and radius are the robust extent of the selection (that of
    the seed lift, :func:`~seed2gs_inverse.pipeline.seed_lift.seed_lift`),
    or the lift's when nothing is selected; ``e1`` is the horizontal
    direction (perpendicular to the axis) towards the reference camera, and
    the distance the reference camera's, at least three radii.
    """
    if len(obj):
        center, radius, _ = _extent(obj.means.astype(np.float64), np.ones(len(obj), bool), obj.scales.max(axis=1))
    else:
        center, radius = np.asarray(ex.lift.center, np.float64), float(ex.lift.radius)
    u = _axis(ex)
    d = ex.reference_camera.center - center
    horiz = d - (d @ u) * u
    if np.linalg.norm(horiz) < 1e-6 * max(np.linalg.norm(d), 1e-12):  # a reference straight above the object
        a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        horiz = a - (a @ u) * u
    return center, float(radius), u, horiz / np.linalg.norm(horiz), max(float(np.linalg.norm(d)), 3.0 * radius)


def _fit(camera: Camera, points: np.ndarray, size: int, fill: float) -> Camera:
    """``camera``'s pose with a ``size`` x ``size`` image whose intrinsics frame ``points``.

    The 1st-99th percentile box of the points' projections (all of them
    below 20 points) fills ``fill`` of the image's side, centred; points
    behind the camera are left out.
    """
    v = camera.world_to_view(points)
    v = v[v[:, 2] > camera.near]
    if len(v) == 0:
        return Camera(size, size, size, size, size / 2, size / 2, camera.world_to_camera, camera.name, camera.near)
    xy = v[:, :2] / v[:, 2:3]
    lo, hi = np.percentile(xy, [1, 99], axis=0) if len(xy) >= 20 else (xy.min(0), xy.max(0))
    f = fill * size / max(float(np.max(hi - lo)), 1e-6)
    mid = 0.5 * (lo + hi)
    return Camera(size, size, f, f, size / 2 - f * mid[0], size / 2 - f * mid[1], camera.world_to_camera,
                  camera.name, camera.near)


def _outside(camera: Camera, points: np.ndarray) -> int:
    """How many ``points`` project outside ``camera``'s image (or lie behind it)."""
    if len(points) == 0:
        return 0
    uv, z = camera.project(points)
    with np.errstate(invalid="ignore"):  # NaN pixels behind the camera compare False: outside
        inside = (z > camera.near) & np.all((uv >= 0) & (uv < [camera.width, camera.height]), axis=1)
    return int(len(points) - inside.sum())


def _object_cameras(ex, obj, size: int, fill: float = OBJECT_FILL, views=OBJECT_VIEWS) -> list:
    """One square camera per ``(azimuth, elevation, label)`` of ``views``, framing the selection ``obj``.

    Each looks at the selection's centre along the orbit axis's frame
    (:func:`_orbit_frame`) with the axis upwards in the image, and is
    zoomed by :func:`_fit` so the selection fills ``fill`` of the tile.
    """
    center, radius, u, e1, dist = _orbit_frame(ex, obj)
    az = np.radians([v[0] for v in views])
    el = np.radians([v[1] for v in views])
    poses = look_at_orbit(center, orbit_directions(u, e1, az, el), dist, u, 60.0, size, size,
                          names=[v[2] for v in views])
    pts = obj.means.astype(np.float64) if len(obj) else (center + radius * np.eye(3))
    return [_fit(cam, pts, size, fill) for cam in poses]


def _hole_camera(ex, box, size: int) -> Camera:
    """The reference camera cut to ``box`` grown by half its size (within the image), at least ``size`` px wide.

    The reference's own intrinsics, shifted to the window and scaled up (at
    most four times) so that the window's longer side has ``size`` pixels.
    """
    cam = ex.reference_camera
    if box is None:
        x0, y0, x1, y1 = 0, 0, cam.width, cam.height
    else:
        x0, y0, x1, y1 = box
        mx, my = (x1 - x0) // 2 + 8, (y1 - y0) // 2 + 8
        x0, y0, x1, y1 = max(x0 - mx, 0), max(y0 - my, 0), min(x1 + mx, cam.width), min(y1 + my, cam.height)
    crop = Camera(x1 - x0, y1 - y0, cam.fx, cam.fy, cam.cx - x0, cam.cy - y0, cam.world_to_camera, cam.name,
                  cam.near)
    scale = min(4.0, max(1.0, size / max(crop.width, crop.height)))
    return crop if scale == 1.0 else crop.scaled(scale)


def _direction(view) -> str:
    """``"az 180°, el 30° (behind)"`` of an :data:`OBJECT_VIEWS` entry."""
    az, el, label = view
    return f"az {az:.0f}\N{DEGREE SIGN}, el {el:.0f}\N{DEGREE SIGN}" + (f" ({label})" if label else "")


def _outline(ax: Axes, mask, color, dashed=False) -> None:
    """Draw the 0.5 level of ``mask`` (an image-sized array) on ``ax``, if it has one."""
    m = np.asarray(mask, np.float32)
    if m.min() < 0.5 <= m.max():
        ax.contour(m, levels=[0.5], colors=[color], linewidths=1.2, linestyles="--" if dashed else "-")


def _panel(fig: Figure, *spec) -> Axes:
    """A subplot with no axis: no ticks are ever made (placing titles would otherwise lay them out)."""
    ax = fig.add_subplot(*spec)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_axis_off()
    return ax


def report_figure(extraction: Extraction, size: int = 320) -> Figure:
    """Figure: the object alone from :data:`OBJECT_VIEWS`, the remainder around the hole, the seed on the reference.

    Only the selected Gaussians (:meth:`Extraction.object_scene`) are
    rendered in the object tiles, over a grey checkerboard (so what is
    see-through shows it); only the others
    (:meth:`Extraction.remainder_scene`) in the remainder panels.

    Row 1: the reference canvas ``I_r`` with the seed ``m*`` (red) and the
    object's silhouette (green, dashed; :func:`seed_summary`); the
    remainder in the reference view, cut to the object's box grown by half
    its size and rendered at the reference's resolution or finer (at
    most four times, ``size`` pixels on the longer side), with the
    object's silhouette; the remainder from behind (azimuth 180 degrees)
    with the object at :data:`REMAINDER_FILL` of the tile. Rows 2-3: the
    object from each direction of :data:`OBJECT_VIEWS` about the centre of
    the selection's robust extent, the run's orbit axis (``resolved["up"]``)
    upwards, at the reference camera's distance (at least three radii),
    each ``size`` x ``size`` pixels and zoomed so that the 1st-99th
    percentile box of the selected centres fills :data:`OBJECT_FILL` of it;
    a title counts the selected Gaussians whose centres fall outside the
    tile. Every render uses the run's rasterization mode.

    Parameters
    ----------
    extraction : Extraction
    size : int
        Pixels on a side of each tile, 32 to 4096.

    Returns
    -------
    matplotlib.figure.Figure
        Not attached to pyplot (save it with ``fig.savefig``).

    Raises
    ------
    ValidationError
        ``size`` is not an integer in range.
    """
    from matplotlib.figure import Figure
    from matplotlib.gridspec import GridSpec

    size = check_int("size", size, lo=32, hi=4096)
    ex = extraction
    mode = ex.settings.mode if ex.settings is not None else "classic"
    summary = seed_summary(ex)
    _, ref_alpha = _object_rendering(ex)
    obj, rem = ex.object_scene(), ex.remainder_scene()
    obj_r = Renderer(obj, mode) if len(obj) else None
    rem_r = Renderer(rem, mode) if len(rem) else None
    cams = _object_cameras(ex, obj, size)
    behind = OBJECT_VIEWS[2]
    wide = _object_cameras(ex, obj, size, REMAINDER_FILL, views=(behind,))[0]
    hole = _hole_camera(ex, summary["object_box"], size)

    def alpha(cam):
        return obj_r.render(cam).alpha if obj_r is not None else np.zeros(cam.image_shape, np.float32)

    def remainder(cam):
        return _on_backdrop(rem_r.render(cam)) if rem_r is not None else _backdrop(cam.image_shape)

    top = max(2.0, 3.6 * ex.reference_camera.height / ex.reference_camera.width + 0.5)  # inches, with the title
    fig = Figure(figsize=(10.8, 0.6 + top + 2 * 3.9))
    gs = GridSpec(3, 3, figure=fig, height_ratios=[top, 3.9, 3.9])
    ax = _panel(fig, gs[0, 0])
    ax.imshow(np.clip(ex.reference.rgb, 0, 1))
    _outline(ax, ex.seed_mask, SEED_COLOR)
    _outline(ax, ref_alpha, OBJECT_COLOR, dashed=True)
    ax.set_title(f"reference: seed (red) {summary['seed_pixels']:,} px,\nobject (green) "
                 f"{summary['object_pixels']:,} px", fontsize=8)
    for col, (cam, what) in enumerate(((hole, "in the reference view"), (wide, _direction(behind))), start=1):
        ax = _panel(fig, gs[0, col])
        ax.imshow(remainder(cam))
        _outline(ax, alpha(cam), OBJECT_COLOR, dashed=True)
        ax.set_title(f"remainder {what}\n(the object's place in green)", fontsize=8)
    points = obj.means.astype(np.float64)
    for j, (cam, view) in enumerate(zip(cams, OBJECT_VIEWS)):
        ax = _panel(fig, gs[1 + j // 3, j % 3])
        ax.imshow(_on_backdrop(obj_r.render(cam)) if obj_r is not None else _backdrop(cam.image_shape))
        out = _outside(cam, points)
        ax.set_title(f"object: {_direction(view)}" + (f"\n{out:,} of {len(obj):,} Gaussians beyond the tile"
                                                       if out else ""), fontsize=8)
    cov, grew, click = summary["share_of_object"], summary["growth_beyond_seed"], summary["grown_from_pixels"]
    fig.suptitle(f"{ex.settings.method if ex.settings is not None else ''}: {len(obj):,} of {len(ex.scene):,} "
                 f"Gaussians selected, {len(ex.views)} views, {ex.total_seconds:.1f} s"
                 + ("" if cov is None else f"\nin the reference the seed covers {cov:.0%} of the object's "
                    f"silhouette, which adds {grew:.0%} of the seed's area beyond it")
                 + ("" if click is None else f"\nthe seed itself grew in 3D from the click's {click:,} px region"),
                 fontsize=10)
    fig.tight_layout()
    return fig


def masks_figure(extraction: Extraction, n_strip: int = 8) -> Figure:
    """Figure: ``n_strip`` supervision views with their masks (``report_masks.png``), for diagnosis.

    The views are spread evenly over the clips; each shows the whole
    scene's rendering with its tracked mask ``Y(c)`` (red; grey =
    unknown), cut to the same window around the lifted object (the
    projection of the sphere ``(o, 2 extent)``, the default ``zoom_margin``
    of the orbit views), so every view shows the object at the same zoom.

    Parameters
    ----------
    extraction : Extraction
    n_strip : int
        How many views, at least 1 (fewer when the run has fewer).

    Returns
    -------
    matplotlib.figure.Figure
        Not attached to pyplot (save it with ``fig.savefig``).

    Raises
    ------
    ValidationError
        ``n_strip`` is not a positive integer.
    """
    from matplotlib.figure import Figure

    n = min(check_int("n_strip", n_strip, lo=1), len(extraction.views))
    ex = extraction
    cam = ex.reference_camera
    picks = np.unique(np.linspace(0, len(ex.views) - 1, n).round().astype(int)) if n else np.zeros(0, int)
    per_row = 4
    rows = max(1, int(np.ceil(len(picks) / per_row)))
    fig = Figure(figsize=(13.2, 3.5 * rows + 0.6))
    for j, i in enumerate(picks):
        op = ex.operators[int(i)]
        vcam = op.camera if getattr(op, "camera", None) is not None else ex.views[int(i)]
        win = _orbit_window(vcam, ex.lift.center, ex.lift.radius)
        rgb = op.rendering.rgb
        if rgb.shape == ex.reference.rgb.shape and np.array_equal(vcam.world_to_camera, cam.world_to_camera):
            rgb = ex.reference.rgb  # the reference view's operator is composited only around the seed
        img = _window(_overlay(rgb, ex.masks[int(i)]), *win)
        ax = _panel(fig, rows, per_row, j + 1)
        ax.imshow(np.clip(_square(img), 0, 1))
        ax.set_title(f"{ex.clips[int(i)]} view {int(i)}", fontsize=8)
    fig.suptitle(f"supervision masks (red; grey = unknown) of {len(picks)} of {len(ex.views)} views: "
                 f"V={ex.vaas.visibility:.2f}, A={ex.vaas.amplitude_deg:.1f} deg", fontsize=10)
    fig.tight_layout()
    return fig
