r"""The orbit axis: world "up" from robust geometry (issue 10, part 1).

VAAS orbits the object about an axis; if that axis is not the world's up
the "flat" orbit rolls about the viewing direction or dives under the
ground and never shows the far side. :func:`estimate_up_axis` combines
several independent cues and reports which one decided and how sure it is.

Cues
----
Reference no-roll constraint
    Nearly every user view has no roll: its x axis :math:`r` is level, so
    :math:`u \cdot r = 0` and :math:`u \in \mathrm{span}(a, b)` with
    :math:`a` the image-up (:attr:`Camera.up`) and :math:`b` the backward
    direction made orthogonal to :math:`a`. The camera's pitch is the angle
    of :math:`u` from :math:`a` in that plane. Used as a filter on plane
    candidates (:math:`|n \cdot r| \le \sin` ``max_roll_deg``) and as a check.
Training cameras (``cameras``)
    Under the same no-roll assumption for every capture camera,
    :math:`u \perp r_j` for all of them, so

    .. math::

        u = \arg\min_{\|u\| = 1} \sum_j (r_j \cdot u)^2,

    the eigenvector of the smallest eigenvalue :math:`\lambda_1` of
    :math:`\sum_j r_j r_j^\top`, signed so that :math:`\sum_j a_j \cdot u > 0`.
    It is determined when the right vectors span a plane: its quality is
    :math:`(\lambda_2 - \lambda_1) / \lambda_3` (0 when all cameras share one
    right vector, e.g. a single camera). In COLMAP captures this is the world up.
Support plane (local)
    The object rests on something. Gaussian means within ``local_factor``
    times the object's radius :math:`R` of its centre :math:`o`, minus the
    object's own support G0 and nearly transparent splats, are fitted with
    RANSAC. Hypotheses are planes through 3 random points and planes through
    the centre of a random flat Gaussian along its normal (the axis of its
    smallest scale). A hypothesis :math:`(n, p)`, oriented so that
    :math:`n \cdot a > 0` (up points up in the image), is admissible when

    * it agrees with the prior: :math:`|n \cdot r| \le \sin` ``max_roll_deg``
      and :math:`n \cdot a \ge \cos` ``max_pitch_deg`` (or, with training
      cameras, :math:`\angle(n, u_{cam}) \le` ``max_camera_deg``), and
    * the object is above it: :math:`0 < n \cdot (o - p) \le`
      ``max_below`` :math:`R` (a wall behind the object, oriented this way,
      has the object on its negative side), and at least 90% of G0 lies on
      its positive side (a plane through G0, e.g. the top of a table when
      G0 is that top, is the object, not its support).

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
    weighted fit recovers the mean plane (on the procedural ground with
    12 cm undulations: scene-plane error 4.7 degrees without, 0.3 with).
    Vertical clutter (grass, plants, fences) does not form a plane under
    the object, so it cannot win however many flat splats it has.
Scene plane (global)
    The same fit over a random subsample of the whole scene (the dominant
    large plane below the object): a cross-check for the local plane, and
    the answer when the neighbourhood holds too few points.
Normals (fallback)
    :func:`~seed2gs_inverse.pipeline.vaas.estimate_up`: the dominant normal
    of flat splats within the no-roll plane. Wrong in vegetation; used only
    when nothing above is available, with confidence 0.2.

Decision and confidence
-----------------------
The local support plane wins when it has at least ``min_inliers`` inliers,
unless the scene plane disagrees with it by more than ``agree_deg`` and,
taken as the answer (checked against the local plane), has the higher
confidence :math:`c` below (method ``"scene-plane"``; the disagreement
stays one of its checks, so such an answer is usually weak and warns): a
local "plane" can
be a flat patch of the object's own unseen side, denser than the ground
(on yard-unicorn-15 of benchmarks/bench_extract.py, a patch on the
unicorn's back, far off the vertical, against the lawn that holds a much
larger share of the scene). When the scene plane agrees with it within
``agree_deg`` (5 degrees) they
are the same surface seen at two extents, and the axis is their
inlier-weighted mean normal :math:`(k_l n_l + k_g n_g) / \|\cdot\|`
(method ``"support-plane+scene-plane"``): a local patch of uneven ground is
tilted by its slope, the wide fit averages the slopes out. Without a local
plane the scene plane is used; otherwise the training cameras; otherwise the
normals. If no admissible plane under the roll prior holds at least
:math:`f_0` (below) of its points, the search is repeated without the roll
prior (the reference may have roll; the pitch bound stays); when that finds
a plane with at least twice the inliers it is used, marked
``"...; roll prior dropped"``, at half confidence. The confidence of
a plane is

.. math::

    c = \min\!\left(1, \frac{f}{f_0}\right) \cdot
        \frac{1}{K} \sum_{k=1}^{K} \exp\!\left(-(\theta_k / 8^\circ)^2\right),

with :math:`f` the plane's inlier fraction of its point set
(:math:`f_0 = 0.15`) and :math:`\theta_k` the angles between the chosen
axis and each available check: the no-roll plane of the reference
(:math:`\arcsin |u \cdot r|`, always), the other plane and the training
cameras' axis when there are. Camera-only answers have confidence 0.8 times
the cameras' quality. Below ``WEAK_CONFIDENCE`` (0.5) the pipeline warns and
names ``--up``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..errors import ValidationError

__all__ = ["UpEstimate", "PlaneFit", "estimate_up_axis", "fit_plane", "cameras_up", "roll_basis",
           "angle_deg", "WEAK_CONFIDENCE", "UP_DEFAULTS"]

#: Below this confidence the pipeline warns and suggests ``--up``.
WEAK_CONFIDENCE = 0.5

#: Defaults of :func:`estimate_up_axis`.
UP_DEFAULTS = {"local_factor": 3.0, "max_below": 3.0, "max_roll_deg": 20.0, "max_pitch_deg": 80.0,
               "max_camera_deg": 25.0, "agree_deg": 5.0, "min_inliers": 30, "n_hypotheses": 400, "max_points": 6000,
               "min_opacity": 0.2, "robust_scale": 3.0, "seed": 0}

_CHECK_DEG = 8.0
_FRACTION_FULL = 0.15
#: When neither plane holds this share of its points there is no ground in sight (an object scanned
#: alone: the best "planes" of a scanned person or guitar hold a few percent) and neither is used: the
#: axis comes from the cameras, the normals or the image-up.
_FRACTION_MIN = 0.05
#: The normals fallback is taken only within this angle of the image-up (a view pitched further with
#: no plane in sight is less likely than a dominant flat surface that is not the ground).
_NORMALS_MAX_PITCH_DEG = 45.0


def angle_deg(u, v) -> float:
    """Angle between two directions in degrees (sign-sensitive)."""
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
        ``"support-plane"``, ``"scene-plane"``, ``"cameras"``, ``"normals"``
        or ``"image-up"`` (``"; roll prior dropped"`` appended when the plane
        search had to ignore the reference's no-roll prior).
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
        return {"axis": [float(v) for v in self.axis], "method": self.method,
                "confidence": float(self.confidence), "details": self.details}


@dataclass(frozen=True)
class PlaneFit:
    """A plane ``n . (x - point) = 0`` fitted by :func:`fit_plane`."""

    normal: np.ndarray
    point: np.ndarray
    inliers: np.ndarray   # (M,) bool over the fitted points: the RANSAC band (before any robust refit)
    threshold: float
    n_points: int

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())

    @property
    def fraction(self) -> float:
        return self.n_inliers / max(self.n_points, 1)

    def summary(self) -> dict:
        return {"normal": [float(v) for v in self.normal], "point": [float(v) for v in self.point],
                "n_inliers": self.n_inliers, "n_points": int(self.n_points),
                "fraction": float(self.fraction), "threshold": float(self.threshold)}


def roll_basis(reference: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, r)``: image-up, backward made orthogonal to it, and the camera's right vector."""
    if not isinstance(reference, Camera):
        raise ValidationError(f"reference must be a Camera, got {type(reference).__name__}")
    a = reference.up / np.linalg.norm(reference.up)
    b = -reference.forward
    b = b - (b @ a) * a
    b /= np.linalg.norm(b)
    return a, b, reference.right / np.linalg.norm(reference.right)


def camera_list(cameras, name: str) -> list:
    """``cameras`` (any iterable of Camera, read once: a generator too) as a list; ``name`` heads the errors."""
    if isinstance(cameras, Camera):
        raise ValidationError(f"{name} must be a sequence of Camera, got one Camera; pass [camera]")
    try:
        cams = list(cameras)
    except TypeError:
        raise ValidationError(f"{name} must be a sequence of Camera, got {type(cameras).__name__}") from None
    if not all(isinstance(c, Camera) for c in cams):
        raise ValidationError(f"{name} must be a sequence of Camera")
    return cams


def cameras_up(cameras) -> tuple[np.ndarray, float]:
    r"""World up from capture cameras without roll, and its quality.

    :math:`u` minimises :math:`\sum_j (r_j \cdot u)^2` over the cameras'
    right vectors :math:`r_j` (smallest eigenvector of :math:`\sum_j r_j
    r_j^\top`, eigenvalues :math:`\lambda_1 \le \lambda_2 \le \lambda_3`),
    signed to agree with the mean image-up. Quality
    :math:`(\lambda_2 - \lambda_1) / \lambda_3` in [0, 1]: 0 when the right
    vectors are all parallel (one camera: the axis is then undetermined),
    near 1 when they spread over a plane.
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


def _plane_ls(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    return vt[2], c


def fit_plane(points, *, normals=None, threshold: float | None = None, admissible=None,
              n_hypotheses: int = 400, max_points: int = 6000, seed: int = 0,
              robust_scale: float = 0.0, keep_normal=None) -> PlaneFit | None:
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
    PlaneFit or None (fewer than 3 points or no admissible hypothesis).
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise ValidationError(f"fit_plane: points must be a finite (M, 3) array, got shape {p.shape}")
    m = len(p)
    if m < 3:
        return None
    rng = np.random.default_rng(seed)
    score_idx = rng.choice(m, max_points, replace=False) if m > max_points else np.arange(m)
    sp = p[score_idx]
    if threshold is None:
        # On a subsample of surface points the neighbour distance grows like
        # 1/sqrt(density): scale it back to the full set's.
        sub = p[rng.choice(m, 20000, replace=False)] if m > 20000 else p
        k = min(4, len(sub) - 1)
        d, _ = cKDTree(sub).query(sub, k=k + 1)
        threshold = 0.5 * float(np.median(d[:, k])) * np.sqrt(len(sub) / m)
    if not threshold > 0:
        threshold = 1e-6
    nh = int(n_hypotheses)
    n_pt = nh // 2 if normals is not None else 0
    tri = rng.integers(0, m, size=(nh - n_pt, 3))
    hn = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
    hp = p[tri[:, 0]]
    if n_pt:
        nrm = np.asarray(normals, dtype=np.float64)
        one = rng.integers(0, m, size=n_pt)
        hn = np.concatenate([hn, nrm[one]])
        hp = np.concatenate([hp, p[one]])
    norm = np.linalg.norm(hn, axis=1)
    ok = norm > 1e-12
    hn, hp = hn[ok] / norm[ok, None], hp[ok]
    if admissible is not None and len(hn):
        good, sign = admissible(hn, hp)
        hn, hp = hn[good] * np.asarray(sign)[good, None], hp[good]
    if not len(hn):
        return None
    off = np.einsum("ij,ij->i", hn, hp)
    best, best_score = -1, -1
    for start in range(0, len(hn), 64):
        dist = np.abs(sp @ hn[start:start + 64].T - off[start:start + 64])
        score = (dist <= threshold).sum(axis=0)
        j = int(np.argmax(score))
        if score[j] > best_score:
            best, best_score = start + j, int(score[j])
    n0, c0 = n, c = hn[best], hp[best]
    inl = np.abs((p - c) @ n) <= threshold
    inl0 = inl
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
        # ``inl`` stays the RANSAC band's: it measures the support found.
    if keep_normal is not None and not keep_normal(n):
        # The refinement turned the plane out of the orientations the caller allows (the unseen
        # back cap of an object scanned alone, refined towards the line of sight): the hypothesis stands.
        n, c, inl = n0, c0, inl0
    return PlaneFit(n, c, inl, float(threshold), m)


def _flat_normals(scene, idx: np.ndarray, flatness: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Normals (axis of the smallest scale) of the flat Gaussians among ``idx``, and which are flat."""
    from ..scene import quat_to_rotmat

    s = scene.scales[idx].astype(np.float64)
    order = np.argsort(s, axis=1)
    smin = np.take_along_axis(s, order[:, :1], 1)[:, 0]
    smid = np.take_along_axis(s, order[:, 1:2], 1)[:, 0]
    rot = quat_to_rotmat(scene.quats[idx])
    n = rot[np.arange(len(idx)), :, order[:, 0]]
    return n, smin < flatness * smid


def estimate_up_axis(scene, reference: Camera, support=None, center=None, radius: float | None = None,
                     cameras=None, **options) -> UpEstimate:
    """World up for the VAAS orbit axis; see the module docstring for the method.

    Parameters
    ----------
    scene : GaussianScene
    reference : Camera
        The user's view ``c_r``.
    support : (N,) bool or None
        The object's lifted support G0 (left out of the plane fits).
    center : (3,) array or None
        Object centre ``o``; None: the support's mean, or without support
        the scene's median (then no local plane is fitted).
    radius : float or None
        Object radius ``R``; None: from the support's spread (the 95th
        percentile distance to ``center``), or 1/20 of the scene's size.
    cameras : sequence of Camera or None
        Capture cameras (e.g. the training cameras of the splat).
    **options
        Any of :data:`UP_DEFAULTS`.

    Returns
    -------
    UpEstimate
    """
    from ..scene import GaussianScene

    unknown = set(options) - set(UP_DEFAULTS)
    if unknown:
        raise ValidationError(f"estimate_up_axis: unknown options {sorted(unknown)}; valid: {sorted(UP_DEFAULTS)}")
    opt = {**UP_DEFAULTS, **options}
    if not isinstance(scene, GaussianScene) or len(scene) == 0:
        raise ValidationError("estimate_up_axis: scene must be a non-empty GaussianScene")
    a, b, r = roll_basis(reference)
    n_all = len(scene)
    means = scene.means.astype(np.float64)
    if support is not None:
        support = np.asarray(support)
        if support.shape != (n_all,) or support.dtype != bool:
            raise ValidationError(f"support must be a boolean array of shape ({n_all},), got "
                                  f"{support.dtype} {support.shape}")
        if not support.any():
            support = None
    if center is None:
        o = means[support].mean(axis=0) if support is not None else np.median(means, axis=0)
        local_ok = support is not None
    else:
        o = np.asarray(center, dtype=np.float64)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValidationError(f"center must be a finite 3-vector, got {center!r}")
        local_ok = True
    if radius is None:
        if support is not None:
            radius = float(np.percentile(np.linalg.norm(means[support] - o, axis=1), 95))
        else:
            radius = float(np.linalg.norm(np.ptp(means, axis=0))) / 20
    radius = float(radius)
    if not (np.isfinite(radius) and radius > 0):
        raise ValidationError(f"radius must be a positive distance, got {radius!r}")

    cam_axis, cam_quality, cams = None, 0.0, []
    if cameras is not None:
        cams = camera_list(cameras, "cameras")
        if cams:
            cam_axis, cam_quality = cameras_up(cams)
            if cam_quality < 0.05:
                cam_axis = None

    sin_roll = np.sin(np.radians(opt["max_roll_deg"]))
    cos_pitch = np.cos(np.radians(opt["max_pitch_deg"]))
    cos_cam = np.cos(np.radians(opt["max_camera_deg"]))

    def oriented(n, use_prior: bool):
        """Which of the unit normals ``n`` (H, 3), oriented with ``n . a >= 0``, the prior allows."""
        if not use_prior:
            return n @ a >= cos_pitch
        if cam_axis is not None:
            return n @ cam_axis >= cos_cam
        return (np.abs(n @ r) <= sin_roll) & (n @ a >= cos_pitch)

    def make_filter(use_prior: bool, below: bool):
        def admissible(hn, hp):
            sign = np.where(hn @ a >= 0, 1.0, -1.0)
            n = hn * sign[:, None]
            ok = oriented(n, use_prior)
            if below:
                h = np.einsum("ij,ij->i", n, o - hp)
                ok &= (h > 0) & (h <= opt["max_below"] * radius)
                if sup_pts is not None:
                    # The object stands on its support, it is not part of
                    # it: most of G0 must be above the plane (else a table
                    # top seen as G0 would be its own "support").
                    hs = sup_pts @ n.T - np.einsum("ij,ij->i", n, hp)
                    ok &= np.percentile(hs, 10, axis=0) > 0
            return ok, sign
        return admissible

    sup_pts = None
    if support is not None:
        sup_idx = np.flatnonzero(support)
        if len(sup_idx) > 256:
            sup_idx = np.random.default_rng(opt["seed"]).choice(sup_idx, 256, replace=False)
        sup_pts = means[sup_idx]
    opacity = scene.opacities
    usable = opacity >= opt["min_opacity"]
    if support is not None:
        usable &= ~support
    rng = np.random.default_rng(opt["seed"])

    def fit(idx, use_prior, below, seed):
        if len(idx) < max(opt["min_inliers"], 3):
            return None
        nrm, flat = _flat_normals(scene, idx)
        nrm = np.where(flat[:, None], nrm, 0.0)  # non-flat splats give no 1-point hypothesis
        f = fit_plane(means[idx], normals=nrm, admissible=make_filter(use_prior, below),
                      n_hypotheses=opt["n_hypotheses"], max_points=opt["max_points"], seed=seed,
                      robust_scale=opt["robust_scale"],
                      keep_normal=lambda n: n @ a > 0 and bool(oriented(n[None], use_prior)[0]))
        if f is None or f.n_inliers < opt["min_inliers"]:
            return None
        return f

    # Point sets: the neighbourhood of the object, and a subsample of the scene.
    local_idx = np.zeros(0, np.int64)
    if local_ok:
        dist = np.linalg.norm(means - o, axis=1)
        local_idx = np.flatnonzero(usable & (dist <= opt["local_factor"] * radius))
        if len(local_idx) > 60000:
            local_idx = np.sort(rng.choice(local_idx, 60000, replace=False))
    glob_idx = np.flatnonzero(usable)
    if len(glob_idx) > 60000:
        glob_idx = np.sort(rng.choice(glob_idx, 60000, replace=False))

    details: dict = {"center": o.tolist(), "radius": radius, "reference_up": a.tolist(),
                     "n_local_points": int(len(local_idx))}
    method_suffix = ""
    local = fit(local_idx, True, True, opt["seed"]) if local_ok else None
    glob = fit(glob_idx, True, local_ok, opt["seed"] + 1)
    best = local if local is not None else glob
    if best is None or best.fraction < _FRACTION_FULL:
        # Nothing convincing under the prior: the reference may have roll.
        # Search again without it and keep that answer only when the
        # geometry clearly prefers it (twice the inliers).
        local_u = fit(local_idx, False, True, opt["seed"] + 2) if local_ok else None
        glob_u = fit(glob_idx, False, local_ok, opt["seed"] + 3)
        best_u = local_u if local_u is not None else glob_u
        # Overriding the user's level view takes a convincing plane: a small flat patch of an object
        # scanned without ground (a person, a guitar face) is no reason to orbit on its side.
        if best_u is not None and best_u.fraction >= _FRACTION_FULL and (
                best is None or best_u.n_inliers >= 2 * best.n_inliers):
            local, glob = local_u, glob_u
            method_suffix = "; roll prior dropped"
    if local is not None and glob is not None and local_ok and np.mean(
            np.linalg.norm(means[glob_idx] - o, axis=1) > opt["local_factor"] * radius) < 0.1:
        # The scene is (almost) only the object's neighbourhood (an object scanned alone): its plane
        # is fitted on the same points as the local one, and their agreement would be no check.
        details["scene_plane_dropped"] = "fitted on the support plane's points: the scene holds little else"
        glob = None
    if local is not None:
        details["support_plane"] = local.summary()
    if glob is not None:
        details["scene_plane"] = glob.summary()
    if max((f.fraction for f in (local, glob) if f is not None), default=1.0) < _FRACTION_MIN:
        details["planes_rejected"] = f"no plane holds {_FRACTION_MIN:.0%} of its points: no ground in sight"
        local = glob = None
    if cam_axis is not None:
        details["cameras"] = {"axis": cam_axis.tolist(), "quality": cam_quality, "n": len(cams)}

    def checks(axis, other_plane):
        th = []
        if other_plane is not None:
            th.append(angle_deg(axis, other_plane.normal))
        if cam_axis is not None:
            th.append(angle_deg(axis, cam_axis))
        th.append(float(np.degrees(np.arcsin(min(1.0, abs(axis @ r))))))
        return th

    def answer(chosen, method, other):
        """(axis, method, confidence, check angles) with ``chosen`` deciding and ``other`` as a check."""
        axis = chosen.normal / np.linalg.norm(chosen.normal)
        if other is not None and angle_deg(axis, other.normal) <= opt["agree_deg"]:
            # The same surface seen wider: the local plane picked it, the
            # scene plane's many more inliers pin its direction down (a
            # local patch of uneven ground is tilted by its slope).
            axis = chosen.n_inliers * axis + other.n_inliers * other.normal
            axis /= np.linalg.norm(axis)
            method = "support-plane+scene-plane"
        th = checks(axis, other)
        agree = float(np.mean(np.exp(-(np.asarray(th) / _CHECK_DEG) ** 2)))
        conf = min(1.0, chosen.fraction / _FRACTION_FULL) * agree
        return axis, method, conf * (0.5 if method_suffix else 1.0), th

    best = None
    if local is not None:
        best = answer(local, "support-plane", glob)
        if glob is not None and best[1] == "support-plane":
            # The two planes disagree: a local "plane" can be a flat patch of
            # the object's own unseen side or of nearby clutter. The better
            # supported answer wins, each checked against the other (the
            # disagreement stays in the confidence: it is real doubt).
            alt = answer(glob, "scene-plane", local)
            if alt[2] > best[2]:
                best = alt
    elif glob is not None:
        best = answer(glob, "scene-plane", None)
    if best is not None:
        axis, method, conf, th = best
        details["check_angles_deg"] = th
        return UpEstimate(axis, method + method_suffix, float(np.clip(conf, 0, 1)), details)
    if cam_axis is not None:
        return UpEstimate(cam_axis, "cameras", float(0.8 * cam_quality), details)
    from .vaas import estimate_up

    axis = np.asarray(estimate_up(scene, reference), dtype=np.float64)
    axis /= np.linalg.norm(axis)
    if angle_deg(axis, a) < 1e-9 or angle_deg(axis, a) > _NORMALS_MAX_PITCH_DEG:
        return UpEstimate(a.copy(), "image-up", 0.1, details)
    return UpEstimate(axis, "normals", 0.2, details)
