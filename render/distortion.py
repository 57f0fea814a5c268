"""Lens distortion as a lookup map: for each pixel of the distorted image, where to sample a pinhole render.

A camera pixel (u, v) sees along the ray undistort(u, v); a projector pixel (u, v) emits along that same ray.
So in both cases: distorted[v, u] = pinhole[K' · undistort(u, v)], with K' the intrinsics of a pinhole render
enlarged just enough to contain every ray the distorted image needs (barrel distortion looks outside).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.intrinsics import Intrinsics

_MARGIN_PX = 2  # a little beyond the outermost ray, so bilinear lookups near the border stay inside


@dataclass(frozen=True)
class DistortionMap:
    """pinhole: intrinsics of the enlarged undistorted render; map_xy: (h, w, 2) float32 pixel positions in it."""

    pinhole: Intrinsics
    map_xy: NDArray[np.float32]


def _pixel_grid(intr: Intrinsics) -> NDArray[np.float64]:
    """Every pixel (u, v) of the image, (h·w, 2), row by row."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    return np.column_stack([u.ravel(), v.ravel()])


def undistorted_directions(intr: Intrinsics) -> NDArray[np.float64]:
    """Normalised image coordinates (h, w, 2) of the ray through every pixel of the distorted image."""
    return intr.rays(_pixel_grid(intr))[:, :2].reshape(intr.height, intr.width, 2)


@lru_cache(maxsize=16)
def distortion_map(intr: Intrinsics) -> DistortionMap:
    """The lookup map for intr (cached: intrinsics are frozen and hashable)."""
    uv = intr.undistorted_pixels(_pixel_grid(intr)).reshape(intr.height, intr.width, 2)
    u, v = uv[..., 0], uv[..., 1]
    u0 = min(0.0, float(np.floor(u.min())) - _MARGIN_PX)
    v0 = min(0.0, float(np.floor(v.min())) - _MARGIN_PX)
    u1 = max(intr.width - 1.0, float(np.ceil(u.max())) + _MARGIN_PX)
    v1 = max(intr.height - 1.0, float(np.ceil(v.max())) + _MARGIN_PX)
    pinhole = replace(intr, cx=intr.cx - u0, cy=intr.cy - v0, width=int(u1 - u0) + 1,
                      height=int(v1 - v0) + 1, dist=())
    map_xy = np.stack([u - u0, v - v0], axis=-1).astype(np.float32)
    return DistortionMap(pinhole, map_xy)


def apply_distortion_cpu(pinhole_image: NDArray, dmap: DistortionMap) -> NDArray:
    """The distortion pass on the CPU (cv2.remap), for images that are not on the GPU."""
    return cv2.remap(pinhole_image, dmap.map_xy[..., 0], dmap.map_xy[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
