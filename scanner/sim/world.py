"""The simulated scanning site: the true wall, where the robot really stands, and what the scanner measures.

Shared by the in-process backend and the serial-device simulators (GRBL drives, wall scanner), so a pass
gives the same samples whichever way it is run: sample k of a measuring move is taken k·period after the move
starts (integer µs period), at the drive position the trapezoidal profile gives, and its noise comes from a
generator seeded by (seed, pass tag).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from geometry.errors import InputError
from scanner.laser import HEADS, LaserConfig, Scan, draw_alignment, fix_from_scans, room_from_scans, simulated_head_scan
from scanner.plan import DriveConfig, FrameTarget, frame_pose_apply, move_position
from scanner.sensor_model import SensorConfig, SensorModel
from scanner.wall import Wall

Pose = tuple[float, float, float]


@dataclass
class FrameReport:
    """What the robot reports after moving to a frame, and (simulation only) where it really is."""

    commanded: Pose
    estimate: Pose
    cov: np.ndarray  # (3, 3): x, y (m²), phi (rad²)
    true: Pose | None
    laser: dict[str, float] | None = None  # the 2-D laser's fix (scanner.laser.LASER_KEYS), if any
    room: dict[str, float] | None = None  # the room's size as the same laser turns saw it (scanner.laser.ROOM_KEYS)
    scans: dict[str, Scan] | None = None  # the laser turns themselves, by head (what a recording replays)


@dataclass(frozen=True)
class RobotStop:
    """Where the simulated platform stopped for a frame: its true pose, its localization's estimate with the
    covariance, and how it really stands to the wall (standoff m, yaw rad: what the horizontal laser sees)."""

    true: Pose
    estimate: Pose
    cov: np.ndarray  # (3, 3): x, y (m²), phi (rad²)
    alignment: tuple[float, float]


class SimRobot:
    """The platform: stops near the commanded frame pose; its localization estimates where it stopped; with
    the room's wall width given, its two 2-D lasers also fix the frame against the side walls and the floor. A
    frame the lift raised to another band stops with an error of its own too (the lift's play and the
    re-alignment; nothing ties it to the band below, so stitching is not helped by an assumption).

    `stop` is what the robot base simulator (scanner/sim/devices.py) does on GOTO and `simulated_head_scan` what
    the laser simulator does on SCAN, so go_to() here gives the same report as the hardware code path
    (scanner.hardware.DeviceRobot) on those simulators."""

    def __init__(self, drives: DriveConfig, seed: int, wall_width_m: float | None = None,
                 laser: LaserConfig | None = None) -> None:
        self.drives = drives
        self.seed = seed
        self.wall_width_m = wall_width_m
        self.laser = laser or LaserConfig()

    def stop(self, frame_id: int, commanded: Pose) -> RobotStop:
        d = self.drives
        rng = np.random.default_rng([self.seed, frame_id, 101])
        err = rng.standard_normal(6)
        true = (commanded[0] + d.robot_sigma_m * err[0], commanded[1] + d.robot_sigma_m * err[1],
                commanded[2] + d.robot_sigma_rad * err[2])
        estimate = (true[0] + d.loc_sigma_m * err[3], true[1] + d.loc_sigma_m * err[4],
                    true[2] + d.loc_sigma_rad * err[5])
        cov = np.diag([d.loc_sigma_m**2, d.loc_sigma_m**2, d.loc_sigma_rad**2])
        alignment = draw_alignment(np.random.default_rng([self.seed, frame_id, 103]), self.laser)
        return RobotStop(true, estimate, cov, alignment)

    def go_to(self, frame: FrameTarget) -> FrameReport:
        commanded = (frame.x_m, frame.y_m, 0.0)  # y: the lift raises the drive frame to its band
        stop = self.stop(frame.frame_id, commanded)
        fix = room = None
        if self.wall_width_m is not None:
            scans = [simulated_head_scan(head, stop.true, stop.alignment, self.wall_width_m, self.laser, self.seed,
                                         frame.frame_id) for head in HEADS]
            try:
                fix = fix_from_scans(scans[0], scans[1], self.laser, seed=frame.frame_id)
            except InputError:
                fix = None  # no fix (walls not in view): the frame keeps its localization alone
            room = room_from_scans(scans[0], scans[1], seed=frame.frame_id)
            turns = dict(zip(HEADS, scans, strict=True))
            return FrameReport(commanded, stop.estimate, stop.cov, stop.true, fix, room, turns)
        return FrameReport(commanded, stop.estimate, stop.cov, stop.true, fix, room)


class SimWorld:
    """Truth of the simulated site, thread-safe (the device simulators run in server threads)."""

    def __init__(self, wall: Wall, sensor: SensorConfig, drives: DriveConfig, seed: int) -> None:
        self.wall = wall
        self.model = SensorModel(wall, sensor)
        self.sensor = sensor
        self.drives = drives
        self.seed = seed
        self.true_pose: Pose = (0.0, 0.0, 0.0)
        self.alignment: tuple[float, float] = (LaserConfig().standoff_m, 0.0)  # (standoff m, yaw rad) to the wall
        self.lock = threading.Lock()

        self.clock_us = 0  # virtual device clock (integer µs, so sample instants are exact)
        self.segments: list[MotionSegment] = []

    def place_robot(self, true_pose: Pose, alignment: tuple[float, float] | None = None) -> None:
        with self.lock:
            self.true_pose = true_pose
            if alignment is not None:
                self.alignment = alignment

    def record_motion(self, segment: MotionSegment) -> None:
        with self.lock:
            self.segments = [*self.segments[-7:], segment]  # older motion can no longer be sampled

    def sample_timeline(self, times_us: np.ndarray, tag: int) -> np.ndarray:
        """Device counts (n, 3) at device times along the recorded motion (the scanner simulator's view)."""
        with self.lock:
            segments, pose = list(self.segments), self.true_pose
        rest = segments[-1].end if segments else np.zeros(2)
        uv, unit = timeline_positions(segments, np.asarray(times_us, dtype=np.int64), self.drives.accel_m_s2,
                                      rest)
        return self._counts(pose, uv, unit, tag)

    def _counts(self, pose: Pose, uv: np.ndarray, unit: np.ndarray, tag: int) -> np.ndarray:
        xy = frame_pose_apply(pose, uv)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        motion = np.column_stack([c * unit[:, 0] - s * unit[:, 1], s * unit[:, 0] + c * unit[:, 1]])
        rng = np.random.default_rng([self.seed, int(tag), 7])
        return self.model.counts(xy, motion, uv, rng)

    def measure_move(self, start_uv: tuple[float, float], end_uv: tuple[float, float], speed: float,
                     accel: float, t_rel: np.ndarray, tag: int) -> np.ndarray:
        """Device counts (n, 3) at times t_rel (s after the move starts) of a straight move start→end."""
        with self.lock:
            pose = self.true_pose
        start = np.asarray(start_uv, dtype=np.float64)
        delta = np.asarray(end_uv, dtype=np.float64) - start
        length = float(np.linalg.norm(delta))
        unit = delta / length if length > 0 else np.zeros(2)
        uv = start + move_position(t_rel, length, speed, accel)[:, None] * unit
        return self._counts(pose, uv, np.tile(unit, (len(uv), 1)), tag)


@dataclass
class MotionSegment:
    """One executed move of the drives on the virtual clock (drive metres, µs)."""

    t0_us: int
    duration_us: int
    start: np.ndarray
    end: np.ndarray
    speed: float


def timeline_positions(segments: list[MotionSegment], times_us: np.ndarray, accel: float,
                       rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drive positions (n, 2) and unit motion directions (n, 2) at device times from recorded segments
    (later segments win at shared instants; outside all segments the drives rest at `rest`)."""
    uv = np.tile(rest, (len(times_us), 1)).astype(np.float64)
    motion = np.zeros((len(times_us), 2))
    for seg in segments:
        inside = (times_us >= seg.t0_us) & (times_us <= seg.t0_us + seg.duration_us)
        if not inside.any():
            continue
        delta = seg.end - seg.start
        length = float(np.linalg.norm(delta))
        if length == 0.0:
            uv[inside] = seg.start
            motion[inside] = 0.0
            continue
        unit = delta / length
        t_rel = (times_us[inside] - seg.t0_us) / 1e6
        uv[inside] = seg.start + move_position(t_rel, length, seg.speed, accel)[:, None] * unit
        motion[inside] = unit
    return uv, motion
