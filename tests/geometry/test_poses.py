import cv2
import numpy as np
import pytest

from geometry import InputError, invert, look_at, make_pose, pose_from_rvec_tvec, rotation_about
from geometry.frames import parse_pose_name
from geometry.poses import (
    pose_from_vector,
    rotation_angle_deg,
    rotation_matrices,
    rotation_matrix,
    rotation_vector,
    rvec_tvec_from_pose,
    transform_points,
)


def test_invert_and_chain_read_right_to_left() -> None:
    rng = np.random.default_rng(1)
    T_a_from_b = make_pose(rotation_about(rng.normal(size=3), 0.7), rng.normal(size=3))
    T_b_from_c = make_pose(rotation_about(rng.normal(size=3), -1.2), rng.normal(size=3))
    p_c = rng.normal(size=(5, 3))
    p_a = transform_points(T_a_from_b @ T_b_from_c, p_c)
    np.testing.assert_allclose(transform_points(T_a_from_b, transform_points(T_b_from_c, p_c)), p_a)
    np.testing.assert_allclose(invert(T_a_from_b) @ T_a_from_b, np.eye(4), atol=1e-12)  # float64 round-off, ~1e-16


def test_rvec_tvec_is_T_camera_from_board_as_opencv_projects() -> None:
    rvec, tvec = np.array([0.1, -0.3, 0.2]), np.array([0.05, -0.02, 1.5])
    board = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0.02]], dtype=float)
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    uv_cv, _ = cv2.projectPoints(board, rvec, tvec, K, None)
    p_cam = transform_points(pose_from_rvec_tvec(rvec, tvec), board)
    uv = (p_cam[:, :2] / p_cam[:, 2:]) * 800 + [320, 240]
    np.testing.assert_allclose(uv, uv_cv.reshape(-1, 2), atol=1e-9)  # same pinhole in float64: ~1e-13 px apart
    r2, t2 = rvec_tvec_from_pose(pose_from_rvec_tvec(rvec, tvec))
    np.testing.assert_allclose(r2, rvec, atol=1e-12)  # Rodrigues there and back: round-off on 0.4 rad, ~1e-16
    np.testing.assert_allclose(t2, tvec)


def test_look_at_puts_target_on_the_optical_axis_with_image_up_towards_up() -> None:
    T_world_from_cam = look_at([2.0, -3.0, 1.5], [0.0, 0.0, 1.0], up=[0, 0, 1])
    target_cam = transform_points(invert(T_world_from_cam), [0.0, 0.0, 1.0])
    np.testing.assert_allclose(target_cam[:2], 0, atol=1e-12)  # float64 round-off on metre-scale coordinates
    assert target_cam[2] > 0
    above = transform_points(invert(T_world_from_cam), [0.0, 0.0, 2.0])
    assert above[1] < 0  # image y points down, so 'up' in the world is negative y


def test_rotation_angle() -> None:
    assert rotation_angle_deg(rotation_about([0, 0, 1], np.radians(30))) == pytest.approx(30)
    R = rotation_about([1, 2, 3], 0.4)
    assert rotation_angle_deg(R, R @ rotation_about([0, 1, 0], np.radians(2))) == pytest.approx(2)


def test_pose_names_use_known_frames() -> None:
    assert parse_pose_name("T_wall_from_projector") == ("wall", "projector")
    with pytest.raises(InputError, match="unknown frame 'beamer'"):
        parse_pose_name("T_wall_from_beamer")
    with pytest.raises(InputError, match="T_<dst>_from_<src>"):
        parse_pose_name("wall_to_projector")


@pytest.mark.parametrize("angle_rad", [1e-12, 1e-9, 1e-6, 0.3, 2.0, np.pi - 1e-6])
def test_rotation_angle_is_exact_from_tiny_to_half_turn(angle_rad: float) -> None:
    axis = np.array([0.3, -0.5, 0.8])
    R = rotation_about(axis, angle_rad)
    # Relative error of a few float64 ulps of the matrix entries: 1e-9 relative allows the products inside.
    assert rotation_angle_deg(R) == pytest.approx(np.degrees(angle_rad), rel=1e-9, abs=1e-14)
    assert rotation_angle_deg(np.eye(3), R) == pytest.approx(np.degrees(angle_rad), rel=1e-9, abs=1e-14)


def test_rotation_matrices_are_opencvs_rodrigues() -> None:
    rng = np.random.default_rng(9)
    rvecs = np.vstack([rng.normal(size=(20, 3)) * rng.uniform(1e-9, 3.0, (20, 1)), np.zeros((1, 3)),
                       [[np.pi, 0.0, 0.0]]])
    R = rotation_matrices(rvecs)
    for v, M in zip(rvecs, R, strict=True):
        # entries of order 1 from a few dozen operations in either library: ~100 eps
        np.testing.assert_allclose(M, cv2.Rodrigues(v)[0], rtol=0, atol=100 * np.finfo(float).eps)
        np.testing.assert_array_equal(rotation_matrix(v), M)
    assert R.shape == (22, 3, 3) and rotation_matrices(np.zeros(3)).shape == (1, 3, 3)


def test_rotation_vector_is_the_log_map() -> None:
    rng = np.random.default_rng(10)
    for v in [*rng.normal(size=(10, 3)), np.zeros(3), np.array([1e-9, -2e-9, 0.0])]:
        v = v if np.linalg.norm(v) < np.pi else v / np.linalg.norm(v) * 3.0
        # there and back: round-off on angles up to 3 rad, ~1e-15
        np.testing.assert_allclose(rotation_vector(rotation_matrix(v)), v, rtol=0, atol=1e-12)
    assert np.linalg.norm(rotation_vector(rotation_about([0, 0, 1], np.pi))) == pytest.approx(np.pi, abs=1e-12)
    # cv2.Rodrigues agrees on ordinary angles (to ~1e-9: it loses digits there) but reads rotations below
    # ~1e-5 rad as none, which would flatten the head fit's small residuals
    v = np.array([0.3, -0.2, 0.5])
    np.testing.assert_allclose(rotation_vector(rotation_matrix(v)), cv2.Rodrigues(rotation_matrix(v))[0].ravel(),
                               rtol=0, atol=1e-8)
    assert not cv2.Rodrigues(rotation_matrix([5e-6, 0, 0]))[0].any()
    assert rotation_vector(rotation_matrix([5e-6, 0, 0]))[0] == pytest.approx(5e-6, rel=1e-9)


def test_pose_from_vector_is_rvec_then_tvec() -> None:
    x = np.array([0.1, -0.3, 0.2, 0.05, -0.02, 1.5])
    np.testing.assert_array_equal(pose_from_vector(x), pose_from_rvec_tvec(x[:3], x[3:]))
    with pytest.raises(ValueError):
        pose_from_vector(x[:5])
