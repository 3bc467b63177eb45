r"""VAAS: visibility-adaptive ascending spiral (paper Section 3.4, Eq. 5).

Two clips of virtual views around the object centre ``o``, both starting at
the reference camera ``c_r`` (frame 0 *is* the reference pose, so a tracker
receives the seed mask on frame 0):

flat orbit
    the reference camera centre rotated about the axis through ``o`` along
    the reference camera's up vector ``u`` (:attr:`Camera.up`; no world axis
    is assumed) by :math:`360 k / n` degrees, ``k = 0..n-1``. Height above
    ``o`` along ``u`` and horizontal radius are those of the reference.
ascending spiral
    the same azimuth sweep with the elevation rising from the reference
    elevation :math:`e_0` to :math:`e_0 + A`; the distance to ``o`` is kept.
    Profile ``"linear"`` (default): :math:`e_k = e_0 + A k/(n-1)`; ``"sin"``:
    :math:`e_k = e_0 + A \sin(\pi k / (2 (n-1)))` (climbs faster early).
    Elevations are capped at ``max_elevation_deg`` (85 degrees) so the up
    vector never becomes parallel to the viewing direction.

Frames ``k >= 1`` look at ``o`` (it lies on their optical axis) with image-up
``u``, with the reference intrinsics or, given ``fit_radius``, zoomed so
that the object fills the view (object-centric views).

The amplitude adapts to the visibility of G0 (the lifted set of the seed
lift) along the flat orbit (Eq. 5): :math:`A = A_{max} (1 - \bar V)^\gamma`, where
:math:`\bar V` is the mean over flat views of the fraction of G0 whose
projected centre is in the image at a depth within :math:`\epsilon_d` of the
rendered depth. The spiral is skipped when :math:`A <` ``skip_deg`` (paper: 5
degrees). The paper gives 24 views per clip and the 5 degree rule; it does
not give :math:`A_{max}` and :math:`\gamma`: we use 60 degrees and 1 (a
target seen in half of the flat views climbs 30 degrees, which shows its top
from a typical eye-level reference).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..camera import Camera, look_at_orbit, orbit_directions
from ..errors import ValidationError

if TYPE_CHECKING:
    from ..operators import ViewOperator

__all__ = ["ClipFrame", "VAASPlan", "flat_orbit", "spiral_orbit", "spiral_elevations", "orbit_cameras", "run_vaas",
           "support_visibility", "vaas_amplitude", "DEFAULTS"]

#: Paper defaults (views per clip, skip threshold) and our documented choices.
DEFAULTS = {"n_views": 24, "a_max_deg": 60.0, "gamma": 1.0, "skip_deg": 5.0,
            "profile": "linear", "max_elevation_deg": 85.0, "eps_rel": 0.02, "eps_sigma": 2.0}


@dataclass
class ClipFrame:
    """One rendered view of a clip: what a tracker receives.

    ``rgb`` (H, W, 3) float32 in [0, 1]; ``depth`` (H, W) float32 expected
    depth (0 where empty); ``alpha`` (H, W) float32; ``camera`` the view;
    ``clip`` ("flat" or "spiral") and ``index`` within the clip;
    ``operator`` the view's ``ViewOperator`` when the pipeline built it in
    the same rasterization pass (None otherwise).
    """

    rgb: np.ndarray
    depth: np.ndarray
    alpha: np.ndarray
    camera: Camera
    clip: str = ""
    index: int = 0
    operator: ViewOperator | None = None


@dataclass
class VAASPlan:
    """The VAAS decision: cameras of both clips and the numbers behind it.

    Attributes
    ----------
    flat, spiral : list of Camera
        The clips' cameras (``spiral`` empty when skipped).
    visibility : float
        :math:`\bar V`, the mean of ``per_view_visibility``.
    per_view_visibility : (n_views,) float64
        The visible fraction of G0 in each flat view (:func:`support_visibility`).
    amplitude_deg : float
        :math:`A` of Eq. 5.
    skipped_spiral : bool
        :math:`A <` ``skip_deg``.
    settings : dict
        The settings used, JSON-ready.
    """

    flat: list[Camera]
    spiral: list[Camera]
    visibility: float
    per_view_visibility: np.ndarray
    amplitude_deg: float
    skipped_spiral: bool
    settings: dict = field(default_factory=dict)

    @property
    def cameras(self) -> list[Camera]:
        """Both clips' cameras, flat first."""
        return list(self.flat) + list(self.spiral)

    def summary(self) -> dict:
        """JSON-ready fields (``report.json``)."""
        return {"visibility": float(self.visibility), "amplitude_deg": float(self.amplitude_deg),
                "skipped_spiral": bool(self.skipped_spiral), "n_flat": len(self.flat),
                "n_spiral": len(self.spiral),
                "per_view_visibility": [float(v) for v in self.per_view_visibility], **self.settings}


def _frame(reference: Camera, center, up=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The orbit frame ``(o, u, e1, distance, e0)``: centre, unit axis, unit horizontal direction to the
    reference, the reference's distance to ``o`` and its elevation (radians).

    Raises
    ------
    ValidationError
        A non-finite centre, a zero or non-finite axis, a centre at the
        reference camera, or a reference straight above or below ``o``.
    """
    o = np.asarray(center, dtype=np.float64)
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise ValidationError(f"orbit centre must be a finite 3-vector, got {center!r}")
    u = reference.up if up is None else np.asarray(up, dtype=np.float64)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) < 1e-12:
        raise ValidationError(f"orbit up must be a finite non-zero 3-vector, got {up!r}")
    u = u / np.linalg.norm(u)
    d = reference.center - o
    dist = float(np.linalg.norm(d))
    if dist < 1e-9:
        raise ValidationError("orbit centre coincides with the reference camera centre")
    height = float(d @ u)
    horiz = d - height * u
    rho = float(np.linalg.norm(horiz))
    if rho < 1e-6 * dist:
        raise ValidationError(
            "the reference camera is straight above or below the object centre (along its own up "
            "vector): the orbit has no horizontal radius; choose a reference that sees the object "
            "from the side")
    return o, u, horiz / rho, dist, float(np.arctan2(height, rho))


def orbit_cameras(reference: Camera, center, azimuths_deg, elevations_deg=None,
                  fit_radius: float | None = None, up=None) -> list[Camera]:
    r"""Cameras on a sphere about ``center`` through the reference camera centre.

    Parameters
    ----------
    reference : Camera
        ``c_r``; its up vector ``u`` is the orbit axis, its intrinsics are reused.
    center : (3,) array
        Orbit centre ``o``.
    azimuths_deg : (n,) array
        Rotation about the axis ``(o, u)`` from the reference, right-handed about ``u``.
    elevations_deg : (n,) array or None
        Elevation above the plane through ``o`` perpendicular to ``u``; None
        keeps the reference elevation (a flat orbit).
    fit_radius : float or None
        None: the views keep the reference intrinsics. A radius ``r``: the
        views (except the reference itself) zoom so that the sphere of radius
        ``r`` about ``o`` just fits the smaller image side
        (:math:`f = \tfrac12 \min(W, H) \sqrt{d^2 - r^2} / r`, square
        pixels, principal point at the image centre). Object-centric views
        put the pixels on the object; the reference distance is kept.

    up : (3,) array or None
        Orbit axis ``u``; None: the reference camera's image-up
        (:attr:`Camera.up`). See :mod:`~seed2gs_inverse.pipeline.up_axis` for a levelled axis.

    Raises
    ------
    ValidationError
        A degenerate frame (see :func:`_frame`), a non-positive
        ``fit_radius``, or as many elevations as azimuths not given.

    Returns
    -------
    list of Camera
        View ``k`` is the reference itself when its azimuth is 0 and its
        elevation the reference one; otherwise it looks at ``o`` with image-up ``u``.
    """
    o, u, e1, dist, e0 = _frame(reference, center, up)
    base = reference
    if fit_radius is not None:
        r = float(fit_radius)
        if not (np.isfinite(r) and r > 0):
            raise ValidationError(f"fit_radius must be a positive distance, got {fit_radius!r}")
        r = min(r, 0.95 * dist)
        f = 0.5 * min(reference.width, reference.height) * np.sqrt(dist ** 2 - r ** 2) / r
        base = Camera(reference.width, reference.height, f, f, reference.width / 2, reference.height / 2,
                      reference.world_to_camera, reference.name, reference.near)
    az = np.radians(np.asarray(azimuths_deg, dtype=np.float64).ravel())
    el = np.full(az.shape, e0) if elevations_deg is None else np.radians(
        np.asarray(elevations_deg, dtype=np.float64).ravel())
    if el.shape != az.shape:
        raise ValidationError(f"orbit: {az.size} azimuths but {el.size} elevations")
    # Frames at azimuth 0 and the reference elevation are the reference itself
    # (a tracker gets the seed mask on frame 0); the others look at o.
    is_ref = (np.abs(az) < 1e-12) & (np.abs(el - e0) < 1e-12)
    moved = iter(look_at_orbit(o, orbit_directions(u, e1, az[~is_ref], el[~is_ref]), dist, u,
                               np.degrees(reference.fov_y), reference.width, reference.height))
    return [reference if r else base.with_pose(next(moved).world_to_camera) for r in is_ref]


def flat_orbit(reference: Camera, center, n_views: int = 24, fit_radius: float | None = None,
               up=None) -> list[Camera]:
    """The flat, reference-anchored orbit of ``n_views`` cameras (360 k / n degrees)."""
    n = _check_n(n_views)
    return orbit_cameras(reference, center, 360.0 * np.arange(n) / n, fit_radius=fit_radius, up=up)


def spiral_elevations(reference: Camera, center, amplitude_deg: float, n_views: int = 24,
                      profile: str = "linear", max_elevation_deg: float = 85.0, up=None) -> np.ndarray:
    """Elevations (degrees) of the ascending spiral: reference elevation + pitch_k, capped."""
    n = _check_n(n_views)
    _, _, _, _, e0 = _frame(reference, center, up)
    t = np.arange(n) / max(n - 1, 1)
    if profile == "linear":
        pitch = amplitude_deg * t
    elif profile == "sin":
        pitch = amplitude_deg * np.sin(0.5 * np.pi * t)
    else:
        raise ValidationError(f"spiral profile must be 'linear' or 'sin', got {profile!r}")
    el = np.degrees(e0) + pitch
    cap = max(float(max_elevation_deg), np.degrees(e0))
    return np.minimum(el, cap)


def spiral_orbit(reference: Camera, center, amplitude_deg: float, n_views: int = 24,
                 profile: str = "linear", max_elevation_deg: float = 85.0,
                 fit_radius: float | None = None, up=None) -> list[Camera]:
    """The ascending spiral: the flat orbit's azimuths with elevations from :func:`spiral_elevations`."""
    if not np.isfinite(amplitude_deg) or amplitude_deg < 0:
        raise ValidationError(f"spiral amplitude must be a non-negative angle, got {amplitude_deg!r}")
    n = _check_n(n_views)
    el = spiral_elevations(reference, center, amplitude_deg, n, profile, max_elevation_deg, up)
    return orbit_cameras(reference, center, 360.0 * np.arange(n) / n, el, fit_radius, up)


def _check_n(n_views) -> int:
    """``n_views`` as an int >= 2 (an integral float passes), or a ValidationError."""
    if isinstance(n_views, bool) or int(n_views) != n_views or int(n_views) < 2:
        raise ValidationError(f"n_views must be an integer >= 2, got {n_views!r}")
    return int(n_views)


def support_visibility(means: np.ndarray, sigma: np.ndarray, camera: Camera, depth: np.ndarray,
                       eps_rel: float = 0.02, eps_sigma: float = 2.0) -> float:
    r"""Fraction of the given Gaussians visible in one view under depth-consistent projection.

    A Gaussian counts as visible when its projected centre lies in the image,
    in front of the near plane, and :math:`|z_i - D(\pi_i)| \le \epsilon_{rel} z_i +
    \epsilon_\sigma s_i` (the seed-lift tolerance). ``means`` (M, 3), ``sigma`` (M,)
    largest standard deviations, ``depth`` (H, W) rendered expected depth.
    Returns the fraction in [0, 1] (0 for no Gaussians).

    Raises
    ------
    ValidationError
        ``depth`` is not of the camera's (H, W).
    """
    means = np.asarray(means, dtype=np.float64)
    if len(means) == 0:
        return 0.0
    h, w = camera.image_shape
    if np.asarray(depth).shape != (h, w):
        raise ValidationError(f"visibility: depth has shape {np.asarray(depth).shape}, expected {(h, w)}")
    uv, z = camera.project(means)
    ok = np.isfinite(uv).all(axis=1) & (z > camera.near)
    px = np.floor(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    py = np.floor(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    ok &= (px >= 0) & (px < w) & (py >= 0) & (py < h)
    vis = np.zeros(len(means), bool)
    i = np.nonzero(ok)[0]
    dd = np.asarray(depth, np.float64)[py[i], px[i]]
    vis[i] = (dd > 0) & (np.abs(z[i] - dd) <= eps_rel * z[i] + eps_sigma * np.asarray(sigma)[i])
    return float(vis.mean())


def vaas_amplitude(visibility: float, a_max_deg: float = 60.0, gamma: float = 1.0) -> float:
    r"""Eq. 5: :math:`A = A_{max} (1 - \bar V)^\gamma` in degrees, with :math:`\bar V` clipped to [0, 1]."""
    if not (np.isfinite(a_max_deg) and a_max_deg >= 0 and np.isfinite(gamma) and gamma > 0):
        raise ValidationError(f"need a_max_deg >= 0 and gamma > 0, got {a_max_deg!r}, {gamma!r}")
    v = float(np.clip(visibility, 0.0, 1.0))
    return float(a_max_deg * (1.0 - v) ** gamma)


def run_vaas(support_means: np.ndarray, support_sigma: np.ndarray, reference: Camera, center,
             view: Callable[[Camera, str, int], ClipFrame], *, n_views: int = 24, a_max_deg: float = 60.0,
             gamma: float = 1.0, skip_deg: float = 5.0, profile: str = "linear", max_elevation_deg: float = 85.0,
             eps_rel: float = 0.02, eps_sigma: float = 2.0, fit_radius: float | None = None,
             up=None) -> tuple[VAASPlan, list[ClipFrame], list[ClipFrame]]:
    """Plan and render both VAAS clips.

    Parameters
    ----------
    support_means : (M, 3) array
        Means of G0 (the lifted set of the seed lift).
    support_sigma : (M,) array
        Their largest standard deviations (depth tolerance, see :func:`support_visibility`).
    reference : Camera
        ``c_r`` at the resolution the clips are rendered at.
    center : (3,) array
        Orbit centre ``o``.
    view : callable ``view(camera, clip, index) -> ClipFrame``
        Renders one view (the pipeline builds the view's operator in the same
        pass and returns it as ``ClipFrame.operator``); called once per flat view, then once per spiral
        view when the spiral is not skipped.
    n_views, a_max_deg, gamma, skip_deg, profile, max_elevation_deg, eps_rel, eps_sigma
        See the module docstring and :data:`DEFAULTS`.
    fit_radius : float or None
        Object-centric zoom of the views, see :func:`orbit_cameras`.
    up : (3,) array or None
        Orbit axis; None: the reference camera's image-up.

    Returns
    -------
    plan : VAASPlan
    flat_frames, spiral_frames : list of ClipFrame
        ``spiral_frames`` is empty when the spiral is skipped.
    """
    flat = flat_orbit(reference, center, n_views, fit_radius, up)
    flat_frames = [view(cam, "flat", k) for k, cam in enumerate(flat)]
    per_view = np.array([support_visibility(support_means, support_sigma, f.camera, f.depth,
                                            eps_rel, eps_sigma) for f in flat_frames])
    vbar = float(per_view.mean())
    amp = vaas_amplitude(vbar, a_max_deg, gamma)
    skipped = amp < skip_deg
    spiral, spiral_frames = [], []
    if not skipped:
        spiral = spiral_orbit(reference, center, amp, n_views, profile, max_elevation_deg, fit_radius, up)
        spiral_frames = [view(cam, "spiral", k) for k, cam in enumerate(spiral)]
    settings = {"n_views": int(n_views), "a_max_deg": float(a_max_deg), "gamma": float(gamma),
                "skip_deg": float(skip_deg), "profile": profile,
                "max_elevation_deg": float(max_elevation_deg),
                "fit_radius": None if fit_radius is None else float(fit_radius),
                "up": (reference.up if up is None else np.asarray(up, float) / np.linalg.norm(up)).tolist()}
    plan = VAASPlan(flat, spiral, vbar, per_view, amp, bool(skipped), settings)
    return plan, flat_frames, spiral_frames
