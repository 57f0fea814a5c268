"""Registration of the projection to the wall: the wall frame from the measured plane, the projector's pose
in it, the expected error on the wall, and the closed loop (check marks photographed and triangulated).

Conventions: T_wall_from_robot maps robot points into the wall frame (x along the wall, y up, z into the
room); the plane estimate (wallpose) gives the wall's normal and distance in the robot frame and the
projector's measured pose T_camera_left_from_projector.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from arproj.session import gate
from arproj.session import tolerances as tol
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, transform_points
from geometry.robust import refine
from geometry.triangulation import reprojection_residuals, triangulate

MARK_MIN_CAMERA_PX = 3.5       # check-mark radius as seen by a camera, at least
MARK_SEARCH_FACTOR = 3.0       # search window radius, in mark radii
MARK_MIN_CONTRAST = 12.0       # grey levels a mark must stand out from its surroundings


def snap_to_plane(T_wall_from_robot_prior: NDArray[np.float64], normal_robot: NDArray[np.float64],
                  distance: float) -> NDArray[np.float64]:
    """The prior wall frame moved onto the measured plane (n·X + d = 0 in the robot frame, n into the room).

    The plane fixes 3 degrees of freedom (tilt of the wall, distance); the prior keeps the other three
    (position along the wall, height, rotation about the normal), as measured by localization, laser or
    the wall's edges.
    """
    T_robot_from_wall = invert(T_wall_from_robot_prior)
    n = np.asarray(normal_robot, dtype=np.float64) / np.linalg.norm(normal_robot)
    y = T_robot_from_wall[:3, 1] - (T_robot_from_wall[:3, 1] @ n) * n
    y /= np.linalg.norm(y)
    x = np.cross(y, n)
    origin = T_robot_from_wall[:3, 3]
    origin = origin - (n @ origin + distance) * n
    return invert(make_pose(np.column_stack([x, y, n]), origin))


def incidence_deg(T_wall_from_projector: NDArray[np.float64]) -> float:
    """Angle between the projector's optical axis and the wall's normal."""
    axis = T_wall_from_projector[:3, 2]
    return float(np.degrees(np.arccos(min(1.0, abs(axis[2]) / np.linalg.norm(axis)))))


def aim_point_on_wall(T_wall_from_projector: NDArray[np.float64], projector: Intrinsics,
                      pixel: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Wall (x, y, 0) hit by a projector pixel (default: the image centre)."""
    px = np.array([[(projector.width - 1) / 2, (projector.height - 1) / 2]]) if pixel is None else pixel
    return rays_to_wall(T_wall_from_projector, projector, np.asarray(px, dtype=float).reshape(-1, 2))[0]


def rays_to_wall(T_wall_from_projector: NDArray[np.float64], projector: Intrinsics,
                 pixels: NDArray[np.float64]) -> NDArray[np.float64]:
    """Wall points (n, 3) (z = 0) where projector pixels (n, 2) land; NaN behind the projector."""
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if len(pixels) == 0:
        return np.zeros((0, 3))
    rays = projector.rays(pixels) @ T_wall_from_projector[:3, :3].T
    origin = T_wall_from_projector[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / rays[:, 2]
    t = np.where(t > 0, t, np.nan)
    return origin + t[:, None] * rays


def project_in_view(intr: Intrinsics, points_cam: NDArray[np.float64], margin: float = 0.0
                    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Pixels (n, 2) of camera-frame points and which of them are truly in view (inside the image shrunk by
    margin, a fraction of its size). Points far outside the field of view can be folded back into the image
    by the distortion polynomial; they are recognised by their pinhole projection and reported outside."""
    p = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    front = p[:, 2] > 1e-6
    safe = np.where(front[:, None], p, [0.0, 0.0, 1.0])
    uv = intr.project(safe)
    pinhole = intr.without_distortion().project(safe)
    w, h = intr.width, intr.height
    lo_u, hi_u, lo_v, hi_v = margin * w - 0.5, (1 - margin) * w - 0.5, margin * h - 0.5, (1 - margin) * h - 0.5
    inside = front & (uv[:, 0] > lo_u) & (uv[:, 0] < hi_u) & (uv[:, 1] > lo_v) & (uv[:, 1] < hi_v)
    # the pinhole image of an in-view point lies within the distortion's reach of the image (50 % slack)
    inside &= (pinhole[:, 0] > -0.5 * w) & (pinhole[:, 0] < 1.5 * w) & (pinhole[:, 1] > -0.5 * h) \
        & (pinhole[:, 1] < 1.5 * h)
    if intr.has_distortion and inside.any():
        # and undistorting its pixel gives back its own ray (no fold-over)
        rays = intr.rays(uv[inside])
        direct = safe[inside, :2] / safe[inside, 2:3]
        inside[np.flatnonzero(inside)] = np.linalg.norm(rays[:, :2] - direct, axis=1) < 1e-6
    return uv, inside


def pixel_footprint_m(T_wall_from_projector: NDArray[np.float64], projector: Intrinsics,
                      pixel: NDArray[np.float64] | None = None) -> float:
    """Size of one projector pixel on the wall (metres): the longer side of its footprint."""
    px = np.array([(projector.width - 1) / 2, (projector.height - 1) / 2]) if pixel is None else pixel
    steps = np.array([px, px + np.array([1.0, 0.0]), px + np.array([0.0, 1.0])])
    pts = rays_to_wall(T_wall_from_projector, projector, steps)
    return float(max(np.linalg.norm(pts[1] - pts[0]), np.linalg.norm(pts[2] - pts[0])))


# Wall-frame degrees of freedom of the robot's pose, as pose_sigma_on_wall_m's `known` names them: rotations
# about the wall's x (horizontal along it: the robot's pitch when facing it), y (the vertical: its heading) and z
# (the normal: its roll when facing it), and its position along, up and off the wall.
POSE_DOFS = ("tilt about the wall's horizontal", "turn about the vertical", "rotation about the wall's normal",
             "position along the wall", "height", "distance")
# What an inclinometer on the robot measures (the wall being vertical): both tilts against gravity
TILT_DOFS = (POSE_DOFS[0], POSE_DOFS[2])


def pose_sigma_on_wall_m(points_xy: NDArray[np.float64], T_wall_from_robot: NDArray[np.float64],
                         covariance: NDArray[np.float64], known: tuple[str, ...] = ()) -> NDArray[np.float64]:
    """1σ (n,) metres by which wall points (n, 2) fixed to the robot move in the wall's plane when the robot's
    pose is off by δ ~ N(0, covariance) (6, 6): δ = (rotation vector rad, translation m) in the robot frame,
    T_true = T_wall_from_robot · exp(δ) (wallpose.pose.WallPose.covariance).

    Where a projector pixel lands moves with the robot: by its in-plane translation, by a rotation about the
    normal times the distance from where the robot's position is pinned, and by a turn about an in-plane axis
    (pitch, heading) times the distance to the wall — all with their correlations. The length of the 2-D
    displacement (root of the 2x2 covariance's trace). Its out-of-plane part slides the landing along the ray:
    that is the plane's share (local_registration_sigma_m's offset and tilt terms).

    known: wall-frame degrees of freedom (POSE_DOFS) taken as measured exactly — the covariance conditioned on
    them (what another sensor, e.g. an inclinometer for the roll, would leave at best)."""
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    R = np.asarray(T_wall_from_robot, dtype=np.float64)[:3, :3]
    C = np.asarray(covariance, dtype=np.float64)
    if known:
        # δ in wall axes (rotation, translation) = blockdiag(R, R)·δ; condition there, then back
        B = np.kron(np.eye(2), R)
        W = B @ C @ B.T
        for dof in known:
            k = POSE_DOFS.index(dof)
            if W[k, k] > 0:
                W = W - np.outer(W[:, k], W[k, :]) / W[k, k]
        C = B.T @ W @ B
    X = transform_points(invert(T_wall_from_robot), np.column_stack([pts, np.zeros(len(pts))]))
    # d(wall point)/dδ = R·[-[X]×, I] for a robot-frame point X; only the wall's x and y rows
    J = np.zeros((len(pts), 2, 6))
    Rxy = R[:2]
    J[:, :, 3:] = Rxy
    skew = np.zeros((len(pts), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -X[:, 2], X[:, 1], -X[:, 0]
    skew -= np.transpose(skew, (0, 2, 1))
    J[:, :, :3] = -np.einsum("ij,njk->nik", Rxy, skew)
    cov = np.einsum("nij,jk,nlk->nil", J, C, J)
    return np.asarray(np.sqrt(np.maximum(np.trace(cov, axis1=1, axis2=2), 0.0)), dtype=np.float64)


@dataclass
class SigmaTerms:
    """The registration error's 1σ terms (n,) metres at each drawn point; the bound is their root sum of
    squares (local_registration_sigma_m). offset / tilt: the plane's offset and tilt sliding the landing along
    the projector's ray; in_plane: the map frame's (or, without a fused pose, the pose's) in-plane σ;
    calibration: the projector calibration's residual on the wall; pose: the fused pose's own σ
    (pose_sigma_on_wall_m), or the roll about the normal times the lever without one."""

    offset: NDArray[np.float64]
    tilt: NDArray[np.float64]
    in_plane: NDArray[np.float64]
    calibration: NDArray[np.float64]
    pose: NDArray[np.float64]

    NAMES = ("offset", "tilt", "in_plane", "calibration", "pose")

    @property
    def total(self) -> NDArray[np.float64]:
        return np.asarray(np.sqrt(sum(getattr(self, name) ** 2 for name in self.NAMES)), dtype=np.float64)

    def largest(self, where: NDArray[np.bool_] | None = None) -> tuple[str, float]:
        """The term with the largest mean square over the points `where` (all: None) and its share of the
        total variance there."""
        mask = np.ones(len(self.total), bool) if where is None else np.asarray(where, dtype=bool)
        if not mask.any():
            return "none", 0.0
        var = {name: float(np.mean(getattr(self, name)[mask] ** 2)) for name in self.NAMES}
        name = max(var, key=lambda k: var[k])
        return name, var[name] / max(sum(var.values()), 1e-300)


def registration_sigma_terms(centre_distance_95_m: float, normal_95_deg: float,
                             T_wall_from_projector: NDArray[np.float64], points_xy: NDArray[np.float64],
                             centre_xy: NDArray[np.float64], in_plane_sigma_m: float, footprint_m: float,
                             calibration_px: float, roll_sigma_rad: float = 0.0,
                             lever_m: NDArray[np.float64] | None = None,
                             pose_sigma_m: NDArray[np.float64] | None = None) -> SigmaTerms:
    """The terms of local_registration_sigma_m (same arguments), each (n,)."""
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    rays = np.column_stack([pts, np.zeros(len(pts))]) - T_wall_from_projector[:3, 3]
    cos_i = np.abs(rays[:, 2]) / np.linalg.norm(rays, axis=1)
    tan_i = np.tan(np.minimum(np.arccos(np.clip(cos_i, 0.0, 1.0)), np.radians(80.0)))
    lever = np.linalg.norm(pts - np.asarray(centre_xy, dtype=np.float64)[:2], axis=1) if lever_m is None \
        else np.asarray(lever_m, dtype=np.float64)
    ones = np.ones(len(pts))
    return SigmaTerms(
        offset=centre_distance_95_m / tol.Z95 * tan_i,
        tilt=lever * np.radians(normal_95_deg) / np.sqrt(5.991) * tan_i,
        in_plane=in_plane_sigma_m * ones, calibration=calibration_px * footprint_m * ones,
        pose=lever * roll_sigma_rad if pose_sigma_m is None else np.asarray(pose_sigma_m, dtype=np.float64) * ones)


def why_cut(terms: SigmaTerms, points_xy: NDArray[np.float64], cut: NDArray[np.bool_],
            T_wall_from_robot: NDArray[np.float64] | None = None,
            covariance: NDArray[np.float64] | None = None) -> str:
    """What cuts the map where the bound exceeds the tolerance (cut (n,)): the largest term there and, when it
    is the fused pose's, the degree of freedom (POSE_DOFS) whose exact knowledge would shrink the bound there
    most, with the mean 95 % bound before and after. Empty when nothing is cut."""
    cut = np.asarray(cut, dtype=bool)
    if not cut.any():
        return ""
    name, share = terms.largest(cut)
    before = float(np.mean(tol.Z95 * terms.total[cut]))
    say = f"the {name} term ({100 * share:.0f} % of the variance where cut; 95 % bound there {1000 * before:.1f} mm)"
    if name != "pose" or covariance is None or T_wall_from_robot is None:
        return say
    pts = np.asarray(points_xy, dtype=np.float64)[cut]
    others = np.sqrt(np.maximum(terms.total[cut] ** 2 - terms.pose[cut] ** 2, 0.0))

    def bound_if_known(dofs: tuple[str, ...]) -> float:
        pose = pose_sigma_on_wall_m(pts, T_wall_from_robot, covariance, known=dofs)
        return float(np.mean(tol.Z95 * np.sqrt(others ** 2 + pose ** 2)))

    after = {dof: bound_if_known((dof,)) for dof in POSE_DOFS}
    best = min(after, key=lambda k: after[k])
    return (f"{say}: the pose's {best} known would leave {1000 * after[best]:.1f} mm, both tilts known (an "
            f"inclinometer) {1000 * bound_if_known(TILT_DOFS):.1f} mm")


def local_registration_sigma_m(centre_distance_95_m: float, normal_95_deg: float,
                               T_wall_from_projector: NDArray[np.float64], points_xy: NDArray[np.float64],
                               centre_xy: NDArray[np.float64], in_plane_sigma_m: float, footprint_m: float,
                               calibration_px: float, roll_sigma_rad: float = 0.0,
                               lever_m: NDArray[np.float64] | None = None,
                               pose_sigma_m: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """1σ registration error on the wall (metres) at each drawn point points_xy (n, 2).

    A plane offset δd slides a point's landing along the wall by δd·tan(i), i the local incidence of the
    projector's ray there; a tilt δθ about the pattern's centre lifts a point r away by r·δθ, which slides by
    r·δθ·tan(i); a rotation about the normal moves it by r·δφ; plus the in-plane position's σ and the
    calibration's residual (projector pixels × footprint). On an
    oblique wall the far end of the image is much less certain than the part near the aim point. lever_m (n,):
    each point's distance from the pattern's centre when that lies off this wall (another wall of a corner).
    pose_sigma_m (n,): the wall pose's own 1σ at each point (pose_sigma_on_wall_m, from its full covariance);
    it takes the place of the roll term, in_plane_sigma_m is then what adds to it (the map frame's σ).
    The terms one by one: registration_sigma_terms.
    """
    return registration_sigma_terms(centre_distance_95_m, normal_95_deg, T_wall_from_projector, points_xy,
                                    centre_xy, in_plane_sigma_m, footprint_m, calibration_px, roll_sigma_rad,
                                    lever_m, pose_sigma_m).total


def inside_polygon(points_xy: NDArray[np.float64], polygon: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(n,) which wall points lie inside (or on) a polygon (k, 2)."""
    contour = np.asarray(polygon, dtype=np.float32).reshape(-1, 1, 2)
    return np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), False) >= 0
                     for x, y in np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)], dtype=bool)


@dataclass
class TrustedRegion:
    """Where the map may be drawn: polygon (k, 2) wall metres, or None for everywhere it lands; sigma_m the
    largest expected 1σ error inside; share the fraction of the drawn area's sample points inside. points_xy
    and point_sigma_m: those samples and their 1σ (to redraw the region after the closed loop);
    checked_polygon: where the closed loop puts its marks (the region drawn with the reserve; None: all)."""

    polygon: NDArray[np.float64] | None
    sigma_m: float
    share: float
    points_xy: NDArray[np.float64] | None = None
    point_sigma_m: NDArray[np.float64] | None = None
    checked_polygon: NDArray[np.float64] | None = None

    @property
    def usable(self) -> bool:
        return self.share >= tol.MIN_TRUSTED_SHARE


def checked_region(region: TrustedRegion, measured_m: float, tolerance_m: float) -> tuple[TrustedRegion, float]:
    """The region once the closed loop and the laser have measured (measured_m: the loop's worst mark plus the
    robot's motion): where the pose's 95 % error plus that stays within the tolerance, and the 1σ the gate
    takes (the region's largest, or the whole drawn area's when too little is left). Smaller than the region
    drawn with the reserve only when measured_m exceeds the reserve, and never larger (the marks were put
    there)."""
    if region.points_xy is None or region.point_sigma_m is None:
        return region, region.sigma_m
    reserve = max(float(measured_m), tol.CLOSED_LOOP_RESERVE_M) if np.isfinite(measured_m) else np.inf
    checked = trusted_region(region.points_xy, region.point_sigma_m, tolerance_m, reserve_m=reserve)
    checked.checked_polygon = region.checked_polygon
    return checked, checked.sigma_m if checked.usable else float(region.point_sigma_m.max())


def within_tolerance(sigma_m: NDArray[np.float64], tolerance_m: float,
                     reserve_m: float = tol.CLOSED_LOOP_RESERVE_M) -> NDArray[np.bool_]:
    """(n,) which points' 95 % error (of their 1σ sigma_m) plus reserve_m stays within the tolerance."""
    return np.asarray(tol.Z95 * np.asarray(sigma_m, dtype=np.float64) + reserve_m <= tolerance_m, dtype=bool)


def trusted_region(points_xy: NDArray[np.float64], sigma_m: NDArray[np.float64], tolerance_m: float,
                   reserve_m: float = tol.CLOSED_LOOP_RESERVE_M) -> TrustedRegion:
    """The part of the drawn area where the registration is within tolerance (95 %, with reserve_m left for
    what the closed loop measures): the convex hull of the trusted sample points (the error grows smoothly
    away from the aim point, so that region is convex in practice)."""
    points_xy = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    sigma_m = np.asarray(sigma_m, dtype=np.float64)
    if len(sigma_m) == 0:
        return TrustedRegion(None, float("inf"), 0.0)
    ok = within_tolerance(sigma_m, tolerance_m, reserve_m)
    share = float(ok.mean())
    if ok.all():
        return TrustedRegion(None, float(sigma_m.max()), 1.0, points_xy, sigma_m)
    if ok.sum() < 3:
        return TrustedRegion(None, float(sigma_m.max()), share, points_xy, sigma_m)
    hull = cv2.convexHull(points_xy[ok].astype(np.float32)).reshape(-1, 2).astype(np.float64)
    return TrustedRegion(hull, float(sigma_m[ok].max()), share, points_xy, sigma_m, hull)


# -- closed loop --------------------------------------------------------------------------------------------
def choose_marks(T_wall_from_projector: NDArray[np.float64], projector: Intrinsics,
                 extent: tuple[float, float, float, float], grid: tuple[int, int] = (8, 6),
                 border: float = 0.06) -> NDArray[np.float64]:
    """Wall points (n, 2) for check marks: a grid over the projector image's inner part, kept on the map."""
    gx = np.linspace(border, 1 - border, grid[0]) * (projector.width - 1)
    gy = np.linspace(border, 1 - border, grid[1]) * (projector.height - 1)
    px = np.array([[x, y] for y in gy for x in gx])
    wall = rays_to_wall(T_wall_from_projector, projector, px)[:, :2]
    x0, y0, x1, y1 = extent
    ok = np.all(np.isfinite(wall), axis=1) & (wall[:, 0] > x0) & (wall[:, 0] < x1) & (wall[:, 1] > y0) \
        & (wall[:, 1] < y1)
    return wall[ok]


def mark_radius_m(distance_m: float, camera: Intrinsics) -> float:
    return max(0.006, MARK_MIN_CAMERA_PX * distance_m / camera.fx)


def find_marks(image: NDArray[np.uint8], predicted_uv: NDArray[np.float64],
               radius_px: float | NDArray[np.float64]) -> NDArray[np.float64]:
    """Sub-pixel centres (n, 2) of bright marks near their predicted pixels; NaN where none stands out.

    Background-subtracted, intensity-weighted centroid in a window around the prediction, re-centred twice.
    """
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    g = gray.astype(np.float32)
    h, w = g.shape
    radii = np.broadcast_to(np.asarray(radius_px, dtype=np.float64), (len(predicted_uv),))
    out = np.full((len(predicted_uv), 2), np.nan)
    for k, (u, v) in enumerate(np.asarray(predicted_uv, dtype=np.float64)):
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        win = int(np.ceil(MARK_SEARCH_FACTOR * radii[k])) + 2
        cu, cv_ = u, v
        for _ in range(3):
            c0, c1 = round(cu) - win, round(cu) + win + 1
            r0, r1 = round(cv_) - win, round(cv_) + win + 1
            if c0 < 0 or r0 < 0 or c1 > w or r1 > h:
                break
            patch = g[r0:r1, c0:c1]
            background = float(np.percentile(patch, 40))
            weight = np.clip(patch - background, 0, None)
            peak = float(weight.max())
            if peak < MARK_MIN_CONTRAST:
                break
            weight[weight < 0.25 * peak] = 0.0  # only the mark, not the texture around it
            rows, cols = np.mgrid[r0:r1, c0:c1]
            total = weight.sum()
            new_u, new_v = float((weight * cols).sum() / total), float((weight * rows).sum() / total)
            if abs(new_u - cu) < 0.01 and abs(new_v - cv_) < 0.01:
                cu, cv_ = new_u, new_v
                out[k] = (cu, cv_)
                break
            cu, cv_ = new_u, new_v
            out[k] = (cu, cv_)
    return out


@dataclass
class ClosedLoopResult:
    """errors_xy: (k, 2) metres, where each used mark landed minus where it should (wall x, y); seen: (n,)
    marks found in both cameras and kept; offset_xy: mean error (the correction applied when small);
    residual_px: stereo residual (root median square); off_plane_m: median left/right disagreement on the wall;
    rejected: marks found in both cameras but dropped as lone outliers of the error field (not in seen)."""

    marks_xy: NDArray[np.float64]
    errors_xy: NDArray[np.float64]
    seen: NDArray[np.bool_]
    residual_px: float
    off_plane_m: float
    rejected: int = 0

    @property
    def errors_m(self) -> NDArray[np.float64]:
        return np.linalg.norm(self.errors_xy, axis=1)

    @property
    def offset_xy(self) -> NDArray[np.float64]:
        return self.errors_xy.mean(axis=0) if len(self.errors_xy) else np.zeros(2)

    def summary(self) -> str:
        if not len(self.errors_xy):
            return f"closed loop: 0 of {len(self.seen)} check marks seen"
        e = self.errors_m * 1000
        dropped = f", {self.rejected} lone outlier mark(s) dropped (mis-detected or off the wall)" \
            if self.rejected else ""
        return (f"closed loop: {self.seen.sum()} of {len(self.seen)} marks, error mean {e.mean():.2f} mm, "
                f"p95 {np.percentile(e, 95):.2f} mm, stereo residual {self.residual_px:.2f} px{dropped}")


def predict_camera_pixels(marks_xy: NDArray[np.float64], T_wall_from_robot: NDArray[np.float64],
                          T_robot_from_camera: NDArray[np.float64], camera: Intrinsics) -> NDArray[np.float64]:
    points_wall = np.column_stack([marks_xy, np.zeros(len(marks_xy))])
    p_cam = transform_points(invert(T_wall_from_robot @ T_robot_from_camera), points_wall)
    uv = camera.project(p_cam)
    behind = p_cam[:, 2] <= 0
    uv[behind] = np.nan
    return uv


MARK_MAX_RESIDUAL_PX = 1.0      # a mark whose two views do not meet within this was mis-detected
MARK_MAX_DISAGREEMENT_M = 0.004  # … or whose left and right landing points differ by more
MARK_OUTLIER_SIGMAS = 4.0        # a mark this many σ off the smooth (affine) error field of the others is alone …
MARK_OUTLIER_MAX_SHARE = 0.25    # … but no more than this share of the marks is ever dropped so
MARK_NOISE_FLOOR_PX = 0.05      # a mark's centre is not found finer than this (its noise σ, at least)
RAYLEIGH_MEDIAN = float(np.sqrt(2 * np.log(2)))  # median of a 2D error's length, in σ per axis


def lone_outliers(marks_xy: NDArray[np.float64], errors_xy: NDArray[np.float64], noise_sigma_m: float
                  ) -> NDArray[np.bool_]:
    """Marks whose error stands alone: beyond MARK_OUTLIER_SIGMAS σ of an affine error field fitted robustly to
    all marks (σ: the residuals' robust spread, at least noise_sigma_m, the marks' own measurement noise).

    Whatever moves the projection on the wall — a slipped head, a moved projector, a wrong pose — moves every
    mark together, smoothly over the wall: the affine field takes it up and no mark is dropped. A mark a
    sunlight patch made the finder mistake, or one landing on a board in front of the wall, is off alone.
    At most MARK_OUTLIER_MAX_SHARE of the marks (the worst) are dropped; with too few marks to tell, none."""
    n = len(errors_xy)
    out = np.zeros(n, dtype=bool)
    if n < 2 * tol.CLOSED_LOOP_MIN_FEATURES:
        return out
    A = np.column_stack([marks_xy, np.ones(n)])

    def refit(keep: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        field_ = np.asarray(np.linalg.lstsq(A[keep], errors_xy[keep], rcond=None)[0], dtype=np.float64)
        r = np.linalg.norm(errors_xy - A @ field_, axis=1)
        sigma = max(float(np.median(r[keep])) / RAYLEIGH_MEDIAN, noise_sigma_m)
        return field_, r <= MARK_OUTLIER_SIGMAS * sigma

    field_, keep = refine(np.ones(n, dtype=bool), refit, rounds=3, min_inliers=2 * tol.CLOSED_LOOP_MIN_FEATURES)
    if field_ is None:
        return out
    r = np.linalg.norm(errors_xy - A @ field_, axis=1)
    worst = np.argsort(-r)[:int(MARK_OUTLIER_MAX_SHARE * n)]
    out[worst] = ~keep[worst]
    return out


def field_worst_m(marks_xy: NDArray[np.float64], errors_xy: NDArray[np.float64], points_xy: NDArray[np.float64]
                  ) -> float:
    """The worst error over points_xy (the drawn area) of the affine error field the marks measured.

    The marks the cameras can photograph cover only part of what is drawn (at 60° the far end lies outside one
    camera's view). A slipped head or a moved projector errs smoothly over the wall, growing away from the
    aim point, so the worst measured mark understates the error where no mark could go; the field fitted to
    the marks tells it there. NaN with too few marks to fit it (the gate then refuses: pattern lost)."""
    marks_xy = np.asarray(marks_xy, dtype=np.float64).reshape(-1, 2)
    errors_xy = np.asarray(errors_xy, dtype=np.float64).reshape(-1, 2)
    points_xy = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    if len(errors_xy) < tol.CLOSED_LOOP_MIN_FEATURES or not len(points_xy):
        return float("nan")
    field_ = np.linalg.lstsq(np.column_stack([marks_xy, np.ones(len(marks_xy))]), errors_xy, rcond=None)[0]
    return float(np.linalg.norm(np.column_stack([points_xy, np.ones(len(points_xy))]) @ field_, axis=1).max())


def _ray_plane_xy(camera: Intrinsics, uv: NDArray[np.float64], T_wall_from_camera: NDArray[np.float64]
                  ) -> NDArray[np.float64]:
    """Wall (x, y) where each camera pixel's ray meets the wall plane z = 0."""
    return rays_to_wall(T_wall_from_camera, camera, uv)[:, :2]


def measure_marks(marks_xy: NDArray[np.float64], uv_left: NDArray[np.float64], uv_right: NDArray[np.float64],
                  camera_left: Intrinsics, camera_right: Intrinsics, T_right_from_left: NDArray[np.float64],
                  T_wall_from_camera_left: NDArray[np.float64]) -> ClosedLoopResult:
    """Where the found marks (NaN rows: not found) landed, compared with marks_xy.

    Each camera's ray is intersected with the measured wall plane (known from hundreds of pattern corners):
    on an oblique wall that is far more precise in the plane than free stereo triangulation, whose depth
    error slides along the wall by tan(incidence). The mean of both cameras is the landing point; a mark
    whose stereo reprojection residual or left/right disagreement is too large was mis-detected and is
    dropped. residual_px (root median square over all marks seen by both cameras) checks the rig: a wrong rig
    file makes every mark's rays miss each other.
    """
    seen = np.all(np.isfinite(uv_left), axis=1) & np.all(np.isfinite(uv_right), axis=1)
    points = triangulate(camera_left, camera_right, T_right_from_left, uv_left[seen], uv_right[seen])
    residual = reprojection_residuals(camera_left, camera_right, T_right_from_left, points, uv_left[seen],
                                      uv_right[seen])
    # The rig check: a wrong rig makes every mark's rays miss each other, so the median mark tells; the RMS
    # over all of them would let a few marks on a person in the beam (found off their predicted spot, their
    # two views not meeting) pass for a wrong rig, keep every mark and warn for a fine map.
    rms = float(np.sqrt(np.median(residual ** 2))) if len(residual) else float("nan")
    T_wall_from_right = T_wall_from_camera_left @ invert(T_right_from_left)
    xy_l = _ray_plane_xy(camera_left, uv_left[seen], T_wall_from_camera_left)
    xy_r = _ray_plane_xy(camera_right, uv_right[seen], T_wall_from_right)
    disagreement = np.linalg.norm(xy_l - xy_r, axis=1)
    good = (residual <= max(MARK_MAX_RESIDUAL_PX, 3.0 * np.median(residual) if len(residual) else 0.0)) \
        & (disagreement <= MARK_MAX_DISAGREEMENT_M) & np.all(np.isfinite(xy_l + xy_r), axis=1)
    if rms > gate.STEREO_RESIDUAL_MAX_PX:
        good[:] = True  # the rig itself is in doubt: keep everything, the gate will say so
    off_plane = float(np.median(disagreement[good])) if good.any() else float("nan")
    kept = np.flatnonzero(seen)[good]
    errors = 0.5 * (xy_l[good] + xy_r[good]) - marks_xy[kept]
    rejected = 0
    if rms <= gate.STEREO_RESIDUAL_MAX_PX and np.isfinite(off_plane):
        # each camera's landing point has the noise σ_d/√2 of their disagreement d (per axis), their mean half σ_d;
        # never below the finder's sub-pixel limit, as a length at the wall (noise-free images: round-off)
        floor = MARK_NOISE_FLOOR_PX * abs(float(T_wall_from_camera_left[2, 3])) / camera_left.fx
        alone = lone_outliers(marks_xy[kept], errors, max(off_plane / RAYLEIGH_MEDIAN / 2, floor))
        kept, errors, rejected = kept[~alone], errors[~alone], int(alone.sum())
    used = np.zeros(len(marks_xy), dtype=bool)
    used[kept] = True
    return ClosedLoopResult(marks_xy, errors, used, rms, off_plane, rejected)


LASER_NEAR_WALL_M = 0.08     # laser returns this close to the estimated wall plane belong to it
LASER_WINDOW_M = 1.5         # … and this far along the wall from the projected area
LASER_MIN_POINTS = 20
LASER_SEARCH_M = 0.6          # no wall return near the plane: the nearest returns within this say by how much


def laser_plane_offset_m(T_wall_from_robot: NDArray[np.float64], laser_points_robot: NDArray[np.float64],
                         centre_x: float, plane_covariance: NDArray[np.float64] | None = None) -> float:
    """How far (metres) the 2D laser's returns from this wall lie off the wall frame the cameras measured,
    near the projected area: the offset at centre_x plus the slope over LASER_WINDOW_M (robust line fit).

    Camera-measured plane and laser both live in the robot frame, so a camera mount that differs from the rig
    file (or a bumped camera) shows up here, and so does a pattern that fell partly on a board before the wall
    (the plane fitted through both tilts off the wall). T_wall_from_robot must be the cameras' plane alone: a
    pose fused with the laser already leans towards it and hides the disagreement. plane_covariance: the
    plane's (4, 4) covariance of (normal, distance) in the robot frame; the disagreement is then what lies
    beyond the plane's own 95 % error at the window's ends and centre (a plane measured at 4 m is known less
    well). When the laser sees through the plane — more returns well behind it than on it, the cameras
    measured a person or a board before the wall — their median distance is the disagreement; so it is when
    the laser sees nothing near the plane but returns within LASER_SEARCH_M of it; NaN when it sees nothing.
    """
    p = np.asarray(laser_points_robot, dtype=np.float64)
    if p.shape[1] == 2:
        raise ValueError("laser points need their height: pass (n, 3) robot-frame points")
    w = transform_points(T_wall_from_robot, p)
    window = np.abs(w[:, 0] - centre_x) < LASER_WINDOW_M
    near = (np.abs(w[:, 2]) < LASER_NEAR_WALL_M) & window
    behind = (w[:, 2] < -LASER_NEAR_WALL_M) & window
    if behind.sum() >= max(LASER_MIN_POINTS, near.sum()):
        return float(np.median(-w[behind, 2]))
    if near.sum() < LASER_MIN_POINTS:
        around = (np.abs(w[:, 2]) < LASER_SEARCH_M) & window
        return float(np.median(np.abs(w[around, 2]))) if around.sum() >= LASER_MIN_POINTS else float("nan")
    x, z = w[near, 0] - centre_x, w[near, 2]

    def refit(keep: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        A = np.column_stack([np.ones(keep.sum()), x[keep]])
        (a, b), *_ = np.linalg.lstsq(A, z[keep], rcond=None)
        r = z - (a + b * x)
        return np.array([a, b]), np.abs(r) < max(3.0 * 1.4826 * np.median(np.abs(r[keep])), 0.005)

    # line fit with outlier rejection (laser outliers return short ranges)
    line, _ = refine(np.ones(len(z), dtype=bool), refit, rounds=3)
    assert line is not None  # without min_inliers every round fits
    a, b = line
    along = np.array([-LASER_WINDOW_M, 0.0, LASER_WINDOW_M])
    offsets = np.abs(a + b * along)
    if plane_covariance is not None:
        # the plane's own 1σ offset at those points (at the laser's height), g·C·g with g = (X, 1)
        ends = np.column_stack([centre_x + along, np.full(3, np.median(w[near, 1])), np.zeros(3)])
        g = np.column_stack([transform_points(invert(T_wall_from_robot), ends), np.ones(3)])
        sd = np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", g, np.asarray(plane_covariance), g), 0.0))
        offsets = np.maximum(offsets - tol.Z95 * sd, 0.0)
    return float(offsets.max())
