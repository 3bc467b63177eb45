"""Tile rasterization of a frozen 3DGS scene: images and the operator W(c).

One pass of the rasterizer gives the image of a view and, optionally, the
sparse matrix ``W(c)`` of shape ``(H*W, N)`` whose entry ``(u, i)`` is the
weight ``alpha_i(u) T_i(u)`` with which Gaussian ``i`` reaches pixel ``u``.

Semantics ("classic" = the reference 3DGS rasterizer and gsplat)
----------------------------------------------------------------
Camera in the OpenCV convention; ``x_c = R x + t`` with ``z`` the view depth.

* Culling: Gaussians with ``z < camera.near`` are dropped.
* Projection (gsplat convention): the 2D mean is
  ``mu = (fx x/z + cx, fy y/z + cy)`` in pixel coordinates where pixel
  ``(px, py)`` has its centre at ``(px + 0.5, py + 0.5)``. (The reference
  3DGS code maps NDC with ``ndc2Pix`` and samples at integer pixel
  coordinates, i.e. a half-pixel shift of both; gsplat, and this module, use
  ``cx`` directly and sample at ``px + 0.5``.)
* EWA: ``Sigma2D = J R Sigma R^T J^T`` with
  ``J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]]`` where
  ``tx = z clamp(x/z, -(cx/fx + 0.3 tan_x), (W - cx)/fx + 0.3 tan_x)``,
  ``tan_x = W / (2 fx)`` (and likewise y), which is the clamp at
  ``1.3 tan(fov/2)`` of the reference code for a centred principal point
  (gsplat ``persp_proj``). ``Sigma = R(q) S S^T R(q)^T``.
* Low-pass: ``Sigma2D + 0.3 I``. Mode "antialiased" (gsplat) additionally
  multiplies the opacity by ``sqrt(det Sigma2D / det(Sigma2D + 0.3 I))``.
  Gaussians with ``det(Sigma2D + 0.3 I) <= 0`` are culled.
* Conic ``(a, b, c)``: the entries ``[[a, b], [b, c]]`` of the inverse.
* Radius: ``r = ceil(3 sqrt(lambda_max))``, ``lambda_max = m +
  sqrt(max(0.01, m^2 - det))``, ``m = (Sigma_xx + Sigma_yy)/2`` (gsplat;
  capped at 2e9 px so that it fits an int32).
* Tiles: 16x16. A Gaussian is binned to the tiles
  ``[floor((mu - r)/16), floor((mu + r + 15)/16))`` per axis, clamped to the
  grid (``getRect`` of the reference code); Gaussians with an empty
  rectangle are culled (radius 0). A Gaussian reaches only pixels of its
  tiles. Each tile's list is ordered by view depth ``z`` (stable: ties by
  Gaussian index). (Internally a Gaussian is left out of the tiles its
  ``o exp(power) >= 1/255`` ellipse does not reach, where it could not
  contribute anyway; this only saves work.)
* Compositing, per pixel front to back, starting from ``T = 1``: with
  ``d = mu - p`` and ``p`` the pixel centre,
  ``power = -(a dx^2 + c dy^2)/2 - b dx dy``; skip if ``power > 0``;
  ``alpha = min(0.99, o exp(power))``; skip if ``alpha < 1/255``; stop if
  ``T (1 - alpha) < 1e-4`` (that Gaussian is not added); else the weight is
  ``w = alpha T`` and ``T <- T (1 - alpha)``.
* Colour: ``max(eval_sh(sh, d) + 0.5, 0)`` with ``d`` the unit vector from
  the camera centre to the Gaussian mean.

Outputs: ``rgb = sum_i w_i c_i + T_final * background``,
``alpha = 1 - T_final = sum_i w_i``, expected depth
``depth = sum_i w_i z_i / alpha`` (0 where nothing contributes), and
``n_contrib`` the number of Gaussians with ``w > 0`` at the pixel.
Hence, on every view, ``W @ 1 == alpha``, ``W @ colors == rgb - T_final
background`` and ``W @ z == depth * alpha`` to float32 precision.

Computation is float64 inside the kernels (Numba, parallel over Gaussians
and tiles); outputs are float32.
"""

from __future__ import annotations

import mmap
import time

import numpy as np
import scipy.sparse as sp

from .._selection import support_indices
from ..errors import ValidationError
from ..operators.view import Rendering, ViewOperator
from . import _kernels
from .cull import cone_cull
from .project import check_inputs, project

__all__ = ["render", "build_operator"]


def _roi_mask(roi, shape):
    """(H, W) uint8 mask of the pixels to composite, from a box or a mask."""
    h, w = shape
    if roi is None:
        return np.ones(shape, np.uint8)
    arr = np.asarray(roi)
    if arr.ndim == 2:
        if arr.shape != (h, w):
            raise ValidationError(f"roi mask has shape {arr.shape}; expected the image shape {(h, w)} "
                                  "(at the operator's scale)")
        if arr.dtype != bool:
            raise ValidationError(f"roi mask must be boolean, got dtype {arr.dtype}")
        if not arr.any():  # as a box with no pixel in the image: nothing would be composited
            raise ValidationError("roi mask selects no pixel; pass None for the whole image")
        return arr.astype(np.uint8)
    if arr.shape != (4,) or arr.dtype.kind not in "iuf" or not np.all(np.isfinite(arr)):
        raise ValidationError(f"roi must be a box (x0, y0, x1, y1) or an (H, W) bool mask, got {roi!r}")
    if np.any(arr != np.round(arr)):
        raise ValidationError(f"roi box must have integer pixel bounds, got {arr.tolist()}")
    x0, y0, x1, y1 = (int(v) for v in arr)
    if x0 >= x1 or y0 >= y1:
        raise ValidationError(f"roi box {(x0, y0, x1, y1)} is empty; need x0 < x1 and y0 < y1")
    # A box reaching past the border is clipped to the image; one with no
    # pixel inside it is an error.
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx0 >= cx1 or cy0 >= cy1:
        raise ValidationError(f"roi box {(x0, y0, x1, y1)} lies outside the {w}x{h} image")
    mask = np.zeros(shape, np.uint8)
    mask[cy0:cy1, cx0:cx1] = 1
    return mask


def _check_background(background):
    if background is None:
        return np.zeros(3)
    try:
        bg = np.asarray(background, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValidationError(f"background must be a finite RGB triple or scalar, got {background!r}") from None
    if bg.shape == ():
        bg = np.full(3, float(bg))
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ValidationError(f"background must be a finite RGB triple or scalar, got {background!r}")
    return bg


def _depth_order(depths, idx):
    """``idx`` (ascending) sorted by ``depths[idx]``, ties by index.

    Same result as a stable argsort, but an unstable sort is several times
    faster; exact depth ties (duplicated Gaussians) are then put back in
    index order, run by run.
    """
    d = depths[idx]
    o = np.argsort(d)
    ds = d[o]
    tie = ds[1:] == ds[:-1]
    if tie.any():
        in_run = np.zeros(o.size, bool)
        in_run[1:] |= tie
        in_run[:-1] |= tie
        run = np.concatenate([[0], np.cumsum(~tie)])
        sub = np.flatnonzero(in_run)
        # Runs are contiguous blocks of ``sub``: sorting by (run, index)
        # leaves each block in place and orders it by index.
        o[sub] = o[sub][np.lexsort((o[sub], run[sub]))]
    return idx[o]


# Room for the first compositing pass to log W's entries, per tile-Gaussian
# pair of the tile (most pairs log a few weights, but up to 256 in tiles of
# big splats), and at most this many
# entries in all (10 bytes each). The scratch is lazily committed memory
# (see _lazy_empty), so room never written costs nothing. Tiles that run
# out of room take the second compositing pass.
_SCRATCH_PER_PAIR = 32
_SCRATCH_MAX = 1 << 26


def _lazy_empty(n, dtype):
    """Uninitialised (n,) array whose pages are committed only when written.

    An anonymous mmap: unlike a large numpy allocation (which asks for
    transparent huge pages, so writing one byte zeroes 2 MB), untouched
    parts of the generous per-tile scratch cost neither time nor memory.
    """
    dtype = np.dtype(dtype)
    if n == 0:
        return np.empty(0, dtype)
    return np.frombuffer(mmap.mmap(-1, n * dtype.itemsize), dtype=dtype, count=n)


def _pixel_box(roi_mask):
    """Pixels ``[x0, y0, x1, y1)`` holding every pixel of the roi (int64; all 0 for an empty roi)."""
    rows = np.flatnonzero(roi_mask.any(axis=1))
    cols = np.flatnonzero(roi_mask.any(axis=0))
    if rows.size == 0:
        return np.zeros(4, np.int64)
    return np.array([cols[0], rows[0], cols[-1] + 1, rows[-1] + 1], np.int64)


def _tile_box(pixel_box):
    """Tiles ``[tx0, ty0, tx1, ty1)`` holding every pixel of ``pixel_box`` (int64)."""
    if pixel_box[2] <= pixel_box[0]:
        return np.zeros(4, np.int64)
    t = _kernels.TILE
    return np.array([pixel_box[0] // t, pixel_box[1] // t, (pixel_box[2] - 1) // t + 1,
                     (pixel_box[3] - 1) // t + 1], np.int64)


def _rasterize(scene, frozen, camera, background, mode, roi, min_weight, build_w, stats=None, subset=None):
    """One rasterizer pass; returns (Rendering, W or None).

    ``frozen``: the scene's :class:`~.frozen.FrozenScene` or None.
    ``subset``: ascending int64 scene indices to rasterize (default all,
    which on a frozen scene are the Gaussians that ``cone_cull`` keeps for
    the roi's bounding box: the others reach none of its pixels); W keeps
    one column per scene Gaussian. ``stats``, a dict, receives stage
    timings (s) and work counts for benchmarks.
    """
    clock = [time.perf_counter()]
    h, w = camera.height, camera.width
    roi_mask = _roi_mask(roi, (h, w))
    bg = _check_background(background)
    box = _pixel_box(roi_mask)
    if subset is None and frozen is not None:
        subset = cone_cull(frozen, camera, box)
    gid = np.arange(len(scene), dtype=np.int64) if subset is None else subset
    splats = project(scene, frozen, camera, mode, gid, _tile_box(box))
    rects = splats.rects
    clock.append(time.perf_counter())

    # Front-to-back order of the binned Gaussians: by depth, ties by index
    # (stable sort of an ascending index list; ``gid`` is ascending, so
    # ties by row are ties by scene index). Gaussians with an empty tile
    # rectangle (culled, outside the roi, or never passing the alpha test)
    # are not binned.
    vis = np.flatnonzero((rects[:, 2] > rects[:, 0]) & (rects[:, 3] > rects[:, 1]))
    order = _depth_order(splats.depths, vis)
    clock.append(time.perf_counter())
    tiles_x = (w + _kernels.TILE - 1) // _kernels.TILE
    tiles_y = (h + _kernels.TILE - 1) // _kernels.TILE
    n_tiles = tiles_x * tiles_y
    tile_start, tile_gauss = _kernels.bin_tiles(order, rects, tiles_x, n_tiles)
    # Tiles differ a lot in cost: visited in a fixed shuffled order, the last
    # tiles claimed (see _kernels._fetch_add) are rarely a run of expensive ones.
    tile_order = np.random.default_rng(0).permutation(n_tiles).astype(np.int64)
    clock.append(time.perf_counter())

    img = _kernels.Image(rgb=np.zeros((h, w, 3), np.float32), alpha=np.zeros((h, w), np.float32),
                         depth=np.zeros((h, w), np.float32), n_contrib=np.zeros((h, w), np.int32),
                         n_kept=np.zeros(h * w, np.int64))
    tile_evals = np.zeros(n_tiles, np.int64)
    if build_w:
        pairs = np.diff(tile_start)
        per_pair = min(float(_SCRATCH_PER_PAIR), _SCRATCH_MAX / max(int(tile_start[-1]), 1))
        scr_start = np.zeros(n_tiles + 1, np.int64)
        np.cumsum((pairs * per_pair).astype(np.int64), out=scr_start[1:])
    else:
        scr_start = np.zeros(n_tiles + 1, np.int64)
    n_scr = int(scr_start[-1])
    scr = _kernels.Scratch(start=scr_start, pix=_lazy_empty(n_scr, np.int16), gi=_lazy_empty(n_scr, np.int32),
                           w=_lazy_empty(n_scr, np.float32), used=np.zeros(n_tiles, np.int64))
    no_csr = _kernels.CSR(np.zeros(1, np.int64), np.zeros(0, np.int32), np.zeros(0, np.float32))
    _kernels.composite(_kernels.TileLists(tile_start, tile_gauss, tile_order), splats, w, h, roi_mask, bg,
                       float(min_weight), False, gid, img, no_csr, scr, tile_evals, _kernels.workers(n_tiles))
    clock.append(time.perf_counter())
    rendering = Rendering(img.rgb, img.alpha, img.depth, img.n_contrib)
    if stats is not None:
        stats.update(project_s=clock[1] - clock[0], sort_s=clock[2] - clock[1],
                     bin_s=clock[3] - clock[2], composite_s=clock[4] - clock[3],
                     n_binned=int(order.size), n_pairs=int(tile_gauss.size),
                     n_evals=int(tile_evals.sum()))
    if not build_w:
        return rendering, None

    indptr = np.zeros(h * w + 1, np.int64)
    np.cumsum(img.n_kept, out=indptr[1:])
    nnz = int(indptr[-1])
    csr = _kernels.CSR(indptr, np.empty(nnz, np.int32), np.empty(nnz, np.float32))
    # Tiles whose log is complete are copied into the rows sized by the first
    # pass; the others composite again (bit-identical arithmetic) and write
    # their weights directly.
    logged = np.flatnonzero(scr.used > 0)
    _kernels.scatter(logged, scr_start[logged], scr_start[logged] + scr.used[logged], w, h,
                     scr.pix, scr.gi, scr.w, gid, indptr, csr.indices, csr.data, _kernels.workers(logged.size))
    redo = np.flatnonzero(scr.used < 0)
    if redo.size:
        _kernels.composite(_kernels.TileLists(tile_start, tile_gauss, redo), splats, w, h, roi_mask, bg,
                           float(min_weight), True, gid, img, csr, scr, tile_evals, _kernels.workers(redo.size))
    if nnz <= np.iinfo(np.int32).max:
        indptr = indptr.astype(np.int32)
    W = sp.csr_matrix((csr.data, csr.indices, indptr), shape=(h * w, len(scene)), copy=False)
    # Columns within a row are in compositing (depth) order, not sorted.
    W.has_sorted_indices = False
    if stats is not None:
        stats["fill_s"] = time.perf_counter() - clock[4]
        stats["n_redo_tiles"] = int(redo.size)
    return rendering, W


def render(scene, camera, background=None, mode: str = "classic") -> Rendering:
    """Render ``scene`` from ``camera`` with the tile rasterizer.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        Non-empty.
    camera : Camera
    background : None, float or (3,) array
        Colour added with the final transmittance; ``None`` is black.
    mode : {"classic", "antialiased"}
        See the module docstring.

    Returns
    -------
    Rendering
        ``rgb`` (H, W, 3), ``alpha`` (H, W), ``depth`` (H, W) float32 and
        ``n_contrib`` (H, W) int32.
    """
    scene, frozen = check_inputs(scene, camera, mode)
    return _rasterize(scene, frozen, camera, background, mode, None, 0.0, build_w=False)[0]


def build_operator(scene, camera, scale: float = 1.0, roi=None, min_weight: float = 0.0,
                   mode: str = "classic", subset=None):
    """Rasterize once and return the view's linear operator.

    ``W[u, i] = alpha_i(u) T_i(u)`` (float32, CSR, int32 indices), so that a
    per-Gaussian quantity ``x`` (N,) composites as ``W @ x`` (pixels
    row-major, ``u = y * width + x``). With the rendering ``r`` of the same
    pass: ``W @ 1 == r.alpha``, ``W @ colors == r.rgb`` (black background)
    and ``W @ depths == r.depth * r.alpha``.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        Non-empty (a :class:`~.frozen.FrozenScene` reuses its activations).
    camera : Camera
    scale : float
        Resolution factor; the operator is built for ``camera.scaled(scale)``.
    roi : None, (x0, y0, x1, y1) or (H, W) bool array
        Pixels to composite, as a half-open integer box (clipped to the
        image; an error if no pixel is left) or a mask at the scaled
        resolution. ``W`` keeps all ``H*W`` rows so that it matches full
        masks; rows outside the roi are empty (they cost only ``indptr``),
        and the rendering is 0 there.
    min_weight : float
        Entries with ``w < min_weight`` are left out of ``W`` (the rendering
        keeps them). The identities then become bounds: per pixel
        ``0 <= alpha - W @ 1 <= k min_weight`` where k is the number of
        dropped entries, and likewise for any ``x`` in [0, 1]. ``0`` keeps
        every contributor.
    mode : {"classic", "antialiased"}
    subset : None, (M,) int array or (N,) bool array
        Rasterize only these Gaussians, as if the others were absent, with
        no copy of the scene; ``W`` still has one column per scene Gaussian
        (the others' columns are empty). Equal to building the operator of
        ``scene.subset(subset)`` and mapping its columns back to scene
        indices. Use it to leave out what cannot reach the view (culling).

    Returns
    -------
    ViewOperator
        ``W``, ``camera`` (the scaled one), ``image_shape`` and the
        ``rendering`` (black background) of the pass.
    """
    scene, frozen = check_inputs(scene, camera, mode)
    if not isinstance(scale, (int, float, np.integer, np.floating)) or isinstance(scale, bool):
        raise ValidationError(f"scale must be a positive number, got {scale!r}")
    mw = float(min_weight) if isinstance(min_weight, (int, float, np.integer, np.floating)) else np.nan
    if not (np.isfinite(mw) and 0.0 <= mw <= 1.0):
        raise ValidationError(f"min_weight must be a number in [0, 1], got {min_weight!r}")
    # the package's one rule for Gaussian selections: integer 0/1 labels (Gaussians 0 and 1 only) are refused
    idx = None if subset is None else support_indices(subset, len(scene), "subset")
    cam = camera if float(scale) == 1.0 else camera.scaled(scale)
    rendering, W = _rasterize(scene, frozen, cam, None, mode, roi, mw, build_w=True, subset=idx)
    return ViewOperator(W, cam, cam.image_shape, rendering)
