"""Degraded scenarios for the safety gate, evaluated at the level of features (no full images).

A scenario takes a registration the session really made from photographs (its belief), changes the physical
truth behind it — the robot nudged, the head slipped, part of the view occluded, or the session started with
another robot's rig file — and evaluates, exactly and cheaply:

  * what the closed loop would measure: check marks drawn where the belief says, landing where the truth
    says, seen by the true cameras (with centroid noise, occluder and image bounds), triangulated with the
    belief's rig; the laser scan at the true pose matched against the reference scan;
  * the gate's decision on that evidence (the session's own gate.decide);
  * the true registration error of the map's features under the belief (after the closed loop's correction).

That is legitimate because each step is the one the session runs on images, minus the image formation and
detection, whose accuracy the end-to-end registration measurement covers separately.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from arproj.session import gate, registration
from arproj.session import tolerances as tol
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, transform_points
from geometry.rig import Rig

if TYPE_CHECKING:
    from arproj.sim.protocols import SiteTruth

CENTROID_NOISE_PX = 0.05  # σ of a check mark's centroid in a camera image (measured on the simulated site)


@dataclass
class Truth:
    """The physical state of a simulated robot (all true values)."""

    T_wall_from_robot: NDArray[np.float64]
    T_robot_from_projector: NDArray[np.float64]
    projector: Intrinsics
    camera_left: Intrinsics
    camera_right: Intrinsics
    T_robot_from_camera_left: NDArray[np.float64]
    T_camera_right_from_camera_left: NDArray[np.float64]

    @property
    def T_wall_from_projector(self) -> NDArray[np.float64]:
        return self.T_wall_from_robot @ self.T_robot_from_projector


def truth_of(site: SiteTruth, wall_index: int) -> Truth:
    s = site
    T_wall_from_room = invert(s.walls[wall_index].T_room_from_wall)
    return Truth(T_wall_from_room @ s.T_room_from_robot, s.T_robot_from_projector, s.projector, s.camera_left,
                 s.camera_right, s.T_robot_from_camera_left, s.T_camera_right_from_camera_left)


@dataclass
class Belief:
    """What the session believes (its rig and registration)."""

    rig: Rig
    T_wall_from_robot: NDArray[np.float64]
    T_wall_from_projector: NDArray[np.float64]
    sigma_m: float
    distance_m: float


def drawn_pixels(belief: Belief, points_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Projector pixels (n, 2) at which the session draws wall points (its rig's projector model)."""
    p = transform_points(invert(belief.T_wall_from_projector), np.column_stack([points_xy, np.zeros(len(points_xy))]))
    return belief.rig.intrinsics["projector"].project(p)


def true_errors(belief: Belief, truth: Truth, points_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance (n,) metres between where the session's drawing of each wall point truly lands and the point."""
    landed = registration.rays_to_wall(truth.T_wall_from_projector, truth.projector,
                                       drawn_pixels(belief, points_xy))[:, :2]
    return np.linalg.norm(landed - points_xy, axis=1)


def observe_marks(belief: Belief, truth: Truth, marks_xy: NDArray[np.float64], rng: np.random.Generator,
                  occluder: tuple[float, float, float, float] | None = None) -> registration.ClosedLoopResult:
    """The closed loop at feature level: where the marks land (truth), what the true cameras see (noise,
    bounds, occluder: wall rectangle x0, y0, x1, y1 hiding marks), triangulated with the belief's rig."""
    landed = registration.rays_to_wall(truth.T_wall_from_projector, truth.projector, drawn_pixels(belief, marks_xy))
    visible = np.all(np.isfinite(landed), axis=1)
    if occluder is not None:
        x0, y0, x1, y1 = occluder
        visible &= ~((landed[:, 0] > x0) & (landed[:, 0] < x1) & (landed[:, 1] > y0) & (landed[:, 1] < y1))
    T_robot_from_wall = invert(truth.T_wall_from_robot)
    p_robot = transform_points(T_robot_from_wall, np.nan_to_num(landed))
    T_left_from_robot = invert(truth.T_robot_from_camera_left)
    p_left = transform_points(T_left_from_robot, p_robot)
    p_right = transform_points(truth.T_camera_right_from_camera_left, p_left)
    uv = []
    for cam, p in ((truth.camera_left, p_left), (truth.camera_right, p_right)):
        ok = p[:, 2] > 0.1
        px = cam.project(np.where(ok[:, None], p, [0.0, 0.0, 1.0])) + rng.normal(0, CENTROID_NOISE_PX, (len(p), 2))
        ok &= (px[:, 0] > 2) & (px[:, 0] < cam.width - 3) & (px[:, 1] > 2) & (px[:, 1] < cam.height - 3)
        visible &= ok
        uv.append(px)
    uv_l = np.where(visible[:, None], uv[0], np.nan)
    uv_r = np.where(visible[:, None], uv[1], np.nan)
    rig = belief.rig
    T_robot_from_left = rig.pose("T_robot_from_camera_left")
    return registration.measure_marks(marks_xy, uv_l, uv_r, rig.intrinsics["camera_left"],
                                      rig.intrinsics["camera_right"], rig.pose("T_camera_right_from_camera_left"),
                                      belief.T_wall_from_robot @ T_robot_from_left)


@dataclass
class Outcome:
    kind: str
    magnitude: str
    show_map: bool
    reasons: list[str]
    true_max_m: float
    true_mean_m: float

    @property
    def unsafe(self) -> bool:
        return self.show_map and self.true_max_m > tol.REGISTRATION_TOLERANCE_M


def evaluate(belief: Belief, truth: Truth, marks_xy: NDArray[np.float64], features_xy: NDArray[np.float64],
             rng: np.random.Generator, kind: str, magnitude: str, occluder: tuple | None = None,
             robot_motion_m: float = 0.0, pose_sigma_m: float | None = None, pose_failure: str | None = None,
             head_error_deg: float = 0.0, laser_points: NDArray[np.float64] | None = None) -> Outcome:
    """Closed loop (with its small-offset correction), gate decision and true error for one scenario."""
    if pose_failure is not None:
        ev = gate.RegistrationEvidence(pose_failure=pose_failure)
        d = gate.decide(ev)
        return Outcome(kind, magnitude, d.show_map, d.reasons, float("nan"), float("nan"))
    loop = observe_marks(belief, truth, marks_xy, rng, occluder)
    corrected = belief
    offset = loop.offset_xy
    if loop.seen.sum() >= tol.CLOSED_LOOP_MIN_FEATURES and np.linalg.norm(offset) <= tol.CLOSED_LOOP_MAX_CORRECTION_M:
        corrected = Belief(belief.rig, belief.T_wall_from_robot,
                           make_pose(None, [offset[0], offset[1], 0.0]) @ belief.T_wall_from_projector,
                           belief.sigma_m, belief.distance_m)
    else:
        offset = np.zeros(2)
    ev = gate.RegistrationEvidence(
        pose_sigma_m=belief.sigma_m if pose_sigma_m is None else pose_sigma_m,
        head_command_error_deg=head_error_deg,
        closed_loop_errors_m=np.linalg.norm(loop.errors_xy - offset, axis=1),
        closed_loop_expected=len(marks_xy),
        stereo_residual_px=loop.residual_px if loop.seen.any() else None,
        robot_motion_m=robot_motion_m)
    if laser_points is not None:
        centre = registration.aim_point_on_wall(belief.T_wall_from_projector, belief.rig.intrinsics["projector"])
        ev.laser_plane_offset_m = registration.laser_plane_offset_m(belief.T_wall_from_robot, laser_points,
                                                                    float(centre[0]))
    d = gate.decide(ev)
    errors = true_errors(corrected, truth, features_xy)
    errors = errors[np.isfinite(errors)]
    return Outcome(kind, magnitude, d.show_map, d.reasons, float(errors.max()) if len(errors) else np.inf,
                   float(errors.mean()) if len(errors) else np.inf)


def perturbed_rig(rig: Rig, variant: int, rng: np.random.Generator) -> tuple[Rig, str]:
    """Another robot's rig file (same devices, other unit): stereo extrinsics, projector, head or camera mount."""
    from dataclasses import replace

    from geometry.head import HeadModel
    from geometry.poses import rotation_about

    intr = dict(rig.intrinsics)
    poses = dict(rig.poses)
    head = rig.head
    kind = variant % 4
    if kind == 0:
        axis = rng.normal(size=3)
        angle = np.radians(rng.uniform(0.3, 1.5))
        T = rig.pose("T_camera_right_from_camera_left").copy()
        T = make_pose(rotation_about(axis, angle), rng.normal(0, 0.004, 3)) @ T
        poses["T_camera_right_from_camera_left"] = T
        poses.pop("T_camera_left_from_camera_right", None)
        what = f"stereo extrinsics off by {np.degrees(angle):.2f}°"
    elif kind == 1:
        p = intr["projector"]
        scale = 1 + rng.choice([-1, 1]) * rng.uniform(0.01, 0.04)
        intr["projector"] = replace(p, fx=p.fx * scale, fy=p.fy * scale, cy=p.cy + rng.uniform(-25, 25))
        what = f"projector focal length off by {100 * (scale - 1):+.1f} %"
    elif kind == 2:
        assert head is not None
        offsets = head.zero_offsets_deg + np.array([*rng.uniform(-1.0, 1.0, 2), 0.0])
        head = HeadModel(head.axes, head.points, head.T_robot_from_projector_zero, offsets)
        what = f"head zero offsets off by {np.abs(offsets - rig.head.zero_offsets_deg).max():.2f}°"  # type: ignore
    else:
        T = rig.pose("T_robot_from_camera_left")
        poses["T_robot_from_camera_left"] = T @ make_pose(rotation_about(rng.normal(size=3),
                                                                          np.radians(rng.uniform(0.5, 2.0))),
                                                            rng.normal(0, 0.015, 3))
        poses.pop("T_camera_left_from_robot", None)
        what = "camera mount on the robot differs"
    return Rig(intr, poses, head, {"source": "another robot's rig"}), what
