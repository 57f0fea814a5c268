"""The cameras' mount from laser lines on leaning panels: the recovered mount lies within its reported 95 % bound."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.laser_mount import (
    CHI2_3_95,
    BoardPlaneView,
    calibrate_mount,
    mount_errors,
    share_of_bound,
    within_bound,
)
from geometry.poses import invert, look_at, make_pose, rotation_about

LASER_HEIGHT_M = 0.2


def _panel_views(T_robot_from_camera: np.ndarray, rng: np.random.Generator, n: int = 8
                 ) -> tuple[list[BoardPlaneView], list[np.ndarray]]:
    views, scans = [], []
    for k in range(n):
        x0, lean = (1.35, 1.55, 1.75)[k % 3], np.radians((0, 12, 24)[(k // 3) % 3])
        yaw = np.radians((-25, 0, 25, 12, -12)[k % 5])
        forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
        up = np.cos(lean) * np.array([0.0, 0.0, 1.0]) + np.sin(lean) * forward
        origin = np.array([x0, 0.1, 0.0]) + 1.5 * up - 0.48 * right
        T_robot_from_board = make_pose(np.column_stack([right, -up, np.cross(right, -up)]), origin)
        views.append(BoardPlaneView(invert(T_robot_from_camera) @ T_robot_from_board, np.eye(6) * 1e-10,
                                    (0.0, 0.96)))
        along = np.linspace(0.05, 0.9, 120)
        points = origin + np.outer(along, right) + (origin[2] - LASER_HEIGHT_M) / up[2] * -up
        points[:, :2] += rng.standard_normal((len(points), 2)) * 0.01  # range noise, in the scan's plane
        points[5] *= 0.5  # a laser outlier: a short return
        scans.append(points)
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
