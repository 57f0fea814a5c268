"""Direct tests of wallpose.plane against ground truth.

Every scene is built from a known wall (tests.support.synthetic_wallpose.wall_plane) and a known rig
(synthetic_wallpose.default_views with the head turned): the projector's corner pixels are cast onto the wall by
explicit pinhole maths (with a planted head error and, where stated, image corrections drawn from the model's
priors), the cameras' views come from cv2.projectPoints, then Gaussian pixel noise with a fixed seed and gross
outliers are added. Nothing is shared between tests: each builds its own arrays. Tolerances come from float64
precision, the noise σ, the fit's own covariance, or binomial and chi-square tails over corners and seeds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from scipy import stats

from geometry.intrinsics import Intrinsics
from geometry.poses import invert, look_at, make_pose, rotation_about, rotation_angle_deg, rvec_tvec_from_pose
from tests.support.synthetic_wallpose import default_views, wall_plane
from wallpose import limits
from wallpose.pattern import choose_pattern
from wallpose.plane import (
    AFFINE,
    N_PARAMS,
    PLANE,
    PROJ_AFFINE,
    PROJ_ROT,
    PROJ_TRANS,
    MLFit,
    MLModel,
    ViewData,
    fit_ml,
    plane_from_points,
    plane_in_frame,
    ransac_plane,
    transfer_residuals_px,
)
from wallpose.rig import ViewRig
from wallpose.triangulate import triangulate_stereo

EPS = float(np.finfo(np.float64).eps)
SIGMA_PX = 0.1          # corner noise of a good detection; well above limits.SIGMA_FLOOR_PX, so the floor never binds
PER_FIT_TAIL = 1e-4     # tail probability of each single-fit check (~4 σ): ~130 such checks, so ~1 % odds overall
ACROSS_SEEDS_TAIL = 1e-3  # tail probability of each binomial / chi-square check over many seeds or corners
GAUSS_NEWTON_TOL = 1e-7   # fit_ml stops when the plane step is below this fraction of |p| (plane.py)
ML_CORNERS = 120          # corners per maximum-likelihood fit: ample for its statistics, and 40 fits stay quick
FORWARD_STEP = 1e-7       # plane.py's forward-difference step for the plane (relative) and the projector (absolute)


# --- ground truth -----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Scene:
    """The rig, the pattern's corner pixels in the projector and the true wall as p (X·p = 1, left camera frame)."""

    views: ViewRig
    projector_px: NDArray[np.float64]
    p_true: NDArray[np.float64]

    @property
    def T_right_from_left(self) -> NDArray[np.float64]:
        return self.views.T_camera_right_from_camera_left

    @property
    def f(self) -> float:
        return float(self.views.camera_left.fx)


def _views() -> ViewRig:
    """The default rig with the head turned 8° right and 5° down: the projector's frame is rotated against the
    cameras', so a correction applied in the wrong frame shows."""
    views = default_views()
    eye = views.T_robot_from_projector[:3, 3]
    pan, tilt = np.radians(-8.0), np.radians(-5.0)
    axis = np.array([np.cos(tilt) * np.cos(pan), np.cos(tilt) * np.sin(pan), np.sin(tilt)])
    return replace(views, T_robot_from_projector=look_at(eye, eye + axis))


def _scene(distance_m: float = 2.0, incidence_deg: float = 30.0, corners: int | None = None) -> Scene:
    """The pattern choose_pattern lays out for this wall; corners: an even subset of that many (as detection keeps
    at most limits.MAX_CORNERS), default all."""
    views = _views()
    px = choose_pattern(views, distance_m, incidence_deg).corner_projector_px
    if corners is not None:
        px = px[np.unique(np.linspace(0, len(px) - 1, corners).astype(np.int64))]
    return Scene(views, px.copy(), _left_plane(views, distance_m, incidence_deg))


def _left_plane(views: ViewRig, distance_m: float, incidence_deg: float) -> NDArray[np.float64]:
    """The synthetic wall (robot frame, n·X = -d) as p in the left camera frame: (-n/d)·X = 1."""
    n, d = wall_plane(distance_m, incidence_deg, views).in_frame(invert(views.T_robot_from_camera_left))
    return -n / d


def _pinhole_rays(intr: Intrinsics, px: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit-z rays through pixels of a distortion-free view, by the pinhole formula."""
    return np.column_stack([(px[:, 0] - intr.cx) / intr.fx, (px[:, 1] - intr.cy) / intr.fy, np.ones(len(px))])


def _affine(xy: NDArray[np.float64], a: NDArray[np.float64]) -> NDArray[np.float64]:
    """The model's image correction written out: x' = x + a0 + a2 x + a3 y, y' = y + a1 + a4 x + a5 y."""
    x, y = xy[:, 0], xy[:, 1]
    return np.column_stack([x + a[0] + a[2] * x + a[3] * y, y + a[1] + a[4] * x + a[5] * y])


def _true_corners(scene: Scene, theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 3) left-frame points where the projector really casts its corners: true pose = nominal · (Rodrigues(ξ_r),
    ξ_t), light leaving along the affinely corrected ray, meeting the true plane."""
    R, _ = cv2.Rodrigues(theta[PROJ_ROT])
    T = scene.views.T_camera_left_from_projector @ make_pose(R, theta[PROJ_TRANS])
    rays = _pinhole_rays(scene.views.projector, scene.projector_px)
    d = np.column_stack([_affine(rays[:, :2], theta[PROJ_AFFINE]), np.ones(len(rays))]) @ T[:3, :3].T
    o = T[:3, 3]
    p = theta[PLANE]
    return o + ((1.0 - p @ o) / (d @ p))[:, None] * d


def _pixels(intr: Intrinsics, T_cam_from_left: NDArray[np.float64], X: NDArray[np.float64]) -> NDArray[np.float64]:
    if len(X) == 0:                                  # cv2.projectPoints returns None for no points
        return np.zeros((0, 2))
    rvec, tvec = rvec_tvec_from_pose(T_cam_from_left)
    return cv2.projectPoints(X, rvec, tvec, intr.K, None)[0].reshape(-1, 2)


def _normalized(intr: Intrinsics, T_cam_from_left: NDArray[np.float64], X: NDArray[np.float64],
                affine: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Exact normalized image coordinates of left-frame points in a view (cv2.projectPoints, then K⁻¹)."""
    uv = (_pixels(intr, T_cam_from_left, X) - [intr.cx, intr.cy]) / [intr.fx, intr.fy]
    return uv if affine is None else _affine(uv, affine)


def _prior_sigmas(scene: Scene) -> NDArray[np.float64]:
    """The prior σ of the 24 nuisance parameters in the model's units, from the limits: the head's repeatability
    (rad, m), then per camera and for the projector an image offset σ_px / f and a gradient reaching σ_px at the
    image's edge, σ_px / half width (the correction multiplies normalized coordinates)."""
    cam, proj = scene.views.camera_left, scene.views.projector
    head = [np.radians(limits.PROJECTOR_ROTATION_SIGMA_DEG)] * 3 + [limits.PROJECTOR_TRANSLATION_SIGMA_M] * 3
    camera = [limits.IMAGE_OFFSET_SIGMA_PX / cam.fx] * 2 + [limits.IMAGE_GRADIENT_SIGMA_PX / (0.5 * cam.width)] * 4
    projector = ([limits.PROJECTOR_OFFSET_SIGMA_PX / proj.fx] * 2
                 + [limits.PROJECTOR_GRADIENT_SIGMA_PX / (0.5 * proj.width)] * 4)
    return np.array(head + camera + camera + projector)


def _model(scene: Scene, normalized: list[NDArray[np.float64]], seen: list[NDArray[np.bool_]],
           projector_px: NDArray[np.float64] | None = None) -> MLModel:
    v = scene.views
    px = scene.projector_px if projector_px is None else projector_px
    views = [ViewData(np.eye(4), v.camera_left.fx, seen[0], normalized[0]),
             ViewData(scene.T_right_from_left, v.camera_right.fx, seen[1], normalized[1])]
    return MLModel(_pinhole_rays(v.projector, px), v.T_camera_left_from_projector, views,
                   np.radians(limits.PROJECTOR_ROTATION_SIGMA_DEG), limits.PROJECTOR_TRANSLATION_SIGMA_M,
                   limits.IMAGE_OFFSET_SIGMA_PX, limits.IMAGE_GRADIENT_SIGMA_PX, 0.5 * v.camera_left.width,
                   v.projector.fx, limits.PROJECTOR_OFFSET_SIGMA_PX, limits.PROJECTOR_GRADIENT_SIGMA_PX,
                   0.5 * v.projector.width)


def _explicit_transfer_px(scene: Scene, p: NDArray[np.float64], normalized_left: NDArray[np.float64],
                          normalized_right: NDArray[np.float64]) -> NDArray[np.float64]:
    """Transfer error by another route: left ray ∩ plane by X = ray / (ray·p), cv2.projectPoints into the right
    camera, pixel distance to where the right camera saw the corner."""
    rays = np.column_stack([normalized_left, np.ones(len(normalized_left))])
    X = rays / (rays @ p)[:, None]
    cam = scene.views.camera_right
    seen_px = normalized_right * [cam.fx, cam.fy] + [cam.cx, cam.cy]
    return np.linalg.norm(_pixels(cam, scene.T_right_from_left, X) - seen_px, axis=1)


def _transfer_gain(scene: Scene) -> float:
    """Bound on how much a left-image shift moves its transferred point in the right image: for parallel cameras
    (R = I, t_z = 0) the transfer is x_r = x_l + t (p·[x_l, 1]), with Jacobian I + t p_xyᵀ, so gain ≤ 1 + |t||p|."""
    T = scene.T_right_from_left
    assert np.allclose(T[:3, :3], np.eye(3), atol=1e-12) and abs(T[2, 3]) < 1e-12  # the bound's premise
    return 1.0 + float(np.linalg.norm(T[:3, 3]) * np.linalg.norm(scene.p_true))


def _transfer_outside_probability(scene: Scene, threshold_px: float, sigma_px: float) -> float:
    """P(transfer error of a clean corner > threshold): the error is right noise minus the left noise carried over,
    a 2-D Gaussian with per-axis σ ≤ σ√(1 + gain²), so P ≤ exp(-t² / (2 σ² (1 + gain²))) (Rayleigh tail)."""
    s2 = sigma_px ** 2 * (1.0 + _transfer_gain(scene) ** 2)
    return float(np.exp(-threshold_px ** 2 / (2.0 * s2)))


def _max_misses(n: int, p: float) -> int:
    """Largest count of n independent events of probability p that is still plausible (binomial upper tail)."""
    return int(stats.binom.isf(ACROSS_SEEDS_TAIL, n, p))


def _plane_errors(p_hat: NDArray[np.float64], p_true: NDArray[np.float64], C: NDArray[np.float64]
                  ) -> tuple[float, float, float]:
    """Errors of an estimated plane, whitened by its reported covariance C (3x3 of p), linearized at the estimate:
    (Mahalanobis² of the normal's direction [2 dof], distance error / its σ [1 dof], Mahalanobis² of p [3 dof]).
    normal = p/|p|, distance = 1/|p| from the left camera."""
    norm = float(np.linalg.norm(p_hat))
    n_hat, n_true = p_hat / norm, p_true / np.linalg.norm(p_true)
    J_n = (np.eye(3) - np.outer(n_hat, n_hat)) / norm
    basis = np.linalg.svd(np.outer(n_hat, n_hat))[0][:, 1:]        # two unit vectors across the normal
    e_n = basis.T @ (n_true - n_hat)
    C_n = basis.T @ J_n @ C @ J_n.T @ basis
    J_d = -p_hat / norm ** 3
    z_d = (1.0 / np.linalg.norm(p_true) - 1.0 / norm) / float(np.sqrt(J_d @ C @ J_d))
    e = p_hat - p_true
    return float(e_n @ np.linalg.solve(C_n, e_n)), float(z_d), float(e @ np.linalg.solve(C, e))


def _angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    c = (a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))          # signed: p and -p are different planes
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


@dataclass
class Observed:
    """Noisy observations of one scene: normalized (n, 2) per camera (NaN where unseen), seen masks, and the
    corners made gross outliers (a corner finder's mistake: shifted in one image by pixels)."""

    normalized: list[NDArray[np.float64]]
    seen: list[NDArray[np.bool_]]
    glitched: NDArray[np.bool_]


def _observe(scene: Scene, theta: NDArray[np.float64], rng: np.random.Generator, sigma_px: float = SIGMA_PX,
             glitch_fraction: float = 0.0, unseen_fraction: float = 0.0, glitch_px: tuple[float, float] = (2.0, 20.0)
             ) -> Observed:
    X = _true_corners(scene, theta)
    n = len(X)
    out, seen = [], []
    for k, (intr, T) in enumerate(((scene.views.camera_left, np.eye(4)),
                                   (scene.views.camera_right, scene.T_right_from_left))):
        uv = _normalized(intr, T, X, theta[AFFINE[k]]) + rng.normal(0.0, sigma_px, (n, 2)) / intr.fx
        s = rng.random(n) >= unseen_fraction
        uv[~s] = np.nan
        out.append(uv)
        seen.append(s)
    glitched = (rng.random(n) < glitch_fraction) & seen[0] & seen[1]
    idx = np.nonzero(glitched)[0]
    which = rng.integers(0, 2, len(idx))
    size = rng.uniform(*glitch_px, len(idx)) / scene.f
    angle = rng.uniform(0.0, 2.0 * np.pi, len(idx))
    for i, w, s, a in zip(idx, which, size, angle, strict=True):
        out[w][i] += s * np.array([np.cos(a), np.sin(a)])
    return Observed(out, seen, glitched)


def _true_theta(scene: Scene, nuisances: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    theta = np.zeros(N_PARAMS)
    theta[PLANE] = scene.p_true
    if nuisances is not None:
        theta[3:] = nuisances
    return theta


def _ransac_then_ml(scene: Scene, obs: Observed, seed: int) -> tuple[MLModel, MLFit]:
    """The estimator's own sequence (estimate.py): triangulate the corners both cameras see, RANSAC, ML fit."""
    both = obs.seen[0] & obs.seen[1]
    nl, nr = obs.normalized[0][both], obs.normalized[1][both]
    points = triangulate_stereo(nl, nr, scene.T_right_from_left)
    p0, inl = ransac_plane(points, nl, nr, scene.T_right_from_left, scene.f, np.random.default_rng(seed))
    inliers = np.zeros(len(both), bool)
    inliers[np.nonzero(both)[0][inl]] = True
    model = _model(scene, obs.normalized, obs.seen)
    return model, fit_ml(model, p0, inliers)


def _gate_outside_probability(fit: MLFit) -> float:
    """P(a clean corner fails fit_ml's inlier gate of INLIER_SIGMAS robust σ): 1.4826 · MAD over m residuals is good
    to 1.166/√m relative, so the gate is ≥ INLIER_SIGMAS σ (1 - 4 · 1.166/√m) but for a 4 SE chance; the corner's
    error in each of its (up to) two views is the norm of a 2-D Gaussian, so P ≤ 2 exp(-gate² / 2σ²)."""
    m = int((fit.row_view >= 0).sum())
    gate_sigmas = limits.INLIER_SIGMAS * (1.0 - 4.0 * 1.166 / np.sqrt(m))
    return float(2.0 * np.exp(-gate_sigmas ** 2 / 2.0))


def _sigma_bound(fit: MLFit) -> float:
    """|σ̂/σ - 1| plausible for the a-posteriori noise: 4 standard errors (1/√(2 dof)) plus the bias of counting
    only 3 of the N_PARAMS parameters against the m pixel residuals (≤ N_PARAMS / (2 m))."""
    m = int((fit.row_view >= 0).sum())
    return 4.0 / np.sqrt(2.0 * (m - N_PARAMS)) + N_PARAMS / (2.0 * m)


# --- the model's configuration -----------------------------------------------------------------------------------

def test_model_priors_are_the_limits_in_model_units() -> None:
    scene = _scene()
    model = _model(scene, [np.zeros((1, 2))] * 2, [np.ones(1, bool)] * 2, scene.projector_px[:1])
    assert model.prior_sigmas.shape == (N_PARAMS - 3,)
    assert np.allclose(model.prior_sigmas, _prior_sigmas(scene), rtol=10 * EPS, atol=0.0)  # same formula, ~1 ulp


# --- plane_from_points -------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("distance_m", "incidence_deg"), [(2.0, 30.0), (4.0, 60.0), (0.8, 0.0)])
def test_plane_from_points_recovers_an_exact_plane(distance_m: float, incidence_deg: float) -> None:
    views = _views()
    p_true = _left_plane(views, distance_m, incidence_deg)
    rng = np.random.default_rng(1)
    rays = _pinhole_rays(views.camera_left, rng.uniform([0, 0], [1280, 800], (500, 2)))
    X = rays / (rays @ p_true)[:, None]                               # on the plane, in front of the camera
    p = plane_from_points(X)
    lam = np.linalg.eigvalsh((X - X.mean(axis=0)).T @ (X - X.mean(axis=0)))
    # round-off of the scatter's n-term sums (≤ n eps relative) divided by its eigen-gap (λ_mid - λ_min ≈ λ_mid)
    tol = len(X) * EPS * lam[2] / lam[1]
    assert np.linalg.norm(p - p_true) <= tol * np.linalg.norm(p_true), (p, p_true)


def test_plane_from_points_is_the_least_squares_plane() -> None:
    scene = _scene()
    rng = np.random.default_rng(2)
    rays = _pinhole_rays(scene.views.camera_left, rng.uniform([0, 0], [1280, 800], (400, 2)))
    n_true = scene.p_true / np.linalg.norm(scene.p_true)
    X = rays / (rays @ scene.p_true)[:, None] + rng.normal(0.0, 0.005, (400, 1)) * n_true  # 5 mm off the wall

    def sse(p: NDArray[np.float64]) -> float:                         # squared orthogonal distances |X·p - 1|/|p|
        return float(np.sum((X @ p - 1.0) ** 2) / (p @ p))

    p = plane_from_points(X)
    best = sse(p)
    assert best <= sse(scene.p_true)
    # any small tilt or shift does worse: 1e-4 |p| changes the sum by ~1e-4 of itself, far above its round-off
    for dp in np.vstack([np.eye(3), -np.eye(3)]) * 1e-4 * np.linalg.norm(p):
        assert sse(p + dp) > best * (1.0 + 1e3 * EPS)


def test_plane_from_points_through_the_origin_is_undefined() -> None:
    rng = np.random.default_rng(3)
    xz = rng.uniform([-1.0, 1.0], [1.0, 3.0], (50, 2))
    X = np.column_stack([xz[:, 0], np.zeros(50), xz[:, 1]])           # the horizontal plane through the camera
    assert np.isnan(plane_from_points(X)).all()


# --- transfer_residuals_px ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("toe_in_deg", [0.0, 2.0])
def test_transfer_residuals_vanish_on_the_true_plane_and_match_reprojection_elsewhere(toe_in_deg: float) -> None:
    scene = _scene()
    if toe_in_deg:                                   # the right camera turned towards the left one: R ≠ I
        T = make_pose(rotation_about([0.0, 1.0, 0.0], np.radians(-toe_in_deg))) @ scene.T_right_from_left
        scene = replace(scene, views=replace(scene.views, T_camera_right_from_camera_left=T))
    X = _true_corners(scene, _true_theta(scene))
    nl = _normalized(scene.views.camera_left, np.eye(4), X)
    nr = _normalized(scene.views.camera_right, scene.T_right_from_left, X)
    # two routes of a few dozen float64 operations on normalized coordinates of order 1: they agree to ~100 eps,
    # i.e. 100 eps · f in pixels
    tol_px = 100 * EPS * scene.f
    err = transfer_residuals_px(scene.p_true, nl, nr, scene.T_right_from_left, scene.f)
    assert err.shape == (1, len(X))
    assert np.max(err) <= tol_px

    n_true = scene.p_true / np.linalg.norm(scene.p_true)
    d_true = 1.0 / np.linalg.norm(scene.p_true)
    shifts = [0.002, 0.01, 0.05]                                      # the wall 2 mm, 1 cm, 5 cm farther away
    wrong = [n_true / (d_true + s) for s in shifts]
    wrong.append(rotation_about([0.0, 1.0, 0.0], np.radians(1.0)) @ scene.p_true)    # turned by 1°
    batch = transfer_residuals_px(np.array(wrong), nl, nr, scene.T_right_from_left, scene.f)
    assert batch.shape == (len(wrong), len(X))
    for k, p in enumerate(wrong):
        expected = _explicit_transfer_px(scene, p, nl, nr)
        assert np.allclose(batch[k], expected, rtol=0.0, atol=tol_px * (1.0 + expected.max())), k
        single = transfer_residuals_px(p, nl, nr, scene.T_right_from_left, scene.f)[0]
        assert np.allclose(single, batch[k], rtol=0.0, atol=tol_px * (1.0 + expected.max())), k
    # a wall farther away puts every corner farther from where the right camera saw it
    assert np.all(np.diff(batch[:3], axis=0) > 0)
    assert np.min(batch[0]) > tol_px


def test_transfer_residuals_behind_the_camera_are_infinite() -> None:
    scene = _scene()
    X = _true_corners(scene, _true_theta(scene))
    nl = _normalized(scene.views.camera_left, np.eye(4), X)
    nr = _normalized(scene.views.camera_right, scene.T_right_from_left, X)
    # -p: the same plane mirrored through the camera, met by every left ray behind it; never an inlier
    err = transfer_residuals_px(-scene.p_true, nl, nr, scene.T_right_from_left, scene.f)
    assert np.isposinf(err).all()


# --- ransac_plane ------------------------------------------------------------------------------------------------

def _ransac_inputs(scene: Scene, X: NDArray[np.float64], rng: np.random.Generator, sigma_px: float = SIGMA_PX
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    nl = _normalized(scene.views.camera_left, np.eye(4), X) + rng.normal(0.0, sigma_px, (len(X), 2)) / scene.f
    nr = (_normalized(scene.views.camera_right, scene.T_right_from_left, X)
          + rng.normal(0.0, sigma_px, (len(X), 2)) / scene.f)
    return triangulate_stereo(nl, nr, scene.T_right_from_left), nl, nr


def _assert_plane_near(scene: Scene, p: NDArray[np.float64], points: NDArray[np.float64], sigma_px: float) -> None:
    """A least-squares plane through n triangulated points is within 5 σ of the truth: depth noise σ_Z = Z² σ√2 /
    (f b) along each ray (≤ |ray| σ_Z across the wall), so σ/√n at the centroid and σ/(√n s) in the normal, s the
    smaller in-plane spread."""
    Z = points[:, 2].max()
    b = float(np.linalg.norm(scene.T_right_from_left[:3, 3]))
    rays = points / points[:, 2:]
    sigma_perp = Z ** 2 * sigma_px * np.sqrt(2.0) / (scene.f * b) * np.linalg.norm(rays, axis=1).max()
    n = len(points)
    centred = points - points.mean(axis=0)
    spread = np.sqrt(np.linalg.eigvalsh(centred.T @ centred)[1] / n)
    assert np.radians(_angle_deg(p, scene.p_true)) <= 5.0 * sigma_perp / (np.sqrt(n) * spread)
    c = points.mean(axis=0)                          # both planes' signed offsets at the points' centroid
    offset_error = (c @ p - 1.0) / np.linalg.norm(p) - (c @ scene.p_true - 1.0) / np.linalg.norm(scene.p_true)
    assert abs(offset_error) <= 5.0 * sigma_perp / np.sqrt(n)


def test_ransac_rejects_planted_outliers_and_keeps_the_inliers() -> None:
    scene = _scene()
    rng = np.random.default_rng(4)
    X = _true_corners(scene, _true_theta(scene))
    n = len(X)
    off_plane = rng.random(n) < 0.10                 # something 5-20 cm in front of the wall at these corners
    X[off_plane] *= (1.0 - rng.uniform(0.05, 0.20, off_plane.sum()) / X[off_plane, 2])[:, None]
    _, nl, nr = _ransac_inputs(scene, X, rng)
    glitch = ~off_plane & (rng.random(n) < 0.08)     # a corner finder's mistake in the right image: 2-20 px
    angle = rng.uniform(0.0, 2.0 * np.pi, glitch.sum())
    nr[glitch] += (rng.uniform(2.0, 20.0, glitch.sum()) / scene.f)[:, None] * np.column_stack(
        [np.cos(angle), np.sin(angle)])
    points = triangulate_stereo(nl, nr, scene.T_right_from_left)
    outlier = off_plane | glitch
    # premise: every planted outlier is far outside the gate even after its noise (6 σ of the transfer noise)
    margin = 6.0 * SIGMA_PX * np.sqrt(1.0 + _transfer_gain(scene) ** 2)
    assert np.all(_explicit_transfer_px(scene, scene.p_true, nl, nr)[outlier] > limits.RANSAC_THRESHOLD_PX + margin)

    p, inliers = ransac_plane(points, nl, nr, scene.T_right_from_left, scene.f, np.random.default_rng(0))
    assert inliers.shape == (n,) and inliers.dtype == bool
    assert not inliers[outlier].any()
    p_miss = _transfer_outside_probability(scene, limits.RANSAC_THRESHOLD_PX, SIGMA_PX)
    assert (~inliers[~outlier]).sum() <= _max_misses(int((~outlier).sum()), p_miss)
    _assert_plane_near(scene, p, points[~outlier], SIGMA_PX)


def test_ransac_at_a_room_corner_takes_the_wall_with_most_corners() -> None:
    scene = _scene()
    rng = np.random.default_rng(5)
    X = _true_corners(scene, _true_theta(scene))
    # the right 35 % of the pattern lands on a second wall, folded 40° about a vertical line through the pattern
    fold_u = np.quantile(scene.projector_px[:, 0], 0.65)
    on_b = scene.projector_px[:, 0] > fold_u
    hinge = X[on_b][np.argmin(scene.projector_px[on_b, 0])]
    n_a = scene.p_true / np.linalg.norm(scene.p_true)
    n_b = rotation_about([0.0, 1.0, 0.0], np.radians(40.0)) @ n_a    # left camera's y is vertical in this rig
    p_b = n_b / (n_b @ hinge)
    origin = scene.views.T_camera_left_from_projector[:3, 3]
    d = X[on_b] - origin
    X[on_b] = origin + ((1.0 - p_b @ origin) / (d @ p_b))[:, None] * d
    points, nl, nr = _ransac_inputs(scene, X, rng)

    p, inliers = ransac_plane(points, nl, nr, scene.T_right_from_left, scene.f, np.random.default_rng(0))
    p_miss = _transfer_outside_probability(scene, limits.RANSAC_THRESHOLD_PX, SIGMA_PX)
    assert (~inliers[~on_b]).sum() <= _max_misses(int((~on_b).sum()), p_miss)
    # corners on the other wall are rejected wherever that wall is clearly off the first (near the fold it is not)
    margin = 6.0 * SIGMA_PX * np.sqrt(1.0 + _transfer_gain(scene) ** 2)
    clearly_off = on_b & (_explicit_transfer_px(scene, scene.p_true, nl, nr) > limits.RANSAC_THRESHOLD_PX + margin)
    assert clearly_off.sum() > 0.8 * on_b.sum()                         # premise: most of the other wall is
    assert not inliers[clearly_off].any()
    _assert_plane_near(scene, p, points[~on_b], SIGMA_PX)


@pytest.mark.parametrize("n", [0, 1, 2])
def test_ransac_with_fewer_than_three_corners_gives_no_plane(n: int) -> None:
    scene = _scene()
    X = _true_corners(scene, _true_theta(scene))[:n]
    nl = _normalized(scene.views.camera_left, np.eye(4), X)
    nr = _normalized(scene.views.camera_right, scene.T_right_from_left, X)
    p, inliers = ransac_plane(X, nl, nr, scene.T_right_from_left, scene.f, np.random.default_rng(0))
    assert np.isnan(p).all() and inliers.shape == (n,) and not inliers.any()


def test_ransac_on_corners_along_one_line_gives_no_plane() -> None:
    # collinear corners (one row of the pattern on a thin beam) do not fix a plane: every sample is degenerate
    scene = _scene()
    t = np.linspace(-0.5, 0.5, 30)[:, None]
    X = np.array([0.1, -0.05, 2.0]) + t * np.array([1.0, 0.02, 0.3])
    nl = _normalized(scene.views.camera_left, np.eye(4), X)
    nr = _normalized(scene.views.camera_right, scene.T_right_from_left, X)
    p, inliers = ransac_plane(X, nl, nr, scene.T_right_from_left, scene.f, np.random.default_rng(0))
    assert np.isnan(p).all() and inliers.shape == (30,) and not inliers.any()


# --- the maximum-likelihood fit ----------------------------------------------------------------------------------

def test_model_casts_and_sees_the_corners_as_the_true_rig_does() -> None:
    """At the true parameters (a head error and image corrections of a few prior σ), the model puts each corner
    where the true projector casts it, its projector pose is the true one, and it predicts exactly what the
    cameras see."""
    scene = _scene(corners=ML_CORNERS)
    rng = np.random.default_rng(6)
    theta_true = _true_theta(scene, 3.0 * rng.normal(size=N_PARAMS - 3) * _prior_sigmas(scene))
    obs = _observe(scene, theta_true, rng, sigma_px=0.0)
    model = _model(scene, obs.normalized, obs.seen)
    # ~100 eps relative, a few dozen float64 operations: of the corners' range (< 5 m) in metres, of f in pixels
    tol_m, tol_px = 100 * EPS * 5.0, 100 * EPS * scene.f
    assert np.allclose(model.points(theta_true), _true_corners(scene, theta_true), rtol=0.0, atol=tol_m)
    T_true = scene.views.T_camera_left_from_projector @ make_pose(cv2.Rodrigues(theta_true[PROJ_ROT])[0],
                                                                  theta_true[PROJ_TRANS])
    assert np.allclose(model.projector_pose(theta_true), T_true, rtol=0.0, atol=100 * EPS)
    residuals = model.pixel_residuals_batch(theta_true[None], np.ones(len(scene.projector_px), bool))
    assert residuals.shape == (1, 4 * len(scene.projector_px))
    assert np.max(np.abs(residuals)) <= tol_px
    assert np.max(model.corner_errors(theta_true)) <= tol_px
    # a wall 1 cm farther: each corner's error is the larger of its two views' distances between where the true
    # projector would cast it on that wall, seen through each camera, and where the camera saw it
    wrong = theta_true.copy()
    wrong[PLANE] = scene.p_true / (1.0 + 0.01 * np.linalg.norm(scene.p_true))
    X = _true_corners(scene, wrong)
    expected = np.max([intr.fx * np.linalg.norm(_normalized(intr, T, X, wrong[AFFINE[k]]) - obs.normalized[k], axis=1)
                       for k, (intr, T) in enumerate(((scene.views.camera_left, np.eye(4)),
                                                      (scene.views.camera_right, scene.T_right_from_left)))], axis=0)
    assert np.min(expected) > 1e3 * tol_px                             # premise: the shift is visible
    assert np.allclose(model.corner_errors(wrong), expected, rtol=0.0, atol=tol_px)


def test_ml_fit_errors_are_distributed_as_its_covariance_says() -> None:
    """Over seeds, with every nuisance (head error, image corrections) drawn from the model's own prior, the fit's
    errors are Gaussian with its reported covariance (a linear-Gaussian posterior is calibrated exactly)."""
    scene = _scene(corners=ML_CORNERS)
    prior = _prior_sigmas(scene)
    seeds = range(40)
    normal_d2, dist_z, plane_d2 = [], [], []
    single_d2: dict[int, list[float]] = {0: [], 1: []}
    clean_total, clean_dropped, gate_p = 0, 0, 0.0
    for seed in seeds:
        rng = np.random.default_rng(100 + seed)
        theta_true = _true_theta(scene, rng.normal(size=N_PARAMS - 3) * prior)
        obs = _observe(scene, theta_true, rng, glitch_fraction=0.03, unseen_fraction=0.03)
        _, fit = _ransac_then_ml(scene, obs, seed)
        assert not fit.inliers[obs.glitched].any(), seed                 # ≥ 2 px: four times the 5 σ gate
        clean = (obs.seen[0] | obs.seen[1]) & ~obs.glitched
        clean_total += int(clean.sum())
        clean_dropped += int((~fit.inliers[clean]).sum())
        gate_p = max(gate_p, _gate_outside_probability(fit))
        a, z, b = _plane_errors(fit.theta[PLANE], scene.p_true, fit.covariance[PLANE, PLANE])
        # each fit alone: within ~4 σ of the truth by its own covariance
        assert a <= stats.chi2.isf(PER_FIT_TAIL, 2), (seed, a)
        assert abs(z) <= stats.norm.isf(PER_FIT_TAIL / 2), (seed, z)
        assert abs(fit.sigma_px / SIGMA_PX - 1.0) <= _sigma_bound(fit), (seed, fit.sigma_px)
        normal_d2.append(a)
        dist_z.append(z)
        plane_d2.append(b)
        for view in (0, 1):                                          # each camera with the projector alone
            theta_v, cov_v, _ = fit.single_view(view)
            single_d2[view].append(_plane_errors(theta_v[PLANE], scene.p_true, cov_v[PLANE, PLANE])[2])
    count = len(seeds)
    # the inlier gate keeps the clean corners but for its Gaussian tail, over all the fits
    assert clean_dropped <= _max_misses(clean_total, gate_p), (clean_dropped, clean_total, gate_p)
    # the fraction inside the 95 % bounds: Binomial(count, 0.95); an over-confident covariance falls below
    lowest = stats.binom.ppf(ACROSS_SEEDS_TAIL, count, 0.95)
    assert np.sum(np.array(normal_d2) <= limits.CHI2_2_95) >= lowest
    assert np.sum(np.abs(dist_z) <= limits.Z_95) >= lowest
    # inside the 50 % bound: Binomial(count, 0.5), two-sided, so an over-cautious covariance fails as well
    inside = np.sum(np.array(plane_d2) <= stats.chi2.ppf(0.5, 3))
    assert stats.binom.ppf(ACROSS_SEEDS_TAIL / 2, count, 0.5) <= inside <= stats.binom.isf(ACROSS_SEEDS_TAIL / 2,
                                                                                              count, 0.5)
    # the sum of the 3-dof Mahalanobis² is chi-square with 3·count degrees of freedom: the joint fit's and each
    # single camera's (fit.single_view, the estimator's check that the views agree)
    low, high = stats.chi2.ppf(ACROSS_SEEDS_TAIL / 2, 3 * count), stats.chi2.isf(ACROSS_SEEDS_TAIL / 2, 3 * count)
    for name, d2 in (("joint", plane_d2), ("left", single_d2[0]), ("right", single_d2[1])):
        assert low <= float(np.sum(d2)) <= high, (name, float(np.sum(d2)), low, high)


def test_ml_fit_measures_a_planted_head_error_and_drops_the_outliers() -> None:
    scene = _scene(corners=ML_CORNERS)
    prior = _prior_sigmas(scene)
    nuisances = np.zeros(N_PARAMS - 3)
    # the head 3 prior σ off in rotation and translation: a clear error the prior still admits
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    direction = np.array([0.3, 1.0, -0.5]) / np.linalg.norm([0.3, 1.0, -0.5])
    nuisances[0:3] = 3.0 * prior[0] * axis
    nuisances[3:6] = 3.0 * prior[3] * direction
    theta_true = _true_theta(scene, nuisances)
    rng = np.random.default_rng(7)
    obs = _observe(scene, theta_true, rng, glitch_fraction=0.05, unseen_fraction=0.04)
    hidden = np.arange(len(scene.projector_px)) % 50 == 0            # corners neither camera saw (occluded)
    for k in (0, 1):
        obs.seen[k][hidden] = False
        obs.normalized[k][hidden] = np.nan
    obs.glitched[hidden] = False
    model, fit = _ransac_then_ml(scene, obs, 0)

    # the projector correction ξ = (rotation, translation) agrees with the planted one by its covariance
    xi = np.r_[PROJ_ROT.start:PROJ_TRANS.stop]
    e = fit.theta[xi] - theta_true[xi]
    assert e @ np.linalg.solve(fit.covariance[np.ix_(xi, xi)], e) <= stats.chi2.isf(PER_FIT_TAIL, 6)
    # and the measured projector pose is near the true one, far nearer than the nominal (head model) pose
    T_true = scene.views.T_camera_left_from_projector @ make_pose(cv2.Rodrigues(nuisances[0:3])[0], nuisances[3:6])
    rot_bound_deg = np.degrees(np.sqrt(stats.chi2.isf(PER_FIT_TAIL, 3)
                                       * np.linalg.eigvalsh(fit.covariance[PROJ_ROT, PROJ_ROT])[-1]))
    trans_bound_m = np.sqrt(stats.chi2.isf(PER_FIT_TAIL, 3) * np.linalg.eigvalsh(fit.covariance[PROJ_TRANS,
                                                                                                 PROJ_TRANS])[-1])
    T_meas = model.projector_pose(fit.theta)
    assert rotation_angle_deg(T_meas, T_true) <= rot_bound_deg
    assert np.linalg.norm(T_meas[:3, 3] - T_true[:3, 3]) <= trans_bound_m
    assert rot_bound_deg < 0.2 * rotation_angle_deg(model.T_left_from_projector, T_true)  # premise: it measured it

    # the plane is right by its covariance, and so is each camera with the projector alone
    a, z, _ = _plane_errors(fit.theta[PLANE], scene.p_true, fit.covariance[PLANE, PLANE])
    assert a <= stats.chi2.isf(PER_FIT_TAIL, 2) and abs(z) <= stats.norm.isf(PER_FIT_TAIL / 2)
    for view in (0, 1):
        theta_v, cov_v, sigma_v = fit.single_view(view)
        e_v = theta_v[PLANE] - scene.p_true
        assert e_v @ np.linalg.solve(cov_v[PLANE, PLANE], e_v) <= stats.chi2.isf(PER_FIT_TAIL, 3), view
        assert abs(sigma_v / SIGMA_PX - 1.0) <= 2.0 * _sigma_bound(fit), view   # half the rows: SE ×√2, bias ×2
    assert abs(fit.sigma_px / SIGMA_PX - 1.0) <= _sigma_bound(fit)
    assert abs(fit.rms_px / SIGMA_PX - 1.0) <= _sigma_bound(fit)

    # inliers: no glitch (≥ 2 px, four times the 5 σ gate), no corner nobody saw, and the clean corners kept
    assert not fit.inliers[obs.glitched].any()
    seen_any = obs.seen[0] | obs.seen[1]
    assert not fit.inliers[~seen_any].any()
    clean = seen_any & ~obs.glitched
    assert (~fit.inliers[clean]).sum() <= _max_misses(int(clean.sum()), _gate_outside_probability(fit))


def test_ml_fit_on_exact_corners_returns_the_truth() -> None:
    """No noise, no nuisance: from a rough start the fit reaches the true plane within its stopping tolerance."""
    scene = _scene(corners=ML_CORNERS)
    theta_true = _true_theta(scene)
    obs = _observe(scene, theta_true, np.random.default_rng(8), sigma_px=0.0)
    model = _model(scene, obs.normalized, obs.seen)
    p0 = rotation_about([0.0, 1.0, 0.3], np.radians(15.0)) @ scene.p_true * 0.7  # 15° off and 43 % farther
    fit = fit_ml(model, p0, obs.seen[0] & obs.seen[1])
    # the last step was < tol |p|, and a forward-difference Jacobian (relative error ~ its step, = tol) shrinks the
    # remaining error by ~tol per step: the plane is left within tol² |p|
    assert np.linalg.norm(fit.theta[PLANE] - scene.p_true) <= GAUSS_NEWTON_TOL ** 2 * np.linalg.norm(scene.p_true)
    # stopping is judged on the plane alone; the nuisances are left within a step's relative size of their prior
    assert np.all(np.abs(fit.theta[3:]) <= GAUSS_NEWTON_TOL * _prior_sigmas(scene))
    # corner errors at the truth are round-off: the noise estimate sits on its floor, every corner is an inlier
    assert fit.sigma_px == limits.SIGMA_FLOOR_PX
    assert fit.inliers.all()


def test_ml_fit_without_refinement_keeps_the_callers_corners() -> None:
    """refine_inliers=False (the estimator's refit after eroding a fold's border): the corners given are the ones
    used, even a planted glitch, and every residual row belongs to one of them."""
    scene = _scene(corners=ML_CORNERS)
    rng = np.random.default_rng(10)
    obs = _observe(scene, _true_theta(scene), rng, glitch_fraction=0.05, unseen_fraction=0.05)
    given = (obs.seen[0] | obs.seen[1]) & (rng.random(len(scene.projector_px)) < 0.8)
    assert (given & obs.glitched).any()                                 # premise: a glitch among them
    model = _model(scene, obs.normalized, obs.seen)
    fit = fit_ml(model, scene.p_true, given, refine_inliers=False)
    assert np.array_equal(fit.inliers, given)
    for view in (0, 1):
        assert (fit.row_view == view).sum() == 2 * (obs.seen[view] & given).sum()
    assert (fit.row_view < 0).sum() == N_PARAMS - 3                    # one prior row per nuisance parameter


def test_ml_fit_jacobian_is_the_derivative_of_its_residuals() -> None:
    """The covariance is (JᵀJ)⁻¹ of the reported Jacobian: it must be the derivative of the whitened residuals,
    here taken by central differences at 1e-4 of each parameter's scale (|p|, or its prior σ)."""
    scene = _scene(corners=ML_CORNERS)
    prior = _prior_sigmas(scene)
    rng = np.random.default_rng(3)
    obs = _observe(scene, _true_theta(scene, rng.normal(size=N_PARAMS - 3) * prior), rng, glitch_fraction=0.03,
                   unseen_fraction=0.03)
    model, fit = _ransac_then_ml(scene, obs, 0)
    scale = np.r_[np.full(3, np.linalg.norm(fit.theta[PLANE])), prior]
    h = 1e-4 * scale
    r = model.whitened_batch(np.vstack([fit.theta + np.diag(h), fit.theta - np.diag(h)]), fit.sigma_px, fit.inliers)
    J = ((r[:N_PARAMS] - r[N_PARAMS:]) / (2.0 * h[:, None])).T
    assert fit.jacobian.shape == J.shape
    # plane.py differentiates forward with steps of 1e-7 (relative for the plane): an error ~1e-7 of each column;
    # central differences at 1e-4 err by ~1e-8. 100 times the product's step leaves room for both
    column_error = np.linalg.norm(fit.jacobian - J, axis=0) / np.linalg.norm(J, axis=0)
    assert np.all(column_error <= 100 * FORWARD_STEP), column_error


# --- small helpers of the module ----------------------------------------------------------------------------------

def test_plane_in_frame_gives_the_walls_normal_and_distance() -> None:
    views = _views()
    for distance_m, incidence_deg in ((2.0, 30.0), (4.0, 60.0)):
        wall = wall_plane(distance_m, incidence_deg, views)
        p = _left_plane(views, distance_m, incidence_deg)
        nd = plane_in_frame(p, views.T_robot_from_camera_left)
        # a rotation and a dot product on metre-sized numbers: ~10 eps · distance
        assert np.allclose(nd[:3], wall.normal, rtol=0.0, atol=10 * EPS)
        assert abs(nd[3] - wall.distance) <= 10 * EPS * wall.distance
        # and in the (rotated) projector frame, where the synthetic wall says it is
        T_projector_from_left = invert(views.T_camera_left_from_projector)
        n_p, d_p = wall.in_frame(invert(views.T_robot_from_projector))
        assert np.allclose(plane_in_frame(p, T_projector_from_left), np.r_[n_p, d_p], rtol=0.0,
                           atol=10 * EPS * distance_m)
