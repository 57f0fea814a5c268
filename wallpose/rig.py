"""The views the wall-pose estimator uses: two cameras and the projector, with their poses on the robot.

Calibrated values (a geometry.Rig plus the head's current angles) or a simulated site's ground truth
(arproj.sim.wallpose_trial) plug in the same way, so the estimator never knows where its numbers came from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert
from geometry.rig import Rig


@dataclass(frozen=True)
class ViewRig:
    """Intrinsics of the three views and the fixed poses between them (4x4, metres).

    T_robot_from_projector is the projector's pose at the head's current (commanded) angles; the estimator
    treats it as known up to the head's repeatability and measures the remainder.
    """

    camera_left: Intrinsics
    camera_right: Intrinsics
    projector: Intrinsics
    T_robot_from_camera_left: NDArray[np.float64]
    T_camera_right_from_camera_left: NDArray[np.float64]
    T_robot_from_projector: NDArray[np.float64]

    @property
    def T_camera_left_from_projector(self) -> NDArray[np.float64]:
        return invert(self.T_robot_from_camera_left) @ self.T_robot_from_projector

    @property
    def T_robot_from_camera_right(self) -> NDArray[np.float64]:
        return self.T_robot_from_camera_left @ invert(self.T_camera_right_from_camera_left)

    def camera(self, name: str) -> Intrinsics:
        if name == "camera_left":
            return self.camera_left
        if name == "camera_right":
            return self.camera_right
        raise InputError(f"unknown camera {name!r}", "use camera_left or camera_right")

    @classmethod
    def from_rig(cls, rig: Rig, head_angles_deg: ArrayLike) -> ViewRig:
        """From a calibrated rig folder (geometry.Rig) and the head's current (pan, tilt, roll) in degrees."""
        for device in ("camera_left", "camera_right", "projector"):
            if device not in rig.intrinsics:
                raise InputError(f"rig has no intrinsics for {device}",
                                 "calibrate the stereo cameras and the projector first (`arproj calibrate`)")
        if rig.head is None:
            raise InputError("rig has no head model, so the projector's pose is unknown",
                             "calibrate the pan/tilt head first (`arproj calibrate`)")
        return cls(camera_left=rig.intrinsics["camera_left"], camera_right=rig.intrinsics["camera_right"],
                   projector=rig.intrinsics["projector"],
                   T_robot_from_camera_left=rig.pose("T_robot_from_camera_left"),
                   T_camera_right_from_camera_left=rig.pose("T_camera_right_from_camera_left"),
                   T_robot_from_projector=rig.head.T_robot_from_projector(head_angles_deg))
