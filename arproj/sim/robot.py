"""The projection robot: its 3-DOF head (nominal and true kinematics, angle errors), stereo cameras, placement.

Robot frame (ROS base_link): x forward, y left, z up, origin on the floor. The head follows
geometry.HeadModel; at zero angles the projector looks along the robot's x axis, image x to the robot's
right, image y down. Positive pan turns left (about +z), positive tilt looks up, roll turns about the
projector's axis (about robot +x at zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from geometry.errors import InputError
from geometry.head import HeadModel
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, look_at, make_pose, rotation_about, transform_points

# The projector's optical frame at zero head angles, in robot axes (columns: image x, image y, optical axis).
R_ROBOT_FROM_PROJECTOR_ZERO = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
NOMINAL_AXES = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
AIM_TOLERANCE_RAD = 1e-10


def nominal_head(config: dict) -> HeadModel:
    """The head as designed (scene section `head`): ideal axes through the configured points."""
    points = np.array([config["pan_point_m"], config["tilt_point_m"], config["projector_position_m"]])
    T_zero = make_pose(R_ROBOT_FROM_PROJECTOR_ZERO, config["projector_position_m"])
    return HeadModel(axes=NOMINAL_AXES.copy(), points=points, T_robot_from_projector_zero=T_zero)


def true_head(config: dict, rng: np.random.Generator) -> HeadModel:
    """The head as built: every axis, point and the projector mount perturbed by the configured σ."""
    nominal = nominal_head(config)
    sigma_rad = np.radians(config["axis_error_deg"])
    sigma_m = config["point_error_m"]

    def small_rotation() -> NDArray[np.float64]:
        v = rng.standard_normal(3) * sigma_rad
        angle = float(np.linalg.norm(v))
        return np.eye(3) if angle == 0 else rotation_about(v, angle)

    axes = np.array([small_rotation() @ a for a in nominal.axes])
    points = nominal.points + rng.standard_normal((3, 3)) * sigma_m
    T_zero = nominal.T_robot_from_projector_zero.copy()
    T_zero[:3, :3] = small_rotation() @ T_zero[:3, :3]
    T_zero[:3, 3] += rng.standard_normal(3) * sigma_m
    return HeadModel(axes=axes, points=points, T_robot_from_projector_zero=T_zero)


class HeadDrive:
    """Commanded vs true joint angles: true = commanded + bias + noise, stopping short by backlash."""

    def __init__(self, config: dict, rng: np.random.Generator) -> None:
        self.bias_deg = np.asarray(config["angle_bias_deg"], dtype=np.float64)
        self.noise_deg = float(config["angle_noise_deg"])
        self.backlash_deg = float(config["backlash_deg"])
        self.limits_deg = np.asarray(config["limits_deg"], dtype=np.float64)
        self.rng = rng
        self.cmd_deg = np.zeros(3)
        self.true_deg = self.bias_deg.copy()
        self._last_direction = np.zeros(3)

    def command(self, cmd_deg: ArrayLike) -> NDArray[np.float64]:
        cmd = np.asarray(cmd_deg, dtype=np.float64).reshape(-1)
        if cmd.shape != (3,) or not np.all(np.isfinite(cmd)):
            raise InputError(f"head command must be three finite angles (pan, tilt, roll) in degrees, "
                             f"got {np.asarray(cmd_deg).tolist()!r}")
        for i, name in enumerate(("pan", "tilt", "roll")):
            lo, hi = self.limits_deg[i]
            if not lo <= cmd[i] <= hi:
                raise InputError(f"head {name} = {cmd[i]:.3f}° is outside its limits [{lo}, {hi}]°",
                                 "command an angle within head.limits_deg")
        moved = np.sign(cmd - self.cmd_deg)
        direction = np.where(moved != 0, moved, self._last_direction)
        self._last_direction = direction
        self.cmd_deg = cmd
        noise = self.rng.standard_normal(3) * self.noise_deg
        self.true_deg = cmd + self.bias_deg + noise - direction * self.backlash_deg / 2.0
        return self.true_deg


def camera_poses(config: dict) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(T_robot_from_camera_left, T_camera_right_from_camera_left) of the stereo pair (section `cameras`)."""
    position = np.asarray(config["position_m"], dtype=np.float64)
    pitch = np.radians(config["pitch_deg"])
    forward = np.array([np.cos(pitch), 0.0, np.sin(pitch)])
    T_robot_from_left = look_at(position, position + forward, up=(0.0, 0.0, 1.0))
    toe = np.radians(config["toe_in_deg"])
    T_left_from_right = make_pose(rotation_about((0.0, 1.0, 0.0), -toe), [config["baseline_m"], 0.0, 0.0])
    return T_robot_from_left, invert(T_left_from_right)


def mount_error(config: dict, rng: np.random.Generator) -> NDArray[np.float64]:
    """T_robot_from_robot': how far the stereo pair's true mount is from its design (section `cameras`,
    mount_error_deg / mount_error_m, σ per axis), applied in the robot frame; the identity when both are 0."""
    v = rng.standard_normal(3) * np.radians(config["mount_error_deg"])
    t = rng.standard_normal(3) * config["mount_error_m"]
    angle = float(np.linalg.norm(v))
    return make_pose(np.eye(3) if angle == 0 else rotation_about(v, angle), t)


def camera_intrinsics(config: dict, right: bool = False) -> Intrinsics:
    c = dict(config)
    if right:
        c.update(config["right"])
    return Intrinsics.from_fov(int(c["width"]), int(c["height"]), float(c["hfov_deg"]), dist=c["dist"])


def projector_intrinsics(config: dict) -> Intrinsics:
    """Throw ratio → focal length; lens shift moves the principal point below the centre (image above axis)."""
    w, h = int(config["width"]), int(config["height"])
    f = float(config["throw_ratio"]) * w
    cy = (h - 1) / 2.0 + float(config["lens_shift"]) * h
    return Intrinsics(f, f, (w - 1) / 2.0, cy, w, h, tuple(config["dist"]))


@dataclass
class Placement:
    """Result of placing the robot: its pose, the commanded head angles, and the aimed point (room)."""

    T_room_from_robot: NDArray[np.float64]
    head_cmd_deg: NDArray[np.float64]
    aim_point: NDArray[np.float64]


def floor_pose(x: float, y: float, yaw_rad: float) -> NDArray[np.float64]:
    return make_pose(rotation_about((0.0, 0.0, 1.0), yaw_rad), [x, y, 0.0])


def aim_head(head: HeadModel, bias_deg: NDArray[np.float64], T_room_from_robot: NDArray[np.float64],
             aim_point: ArrayLike, start_deg: ArrayLike = (0.0, 0.0, 0.0), roll_deg: float = 0.0
             ) -> NDArray[np.float64]:
    """Commanded (pan, tilt, roll) that put the true projector axis through aim_point (room), roll fixed."""
    p_robot = transform_points(invert(T_room_from_robot), aim_point)

    def residual(pt: NDArray[np.float64]) -> NDArray[np.float64]:
        true = np.array([pt[0], pt[1], roll_deg]) + bias_deg
        T = head.T_robot_from_projector(true)
        p_cam = transform_points(invert(T), p_robot)
        return p_cam[:2] / max(p_cam[2], 1e-6)

    start = np.asarray(start_deg, dtype=np.float64)[:2]
    sol = least_squares(residual, start, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return np.array([sol.x[0], sol.x[1], roll_deg])


def place_in_front_of_wall(wall_T: NDArray[np.float64], wall_width: float, head: HeadModel,
                           bias_deg: NDArray[np.float64], distance_m: float, incidence_deg: float,
                           along_m: float | None, aim_height_m: float,
                           R_level_from_robot: NDArray[np.float64] | None = None) -> Placement:
    """Robot pose and head command so the projector's centre is distance_m from the aim point on the wall,
    its axis through that point at the given horizontal incidence, and the robot body facing along it.
    R_level_from_robot: the floor's tilt under the robot (geometry.poses.tilt_rotation; None: level), applied
    about the robot's origin on the floor; the head is aimed for the tilted body."""
    tilt = make_pose(R_level_from_robot)
    along = wall_width / 2.0 if along_m is None else along_m
    aim = transform_points(wall_T, [along, aim_height_m, 0.0])
    x_w, n_w = wall_T[:3, 0], wall_T[:3, 2]
    inc = np.radians(incidence_deg)
    u_h = np.cos(inc) * n_w + np.sin(inc) * x_w          # horizontal, from the wall towards the robot
    yaw = float(np.arctan2(-u_h[1], -u_h[0]))
    cmd = np.zeros(3)
    T_room_from_robot = floor_pose(0.0, 0.0, yaw) @ tilt
    for _ in range(8):
        T_robot_from_projector = head.T_robot_from_projector(cmd + bias_deg)
        # the projector's centre from the robot's origin, in room axes (the origin stays on the floor)
        c_room = rotation_about((0.0, 0.0, 1.0), yaw) @ tilt[:3, :3] @ T_robot_from_projector[:3, 3]
        dz = aim_height_m - c_room[2]
        if abs(dz) >= distance_m:
            raise InputError(f"robot.distance_m = {distance_m} is shorter than the height difference "
                             f"{abs(dz):.2f} m between the projector and the aim point")
        centre = aim + np.sqrt(distance_m**2 - dz**2) * u_h
        xy = centre[:2] - c_room[:2]
        T_room_from_robot = floor_pose(xy[0], xy[1], yaw) @ tilt
        cmd = aim_head(head, bias_deg, T_room_from_robot, aim, start_deg=cmd)
    return Placement(T_room_from_robot, cmd, aim)
