"""OpenCV intrinsics and poses as OpenGL matrices: the only place the two conventions meet.

Pixel centres are at integer coordinates (OpenCV); the image's top-left pixel covers [-0.5, 0.5]².
The principal point may be anywhere, so the frustum is off-centre (a projector's lens shift).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.intrinsics import Intrinsics
from geometry.poses import T_GL_FROM_CV, invert


def projection_matrix(intr: Intrinsics, near: float, far: float) -> NDArray[np.float64]:
    """4x4 OpenGL projection (GL camera frame → clip) reproducing the pinhole part of intr."""
    if not 0 < near < far:
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")
    W, H = intr.width, intr.height
    return np.array([
        [2.0 * intr.fx / W, 0.0, 1.0 - 2.0 * (intr.cx + 0.5) / W, 0.0],
        [0.0, 2.0 * intr.fy / H, 2.0 * (intr.cy + 0.5) / H - 1.0, 0.0],
        [0.0, 0.0, -(far + near) / (far - near), -2.0 * far * near / (far - near)],
        [0.0, 0.0, -1.0, 0.0],
    ])


def view_matrix(T_world_from_camera: ArrayLike) -> NDArray[np.float64]:
    """4x4 OpenGL view matrix (world → GL camera) for an OpenCV camera pose T_world_from_camera."""
    return T_GL_FROM_CV @ invert(T_world_from_camera)


def clip_from_world(intr: Intrinsics, T_world_from_camera: ArrayLike, near: float, far: float
                    ) -> NDArray[np.float32]:
    """projection @ view as float32, column-major bytes ready for a GLSL mat4 uniform via .T.tobytes()."""
    return (projection_matrix(intr, near, far) @ view_matrix(T_world_from_camera)).astype(np.float32)


def linear_depth(ndc_depth: NDArray[np.float32], near: float, far: float) -> NDArray[np.float32]:
    """Window depth in [0, 1] (GL's default depth range) → distance along the optical axis, metres.

    Pixels where nothing was drawn (depth == 1) become NaN.
    """
    z_ndc = ndc_depth.astype(np.float64) * 2.0 - 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        z = 2.0 * near * far / (far + near - z_ndc * (far - near))
    z[ndc_depth >= 1.0] = np.nan
    return z.astype(np.float32)
