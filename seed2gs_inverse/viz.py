"""Looking at scenes and results: pyvista membership views, matplotlib view grids.

:func:`membership_plot` shows Gaussians as points or ellipsoid glyphs,
coloured by a membership ``q`` (a colormap over [0, 1]) or by their own
colour. Without a display (no ``DISPLAY``/``WAYLAND_DISPLAY``) it renders
off-screen through EGL and can only save a screenshot.
:func:`view_grid` lays out rendered views with their masks overlaid, for
reports.
"""

from __future__ import annotations

import numbers
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from ._extras import missing_extra
from .errors import ValidationError
from .geometry import unit_vector
from .scene import GaussianScene, quat_to_rotmat
from .sh import SH_C0

__all__ = ["membership_plot", "view_grid", "has_display", "check_membership", "require_pyvista"]


def has_display() -> bool:
    """Whether an interactive window can be opened (always True off Linux/BSD)."""
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def check_membership(q, n: int, name: str = "membership q") -> np.ndarray:
    """A membership vector checked against a scene of ``n`` Gaussians.

    Parameters
    ----------
    q : array_like, shape (n,)
        One number in [0, 1] per Gaussian (bool and integer 0/1 accepted).
    n : int
        Number of Gaussians of the scene it belongs to.
    name : str
        What to call ``q`` in error messages (e.g. the file it came from).

    Returns
    -------
    (n,) float64 array

    Raises
    ------
    ValidationError
        Naming ``name`` when the shape, dtype or values are wrong.
    """
    arr = np.asarray(q)
    if arr.ndim != 1 or arr.shape[0] != n:
        raise ValidationError(f"{name} has shape {arr.shape}; the scene has {n} Gaussians, "
                              f"so it must have shape ({n},)")
    if arr.dtype.kind not in "biuf":
        raise ValidationError(f"{name} has dtype {arr.dtype}; expected numbers")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr) & (arr >= 0) & (arr <= 1)):  # also for n = 0
        raise ValidationError(f"{name}: values must be finite and in [0, 1]")
    return arr


def require_pyvista():
    """The ``pyvista`` module (imported on first use: VTK is large and only the 3D views need it).

    Raises
    ------
    MissingExtraError
        pyvista cannot be imported; the message names ``pip install "seed2gs-inverse[view]"``.
    """
    try:
        import pyvista
    except ImportError as exc:
        raise missing_extra("view", "drawing Gaussians in 3D (seed2gs view, membership_plot)", exc) from None
    return pyvista


def _ellipsoid_mesh(means, rotmats, scales, n_theta=10, n_phi=6):
    """One merged triangle mesh of ellipsoids ``mean + R diag(scales) u``, |u| = 1.

    Returns ``(points (G*V, 3), faces (G*F, 4) in VTK layout, V)``; building
    the arrays in numpy is far faster than one glyph filter call per Gaussian.
    """
    pv = require_pyvista()
    sphere = pv.Sphere(radius=1.0, theta_resolution=n_theta, phi_resolution=n_phi)
    unit = np.asarray(sphere.points, dtype=np.float64)
    tri = np.asarray(sphere.faces).reshape(-1, 4)[:, 1:]
    v = unit.shape[0]
    m = rotmats * scales[:, None, :]                                  # R S
    pts = means[:, None, :] + np.einsum("gij,vj->gvi", m, unit)        # (G, V, 3)
    faces = tri[None, :, :] + (np.arange(len(means)) * v)[:, None, None]
    faces = np.concatenate([np.full(faces.shape[:2] + (1,), 3), faces], axis=2)
    return pts.reshape(-1, 3), faces.reshape(-1), v


def membership_plot(scene: GaussianScene, q=None, mode: str = "points", threshold: float | None = None,
                    screenshot=None, off_screen: bool | None = None, camera=None,
                    max_glyphs: int = 20000, glyph_sigma: float = 1.0, point_size: float = 3.0,
                    cmap: str = "viridis", window_size=None, min_opacity: float = 0.0,
                    background="white", scalar_bar: bool = True, seed: int = 0, up=None):
    """Show Gaussians coloured by membership.

    Parameters
    ----------
    scene : GaussianScene
    q : (N,) array in [0, 1], optional
        Membership. Colour = ``cmap(q)`` with the colormap spanning [0, 1]
        (so q = 1 is the top colour of ``cmap``). When None each Gaussian
        shows its base colour ``clip(SH_C0 sh[:, 0] + 0.5, 0, 1)``.
    mode : {"points", "ellipsoids"}
        Points are one unlit dot per Gaussian mean. Ellipsoids draw the
        ``glyph_sigma``-sigma surface ``mean + R diag(glyph_sigma s) u``,
        ``|u| = 1``, lit, for at most ``max_glyphs`` Gaussians (a random
        subset drawn with ``seed`` when there are more; a warning and a
        caption say how many are shown).
    threshold : float, optional
        Show only Gaussians with ``q > threshold`` (needs ``q``).
    screenshot : path, optional
        Write a PNG to this path (which must end in ``.png``) and return the image.
    off_screen : bool, optional
        Default: off-screen when there is no display (then EGL is used and
        only screenshots are possible).
    camera : Camera, optional
        View from this camera: position, orientation, vertical field of
        view from ``fy`` and the principal point ``(cx, cy)``; the window
        size defaults to its image size, where points land on the pixels
        ``camera.project`` gives. (``fx != fy`` is not represented: VTK
        pixels are square.)
    up : (3,) array, optional
        Without a camera: the world direction to show upwards (e.g. ``-y``
        for COLMAP-like scenes); default: VTK's isometric view with +z up.
    max_glyphs : int
        Cap on ellipsoids.
    glyph_sigma, point_size, cmap, window_size, background, scalar_bar
        Drawing options; ``window_size`` is ``(width, height)``, each in
        1..8192, default the camera's image size or ``(1024, 768)``;
        ``scalar_bar`` shows the colormap legend when ``q`` is given.
    min_opacity : float
        Hide Gaussians with activated opacity below this (real scenes carry
        many invisible ones that clutter the view).
    seed : int
        Seed of the glyph subsample.

    Returns
    -------
    (H, W, 3) uint8 image when ``screenshot`` is given (the plotter is
    closed), else the ``pyvista.Plotter`` (call ``.show()``).
    """
    if not isinstance(scene, GaussianScene):
        raise ValidationError(f"scene must be a GaussianScene, got {type(scene).__name__}")
    if mode not in ("points", "ellipsoids"):
        raise ValidationError(f"mode must be 'points' or 'ellipsoids', got {mode!r}")
    n = len(scene)
    qv = None if q is None else check_membership(q, n)
    if threshold is not None:
        if qv is None:
            raise ValidationError("threshold needs a membership q")
        if not (np.isfinite(threshold) and 0 <= threshold < 1):
            raise ValidationError(f"threshold must be in [0, 1), got {threshold!r}")
    if int(max_glyphs) < 1:
        raise ValidationError(f"max_glyphs must be >= 1, got {max_glyphs}")
    if not (np.isfinite(glyph_sigma) and glyph_sigma > 0):
        raise ValidationError(f"glyph_sigma must be positive, got {glyph_sigma!r}")
    if not (np.isfinite(min_opacity) and 0 <= min_opacity <= 1):
        raise ValidationError(f"min_opacity must be in [0, 1], got {min_opacity!r}")
    up = None if up is None else unit_vector("up", up)
    if window_size is not None:
        window_size = _window_size(window_size)
    else:  # a camera's image size is checked with the camera
        window_size = [camera.width, camera.height] if camera is not None else [1024, 768]
    if screenshot is not None and Path(screenshot).suffix.lower() != ".png":
        raise ValidationError(f"screenshot {str(screenshot)!r}: must be a .png path (the image is written as PNG)")
    if off_screen is None:
        off_screen = not has_display()
    if not off_screen and screenshot is None and not has_display():
        raise ValidationError("no display to open a window on: pass screenshot=... (off-screen)")
    if off_screen and not has_display():
        # Without X, VTK would try X first and warn; EGL renders headless on GPUs and Mesa.
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    pv = require_pyvista()

    keep = np.ones(n, bool)
    if min_opacity > 0:
        keep &= scene.opacities >= min_opacity
    if threshold is not None:
        keep &= qv > threshold
    idx = np.nonzero(keep)[0]
    caption = None
    if mode == "ellipsoids" and idx.size > max_glyphs:
        idx = np.sort(np.random.default_rng(seed).choice(idx, size=int(max_glyphs), replace=False))
        caption = f"ellipsoids for {idx.size} of {int(keep.sum())} Gaussians (random subset)"
        warnings.warn(caption + "; raise max_glyphs to draw more", stacklevel=2)
    pl = pv.Plotter(off_screen=bool(off_screen), window_size=list(window_size))
    try:
        pl.set_background(background)
        if qv is not None:
            color_kw = dict(scalars=qv[idx], cmap=cmap, clim=(0.0, 1.0), show_scalar_bar=bool(scalar_bar),
                            scalar_bar_args={"title": "q", "n_labels": 3, "fmt": "%.1f", "vertical": True,
                                             "position_x": 0.86, "position_y": 0.15,
                                             "width": 0.08, "height": 0.7})
        else:
            rgb = np.clip(SH_C0 * scene.sh[idx, 0, :].astype(np.float64) + 0.5, 0.0, 1.0)
            color_kw = dict(scalars=(rgb * 255).astype(np.uint8), rgb=True)
        if idx.size == 0:
            pl.add_text("no Gaussians to show", font_size=10, color="black")
        elif mode == "points":
            cloud = pv.PolyData(scene.means[idx].astype(np.float64))
            pl.add_mesh(cloud, style="points", point_size=point_size, lighting=False,
                        render_points_as_spheres=False, **color_kw)
        else:
            pts, faces, v = _ellipsoid_mesh(scene.means[idx].astype(np.float64),
                                            quat_to_rotmat(scene.quats[idx]),
                                            glyph_sigma * scene.scales_at(idx).astype(np.float64))
            mesh = pv.PolyData(pts, faces)
            color_kw["scalars"] = np.repeat(color_kw["scalars"], v, axis=0)
            pl.add_mesh(mesh, smooth_shading=False, **color_kw)
        if caption:
            pl.add_text(caption, font_size=8, color="black")
        if camera is not None:
            pl.camera.position = tuple(camera.center)
            pl.camera.focal_point = tuple(camera.center + camera.forward)
            pl.camera.up = tuple(camera.up)
            pl.camera.view_angle = float(np.degrees(camera.fov_y))
            # VTK centres the optical axis; shift the window so it lands on (cx, cy).
            pl.camera.SetWindowCenter(1.0 - 2.0 * camera.cx / camera.width,
                                      2.0 * camera.cy / camera.height - 1.0)
            pl.reset_camera_clipping_range()
        elif idx.size:
            pl.view_isometric()
            if up is not None:
                # Oblique view from above along the scene's own "up" (a unit vector; VTK assumes +z).
                side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
                side /= np.linalg.norm(side)
                focal = np.asarray(pl.camera.focal_point)
                pl.camera.position = tuple(focal + pl.camera.distance * (0.8 * side + 0.6 * up))
                pl.camera.up = tuple(up)
                pl.reset_camera()
        img = None if screenshot is None else pl.screenshot(str(screenshot), return_img=True)
    except BaseException:
        pl.close()  # no off-screen plotter (and its GL context) left behind
        raise
    if screenshot is None:
        return pl
    pl.close()
    return img


def _window_size(size) -> list:
    """``[width, height]`` from two whole numbers in 1..8192 (a ValidationError otherwise)."""
    try:
        vals = list(size)
    except TypeError:
        vals = []
    if len(vals) != 2 or not all(isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))
                                 and float(v).is_integer() for v in vals):
        raise ValidationError(f"window_size must be two whole numbers (width, height), got {size!r}")
    w, h = (int(v) for v in vals)
    if not (0 < w <= 8192 and 0 < h <= 8192):
        raise ValidationError(f"window_size {(w, h)!r}: width and height must be in 1..8192")
    return [w, h]


def view_grid(images, masks=None, titles=None, ncols: int | None = None, mask_color=(1.0, 0.1, 0.1),
              mask_alpha: float = 0.45, panel_size: float = 3.0):
    """A matplotlib figure of views with their masks overlaid.

    Panel i shows ``images[i]`` (float in [0, 1] or uint8, (H, W, 3) or
    (H, W)) with, if given, mask ``masks[i]`` blended in:
    ``out = (1 - a m) img + a m color`` with ``a = mask_alpha`` and ``m`` the
    mask value; unknown (NaN) pixels are greyed (``0.5 img + 0.25``), and the
    0.5 contour of the mask is drawn. A mask may be None for a panel.

    Returns
    -------
    matplotlib.figure.Figure (not attached to pyplot, so nothing opens a window).
    """
    from matplotlib.figure import Figure

    imgs = list(images)
    if not imgs:
        raise ValidationError("view_grid needs at least one image")
    if masks is not None:
        masks = list(masks)
        if len(masks) != len(imgs):
            raise ValidationError(f"view_grid got {len(imgs)} images but {len(masks)} masks")
    if titles is not None:
        titles = [str(t) for t in titles]
        if len(titles) != len(imgs):
            raise ValidationError(f"view_grid got {len(imgs)} images but {len(titles)} titles")
    if not (0 <= mask_alpha <= 1):
        raise ValidationError(f"mask_alpha must be in [0, 1], got {mask_alpha}")
    color = np.asarray(mask_color, dtype=np.float64)
    if color.shape != (3,):
        raise ValidationError(f"mask_color must be an RGB triple, got {mask_color!r}")
    ncols = min(len(imgs), 4) if ncols is None else int(ncols)
    if ncols < 1:
        raise ValidationError(f"ncols must be >= 1, got {ncols}")
    nrows = -(-len(imgs) // ncols)
    fig = Figure(figsize=(panel_size * ncols, panel_size * nrows * 0.8))
    for i, im in enumerate(imgs):
        a = np.asarray(im)
        if a.ndim == 2:
            a = np.repeat(a[:, :, None], 3, axis=2)
        if a.ndim != 3 or a.shape[2] not in (3, 4):
            raise ValidationError(f"image {i} has shape {a.shape}; expected (H, W, 3) or (H, W)")
        a = a[:, :, :3].astype(np.float64) / (255.0 if a.dtype == np.uint8 else 1.0)
        a = np.clip(a, 0, 1)
        ax = fig.add_subplot(nrows, ncols, i + 1)
        m = None if masks is None or masks[i] is None else np.asarray(masks[i], dtype=np.float64)
        if m is not None:
            if m.shape != a.shape[:2]:
                raise ValidationError(f"mask {i} has shape {m.shape}; image {i} is {a.shape[:2]}")
            unknown = np.isnan(m)
            w = mask_alpha * np.where(unknown, 0.0, np.clip(m, 0, 1))[:, :, None]
            a = (1 - w) * a + w * color
            a[unknown] = 0.5 * a[unknown] + 0.25
        ax.imshow(a, interpolation="nearest")
        if m is not None:
            filled = np.where(np.isnan(m), 0.0, m)
            if filled.max() > 0.5 > filled.min():
                ax.contour(filled, levels=[0.5], colors=[tuple(color)], linewidths=0.8)
        if titles is not None:
            ax.set_title(titles[i], fontsize=8)
        ax.set_axis_off()
    fig.tight_layout()
    return fig
