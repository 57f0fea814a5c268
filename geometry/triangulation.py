"""Stereo triangulation of matched pixels (OpenCV's linear DLT on undistorted rays) and its reprojection residual.

wallpose.triangulate keeps the other estimator, the least-squares midpoint of several rays: on noisy pixels the
two give different points (the DLT minimises an algebraic error, the midpoint the distance to the rays), so
each caller keeps the one its results were measured with.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.intrinsics import Intrinsics
from geometry.poses import transform_points


def triangulate(left: Intrinsics, right: Intrinsics, T_right_from_left: ArrayLike, left_pixels: ArrayLike,
                right_pixels: ArrayLike) -> NDArray[np.float64]:
    """Points (n, 3) in the left camera frame, metres, from distorted pixel pairs (n, 2) in both cameras
    (cv2.triangulatePoints on the undistorted normalised coordinates)."""
    uv_left = np.asarray(left_pixels, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(right_pixels, dtype=np.float64).reshape(-1, 2)
    if len(uv_left) == 0:
        return np.zeros((0, 3))
    xl = left.rays(uv_left)[:, :2]
    xr = right.rays(uv_right)[:, :2]
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.asarray(T_right_from_left, dtype=np.float64)[:3, :]
    X = cv2.triangulatePoints(P1, P2, xl.T, xr.T)
    return (X[:3] / X[3]).T


def reprojection_residuals(left: Intrinsics, right: Intrinsics, T_right_from_left: ArrayLike, points: ArrayLike,
                           left_pixels: ArrayLike, right_pixels: ArrayLike) -> NDArray[np.float64]:
    """Per point (n, 3) in the left frame: RMS over both cameras of the distance (px) between its projection
    and the measured pixel (n, 2); large when the rig does not describe these cameras."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(0)
    uv_left = np.asarray(left_pixels, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(right_pixels, dtype=np.float64).reshape(-1, 2)
    pl = left.project(p)
    pr = right.project(transform_points(T_right_from_left, p))
    return np.sqrt(0.5 * (np.sum((pl - uv_left) ** 2, axis=1) + np.sum((pr - uv_right) ** 2, axis=1)))
