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


def photograph_pair(site: RobotSite, projector_image: NDArray[np.uint8], rng: np.random.Generator,
                    exposure_gain: float = 1.0, auto_exposure: bool = True, direct: bool = True
                    ) -> tuple[NDArray, NDArray]:
    """Both cameras' photos of the projector showing projector_image.

    auto_exposure meters each camera on the lit pattern (as a camera's auto exposure would); exposure_gain
    multiplies the result (e.g. 8 for an over-exposed shot). Sensor noise is drawn from rng.
    direct: each photo rendered anew by the direct GL path (the projector image textured in the shader,
    multisampled: what the benchmark's full run and the tests judge); False: Site.photograph's deferred path,
    which renders a pose's geometry once and looks any further pattern up on the CPU (no multisampling; the
    same picture up to texture filtering, tests/arproj/sim/test_site.py) — about a third of the time for two
    patterns at one pose, for `bench wallpose --quick`."""
    images = []
    for camera in ("camera_left", "camera_right"):
        model = site.camera_models[camera]
        if direct:
            radiance = site.render_radiance(camera, projector_image)
            exposure = model.metered_exposure(radiance[..., :3]) if auto_exposure else model.exposure_s
            images.append(model.develop(radiance, exposure * exposure_gain, rng))
        elif exposure_gain == 1.0:
            images.append(site.photograph(camera, projector_image, "auto" if auto_exposure else None,
                                          rng=rng).image)
        else:
            raise ValueError("exposure_gain needs the direct path (its radiance is metered before the photo)")
    return images[0], images[1]
