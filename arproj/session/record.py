"""A projection session as ROS 2 messages (`arproj project --record FILE.mcap`; mapping.ros.bag writes them).

Topics, once per cycle (stamps: nanoseconds since the session started, on the wall clock's epoch):
  /tf  tf2_msgs/msg/TFMessage  room -> robot (the registration's T_wall_from_robot: the map's wall frame is the
       session's room), robot -> head (the head's moving plate, geometry.head, at the pan/tilt the head reported
       when the registration was made) -> projector (the rest of the registered projector pose: room -> projector
       along the tree is the registration's), robot -> camera_left (the rig's T_robot_from_camera_left) ->
       camera_right: REP 105's one-parent tree. A rig without a head model: robot -> projector. No registration:
       no /tf.
  /projector/camera_info, /camera_left/camera_info, /camera_right/camera_info  sensor_msgs/msg/CameraInfo
  /projector/image/compressed, /camera_left/image/compressed, /camera_right/image/compressed
       sensor_msgs/msg/CompressedImage (PNG): the frame shown, the cameras' last captures
  /gate  std_msgs/msg/String  "MAP SHOWN" or "WARNING: reasons"
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert
from geometry.rig import Rig
from mapping.ros.bag import RosBag, header, tf_message

TF = "tf2_msgs/msg/TFMessage"
INFO = "sensor_msgs/msg/CameraInfo"
IMAGE = "sensor_msgs/msg/CompressedImage"
STRING = "std_msgs/msg/String"
DEVICES = ("projector", "camera_left", "camera_right")


def camera_info(intr: Intrinsics, frame_id: str, t_ns: int) -> dict[str, Any]:
    d = [float(v) for v in intr.dist]
    K = intr.K
    return {"header": header(t_ns, frame_id), "height": intr.height, "width": intr.width,
            "distortion_model": "plumb_bob" if len(d) <= 5 else "rational_polynomial", "d": d,
            "k": K.ravel().tolist(), "r": np.eye(3).ravel().tolist(),
            "p": np.hstack([K, np.zeros((3, 1))]).ravel().tolist(), "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def png_image(image: NDArray[np.uint8], frame_id: str, t_ns: int) -> dict[str, Any]:
    """CompressedImage of an RGB (or grey) image as PNG (cv2 writes BGR: the channels are swapped first)."""
    img = image[..., ::-1] if image.ndim == 3 else image
    ok, data = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:
        raise InputError(f"--record: could not encode the {frame_id} image as PNG")
    return {"header": header(t_ns, frame_id), "format": "png", "data": data.ravel().tobytes()}


class Captures:
    """The cameras' last captures and the image shown for them, and whoever wants every capture as it comes
    (`listeners`, called with the image shown and the frames): `watch` wraps the capture(image) -> frames of a
    device, the session's robot (two cameras) or the calibration's station (one or two)."""

    def __init__(self) -> None:
        self.last: tuple[NDArray[np.uint8], ...] | None = None
        self.shown: NDArray[np.uint8] | None = None
        self.listeners: list[Callable[[NDArray[np.uint8], tuple[NDArray[np.uint8], ...]], None]] = []

    def watch(self, device: Any) -> None:
        capture = device.capture

        def recorded(image: NDArray[np.uint8]) -> Any:
            frames = capture(image)
            self.last, self.shown = tuple(frames), image
            for listen in self.listeners:
                listen(image, self.last)
            return frames

        device.capture = recorded


class SessionRecorder:
    """Writes each cycle of a ProjectionSession into a RosBag, with the cameras' last captures (`captures`)."""

    def __init__(self, bag: RosBag, rig: Rig, captures: Captures) -> None:
        self.bag, self.rig, self.captures = bag, rig, captures
        self.t0_ns = time.time_ns()
        self._t0 = time.monotonic_ns()
        try:
            self.T_robot_from_left: NDArray[np.float64] | None = rig.pose("T_robot_from_camera_left")
            self.T_right_from_left: NDArray[np.float64] | None = rig.pose("T_camera_right_from_camera_left")
        except InputError:
            self.T_robot_from_left = self.T_right_from_left = None

    def cycle(self, session: Any, decision: Any) -> None:
        t = self.t0_ns + time.monotonic_ns() - self._t0
        reg = session.registration
        if reg is not None:
            T_robot_from_projector = invert(reg.T_wall_from_robot) @ reg.T_wall_from_projector
            tfs = [(reg.T_wall_from_robot, "room", "robot", t)]
            if self.rig.head is not None:
                T_robot_from_head = self.rig.head.T_robot_from_head([*reg.head_deg, 0.0])
                tfs += [(T_robot_from_head, "robot", "head", t),
                        (invert(T_robot_from_head) @ T_robot_from_projector, "head", "projector", t)]
            else:
                tfs += [(T_robot_from_projector, "robot", "projector", t)]
            if self.T_robot_from_left is not None and self.T_right_from_left is not None:
                tfs += [(self.T_robot_from_left, "robot", "camera_left", t),
                        (invert(self.T_right_from_left), "camera_left", "camera_right", t)]
            self.bag.write_cdr("/tf", TF, tf_message(tfs), t)
        for name in DEVICES:
            intr = self.rig.intrinsics.get(name)
            if intr is not None:
                self.bag.write(f"/{name}/camera_info", INFO, camera_info(intr, name, t), t)
        frame = getattr(session, "last_frame", None)
        if frame is not None:
            self.bag.write("/projector/image/compressed", IMAGE, png_image(frame, "projector", t), t)
        if self.captures.last is not None:
            for name, image in zip(("camera_left", "camera_right"), self.captures.last, strict=True):
                self.bag.write(f"/{name}/image/compressed", IMAGE, png_image(image, name, t), t)
        self.bag.write("/gate", STRING, {"data": gate_state(decision)}, t)


def gate_state(decision: Any) -> str:
    return "MAP SHOWN" if decision.show_map else "WARNING: " + "; ".join(decision.reasons)
