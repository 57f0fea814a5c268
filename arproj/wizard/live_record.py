"""A live calibration as ROS 2 messages (`arproj calibrate projector --live --record FILE.mcap`; mapping.ros.bag
writes them), fed by the station's capture tap (arproj.session.record.Captures, as the projection session's).

Topics (stamps: nanoseconds since the calibration started, on the wall clock's epoch):
  /projector/image/compressed, /camera_left/image/compressed, /camera_right/image/compressed
       sensor_msgs/msg/CompressedImage (PNG): every capture, the image shown and each camera's settled frame
  /projector/camera_info, /camera_left/camera_info, /camera_right/camera_info  sensor_msgs/msg/CameraInfo: the
       rig's intrinsics as the calibration left them, once at the end (a device it did not calibrate: none)
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from arproj.session.record import DEVICES, IMAGE, INFO, camera_info, png_image
from geometry.rig import Rig
from mapping.ros.bag import RosBag

CAMERAS = ("camera_left", "camera_right")


class CalibrationRecorder:
    """Writes every capture of a LiveStation into a RosBag (a Captures listener), the rig's intrinsics at the end."""

    def __init__(self, bag: RosBag) -> None:
        self.bag = bag
        self.t0_ns = time.time_ns()
        self._t0 = time.monotonic_ns()
        self.captures = 0

    def now(self) -> int:
        return self.t0_ns + time.monotonic_ns() - self._t0

    def captured(self, image: NDArray[np.uint8], frames: tuple[NDArray[np.uint8], ...]) -> None:
        t = self.now()
        self.bag.write("/projector/image/compressed", IMAGE, png_image(image, "projector", t), t)
        for name, frame in zip(CAMERAS, frames, strict=False):
            self.bag.write(f"/{name}/image/compressed", IMAGE, png_image(frame, name, t), t)
        self.captures += 1

    def finish(self, rig: Rig) -> None:
        t = self.now()
        for name in DEVICES:
            intr = rig.intrinsics.get(name)
            if intr is not None:
                self.bag.write(f"/{name}/camera_info", INFO, camera_info(intr, name, t), t)
