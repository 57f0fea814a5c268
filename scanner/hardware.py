"""Scanning with the real device stack (devices/): GRBL drives, the wall scanner, the 2-D laser and the robot
base over serial URLs (real ports, or the simulators `arproj devices serve` runs).

`DeviceBackend.measure_pass` runs one pass as a real scan does: home if needed, rapid to the pass start, arm
the scanner (its clock stamps sample 0 at the start of the measuring move), feed move at scan speed, wait until
the drives report Idle at the end, disarm, read the buffer back (missing samples fetched again), and turn
device times into drive positions with the same trapezoidal profile GRBL runs. Whatever goes wrong on the way
(garbage, truncated lines, timeouts, a device that disappears and comes back) is retried; a pass interrupted by
a device reset is measured again from its start, so no sample is lost or duplicated; after `max_pass_attempts`
the scan stops with a clear message (DeviceError) and can be resumed from its log.

`DeviceRobot` places the robot for each frame: a robot base drives there (devices/robotbase.py) and reports its
navigation stack's pose with the covariance, or the operator is told where to put the robot and confirms; then
the laser's two heads (horizontal, vertical) each take a turn and `scanner.laser.fix_from_scans` fixes the frame
against the side walls and the floor. Without a base the frame's pose is that fix, with its covariance.

`simulated_devices(world, robot, faults)` starts the four simulators on 127.0.0.1 (scanner.sim.devices.SiteServers)
and yields the backend and the robot connected to them through `socket://` URLs — the same code path as hardware,
the same samples and frames as the in-process site (scanner.run.DirectBackend with the SimRobot).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from devices.crclines import CrcLineFramer
from devices.errors import DeviceError, DeviceResetError, DisconnectedError
from devices.grbl import GrblDrives
from devices.laser2d import Laser2D
from devices.link import LineFramer, SerialLink
from devices.robotbase import RobotBase
from devices.sim import FaultConfig
from devices.wallscanner import WallScanner
from geometry.errors import InputError
from scanner.laser import HEADS, LaserConfig, Scan, fix_from_scans, pose_from_fix, room_from_scans
from scanner.plan import DriveConfig, FrameTarget, PassSpec, move_position, move_time
from scanner.sensor_model import SensorConfig
from scanner.sim.devices import SiteServers
from scanner.sim.world import FrameReport, SimRobot, SimWorld

T = TypeVar("T")

HINT = "check the cable and power of the device, then resume the scan from its log"


class DeviceBackend:
    """Measures passes with GRBL drives and a wall scanner (see the module docstring)."""

    def __init__(self, drives_url: str, scanner_url: str, drives: DriveConfig, sensor: SensorConfig,
                 timeout_s: float = 0.5, max_pass_attempts: int = 12, realtime: bool = True) -> None:
        self.drives_cfg = drives
        self.sensor_cfg = sensor
        self.max_pass_attempts = max_pass_attempts
        self.drive_link = SerialLink(drives_url, LineFramer(), "drives", timeout_s=timeout_s, hint=HINT)
        self.scanner_link = SerialLink(scanner_url, CrcLineFramer(), "scanner", timeout_s=timeout_s, hint=HINT)
        # Real drives take the motion's time to answer G4/$H; simulated ones answer at once (virtual clock).
        self.realtime = realtime
        self.grbl = GrblDrives(self.drive_link, homing_timeout_s=60.0 if realtime else timeout_s)
        self._uv = np.zeros(2)
        self.scanner = WallScanner(self.scanner_link)
        self.pass_restarts = 0

    def start(self) -> None:
        _open(self.drive_link, self.scanner_link)

    @property
    def faults_recovered(self) -> int:
        return self.grbl.faults_recovered + self.scanner.faults_recovered + self.pass_restarts

    def place_robot(self, report: FrameReport) -> None:
        self.grbl.homed = False  # home the drives at every frame (the robot moved)

    def measure_pass(self, pass_id: int, spec: PassSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d, s = self.drives_cfg, self.sensor_cfg
        duration_us = round(move_time(spec.length, d.scan_speed_m_s, d.accel_m_s2) * 1e6)
        period_us = round(1e6 / s.rate_hz)
        expected = duration_us // period_us + 1
        last_error = ""
        for _ in range(self.max_pass_attempts):
            try:
                if not self.grbl.homed:
                    self.grbl.home()
                    self._uv = np.zeros(2)
                rapid = move_time(float(np.linalg.norm(np.asarray(spec.start_uv) - self._uv)), d.rapid_speed_m_s,
                                  d.accel_m_s2)
                self.grbl.move_to(*spec.start_uv)
                self.grbl.wait_until_at(*spec.start_uv, expected_s=rapid if self.realtime else 0.0)
                self._uv = np.asarray(spec.start_uv, dtype=np.float64)
                t0 = self.scanner.arm(s.rate_hz, pass_id)
                self.grbl.move_to(*spec.end_uv, speed_m_s=d.scan_speed_m_s)
                self.grbl.wait_until_at(*spec.end_uv, expected_s=duration_us / 1e6 if self.realtime else 0.0)
                self._uv = np.asarray(spec.end_uv, dtype=np.float64)
                n = self.scanner.disarm()
                t_us, counts = self.scanner.fetch(n)
                rel = t_us - t0
                keep = (rel >= 0) & (rel <= duration_us)
                if int(keep.sum()) != expected or np.any(np.diff(rel[keep]) != period_us):
                    raise DeviceResetError(f"pass {pass_id}: {int(keep.sum())} samples in the move, "
                                           f"expected {expected}")
                t_rel = rel[keep] / 1e6
                start = np.asarray(spec.start_uv, dtype=np.float64)
                unit = (np.asarray(spec.end_uv) - start) / spec.length
                uv = start + move_position(t_rel, spec.length, d.scan_speed_m_s, d.accel_m_s2)[:, None] * unit
                return t_rel, uv, counts[keep]
            except DeviceResetError as reset:
                self.pass_restarts += 1
                last_error = str(reset)
        raise DeviceError(f"pass {pass_id} failed {self.max_pass_attempts} times (last: {last_error})",
                        "the devices keep resetting: check power and cables, then resume the scan from its log")

    def close(self) -> None:
        self.drive_link.close()
        self.scanner_link.close()


def _open(*links: SerialLink[Any, Any]) -> None:
    for link in links:
        try:
            link.open()
        except DisconnectedError:
            link.reconnect()


Operator = Callable[[FrameTarget], None]  # tells a person where to put the robot; returns once it stands there


class DeviceRobot:
    """The robot on hardware (see the module docstring): go_to(frame) -> FrameReport, as SimRobot's.

    base_url : the robot base (None: `operator` places the robot); laser_url : the 2-D laser with heads H and V
    (None: no fix; then a base is needed). A device reset during a step redoes the step, at most max_attempts
    times."""

    def __init__(self, laser_url: str | None, base_url: str | None, laser: LaserConfig | None = None,
                 operator: Operator | None = None, timeout_s: float = 0.5, max_attempts: int = 12) -> None:
        if base_url is None and (laser_url is None or operator is None):
            raise InputError("the robot's frames need a robot base (--base URL), or an operator and the 2-D laser "
                             "(--laser URL) to fix where the operator put it")
        self.laser_cfg = laser or LaserConfig()
        self.operator = operator
        self.max_attempts = max_attempts
        self.laser_link = None if laser_url is None else \
            SerialLink(laser_url, CrcLineFramer(), "laser", timeout_s=timeout_s, hint=HINT)
        self.base_link = None if base_url is None else \
            SerialLink(base_url, CrcLineFramer(), "robot base", timeout_s=timeout_s, hint=HINT)
        self.laser = None if self.laser_link is None else Laser2D(self.laser_link)
        self.base = None if self.base_link is None else RobotBase(self.base_link)

    def start(self) -> None:
        _open(*(link for link in (self.laser_link, self.base_link) if link is not None))
        if self.laser is not None:
            heads = self._retry(self.laser.heads)
            if not set(HEADS) <= set(heads):
                raise DeviceError(f"the laser at {self.laser.link.url} has heads {heads}: the scanning robot needs "
                                  f"{' and '.join(HEADS)} (horizontal and vertical)", HINT)

    @property
    def faults_recovered(self) -> int:
        return sum(device.faults_recovered for device in (self.laser, self.base) if device is not None)

    def _retry(self, step: Callable[[], T]) -> T:
        last = ""
        for _ in range(self.max_attempts):
            try:
                return step()
            except DeviceResetError as reset:
                last = str(reset)
        raise DeviceError(f"the robot's devices reset {self.max_attempts} times in one step (last: {last})",
                          "check power and cables, then resume the scan from its log")

    def go_to(self, frame: FrameTarget) -> FrameReport:
        commanded = (frame.x_m, frame.y_m, 0.0)
        true = None
        if self.base is not None:
            base = self.base
            self._retry(lambda: base.go_to(commanded, frame.frame_id))
            estimate, cov = self._retry(base.pose)
            true = self._retry(base.true_pose)
        else:
            assert self.operator is not None
            self.operator(frame)
        fix = room = None
        turns = None
        if self.laser is not None:
            laser = self.laser

            def turn(head: str) -> Callable[[], Scan]:
                return lambda: laser.scan(head, frame.frame_id)

            scans = [self._retry(turn(head)) for head in HEADS]
            try:
                fix = fix_from_scans(scans[0], scans[1], self.laser_cfg, seed=frame.frame_id)
            except InputError as err:
                if self.base is None:  # nothing else says where the robot stands
                    raise DeviceError(f"frame {frame.frame_id}: the laser cannot fix the robot ({err})",
                                      "clear the laser's view of the side walls and the floor, then resume") from None
            room = room_from_scans(scans[0], scans[1], seed=frame.frame_id)
            turns = dict(zip(HEADS, scans, strict=True))
        if self.base is None:
            assert fix is not None
            estimate, cov = pose_from_fix(fix)
        return FrameReport(commanded, estimate, cov, true, fix, room, turns)

    def close(self) -> None:
        for link in (self.laser_link, self.base_link):
            if link is not None:
                link.close()


@dataclass
class SimulatedDevices:
    backend: DeviceBackend
    robot: DeviceRobot
    servers: SiteServers

    @property
    def faults_recovered(self) -> int:
        return self.backend.faults_recovered + self.robot.faults_recovered


@contextmanager
def simulated_devices(world: SimWorld, robot: SimRobot, faults: FaultConfig | None = None, timeout_s: float = 0.5,
                      max_pass_attempts: int = 12) -> Iterator[SimulatedDevices]:
    """Start the four device simulators on `world` and `robot` and connect a DeviceBackend and a DeviceRobot to
    them (socket:// URLs on 127.0.0.1)."""
    servers = SiteServers(world, robot, faults)
    urls = servers.urls
    backend = DeviceBackend(urls["drives"], urls["scanner"], world.drives, world.sensor, timeout_s,
                            max_pass_attempts, realtime=False)
    device_robot = DeviceRobot(urls["laser"], urls["base"], robot.laser, timeout_s=timeout_s,
                               max_attempts=max_pass_attempts)
    try:
        backend.start()
        device_robot.start()
        yield SimulatedDevices(backend, device_robot, servers)
    finally:
        backend.close()
        device_robot.close()
        servers.close()
