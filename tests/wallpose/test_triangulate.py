import numpy as np

from geometry.poses import invert, look_at, transform_points
from wallpose.triangulate import triangulate_rays, triangulate_stereo


def test_rays_through_a_point_meet_there() -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (20, 3)) + np.array([0.0, 0.0, 3.0])
    origins = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.1, 0.25, 0.0]])
    dirs = points[:, None, :] - origins[None]
    # exact rays: float64 round-off at metres is ~1e-15 m; 1e-9 m leaves room for the solve's conditioning
    assert np.allclose(triangulate_rays(origins, dirs), points, atol=1e-9)
    valid = np.ones((20, 3), bool)
    valid[:5, 1:] = False  # one view only: no point
    out = triangulate_rays(origins, dirs, valid)
    assert np.isnan(out[:5]).all() and np.allclose(out[5:], points[5:], atol=1e-9)


def test_stereo_from_normalized_coordinates() -> None:
    T_world_from_left = look_at([0, 0, 0], [0, 0, 1], up=(0, -1, 0))
    T_world_from_right = look_at([0.2, 0.01, 0], [0.1, 0, 1], up=(0, -1, 0))
    T_right_from_left = invert(T_world_from_right) @ T_world_from_left
    points = np.array([[0.3, -0.2, 2.0], [-0.5, 0.4, 4.0], [0.0, 0.0, 1.0]])
    left = points[:, :2] / points[:, 2:]
    pr = transform_points(T_right_from_left, points)
    right = pr[:, :2] / pr[:, 2:]
    # exact coordinates: float64 round-off, far below 1e-9 m
    assert np.allclose(triangulate_stereo(left, right, T_right_from_left), points, atol=1e-9)
