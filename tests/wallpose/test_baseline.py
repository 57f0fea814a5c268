import numpy as np
import pytest

from geometry.poses import invert, transform_points
from wallpose.baseline import SquarePattern, estimate_plane_baseline, square_corners
from wallpose.evidence import NotEnoughEvidenceError


def test_square_corners_and_plane(case_2m_30) -> None:
    square = SquarePattern.like(case_2m_30.pattern, 0.6)
    img = square.image()
    left = case_2m_30.scene.photograph("camera_left", img)
    right = case_2m_30.scene.photograph("camera_right", img)
    # corners where the projector's square corners land
    T = case_2m_30.scene.T_robot_from_projector_true
    rays = case_2m_30.views.projector.rays(square.corners_px)
    n, d = case_2m_30.plane.in_frame(invert(T))
    X = transform_points(T, rays * (-d / (rays @ n))[:, None])
    truth = case_2m_30.views.camera_left.project(
        transform_points(invert(case_2m_30.views.T_robot_from_camera_left), X))
    assert np.abs(square_corners(left) - truth).max() < 1.0  # 1 px: the paper's outline corners claim no subpixel
    est = estimate_plane_baseline(left, right, case_2m_30.views)
    # four corners: right to about a degree, not to hundredths
    assert est.normal_error_deg(case_2m_30.plane.normal) < 2.0
    # 1 px corner errors opposed in the two images: 2 px disparity, 2·z²/(f·b) ≈ 0.04 m at z ≈ 2.1 m, f 1065 px
    assert np.abs(est.corners - X).max() < 0.05


def test_no_square_is_declined(case_2m_30) -> None:
    dark = np.full((800, 1280), 20, np.uint8)
    with pytest.raises(NotEnoughEvidenceError):
        estimate_plane_baseline(dark, dark, case_2m_30.views)
