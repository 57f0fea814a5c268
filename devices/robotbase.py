"""The scanning robot's mobile base: its line protocol (ours; the simulator in scanner/sim/devices.py speaks it)
over CRC lines with request ids (devices/crclines.py), and the host's driver (`RobotBase`).

The base drives to a frame pose in wall coordinates (the drive frame's origin x, y in metres along and up the
wall, its roll φ in the wall plane; y is reached by the lift) and reports where its navigation stack believes it
stands, with the covariance, as the paper's robot does.

    host -> device                           device -> host
    #1 ID?*CRC                                #1 OK ROBOTBASE <model> <firmware>*CRC
    #2 GOTO <x_m> <y_m> <phi_rad> <tag>*CRC   #2 OK*CRC              accepted: the base starts moving
    #3 STATE?*CRC                             #3 OK IDLE*CRC         (or MOVING; FAULT <text> when it stopped)
    #4 POSE?*CRC                              #4 OK <x> <y> <phi> <cxx> <cxy> <cxp> <cyy> <cyp> <cpp>*CRC
                                             the estimate (m, m, rad) and its covariance's upper triangle
                                             (m², m·rad, rad²)
    #5 TRUE?*CRC                              simulators only: #5 OK <x> <y> <phi>*CRC, the pose the base
                                             really has (a real base answers ERR 1; the host logs no truth)
    errors                                   #<id> ERR <code> <text>*CRC  1 unknown command, 2 bad checksum,
                                                                         4 bad argument, 5 unreachable pose
Numbers are sent as Python's round-trip float repr. GOTO with the same tag is idempotent (a resend after a lost
answer does not start another move); <tag> (the frame id) lets a simulator reproduce its stop.
"""

from __future__ import annotations

import time

import numpy as np

from devices.crclines import CrcLineFramer, Damaged, TaggedClient
from devices.errors import DeviceError, DeviceRefusedError
from devices.link import SerialLink

__all__ = ["CrcLineFramer", "RobotBase", "RobotBaseError", "covariance_fields", "covariance_from_fields"]

Pose = tuple[float, float, float]


class RobotBaseError(DeviceRefusedError):
    """The robot base refused a pose or stopped with a fault."""


def covariance_fields(cov: np.ndarray) -> list[str]:
    """The wire's six covariance fields (upper triangle, row by row) of a (3, 3) covariance."""
    c = np.asarray(cov, dtype=np.float64)
    return [repr(float(c[i, j])) for i in range(3) for j in range(i, 3)]


def covariance_from_fields(fields: list[str]) -> np.ndarray:
    """(3, 3) symmetric covariance from the six wire fields."""
    cov = np.zeros((3, 3))
    values = iter(float(v) for v in fields)
    for i in range(3):
        for j in range(i, 3):
            cov[i, j] = cov[j, i] = next(values)
    return cov


class RobotBase(TaggedClient):
    """Client of the robot base over a SerialLink framed by CrcLineFramer."""

    refused = RobotBaseError
    what = "robot base"

    def __init__(self, link: SerialLink[str | Damaged, str], retries: int = 8, move_timeout_s: float = 300.0,
                 poll_s: float = 0.2) -> None:
        super().__init__(link, retries)
        self.move_timeout_s = move_timeout_s
        self.poll_s = poll_s

    def identify(self) -> str:
        return " ".join(self.request("ID?")[0][1:])

    def go_to(self, pose: Pose, tag: int) -> None:
        """Drive to `pose` and return once the base is idle there (DeviceError after move_timeout_s)."""
        x, y, phi = (repr(float(v)) for v in pose)
        self.ok_fields(f"GOTO {x} {y} {phi} {int(tag)}", 0)
        deadline = time.monotonic() + self.move_timeout_s
        while True:
            state = self.request("STATE?")[0]
            if state[:2] == ["OK", "IDLE"]:
                return
            if state[:2] == ["OK", "FAULT"]:
                raise RobotBaseError(f"robot base ({self.link.url}) stopped: {' '.join(state[2:])}",
                                     "clear the base's way and resume the scan")
            if time.monotonic() > deadline:
                raise DeviceError(f"robot base ({self.link.url}) still moving after {self.move_timeout_s:g} s",
                                  "check the base, then resume the scan")
            time.sleep(self.poll_s)

    def pose(self) -> tuple[Pose, np.ndarray]:
        """The navigation stack's estimate (x m, y m, φ rad) and its (3, 3) covariance."""
        fields = self.ok_fields("POSE?", 9)
        try:
            x, y, phi = (float(v) for v in fields[:3])
            cov = covariance_from_fields(fields[3:])
        except ValueError:
            raise RobotBaseError(f"robot base ({self.link.url}): POSE? -> {' '.join(fields)}: not numbers") from None
        if not np.all(np.isfinite(cov)) or np.any(np.linalg.eigvalsh(cov) < -1e-15):
            raise RobotBaseError(f"robot base ({self.link.url}) reported a covariance that is not one: {fields[3:]}")
        return (x, y, phi), cov

    def true_pose(self) -> Pose | None:
        """Where a simulated base really stands; None for a real base (it does not know TRUE?)."""
        try:
            fields = self.ok_fields("TRUE?", 3)
        except RobotBaseError:
            return None
        x, y, phi = (float(v) for v in fields)
        return x, y, phi
