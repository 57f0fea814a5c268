"""Scanning with the real device stack (devices/): GRBL drives and the wall scanner over serial URLs.

`DeviceBackend.measure_pass` runs one pass as a real scan does: home if needed, rapid to the pass start, arm
the scanner (its clock stamps sample 0 at the start of the measuring move), feed move at scan speed, wait until
the drives report Idle at the end, disarm, read the buffer back (missing samples fetched again), and turn
device times into drive positions with the same trapezoidal profile GRBL runs. Whatever goes wrong on the way
(garbage, truncated lines, timeouts, a device that disappears and comes back) is retried; a pass interrupted by
a device reset is measured again from its start, so no sample is lost or duplicated; after `max_pass_attempts`
the scan stops with a clear message (DeviceError) and can be resumed from its log.

`simulated_devices(world, faults)` starts the GRBL and wall-scanner simulators on 127.0.0.1 and yields a
backend connected to them through `socket://` URLs — the same code path as hardware.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

from devices.errors import DeviceError, DeviceResetError, DisconnectedError
from devices.grbl import GrblDrives
from devices.link import LineFramer, SerialLink
from devices.sim import DeviceServer, FaultConfig
from devices.wallscanner import CrcLineFramer, WallScanner
from scanner.plan import DriveConfig, PassSpec, move_position, move_time
from scanner.sensor_model import SensorConfig
from scanner.sim.devices import GRBL_STREAM, SCANNER_STREAM, GrblSim, WallScannerSim
from scanner.sim.world import FrameReport, SimWorld

HINT = "check the cable and power of the device, then resume the scan from its log"


class DeviceBackend:
    """Measures passes with GRBL drives and a wall scanner (see the module docstring)."""

    def __init__(self, drives_url: str, scanner_url: str, drives: DriveConfig, sensor: SensorConfig,
                 timeout_s: float = 0.5, max_pass_attempts: int = 12,
                 place_robot_hook: Callable[[FrameReport], None] | None = None, realtime: bool = True) -> None:
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
        self.place_robot_hook = place_robot_hook
        self.pass_restarts = 0

    def start(self) -> None:
        for link in (self.drive_link, self.scanner_link):
            try:
                link.open()
            except DisconnectedError:
                link.reconnect()

    @property
    def faults_recovered(self) -> int:
        return self.grbl.faults_recovered + self.scanner.faults_recovered + self.pass_restarts

    def place_robot(self, report: FrameReport) -> None:
        if self.place_robot_hook is not None:
            self.place_robot_hook(report)
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


@contextmanager
def simulated_devices(world: SimWorld, faults: FaultConfig | None = None, timeout_s: float = 0.5,
                      max_pass_attempts: int = 12) -> Iterator[tuple[DeviceBackend, DeviceServer, DeviceServer]]:
    """Start both device simulators and connect a DeviceBackend to them (socket:// URLs on 127.0.0.1)."""
    grbl_server = DeviceServer(GrblSim(world), faults, stream=GRBL_STREAM)
    scanner_server = DeviceServer(WallScannerSim(world), faults, stream=SCANNER_STREAM)
    grbl_server.start()
    scanner_server.start()
    assert world is not None

    def place(report: FrameReport) -> None:
        if report.true is not None:
            world.place_robot(report.true)

    backend = DeviceBackend(grbl_server.url, scanner_server.url, world.drives, world.sensor, timeout_s,
                            max_pass_attempts, place, realtime=False)
    try:
        backend.start()
        yield backend, grbl_server, scanner_server
    finally:
        backend.close()
        grbl_server.stop()
        scanner_server.stop()
