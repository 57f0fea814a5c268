"""The calibration station on the simulated site: boards held in front of the cameras, patterns projected at
commanded head angles, photographs from both cameras — and the truth, for reporting errors.

It places things physically (boards relative to the true camera pose, as a person would hold them in view);
the calibration steps only ever see the photographs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.boards import Board, BoardView, detect
from calibration.defaults import DEFAULT_BOARD
from geometry.head import HeadModel
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, rotation_about, transform_points

STEREO_BOARD = DEFAULT_BOARD  # the board the wizard tells a person to print
HEAD_APPROACH_DEG = 2.0  # every commanded angle is approached from below, so backlash is the same each time
DEFAULT_DISTANCE_M = 2.0  # validation target: ≤ 1 mm RMS at 2 m
Z0, ZSPAN = 1.35, 0.45


def board_pose_plan(board: Board, n: int, rng: np.random.Generator) -> list[NDArray[np.float64]]:
    """T_camera_from_board poses covering the image (3x3 regions and centre) with tilts in four directions."""
    cols, rows = board.pattern_size
    centre = np.array([(cols - 1) * board.square_m / 2, (rows - 1) * board.square_m / 2, 0.0])
    spots = [(0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1), (0, -1), (0, 1), (-1, 0), (1, 0)]
    tilts = [(30, 0), (-30, 0), (0, 30), (0, -30), (22, 22), (-22, -22), (22, -22), (-22, 22), (0, 0)]
    poses = []
    for k in range(n):
        sx, sy = spots[k % len(spots)]
        yaw, pitch = tilts[(k * 4) % len(tilts)]
        z = Z0 + ZSPAN * ((k * 7) % 5) / 4 + rng.uniform(-0.05, 0.05)
        x = sx * 0.42 * z + 0.1
        y = sy * 0.26 * z
        R = (rotation_about([0, 1, 0], np.radians(yaw + rng.uniform(-4, 4)))
             @ rotation_about([1, 0, 0], np.radians(pitch + rng.uniform(-4, 4)))
             @ rotation_about([0, 0, 1], np.radians(rng.uniform(-8, 8))))
        poses.append(make_pose(R, np.array([x, y, z]) - R @ centre))
    return poses


@dataclass
class SimTruth:
    camera_left: Intrinsics
    camera_right: Intrinsics
    T_right_from_left: NDArray[np.float64]
    projector: Intrinsics
    head: HeadModel  # in the robot frame, true angles
    bias_deg: NDArray[np.float64]
    T_robot_from_camera_left: NDArray[np.float64]


class SimStation:
    """Drives arproj.sim.Site for the wizard."""

    def __init__(self, seed: int = 0, distance_m: float = DEFAULT_DISTANCE_M) -> None:
        from arproj.sim.site import Site

        self.site = Site.build(seed=seed)
        self.site.place_robot(distance_m, 0.0)
        self.rng = np.random.default_rng(seed + 1000)
        # The projector shows black while boards are photographed (room light only).
        self._black = np.zeros((self.site.projector.height, self.site.projector.width), np.uint8)
        # The head plan turns about these angles: they put the projected image's centre (not the optical
        # axis, which lens shift moves off the image) at the aim point, so the image stays in the cameras' view.
        p = self.site.projector
        shift_deg = np.degrees(np.arctan((p.cy - (p.height - 1) / 2) / p.fy))
        self.aim_deg = self.site.head_angles_cmd_deg.copy() + np.array([0.0, -shift_deg, 0.0])
        s = self.site
        self.truth = SimTruth(s.camera_left, s.camera_right, s.T_camera_right_from_camera_left, s.projector,
                              s.head, s.head_angle_bias_deg, s.T_robot_from_camera_left)

    def release(self) -> None:
        self.site.release()

    @property
    def projector_size(self) -> tuple[int, int]:
        return self.site.projector.size

    @property
    def T_robot_from_camera_left_design(self) -> NDArray[np.float64]:
        """How the cameras are mounted on the robot (by design; not calibrated here)."""
        return self.site.T_robot_from_camera_left.copy()

    def board_views(self, board: Board, n: int) -> tuple[list[BoardView | None], list[BoardView | None]]:
        """Photograph a printed board at n poses in front of the cameras; detect it in both images."""
        from arproj.sim.room import Target

        texture = board.render(pixels_per_square=48, margin_squares=1.0)
        sq = board.square_m
        size = (texture.shape[1] / 48 * sq, texture.shape[0] / 48 * sq)
        T_room_from_left = self.site.T_room_from("camera_left")
        left, right = [], []
        for k, T_cam_from_board in enumerate(board_pose_plan(board, n, self.rng)):
            T_board_from_texture = make_pose(None, [-2 * sq, -2 * sq, 0.0])
            target = Target(texture, size, T_room_from_left @ T_cam_from_board @ T_board_from_texture)
            for cam, out in (("camera_left", left), ("camera_right", right)):
                photo = self.site.photograph(cam, projector_image=self._black, targets=[target])
                out.append(detect(board, photo.image, source=f"sim board pose {k:02d} {cam}"))
        return left, right

    def command_head(self, angles_deg: NDArray[np.float64]) -> None:
        """Move the head to these (absolute, commanded) angles, always arriving from below."""
        target = np.asarray(angles_deg, dtype=np.float64)
        self.site.set_head(target - HEAD_APPROACH_DEG)
        self.site.set_head(target)

    def project(self, image: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Both cameras' photographs with the projector showing image."""
        return (self.site.photograph("camera_left", projector_image=image).image,
                self.site.photograph("camera_right", projector_image=image).image)

    def true_T_left_from_projector(self, angles_deg: NDArray[np.float64]) -> NDArray[np.float64]:
        """Truth at the angles the head actually reached (for reports only)."""
        self.command_head(angles_deg)
        return invert(self.site.T_room_from("camera_left")) @ self.site.T_room_from("projector")

    def true_landing_left(self, projector_px: NDArray[np.float64]) -> NDArray[np.float64]:
        """Where projector pixels truly land (camera_left frame), at the current head pose."""
        truth = self.site.raycast("projector", projector_px)
        return transform_points(invert(self.site.T_room_from("camera_left")), truth.points_room.reshape(-1, 3))
