r"""A tracker that needs no model: rendered geometry plus edge-aware filling.

The views of a VAAS clip are *rendered*, so two things come for free that a
video tracker has to estimate: the depth of every pixel and the exact camera
motion between views. :class:`GeometricTracker` propagates the seed mask
with them (2D propagation, as the paper requires: the masks are never read
off a 3D membership, so they add evidence beyond the seed lift).

For frame ``k`` and each pixel ``p`` with rendered alpha above ``alpha_min``:

1. unproject ``p`` with the rendered expected depth :math:`D_k(p)` to a world
   point ``X`` and project ``X`` into a source frame ``j`` (``p' = \pi_j(X)``,
   depth ``z'``);
2. ``X`` is *seen* in frame ``j`` when ``p'`` is in the image, frame ``j`` is
   opaque there and :math:`|z' - D_j(p')| \le \tau_{rel} z'` (a z-test: if
   something else is in front, ``X`` was occluded in ``j``);
3. the label is copied from the first source that sees ``X`` and has a label
   there, trying the seed frame 0 first (no drift where the reference saw
   the surface), then the previous frame ``k-1``.

Pixels with alpha below ``alpha_min`` are empty space and get 0 (nothing
there can be the object). Pixels no source sees (newly revealed surfaces,
blended depths at silhouettes) are decided by image evidence: a normalised
joint-bilateral filter (``cv2.ximgproc.jointBilateralFilter`` guided by the
frame's RGB) spreads the decided labels along colour-homogeneous regions,

.. math::

    \hat y(p) = \frac{\sum_q k(p,q)\, c(q)\, y(q)}{\sum_q k(p,q)\, c(q)},

with ``c`` = 1 on decided pixels and 0 elsewhere. A revealed pixel takes 1
when :math:`\hat y \ge 1 - \delta`, 0 when :math:`\hat y \le \delta`, given enough
support :math:`\sum_q k c \ge` ``min_support`` (relative to the kernel mass);
otherwise it stays NaN (unknown): the tracker does not guess.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..errors import ValidationError

__all__ = ["GeometricTracker", "warp_labels"]


def _pixel_rays(camera) -> np.ndarray:
    """Camera-frame rays (H, W, 3) with z = 1 through the pixel centres."""
    h, w = camera.image_shape
    x = (np.arange(w) + 0.5 - camera.cx) / camera.fx
    y = (np.arange(h) + 0.5 - camera.cy) / camera.fy
    rays = np.empty((h, w, 3))
    rays[..., 0] = x[None, :]
    rays[..., 1] = y[:, None]
    rays[..., 2] = 1.0
    return rays


def warp_labels(dst, src, src_labels: np.ndarray, *, alpha_min: float = 0.5,
                depth_tol: float = 0.01) -> np.ndarray:
    """Backward-warp labels of frame ``src`` into frame ``dst`` through rendered depth.

    Parameters
    ----------
    dst, src : frames with ``depth`` (H, W), ``alpha`` (H, W), ``camera``
    src_labels : (Hs, Ws) float array, NaN = unknown
    alpha_min, depth_tol : float
        Opacity needed for a pixel to be a surface; relative z-test tolerance.

    Returns
    -------
    (H, W) float64: the label seen at each ``dst`` pixel's surface point in
    ``src`` (nearest pixel), NaN where ``src`` does not see that point or has
    no label.
    """
    cam, scam = dst.camera, src.camera
    h, w = cam.image_shape
    sh, sw = scam.image_shape
    d = np.asarray(dst.depth, np.float64)
    valid = (np.asarray(dst.alpha) >= alpha_min) & (d > 0)
    out = np.full((h, w), np.nan)
    if not valid.any():
        return out
    pc = _pixel_rays(cam)[valid] * d[valid][:, None]
    world = (pc - cam.translation) @ cam.rotation  # R^T (p - t)
    uv, z = scam.project(world)
    ok = np.isfinite(uv).all(axis=1) & (z > scam.near)
    px = np.floor(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    py = np.floor(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (px >= 0) & (px < sw) & (py >= 0) & (py < sh)
    i = np.nonzero(ok)[0]
    sd = np.asarray(src.depth, np.float64)[py[i], px[i]]
    sa = np.asarray(src.alpha)[py[i], px[i]]
    seen = (sa >= alpha_min) & (sd > 0) & (np.abs(z[i] - sd) <= depth_tol * z[i])
    vals = np.full(len(z), np.nan)
    vals[i[seen]] = np.asarray(src_labels, np.float64)[py[i[seen]], px[i[seen]]]
    out[valid] = vals
    return out


class GeometricTracker:
    """Model-free :class:`~seed2gs_inverse.frontend.base.Tracker` for rendered clips.

    Parameters
    ----------
    alpha_min : float
        Rendered alpha below which a pixel is empty space (label 0).
    depth_tol : float
        Relative z-test tolerance of the warp (1 % of depth).
    fill : bool
        Decide pixels no source sees with the joint-bilateral filter.
    fill_radius : float
        Spatial sigma of the filter as a fraction of the image diagonal.
    fill_sigma_color : float
        Colour sigma of the filter (RGB in [0, 1]).
    decisive : float
        ``delta``: a revealed pixel is labelled only when the filtered value
        is within ``delta`` of 0 or 1.
    min_support : float
        Minimum normalised weight of decided pixels around a revealed pixel.
    """

    def __init__(self, alpha_min: float = 0.5, depth_tol: float = 0.01, fill: bool = True,
                 fill_radius: float = 0.02, fill_sigma_color: float = 0.1, decisive: float = 0.2,
                 min_support: float = 0.25):
        if not 0 < alpha_min < 1:
            raise ValidationError(f"alpha_min must be in (0, 1), got {alpha_min!r}")
        if not depth_tol > 0:
            raise ValidationError(f"depth_tol must be positive, got {depth_tol!r}")
        if not 0 <= decisive < 0.5:
            raise ValidationError(f"decisive must be in [0, 0.5), got {decisive!r}")
        self.alpha_min = float(alpha_min)
        self.depth_tol = float(depth_tol)
        self.fill = bool(fill)
        self.fill_radius = float(fill_radius)
        self.fill_sigma_color = float(fill_sigma_color)
        self.decisive = float(decisive)
        self.min_support = float(min_support)

    def track(self, frames: Sequence[Any], seed_mask: np.ndarray) -> list:
        """Propagate ``seed_mask`` (frame 0) along ``frames``; float32 masks, NaN = unknown."""
        frames = list(frames)
        if not frames:
            raise ValidationError("tracker: the clip has no frames")
        for k, f in enumerate(frames):
            for attr in ("rgb", "depth", "alpha", "camera"):
                if not hasattr(f, attr):
                    raise ValidationError(f"tracker: frame {k} has no '{attr}'")
            hw = f.camera.image_shape
            if np.asarray(f.depth).shape != hw or np.asarray(f.alpha).shape != hw:
                raise ValidationError(f"tracker: frame {k} depth/alpha do not match its camera {hw}")
        seed = np.asarray(seed_mask, dtype=np.float64)
        if seed.shape != frames[0].camera.image_shape:
            raise ValidationError(f"tracker: seed mask has shape {seed.shape}, frame 0 is "
                                  f"{frames[0].camera.image_shape}")
        seed = np.where(np.isnan(seed), np.nan, (seed > 0.5).astype(np.float64))
        masks = [seed.astype(np.float32)]
        for k in range(1, len(frames)):
            f = frames[k]
            lab = warp_labels(f, frames[0], seed, alpha_min=self.alpha_min, depth_tol=self.depth_tol)
            if k > 1:
                todo = np.isnan(lab)
                if todo.any():
                    prev = warp_labels(f, frames[k - 1], masks[k - 1].astype(np.float64),
                                       alpha_min=self.alpha_min, depth_tol=self.depth_tol)
                    lab[todo] = prev[todo]
            lab = np.where(np.isnan(lab), lab, (lab > 0.5).astype(np.float64))
            empty = np.asarray(f.alpha) < self.alpha_min
            lab[empty] = 0.0
            if self.fill and np.isnan(lab).any():
                lab = self._fill(np.asarray(f.rgb, np.float32), lab)
            masks.append(lab.astype(np.float32))
        return masks

    def _fill(self, rgb: np.ndarray, lab: np.ndarray) -> np.ndarray:
        import cv2

        h, w = lab.shape
        known = ~np.isnan(lab)
        if not known.any():
            return lab
        sigma_s = max(1.0, self.fill_radius * float(np.hypot(h, w)))
        d = int(2 * np.ceil(2 * sigma_s) + 1)
        guide = np.ascontiguousarray(np.clip(rgb, 0, 1).astype(np.float32))
        num = np.where(known, lab, 0.0).astype(np.float32)
        den = known.astype(np.float32)
        fnum = cv2.ximgproc.jointBilateralFilter(guide, num, d, self.fill_sigma_color, sigma_s)
        fden = cv2.ximgproc.jointBilateralFilter(guide, den, d, self.fill_sigma_color, sigma_s)
        with np.errstate(invalid="ignore", divide="ignore"):
            val = fnum / np.maximum(fden, 1e-12)
        # fden is the (colour- and space-weighted) fraction of decided neighbours.
        ok = ~known & (fden >= self.min_support)
        out = lab.copy()
        out[ok & (val >= 1 - self.decisive)] = 1.0
        out[ok & (val <= self.decisive)] = 0.0
        return out
