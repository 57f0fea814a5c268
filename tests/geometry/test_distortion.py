"""OpenCV's distortion model in numpy against cv2.projectPoints, and the undistorted pixels against the pinhole."""

import cv2
import numpy as np
import pytest

from geometry import Intrinsics
from geometry.distortion import distort_normalized, full_coefficients

K = np.array([[812.0, 0.0, 640.3], [0.0, 809.5, 401.2], [0.0, 0.0, 1.0]])
# A strong but monotonic lens of each of OpenCV's models: plumb bob, rational, thin prism, tilted sensor.
COEFFICIENTS = {
    0: (),
    4: (-0.21, 0.08, 0.0012, -0.0007),
    5: (-0.21, 0.08, 0.0012, -0.0007, 0.02),
    8: (0.9, 0.2, 0.0012, -0.0007, 0.01, 1.1, 0.35, 0.03),
    12: (-0.21, 0.08, 0.0012, -0.0007, 0.02, 0.01, 0.002, 0.0005, 0.003, -0.001, -0.002, 0.0008),
    14: (-0.21, 0.08, 0.0012, -0.0007, 0.02, 0.01, 0.002, 0.0005, 0.003, -0.001, -0.002, 0.0008, 0.02, -0.015),
}


@pytest.mark.parametrize("count", sorted(COEFFICIENTS))
def test_distort_normalized_is_cv2_project_points(count: int) -> None:
    rng = np.random.default_rng(count)
    pts = np.column_stack([rng.uniform(-0.5, 0.5, (300, 2)), rng.uniform(0.8, 3.0, 300)])
    dist = np.asarray(COEFFICIENTS[count], dtype=np.float64)
    xy = distort_normalized(pts[:, :2] / pts[:, 2:], dist)
    ours = np.column_stack([K[0, 0] * xy[:, 0] + K[0, 2], K[1, 1] * xy[:, 1] + K[1, 2]])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist if count else None)
    # the same formula in float64 (OpenCV adds its terms in another order): ~1000 px agree to ~1e-13 px
    assert np.max(np.abs(ours - ref.reshape(-1, 2))) < 1e-9


def test_distort_normalized_keeps_any_leading_shape() -> None:
    xy = np.random.default_rng(0).uniform(-0.4, 0.4, (4, 5, 2))
    dist = COEFFICIENTS[8]
    np.testing.assert_array_equal(distort_normalized(xy, dist).reshape(-1, 2), distort_normalized(xy.reshape(-1, 2),
                                                                                                 dist))
    with pytest.raises(ValueError, match="4, 5, 8, 12 or 14"):
        full_coefficients((0.1, 0.0, 0.0))


@pytest.mark.parametrize("count", [5, 8, 14])
def test_undistorted_pixels_are_the_pinhole_projection(count: int) -> None:
    intr = Intrinsics.from_K(K, 1280, 800, COEFFICIENTS[count])
    rng = np.random.default_rng(10 + count)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, (200, 2)), rng.uniform(1.0, 3.0, 200)])
    pinhole = pts[:, :2] / pts[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
    # undistortion iterates to 1e-12 in normalised units: ~1e-9 px at f = 800
    np.testing.assert_allclose(intr.undistorted_pixels(intr.project(pts)), pinhole, rtol=0, atol=1e-6)
    assert intr.without_distortion().undistorted_pixels(pinhole[:3]) == pytest.approx(pinhole[:3], abs=1e-9)
