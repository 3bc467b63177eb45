"""A spatial index of a frozen scene's Gaussian centres (:class:`SpatialIndex`), for queries whose cost follows the
region asked about rather than the scene's size."""

from __future__ import annotations

import math

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from .._validation import check_int, check_real, check_vector
from . import _kernels

__all__ = ["SpatialIndex", "roi_box", "check_depth_cut"]

#: ``sqrt(2 ln 255)``: a pixel passes the alpha test only within this many standard deviations (the cull kernel's).
_K_SUPPORT = math.sqrt(2.0 * math.log(255.0))
#: Pixels the cull kernel adds to its footprint bound.
_PAD_PX = 2.0
#: Relative slack of every cell test, far above float64 rounding (the tests are exact otherwise).
_REL_TOL = 1e-9
#: Morton bits per axis of the centres' quantisation.
_BITS = 21
#: Chunks are also cut between cells of the finest Morton grid with at most (Gaussians / chunk) / this many
#: occupied cells.
_SPLIT_CELLS = 4
#: Chunks per block (the coarse level that the queries test first).
_BLOCK = 32
#: Most Gaussians per chunk when the caller does not say.
_CHUNK = 128


def roi_box(roi, camera: Camera) -> tuple:
    """``roi`` (None: the whole image) as a float pixel box ``(x0, y0, x1, y1)`` of ``camera``.

    Raises
    ------
    ValidationError
        Not None or four finite numbers, or an empty box.
    """
    if roi is None:
        return (0.0, 0.0, float(camera.width), float(camera.height))
    arr = np.asarray(roi)
    if arr.shape != (4,) or arr.dtype.kind not in "iuf" or not np.all(np.isfinite(arr)):
        raise ValidationError(f"roi must be None or a box (x0, y0, x1, y1), got {roi!r}")
    x0, y0, x1, y1 = (float(v) for v in arr)
    if x0 >= x1 or y0 >= y1:
        raise ValidationError(f"roi box {(x0, y0, x1, y1)} is empty; need x0 < x1 and y0 < y1")
    return (x0, y0, x1, y1)


def check_depth_cut(name: str, value) -> float | None:
    """A depth cut (``far`` or ``near``): None, or a number that is not NaN (infinities allowed).

    Raises
    ------
    ValidationError
        Neither None nor a number, or NaN.
    """
    if value is not None and (isinstance(value, (bool, np.bool_)) or not isinstance(
            value, (int, float, np.integer, np.floating)) or np.isnan(value)):
        raise ValidationError(f"{name} must be a number or None, got {value!r}")
    return None if value is None else float(value)


def _part1by2(v: np.ndarray) -> np.ndarray:
    """The 21 low bits of ``v`` (uint64) spread to every third bit (Morton interleave)."""
    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def _expand(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for each ``(s, c)`` (int64)."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    out = np.ones(total, np.int64)
    # At the first slot of each later run: jump from the previous run's last value to this run's start.
    nz = counts > 0
    first = (ends - counts)[nz]
    s_nz = starts[nz]
    prev_last = (starts + counts - 1)[nz]
    out[0] = s_nz[0]
    out[first[1:]] = s_nz[1:] - prev_last[:-1]
    return np.cumsum(out)


class _Boxes:
    """Axis-aligned boxes of centres (``lo``, ``hi``: (C, 3) float64) with the largest 1-sigma size in each."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, smax: np.ndarray):
        self.centre = 0.5 * (lo + hi)
        self.half = 0.5 * (hi - lo)
        self.smax = smax
        self.mag = np.abs(self.centre) + self.half  # bounds |p| per axis over each box, for the tolerances

    def subset(self, rows: np.ndarray) -> "_Boxes":
        out = _Boxes.__new__(_Boxes)
        out.centre, out.half, out.smax, out.mag = self.centre[rows], self.half[rows], self.smax[rows], self.mag[rows]
        return out

    def extremes(self, normal: np.ndarray, offset: float) -> tuple:
        """``(max, min, scale)`` over each box of ``normal . p + offset``; ``scale`` bounds its terms' size."""
        mid = self.centre @ normal + offset
        spread = self.half @ np.abs(normal)
        return mid + spread, mid - spread, self.mag @ np.abs(normal) + abs(offset)


class SpatialIndex:
    """Gaussian centres grouped into small, spatially compact chunks, for region queries.

    Built once per scene (a :class:`~seed2gs_inverse.raster.FrozenScene`
    builds it on first use and keeps it): the centres are sorted along a
    Morton curve over their bounding box and cut into chunks of at most
    ``chunk`` consecutive Gaussians, also wherever the curve leaves a cell of
    the finest ``2^L``-per-axis grid that has at most ``N / chunk / 4``
    occupied cells, so that few chunks span distant regions.
    Each chunk keeps the bounding box of its centres and the largest 1-sigma
    size of its Gaussians; blocks of consecutive chunks keep the same, so
    that a query first discards whole blocks. A query's cost follows the
    chunks it touches, not the scene's size.

    Parameters
    ----------
    means : (N, 3) float array
        Finite Gaussian centres (a scene's ``means``); N >= 1.
    smax : (N,) float array
        Each Gaussian's largest standard deviation ``max_k exp(log_scale_k)``
        (finite, >= 0), as :func:`~seed2gs_inverse.raster.cone_cull` uses it.
    chunk : int, optional
        Most Gaussians per chunk (>= 1); default 128.

    Raises
    ------
    ValidationError
        Shapes, sizes or values as above violated.

    Attributes
    ----------
    perm : (N,) int64
        Scene indices in chunk order.
    starts : (C + 1,) int64
        Chunk ``c`` holds ``perm[starts[c]:starts[c + 1]]``.
    """

    def __init__(self, means, smax, chunk: int | None = None):
        means = np.asarray(means)
        smax = np.asarray(smax)
        if means.ndim != 2 or means.shape[1] != 3 or means.shape[0] == 0 or means.dtype.kind != "f":
            raise ValidationError(f"means must be a non-empty (N, 3) float array, got {means.dtype} {means.shape}")
        # min and max propagate NaN, so finite bounds mean finite values (one pass each instead of three).
        # (Per column: numpy reduces an (N, 3) array along axis 0 several times slower.)
        box = np.array([[means[:, d].min() for d in range(3)], [means[:, d].max() for d in range(3)]], np.float64)
        if not np.all(np.isfinite(box)):
            raise ValidationError("means has non-finite values; the scene's centres must be finite")
        if smax.shape != (means.shape[0],) or smax.dtype.kind != "f" or not (smax.min() >= 0) \
                or not np.isfinite(smax.max()):
            raise ValidationError(f"smax must be a ({means.shape[0]},) array of finite sizes >= 0, "
                                  f"got {smax.dtype} {smax.shape}")
        chunk = _CHUNK if chunk is None else check_int("chunk", chunk, lo=1)
        self.n = means.shape[0]
        self.means = means  # the caller's array, not a copy (ball tests members against it)
        self.perm, self.starts = self._order(means, box, chunk)
        lo, hi, sz = [], [], np.maximum.reduceat(smax[self.perm], self.starts[:-1])
        for d in range(3):
            col = means[self.perm, d]
            lo.append(np.minimum.reduceat(col, self.starts[:-1]))
            hi.append(np.maximum.reduceat(col, self.starts[:-1]))
        lo, hi = np.stack(lo, 1).astype(np.float64), np.stack(hi, 1).astype(np.float64)
        self.chunks = _Boxes(lo, hi, sz.astype(np.float64))
        # Blocks of _BLOCK consecutive chunks.
        b_first = np.arange(0, len(self.starts) - 1, _BLOCK)
        self.blocks = _Boxes(np.minimum.reduceat(lo, b_first, axis=0), np.maximum.reduceat(hi, b_first, axis=0),
                             np.maximum.reduceat(self.chunks.smax, b_first))
        self._block_first = np.append(b_first, len(self.starts) - 1)

    @staticmethod
    def _order(means: np.ndarray, box: np.ndarray, chunk: int) -> tuple:
        """``(perm, starts)``: Morton order of the centres (bounds ``box``: min and max rows) and its cut into
        chunks."""
        lo = box[0]
        ext = box[1] - lo
        scale = np.where(ext > 0, ((1 << _BITS) - 1) / np.where(ext > 0, ext, 1.0), 0.0)
        code = np.zeros(means.shape[0], np.uint64)
        for d in range(3):
            q = np.clip((means[:, d].astype(np.float64) - lo[d]) * scale[d], 0, (1 << _BITS) - 1)
            code |= _part1by2(q.astype(np.uint64)) << np.uint64(d)
        perm = np.argsort(code).astype(np.int64, copy=False)
        code = code[perm]
        # Consecutive sorted codes lie in different cells of level L exactly when their XOR reaches bit 3 (21 - L).
        diff = code[1:] ^ code[:-1]
        budget = max(1, means.shape[0] // (chunk * _SPLIT_CELLS))
        level = 0
        while level < _BITS and np.count_nonzero(diff >> np.uint64(3 * (_BITS - level - 1))) + 1 <= budget:
            level += 1
        run_start = np.r_[0, np.flatnonzero(diff >> np.uint64(3 * (_BITS - level))) + 1] if level else np.zeros(1, int)
        # Position of each sorted Gaussian within its coarse cell's run; a chunk starts every `chunk` of them.
        run_len = np.diff(np.append(run_start, perm.size))
        pos = np.arange(perm.size, dtype=np.int64) - np.repeat(run_start, run_len)
        starts = np.append(np.flatnonzero(pos % chunk == 0), perm.size).astype(np.int64)
        return perm, starts

    def __len__(self) -> int:
        return self.n

    def __repr__(self) -> str:
        return f"SpatialIndex({self.n} Gaussians in {len(self.starts) - 1} chunks)"

    # -- queries ---------------------------------------------------------------------------------------------

    def _select(self, test) -> np.ndarray:
        """Chunk ids whose boxes pass ``test(boxes) -> bool mask``, through the blocks first."""
        blocks = np.flatnonzero(test(self.blocks))
        first = self._block_first[blocks]
        rows = _expand(first, self._block_first[blocks + 1] - first)
        return rows[test(self.chunks.subset(rows))]

    def _members(self, rows: np.ndarray) -> np.ndarray:
        """Scene indices of the chunks ``rows``, in chunk order."""
        return self.perm[_expand(self.starts[rows], self.starts[rows + 1] - self.starts[rows])]

    def ascending(self, idx: np.ndarray) -> np.ndarray:
        """``idx`` (distinct scene indices, int64) in ascending order, through a mask over the scene when that is
        cheaper than a sort."""
        if 8 * idx.size >= self.n:
            mask = np.zeros(self.n, bool)
            mask[idx] = True
            return np.flatnonzero(mask).astype(np.int64, copy=False)
        return np.sort(idx)

    def view_rows(self, camera: Camera, roi=None, far: float | None = None) -> np.ndarray:
        """:meth:`view_candidates` in chunk order (not sorted); the arguments are not checked."""
        x0, y0, x1, y1 = roi_box(roi, camera)
        lim_xp, lim_xn, lim_yp, lim_yn = _kernels._jacobian_limits.py_func(
            camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        tx, ty = max(lim_xp, lim_xn), max(lim_yp, lim_yn)
        fx, fy, cx, cy = float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)
        root_c = math.sqrt(fx * fx * (1.0 + tx * tx) + fy * fy * (1.0 + ty * ty))
        pad = _K_SUPPORT * math.sqrt(_kernels.EPS2D) + _PAD_PX
        # Necessary conditions n . v + beta s >= 0 on the view-frame centre v and size s (class Notes).
        sides = ((np.array([1.0, 0.0, (cx + pad - x0) / fx]), _K_SUPPORT * root_c / fx),
                 (np.array([-1.0, 0.0, (x1 - cx + pad) / fx]), _K_SUPPORT * root_c / fx),
                 (np.array([0.0, 1.0, (cy + pad - y0) / fy]), _K_SUPPORT * root_c / fy),
                 (np.array([0.0, -1.0, (y1 - cy + pad) / fy]), _K_SUPPORT * root_c / fy))
        rot = np.asarray(camera.rotation, np.float64)
        trans = np.asarray(camera.translation, np.float64)
        axis = np.array([(0.5 * (x0 + x1) - cx) / fx, (0.5 * (y0 + y1) - cy) / fy, 1.0])
        axis /= np.linalg.norm(axis)
        near = float(camera.near)

        def test(boxes: _Boxes) -> np.ndarray:
            zmax, _, zs = boxes.extremes(rot[2], trans[2])
            ok = zmax >= near - _REL_TOL * (zs + abs(near))
            if far is not None and far < math.inf:
                _, amin, a_s = boxes.extremes(rot.T @ axis, float(trans @ axis))
                slack = _REL_TOL * (a_s + 3.0 * boxes.smax + (abs(far) if far > -math.inf else 0.0))
                ok &= amin - 3.0 * boxes.smax <= far + slack
            for normal, beta in sides:
                top, _, sc = boxes.extremes(rot.T @ normal, float(trans @ normal))
                ok &= top + beta * boxes.smax >= -_REL_TOL * (sc + beta * boxes.smax)
            return ok

        return self._members(self._select(test))

    def view_candidates(self, camera: Camera, roi=None, far: float | None = None) -> np.ndarray:
        """Gaussians that may reach the pixels of ``roi`` in ``camera``: a superset of ``cone_cull``'s.

        Parameters
        ----------
        camera : Camera
        roi : None or (x0, y0, x1, y1)
            Pixel box; default the whole image.
        far : float, optional
            The far cut of :func:`~seed2gs_inverse.raster.cone_cull`.

        Returns
        -------
        (M,) int64
            Ascending scene indices: every Gaussian that
            :func:`~seed2gs_inverse.raster.cone_cull` keeps for the same
            ``(camera, roi, far)`` (without a near cut), and others of the
            same chunks.

        Raises
        ------
        ValidationError
            ``camera``, ``roi`` or ``far`` invalid (as for ``cone_cull``).

        Notes
        -----
        ``cone_cull`` keeps Gaussian ``i`` (view-frame centre
        ``v = R x + t``, size ``s = smax_i``) only if ``v_z >= near``,
        ``axis . v - 3 s <= far`` and ``m_x + r >= x0``, ``m_x - r <= x1``
        (and in y), with ``m_x = fx v_x / v_z + cx`` and
        ``r = k sqrt(lmax s^2 + eps2d) + 2``, ``k = sqrt(2 ln 255)``,
        ``lmax`` the largest eigenvalue of ``J J^T`` for the Jacobian at the
        clamped ``tx = clamp(v_x / v_z)``, ``|tx| <= Tx`` (the larger of the
        two clamp limits; likewise ``Ty``). Since
        ``lmax <= trace(J J^T) = (fx^2 (1 + tx^2) + fy^2 (1 + ty^2)) / v_z^2
        <= C / v_z^2`` with ``C = fx^2 (1 + Tx^2) + fy^2 (1 + Ty^2)``, and
        ``sqrt(a + b) <= sqrt(a) + sqrt(b)``,
        ``r <= k sqrt(C) s / v_z + k sqrt(eps2d) + 2``. Multiplying
        ``m_x + r >= x0`` by ``v_z / fx > 0`` (``v_z >= near > 0``) gives the
        necessary condition, linear in ``(v, s)``,
        ``v_x + v_z (cx + k sqrt(eps2d) + 2 - x0) / fx + (k sqrt(C) / fx) s >= 0``,
        and likewise for the other three sides. Whatever the clamp does to
        an off-screen centre, it only lowers ``|tx|`` below ``Tx``; a
        Gaussian at or behind the near plane is dropped by the kernel, and
        the conditions hold for every ``v_z > 0``, so a chunk that straddles
        the near plane or holds the camera is tested like any other. For a
        chunk, ``v`` ranges over the image of its centres' bounding box and
        ``s`` is at most the chunk's largest size: a linear function's
        largest value over a box is exact (centre plus half extents times
        the absolute normal), so a chunk that fails any condition (largest
        ``v_z`` below ``near``, smallest ``axis . v`` minus ``3 s_max``
        beyond ``far``, or a side's largest value below 0) holds no Gaussian
        that ``cone_cull`` keeps. Each test is loosened by a relative
        ``1e-9`` of its terms' magnitudes, far above the float64 rounding of
        the kernel and of the test, so rounding cannot flip it.
        """
        if not isinstance(camera, Camera):
            raise ValidationError(f"camera must be a Camera, got {type(camera).__name__}")
        roi_box(roi, camera)
        far = check_depth_cut("far", far)
        return self.ascending(self.view_rows(camera, roi, far))

    def ball(self, center, radius: float) -> np.ndarray:
        """Gaussians whose centre lies within ``radius`` of ``center``.

        Parameters
        ----------
        center : (3,) float
            Finite.
        radius : float
            Finite, >= 0.

        Returns
        -------
        (M,) int64
            Ascending scene indices ``i`` with
            ``sum_k (means[i, k] - center[k])^2 <= radius^2`` (float64).

        Raises
        ------
        ValidationError
            ``center`` or ``radius`` invalid.

        Notes
        -----
        Chunks whose bounding box lies farther than ``radius`` (loosened by a
        relative ``1e-9``) are skipped; the members of the others are tested
        exactly.
        """
        c = check_vector("center", center)
        r = check_real("radius", radius, lo=0.0)

        def test(boxes: _Boxes) -> np.ndarray:
            gap = np.maximum(np.abs(boxes.centre - c) - boxes.half, 0.0)
            scale = ((boxes.mag + np.abs(c)) ** 2).sum(axis=1)
            return (gap * gap).sum(axis=1) <= r * r * (1.0 + _REL_TOL) + _REL_TOL * scale

        idx = self._members(self._select(test))
        d = self.means[idx].astype(np.float64) - c
        return self.ascending(idx[np.einsum("ij,ij->i", d, d) <= r * r])
