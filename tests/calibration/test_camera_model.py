"""The numpy projection used by the bundle adjustment against OpenCV's."""

import cv2
import numpy as np

from calibration.camera_model import project, rodrigues_batch


def test_rodrigues_batch_matches_opencv() -> None:
    rng = np.random.default_rng(0)
    rvecs = rng.normal(0, 1.0, (20, 3))
    rvecs[0] = 0.0
    R = rodrigues_batch(rvecs)
    for v, M in zip(rvecs, R, strict=True):
        assert np.allclose(M, cv2.Rodrigues(v)[0], atol=1e-12)  # entries of order 1: ~5000 float64 ulps of slack


def test_project_matches_cv2_project_points() -> None:
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), rng.uniform(0.8, 3.0, 200)])
    dist = np.array([-0.21, 0.08, 0.0012, -0.0007, 0.02])
    K = np.array([[812.0, 0, 640.3], [0, 809.5, 401.2], [0, 0, 1]])
    ours = project(pts, K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    # Same formula in float64: ~1000 px coordinates agree to an ulp (1e-13); 1e-9 px leaves room for op order.
    assert np.max(np.abs(ours - ref.reshape(-1, 2))) < 1e-9
