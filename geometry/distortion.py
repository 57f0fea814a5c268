"""OpenCV's lens distortion model, in numpy: what cv2.projectPoints does to normalised image coordinates.

Coefficients in OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, τx, τy]]]]): 4, 5, 8, 12 or 14
of them; none or all zero is the pinhole. `Intrinsics.project` and `Intrinsics.rays` evaluate this model with
OpenCV itself (cv2.projectPoints, cv2.undistortPoints); `distort_normalized` is the same formula over arrays of
any shape, for the vectorised least-squares fits that need many projections or their derivatives.
tests/geometry/test_distortion.py checks it against cv2.projectPoints for every coefficient count.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

COEFFICIENT_COUNTS = (0, 4, 5, 8, 12, 14)


def full_coefficients(dist: ArrayLike) -> NDArray[np.float64]:
    """Any valid coefficient vector as all 14 (the missing ones zero)."""
    d = np.asarray(dist, dtype=np.float64).ravel()
    if len(d) not in COEFFICIENT_COUNTS:
        raise ValueError(f"OpenCV's distortion takes 4, 5, 8, 12 or 14 coefficients, got {len(d)}")
    out = np.zeros(14)
    out[:len(d)] = d
    return out


def _tilt(tau_x: float, tau_y: float) -> NDArray[np.float64]:
    """The 3x3 tilted-sensor map of OpenCV's computeTiltProjectionMatrix (Scheimpflug cameras)."""
    cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot = rot_y @ rot_x
    proj_z = np.array([[rot[2, 2], 0.0, -rot[0, 2]], [0.0, rot[2, 2], -rot[1, 2]], [0.0, 0.0, 1.0]])
    return proj_z @ rot


def distort_normalized(xy: ArrayLike, dist: ArrayLike) -> NDArray[np.float64]:
    """Distorted normalised coordinates (..., 2) of ideal ones (x/z, y/z) (..., 2); pixels are then
    (fx·x + cx, fy·y + cy)."""
    xy = np.asarray(xy, dtype=np.float64)
    c = full_coefficients(dist)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    if not c[5:].any():  # the plumb-bob model (k1, k2, p1, p2, k3) that the calibration fits, in Horner form
        k1, k2, p1, p2, k3 = c[:5]
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y = c
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + s3 * r2 + s4 * r4
    if tau_x == 0.0 and tau_y == 0.0:
        return np.stack([xd, yd], axis=-1)
    t = _tilt(tau_x, tau_y)
    w = t[2, 0] * xd + t[2, 1] * yd + t[2, 2]
    inv = np.where(w != 0.0, 1.0 / np.where(w != 0.0, w, 1.0), 1.0)
    return np.stack([(t[0, 0] * xd + t[0, 1] * yd + t[0, 2]) * inv, (t[1, 0] * xd + t[1, 1] * yd + t[1, 2]) * inv],
                    axis=-1)
