"""The rig file: which intrinsics files belong to the rig, the fixed poses between devices, the head model.

A rig folder holds `rig.yaml` plus one ROS camera_info YAML per device:

    version: 1
    intrinsics: {camera_left: camera_left.yaml, camera_right: camera_right.yaml, projector: projector.yaml}
    poses:                                   # 4x4 row-major, metres
      T_camera_right_from_camera_left: [[...], ...]   # OpenCV stereoCalibrate's R, T
      T_robot_from_camera_left: [[...], ...]
    head: {model: product_of_exponentials, ...}       # optional, see geometry.head
    quality: {reprojection_rms_px: 0.21, ...}          # free-form figures from calibration

With both cameras and T_camera_right_from_camera_left present, the two camera_info files carry the stereo
rectification as ROS camera_calibration writes it (cv2.stereoRectify, alpha 0): rectification_matrix R is the
rotation into the common rectified frame and projection_matrix P = [fx' 0 cx' Tx; 0 fy' cy' 0; 0 0 1 0] with
Tx = -fx' * baseline for the right camera (0 for the left), so ROS stereo_image_proc sees the baseline.
camera_matrix and distortion_coefficients stay the raw intrinsics and rig.yaml the raw extrinsics; reading
ignores R and P, so rig folders written before (R = I, P = [K|0]) read the same.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from geometry import provenance
from geometry.errors import InputError
from geometry.frames import parse_pose_name
from geometry.head import HeadModel
from geometry.inputs import fail, float_array, load_document, mapping
from geometry.intrinsics import Intrinsics, read_camera_info, write_camera_info
from geometry.plain import plain
from geometry.poses import invert

RIG_FILE = "rig.yaml"
MAX_TRANSLATION_M = 100.0  # poses within one rig and its robot: farther is no rig
STEREO_POSE = "T_camera_right_from_camera_left"
# ROS camera_calibration's default: the rectified images keep only valid pixels (no black borders).
RECTIFY_ALPHA = 0.0


def stereo_rectification(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray[np.float64]
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                    NDArray[np.float64]]:
    """(R_left, P_left, R_right, P_right) from cv2.stereoRectify as ROS camera_calibration calls it.

    R_* rotates a camera's rays into the common rectified frame; P_* (3x4) projects rectified rays, the
    right one with P[0, 3] = -fx' * baseline. Both cameras' images are taken at the left one's size (ROS
    requires equal sizes).
    """
    T = np.asarray(T_right_from_left, dtype=np.float64)
    R1, R2, P1, P2, *_ = cv2.stereoRectify(left.K, left.dist_array, right.K, right.dist_array,
                                           (left.width, left.height), T[:3, :3], T[:3, 3].reshape(3, 1),
                                           flags=cv2.CALIB_ZERO_DISPARITY, alpha=RECTIFY_ALPHA)
    return (np.asarray(R1, np.float64), np.asarray(P1, np.float64), np.asarray(R2, np.float64),
            np.asarray(P2, np.float64))


@dataclass
class Rig:
    intrinsics: dict[str, Intrinsics] = field(default_factory=dict)
    poses: dict[str, np.ndarray] = field(default_factory=dict)
    head: HeadModel | None = None
    quality: dict = field(default_factory=dict)

    def pose(self, name: str) -> np.ndarray:
        """T_dst_from_src by name; the inverse is found too (T_a_from_b from T_b_from_a)."""
        dst, src = parse_pose_name(name)
        if name in self.poses:
            return self.poses[name]
        inverse = f"T_{src}_from_{dst}"
        if inverse in self.poses:
            return invert(self.poses[inverse])
        raise InputError(f"rig has no pose {name} (nor {inverse})",
                         f"it has: {', '.join(sorted(self.poses)) or 'none'}")

    def _optional_pose(self, name: str) -> bool:
        try:
            self.pose(name)
        except InputError:
            return False
        return True

    def save(self, folder: str | Path) -> Path:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        files = {}
        rectified: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        if {"camera_left", "camera_right"} <= self.intrinsics.keys() and self._optional_pose(STEREO_POSE):
            R1, P1, R2, P2 = stereo_rectification(self.intrinsics["camera_left"], self.intrinsics["camera_right"],
                                                  self.pose(STEREO_POSE))
            rectified = {"camera_left": (R1, P1), "camera_right": (R2, P2)}
        for device, intr in self.intrinsics.items():
            files[device] = f"{device}.yaml"
            R, P = rectified.get(device, (None, None))
            write_camera_info(folder / files[device], intr, camera_name=device, R=R, P=P)
        for name in self.poses:
            parse_pose_name(name)
        doc = {
            "version": 1,
            "made_by": provenance.record(),
            "intrinsics": files,
            "poses": {k: np.asarray(v, dtype=float).tolist() for k, v in self.poses.items()},
            "quality": plain(self.quality),
        }
        if self.head is not None:
            doc["head"] = self.head.to_dict()
        (folder / RIG_FILE).write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
        return folder / RIG_FILE

    @classmethod
    def load(cls, folder: str | Path) -> Rig:
        folder = Path(folder)
        path = folder / RIG_FILE if folder.is_dir() else folder
        folder = path.parent
        source = str(path)
        hint = "run `arproj calibrate` to make one, or pass --sim"
        if not path.exists():
            raise InputError(f"{path}: no rig file here", hint)
        doc = load_document(path, "rig file", hint)
        if not isinstance(doc, dict) or doc.get("version") != 1 or isinstance(doc.get("version"), bool):
            raise InputError(f"{path}: not an arproj rig file (expected 'version: 1')", hint)
        quality = doc.get("quality") or {}
        rig = cls(quality=mapping(source, "quality", quality, "a mapping of figures", hint))
        files = mapping(source, "intrinsics", doc.get("intrinsics") or {}, "a mapping device: camera_info file",
                        hint)
        for device, name in files.items():
            where = f"intrinsics.{device}"
            if not isinstance(device, str) or not (isinstance(name, str) and name):
                raise fail(source, where, name, "must be the name of a camera_info file beside the rig file", hint)
            rig.intrinsics[device] = read_camera_info(folder / name)
        for name, value in mapping(source, "poses", doc.get("poses") or {}, "a mapping of named 4x4 poses",
                                   hint).items():
            if not isinstance(name, str):
                raise fail(source, "poses", name, "pose names are text, e.g. T_robot_from_camera_left", hint)
            parse_pose_name(name)
            T = float_array(source, f"poses.{name}", value, (4, 4), -MAX_TRANSLATION_M, MAX_TRANSLATION_M,
                            unit="metres", hint=hint)
            if not np.allclose(T[3], [0, 0, 0, 1]):
                raise InputError(f"{path}: pose {name} is not a 4x4 rigid transform", hint)
            R = T[:3, :3]
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise InputError(f"{path}: pose {name} has a rotation part that is not a rotation", hint)
            rig.poses[name] = T
        if doc.get("head") is not None:
            rig.head = HeadModel.from_dict(mapping(source, "head", doc["head"], "a head model mapping", hint),
                                           source=f"{path}: head")
        return rig
