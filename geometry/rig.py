"""The rig file: which intrinsics files belong to the rig, the fixed poses between devices, the head model.

A rig folder holds `rig.yaml` plus one ROS camera_info YAML per device:

    version: 1
    intrinsics: {camera_left: camera_left.yaml, camera_right: camera_right.yaml, projector: projector.yaml}
    poses:                                   # 4x4 row-major, metres
      T_camera_right_from_camera_left: [[...], ...]   # OpenCV stereoCalibrate's R, T
      T_robot_from_camera_left: [[...], ...]
    head: {model: product_of_exponentials, ...}       # optional, see geometry.head
    quality: {reprojection_rms_px: 0.21, ...}          # free-form figures from calibration
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from geometry.errors import InputError
from geometry.frames import parse_pose_name
from geometry.head import HeadModel
from geometry.intrinsics import Intrinsics, read_camera_info, write_camera_info
from geometry.plain import plain
from geometry.poses import invert

RIG_FILE = "rig.yaml"


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

    def save(self, folder: str | Path) -> Path:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        files = {}
        for device, intr in self.intrinsics.items():
            files[device] = f"{device}.yaml"
            write_camera_info(folder / files[device], intr, camera_name=device)
        for name in self.poses:
            parse_pose_name(name)
        doc = {
            "version": 1,
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
        if not path.exists():
            raise InputError(f"{path}: no rig file here", "run `arproj calibrate` to make one, or pass --sim")
        try:
            doc = yaml.safe_load(path.read_text())
        except yaml.YAMLError as err:
            raise InputError(f"{path}: not valid YAML ({str(err).splitlines()[0]})") from None
        if not isinstance(doc, dict) or doc.get("version") != 1:
            raise InputError(f"{path}: not an arproj rig file (expected 'version: 1')")
        rig = cls(quality=doc.get("quality") or {})
        for device, name in (doc.get("intrinsics") or {}).items():
            rig.intrinsics[device] = read_camera_info(folder / name)
        for name, value in (doc.get("poses") or {}).items():
            parse_pose_name(name)
            T = np.asarray(value, dtype=np.float64)
            if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]) or not np.all(np.isfinite(T)):
                raise InputError(f"{path}: pose {name} is not a 4x4 rigid transform")
            R = T[:3, :3]
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise InputError(f"{path}: pose {name} has a rotation part that is not a rotation")
            rig.poses[name] = T
        if doc.get("head") is not None:
            rig.head = HeadModel.from_dict(doc["head"], source=f"{path}: head")
        return rig
