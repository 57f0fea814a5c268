"""The wall plane from one pair of camera images of the projected pattern: detection, matching, RANSAC,
maximum likelihood with the projector as third view, covariance, and the evidence checks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from geometry.intrinsics import Intrinsics
from geometry.poses import rotation_angle_deg
from geometry.threads import single_threaded
from wallpose import limits
from wallpose.detect import Detection, detect
from wallpose.evidence import EvidenceCode, NotEnoughEvidenceError
from wallpose.pattern import CheckerPattern
from wallpose.plane import PROJ_TRANS, MLFit, MLModel, ViewData, fit_ml, plane_in_frame, ransac_plane
from wallpose.rig import ViewRig
from wallpose.triangulate import triangulate_stereo

# One draw of the stereo pair from its calibration's covariance: (left, right, T_right_from_left).
StereoDraw = tuple[Intrinsics, Intrinsics, NDArray[np.float64]]


@dataclass(frozen=True)
class Uncertainty:
    """How well the rig is known, as Gaussian σ: the projector's pose at the head's current angles (the head's
    repeatability, or the head calibration's residual), and per camera an image-wide corner offset and gradient
    (what the stereo calibration and corner finding get wrong for a whole image alike). stereo_draws: the
    stereo pair drawn from its calibration's covariance (calibration.stereo.sample_stereo); the plane's
    covariance then holds what the calibration leaves unknown (a depth scale or vergence error tilts and moves
    the whole plane alike, growing with the distance squared), beside the corners' noise."""

    projector_rotation_deg: float = limits.PROJECTOR_ROTATION_SIGMA_DEG
    projector_translation_m: float = limits.PROJECTOR_TRANSLATION_SIGMA_M
    image_offset_px: float = limits.IMAGE_OFFSET_SIGMA_PX
    image_gradient_px: float = limits.IMAGE_GRADIENT_SIGMA_PX
    projector_offset_px: float = limits.PROJECTOR_OFFSET_SIGMA_PX
    projector_gradient_px: float = limits.PROJECTOR_GRADIENT_SIGMA_PX
    stereo_draws: tuple[StereoDraw, ...] = ()


@dataclass
class PlaneEstimate:
    """The wall plane in the robot frame, with its uncertainty.

    normal: (3,) unit, pointing out of the wall into the room; distance: metres, normal·X = -distance on the
    wall; covariance: (4, 4) of (normal, distance) (rank 3); centre: (3,) robot-frame point where the pattern's
    centre lands; normal_95_deg / centre_distance_95_m: 95 % bounds of the normal's angle error and of the
    plane's offset at the centre; T_camera_left_from_projector: the projector's pose as measured (nominal pose
    corrected by the fit); sigma_px: a-posteriori corner noise; corners: inlier corners used.
    """

    normal: NDArray[np.float64]
    distance: float
    covariance: NDArray[np.float64]
    centre: NDArray[np.float64]
    normal_95_deg: float
    centre_distance_95_m: float
    T_camera_left_from_projector: NDArray[np.float64]
    projector_correction_deg: float
    projector_correction_m: float
    sigma_px: float
    rms_px: float
    corners: int
    matched: int
    corners_left: int
    corners_right: int
    inlier_ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    warnings: list[str] = field(default_factory=list)

    def normal_error_deg(self, true_normal: NDArray[np.float64]) -> float:
        c = np.clip(self.normal @ (true_normal / np.linalg.norm(true_normal)), -1.0, 1.0)
        return float(np.degrees(np.arccos(c)))

    def offset_at(self, point: NDArray[np.float64]) -> float:
        """Signed distance (m) of a robot-frame point from this plane (positive on the room side)."""
        return float(self.normal @ point + self.distance)

    def summary(self) -> str:
        return (f"normal {np.array2string(self.normal, precision=4)} (±{self.normal_95_deg:.3f}° at 95 %), "
                f"distance {self.distance:.4f} m, at the pattern's centre ±{1000 * self.centre_distance_95_m:.2f} mm, "
                f"{self.corners} corners, corner noise {self.sigma_px:.3f} px")


def _view_data(det: Detection, n: int, T_cam_from_left: NDArray[np.float64], f: float) -> ViewData:
    seen = np.zeros(n, dtype=bool)
    seen[det.corner_ids] = True
    normalized = np.full((n, 2), np.nan)
    normalized[det.corner_ids] = det.normalized
    return ViewData(T_cam_from_left, f, seen, normalized)


def estimate_plane(image_left: NDArray, image_right: NDArray, pattern: CheckerPattern, views: ViewRig,
                   uncertainty: Uncertainty | None = None, seed: int = 0) -> PlaneEstimate:
    """The wall plane from the two cameras' images of the projected pattern.

    uncertainty: how well the rig is known (default Uncertainty()). Raises NotEnoughEvidenceError with the reason
    when the images do not support a trustworthy plane.
    """
    with single_threaded():
        det_l = detect(image_left, pattern, views.camera_left, views.projector, "camera_left")
        det_r = detect(image_right, pattern, views.camera_right, views.projector, "camera_right")
        return estimate_from_detections(det_l, det_r, pattern, views, uncertainty, seed)


def _describe(det: Detection) -> str:
    return f"{det.camera}: {det.count} corners" + (f" ({det.reason})" if det.reason else "")


def estimate_from_detections(det_l: Detection, det_r: Detection, pattern: CheckerPattern, views: ViewRig,
                             uncertainty: Uncertainty | None = None, seed: int = 0) -> PlaneEstimate:
    """estimate_plane after detection (so a caller can reuse detections). Runs BLAS single-threaded (see
    geometry.threads): the fit's small normal equations cost several times the CPU on a thread pool."""
    with single_threaded():
        return _estimate_from_detections(det_l, det_r, pattern, views, uncertainty, seed)


def _estimate_from_detections(det_l: Detection, det_r: Detection, pattern: CheckerPattern, views: ViewRig,
                              uncertainty: Uncertainty | None, seed: int) -> PlaneEstimate:
    u = Uncertainty() if uncertainty is None else uncertainty
    n = pattern.n_corners
    T_rl = views.T_camera_right_from_camera_left
    left = _view_data(det_l, n, np.eye(4), views.camera_left.fx)
    right = _view_data(det_r, n, T_rl, views.camera_right.fx)
    both = left.seen & right.seen
    if det_l.count == 0 and det_r.count == 0:
        raise NotEnoughEvidenceError(EvidenceCode.NO_PATTERN,
                                     f"the pattern was not found ({_describe(det_l)}; {_describe(det_r)})")
    if both.sum() < limits.MIN_CORNERS:
        raise NotEnoughEvidenceError(EvidenceCode.TOO_FEW_CORNERS,
                                f"only {both.sum()} corners are seen by both cameras, {limits.MIN_CORNERS} needed "
                                f"({_describe(det_l)}; {_describe(det_r)})",
                                "aim the projector at a free part of the wall")
    idx_both = np.nonzero(both)[0]
    points = triangulate_stereo(left.normalized[both], right.normalized[both], T_rl)
    rng = np.random.default_rng(seed)
    p0, inl = ransac_plane(points, left.normalized[both], right.normalized[both], T_rl, views.camera_right.fx, rng)
    if inl.sum() < limits.MIN_CORNERS:
        raise NotEnoughEvidenceError(EvidenceCode.NOT_ONE_PLANE,
                                     f"no plane holds {limits.MIN_CORNERS} of the {both.sum()} "
                                     "corners seen by both cameras", "is the pattern on a flat wall?")
    inliers0 = np.zeros(n, dtype=bool)
    inliers0[idx_both[inl]] = True
    rays = views.projector.rays(pattern.corner_projector_px)
    model = MLModel(rays, views.T_camera_left_from_projector, [left, right],
                    np.radians(u.projector_rotation_deg), u.projector_translation_m,
                    u.image_offset_px, u.image_gradient_px, 0.5 * views.camera_left.width,
                    views.projector.fx, u.projector_offset_px, u.projector_gradient_px, 0.5 * views.projector.width)
    fit = fit_ml(model, p0, inliers0)
    fit = _erode_off_plane_border(model, fit, pattern)
    matched = int(model.seen_any.sum())
    used = int(fit.inliers.sum())
    warnings = det_l.warnings + det_r.warnings
    if used < limits.MIN_CORNERS:
        raise NotEnoughEvidenceError(EvidenceCode.TOO_FEW_CORNERS, f"only {used} corners agree with one plane")
    if used < limits.MIN_INLIER_FRACTION * matched:
        raise NotEnoughEvidenceError(EvidenceCode.NOT_ONE_PLANE, f"only {used} of {matched} corners lie on one plane",
                                "the pattern spans several surfaces; aim it at one wall")
    if fit.sigma_px > limits.MAX_RMS_PX:
        raise NotEnoughEvidenceError(EvidenceCode.VIEWS_DISAGREE,
                                     f"the corners disagree with the calibrated geometry by "
                                f"{fit.sigma_px:.2f} px (at most {limits.MAX_RMS_PX} px expected)",
                                "keep the robot still between the two images, or recalibrate")
    _check_views_agree(model, fit)
    if used < matched:
        warnings.append(f"{matched - used} of {matched} corners are off the plane (another surface or occluded)")
    calibration = _stereo_calibration_covariance(det_l, det_r, np.flatnonzero(fit.inliers & both), views,
                                                 u.stereo_draws)
    return _result(model, fit, pattern, views, matched, warnings, u, calibration)


def _stereo_calibration_covariance(det_l: Detection, det_r: Detection, ids: NDArray[np.int64], views: ViewRig,
                                   draws: tuple[StereoDraw, ...]) -> NDArray[np.float64]:
    """(3, 3) covariance of the plane p (left camera frame, p·X = 1) that the stereo calibration's own
    uncertainty leaves: the corners seen by both cameras re-triangulated with each draw of the pair and the
    plane refitted, its scatter about the calibrated pair's plane. Zeros without draws."""
    if not draws or len(ids) < limits.MIN_CORNERS:
        return np.zeros((3, 3))
    row_l = {int(c): k for k, c in enumerate(det_l.corner_ids)}
    row_r = {int(c): k for k, c in enumerate(det_r.corner_ids)}
    px_l = det_l.pixels[[row_l[int(c)] for c in ids]]
    px_r = det_r.pixels[[row_r[int(c)] for c in ids]]

    def plane_of(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray[np.float64]) -> NDArray:
        X = triangulate_stereo(left.rays(px_l)[:, :2], right.rays(px_r)[:, :2], T_right_from_left)
        X = X[np.all(np.isfinite(X), axis=1)]
        return np.asarray(np.linalg.lstsq(X, np.ones(len(X)), rcond=None)[0], dtype=np.float64)

    p0 = plane_of(views.camera_left, views.camera_right, views.T_camera_right_from_camera_left)
    dp = np.array([plane_of(*draw) - p0 for draw in draws])
    return np.asarray(dp.T @ dp / len(dp), dtype=np.float64)


def _erode_off_plane_border(model: MLModel, fit: MLFit, pattern: CheckerPattern) -> MLFit:
    """Leave out the corners next to corners that lie off the plane, and refit.

    Where the pattern folds onto another surface (a room corner, a door frame) the corners just before the
    fold are found slightly off their place (their squares reach over the fold) and drag the plane with
    them; one grid step of margin removes them. With an even subset of the corners (detect's max_corners) the
    neighbour across the fold is not always among them; the inlier gate catches what this misses."""
    off = model.seen_any & ~fit.inliers
    if not off.any():
        return fit
    grid = pattern.corner_grid
    lookup = {(int(i), int(j)): k for k, (i, j) in enumerate(grid)}
    near = np.zeros(len(grid), dtype=bool)
    for k in np.nonzero(off)[0]:
        i, j = grid[k]
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                m = lookup.get((int(i + di), int(j + dj)))
                if m is not None:
                    near[m] = True
    keep = fit.inliers & ~near
    if keep.sum() < limits.MIN_CORNERS or keep.sum() == fit.inliers.sum():
        return fit
    return fit_ml(model, fit.theta[:3], keep, iterations=2, theta0=fit.theta, refine_inliers=False)


def _check_views_agree(model: MLModel, fit: MLFit) -> None:
    """The images must agree with the rig model: no correction far beyond its prior (a robot that moved between
    the two images shows up as opposite image gradients in the two cameras), and each camera with the
    projector alone must see the same plane as the other."""
    z = np.abs(fit.theta[3:] / model.prior_sigmas)
    groups = {"projector pose": z[0:6], "left camera": z[6:12], "right camera": z[12:18], "projector image": z[18:24]}
    worst = max(groups, key=lambda g: float(groups[g].max()))
    if z.max() > limits.MAX_NUISANCE_SIGMAS:
        code = EvidenceCode.PROJECTOR_POSE_OFF if worst == "projector pose" else EvidenceCode.VIEWS_DISAGREE
        raise NotEnoughEvidenceError(code, f"the images disagree with the calibrated rig: the {worst} needs a "
                                     f"correction of {z.max():.1f} σ",
                                     "did the robot or the head move between the two images? take both at once; "
                                     "otherwise recalibrate")
    for k in range(2):
        if (fit.inliers & model.views[k].seen).sum() < limits.MIN_CORNERS:
            return
    (theta_l, cov_l, sigma_l), (theta_r, cov_r, sigma_r) = fit.single_view(0), fit.single_view(1)
    diff = theta_l[:3] - theta_r[:3]
    d2 = float(diff @ np.linalg.solve(cov_l[:3, :3] + cov_r[:3, :3], diff))
    ratio = fit.sigma_px / max(np.sqrt(0.5 * (sigma_l ** 2 + sigma_r ** 2)), limits.SIGMA_FLOOR_PX)
    if d2 > limits.CHI2_3_999 or ratio > limits.MAX_NOISE_RATIO:
        raise NotEnoughEvidenceError(EvidenceCode.VIEWS_DISAGREE,
                                     f"the left and right images do not show the same wall pose "
                                     f"(Mahalanobis² {d2:.1f}, joint/single noise ratio {ratio:.1f})",
                                     "did the robot or the head move between the two images? take both at once")


def _result(model: MLModel, fit: MLFit, pattern: CheckerPattern, views: ViewRig, matched: int,
            warnings: list[str], u: Uncertainty, calibration_covariance: NDArray[np.float64]) -> PlaneEstimate:
    T_robot_from_left = views.T_robot_from_camera_left
    theta = fit.theta
    nd = plane_in_frame(theta[:3], T_robot_from_left)
    J = np.zeros((4, 3))
    for k in range(3):
        h = 1e-7 * np.linalg.norm(theta[:3])
        dp = np.zeros(3)
        dp[k] = h
        J[:, k] = (plane_in_frame(theta[:3] + dp, T_robot_from_left)
                   - plane_in_frame(theta[:3] - dp, T_robot_from_left)) / (2 * h)
    cov_p = fit.covariance[:3, :3] + calibration_covariance
    cov_nd = J @ cov_p @ J.T
    normal_var = np.linalg.eigvalsh(cov_nd[:3, :3])[-1]
    normal_95 = float(np.degrees(np.sqrt(limits.CHI2_2_95 * max(normal_var, 0.0))))
    centre_left = model.points(theta, views.projector.rays(pattern.centre_px[None]))[0]
    centre = T_robot_from_left[:3, :3] @ centre_left + T_robot_from_left[:3, 3]
    g = np.append(centre, 1.0)  # offset at a fixed point: n·c + d, linear in (n, d)
    centre_sd = float(np.sqrt(max(g @ cov_nd @ g, 0.0)))
    T_meas = model.projector_pose(theta)
    corr_deg = rotation_angle_deg(T_meas, model.T_left_from_projector)
    corr_m = float(np.linalg.norm(theta[PROJ_TRANS]))
    if corr_deg > 4 * u.projector_rotation_deg or corr_m > 4 * u.projector_translation_m:
        warnings.append(f"the projector sits {corr_deg:.2f}° / {1000 * corr_m:.1f} mm from where the head model "
                        "puts it; recalibrate the head")
    estimate = PlaneEstimate(
        normal=nd[:3], distance=float(nd[3]), covariance=cov_nd, centre=centre, normal_95_deg=normal_95,
        centre_distance_95_m=limits.Z_95 * centre_sd, T_camera_left_from_projector=T_meas,
        projector_correction_deg=corr_deg, projector_correction_m=corr_m, sigma_px=fit.sigma_px,
        rms_px=fit.rms_px, corners=int(fit.inliers.sum()), matched=matched,
        corners_left=int((fit.inliers & model.views[0].seen).sum()),
        corners_right=int((fit.inliers & model.views[1].seen).sum()), inlier_ids=np.nonzero(fit.inliers)[0],
        warnings=warnings)
    if normal_95 > limits.MAX_NORMAL_95_DEG or estimate.centre_distance_95_m > limits.MAX_DISTANCE_95_M:
        raise NotEnoughEvidenceError(EvidenceCode.TOO_UNCERTAIN,
                                     f"the corners found constrain the wall only to ±{normal_95:.2f}° "
                                f"and ±{1000 * estimate.centre_distance_95_m:.1f} mm ({estimate.corners} corners)",
                                "make more of the pattern visible to both cameras")
    return estimate

