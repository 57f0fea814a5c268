"""The wall-pose library (wallpose/) on the simulated site: the site's rig and room as the estimator takes them,
the robot placed in front of a wall, the pattern photographed by both cameras, and the truth the estimate is
judged against. Used by the benchmark, the CLI, the projection session and the tests; wallpose/ itself knows only
real data (ViewRig.from_rig)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from arproj.sim.protocols import RobotSite, SiteTruth
from geometry.head import HeadModel
from geometry.poses import invert, transform_points
from wallpose.pose import RoomMap
from wallpose.rig import ViewRig

# A room large enough for 4 m at 60° incidence in front of wall 0 (the default room is 5 m x 4 m).
LARGE_ROOM = {"corners_m": [[12.0, 0.0], [0.0, 0.0], [0.0, 10.0], [12.0, 10.0]]}


@dataclass
class WallTruth:
    """The true wall plane in the robot frame (normal into the room, normal·X = -distance) and the point
    (robot frame) where a projector pixel really lands."""

    normal: NDArray[np.float64]
    distance: float
    T_wall_from_robot: NDArray[np.float64]
    T_robot_from_projector: NDArray[np.float64]


def room_map(site: SiteTruth) -> RoomMap:
    """The site's walls as the full wall-pose estimate takes them (a real robot's come from a room survey)."""
    walls = site.walls
    return RoomMap([np.asarray(w.T_room_from_wall) for w in walls], [(w.width_m, w.height_m) for w in walls])


def calibrated_views(site: RobotSite) -> ViewRig:
    """The rig as a perfect calibration would know it: true intrinsics, camera poses and head kinematics with
    its angle bias, at the commanded angles. What stays unknown is the head's repeatability (angle noise and
    backlash), as on a real robot."""
    head = site.head
    calibrated = HeadModel(axes=head.axes, points=head.points,
                           T_robot_from_projector_zero=head.T_robot_from_projector_zero,
                           zero_offsets_deg=np.asarray(site.head_angle_bias_deg))
    return ViewRig(camera_left=site.camera_left, camera_right=site.camera_right, projector=site.projector,
                   T_robot_from_camera_left=site.T_robot_from_camera_left,
                   T_camera_right_from_camera_left=site.T_camera_right_from_camera_left,
                   T_robot_from_projector=calibrated.T_robot_from_projector(site.head_angles_cmd_deg))


def wall_truth(site: SiteTruth, wall: int = 0) -> WallTruth:
    T_robot_from_room = invert(site.T_room_from_robot)
    T_robot_from_wall = T_robot_from_room @ site.walls[wall].T_room_from_wall
    n = T_robot_from_wall[:3, 2].copy()
    return WallTruth(n, float(-n @ T_robot_from_wall[:3, 3]), invert(T_robot_from_wall),
                     np.asarray(site.T_robot_from_projector).copy())


def true_landing(site: SiteTruth, projector_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 3) robot-frame points where projector pixels (n, 2) really land (NaN where on nothing)."""
    truth = site.raycast("projector", np.asarray(projector_px, dtype=np.float64).reshape(-1, 2))
    points = truth.points_room.reshape(-1, 3)
    return transform_points(invert(site.T_room_from_robot), points)


AUTO_EXPOSURE_LEVEL = 0.75      # the brightest pattern pixels (99.5th percentile) land at this fraction of full well
AUTO_EXPOSURE_MAX_GAIN = 4.0    # never expose longer than this many times the scene's default


def metered_exposure(site: RobotSite, camera: str, radiance: NDArray[np.float32]) -> float:
    """Exposure time (s) that puts the brightest part of the lit pattern just below clipping (auto exposure)."""
    model = site.camera_models[camera]
    signal = radiance[..., :3] @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    bright = float(np.percentile(signal[signal > 0], 99.5)) if np.any(signal > 0) else 0.0
    if bright <= 0:
        return float(model.exposure_s)
    exposure = AUTO_EXPOSURE_LEVEL * model.full_well_e / (bright * model.responsivity)
    return float(min(exposure, AUTO_EXPOSURE_MAX_GAIN * model.exposure_s))


def photograph_pair(site: RobotSite, projector_image: NDArray[np.uint8], rng: np.random.Generator,
                    exposure_gain: float = 1.0, auto_exposure: bool = True) -> tuple[NDArray, NDArray]:
    """Both cameras' photos of the projector showing projector_image, each rendered once.

    auto_exposure meters each camera on the lit pattern (as a camera's auto exposure would); exposure_gain
    multiplies the result (e.g. 8 for an over-exposed shot). Sensor noise is drawn from rng."""
    images = []
    for camera in ("camera_left", "camera_right"):
        radiance = site.render_radiance(camera, projector_image)
        model = site.camera_models[camera]
        exposure = metered_exposure(site, camera, radiance) if auto_exposure else model.exposure_s
        images.append(model.develop(radiance, exposure * exposure_gain, rng))
    return images[0], images[1]
