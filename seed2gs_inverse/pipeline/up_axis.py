r"""The orbit axis: world "up" from robust geometry.

VAAS orbits the object about an axis; if that axis is not the world's up
the "flat" orbit rolls about the viewing direction or dives under the
ground and never shows the far side. :func:`estimate_up_axis` combines
several independent cues and reports which one decided and how sure it is;
:func:`estimate_up` is the single-cue estimate from splat normals that
``ExtractSettings(up="level")`` selects.

Cues
----
Reference no-roll constraint
    Nearly every user view has no roll: its x axis :math:`r` is level, so
    :math:`u \cdot r = 0` and :math:`u \in \mathrm{span}(a, b)` with
    :math:`a` the image-up (:attr:`Camera.up`) and :math:`b` the backward
    direction made orthogonal to :math:`a` (:func:`roll_basis`). The
    camera's pitch is the angle of :math:`u` from :math:`a` in that plane:
    :math:`u = \cos\phi\, a + \sin\phi\, b` for a view looking down by
    :math:`\phi` (straight down: :math:`u = b`, the image-up level, and the
    constraint still holds whatever the image's rotation about the view).
    Used as a filter on plane candidates (:math:`|n \cdot r| \le \sin`
    ``max_roll_deg``) and as a check.
Training cameras (``cameras``)
    Under the same no-roll assumption for every capture camera,
    :math:`u \perp r_j` for all of them, so

    .. math::

        u = \arg\min_{\|u\| = 1} \sum_j (r_j \cdot u)^2,

    the eigenvector of the smallest eigenvalue :math:`\lambda_1` of
    :math:`\sum_j r_j r_j^\top`, signed so that :math:`\sum_j a_j \cdot u > 0`
    (:func:`cameras_up`). It is determined when the right vectors span a
    plane: its quality is :math:`(\lambda_2 - \lambda_1) / \lambda_3` (0 when
    all cameras share one right vector, e.g. a single camera). In COLMAP
    captures this is the world up.
Support plane (local)
    The object rests on something. Gaussian means within ``local_factor``
    times the object's radius :math:`R` of its centre :math:`o`, minus G0
    (the lifted set: the object's own Gaussians) and nearly transparent
    splats, are fitted with RANSAC (:func:`fit_plane`). Hypotheses are
    planes through 3 random points and planes through the centre of a random
    flat Gaussian along its normal (the axis of its smallest scale). A
    hypothesis :math:`(n, p)`, oriented so that :math:`n \cdot a > 0` (up
    points up in the image), is admissible when

    * it agrees with the prior: :math:`|n \cdot r| \le \sin` ``max_roll_deg``
      and :math:`n \cdot a \ge \cos` ``max_pitch_deg`` (or, with training
      cameras, :math:`\angle(n, u_{cam}) \le` ``max_camera_deg``), and
    * the object is above it: :math:`0 < n \cdot (o - p) \le`
      ``max_below`` :math:`R` (a wall behind the object, oriented this way,
      has the object on its negative side), and at least 90% of G0 lies on
      its positive side (a plane through G0, e.g. the top of a table when
      G0 is that top, is the object, not the surface it rests on).

    A view pitched past ``max_pitch_deg`` (a drone looking straight down)
    sees its ground outside that window, and the vertical planes around
    (walls, fences, seen edge-on) inside it. So the search is repeated in
    the steep window: normals oriented towards the camera's side
    (:math:`n \cdot b > 0`) with :math:`|n \cdot a| < \cos`
    ``max_pitch_deg`` and the same roll bound, pitches from
    ``max_pitch_deg`` to as far past straight down. A wall seen face-on
    from a level view lies there too, so the steep planes are taken only
    when they dominate: the steep scene plane holds twice
    (:data:`_STEEP_FACTOR`) the inliers of the ordinary scene plane (the ground extends, a
    wall ends) and the steep local plane at least as many as the ordinary
    one (without a steep scene plane, the local planes compared with the
    factor). Method ``"...; steep reference"``; the confidence is
    multiplied by 1 minus the ordinary rival's share of the steep plane's
    inliers. With capture cameras their axis sets the window and there is
    no steep search.

    Its score is its inlier count :math:`|\{i : |n \cdot (x_i - p)| \le \tau\}|`
    with :math:`\tau` half the median distance of a point to its 4th
    nearest neighbour (scale-free: it follows the sampling density). The
    best admissible plane is refined by least squares (the normal is the
    smallest principal axis of its inliers, twice, re-selecting inliers),
    then by Cauchy-weighted least squares,
    :math:`w_i = 1 / (1 + (r_i / c)^2)` with :math:`c` = ``robust_scale``
    :math:`\tau` over the points with :math:`|r_i| \le 3c` (5 rounds): on
    ground that undulates by more than :math:`\tau` (lawns, patios) RANSAC
    catches the band of one tangent plane, tilted by the local slope; the
    weighted fit recovers the mean plane. Vertical clutter (grass, plants,
    fences) does not form a plane under the object, so it cannot win however
    many flat splats it has.
Scene plane (regional)
    The same fit over a random subsample of the Gaussians within
    :math:`\rho = \max(` ``scene_factor`` :math:`\|c - o\|,\ 3`
    ``local_factor`` :math:`R)` of :math:`o`, :math:`c` the reference's
    centre (the surroundings the user sees the object in; the dominant
    large plane below the object): a cross-check for the local plane, and
    the answer when the neighbourhood holds too few points. The ball is
    :func:`~.local.neighbourhood`'s and the subsample depends only on the
    Gaussians in it: parts of the scene farther away change nothing.
    Without an object (no G0 and no centre) it is the whole scene.
Normals (fallback)
    :func:`estimate_up`: the dominant normal of flat splats within the
    no-roll plane, over the scene plane's ball. Wrong in vegetation; used
    only when nothing above is available, with confidence 0.2.

Decision and confidence
-----------------------
The local support plane wins when it has at least ``min_inliers`` inliers,
unless the scene plane disagrees with it by more than ``agree_deg`` and,
taken as the answer (checked against the local plane), has the higher
confidence :math:`c` below (method ``"scene-plane"``; the disagreement
stays one of its checks, weighed by the local plane's share of its points,
so such an answer is weak and warns when that plane is well supported): a
local "plane" can be a flat patch of the object's own unseen side, denser
than the ground (a patch on an animal's back, far off the vertical, against
a lawn that holds a much larger share of the scene). When the scene plane
agrees with it within ``agree_deg`` they are the same surface seen at two
extents, and the axis is their inlier-weighted mean normal
:math:`(k_l n_l + k_g n_g) / \|\cdot\|` (method
``"support-plane+scene-plane"``): a local patch of uneven ground is tilted
by its slope, the wide fit averages the slopes out. Without a local plane
the scene plane is used; otherwise the training cameras; otherwise the
normals. If no admissible plane under the roll prior holds at least
:math:`f_0` (below) of its points, the search is repeated without the roll
prior (the reference may have roll; the pitch bound stays); when that finds
a plane with at least twice the inliers it is used, marked
``"...; roll prior dropped"``, at half confidence. The confidence of
a plane is

.. math::

    c = \min\!\left(1, \frac{f}{f_0}\right) \cdot
        \frac{\sum_{k=1}^{K} w_k \exp\!\left(-(\theta_k / 8^\circ)^2\right)}{\sum_{k=1}^{K} w_k},

with :math:`f` the plane's inlier fraction of its point set
(:math:`f_0 = 0.15`; for the agreeing pair ``"support-plane+scene-plane"``
the larger of the two fractions: both found the surface, and the local
ball, small and dense, puts a thinner band :math:`\tau` through an
undulating ground than the subsampled scene ball) and :math:`\theta_k` the
angles between the chosen axis and each available check: the no-roll
plane of the reference (:math:`\arcsin |u \cdot r|`, always), the other
plane and the training cameras' axis when there are. Each check weighs
:math:`w_k = 1`, except the other plane's, which weighs its own
:math:`\min(1, f_k / f_0)`: a "plane" holding a few percent of its points
(a flat patch of the object's unseen side) is no evidence that the ground
found in the wider ball is wrong. Camera-only answers have confidence 0.8 times
the cameras' quality. A plane answer less confident than the answer
without a plane (the cameras', the normals' 0.2 or the image-up's 0.1) gives
way to it, unless the plane was found with the roll prior dropped (the
answers without a plane assume that prior); the plane is kept in
``details["rejected_plane"]``. A scanned object alone, with no ground, is
the case: a flat part of it is a "plane" that agrees with nothing, far off
the vertical. Below :data:`WEAK_CONFIDENCE` the
pipeline warns and names ``--up``.

The steps of :func:`estimate_up_axis` are separate private functions, in
the order it calls them: :func:`_object_frame` (o, R),
:func:`_camera_axis`, :func:`_plane_point_sets`, :func:`_search_planes`
(over :func:`_fit_ground_plane` and the admissibility test
:func:`_admissible`), :func:`_screen_planes`, :func:`_decide_plane` (over
:func:`_plane_answer`) and :func:`_fallback_axis`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Iterable, NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from ..camera import Camera
from ..errors import ValidationError
from ..raster import FrozenScene
from ..scene import GaussianScene, rotation_columns
from .local import neighbourhood

__all__ = ["UpEstimate", "PlaneFit", "estimate_up_axis", "estimate_up", "fit_plane", "cameras_up", "roll_basis",
           "camera_list", "flat_normals", "angle_deg", "WEAK_CONFIDENCE", "UP_DEFAULTS"]

#: Below this confidence the pipeline warns and suggests ``--up``.
WEAK_CONFIDENCE = 0.5

#: Defaults of :func:`estimate_up_axis`.
UP_DEFAULTS = {"local_factor": 3.0, "scene_factor": 4.0, "max_below": 3.0, "max_roll_deg": 20.0, "max_pitch_deg": 80.0,
               "max_camera_deg": 25.0, "agree_deg": 5.0, "min_inliers": 30, "n_hypotheses": 400, "max_points": 6000,
               "min_opacity": 0.2, "robust_scale": 3.0, "seed": 0}

#: Angular scale (degrees) of a check's agreement term in the confidence.
_CHECK_DEG = 8.0
#: :math:`f_0`: a plane holding this share of its points has full confidence.
_FRACTION_FULL = 0.15
#: When neither plane holds this share of its points there is no ground in sight (an object scanned
#: alone: its best "planes" hold a few percent) and neither is used: the axis comes from the cameras,
#: the normals or the image-up.
_FRACTION_MIN = 0.05
#: The normals fallback is taken only within this angle of the image-up (a view pitched further with
#: no plane in sight is less likely than a dominant flat surface that is not the ground).
_NORMALS_MAX_PITCH_DEG = 45.0
#: Planes in the steep pitch window (the reference looking down past ``max_pitch_deg``) replace the
#: ordinary ones only with this many times their inliers (a wall seen face-on from a level view lies there too).
_STEEP_FACTOR = 2.0
#: Capture cameras whose quality (:func:`cameras_up`) is below this leave the axis undetermined.
_MIN_CAMERA_QUALITY = 0.05
#: At most this many Gaussians of G0 test "the object is above the plane".
_MAX_G0_POINTS = 256
#: At most this many points enter each plane fit (a random subsample beyond).
_MAX_FIT_POINTS = 60000


def angle_deg(u, v) -> float:
    """Angle between two directions in degrees (sign-sensitive).

    Parameters
    ----------
    u, v : (3,) array_like
        Directions; need not be unit.

    Returns
    -------
    float
        In [0, 180].
    """
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    c = float(u @ v / (np.linalg.norm(u) * np.linalg.norm(v)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


@dataclass(frozen=True)
class UpEstimate:
    """The orbit axis and where it came from.

    Attributes
    ----------
    axis : (3,) float64 unit vector
    method : str
        ``"support-plane"``, ``"support-plane+scene-plane"``,
        ``"scene-plane"``, ``"cameras"``, ``"normals"`` or ``"image-up"``
        (``"; roll prior dropped"`` appended when the plane search had to
        ignore the reference's no-roll prior).
    confidence : float in [0, 1]
    details : dict
        JSON-ready facts: every candidate's normal, inliers and checks.
    """

    axis: np.ndarray
    method: str
    confidence: float
    details: dict = field(default_factory=dict)

    @property
    def weak(self) -> bool:
        """Whether the confidence is below :data:`WEAK_CONFIDENCE` (the pipeline then warns)."""
        return self.confidence < WEAK_CONFIDENCE

    def warning(self) -> str | None:
        """A message for the user when the estimate is weak, else None."""
        if not self.weak:
            return None
        return (f"the orbit axis is uncertain (method {self.method}, confidence {self.confidence:.2f}); "
                f"if the far side of the object is missing, give the world up direction with "
                f"--up X,Y,Z (or up=(x, y, z)), use --up camera when the reference view is level "
                f"(its image-up is the world's), or pass capture cameras seen from several directions "
                f"with --cameras FILE (up_cameras=...)")

    def summary(self) -> dict:
        """JSON-ready fields (``report()["up"]``)."""
        return {"axis": [float(v) for v in self.axis], "method": self.method,
                "confidence": float(self.confidence), "details": self.details}


@dataclass(frozen=True)
class PlaneFit:
    r"""A plane ``normal . (x - point) = 0`` fitted by :func:`fit_plane`.

    Attributes
    ----------
    normal : (3,) float64
        Unit normal, oriented by the caller's ``admissible`` convention.
    point : (3,) float64
        A point of the plane.
    inliers : (M,) bool
        Over the fitted points: the RANSAC band (before any robust refit),
        the points the plane found.
    threshold : float
        The inlier distance :math:`\tau`.
    n_points : int
        M, how many points were fitted.
    """

    normal: np.ndarray
    point: np.ndarray
    inliers: np.ndarray
    threshold: float
    n_points: int

    @property
    def n_inliers(self) -> int:
        """How many of the fitted points are inliers."""
        return int(self.inliers.sum())

    @property
    def fraction(self) -> float:
        """The inlier share :math:`f` of the fitted points."""
        return self.n_inliers / max(self.n_points, 1)

    def summary(self) -> dict:
        """JSON-ready fields (``UpEstimate.details``)."""
        return {"normal": [float(v) for v in self.normal], "point": [float(v) for v in self.point],
                "n_inliers": self.n_inliers, "n_points": int(self.n_points),
                "fraction": float(self.fraction), "threshold": float(self.threshold)}


def _level_basis(reference: Camera) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)``: the image-up and the backward direction made orthogonal to it, both unit."""
    a = reference.up / np.linalg.norm(reference.up)
    b = -reference.forward
    b = b - (b @ a) * a
    b /= np.linalg.norm(b)
    return a, b


def roll_basis(reference: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The no-roll frame of a view: ``(a, b, r)``, all (3,) float64 unit vectors.

    ``a`` is the image-up, ``b`` the backward direction made orthogonal to
    ``a``, ``r`` the camera's right vector. A view without roll has its
    world up in ``span(a, b)``, perpendicular to ``r``.

    Raises
    ------
    ValidationError
        ``reference`` is not a Camera.
    """
    if not isinstance(reference, Camera):
        raise ValidationError(f"reference must be a Camera, got {type(reference).__name__}")
    a, b = _level_basis(reference)
    return a, b, reference.right / np.linalg.norm(reference.right)


def camera_list(cameras: Iterable[Camera], name: str) -> list[Camera]:
    """``cameras`` (any iterable of Camera, read once: a generator too) as a list.

    Raises
    ------
    ValidationError
        One Camera instead of a sequence, not iterable, or an item that is
        not a Camera; ``name`` heads the message.
    """
    if isinstance(cameras, Camera):
        raise ValidationError(f"{name} must be a sequence of Camera, got one Camera; pass [camera]")
    try:
        cams = list(cameras)
    except TypeError:
        raise ValidationError(f"{name} must be a sequence of Camera, got {type(cameras).__name__}") from None
    if not all(isinstance(c, Camera) for c in cams):
        raise ValidationError(f"{name} must be a sequence of Camera")
    return cams


def cameras_up(cameras: Iterable[Camera]) -> tuple[np.ndarray, float]:
    r"""World up from capture cameras without roll, and its quality.

    :math:`u` minimises :math:`\sum_j (r_j \cdot u)^2` over the cameras'
    right vectors :math:`r_j` (smallest eigenvector of :math:`\sum_j r_j
    r_j^\top`, eigenvalues :math:`\lambda_1 \le \lambda_2 \le \lambda_3`),
    signed to agree with the mean image-up.

    Returns
    -------
    axis : (3,) float64 unit vector
    quality : float
        :math:`(\lambda_2 - \lambda_1) / \lambda_3` in [0, 1]: 0 when the
        right vectors are all parallel (one camera: the axis is then
        undetermined), near 1 when they spread over a plane.

    Raises
    ------
    ValidationError
        ``cameras`` is empty or holds something that is not a Camera.
    """
    cams = list(cameras)
    if not cams or not all(isinstance(c, Camera) for c in cams):
        raise ValidationError("cameras must be a non-empty sequence of Camera")
    r = np.stack([c.right for c in cams])
    a = np.stack([c.up for c in cams]).sum(axis=0)
    evals, evecs = np.linalg.eigh(r.T @ r)
    u = evecs[:, 0]
    if u @ a < 0:
        u = -u
    quality = float(np.clip((evals[1] - evals[0]) / evals[2], 0.0, 1.0))
    return u, quality


def estimate_up(scene: GaussianScene, reference: Camera, weights=None, flatness: float = 0.3) -> np.ndarray:
    r"""A levelled orbit axis: the reference's image-up with the camera pitch removed.

    The paper takes "up" from the reference camera, but a camera that looks
    down at the object has an image-up tilted towards the viewing direction
    by the pitch, and a flat orbit about that axis dives below the ground on
    the far side. Assuming only that the reference has no roll (its x axis
    is level, as in nearly every user view), the world up lies in the plane
    spanned by :attr:`Camera.up` ``a`` and the backward direction ``b``; the
    axis is the direction in that plane best aligned with the normals of the
    scene's flat Gaussians (splats of a trained 3DGS lie on surfaces; floors
    and table tops dominate their normal distribution):

    .. math::

        u = \arg\max_{\|u\|=1,\, u \in \mathrm{span}(a, b)}
            \sum_i \omega_i (n_i \cdot u)^2,

    the principal eigenvector of a 2x2 matrix, signed so that
    :math:`u \cdot a > 0`.

    Parameters
    ----------
    scene : GaussianScene
    reference : Camera
    weights : (N,) array_like or None
        Per-Gaussian weights (e.g. each Gaussian's total compositing weight
        in the reference view, so that what the user sees counts);
        :math:`\omega_i` is this times the opacity. None: the opacity alone.
    flatness : float
        A Gaussian is flat, and its normal :math:`n_i` (the axis of its
        smallest scale) counts, when its smallest scale is below
        ``flatness`` times the middle one.

    Returns
    -------
    (3,) float64
        The axis (unit); ``reference.up`` when there are no flat Gaussians.
    """
    a, b = _level_basis(reference)
    s = scene.scales.astype(np.float64)
    order = np.argsort(s, axis=1)
    smin = np.take_along_axis(s, order[:, :1], 1)[:, 0]
    smid = np.take_along_axis(s, order[:, 1:2], 1)[:, 0]
    w = scene.opacities.astype(np.float64) * (smin < flatness * smid)
    if weights is not None:
        w = w * np.asarray(weights, dtype=np.float64).ravel()
    sel = np.nonzero(w > 0)[0]
    if sel.size == 0:
        return a
    normals = rotation_columns(scene.quats[sel], order[sel, 0])
    p = np.stack([normals @ a, normals @ b], 1)
    m = (p * w[sel, None]).T @ p
    evals, evecs = np.linalg.eigh(m)
    v = evecs[:, -1]
    u = v[0] * a + v[1] * b
    return u if u @ a > 0 else -u


def _plane_ls(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane of (M, 3) points: (normal, centroid), the normal their smallest principal axis."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    return vt[2], c


def fit_plane(points, *, normals=None, threshold: float | None = None,
              admissible: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
              n_hypotheses: int = 400, max_points: int = 6000, seed: int = 0, robust_scale: float = 0.0,
              keep_normal: Callable[[np.ndarray], bool] | None = None) -> PlaneFit | None:
    r"""RANSAC plane with admissibility filter, refined by least squares.

    Parameters
    ----------
    points : (M, 3) array
    normals : (M, 3) array or None
        Per-point normals (flat Gaussians); a random half of the hypotheses
        are then planes through one point along its normal, the rest
        through 3 random points.
    threshold : float or None
        Inlier distance :math:`\tau`; None: half the median distance of a
        point to its 4th nearest neighbour.
    admissible : callable or None
        ``admissible(normals (H, 3), points (H, 3)) -> (ok (H,) bool, sign (H,))``
        for hypotheses ``n . (x - p) = 0`` with unit normals as sampled:
        which are allowed, and the sign (+1 / -1) that orients each normal
        by the caller's convention. The returned plane keeps that orientation.
    n_hypotheses, max_points, seed
        Hypotheses drawn; at most ``max_points`` points score them.
    robust_scale : float
        0: least squares on the inliers only. > 0: then Cauchy-weighted
        least squares at scale ``robust_scale * threshold`` over the points
        within 3 scales (the mean plane of an undulating surface).
    keep_normal : callable or None
        ``keep_normal(n (3,)) -> bool``: whether the refined plane's normal
        is still allowed (e.g. the orientation part of ``admissible``; the
        refinement moves the plane's point, so point conditions do not
        carry over). When it is not, the RANSAC hypothesis the refinement
        started from is returned instead.

    Returns
    -------
    PlaneFit or None
        None with fewer than 3 points or no admissible hypothesis.

    Raises
    ------
    ValidationError
        ``points`` is not a finite (M, 3) array.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise ValidationError(f"fit_plane: points must be a finite (M, 3) array, got shape {p.shape}")
    m = len(p)
    if m < 3:
        return None
    rng = np.random.default_rng(seed)
    score_idx = rng.choice(m, max_points, replace=False) if m > max_points else np.arange(m)
    if threshold is None:
        threshold = _inlier_threshold(p, rng)
    if not threshold > 0:
        threshold = 1e-6
    hn, hp = _hypotheses(p, normals, int(n_hypotheses), rng)
    if admissible is not None and len(hn):
        good, sign = admissible(hn, hp)
        hn, hp = hn[good] * np.asarray(sign)[good, None], hp[good]
    if not len(hn):
        return None
    best = _best_hypothesis(p[score_idx], hn, hp, threshold)
    n0, c0 = hn[best], hp[best]
    inl0 = np.abs((p - c0) @ n0) <= threshold
    n, c, inl = _refine_plane(p, n0, c0, inl0, threshold, robust_scale)
    if keep_normal is not None and not keep_normal(n):
        # The refinement turned the plane out of the orientations the caller allows (the unseen
        # back cap of an object scanned alone, refined towards the line of sight): the hypothesis stands.
        n, c, inl = n0, c0, inl0
    return PlaneFit(n, c, inl, float(threshold), m)


def _inlier_threshold(p: np.ndarray, rng: np.random.Generator) -> float:
    """:math:`\tau`: half the median distance of a point of ``p`` (M, 3) to its 4th nearest neighbour.

    Measured on at most 20,000 random points; on a subsample of surface
    points the neighbour distance grows like 1/sqrt(density), so it is
    scaled back to the full set's.
    """
    m = len(p)
    sub = p[rng.choice(m, 20000, replace=False)] if m > 20000 else p
    k = min(4, len(sub) - 1)
    d, _ = cKDTree(sub).query(sub, k=k + 1)
    return 0.5 * float(np.median(d[:, k])) * np.sqrt(len(sub) / m)


def _hypotheses(p: np.ndarray, normals, n_hypotheses: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC hypotheses over ``p`` (M, 3): ``(unit normals (H, 3), points (H, 3))``.

    Planes through 3 random points; with ``normals`` (M, 3), half of them
    planes through one random point along its normal instead. Degenerate
    ones (collinear points, zero normals) are left out.
    """
    m = len(p)
    n_pt = n_hypotheses // 2 if normals is not None else 0
    tri = rng.integers(0, m, size=(n_hypotheses - n_pt, 3))
    hn = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
    hp = p[tri[:, 0]]
    if n_pt:
        nrm = np.asarray(normals, dtype=np.float64)
        one = rng.integers(0, m, size=n_pt)
        hn = np.concatenate([hn, nrm[one]])
        hp = np.concatenate([hp, p[one]])
    norm = np.linalg.norm(hn, axis=1)
    ok = norm > 1e-12
    return hn[ok] / norm[ok, None], hp[ok]


def _best_hypothesis(points: np.ndarray, hn: np.ndarray, hp: np.ndarray, threshold: float) -> int:
    """Index of the hypothesis with the most of ``points`` (K, 3) within ``threshold``; the first on ties."""
    off = np.einsum("ij,ij->i", hn, hp)
    best, best_score = -1, -1
    for start in range(0, len(hn), 64):
        dist = np.abs(points @ hn[start:start + 64].T - off[start:start + 64])
        score = (dist <= threshold).sum(axis=0)
        j = int(np.argmax(score))
        if score[j] > best_score:
            best, best_score = start + j, int(score[j])
    return best


def _refine_plane(p: np.ndarray, n: np.ndarray, c: np.ndarray, inl: np.ndarray, threshold: float,
                  robust_scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plane ``(n, c)`` refined on the points ``p`` (M, 3): ``(normal, point, inliers (M,) bool)``.

    Least squares on the inliers ``inl``, twice, re-selecting the inliers
    within ``threshold``; then, with ``robust_scale`` > 0, Cauchy-weighted
    least squares (module docstring). The normal keeps the side of ``n``.
    """
    for _ in range(2):
        if inl.sum() < 3:
            break
        n_new, c = _plane_ls(p[inl])
        n = n_new if n_new @ n >= 0 else -n_new
        inl = np.abs((p - c) @ n) <= threshold
    if robust_scale > 0 and inl.sum() >= 3:
        # A surface that undulates by more than tau (a lawn, a patio) is
        # caught by RANSAC as the band of one tangent plane; the mean plane
        # follows from Cauchy-weighted least squares over a wider band.
        cs = robust_scale * threshold
        for _ in range(5):
            r = (p - c) @ n
            near = np.abs(r) <= 3 * cs
            if near.sum() < 3:
                break
            wts = 1.0 / (1.0 + (r[near] / cs) ** 2)
            q = p[near]
            c = (wts[:, None] * q).sum(0) / wts.sum()
            d = (q - c) * np.sqrt(wts)[:, None]
            n_new = np.linalg.svd(d, full_matrices=False)[2][2]
            n = n_new if n_new @ n >= 0 else -n_new
        # ``inl`` stays the RANSAC band's: it counts the points the plane found.
    return n, c, inl


def flat_normals(scene: GaussianScene, idx: np.ndarray, flatness: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Normals of the Gaussians ``idx`` (M indices) and which of them are flat.

    Returns
    -------
    normals : (M, 3) float
        The axis of each Gaussian's smallest scale (unit, unsigned).
    flat : (M,) bool
        Smallest scale below ``flatness`` times the middle one.
    """
    s = scene.scales_at(idx).astype(np.float64)
    order = np.argsort(s, axis=1)
    smin = np.take_along_axis(s, order[:, :1], 1)[:, 0]
    smid = np.take_along_axis(s, order[:, 1:2], 1)[:, 0]
    return rotation_columns(scene.quats[idx], order[:, 0]), smin < flatness * smid


class _Prior(NamedTuple):
    """What a plane's orientation is checked against (module docstring, "Support plane")."""

    a: np.ndarray                   # (3,) image-up of the reference
    b: np.ndarray                   # (3,) backward direction of the reference, orthogonal to a
    r: np.ndarray                   # (3,) right vector of the reference
    cam_axis: np.ndarray | None     # (3,) up of the capture cameras, None when undetermined
    sin_roll: float                 # sin(max_roll_deg)
    cos_pitch: float                # cos(max_pitch_deg)
    cos_cam: float                  # cos(max_camera_deg)


class _Below(NamedTuple):
    """Where the object is, for the test "the object is above the plane"."""

    center: np.ndarray              # (3,) o
    max_height: float               # max_below * R
    g0_points: np.ndarray | None    # (K, 3) a subsample of G0's means, None without G0


def _up_options(options: dict) -> dict:
    """:data:`UP_DEFAULTS` updated by ``options``; unknown names raise a ValidationError listing the valid ones."""
    unknown = set(options) - set(UP_DEFAULTS)
    if unknown:
        raise ValidationError(f"estimate_up_axis: unknown options {sorted(unknown)}; valid: {sorted(UP_DEFAULTS)}")
    return {**UP_DEFAULTS, **options}


def _object_frame(means: np.ndarray, support, center, radius) -> tuple[np.ndarray | None, np.ndarray, float, bool]:
    """G0, the object's centre ``o`` and radius ``R``, and whether a local plane can be fitted.

    Parameters
    ----------
    means : (N, 3) float array
        The scene's means (taken in float64 where used).
    support, center, radius
        As in :func:`estimate_up_axis`.

    Returns
    -------
    g0 : (N,) bool or None
        None when not given or empty.
    center : (3,) float64
        ``center``; else G0's mean; else the scene's median.
    radius : float
        ``radius``; else the 95th percentile distance of G0 to ``o``; else
        1/20 of the scene's bounding-box diagonal.
    local_ok : bool
        A centre was given or G0 is known (else no local plane).

    Raises
    ------
    ValidationError
        ``support`` is not an (N,) bool array, ``center`` not a finite
        3-vector or ``radius`` not a positive distance.
    """
    n_all = len(means)
    g0 = None
    if support is not None:
        g0 = np.asarray(support)
        if g0.shape != (n_all,) or g0.dtype != bool:
            raise ValidationError(f"support must be a boolean array of shape ({n_all},), got "
                                  f"{g0.dtype} {g0.shape}")
        if not g0.any():
            g0 = None
    if center is None:
        o = means[g0].astype(np.float64).mean(axis=0) if g0 is not None else np.median(
            means.astype(np.float64), axis=0)
        local_ok = g0 is not None
    else:
        o = np.asarray(center, dtype=np.float64)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValidationError(f"center must be a finite 3-vector, got {center!r}")
        local_ok = True
    if radius is None:
        if g0 is not None:
            radius = float(np.percentile(np.linalg.norm(means[g0].astype(np.float64) - o, axis=1), 95))
        else:
            radius = float(np.linalg.norm(np.ptp(means.astype(np.float64), axis=0))) / 20
    radius = float(radius)
    if not (np.isfinite(radius) and radius > 0):
        raise ValidationError(f"radius must be a positive distance, got {radius!r}")
    return g0, o, radius, local_ok


def _camera_axis(cameras) -> tuple[np.ndarray | None, float, list[Camera]]:
    """The capture cameras' up (:func:`cameras_up`), its quality and the cameras as a list.

    The axis is None without cameras or when their quality is below
    :data:`_MIN_CAMERA_QUALITY` (their right vectors do not span a plane).
    """
    cam_axis, cam_quality, cams = None, 0.0, []
    if cameras is not None:
        cams = camera_list(cameras, "cameras")
        if cams:
            cam_axis, cam_quality = cameras_up(cams)
            if cam_quality < _MIN_CAMERA_QUALITY:
                cam_axis = None
    return cam_axis, cam_quality, cams


def _g0_sample(means: np.ndarray, g0: np.ndarray | None, seed: int) -> np.ndarray | None:
    """At most :data:`_MAX_G0_POINTS` means of G0 (a random subset, by ``seed``); None without G0."""
    if g0 is None:
        return None
    idx = np.flatnonzero(g0)
    if len(idx) > _MAX_G0_POINTS:
        idx = np.random.default_rng(seed).choice(idx, _MAX_G0_POINTS, replace=False)
    return means[idx].astype(np.float64)


def _plane_point_sets(scene: GaussianScene, frozen: FrozenScene | None, g0: np.ndarray | None,
                      center: np.ndarray, radius: float, local_ok: bool, reach: float,
                      opt: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The Gaussians the two planes are fitted on: ``(local, scene, region)`` int64 index arrays.

    ``region`` is every Gaussian of the scene set's ball (None: the whole
    scene), for :func:`_fallback_axis`.

    Both leave out G0 and splats with opacity below ``min_opacity``. The
    local set is those within ``local_factor`` ``R`` of ``o``, the scene
    set those within ``reach`` of ``o`` (:func:`~.local.neighbourhood`,
    through ``frozen``'s spatial index when given);
    without ``local_ok`` the local set is empty and the scene set is the
    whole scene. Each is randomly subsampled (sorted, by ``opt["seed"]``)
    to at most :data:`_MAX_FIT_POINTS`: the draw depends on the Gaussians
    inside the ball only.
    """
    def usable(idx: np.ndarray) -> np.ndarray:
        keep = scene.opacities_at(idx) >= opt["min_opacity"]
        if g0 is not None:
            keep &= ~g0[idx]
        idx = idx[keep]
        return np.sort(rng.choice(idx, _MAX_FIT_POINTS, replace=False)) if len(idx) > _MAX_FIT_POINTS else idx

    rng = np.random.default_rng(opt["seed"])
    if not local_ok:
        return np.zeros(0, np.int64), usable(np.arange(len(scene))), None
    where = scene if frozen is None else frozen
    local_idx = usable(neighbourhood(where, center, opt["local_factor"] * radius))
    region = neighbourhood(where, center, reach)
    return local_idx, usable(region), region


def _oriented(n: np.ndarray, prior: _Prior, use_prior: bool, steep: bool = False) -> np.ndarray:
    """Which of the unit normals ``n`` (H, 3), oriented by :func:`_admissible`, the prior allows: (H,) bool.

    Ordinary (``steep`` False, ``n . a >= 0``): always :math:`n \\cdot a \\ge \\cos`
    ``max_pitch_deg``; with ``use_prior`` also within ``max_camera_deg`` of
    the cameras' axis when there is one, else :math:`|n \\cdot r| \\le \\sin`
    ``max_roll_deg`` (the reference's no-roll prior). Steep (``n . b >= 0``,
    only under the no-roll prior): :math:`|n \\cdot a| < \\cos`
    ``max_pitch_deg`` and :math:`|n \\cdot r| \\le \\sin` ``max_roll_deg``,
    the pitches the ordinary bound refuses, from ``max_pitch_deg`` to as far
    past straight down.
    """
    if steep:
        return (np.abs(n @ prior.a) < prior.cos_pitch) & (np.abs(n @ prior.r) <= prior.sin_roll)
    if not use_prior:
        return n @ prior.a >= prior.cos_pitch
    if prior.cam_axis is not None:
        return n @ prior.cam_axis >= prior.cos_cam
    return (np.abs(n @ prior.r) <= prior.sin_roll) & (n @ prior.a >= prior.cos_pitch)


def _admissible(hn: np.ndarray, hp: np.ndarray, *, prior: _Prior, use_prior: bool,
                below: _Below | None, steep: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fit_plane`'s ``admissible`` test for the support plane: ``(ok (H,) bool, sign (H,))``.

    ``hn`` (H, 3) unit normals and ``hp`` (H, 3) points of the hypotheses.
    Each normal is oriented along the image-up ``a`` (``sign``), or with
    ``steep`` along the backward direction ``b`` (towards the camera's side:
    a view looking straight down has its image-up level); it is admissible
    when :func:`_oriented` allows it and, with ``below``, the object is
    above it: :math:`0 < n \\cdot (o - p) \\le` ``max_below`` ``R`` and the
    10th percentile of G0's heights above it is positive (the object stands
    on the surface, it is not part of it: a table top seen as G0 would
    otherwise be the surface it rests on).
    """
    sign = np.where(hn @ (prior.b if steep else prior.a) >= 0, 1.0, -1.0)
    n = hn * sign[:, None]
    ok = _oriented(n, prior, use_prior, steep)
    if below is not None:
        h = np.einsum("ij,ij->i", n, below.center - hp)
        ok &= (h > 0) & (h <= below.max_height)
        if below.g0_points is not None:
            hs = below.g0_points @ n.T - np.einsum("ij,ij->i", n, hp)
            ok &= np.percentile(hs, 10, axis=0) > 0
    return ok, sign


def _keeps_orientation(n: np.ndarray, *, prior: _Prior, use_prior: bool, steep: bool = False) -> bool:
    """:func:`fit_plane`'s ``keep_normal``: the refined (3,) normal keeps its side and the prior allows it."""
    return n @ (prior.b if steep else prior.a) > 0 and bool(_oriented(n[None], prior, use_prior, steep)[0])


def _fit_ground_plane(scene: GaussianScene, means: np.ndarray, idx: np.ndarray, *, prior: _Prior,
                      use_prior: bool, below: _Below | None, seed: int, opt: dict,
                      steep: bool = False) -> PlaneFit | None:
    """:func:`fit_plane` over the Gaussians ``idx``, flat ones giving 1-point hypotheses along their normals.

    ``steep`` selects the steep pitch window of :func:`_oriented`. Returns
    None with fewer than ``min_inliers`` (at least 3) points or when the
    best admissible plane has fewer than ``min_inliers`` inliers.
    """
    if len(idx) < max(opt["min_inliers"], 3):
        return None
    nrm, flat = flat_normals(scene, idx)
    nrm = np.where(flat[:, None], nrm, 0.0)  # non-flat splats give no 1-point hypothesis
    f = fit_plane(means[idx].astype(np.float64), normals=nrm,
                  admissible=partial(_admissible, prior=prior, use_prior=use_prior, below=below, steep=steep),
                  n_hypotheses=opt["n_hypotheses"], max_points=opt["max_points"], seed=seed,
                  robust_scale=opt["robust_scale"],
                  keep_normal=partial(_keeps_orientation, prior=prior, use_prior=use_prior, steep=steep))
    if f is None or f.n_inliers < opt["min_inliers"]:
        return None
    return f


class _Planes(NamedTuple):
    """What :func:`_search_planes` found."""

    local: PlaneFit | None          # the support plane
    glob: PlaneFit | None           # the scene plane
    roll_dropped: bool              # found without the roll prior
    steep_rival: float | None       # steep planes: the ordinary rival's inliers over theirs; else None


def _steep_rival(local_s: PlaneFit | None, glob_s: PlaneFit | None, local: PlaneFit | None,
                 glob: PlaneFit | None) -> float | None:
    """Whether the steep planes win over the ordinary ones: the ordinary rival's share of their inliers, or None.

    The ground extends, a wall seen face-on ends: when there is a steep
    scene plane it must hold :data:`_STEEP_FACTOR` times the ordinary scene
    plane's inliers and the steep local plane at least as many as the
    ordinary local plane; without one, the steep local plane must hold
    :data:`_STEEP_FACTOR` times the ordinary local plane's. The better
    steep plane must hold :data:`_FRACTION_MIN` of its points.
    """
    def k(f: PlaneFit | None) -> int:
        return f.n_inliers if f is not None else 0

    best = local_s if local_s is not None else glob_s
    if best is None or best.fraction < _FRACTION_MIN:
        return None
    if glob_s is not None:
        if k(glob_s) >= _STEEP_FACTOR * k(glob) and k(local_s) >= k(local):
            return k(glob) / k(glob_s)
        return None
    if k(local_s) >= _STEEP_FACTOR * k(local):
        return k(local) / k(local_s)
    return None


def _search_planes(scene: GaussianScene, means: np.ndarray, local_idx: np.ndarray, glob_idx: np.ndarray,
                   local_ok: bool, prior: _Prior, below: _Below, opt: dict) -> _Planes:
    """The support plane (local) and the scene plane, and how they were found.

    Under the prior first (seeds ``seed`` and ``seed + 1``); when the
    better of the two holds less than :data:`_FRACTION_FULL` of its points,
    again without the roll prior (seeds ``seed + 2``, ``seed + 3``), whose
    planes replace the first ones when the better holds at least that share
    and twice the inliers. Without capture cameras, then in the steep pitch
    window (:func:`_oriented`; seeds ``seed + 4``, ``seed + 5``): those
    planes replace the ordinary ones when they dominate them
    (:func:`_steep_rival`). The scene plane is tested against
    the object's position only when there is a local neighbourhood
    (``local_ok``).
    """
    seed = opt["seed"]
    glob_below = below if local_ok else None
    fit = partial(_fit_ground_plane, scene, means, prior=prior, opt=opt)
    local = fit(local_idx, use_prior=True, below=below, seed=seed) if local_ok else None
    glob = fit(glob_idx, use_prior=True, below=glob_below, seed=seed + 1)
    dropped = False
    best = local if local is not None else glob
    if best is None or best.fraction < _FRACTION_FULL:
        # Nothing convincing under the prior: the reference may have roll. Overriding the user's level
        # view takes a convincing plane: a small flat patch of an object scanned without ground (a
        # person, a guitar face) is no reason to orbit on its side.
        local_u = fit(local_idx, use_prior=False, below=below, seed=seed + 2) if local_ok else None
        glob_u = fit(glob_idx, use_prior=False, below=glob_below, seed=seed + 3)
        best_u = local_u if local_u is not None else glob_u
        if best_u is not None and best_u.fraction >= _FRACTION_FULL and (
                best is None or best_u.n_inliers >= 2 * best.n_inliers):
            local, glob, dropped = local_u, glob_u, True
    if prior.cam_axis is None:
        # A view pitched past max_pitch_deg (a drone looking straight down) has its ground's normal
        # near b, outside the ordinary window, where a wall seen face-on from a level view also lies:
        # the steep planes must dominate the ordinary ones to be taken.
        local_s = fit(local_idx, use_prior=True, below=below, seed=seed + 4, steep=True) if local_ok else None
        glob_s = fit(glob_idx, use_prior=True, below=glob_below, seed=seed + 5, steep=True)
        rival = _steep_rival(local_s, glob_s, local, glob)
        if rival is not None:
            return _Planes(local_s, glob_s, False, rival)
    return _Planes(local, glob, dropped, None)


def _screen_planes(local: PlaneFit | None, glob: PlaneFit | None, means: np.ndarray, glob_idx: np.ndarray,
                   center: np.ndarray, radius: float, local_ok: bool, local_factor: float,
                   details: dict) -> tuple[PlaneFit | None, PlaneFit | None]:
    """The planes that count as evidence, recording each in ``details``.

    The scene plane is dropped when under 10% of its points lie outside the
    local neighbourhood (the scene is the object's surroundings only: the
    two fits share their points, so their agreement would be no check).
    Both are dropped when neither holds :data:`_FRACTION_MIN` of its points
    (no ground in sight).
    """
    if local is not None and glob is not None and local_ok and np.mean(
            np.linalg.norm(means[glob_idx].astype(np.float64) - center, axis=1) > local_factor * radius) < 0.1:
        details["scene_plane_dropped"] = "fitted on the support plane's points: the scene holds little else"
        glob = None
    if local is not None:
        details["support_plane"] = local.summary()
    if glob is not None:
        details["scene_plane"] = glob.summary()
    if max((f.fraction for f in (local, glob) if f is not None), default=1.0) < _FRACTION_MIN:
        details["planes_rejected"] = f"no plane holds {_FRACTION_MIN:.0%} of its points: no ground in sight"
        local = glob = None
    return local, glob


def _credibility(plane: PlaneFit) -> float:
    """:math:`\\min(1, f / f_0)`: how much a plane's inlier share :math:`f` counts, as an answer or as a check."""
    return min(1.0, plane.fraction / _FRACTION_FULL)


def _check_angles(axis: np.ndarray, other: PlaneFit | None, prior: _Prior) -> tuple[list[float], list[float]]:
    """:math:`\\theta_k` in degrees and their weights :math:`w_k`: the angle to the other plane (weight its
    :func:`_credibility`), to the cameras' axis and off the no-roll plane (weight 1 each)."""
    th, wt = [], []
    if other is not None:
        th.append(angle_deg(axis, other.normal))
        wt.append(_credibility(other))
    if prior.cam_axis is not None:
        th.append(angle_deg(axis, prior.cam_axis))
        wt.append(1.0)
    th.append(float(np.degrees(np.arcsin(min(1.0, abs(axis @ prior.r))))))
    wt.append(1.0)
    return th, wt


def _plane_answer(chosen: PlaneFit, method: str, other: PlaneFit | None, prior: _Prior, agree_deg: float,
                  trust: float) -> tuple[np.ndarray, str, float, list[float], list[float]]:
    """``(axis, method, confidence, check angles, check weights)`` with ``chosen`` deciding and ``other`` as a check.

    When ``other`` agrees within ``agree_deg`` the axis is the two normals'
    inlier-weighted mean (method ``"support-plane+scene-plane"``): the same
    surface seen wider, whose many more inliers pin its direction down (a
    local patch of uneven ground is tilted by its slope); its inlier share
    is then the larger of the two (each fit found the surface; the small,
    dense local ball's band catches less of an undulating ground). The
    confidence is :math:`c` of the module docstring times ``trust``
    (:func:`_plane_trust`).
    """
    axis = chosen.normal / np.linalg.norm(chosen.normal)
    credibility = _credibility(chosen)
    if other is not None and angle_deg(axis, other.normal) <= agree_deg:
        axis = chosen.n_inliers * axis + other.n_inliers * other.normal
        axis /= np.linalg.norm(axis)
        method = "support-plane+scene-plane"
        credibility = max(credibility, _credibility(other))
    th, wt = _check_angles(axis, other, prior)
    agree = float(np.average(np.exp(-(np.asarray(th) / _CHECK_DEG) ** 2), weights=wt))
    return axis, method, credibility * agree * trust, th, wt


def _plane_trust(planes: _Planes) -> float:
    """The factor on a plane answer's confidence: 1/2 when the roll prior was dropped; for steep
    planes 1 minus the ordinary rival's share of their inliers (:func:`_steep_rival`)."""
    trust = 0.5 if planes.roll_dropped else 1.0
    return trust * (1.0 - planes.steep_rival) if planes.steep_rival is not None else trust


def _decide_plane(local: PlaneFit | None, glob: PlaneFit | None, prior: _Prior, agree_deg: float,
                  trust: float) -> tuple[np.ndarray, str, float, list[float], list[float]] | None:
    """The plane answer (:func:`_plane_answer`), or None without a plane.

    The local plane decides, checked against the scene plane; when the two
    disagree, a local "plane" can be a flat patch of the object's own unseen
    side or of nearby clutter, so the scene plane's answer, checked against
    the local one, wins when its confidence is higher (the disagreement
    stays in the confidence: it is real doubt).
    """
    answer = partial(_plane_answer, prior=prior, agree_deg=agree_deg, trust=trust)
    if local is not None:
        best = answer(local, "support-plane", glob)
        if glob is not None and best[1] == "support-plane":
            alt = answer(glob, "scene-plane", local)
            if alt[2] > best[2]:
                best = alt
        return best
    if glob is not None:
        return answer(glob, "scene-plane", None)
    return None


#: The confidence of the normals' answer, the most confident :func:`_fallback_axis` gives without
#: capture cameras.
_NORMALS_CONFIDENCE = 0.2


def _fallback_axis(scene: GaussianScene, region: np.ndarray | None, reference: Camera, a: np.ndarray,
                   cam_axis: np.ndarray | None, cam_quality: float, details: dict) -> UpEstimate:
    """The answer without a plane: the cameras' axis, else the normals (:func:`estimate_up`), else the image-up.

    The normals are those of the Gaussians ``region`` (indices; None: the
    whole scene). They are used only within :data:`_NORMALS_MAX_PITCH_DEG` of the
    image-up ``a`` (confidence 0.2); otherwise the image-up itself
    (confidence 0.1). The cameras' answer has confidence 0.8 times their quality.
    """
    if cam_axis is not None:
        return UpEstimate(cam_axis, "cameras", float(0.8 * cam_quality), details)
    axis = np.asarray(estimate_up(scene if region is None else scene.subset(region), reference), dtype=np.float64)
    axis /= np.linalg.norm(axis)
    if angle_deg(axis, a) < 1e-9 or angle_deg(axis, a) > _NORMALS_MAX_PITCH_DEG:
        return UpEstimate(a.copy(), "image-up", 0.1, details)
    return UpEstimate(axis, "normals", _NORMALS_CONFIDENCE, details)


def estimate_up_axis(scene: GaussianScene | FrozenScene, reference: Camera, support=None, center=None,
                     radius: float | None = None, cameras: Iterable[Camera] | None = None,
                     **options) -> UpEstimate:
    """World up for the VAAS orbit axis; see the module docstring for the method.

    Parameters
    ----------
    scene : GaussianScene or FrozenScene
        A :class:`~seed2gs_inverse.raster.FrozenScene` finds the Gaussians
        about the object through its spatial index
        (:func:`~.local.neighbourhood`); the estimate is the same.
    reference : Camera
        The user's view ``c_r``.
    support : (N,) bool or None
        G0 (the lifted set: ``SeedLift.g0``), left out of the plane fits
        and required to lie above the support plane.
    center : (3,) array or None
        Object centre ``o``; None: G0's mean, or without G0 the scene's
        median (then no local plane is fitted).
    radius : float or None
        Object radius ``R``; None: from G0's spread (the 95th percentile
        distance to ``center``), or 1/20 of the scene's size.
    cameras : iterable of Camera or None
        Capture cameras (e.g. the training cameras of the splat).
    **options
        Any of :data:`UP_DEFAULTS`.

    Returns
    -------
    UpEstimate

    Raises
    ------
    ValidationError
        An unknown option, an empty scene, a reference that is not a
        Camera, or a ``support``, ``center``, ``radius`` or ``cameras`` of
        the wrong kind.
    """
    opt = _up_options(options)
    frozen = scene if isinstance(scene, FrozenScene) else None
    scene = scene.scene if frozen is not None else scene
    if not isinstance(scene, GaussianScene) or len(scene) == 0:
        raise ValidationError("estimate_up_axis: scene must be a non-empty GaussianScene or FrozenScene")
    a, b, r = roll_basis(reference)
    means = scene.means  # float32, taken in float64 where used: no copy of all N
    g0, o, radius, local_ok = _object_frame(means, support, center, radius)
    cam_axis, cam_quality, cams = _camera_axis(cameras)
    prior = _Prior(a, b, r, cam_axis, np.sin(np.radians(opt["max_roll_deg"])),
                   np.cos(np.radians(opt["max_pitch_deg"])), np.cos(np.radians(opt["max_camera_deg"])))
    below = _Below(o, opt["max_below"] * radius, _g0_sample(means, g0, opt["seed"]))
    reach = max(opt["scene_factor"] * float(np.linalg.norm(reference.center - o)), 3 * opt["local_factor"] * radius)
    local_idx, glob_idx, region = _plane_point_sets(scene, frozen, g0, o, radius, local_ok, reach, opt)
    details: dict = {"center": o.tolist(), "radius": radius, "reference_up": a.tolist(),
                     "n_local_points": int(len(local_idx)), "scene_reach": reach if local_ok else None}
    planes = _search_planes(scene, means, local_idx, glob_idx, local_ok, prior, below, opt)
    local, glob = _screen_planes(planes.local, planes.glob, means, glob_idx, o, radius, local_ok,
                                 opt["local_factor"], details)
    if cam_axis is not None:
        details["cameras"] = {"axis": cam_axis.tolist(), "quality": cam_quality, "n": len(cams)}
    best = _decide_plane(local, glob, prior, opt["agree_deg"], _plane_trust(planes))
    if best is None:
        return _fallback_axis(scene, region, reference, a, cam_axis, cam_quality, details)
    axis, method, conf, th, wt = best
    details["check_angles_deg"] = th
    details["check_weights"] = wt
    if planes.steep_rival is not None:
        details["steep_rival_share"] = planes.steep_rival
    suffix = ("; roll prior dropped" if planes.roll_dropped
              else "; steep reference" if planes.steep_rival is not None else "")
    answer = UpEstimate(axis, method + suffix, float(np.clip(conf, 0, 1)), details)
    if planes.roll_dropped or (answer.confidence >= _NORMALS_CONFIDENCE and cam_axis is None):
        # the answers without a plane assume the no-roll prior this plane had to drop; or none of them
        # can be more confident
        return answer
    fallback = _fallback_axis(scene, region, reference, a, cam_axis, cam_quality, dict(details))
    if fallback.confidence <= answer.confidence:
        return answer
    fallback.details["rejected_plane"] = {"axis": answer.axis.tolist(), "method": answer.method,
                                          "confidence": answer.confidence}
    return fallback
