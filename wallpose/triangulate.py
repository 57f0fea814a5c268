"""Triangulation of matched corners from two or three views (rays with origins, least squares)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def triangulate_rays(origins: NDArray[np.float64], directions: NDArray[np.float64],
                     valid: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """The points closest (least squares) to several rays each.

    origins: (v, 3) ray origins of the v views (metres, a common frame); directions: (n, v, 3) ray directions
    (any length); valid: (n, v) which views see each point (default all). Returns (n, 3); NaN where fewer than
    two views see a point or the rays are parallel.
    """
    d = directions / np.linalg.norm(directions, axis=2, keepdims=True)
    n, v, _ = d.shape
    w = np.ones((n, v)) if valid is None else valid.astype(np.float64)
    d = np.where(w[..., None] > 0, d, 0.0)
    # sum over views of (I - d d^T): the normal equations of the distance to each ray
    P = np.eye(3)[None, None] - d[..., :, None] * d[..., None, :]
    P = P * w[..., None, None]
    A = P.sum(axis=1)
    b = np.einsum("nvij,vj->ni", P, origins)
    out = np.full((n, 3), np.nan)
    ok = (w.sum(axis=1) >= 2) & (np.abs(np.linalg.det(A)) > 1e-12)
    out[ok] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    return out


def triangulate_stereo(normalized_left: NDArray[np.float64], normalized_right: NDArray[np.float64],
                       T_right_from_left: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points (n, 3) in the left camera frame from undistorted normalized coordinates (n, 2) in both cameras."""
    T_left_from_right = np.linalg.inv(T_right_from_left)
    origins = np.array([[0.0, 0.0, 0.0], T_left_from_right[:3, 3]])
    ray_l = np.column_stack([normalized_left, np.ones(len(normalized_left))])
    ray_r = np.column_stack([normalized_right, np.ones(len(normalized_right))]) @ T_left_from_right[:3, :3].T
    return triangulate_rays(origins, np.stack([ray_l, ray_r], axis=1))
