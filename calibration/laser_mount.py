"""The stereo pair's mount on the robot, T_robot_from_camera_left, from the 2-D laser and a board (Zhang & Pless).

Why the laser: the robot frame is the body's, and of everything on the robot only the laser is fixed to the body
with a known pose (T_robot_from_laser; its scan is in the robot frame). The cameras see the projector on the head,
but the head's own kinematics in the robot frame are a design value too (axes off by tenths of a degree, an
angle bias), so a hand–eye solve against head poses would hand the head's design error on to the mount. The
laser meets the cameras on a shared plane instead: a board printed at the top of a tall panel standing on the
floor, leaning back and turned a little differently each time. The camera gives the board's plane
(n·x = d in camera_left, from its pose by PnP); the laser's scan line crosses the panel lower down, and those
points, taken into camera_left by the unknown mount, must lie on that plane (Zhang & Pless 2004). Walls alone
would not do: vertical planes cut by a horizontal scan leave the mount's pitch, roll and height free; a panel
leaning back at several angles fixes all six.

Unknowns: a rotation vector ω (applied in the robot frame) and an offset δt of the mount from its design
value. Residuals: n·(T_camera_left_from_robot · p) − d per laser point on the panel, metres. Points are picked
by the design mount (within GATE_M of the predicted plane and within the printed board's width), then by the
fit (RESIDUAL_GATE_SIGMAS). Uncertainty: the unweighted least squares' sandwich (JᵀJ)⁻¹ (Σ_k J_kᵀ Σ_k J_k)
(JᵀJ)⁻¹, where view k's residuals have covariance σ²·I (σ from the residuals: range noise) plus A_k Σ_k Aᵀ_k,
the board pose's own covariance (from PnP's Jacobian and its corner residuals) carried to the residuals. The
fit takes the camera's intrinsics as exact (see camera_draws_covariance).

The laser alone leaves the mount weakly fixed: its scan is one horizontal line, so the mount's pitch, roll,
height and forward offset move every panel's line nearly alike (with 6-12 panels 1.35-1.75 m away: errors of
30-100 mm and 2-4°, worse than the design value). So the design value enters as what it is, a measurement with
the build tolerance as its spread: the build error M = T_robot_from_camera_left · design⁻¹ (rotation vector v,
offset t, in the robot frame) is a priori N(0, σ²) per axis (DESIGN_SIGMA_DEG, DESIGN_SIGMA_M), and the fit is
the maximum a posteriori one: laser residuals / σ_laser and (v / σ_rot, t / σ_pos) together. The laser fixes
the directions it sees (yaw, the lateral offset, combinations) to a few tenths of a millimetre, the design the
rest; the covariance is the sandwich of that fit with the prior's information added.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative

from calibration.boards import BoardView
from calibration.camera_model import solve_pnp
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, pose_from_rvec_tvec, rotation_matrix, rotation_vector

GATE_M = 0.08  # laser points this close to the plane the design mount predicts are candidates
RESIDUAL_GATE_SIGMAS = 4.0
MIN_POINTS_PER_VIEW = 20
MIN_VIEWS = 4
CORNER_GATE_SIGMAS = 5.0  # board corners this many robust σ off the board's pose are refinement failures
CORNER_GATE_MIN_PX = 0.5  # never below this: sharp renders reproject to a few hundredths of a pixel
MIN_CORNERS_PER_VIEW = 12
CHI2_3_95 = 7.814727903251178  # 95 % quantile of χ² with 3 degrees of freedom
# The mount as built is off its drawing by about this, σ per axis of the build error in the robot frame (a tilt
# of the mast at its foot moves the cameras too): the prior of the fit. arproj.sim.live builds its site so.
DESIGN_SIGMA_DEG = 0.5
DESIGN_SIGMA_M = 0.005


@dataclass
class BoardPlaneView:
    """A board seen by camera_left: T_camera_from_board, the covariance of its (rvec, tvec), and its extent
    along the board's x axis (m), where the laser may meet it."""

    T_camera_from_board: NDArray[np.float64]
    covariance: NDArray[np.float64]
    x_range_m: tuple[float, float]
    source: str = ""


def board_plane_view(view: BoardView, camera: Intrinsics) -> BoardPlaneView:
    """The board's pose from its corners (PnP) and that pose's covariance s²·(JᵀJ)⁻¹.

    Corners whose reprojection error is beyond CORNER_GATE_SIGMAS robust σ (the median's) are left out and the
    pose solved again: a corner the refinement settled several pixels off (seen at the print's top edge, 2 m
    away: 5.5 px against 0.06 px RMS for the rest) is no pixel noise, and taken as such it tilted the plane by
    2 σ of its covariance where the laser meets the panel a metre below the board."""
    keep = np.ones(len(view.object_points), bool)
    while True:
        obj, img = view.object_points[keep], view.image_points[keep]
        x = solve_pnp(obj, img, camera.K, camera.dist_array)
        projected, jac = cv2.projectPoints(view.object_points, x[:3], x[3:], camera.K, camera.dist_array)
        miss = np.linalg.norm(projected.reshape(-1, 2) - view.image_points, axis=1)
        scale = 1.4826 * float(np.median(miss[keep])) / np.sqrt(np.log(4.0))  # a 2-D normal's σ per axis
        kept = keep & (miss <= max(CORNER_GATE_SIGMAS * scale, CORNER_GATE_MIN_PX))
        if (kept == keep).all() or kept.sum() < MIN_CORNERS_PER_VIEW:
            break
        keep = kept
    r = (projected.reshape(-1, 2) - view.image_points)[keep].ravel()
    J = jac.reshape(-1, 2, jac.shape[1])[keep].reshape(-1, jac.shape[1])[:, :6]
    s2 = float(r @ r) / max(len(r) - 6, 1)
    xs = view.object_points[:, 0]
    return BoardPlaneView(pose_from_rvec_tvec(x[:3], x[3:]), s2 * np.linalg.pinv(J.T @ J),
                          (float(xs.min()), float(xs.max())), view.source)


@dataclass
class MountFit:
    T_robot_from_camera_left: NDArray[np.float64]
    covariance: NDArray[np.float64]  # 6x6 of (ω rad, δt m), robot frame
    rms_m: float
    points_per_view: list[int]
    sources: list[str] = field(default_factory=list)

    def bounds_95(self) -> dict[str, float]:
        return bounds_95(self.covariance)

    def quality(self) -> dict:
        return {"laser_rms_mm": round(1000 * self.rms_m, 3), "views": len(self.points_per_view),
                "laser_points_per_view": self.points_per_view,
                "mount_95": {k: round(v, 4) for k, v in self.bounds_95().items()},
                "covariance": self.covariance.tolist()}


def bounds_95(covariance: NDArray[np.float64]) -> dict[str, float]:
    """95 % bounds of a mount's 6x6 (ω, δt) covariance: the largest semi-axis of the rotation's (degrees) and the
    offset's (mm) ellipsoid."""
    rot = np.sqrt(CHI2_3_95 * np.linalg.eigvalsh(covariance[:3, :3]).max())
    pos = np.sqrt(CHI2_3_95 * np.linalg.eigvalsh(covariance[3:, 3:]).max())
    return {"rotation_deg": float(np.degrees(rot)), "position_mm": float(1000 * pos)}


def mount_errors(T_est: NDArray[np.float64], T_true: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                                                    NDArray[np.float64]]:
    """(rotation vector ω with R_est = R(ω) R_true, rad; offset t_est − t_true, m): the fit's parameters."""
    return rotation_vector(T_est[:3, :3] @ T_true[:3, :3].T), T_est[:3, 3] - T_true[:3, 3]


def share_of_bound(error: NDArray[np.float64], covariance: NDArray[np.float64]) -> float:
    """A 3-vector error in units of its 95 % ellipsoid: √(eᵀ Σ⁻¹ e / χ²₃,₀.₉₅); 1 on the ellipsoid's surface."""
    e = np.asarray(error, dtype=np.float64)
    return float(np.sqrt(max(float(e @ np.linalg.pinv(covariance) @ e), 0.0) / CHI2_3_95))


def within_bound(error: NDArray[np.float64], covariance: NDArray[np.float64]) -> bool:
    """Whether a 3-vector error lies inside the 95 % ellipsoid of its covariance (Mahalanobis vs χ²₃)."""
    return share_of_bound(error, covariance) <= 1.0


def _residuals(params: NDArray[np.float64], T0: NDArray[np.float64], planes: list[NDArray[np.float64]],
               points: list[NDArray[np.float64]]) -> list[NDArray[np.float64]]:
    T = make_pose(rotation_matrix(params[:3]) @ T0[:3, :3], T0[:3, 3] + params[3:6])
    T_cam_from_robot = invert(T)
    out = []
    for q, p in zip(planes, points, strict=True):
        R_cb = rotation_matrix(q[:3])
        n, d = R_cb[:, 2], float(R_cb[:, 2] @ q[3:])
        pc = p @ T_cam_from_robot[:3, :3].T + T_cam_from_robot[:3, 3]
        out.append(pc @ n - d)
    return out


def calibrate_mount(views: list[BoardPlaneView], scans_robot: list[NDArray[np.float64]],
                    T_robot_from_camera_left_design: NDArray[np.float64],
                    design_sigma: tuple[float, float] | None = (np.radians(DESIGN_SIGMA_DEG), DESIGN_SIGMA_M)
                    ) -> MountFit:
    """The mount from board views (camera_left) and the laser scans taken at the same time (robot frame).

    design_sigma: the build tolerance (rad, m; σ per axis) that makes the design value the fit's prior; None:
    the laser alone."""
    if len(views) != len(scans_robot):
        raise InputError(f"mount calibration: {len(views)} board views but {len(scans_robot)} laser scans")
    T0 = np.asarray(T_robot_from_camera_left_design, dtype=np.float64)
    planes = [np.concatenate([rotation_vector(v.T_camera_from_board[:3, :3]), v.T_camera_from_board[:3, 3]])
              for v in views]
    # Candidates: near the plane the design mount predicts, and within the printed board's width.
    picked, used, sources = [], [], []
    for k, (v, scan) in enumerate(zip(views, scans_robot, strict=True)):
        scan = np.asarray(scan, dtype=np.float64).reshape(-1, 3)
        r = _residuals(np.zeros(6), T0, [planes[k]], [scan])[0]
        in_board = invert(v.T_camera_from_board) @ invert(T0)
        xb = scan @ in_board[:3, :3].T[:, 0] + in_board[0, 3]
        keep = (np.abs(r) < GATE_M) & (xb >= v.x_range_m[0]) & (xb <= v.x_range_m[1])
        if keep.sum() >= MIN_POINTS_PER_VIEW:
            picked.append(scan[keep])
            used.append(k)
            sources.append(v.source)
    if len(used) < MIN_VIEWS:
        raise InputError(f"mount calibration: the laser met the board's panel in {len(used)} of {len(views)} "
                         f"views; at least {MIN_VIEWS} are needed",
                         "stand the panel on the floor in front of the robot, across the laser's plane, leaning "
                         "back by 0-25° and turned by up to ±25°")
    planes = [planes[k] for k in used]
    views = [views[k] for k in used]
    x = np.zeros(6)
    for _ in range(4):  # refit, dropping points the fit puts beyond RESIDUAL_GATE_SIGMAS (laser outliers)
        sol = least_squares(lambda v, pts=picked: np.concatenate(_residuals(v, T0, planes, pts)), x, method="lm",
                            xtol=1e-12, ftol=1e-12, gtol=1e-12)
        x = sol.x
        res = _residuals(x, T0, planes, picked)
        sigma = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
        kept = [np.abs(r) <= RESIDUAL_GATE_SIGMAS * sigma for r in res]
        if all(k.all() for k in kept):
            break
        picked = [p[k] for p, k in zip(picked, kept, strict=True)]
    r_all = np.concatenate(_residuals(x, T0, planes, picked))
    var = float(r_all @ r_all) / max(len(r_all) - 6, 1)
    if design_sigma is not None:  # the maximum a posteriori fit: laser residuals in σ_laser, the prior's in its σ
        scale = np.repeat(design_sigma, 3)

        def posterior(v: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.concatenate([np.concatenate(_residuals(v, T0, planes, picked)) / np.sqrt(var),
                                   build_error(v, T0) / scale])

        x = least_squares(posterior, x, method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12).x
        r_all = np.concatenate(_residuals(x, T0, planes, picked))
        var = float(r_all @ r_all) / max(len(r_all) - 6, 1)
    J = approx_derivative(lambda v: np.concatenate(_residuals(v, T0, planes, picked)), x, method="3-point")
    information = J.T @ J / var
    middle = np.zeros((6, 6))
    start = 0
    for k, (q, p) in enumerate(zip(planes, picked, strict=True)):
        Jk = J[start:start + len(p)]
        start += len(p)
        Ak = approx_derivative(lambda qq, k=k: _residuals(x, T0, [qq], [picked[k]])[0], q, method="3-point")
        Sk = var * np.eye(len(p)) + Ak @ views[k].covariance @ Ak.T
        middle += Jk.T @ Sk @ Jk / var**2
    if design_sigma is not None:
        G = approx_derivative(lambda v: build_error(v, T0) / scale, x, method="3-point")
        information = information + G.T @ G
        middle = middle + G.T @ G
    A = np.linalg.pinv(information)
    T = make_pose(rotation_matrix(x[:3]) @ T0[:3, :3], T0[:3, 3] + x[3:6])
    return MountFit(T, A @ middle @ A, float(np.sqrt(var)), [len(p) for p in picked], sources)


def camera_draws_covariance(views: list[BoardView], scans_robot: list[NDArray[np.float64]],
                            T_robot_from_camera_left_design: NDArray[np.float64], fit: MountFit,
                            cameras: list[Intrinsics]) -> NDArray[np.float64]:
    """What the camera's own calibration error does to the mount: the fit repeated with each of `cameras` (draws
    of camera_left from its calibration's covariance; the laser data the same), the sample covariance of where
    the mount lands (ω, δt about fit), 6x6. The fit itself takes the intrinsics as exact: add this to it."""
    shifts = []
    for camera in cameras:
        try:
            again = calibrate_mount([board_plane_view(v, camera) for v in views], scans_robot,
                                    T_robot_from_camera_left_design)
        except InputError:
            continue  # this draw lost a view the fit needs: the spread goes without it
        shifts.append(np.concatenate(mount_errors(again.T_robot_from_camera_left, fit.T_robot_from_camera_left)))
    if len(shifts) < 2:
        return np.zeros((6, 6))
    return np.cov(np.array(shifts), rowvar=False)


def build_error(params: NDArray[np.float64], T_design: NDArray[np.float64]) -> NDArray[np.float64]:
    """(v rad, t m) of the build error M = T · design⁻¹ for the fit's parameters (ω, δt): v = ω and
    t = t₀ + δt − R(ω) t₀."""
    t0 = T_design[:3, 3]
    return np.concatenate([params[:3], t0 + params[3:6] - rotation_matrix(params[:3]) @ t0])


def design_covariance(T_design: NDArray[np.float64],
                      design_sigma: tuple[float, float] = (np.radians(DESIGN_SIGMA_DEG), DESIGN_SIGMA_M)
                      ) -> NDArray[np.float64]:
    """The design value's own covariance in the fit's parameters (ω, δt): the prior's, carried through
    build_error (its Jacobian inverted at zero)."""
    G = approx_derivative(lambda v: build_error(v, T_design), np.zeros(6), method="3-point")
    Ginv = np.linalg.inv(G)
    return Ginv @ np.diag(np.repeat(np.square(design_sigma), 3)) @ Ginv.T
