"""Test patterns for the projector and the measurements that check the simulation against analytic truth.

dot_pattern: Gaussian dots at sub-pixel projector positions; expected_camera_pixels: where a projector
pixel's light must appear in a camera, by ray casting and cv2.projectPoints (the analytic path);
dot_centroids: intensity centroids of dots in a photo, background subtracted.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.intrinsics import Intrinsics
from geometry.poses import invert, transform_points

if TYPE_CHECKING:
    from arproj.sim.site import Site

DOT_WINDOW_SIGMAS = 4.0   # a dot's centroid window reaches this many σ (camera pixels) from the centre


def dot_grid(intr: Intrinsics, cols: int = 7, rows: int = 5, margin: float = 0.12,
             jitter_px: float = 0.37) -> NDArray[np.float64]:
    """(rows·cols, 2) projector pixel positions on a grid, offset by a sub-pixel amount."""
    u = np.linspace(margin, 1.0 - margin, cols) * (intr.width - 1) + jitter_px
    v = np.linspace(margin, 1.0 - margin, rows) * (intr.height - 1) + jitter_px * 0.7
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def dot_pattern(intr: Intrinsics, positions: ArrayLike, sigma_px: float = 3.0, peak: int = 255
                ) -> NDArray[np.uint8]:
    """(h, w) uint8 image of Gaussian dots (σ in projector pixels) centred at positions (n, 2)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    image = np.zeros((intr.height, intr.width), dtype=np.float64)
    r = int(np.ceil(4 * sigma_px))
    for u, v in positions:
        u0, v0 = round(u), round(v)
        ys, xs = np.mgrid[max(v0 - r, 0):min(v0 + r + 1, intr.height), max(u0 - r, 0):min(u0 + r + 1, intr.width)]
        blob = np.exp(-((xs - u) ** 2 + (ys - v) ** 2) / (2 * sigma_px**2))
        image[ys, xs] = np.maximum(image[ys, xs], blob)
    return np.clip(np.rint(image * peak), 0, 255).astype(np.uint8)


def expected_camera_pixels(site: Site, camera: str, projector_pixels: ArrayLike) -> NDArray[np.float64]:
    """(n, 2) camera pixels where the light of projector pixels (n, 2) appears: the projector ray is cast onto
    the room exactly, and the landing point projected through the camera with cv2.projectPoints."""
    landing = site.raycast("projector", projector_pixels)
    T_camera_from_room = invert(site.T_room_from(camera))
    return site.intrinsics(camera).project(transform_points(T_camera_from_room, landing.points_room))


def dot_centroids(image: NDArray, background: NDArray, predicted: ArrayLike, radius_px: float
                  ) -> NDArray[np.float64]:
    """(n, 2) intensity centroids of (image − background) in windows of radius_px around predicted (n, 2).

    NaN where the window leaves the image or holds no signal.
    """
    diff = image.astype(np.float64) - background.astype(np.float64)
    if diff.ndim == 3:
        diff = diff.mean(axis=2)
    h, w = diff.shape
    out = np.full((len(np.atleast_2d(predicted)), 2), np.nan)
    r = int(np.ceil(radius_px))
    for i, (u, v) in enumerate(np.asarray(predicted, dtype=np.float64).reshape(-1, 2)):
        u0, v0 = round(u), round(v)
        if not (r <= u0 < w - r and r <= v0 < h - r):
            continue
        ys, xs = np.mgrid[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1]
        weight = np.clip(diff[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1], 0.0, None)
        inside = (xs - u) ** 2 + (ys - v) ** 2 <= radius_px**2
        weight = weight * inside
        total = weight.sum()
        if total > 0:
            out[i] = [(weight * xs).sum() / total, (weight * ys).sum() / total]
    return out
