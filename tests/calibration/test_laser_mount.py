"""The cameras' mount from laser lines on leaning panels: the recovered mount lies within its reported 95 % bound."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.boards import BoardView, parse_board
from calibration.defaults import DEFAULT_BOARD
from calibration.laser_mount import (
    CHI2_3_95,
    BoardPlaneView,
    board_plane_view,
    calibrate_mount,
    camera_draws_covariance,
    mount_errors,
    share_of_bound,
    within_bound,
)
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, look_at, make_pose, rotation_about

LASER_HEIGHT_M = 0.2


def _T_robot_from_panel(k: int, panel_width_m: float = 0.96, height_m: float = 1.5) -> np.ndarray:
    """Panel pose k of the mount plan: the board's frame at the print's top-left corner (x right, y down)."""
    x0, lean = (1.35, 1.55, 1.75)[k % 3], np.radians((0, 12, 24)[(k // 3) % 3])
    yaw = np.radians((-25, 0, 25, 12, -12)[k % 5])
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    up = np.cos(lean) * np.array([0.0, 0.0, 1.0]) + np.sin(lean) * forward
    origin = np.array([x0, 0.1, 0.0]) + height_m * up - panel_width_m / 2 * right
    return make_pose(np.column_stack([right, -up, np.cross(right, -up)]), origin)


def _laser_line(T_robot_from_panel: np.ndarray, width_m: float, rng: np.random.Generator) -> np.ndarray:
    """The laser's points where its plane cuts the panel, with range noise and one short return."""
    origin, right, down = T_robot_from_panel[:3, 3], T_robot_from_panel[:3, 0], T_robot_from_panel[:3, 1]
    along = np.linspace(0.05, 0.94, 120) * width_m
    points = origin + np.outer(along, right) + (origin[2] - LASER_HEIGHT_M) / -down[2] * down
    points[:, :2] += rng.standard_normal((len(points), 2)) * 0.01  # range noise, in the scan's plane
    points[5] *= 0.5  # a laser outlier: a short return
    return points


def _panel_views(T_robot_from_camera: np.ndarray, rng: np.random.Generator, n: int = 8
                 ) -> tuple[list[BoardPlaneView], list[np.ndarray]]:
    views, scans = [], []
    for k in range(n):
        T_robot_from_board = _T_robot_from_panel(k)
        views.append(BoardPlaneView(invert(T_robot_from_camera) @ T_robot_from_board, np.eye(6) * 1e-10,
                                    (0.0, 0.96)))
        scans.append(_laser_line(T_robot_from_board, 0.96, rng))
    return views, scans


def test_mount_within_its_bound_better_than_the_design_and_outliers_dropped() -> None:
    T_true = look_at([0.15, 0.1, 1.0], [1.15, 0.1, 1.0 + np.tan(np.radians(10))])
    design = T_true @ make_pose(rotation_about([1, 0, 0], np.radians(0.5)), [0.005, 0.0, 0.003])
    design_rot, design_pos = (np.linalg.norm(e) for e in mount_errors(design, T_true))
    inside, rot_errors, pos_errors = 0, [], []
    for seed in range(20):
        views, scans = _panel_views(T_true, np.random.default_rng(seed))
        fit = calibrate_mount(views, scans, design)
        rot, pos = mount_errors(fit.T_robot_from_camera_left, T_true)
        inside += within_bound(rot, fit.covariance[:3, :3]) and within_bound(pos, fit.covariance[3:, 3:])
        rot_errors.append(np.linalg.norm(rot))
        pos_errors.append(np.linalg.norm(pos))
        assert all(n < 120 for n in fit.points_per_view)  # the outlier is gone
        assert 0.008 < fit.rms_m < 0.012
    # Both 95 % ellipsoids hold in about 18 of 20 (measured 20 with the design value as prior; the laser alone
    # held in 13 and its errors were 2-4x the design value's: its one horizontal line leaves pitch and height
    # weakly fixed).
    assert inside >= 17
    assert np.mean(rot_errors) < 0.6 * design_rot and np.mean(pos_errors) < 0.8 * design_pos


def test_share_of_bound_is_one_on_the_95_percent_ellipsoid() -> None:
    cov = np.diag([1.0, 4.0, 9.0])
    on_surface = np.array([0.0, 2.0 * np.sqrt(CHI2_3_95), 0.0])  # 2 = σ along y
    assert share_of_bound(on_surface, cov) == pytest.approx(1.0)
    assert share_of_bound(0.5 * on_surface, cov) == pytest.approx(0.5)
    assert within_bound(0.99 * on_surface, cov) and not within_bound(1.01 * on_surface, cov)


def test_a_camera_focal_error_is_carried_into_the_mount_bound_by_the_camera_draws() -> None:
    # The same panels seen by a camera with the board corners projected, the camera calibrated 0.6 % long in
    # focal length (2 σ of its calibration): the fit takes it as exact and its offset error is 2.4 bounds out; with
    # the fit repeated for draws of the camera (σ 0.3 % focal, 1 px principal point) it is within.
    board = parse_board(DEFAULT_BOARD)
    obj = board.object_points()
    camera = Intrinsics.from_fov(640, 400, 70.0)
    T_true = look_at([0.15, 0.1, 1.0], [1.15, 0.1, 1.0 + np.tan(np.radians(15))])
    design = make_pose(rotation_about([0, 1, 0], np.radians(0.5)), [0.004, -0.003, 0.005]) @ T_true
    rng = np.random.default_rng(1)
    _, scans = _panel_views(T_true, rng)
    views = []
    for k in range(len(scans)):
        T_camera_from_board = invert(T_true) @ _T_robot_from_panel(k, panel_width_m=0.64, height_m=1.4)
        pixels, _ = cv2.projectPoints(obj, cv2.Rodrigues(T_camera_from_board[:3, :3])[0], T_camera_from_board[:3, 3],
                                      camera.K, camera.dist_array)
        views.append(BoardView(pixels.reshape(-1, 2) + rng.standard_normal((len(obj), 2)) * 0.1, obj,
                               np.arange(len(obj)), (camera.width, camera.height)))
        scans[k] = _laser_line(_T_robot_from_panel(k, panel_width_m=0.64, height_m=1.4), 0.6, rng)

    def drawn(c: Intrinsics, z: np.ndarray) -> Intrinsics:
        f = 1 + 0.003 * z[0]
        return Intrinsics(c.fx * f, c.fy * f, c.cx + z[1], c.cy + z[2], c.width, c.height, c.dist)

    calibrated = drawn(camera, np.array([2.0, 0.0, 0.0]))
    fit = calibrate_mount([board_plane_view(v, calibrated) for v in views], scans, design)
    draws = np.random.default_rng(5).standard_normal((8, 3))
    extra = camera_draws_covariance(views, scans, design, fit, [drawn(calibrated, z) for z in draws])
    _, pos = mount_errors(fit.T_robot_from_camera_left, T_true)
    assert share_of_bound(pos, fit.covariance[3:, 3:]) > 1.5
    assert share_of_bound(pos, fit.covariance[3:, 3:] + extra[3:, 3:]) < 1.0
    same = camera_draws_covariance(views, scans, design, fit, [calibrated, calibrated])
    assert np.abs(same).max() < 1e-12  # the camera as calibrated, twice: no spread


def test_a_corner_refined_pixels_off_is_left_out_of_the_board_plane() -> None:
    # As seen in the simulated live mount step (seed 7, the board 2 m away): two corners at the print's edge
    # settled 5.5 and 3.6 px off while the rest reproject to 0.06 px. Taken as pixel noise they tilted the plane:
    # 20 mm off where the laser meets the panel 1.2 m below the board, and the mount 3.6 bounds out.
    board = parse_board(DEFAULT_BOARD)
    obj = board.object_points()
    camera = Intrinsics.from_fov(640, 400, 70.0)
    T_camera_from_board = make_pose(rotation_about([1, 0.3, 0], np.radians(30)), [-0.12, 0.04, 2.0])
    pixels, _ = cv2.projectPoints(obj, cv2.Rodrigues(T_camera_from_board[:3, :3])[0], T_camera_from_board[:3, 3],
                                  camera.K, camera.dist_array)
    pixels = pixels.reshape(-1, 2) + np.random.default_rng(3).standard_normal((len(obj), 2)) * 0.06
    bad = [0, board.pattern_size[0]]
    pixels[bad] += [[-5.5, -3.5], [-3.6, 1.1]]
    view = board_plane_view(BoardView(pixels, obj, np.arange(len(obj)), (camera.width, camera.height)), camera)
    good = np.setdiff1d(np.arange(len(obj)), bad)
    clean = board_plane_view(BoardView(pixels[good], obj[good], good, (camera.width, camera.height)), camera)
    assert np.allclose(view.T_camera_from_board, clean.T_camera_from_board, atol=1e-9)
    assert np.allclose(view.covariance, clean.covariance, rtol=1e-6, atol=1e-15)
    below = T_camera_from_board @ [0.3, 1.2, 0.0, 1.0]  # on the true plane, where a laser line would cross it
    n, origin = view.T_camera_from_board[:3, 2], view.T_camera_from_board[:3, 3]
    assert abs(float(n @ (below[:3] - origin))) < 0.002
