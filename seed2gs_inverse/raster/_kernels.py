"""Numba kernels of the tile rasterizer (private; use :mod:`seed2gs_inverse.raster`).

Three stages, each a kernel over plain arrays, plus the CSR assembly:

``project``     per Gaussian of an index list (parallel; a subset needs no
                copy of the scene): EWA projection, culling, conic, 3-sigma
                radius, tile rectangle (clipped to the roi's tiles), SH
                colour, effective opacity.
``bin_tiles``   Gaussians in (depth, index) order are appended to the list
                of every tile their rectangle covers (stable counting sort,
                parallel over chunks of the order, so each tile list stays
                in front-to-back order).
``composite``   per tile (parallel): front-to-back alpha compositing of the
                tile's pixels; logs the compositing weights
                ``alpha_i(u) T_i(u)`` per tile in a scratch, or (second
                pass, for tiles whose scratch ran out) writes them straight
                into CSR arrays.
``scatter``     per tile (parallel): copies a tile's logged weights into the
                CSR rows sized by the first pass.

``cone_cull`` (parallel) picks the Gaussians that can reach a view cone
(:func:`seed2gs_inverse.raster.cone_cull`).

All arithmetic is float64; the public wrapper converts outputs to float32.
Arguments are packed in the NamedTuples below. See
:mod:`seed2gs_inverse.raster.rasterize` for the exact semantics.

Entry points: ``activate``, ``project``, ``composite`` and ``cone_cull``
are plain Python functions that unpack the bundles and call one compiled
parallel kernel each. They are not cached ``@njit`` callers of the cached
kernels because Numba (0.68.1) can store such a caller against the callee's
code loaded from the cache, which then crashes (segmentation fault) every
later process that loads it: that happens when the caller is compiled while
the callee comes from the cache, e.g. two batch workers compiling at once on
a cold cache. Only inlined helpers (``inline="always"``) and intrinsics are
called from compiled code.

Projection (``_project``)
-------------------------
``idx`` (M,) int64 lists the scene rows to project (so a subset needs no
copy of the scene); output row ``i`` belongs to Gaussian ``idx[i]``, whose
:func:`activate` outputs (``mfac``, ``opac``, ``col0``) are at row
``act_rows[i]`` (so they can be computed once per scene, or per call).
Inputs are the raw scene means and SH (float32) and the camera (float64).
``tile_box`` (4,) int64 ``[tx0, ty0, tx1, ty1)``: only these tiles are
composited (the roi), so ``rects`` are clipped to them. Outputs
(preallocated, float64 unless noted): means2d (M,2), conics (M,3) (a, b, c
of the inverse 2D covariance), radii (M,) int32 (0 = culled), depths (M,)
view z, colors (M,3), opacities (M,) (times the antialiasing compensation),
support (M,3) and rects (M,4) int32:

``support`` = ``(pmin, hx, hy)``
    ``pmin = ln(1/(255 o)) - 1e-6``, below which ``o exp(power) < 1/255``
    for sure (so ``exp`` can be skipped; the margin leaves the exact test in
    charge), and the half-sizes of the bounding box of the ellipse
    ``d^T Q d <= 2 ln(255 o)`` (Q the conic), outside which the alpha test
    cannot pass: ``sqrt(k (Q^-1)_xx)``, ``sqrt(k (Q^-1)_yy)`` plus 1e-3 px
    for rounding.
``rects`` = ``[tx0, ty0, tx1, ty1)``
    the tiles the Gaussian is binned to, i.e. its getRect tile rectangle
    intersected with the tiles its support box touches and with
    ``tile_box``. In the other tiles of the getRect rectangle it would pass
    the alpha test at no pixel (or no pixel is composited), so leaving them
    out changes nothing but the work. Empty for culled Gaussians and for
    those with ``o < 1/255``, which can never pass the alpha test.
"""

from __future__ import annotations

import math
import os
import threading
import time
from typing import NamedTuple

# OpenMP threads (Numba's "omp" threading layer) that finish a parallel loop
# early sleep instead of spinning: a spinning waiter takes the core from the
# thread it waits for whenever other work shares the cores, and every view
# runs several parallel loops (benchmarks/bench_speed.py --competing-load
# prints the operators stage beside other work). A value the user set is
# kept; it is read when the OpenMP runtime loads, at the first parallel
# kernel, so it has no effect if another library loaded OpenMP before.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from llvmlite import ir  # noqa: E402
from numba import get_num_threads, njit, prange, types  # noqa: E402
from numba.core import cgutils  # noqa: E402
from numba.core import event as _numba_event  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

from ..progress import notice
from ..sh import SH_C0, SH_C1, SH_C2, SH_C3

TILE = 16
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
#: The dilation added to every projected 2D covariance (px^2), as in the reference rasterizer.
EPS2D = 0.3
T_MIN = 1e-4

# One source of the SH constants: seed2gs_inverse.sh (module-level floats are
# compile-time constants for Numba).
_C0 = SH_C0
_C1 = SH_C1
_C20, _C21, _C22, _C23, _C24 = SH_C2
_C30, _C31, _C32, _C33, _C34, _C35, _C36 = SH_C3


# -- dynamic scheduling -------------------------------------------------------
# Numba hands each thread one equal, contiguous share of a prange, so a thread
# the OS deschedules (other work on the cores) stalls the whole loop while the
# other threads sit idle. The tile loops below instead start one worker per
# thread, and each worker claims the next tile from a shared counter with an
# atomic fetch-and-add until none is left: a slowed thread just takes fewer
# tiles. The per-Gaussian loops (projection, culling) claim CHUNK Gaussians
# at a time the same way. Every tile and every Gaussian writes only its own
# outputs, so results do not depend on which thread took which.
@intrinsic
def _fetch_add(typingctx, counter, value):
    """``old = counter[0]; counter[0] += value; return old``, atomically (``counter``: (1,) int64)."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64):
        return None
    sig = types.int64(counter, types.int64)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [zero])
        return builder.atomic_rmw("add", ptr, args[1], "monotonic")

    return sig, codegen


# Per-Gaussian data is read in depth order, i.e. at random rows: each tile-Gaussian
# pair of the compositing loop (and each Gaussian of the binning) waited on a
# cache miss before its work. The loops ask for the rows PREFETCH items
# ahead; a prefetch only moves memory into the cache, so results are unchanged.
PREFETCH = 8


@intrinsic
def _prefetch(typingctx, arr, row):
    """Hint the CPU to bring ``arr[row, 0, ...]`` into the cache (``llvm.prefetch``; never faults, no result)."""
    if not (isinstance(arr, types.Array) and isinstance(row, types.Integer)):
        return None
    sig = types.void(arr, row)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = [context.cast(builder, args[1], signature.args[1], types.intp)]
        idx += [context.get_constant(types.intp, 0)] * (aryty.ndim - 1)
        ptr = cgutils.get_item_pointer2(context, builder, ary.data, cgutils.unpack_tuple(builder, ary.shape),
                                        cgutils.unpack_tuple(builder, ary.strides), aryty.layout, idx,
                                        wraparound=False, boundscheck=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0i8")
        # read (0), keep in all cache levels (3), data (1)
        builder.call(fn, [builder.bitcast(ptr, i8p), i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, inline="always")
def _tile_box(t, tiles_x, width, height):
    """Pixel box ``(x0, y0, x1, y1)`` (end exclusive, clipped to the image) of tile ``t``."""
    ty = t // tiles_x
    x0 = (t - ty * tiles_x) * TILE
    y0 = ty * TILE
    return x0, y0, min(x0 + TILE, width), min(y0 + TILE, height)


def workers(n_items: int) -> int:
    """Workers for a loop over ``n_items``: one per Numba thread, at most one per item.

    Asked in Python and passed to the kernels: ``get_num_threads`` inside a
    kernel would keep it out of the on-disk cache.
    """
    return max(1, min(get_num_threads(), int(n_items)))


#: Items a worker claims at a time in the per-Gaussian loops (projection,
#: culling): small enough that a descheduled thread leaves little behind,
#: large enough that claiming costs nothing beside the work.
CHUNK = 1024


def chunk_workers(n_items: int) -> int:
    """:func:`workers` for a loop over ``n_items`` claimed :data:`CHUNK` at a time."""
    return workers(-(-int(n_items) // CHUNK))


# -- argument bundles (Numba passes NamedTuples of arrays and scalars as typed tuples) --
class Activations(NamedTuple):
    """View-independent quantities of :func:`activate`, one row per Gaussian activated."""

    mfac: np.ndarray   # (M, 9) float64 covariance factor R(q) diag(s), row-major
    opac: np.ndarray   # (M,) float64 sigmoid of the opacity logit
    col0: np.ndarray   # (M, 3) float64 SH-0 colour, or (0, 3) when the scene has higher SH


class CameraParams(NamedTuple):
    """A camera as plain numbers: world-to-camera ``rot``/``trans``, centre, intrinsics."""

    rot: np.ndarray     # (3, 3) float64
    trans: np.ndarray   # (3,) float64
    center: np.ndarray  # (3,) float64
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float


class Splats(NamedTuple):
    """Per-Gaussian screen-space outputs of :func:`project`, inputs of :func:`composite`."""

    means2d: np.ndarray    # (M, 2) float64
    conics: np.ndarray     # (M, 3) float64
    radii: np.ndarray      # (M,) int32
    depths: np.ndarray     # (M,) float64
    colors: np.ndarray     # (M, 3) float64
    opacities: np.ndarray  # (M,) float64
    support: np.ndarray    # (M, 3) float64
    rects: np.ndarray      # (M, 4) int32


class TileLists(NamedTuple):
    """Tile lists of :func:`bin_tiles` and the order in which tiles are visited."""

    tile_start: np.ndarray  # (n_tiles+1,) int64
    tile_gauss: np.ndarray  # (pairs,) int32
    tile_order: np.ndarray  # (n,) int64 tiles to composite


class Image(NamedTuple):
    """Per-pixel outputs of :func:`composite`."""

    rgb: np.ndarray        # (H, W, 3) float32
    alpha: np.ndarray      # (H, W) float32
    depth: np.ndarray      # (H, W) float32
    n_contrib: np.ndarray  # (H, W) int32
    n_kept: np.ndarray     # (H*W,) int64


class CSR(NamedTuple):
    """Arrays of the operator W being filled."""

    indptr: np.ndarray   # (H*W+1,) int64
    indices: np.ndarray  # (nnz,) int32
    data: np.ndarray     # (nnz,) float32


class Scratch(NamedTuple):
    """Per-tile log of the first compositing pass (see :func:`composite`)."""

    start: np.ndarray  # (n_tiles+1,) int64
    pix: np.ndarray    # int16 local pixel
    gi: np.ndarray     # int32 Gaussian row
    w: np.ndarray      # float32 weight
    used: np.ndarray   # (n_tiles,) int64 entries logged, -1 on overflow


@njit(cache=True, inline="always")
def _sh_basis(x, y, z, k, out):
    """Real SH basis (3DGS ordering and signs) at unit direction, first k terms."""
    out[0] = _C0
    if k > 1:
        out[1] = -_C1 * y
        out[2] = _C1 * z
        out[3] = -_C1 * x
    if k > 4:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = _C20 * x * y
        out[5] = _C21 * y * z
        out[6] = _C22 * (2.0 * zz - xx - yy)
        out[7] = _C23 * x * z
        out[8] = _C24 * (xx - yy)
        if k > 9:
            out[9] = _C30 * y * (3.0 * xx - yy)
            out[10] = _C31 * x * y * z
            out[11] = _C32 * y * (4.0 * zz - xx - yy)
            out[12] = _C33 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
            out[13] = _C34 * x * (4.0 * zz - xx - yy)
            out[14] = _C35 * z * (xx - yy)
            out[15] = _C36 * x * (xx - 3.0 * yy)


@njit(cache=True, inline="always")
def _jacobian_limits(width, height, fx, fy, cx, cy):
    """Bounds ``(x+, x-, y+, y-)`` of ``x/z`` and ``y/z`` at which the EWA Jacobian is evaluated: the
    image's extent plus 0.3 of the half field of view on each side (gsplat's persp_proj)."""
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    return (width - cx) / fx + 0.3 * tan_fovx, cx / fx + 0.3 * tan_fovx, \
        (height - cy) / fy + 0.3 * tan_fovy, cy / fy + 0.3 * tan_fovy


@njit(cache=True, inline="always")
def _clamp_floor(v, hi):
    """``floor(v)`` clamped to [0, hi], safe for huge or NaN ``v`` (gives 0)."""
    if not v > 0.0:
        return 0
    if v >= hi:
        return hi
    return int(math.floor(v))


def activate(idx, quats, log_scales, opacity_logits, sh, act):
    """:func:`_activate` with its outputs in ``act`` (:class:`Activations`)."""
    mfac, opac, col0 = act
    _activate(idx, quats, log_scales, opacity_logits, sh, mfac, opac, col0)


@njit(cache=True, parallel=True)
def _activate(idx, quats, log_scales, opacity_logits, sh, mfac, opac, col0):
    """View-independent quantities of the Gaussians ``idx`` (parallel).

    Row ``i`` of the outputs belongs to Gaussian ``idx[i]``: ``mfac`` (M, 9)
    the covariance factor ``M = R(q/|q|) diag(exp(log_scales))`` row-major
    (``Sigma = M M^T``), ``opac`` (M,) the sigmoid of the logit, and for SH
    degree 0 (``col0`` of M rows; pass 0 rows otherwise) the colour
    ``max(C0 sh_0 + 0.5, 0)``, which then needs no view direction.
    """
    for i in prange(idx.shape[0]):
        g = idx[i]
        opac[i] = 1.0 / (1.0 + math.exp(-np.float64(opacity_logits[g])))
        if col0.shape[0] > 0:
            # The basis sum of ``project`` for k = 1, same arithmetic.
            for ch in range(3):
                col0[i, ch] = max(_C0 * sh[g, 0, ch] + 0.5, 0.0)
        qw = np.float64(quats[g, 0])
        qx = np.float64(quats[g, 1])
        qy = np.float64(quats[g, 2])
        qz = np.float64(quats[g, 3])
        qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw /= qn
        qx /= qn
        qy /= qn
        qz /= qn
        s0 = math.exp(np.float64(log_scales[g, 0]))
        s1 = math.exp(np.float64(log_scales[g, 1]))
        s2 = math.exp(np.float64(log_scales[g, 2]))
        mfac[i, 0] = (1.0 - 2.0 * (qy * qy + qz * qz)) * s0
        mfac[i, 1] = 2.0 * (qx * qy - qw * qz) * s1
        mfac[i, 2] = 2.0 * (qx * qz + qw * qy) * s2
        mfac[i, 3] = 2.0 * (qx * qy + qw * qz) * s0
        mfac[i, 4] = (1.0 - 2.0 * (qx * qx + qz * qz)) * s1
        mfac[i, 5] = 2.0 * (qy * qz - qw * qx) * s2
        mfac[i, 6] = 2.0 * (qx * qz - qw * qy) * s0
        mfac[i, 7] = 2.0 * (qy * qz + qw * qx) * s1
        mfac[i, 8] = (1.0 - 2.0 * (qx * qx + qy * qy)) * s2


@njit(cache=True, inline="always")
def _view_color(i, g, a_row, px, py, pz, center, k, sh, col0, colors):
    """``colors[i]`` of Gaussian ``g`` at ``(px, py, pz)`` seen from ``center``: ``max(eval_sh + 0.5, 0)``
    with the first ``k`` SH terms, or the view-independent ``col0[a_row]`` when given (SH degree 0)."""
    if col0.shape[0] > 0:
        for ch in range(3):
            colors[i, ch] = col0[a_row, ch]
        return
    basis = np.empty(16)
    dx = px - center[0]
    dy = py - center[1]
    dz = pz - center[2]
    nrm = math.sqrt(dx * dx + dy * dy + dz * dz)
    if nrm > 0.0:
        dx /= nrm
        dy /= nrm
        dz /= nrm
    _sh_basis(dx, dy, dz, k, basis)
    for ch in range(3):
        acc = 0.0
        for j in range(k):
            acc += basis[j] * sh[g, j, ch]
        colors[i, ch] = max(acc + 0.5, 0.0)


def project(idx, act_rows, means, sh, act, cam, eps2d, antialiased, tile_box, out):
    """:func:`_project` with the activations ``act`` (:class:`Activations`), the camera
    ``cam`` (:class:`CameraParams`) and the outputs ``out`` (:class:`Splats`) bundled.

    The bundles are unpacked here, in Python (see the module docstring), and
    not inside the parallel loop: writes through arrays unpacked from a
    tuple inside a ``prange`` kernel are lost (Numba 0.68.1 parfor
    lowering leaves the outputs uninitialised).
    """
    mfac, opac, col0 = act
    rot, trans, center, fx, fy, cx, cy, width, height, near = cam
    means2d, conics, radii, depths, colors, opacities, support, rects = out
    _project(idx, act_rows, means, mfac, opac, col0, sh, rot, trans, center,
             fx, fy, cx, cy, width, height, near, eps2d, antialiased, tile_box,
             means2d, conics, radii, depths, colors, opacities, support, rects, chunk_workers(idx.shape[0]))


@njit(cache=True, parallel=True)
def _project(idx, act_rows, means, mfac, opac, col0, sh, rot, trans, center,
             fx, fy, cx, cy, width, height, near, eps2d, antialiased, tile_box,
             means2d, conics, radii, depths, colors, opacities, support, rects, n_workers):
    """Project the Gaussians ``idx`` (module docstring, "Projection"; maths in ``project_gaussians``).

    ``n_workers``: :func:`chunk_workers` of ``idx``'s length (dynamic scheduling by chunks).
    """
    n = idx.shape[0]
    k = sh.shape[1]
    tiles_x = (width + TILE - 1) // TILE
    tiles_y = (height + TILE - 1) // TILE
    lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg = _jacobian_limits(width, height, fx, fy, cx, cy)
    claimed = np.zeros(1, np.int64)  # items handed out so far (_fetch_add)
    for _worker in prange(n_workers):
        while True:
            first = _fetch_add(claimed, CHUNK)
            if first >= n:
                break
            for i in range(first, min(first + CHUNK, n)):
                g = idx[i]
                px = np.float64(means[g, 0])
                py = np.float64(means[g, 1])
                pz = np.float64(means[g, 2])
                x = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz + trans[0]
                y = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz + trans[1]
                z = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz + trans[2]
                depths[i] = z

                a_row = act_rows[i]
                # View-dependent colour, for every Gaussian (callers use it for W @ colors).
                _view_color(i, g, a_row, px, py, pz, center, k, sh, col0, colors)

                opacities[i] = opac[a_row]
                radii[i] = 0
                means2d[i, 0] = 0.0
                means2d[i, 1] = 0.0
                conics[i, 0] = 0.0
                conics[i, 1] = 0.0
                conics[i, 2] = 0.0
                for j in range(4):
                    rects[i, j] = 0
                for j in range(3):
                    support[i, j] = 0.0
                if not z >= near:  # also rejects NaN
                    continue

                # World covariance Sigma = M M^T with M = R(q) diag(s).
                m00 = mfac[a_row, 0]
                m01 = mfac[a_row, 1]
                m02 = mfac[a_row, 2]
                m10 = mfac[a_row, 3]
                m11 = mfac[a_row, 4]
                m12 = mfac[a_row, 5]
                m20 = mfac[a_row, 6]
                m21 = mfac[a_row, 7]
                m22 = mfac[a_row, 8]

                # EWA Jacobian, with the view-space x/y clamped to 1.3 times the field of
                # view so Gaussians far outside the image do not blow up (gsplat persp_proj).
                tx = z * min(lim_x_pos, max(-lim_x_neg, x / z))
                ty = z * min(lim_y_pos, max(-lim_y_neg, y / z))
                j00 = fx / z
                j02 = -fx * tx / (z * z)
                j11 = fy / z
                j12 = -fy * ty / (z * z)
                # T = J R_cam (2x3); cov2d = (T M)(T M)^T.
                t00 = j00 * rot[0, 0] + j02 * rot[2, 0]
                t01 = j00 * rot[0, 1] + j02 * rot[2, 1]
                t02 = j00 * rot[0, 2] + j02 * rot[2, 2]
                t10 = j11 * rot[1, 0] + j12 * rot[2, 0]
                t11 = j11 * rot[1, 1] + j12 * rot[2, 1]
                t12 = j11 * rot[1, 2] + j12 * rot[2, 2]
                u0 = t00 * m00 + t01 * m10 + t02 * m20
                u1 = t00 * m01 + t01 * m11 + t02 * m21
                u2 = t00 * m02 + t01 * m12 + t02 * m22
                v0 = t10 * m00 + t11 * m10 + t12 * m20
                v1 = t10 * m01 + t11 * m11 + t12 * m21
                v2 = t10 * m02 + t11 * m12 + t12 * m22
                a = u0 * u0 + u1 * u1 + u2 * u2
                b = u0 * v0 + u1 * v1 + u2 * v2
                c = v0 * v0 + v1 * v1 + v2 * v2
                det_orig = a * c - b * b
                a += eps2d
                c += eps2d
                det = a * c - b * b
                if not det > 0.0:
                    continue
                if antialiased:
                    opacities[i] *= math.sqrt(max(0.0, det_orig / det))
                mid = 0.5 * (a + c)
                lam = mid + math.sqrt(max(0.01, mid * mid - det))
                # Float ceil, capped so the int32 radius cannot overflow.
                radius = min(np.ceil(3.0 * math.sqrt(lam)), 2.0e9)
                mx = fx * x / z + cx
                my = fy * y / z + cy
                # Tile rectangle of [mean - r, mean + r] as getRect of the reference code.
                rx0 = _clamp_floor((mx - radius) / TILE, tiles_x)
                ry0 = _clamp_floor((my - radius) / TILE, tiles_y)
                rx1 = _clamp_floor((mx + radius + TILE - 1) / TILE, tiles_x)
                ry1 = _clamp_floor((my + radius + TILE - 1) / TILE, tiles_y)
                if rx1 <= rx0 or ry1 <= ry0:
                    continue
                radii[i] = np.int32(radius)
                means2d[i, 0] = mx
                means2d[i, 1] = my
                ca = c / det
                cb = -b / det
                cc = a / det
                conics[i, 0] = ca
                conics[i, 1] = cb
                conics[i, 2] = cc
                o = opacities[i]
                if not o >= ALPHA_MIN:
                    continue
                pmin = math.log(ALPHA_MIN / o) - 1e-6
                kq = max(0.0, -2.0 * pmin) / (ca * cc - cb * cb)
                # Capped so that pixel bounds computed from them stay sane integers.
                hx = min(math.sqrt(kq * cc) + 1e-3, 1e9)
                hy = min(math.sqrt(kq * ca) + 1e-3, 1e9)
                support[i, 0] = pmin
                support[i, 1] = hx
                support[i, 2] = hy
                # Pixels whose centre can lie in the support box, then their tiles.
                sx0 = _clamp_floor(np.ceil(mx - hx - 0.5) / TILE, tiles_x)
                sx1 = _clamp_floor(np.floor(mx + hx - 0.5) / TILE, tiles_x - 1) + 1
                sy0 = _clamp_floor(np.ceil(my - hy - 0.5) / TILE, tiles_y)
                sy1 = _clamp_floor(np.floor(my + hy - 0.5) / TILE, tiles_y - 1) + 1
                rx0 = max(rx0, sx0, tile_box[0])
                rx1 = min(rx1, sx1, tile_box[2])
                ry0 = max(ry0, sy0, tile_box[1])
                ry1 = min(ry1, sy1, tile_box[3])
                if rx1 <= rx0 or ry1 <= ry0:
                    continue
                rects[i, 0] = rx0
                rects[i, 1] = ry0
                rects[i, 2] = rx1
                rects[i, 3] = ry1


@njit(cache=True, parallel=True)
def bin_tiles(order, rects, tiles_x, n_tiles):
    """Tile lists by a parallel counting sort.

    ``order`` lists the Gaussians to bin in front-to-back order. Returns
    ``tile_start`` (n_tiles+1,) int64 and ``tile_gauss`` (M,) int32 where tile
    t owns ``tile_gauss[tile_start[t]:tile_start[t+1]]``, still in that order:
    ``order`` is cut into consecutive chunks, each chunk counts its entries
    per tile, and chunk c writes after chunks 0..c-1 in every tile, walking
    its part of ``order`` sequentially (so the scatter is stable).
    """
    n = order.shape[0]
    n_chunks = max(1, min(32, n // 16384))
    counts = np.zeros((n_chunks, n_tiles), np.int64)
    for c in prange(n_chunks):
        end = (c + 1) * n // n_chunks
        for k in range(c * n // n_chunks, end):
            g = order[k]
            if k + PREFETCH < end:  # rows in depth order: random (see PREFETCH)
                _prefetch(rects, order[k + PREFETCH])
            for ty in range(rects[g, 1], rects[g, 3]):
                for tx in range(rects[g, 0], rects[g, 2]):
                    counts[c, ty * tiles_x + tx] += 1
    tile_start = np.zeros(n_tiles + 1, np.int64)
    for t in range(n_tiles):
        tot = tile_start[t]
        for c in range(n_chunks):
            cnt = counts[c, t]
            counts[c, t] = tot  # now chunk c's first slot in tile t
            tot += cnt
        tile_start[t + 1] = tot
    tile_gauss = np.empty(tile_start[n_tiles], np.int32)
    for c in prange(n_chunks):
        cursor = counts[c]
        end = (c + 1) * n // n_chunks
        for k in range(c * n // n_chunks, end):
            g = order[k]
            if k + PREFETCH < end:
                _prefetch(rects, order[k + PREFETCH])
            for ty in range(rects[g, 1], rects[g, 3]):
                for tx in range(rects[g, 0], rects[g, 2]):
                    t = ty * tiles_x + tx
                    tile_gauss[cursor[t]] = g
                    cursor[t] += 1
    return tile_start, tile_gauss


def composite(tiles, splats, width, height, roi, background, min_weight, fill, gid, img, csr, scr, tile_evals,
              n_workers):
    """Front-to-back compositing of every tile (parallel over tiles).

    For pixel centre ``p = (x + 0.5, y + 0.5)`` and each Gaussian g of the
    tile's list in order: ``d = mean2d_g - p``, ``power = -(a dx^2 + c dy^2)/2
    - b dx dy``; skip ``power > 0``; ``alpha = min(0.99, o exp(power))``; skip
    ``alpha < 1/255``; stop (without adding g) when ``T (1 - alpha) < 1e-4``;
    else weight ``w = alpha T``, accumulate, ``T *= 1 - alpha``.

    The loop is Gaussian-major inside a tile: each Gaussian visits only the
    tile pixels inside the ellipse where ``o exp(power) >= 1/255`` can hold
    (its bounding box, with a margin so the exact tests above decide), and a
    pixel that stopped is skipped. Every pixel still sees its Gaussians in
    list order, so the result is that of the per-pixel walk.

    ``roi`` (H, W) uint8: pixels where it is 0 are not composited (all
    outputs 0). ``n_contrib`` counts all contributors, ``n_kept`` (H*W,)
    those with ``w >= min_weight``. With ``fill`` (second pass) the kept
    weights go to ``indices[indptr[u]:...]`` / ``data`` in compositing
    order; ``indptr`` must then be the cumulative sum of the first pass's
    ``n_kept`` and ``n_contrib`` its output, which is read (a pixel stops
    after its last contributor) and not written, nor are rgb, alpha, depth
    and n_kept.
    ``gid`` (M,) int64 maps the kernel's Gaussian rows to the column
    indices written to ``indices``.

    Scratch (first pass only), so that W can usually be assembled without
    the second pass: tile t may log its kept weights, in compositing order,
    in ``scr_pix`` (local pixel, int16), ``scr_gi`` (Gaussian row, int32)
    and ``scr_w`` (float32) at ``[scr_start[t], scr_start[t+1])``;
    ``scr_used[t]`` receives the number logged, or -1 when the room ran out
    (that tile then needs the second pass). Pass ``scr_start`` all zeros to
    log nothing.
    ``tile_evals`` (n_tiles,) int64 receives the number of Gaussian-pixel
    evaluations (power computed) per tile, for benchmarks. ``n_workers``:
    :func:`workers` of the number of tiles (dynamic scheduling, see
    :func:`_fetch_add`).

    Bundles: ``tiles`` :class:`TileLists` (the tiles to visit), ``splats``
    :class:`Splats` (projection), ``img`` :class:`Image` (rgb, alpha, depth,
    n_contrib, n_kept), ``csr`` :class:`CSR` (indptr, indices, data) and
    ``scr`` :class:`Scratch` (scr_start, scr_pix, scr_gi, scr_w, scr_used).
    """
    # Unpacked here, in Python, as in project().
    tile_start, tile_gauss, tile_order = tiles
    means2d, conics, _radii, depths, colors, opacities, support, _rects = splats
    rgb, alpha, depth, n_contrib, n_kept = img
    indptr, indices, data = csr
    scr_start, scr_pix, scr_gi, scr_w, scr_used = scr
    _composite_tiles(tile_start, tile_gauss, tile_order, means2d, conics, opacities, support, colors, depths,
                     width, height, roi, background, min_weight, fill, gid,
                     rgb, alpha, depth, n_contrib, n_kept, indptr, indices, data,
                     scr_start, scr_pix, scr_gi, scr_w, scr_used, tile_evals, n_workers)


@njit(cache=True, parallel=True)
def _composite_tiles(tile_start, tile_gauss, tile_order, means2d, conics, opacities, support, colors, depths,
                     width, height, roi, background, min_weight, fill, gid,
                     rgb, alpha, depth, n_contrib, n_kept, indptr, indices, data,
                     scr_start, scr_pix, scr_gi, scr_w, scr_used, tile_evals, n_workers):
    """The parallel loop of :func:`composite` (same arguments, unpacked)."""
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = tile_order.shape[0]
    claimed = np.zeros(1, np.int64)  # items handed out so far (_fetch_add)
    for _worker in prange(n_workers):
        while True:
            it = _fetch_add(claimed, 1)
            if it >= n_tiles:
                break
            t = tile_order[it]
            x0, y0, x1, y1 = _tile_box(t, tiles_x, width, height)
            tw = x1 - x0
            npix = tw * (y1 - y0)
            # Per-pixel state of the tile, local index (y - y0) * tw + (x - x0).
            T = np.ones(npix)
            acc = np.zeros((npix, 4))  # r, g, b, depth
            cnt = np.zeros(npix, np.int64)
            kept = np.zeros(npix, np.int64)
            cursor = np.zeros(npix, np.int64)
            done = np.zeros(npix, np.bool_)
            n_done = 0
            n_eval = 0
            sp = scr_start[t]
            sp_end = scr_start[t + 1]
            overflow = False
            for yy in range(y0, y1):
                for xx in range(x0, x1):
                    lp = (yy - y0) * tw + (xx - x0)
                    if not roi[yy, xx]:
                        done[lp] = True
                        n_done += 1
                    elif fill:
                        cursor[lp] = indptr[yy * width + xx]
                        # The first pass counted this pixel's contributors: stop
                        # right after the last one instead of scanning the rest.
                        if n_contrib[yy, xx] == 0:
                            done[lp] = True
                            n_done += 1
            s = tile_start[t]
            e = tile_start[t + 1]
            j = s
            while j < e and n_done < npix:
                gi = tile_gauss[j]
                if j + PREFETCH < e:
                    ahead = tile_gauss[j + PREFETCH]
                    _prefetch(means2d, ahead)
                    _prefetch(support, ahead)
                    _prefetch(conics, ahead)
                    _prefetch(opacities, ahead)
                    _prefetch(colors, ahead)
                    _prefetch(depths, ahead)
                j += 1
                mx = means2d[gi, 0]
                my = means2d[gi, 1]
                ca = conics[gi, 0]
                cb = conics[gi, 1]
                cc = conics[gi, 2]
                o = opacities[gi]
                pmin = support[gi, 0]
                hx = support[gi, 1]
                hy = support[gi, 2]
                # Clamped as floats first: int() of a huge float is undefined.
                bx0 = int(max(float(x0), np.ceil(mx - hx - 0.5)))
                bx1 = int(min(float(x1), np.floor(mx + hx - 0.5) + 1.0))
                by0 = int(max(float(y0), np.ceil(my - hy - 0.5)))
                by1 = int(min(float(y1), np.floor(my + hy - 0.5) + 1.0))
                if bx0 >= bx1 or by0 >= by1:
                    continue
                cr = colors[gi, 0]
                cg = colors[gi, 1]
                cbl = colors[gi, 2]
                z = depths[gi]
                for yy in range(by0, by1):
                    dy = my - (yy + 0.5)
                    for xx in range(bx0, bx1):
                        lp = (yy - y0) * tw + (xx - x0)
                        if done[lp]:
                            continue
                        n_eval += 1
                        dx = mx - (xx + 0.5)
                        power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                        if power > 0.0 or power < pmin:
                            continue
                        a = min(ALPHA_MAX, o * math.exp(power))
                        if a < ALPHA_MIN:
                            continue
                        tp = T[lp]
                        nt = tp * (1.0 - a)
                        if nt < T_MIN:
                            done[lp] = True
                            n_done += 1
                            continue
                        w = a * tp
                        acc[lp, 0] += w * cr
                        acc[lp, 1] += w * cg
                        acc[lp, 2] += w * cbl
                        acc[lp, 3] += w * z
                        cnt[lp] += 1
                        if w >= min_weight:
                            if fill:
                                indices[cursor[lp]] = gid[gi]
                                data[cursor[lp]] = w
                                cursor[lp] += 1
                            elif sp < sp_end:
                                scr_pix[sp] = lp
                                scr_gi[sp] = gi
                                scr_w[sp] = w
                                sp += 1
                            else:
                                overflow = True
                            kept[lp] += 1
                        T[lp] = nt
                        if fill and cnt[lp] == n_contrib[yy, xx]:
                            done[lp] = True
                            n_done += 1
            tile_evals[t] = n_eval
            if fill:
                continue
            scr_used[t] = -1 if overflow else sp - scr_start[t]
            for yy in range(y0, y1):
                for xx in range(x0, x1):
                    if not roi[yy, xx]:
                        continue
                    lp = (yy - y0) * tw + (xx - x0)
                    tp = T[lp]
                    al = 1.0 - tp
                    rgb[yy, xx, 0] = acc[lp, 0] + tp * background[0]
                    rgb[yy, xx, 1] = acc[lp, 1] + tp * background[1]
                    rgb[yy, xx, 2] = acc[lp, 2] + tp * background[2]
                    alpha[yy, xx] = al
                    depth[yy, xx] = acc[lp, 3] / al if cnt[lp] > 0 else 0.0
                    n_contrib[yy, xx] = cnt[lp]
                    n_kept[yy * width + xx] = kept[lp]


@njit(cache=True, parallel=True)
def scatter(tiles, lo, hi, width, height, scr_pix, scr_gi, scr_w, gid, indptr, indices, data, n_workers):
    """CSR fill from the first compositing pass's scratch (parallel over tiles).

    Tile ``tiles[j]`` logged its entries at ``[lo[j], hi[j])`` of ``scr_*``
    (see :func:`composite`); they go to the rows of their pixels in logged
    order, which is compositing order: ``indices = gid[scr_gi]``,
    ``data = scr_w``, row ``u`` starting at ``indptr[u]``. ``n_workers``:
    :func:`workers` of the number of tiles.
    """
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = tiles.shape[0]
    claimed = np.zeros(1, np.int64)  # items handed out so far (_fetch_add)
    for _worker in prange(n_workers):
        while True:
            it = _fetch_add(claimed, 1)
            if it >= n_tiles:
                break
            x0, y0, x1, y1 = _tile_box(tiles[it], tiles_x, width, height)
            tw = x1 - x0
            th = y1 - y0
            cursor = np.empty(tw * th, np.int64)
            for yy in range(th):
                for xx in range(tw):
                    cursor[yy * tw + xx] = indptr[(y0 + yy) * width + x0 + xx]
            for e in range(lo[it], hi[it]):
                lp = scr_pix[e]
                c = cursor[lp]
                indices[c] = gid[scr_gi[e]]
                data[c] = scr_w[e]
                cursor[lp] = c + 1


def cone_cull(means, rows, cam, roi, sigma3, eps2d, axis, far, cut, spare, keep):
    """:func:`_cone_cull` with the camera ``cam`` (:class:`CameraParams`) bundled."""
    _cone_cull(means, rows, cam.rot, cam.trans, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, cam.near,
               roi, sigma3, eps2d, axis, far, cut, spare, keep, chunk_workers(keep.shape[0]))


@njit(cache=True, parallel=True)
def _cone_cull(means, rows, rot, trans, fx, fy, cx, cy, width, height, near, roi, sigma3, eps2d, axis, far, cut,
               spare, keep, n_workers):
    """Gaussians whose screen footprint in :func:`_project` can reach the pixel box ``roi`` (parallel).

    ``keep[k]`` is the test of Gaussian ``rows[k]`` (``rows``: int64 scene
    rows, read where the kernel tests them, so the caller gathers no copy of
    their means), or of Gaussian ``k`` when ``rows`` is empty (every row).

    With ``smax[i] = sigma3[i] / 3`` (``sigma3``: the 3-sigma sizes of
    :func:`~seed2gs_inverse.raster.frozen.sigma3`) and ``v = R x + t`` (view
    frame), ``keep[i]`` requires ``v_z >= near``
    (the projection's own test), ``v . axis - 3 smax[i] <= far``, ``v . axis
    >= cut`` unless ``spare[i]`` (``spare``: (N,) bool, or (0,) for none;
    ``cut = -inf`` for no cut) and the
    square of half-size ``r`` around the projected centre ``m`` meeting
    ``roi = (x0, y0, x1, y1)``: ``m_x + r >= x0`` and ``m_x - r <= x1``
    (and in y). ``r = sqrt(2 ln 255) sqrt(lam) + 2`` px bounds both the
    projection's radius ``ceil(3 sqrt(lam2d))`` and its support box
    (``o exp(power) >= 1/255`` needs ``d^T Q d <= 2 ln 255``), because the
    2D covariance ``J R Sigma R^T J^T + eps2d I`` has its largest eigenvalue
    ``lam2d <= lam = lmax(J J^T) smax^2 + eps2d`` (``Sigma``'s largest
    eigenvalue is ``smax^2``; ``J`` the same clamped EWA Jacobian).
    ``n_workers``: :func:`chunk_workers` of N (dynamic scheduling by chunks).
    """
    lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg = _jacobian_limits(width, height, fx, fy, cx, cy)
    k_support = math.sqrt(2.0 * math.log(255.0))
    n_items = keep.shape[0]
    some = rows.shape[0] > 0
    claimed = np.zeros(1, np.int64)  # items handed out so far (_fetch_add)
    for _worker in prange(n_workers):
        while True:
            first = _fetch_add(claimed, CHUNK)
            if first >= n_items:
                break
            for k in range(first, min(first + CHUNK, n_items)):
                i = rows[k] if some else k
                px = np.float64(means[i, 0])
                py = np.float64(means[i, 1])
                pz = np.float64(means[i, 2])
                x = px * rot[0, 0] + py * rot[0, 1] + pz * rot[0, 2] + trans[0]
                y = px * rot[1, 0] + py * rot[1, 1] + pz * rot[1, 2] + trans[1]
                z = px * rot[2, 0] + py * rot[2, 1] + pz * rot[2, 2] + trans[2]
                keep[k] = False
                if not z >= near:  # also rejects NaN
                    continue
                t_a = x * axis[0] + y * axis[1] + z * axis[2]
                smax = sigma3[i] / 3.0
                if not t_a - 3.0 * smax <= far:
                    continue
                if t_a < cut and not (spare.shape[0] > 0 and spare[i]):
                    continue
                tx = min(lim_x_pos, max(-lim_x_neg, x / z))
                ty = min(lim_y_pos, max(-lim_y_neg, y / z))
                # J J^T = [[a, b], [b, c]] for J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]].
                a = (fx / z) ** 2 * (1.0 + tx * tx)
                c = (fy / z) ** 2 * (1.0 + ty * ty)
                b = (fx / z) * (fy / z) * tx * ty
                mid = 0.5 * (a + c)
                lmax = mid + math.sqrt(max(mid * mid - (a * c - b * b), 0.0))
                r = k_support * math.sqrt(lmax * smax * smax + eps2d) + 2.0
                mx = fx * x / z + cx
                my = fy * y / z + cy
                keep[k] = mx + r >= roi[0] and mx - r <= roi[2] and my + r >= roi[1] and my - r <= roi[3]


# -- compilation, said once ----------------------------------------------------
# Every kernel above is compiled on first use and cached on disk (``cache=True``: the
# ``__pycache__`` next to this file, or Numba's user-wide cache directory when that is not
# writable, or ``$NUMBA_CACHE_DIR``), so a user compiles them once per installation.
#: The compiled kernels, each called from Python (the helpers they call are inlined).
ENTRY_KERNELS = (_activate, _project, bin_tiles, _composite_tiles, scatter, _cone_cull)
#: What a render or an operator build runs (the culling kernel runs only in extract and point prompts).
RENDER_KERNELS = ENTRY_KERNELS[:5]
#: Seconds a cold compilation of all of them takes on a quiet 2-core machine (the CHANGELOG
#: has the measurements). Said, not measured, at run time.
COMPILE_SECONDS = 20
_announced = set()  # names of the entry kernels whose compilation was announced (or not needed)


def kernels_cached():
    """Whether every entry kernel has a compiled version in Numba's on-disk cache.

    Cheap: reads each kernel's small index file (Numba drops an index whose
    source stamp or Numba version differs). ``None`` when Numba's cache
    internals cannot be read (then nothing is announced).
    """
    cold = _cold_kernels()
    return None if cold is None else not cold


def _cold_kernels():
    """Names of the entry kernels without a cached compiled version (None: unknown)."""
    try:
        return [k.py_func.__name__ for k in ENTRY_KERNELS if not k._cache._cache_file._load_index()]
    except Exception:  # noqa: BLE001 - private Numba API: any failure means "unknown"
        return None


def announce_compilation(kernels=ENTRY_KERNELS) -> bool:
    """Before a call of ``kernels`` (entry kernels): say on stderr which of them compile, when any is cold.

    Prints ``seed2gs: compiling the rasterizer kernels (k of 6), once
    (cached for later runs), up to about N s`` through the run's feedback
    (:func:`~seed2gs_inverse.progress.notice`: nothing in a quiet run), at
    most once per kernel and process, counting only the cold ``kernels``
    about to run: a render does not announce the culling kernel that only
    ``extract`` compiles. Returns whether it was due (also when a quiet run
    kept it silent).
    """
    names = {k.py_func.__name__ for k in kernels}
    todo = names - _announced
    if not todo:
        return False
    _announced.update(todo)
    cold = _cold_kernels()
    if cold is None:  # Numba's cache internals unreadable: say nothing
        return False
    n_cold = len(set(cold) & todo)
    if not n_cold:
        return False
    notice(f"compiling the rasterizer kernels ({n_cold} of {len(ENTRY_KERNELS)}), once (cached for later runs), "
           f"up to about {COMPILE_SECONDS} s")
    return True


class _CompileClock(_numba_event.Listener):
    """Seconds each thread spent in Numba compilations (outermost ``numba:compile`` events).

    Numba raises the event only for a real compilation, not for a load from
    its on-disk cache; a compilation nested in another (a callee typed while
    its caller compiles) is counted once, within the outer one.
    """

    def __init__(self):
        self._local = threading.local()

    def on_start(self, event) -> None:
        loc = self._local
        depth = getattr(loc, "depth", 0)
        if depth == 0:
            loc.t0 = time.perf_counter()
        loc.depth = depth + 1

    def on_end(self, event) -> None:
        loc = self._local
        loc.depth -= 1
        if loc.depth == 0:
            loc.total = getattr(loc, "total", 0.0) + time.perf_counter() - loc.t0

    def seconds(self) -> float:
        return getattr(self._local, "total", 0.0)


_COMPILE_CLOCK = _CompileClock()
_numba_event.register("numba:compile", _COMPILE_CLOCK)


def compile_seconds() -> float:
    """Seconds the calling thread has spent compiling Numba functions so far in this process.

    A clock for :class:`~seed2gs_inverse.progress.StageTimer`: the
    difference over a stage is the compilation it contained (0 when every
    kernel came from the on-disk cache).
    """
    return _COMPILE_CLOCK.seconds()
