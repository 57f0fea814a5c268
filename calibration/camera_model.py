"""The calibration's camera models (which of OpenCV's k1 k2 p1 p2 k3 each lets free) and its projection.

The projection is geometry.distortion's numpy form of OpenCV's model: vectorised, it lets scipy's least_squares
refine many views at once without a Python loop per view; `tests/calibration/test_camera_model.py` checks it
against cv2.projectPoints.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.distortion import distort_normalized

# Which of OpenCV's five coefficients (k1, k2, p1, p2, k3) each model lets free; the others stay zero.
DISTORTION_MODELS: dict[str, tuple[int, ...]] = {
    "none": (),
    "k1": (0,),
    "k1k2": (0, 1),
    "k1k2k3": (0, 1, 4),
    "k1k2p1p2": (0, 1, 2, 3),
    "k1k2p1p2k3": (0, 1, 2, 3, 4),
}


def project(points_cam: NDArray[np.float64], fx: float, fy: float, cx: float, cy: float,
            dist5: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pixels (..., 2) of camera-frame points (..., 3), metres."""
    xy = points_cam[..., :2] / points_cam[..., 2:3]
    d = distort_normalized(xy, dist5)
    return np.stack([fx * d[..., 0] + cx, fy * d[..., 1] + cy], axis=-1)


def dist5_from(coeffs: NDArray[np.float64] | tuple[float, ...]) -> NDArray[np.float64]:
    """OpenCV coefficients of any length as the five (k1, k2, p1, p2, k3); longer models are not supported."""
    c = np.zeros(5)
    arr = np.asarray(coeffs, dtype=np.float64).ravel()
    n = min(len(arr), 5)
    c[:n] = arr[:n]
    return c


def solve_pnp(object_points: NDArray[np.float64], image_points: NDArray[np.float64], K: NDArray[np.float64],
              dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """(rvec, tvec) as one (6,) vector for T_camera_from_board; iterative PnP refined by LM."""
    obj = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(image_points, dtype=np.float64).reshape(-1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE if len(obj) >= 4
                                  else cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist)
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec)
    return np.concatenate([rvec.ravel(), tvec.ravel()])
