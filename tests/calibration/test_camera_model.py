"""The numpy projection used by the bundle adjustment against OpenCV's."""

import cv2
import numpy as np

from calibration.camera_model import project


def test_project_matches_cv2_project_points() -> None:
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), rng.uniform(0.8, 3.0, 200)])
    dist = np.array([-0.21, 0.08, 0.0012, -0.0007, 0.02])
    K = np.array([[812.0, 0, 640.3], [0, 809.5, 401.2], [0, 0, 1]])
    ours = project(pts, K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    # Same formula in float64: ~1000 px coordinates agree to an ulp (1e-13); 1e-9 px leaves room for op order.
    assert np.max(np.abs(ours - ref.reshape(-1, 2))) < 1e-9
