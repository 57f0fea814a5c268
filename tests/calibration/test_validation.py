"""Projected grids and the landing-point prediction."""

from __future__ import annotations

import numpy as np

from calibration.boards import detect
from calibration.validation import cast_onto_plane, compare, projected_charuco, projected_chessboard
from geometry.intrinsics import Intrinsics
from geometry.poses import look_at, make_pose, transform_points


def test_projected_chessboard_corners_are_where_the_detector_finds_them() -> None:
    grid = projected_chessboard(640, 400, 40)
    view = detect(grid.board, grid.image)
    assert view is not None
    # Noise-free, pixel-aligned render: the detector finds the corners exactly; 0.1 px still fails a half-pixel slip.
    assert np.max(np.abs(view.image_points - grid.corners_px)) < 0.1


def test_projected_charuco_corners_by_id() -> None:
    grid = projected_charuco(640, 400, 48)
    view = detect(grid.board, grid.image)
    assert view is not None and len(view.ids) > 30
    assert np.max(np.abs(view.image_points - grid.corners_px[view.ids])) < 0.1  # as above: exact render, id mapping


def test_cast_onto_plane_inverts_projection() -> None:
    proj = Intrinsics(1500.0, 1500.0, 639.5, 700.0, 1280, 800, (0.02, -0.01, 0.0, 0.0, 0.0))
    T_ref_from_proj = look_at([0.2, 0.1, 0.0], [0.0, 0.3, 2.0], up=[0, -1, 0])
    point, normal = np.array([0.0, 0.0, 2.0]), np.array([0.1, 0.0, -1.0]) / np.hypot(0.1, 1.0)
    pixels = np.array([[10.0, 20.0], [640.0, 400.0], [1200.0, 790.0]])
    X = cast_onto_plane(proj, T_ref_from_proj, pixels, point, normal)
    assert np.allclose((X - point) @ normal, 0.0, atol=1e-12)  # float64 round-off at 2 m is ~1e-16 m
    back = proj.project(transform_points(np.linalg.inv(T_ref_from_proj), X))
    assert np.allclose(back, pixels, atol=1e-6)  # undistortion iterates to 1e-12 px; a millionth of a pixel is ample


def test_compare_reports_millimetres() -> None:
    a = np.zeros((4, 3))
    b = a + np.array([0.001, 0.0, 0.0])
    r = compare(a, b)
    assert abs(r.rms_mm - 1.0) < 1e-12 and abs(r.max_mm - 1.0) < 1e-12  # exact: 0.001 m x 1000, float round-off only
    assert make_pose().shape == (4, 4)
