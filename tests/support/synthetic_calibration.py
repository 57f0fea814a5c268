"""Exact synthetic captures of a plane (printed board or bare wall) lit by a projector, for the tests.

A camera pixel's ray (through the lens distortion) meets the plane; the point's albedo comes from the board
pattern; the projector lights it with the pattern pixel it falls in (through the projector's own lens
model). Rendering at `supersample`x resolution then area-averaging gives honest edges; Gaussian noise in grey
levels models the sensor. Every pose and intrinsic is known, so recovered calibrations can be checked against
the truth. (The full simulated site is arproj.sim; this is the small, fast version for the algorithms.)
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.boards import Board
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, rotation_about, transform_points

Albedo = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]

BLACK_ALBEDO = 0.08
WHITE_ALBEDO = 0.85
BACKGROUND_ALBEDO = 0.5


def chessboard_albedo(board: Board, margin_squares: float = 1.0) -> Albedo:
    """Albedo at board-frame (x, y) metres: chessboard squares, a white margin, grey beyond."""
    s = board.square_m
    cols, rows = board.pattern_size

    def albedo(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        i = np.floor(x / s).astype(np.int64) + 1
        j = np.floor(y / s).astype(np.int64) + 1
        inside = (i >= 0) & (i <= cols) & (j >= 0) & (j <= rows)
        a = np.where((i + j) % 2 == 0, BLACK_ALBEDO, WHITE_ALBEDO)
        margin = ((x >= -s * (1 + margin_squares)) & (x <= s * (cols + margin_squares))
                  & (y >= -s * (1 + margin_squares)) & (y <= s * (rows + margin_squares)))
        return np.where(inside, a, np.where(margin, WHITE_ALBEDO, BACKGROUND_ALBEDO))

    return albedo


def texture_albedo(board: Board, pixels_per_square: int = 40, margin_squares: float = 1.0) -> Albedo:
    """Albedo of the board's printable image (Board.render; ChArUco too), placed like chessboard_albedo: corner
    id 0 at the board origin, one square plus the margin in from the image's top-left; grey beyond."""
    texture = board.render(pixels_per_square, margin_squares)
    a_img = np.where(texture > 127, WHITE_ALBEDO, BLACK_ALBEDO)
    offset = (1 + margin_squares) * pixels_per_square
    s = board.square_m

    def albedo(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        i = np.floor(x / s * pixels_per_square + offset).astype(np.int64)
        j = np.floor(y / s * pixels_per_square + offset).astype(np.int64)
        inside = (i >= 0) & (i < texture.shape[1]) & (j >= 0) & (j < texture.shape[0])
        return np.where(inside, a_img[np.clip(j, 0, texture.shape[0] - 1), np.clip(i, 0, texture.shape[1] - 1)],
                        BACKGROUND_ALBEDO)

    return albedo


def uniform_albedo(value: float = WHITE_ALBEDO) -> Albedo:
    """A bare wall."""
    return lambda x, y: np.full(np.shape(x), value)


class PlaneRenderer:
    """Renders one plane pose for one camera; patterns can then be swapped cheaply (geometry is cached)."""

    def __init__(self, camera: Intrinsics, T_camera_from_plane: NDArray[np.float64], albedo: Albedo,
                 projector: Intrinsics | None = None, T_projector_from_camera: NDArray[np.float64] | None = None,
                 supersample: int = 2) -> None:
        self.camera = camera
        self.supersample = supersample
        fine = camera.scaled(supersample)
        ys, xs = np.mgrid[0:fine.height, 0:fine.width]
        rays = fine.rays(np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64))
        # Plane z = 0 in its frame: n·(t·ray − o) = 0 in the camera frame.
        n = T_camera_from_plane[:3, 2]
        o = T_camera_from_plane[:3, 3]
        denom = rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (o @ n) / denom
        hit = np.isfinite(t) & (t > 0)
        points_cam = rays * np.where(hit, t, np.nan)[:, None]
        points_plane = transform_points(invert(T_camera_from_plane), points_cam)
        self.albedo = np.where(hit, albedo(points_plane[:, 0], points_plane[:, 1]), 0.0)
        self.shape = (fine.height, fine.width)
        self.proj_index: NDArray[np.int64] | None = None
        if projector is not None and T_projector_from_camera is not None:
            p_proj = transform_points(T_projector_from_camera, points_cam)
            front = hit & (p_proj[:, 2] > 0)
            uv = np.full((len(p_proj), 2), -1.0)
            uv[front] = projector.project(p_proj[front])
            col = np.floor(uv[:, 0] + 0.5).astype(np.int64)
            row = np.floor(uv[:, 1] + 0.5).astype(np.int64)
            lit = front & (col >= 0) & (col < projector.width) & (row >= 0) & (row < projector.height)
            self.proj_index = np.where(lit, row * projector.width + col, -1)

    def render(self, pattern: NDArray[np.uint8] | None, rng: np.random.Generator, ambient: float = 60.0,
               gain: float = 190.0, noise: float = 1.0, blur_px: float = 0.6) -> NDArray[np.uint8]:
        """Camera image (h, w) uint8: albedo x (ambient + gain x pattern/255), area-averaged, lens blur
        (Gaussian σ blur_px camera pixels), plus noise (σ grey levels)."""
        light = np.full(self.albedo.shape, ambient)
        if pattern is not None and self.proj_index is not None:
            flat = np.asarray(pattern, dtype=np.float64).ravel() / 255.0
            lit = self.proj_index >= 0
            light[lit] += gain * flat[self.proj_index[lit]]
        img = (self.albedo * light).reshape(self.shape)
        img = cv2.resize(img, (self.camera.width, self.camera.height), interpolation=cv2.INTER_AREA)
        if blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), blur_px)
        img = img + rng.normal(0.0, noise, img.shape)
        return np.clip(np.round(img), 0, 255).astype(np.uint8)


def board_poses(board: Board, n: int, rng: np.random.Generator, distance_m: float = 1.0,
                max_tilt_deg: float = 35.0) -> list[NDArray[np.float64]]:
    """n varied T_camera_from_board poses: centred-ish, tilted by up to max_tilt_deg about x and y."""
    cols, rows = board.pattern_size
    centre = np.array([(cols - 1) * board.square_m / 2, (rows - 1) * board.square_m / 2, 0.0])
    poses = []
    for k in range(n):
        angle = 2 * np.pi * k / max(n, 1)
        tilt = np.radians(max_tilt_deg) * (0.4 + 0.6 * rng.random())
        axis = np.array([np.cos(angle), np.sin(angle), 0.0])
        R = rotation_about(axis, tilt) @ rotation_about([0, 0, 1], rng.uniform(-0.2, 0.2))
        offset = np.array([rng.uniform(-0.12, 0.12), rng.uniform(-0.08, 0.08), 0.0]) * distance_m
        t = np.array([0, 0, distance_m]) + offset - R @ centre
        poses.append(make_pose(R, t))
    return poses


def plane_facing(distance_m: float, yaw_deg: float, pitch_deg: float) -> NDArray[np.float64]:
    """T_device_from_plane: a plane distance_m ahead of a device, turned by yaw / pitch (degrees).

    The plane's z (its normal) points back towards the device.
    """
    R = rotation_about([0, 1, 0], np.radians(yaw_deg)) @ rotation_about([1, 0, 0], np.radians(pitch_deg))
    return make_pose(R @ rotation_about([1, 0, 0], np.pi), [0.0, 0.0, distance_m])
