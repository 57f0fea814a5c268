"""A Kinect-like range camera: z-depth images of the room by exact ray casting, with the sensor's flaws.

Noise σ = sigma_at_1m_m · z² (structured-light depth error grows with the square of the distance) and depth
comes in steps of step_at_1m_m · z² (quantised disparity); pixels are
missing beyond [range_min_m, range_max_m], where the surface is seen more obliquely than grazing_limit_deg,
within edge_dropout_px of a depth discontinuity (the projected dots are occluded or smeared there), and at
random (dropout_fraction).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from arproj.sim.room import Surface, raycast
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics

EDGE_JUMP_RELATIVE = 0.03   # a neighbour this much (relative) nearer or farther marks a depth edge


def simulate_range_image(surfaces: list[Surface], intr: Intrinsics, T_room_from_rangecam: NDArray[np.float64],
                         config: dict, rng: np.random.Generator) -> NDArray[np.float32]:
    """(h, w) float32 depth along the optical axis in metres, NaN where the sensor returns nothing."""
    T = np.asarray(T_room_from_rangecam, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError("T_room_from_rangecam must be a finite 4x4 pose")
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    rays = intr.rays(np.column_stack([u.ravel(), v.ravel()]))     # z = 1, so ray parameter t is z-depth
    dirs = rays @ T[:3, :3].T
    hits = raycast(surfaces, T[:3, 3], dirs)
    z = hits.t.copy()
    normals = np.array([s.normal for s in surfaces] + [[0.0, 0.0, 1.0]])[hits.surface]
    cos_incidence = np.abs(np.sum(dirs * normals, axis=1)) / np.linalg.norm(dirs, axis=1)
    z[cos_incidence < np.cos(np.radians(config["grazing_limit_deg"]))] = np.nan
    z = z.reshape(intr.height, intr.width)
    z[~np.isfinite(z)] = np.nan

    # Depth edges: compare with the neighbourhood's extremes, then widen by edge_dropout_px.
    filled = np.where(np.isfinite(z), z, 0.0).astype(np.float32)
    kernel = np.ones((3, 3), np.uint8)
    near = cv2.erode(np.where(np.isfinite(z), z, np.inf).astype(np.float32), kernel)
    far = cv2.dilate(filled, kernel)
    with np.errstate(invalid="ignore"):
        edge = ((far - near) > EDGE_JUMP_RELATIVE * np.where(np.isfinite(z), z, 1.0)) | ~np.isfinite(z)
    edge_px = round(config["edge_dropout_px"])
    if edge_px > 0:
        edge = cv2.dilate(edge.astype(np.uint8), np.ones((2 * edge_px + 1, 2 * edge_px + 1), np.uint8)) > 0

    noisy = z + rng.standard_normal(z.shape) * config["sigma_at_1m_m"] * np.where(np.isfinite(z), z, 0.0) ** 2
    step = config["step_at_1m_m"]
    if step > 0:
        # Depth from disparity: disparity (∝ 1/z) comes in whole steps, so depth in steps of step · z².
        with np.errstate(divide="ignore", invalid="ignore"):
            noisy = 1.0 / (np.rint(1.0 / (noisy * step)) * step)
    missing = (edge | (rng.random(z.shape) < config["dropout_fraction"]) | ~np.isfinite(z)
               | (z < config["range_min_m"]) | (z > config["range_max_m"]))
    noisy[missing] = np.nan
    return noisy.astype(np.float32)
