"""Shared geometry conventions: named frames, 4x4 poses and rotations, intrinsics and lens distortion, rig files,
the pan/tilt head model; and the geometry several layers use, once: stereo triangulation (triangulation.py),
polylines (polyline.py), line and plane fits with RANSAC's shared loop (robust.py).

Every other package (scanner, mapping, calibration, arproj) builds on these; this package imports none of them.
"""

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
