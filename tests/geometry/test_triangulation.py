"""Stereo triangulation of exact distorted pixels, and the residual that tells a wrong rig."""

import numpy as np

from geometry import Intrinsics, invert, look_at, make_pose, transform_points
from geometry.triangulation import reprojection_residuals, triangulate

LEFT = Intrinsics.from_fov(1280, 800, 70.0, dist=(-0.1, 0.05, 0.0, 0.0, 0.0))
RIGHT = Intrinsics.from_fov(1280, 800, 69.0, dist=(-0.12, 0.06, 0.0, 0.0, 0.0))
T_RIGHT_FROM_LEFT = invert(make_pose(None, [0.2, 0.0, 0.0]))


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(-0.8, 0.8, 20), rng.uniform(-0.5, 0.5, 20), rng.uniform(2, 4, 20)])
    return points, LEFT.project(points), RIGHT.project(transform_points(T_RIGHT_FROM_LEFT, points))


def test_triangulation_recovers_points_from_exact_pixels() -> None:
    points, uv_l, uv_r = _scene()
    found = triangulate(LEFT, RIGHT, T_RIGHT_FROM_LEFT, uv_l, uv_r)
    residual = reprojection_residuals(LEFT, RIGHT, T_RIGHT_FROM_LEFT, found, uv_l, uv_r)
    # exact pixels: only undistortion's iteration (to 1e-12) and float round-off remain
    assert np.abs(found - points).max() < 1e-6 and residual.max() < 1e-6


def test_a_wrong_rig_shows_in_the_residual() -> None:
    _, uv_l, uv_r = _scene()
    # the right camera turned by about 1.3° more than the rig says: ~15 px of vertical disparity
    wrong = invert(make_pose(look_at([0, 0, 0], [0.02, 0.01, 1.0], up=[0, -1, 0])[:3, :3], [0.2, 0.0, 0.0]))
    found = triangulate(LEFT, RIGHT, wrong, uv_l, uv_r)
    residual = reprojection_residuals(LEFT, RIGHT, wrong, found, uv_l, uv_r)
    assert np.sqrt(np.mean(residual ** 2)) > 1.0


def test_no_pixels_give_no_points() -> None:
    none = np.zeros((0, 2))
    assert triangulate(LEFT, RIGHT, T_RIGHT_FROM_LEFT, none, none).shape == (0, 3)
    assert reprojection_residuals(LEFT, RIGHT, T_RIGHT_FROM_LEFT, np.zeros((0, 3)), none, none).shape == (0,)
