"""Shared geometry conventions: named frames, 4x4 poses and rotations, intrinsics and lens distortion, rig files,
the pan/tilt head model; and the geometry several layers use, once: stereo triangulation (triangulation.py),
polylines (polyline.py), line and plane fits with RANSAC's shared loop (robust.py).

Every other package (scanner, mapping, calibration, arproj) builds on these; this package imports none of them.
The names below are loaded when first used (PEP 562): `from geometry.errors import InputError` must not pull in
scipy (poses) and OpenCV (intrinsics), or `arproj --help` pays seconds for them.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from geometry.errors import InputError
    from geometry.frames import FRAMES
    from geometry.intrinsics import Intrinsics, read_camera_info, write_camera_info
    from geometry.poses import (
        T_GL_FROM_CV,
        invert,
        look_at,
        make_pose,
        pose_from_rvec_tvec,
        rotation_about,
        rotation_angle_deg,
        rvec_tvec_from_pose,
        transform_points,
    )

_WHERE = {
    "InputError": "errors", "FRAMES": "frames", "Intrinsics": "intrinsics", "read_camera_info": "intrinsics",
    "write_camera_info": "intrinsics", "T_GL_FROM_CV": "poses", "invert": "poses", "look_at": "poses",
    "make_pose": "poses", "pose_from_rvec_tvec": "poses", "rotation_about": "poses",
    "rotation_angle_deg": "poses", "rvec_tvec_from_pose": "poses", "transform_points": "poses",
}


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'geometry' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"geometry.{_WHERE[name]}"), name)
    globals()[name] = value  # once: later look-ups are plain attributes
    return value


__all__ = [
    "FRAMES",
    "T_GL_FROM_CV",
    "InputError",
    "Intrinsics",
    "invert",
    "look_at",
    "make_pose",
    "pose_from_rvec_tvec",
    "read_camera_info",
    "rotation_about",
    "rotation_angle_deg",
    "rvec_tvec_from_pose",
    "transform_points",
    "write_camera_info",
]
