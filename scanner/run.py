"""Running a scan: frames, passes, samples, recorded batch by batch in the scan log; resuming after a crash.

A backend measures one pass: `measure_pass(pass_id, spec) -> (t_rel (n,) s, uv (n, 2) m, counts (n, 3) int)`
plus `place_robot(report)` when the robot reached a frame. `DirectBackend` computes it in-process from the
simulated site; `scanner.hardware.DeviceBackend` drives the GRBL drives and the wall scanner over serial URLs
(real hardware or the simulators in scanner/sim). Both give identical samples in simulation.

Resume: the planners are deterministic functions of the samples they have seen, so a resumed scan replays
the plan, takes passes already in the log from the log (checking that they are the same passes) and measures
only the rest: the result has exactly the samples of an uninterrupted scan.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from geometry.errors import InputError
from scanner.channels import CHANNELS
from scanner.laser import LaserConfig
from scanner.log import ScanLog
from scanner.plan import (
    AdaptivePlanner,
    DriveConfig,
    FrameTarget,
    PassSpec,
    Samples,
    check_pass_in_reach,
    check_planner_version,
    frame_pose_apply,
    make_planner,
    move_position,
    move_time,
    reposition_time,
    sample_times,
)
from scanner.sensor_model import COUNTS_FULL_SCALE, SensorConfig
from scanner.sim.world import FrameReport, SimRobot, SimWorld
from scanner.wall import Wall, load_wall, wall_from_dict


class Backend(Protocol):
    def place_robot(self, report: FrameReport) -> None: ...
    def measure_pass(self, pass_id: int, spec: PassSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
    def close(self) -> None: ...


class ScanWatcher(Protocol):
    """Who sees the scan as it happens (a recording, a live view): every frame as the robot reports it, every
    pass with its samples, resumed ones included, in the order the scan makes them. A pass's row is its log
    row; where the adaptive plan searches the pass for crossings, it also holds `peaks`: {channel: [position
    along the pass's drive coordinate, m]} of each LINE_PEAKS channel (AdaptivePlanner.channel_peaks), the
    search the plan makes anyway, so that a watcher showing them need not search again."""

    def frame(self, row: dict[str, Any], report: FrameReport) -> None: ...
    def scanned(self, row: dict[str, Any], samples: Samples) -> None: ...


class DirectBackend:
    """The simulated site evaluated in-process (no serial transport): fast, for benchmarks."""

    def __init__(self, world: SimWorld) -> None:
        self.world = world

    def place_robot(self, report: FrameReport) -> None:
        assert report.true is not None
        self.world.place_robot(report.true)

    def measure_pass(self, pass_id: int, spec: PassSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = self.world.drives
        duration = move_time(spec.length, d.scan_speed_m_s, d.accel_m_s2)
        t_rel = sample_times(duration, self.world.sensor.rate_hz)
        counts = self.world.measure_move(spec.start_uv, spec.end_uv, d.scan_speed_m_s, d.accel_m_s2, t_rel,
                                         pass_id)
        start = np.asarray(spec.start_uv)
        unit = (np.asarray(spec.end_uv) - start) / spec.length
        uv = start + move_position(t_rel, spec.length, d.scan_speed_m_s, d.accel_m_s2)[:, None] * unit
        return t_rel, uv, counts

    def close(self) -> None:
        pass


class ScanCrashError(RuntimeError):
    """Raised by the crash hook in tests to simulate a power loss at a chosen point."""


@dataclass
class ScanResult:
    samples: dict[str, np.ndarray]  # all samples (as in the log), ordered by seq
    scan_time_s: float  # simulated duration of the whole scan
    n_passes: int
    n_frames: int
    frames: list[dict[str, Any]] = field(default_factory=list)
    measured_passes: int = 0  # passes measured in this run (the rest came from the log)
    plan_report: list[dict[str, Any]] = field(default_factory=list)  # the planner's traced objects, if it keeps them
    plan_priors: list[str] = field(default_factory=list)  # what ordered the adaptive plan's passes (scanner.priors)
    rooms: list[dict[str, float]] = field(default_factory=list)  # each frame's look at the room (scanner.laser
    #                                                               room_from_scans), resumed frames' looked again


ProgressFn = Callable[[float, float, int], None]  # (scan time so far s, estimated total s, passes done)


def scan_meta(wall: Wall, wall_path: str, plan: dict[str, Any], sensor: SensorConfig, drives: DriveConfig,
              seed: int | None, simulated: bool) -> dict[str, Any]:
    return {"wall_fingerprint": wall.fingerprint(), "wall_name": wall.name, "wall_path": wall_path,
            "wall_width_m": wall.width_m, "wall_height_m": wall.height_m,
            "wall_json": wall.to_dict() if simulated else None, "plan": plan, "sensor": sensor.to_dict(),
            "drives": drives.to_dict(), "seed": seed}


def check_setup(sensor: SensorConfig, drives: DriveConfig) -> None:
    if drives.scan_speed_m_s > sensor.max_speed_m_s + 1e-12:
        raise InputError(f"drives scan_speed_m_s = {drives.scan_speed_m_s:g} exceeds the scanner's speed limit "
                         f"max_speed_m_s = {sensor.max_speed_m_s:g}", "lower the scan speed")
    if drives.scan_speed_m_s <= 0 or drives.accel_m_s2 <= 0 or drives.rapid_speed_m_s <= 0:
        raise InputError("drives: scan_speed_m_s, rapid_speed_m_s and accel_m_s2 must be positive")


def run_scan(wall: Wall, backend: Backend, robot: Any, *, plan_kind: str = "dense",
             plan_options: dict[str, Any] | None = None, sensor: SensorConfig | None = None,
             drives: DriveConfig | None = None, log: ScanLog | None = None, progress: ProgressFn | None = None,
             crash_hook: Callable[[int], None] | None = None, watch: ScanWatcher | None = None) -> ScanResult:
    """Execute a plan; record every pass in `log` (if given; resuming from what it already holds).

    robot: has go_to(FrameTarget) -> FrameReport. crash_hook(pass_id) is called just before a pass would be
    committed (tests raise ScanCrashError there to simulate a crash mid-batch). watch sees every frame and pass.
    """
    sensor = sensor or SensorConfig()
    drives = drives or DriveConfig()
    check_setup(sensor, drives)
    planner = make_planner(plan_kind, wall, drives, sensor.hysteresis_m, plan_options)
    frames_done: dict[int, dict[str, Any]] = {}
    logged_passes: dict[int, dict[str, Any]] = {}
    if log is not None:
        f = log.frames()
        for i, fid in enumerate(f["frame_id"]):
            frames_done[int(fid)] = {k: v[i] for k, v in f.items()}
        p = log.passes()
        for i, pid in enumerate(p["pass_id"]):
            logged_passes[int(pid)] = {k: v[i] for k, v in p.items()}
    targets = planner.frames()
    estimate_total = _estimate_total(planner, targets, drives)
    t = 0.0
    pass_id = 0
    uv_now = np.zeros(2)
    all_samples: list[Samples] = []
    frame_rows: list[dict[str, Any]] = []
    rooms: list[dict[str, float]] = []
    measured = 0
    previous: FrameTarget | None = None
    for target in targets:
        t += reposition_time(previous, target, drives)
        previous = target
        if target.frame_id in frames_done:
            row = frames_done[target.frame_id]
            report = FrameReport((row["cmd_x_m"], row["cmd_y_m"], row["cmd_phi_rad"]),
                                 (row["est_x_m"], row["est_y_m"], row["est_phi_rad"]), np.asarray(row["cov"]),
                                 None if math.isnan(row["true_x_m"]) else
                                 (row["true_x_m"], row["true_y_m"], row["true_phi_rad"]))
            t = float(row["time_s"])
            fresh = robot.go_to(target)  # the robot still has to be there for the remaining passes
            report.true = fresh.true if report.true is None else report.true
            report.room = fresh.room
        else:
            report = robot.go_to(target)
            row = {"frame_id": target.frame_id, "time_s": t, "cmd_x_m": report.commanded[0],
                   "cmd_y_m": report.commanded[1], "cmd_phi_rad": report.commanded[2],
                   "est_x_m": report.estimate[0], "est_y_m": report.estimate[1], "est_phi_rad": report.estimate[2],
                   "cov": report.cov}
            if report.true is not None:
                row.update(true_x_m=report.true[0], true_y_m=report.true[1], true_phi_rad=report.true[2])
            if report.laser is not None:
                row.update(report.laser)
            if log is not None:
                log.append_frame(row)
        frame_rows.append(row)
        if watch is not None:
            watch.frame(row, report)
        if report.room is not None:
            rooms.append(report.room)
        backend.place_robot(report)
        uv_now = np.zeros(2)  # the drives home at every frame
        localise = getattr(planner, "localise", None)
        if localise is not None:  # the adaptive plan hands finds over at seams by where the frames really are
            localise(target, report.estimate)
        stages = planner.frame_stages(target)
        results: dict[int, Samples] | None = None
        while True:
            try:
                batch = stages.send(results) if results is not None else next(stages)
            except StopIteration:
                break
            results = {}
            for spec in batch:
                check_pass_in_reach(spec, drives)
                t += move_time(float(np.linalg.norm(np.asarray(spec.start_uv) - uv_now)), drives.rapid_speed_m_s,
                               drives.accel_m_s2)
                duration = move_time(spec.length, drives.scan_speed_m_s, drives.accel_m_s2)
                if pass_id in logged_passes:
                    _check_same_pass(log, logged_passes[pass_id], spec, pass_id)
                    samples = log.samples([pass_id])  # type: ignore[union-attr]
                    t = float(logged_passes[pass_id]["t_start_s"])
                else:
                    samples = _measure(backend, pass_id, spec, report, t, sensor)
                    if crash_hook is not None:
                        crash_hook(pass_id)
                    if log is not None:
                        log.append_pass(spec.row(pass_id, t, t + duration), samples)
                    measured += 1
                if watch is not None:
                    watched = spec.row(pass_id, t, t + duration)
                    peaks = planner.channel_peaks(spec, samples) if isinstance(planner, AdaptivePlanner) else None
                    if peaks is not None:
                        watched["peaks"] = peaks
                    watch.scanned(watched, samples)
                t += duration
                uv_now = np.asarray(spec.end_uv, dtype=np.float64)
                results[pass_id] = samples
                all_samples.append(samples)
                pass_id += 1
                if progress is not None:
                    progress(t, max(estimate_total, t), pass_id)
    if log is not None:
        extra = sorted(set(logged_passes) - set(range(pass_id)))
        if extra:
            raise InputError(f"{log.path}: holds passes {extra[:3]}… that this plan does not make",
                             "the log was written by a different plan or configuration; start a new log")
        log.set_meta("status", "complete")
        log.set_meta("scan_time_s", t)
    merged = {k: np.concatenate([s[k] for s in all_samples]) for k in all_samples[0]} if all_samples else {}
    if merged:
        merged["seq"] = np.arange(len(merged["time_s"]))
    priors = planner.priors_lines() if isinstance(planner, AdaptivePlanner) else []
    return ScanResult(merged, t, pass_id, len(targets), frame_rows, measured, list(getattr(planner, "report", [])),
                      priors, rooms)


def _measure(backend: Backend, pass_id: int, spec: PassSpec, report: FrameReport, t_start: float,
             sensor: SensorConfig) -> Samples:
    t_rel, uv, counts = backend.measure_pass(pass_id, spec)
    bad = (counts < 0) | (counts > COUNTS_FULL_SCALE)
    if bad.any():
        i, ch = np.argwhere(bad)[0]
        name = CHANNELS[ch].name
        raise InputError(f"scanner reported {name} = {int(counts[i, ch])} counts (sample {i} of pass {pass_id}), "
                         f"outside 0..{COUNTS_FULL_SCALE}", "check the scanner (sensor fault?) and resume")
    n = len(t_rel)
    axis = {"x": 0, "y": 1}.get(spec.axis, 2)  # 2: a following pass (both drives), see PassSpec
    samples: Samples = {
        "time_s": t_start + t_rel, "frame_id": np.full(n, spec.frame_id), "pass_id": np.full(n, pass_id),
        "drive_u_m": uv[:, 0], "drive_v_m": uv[:, 1],
    }
    cmd = frame_pose_apply(report.commanded, uv)
    est = frame_pose_apply(report.estimate, uv)
    samples.update(cmd_x_m=cmd[:, 0], cmd_y_m=cmd[:, 1], x_m=est[:, 0], y_m=est[:, 1])
    if report.true is not None:
        true = frame_pose_apply(report.true, uv)
        samples.update(true_x_m=true[:, 0], true_y_m=true[:, 1])
    else:
        samples.update(true_x_m=np.full(n, np.nan), true_y_m=np.full(n, np.nan))
    samples.update(axis=np.full(n, axis), direction=np.full(n, spec.direction))
    readings = counts.astype(np.float64) / COUNTS_FULL_SCALE
    samples.update(inductive=readings[:, 0], capacitive=readings[:, 1], ac=readings[:, 2])
    samples["seq"] = np.zeros(n, dtype=np.int64)
    return samples


def _check_same_pass(log: ScanLog | None, row: dict[str, Any], spec: PassSpec, pass_id: int) -> None:
    expected = (spec.frame_id, spec.axis, spec.start_uv[0], spec.start_uv[1], spec.end_uv[0], spec.end_uv[1])
    got = (int(row["frame_id"]), str(row["axis"]), float(row["start_u_m"]), float(row["start_v_m"]),
           float(row["end_u_m"]), float(row["end_v_m"]))
    if expected[:2] != got[:2] or not np.allclose(expected[2:], got[2:], atol=1e-9):
        raise InputError(f"{log.path if log else 'log'}: pass {pass_id} in the log {got} differs from the plan's "
                         f"{expected}", "the log was written by a different plan or configuration; start a new log")


def _estimate_total(planner: Any, targets: list[FrameTarget], drives: DriveConfig) -> float:
    """Scan time estimate for the progress bar: exact for dense, coarse stage × 1.25 for adaptive."""
    total = 0.0
    for previous, target in zip([None, *targets[:-1]], targets, strict=True):
        total += reposition_time(previous, target, drives)
        stages = planner.frame_stages(target)
        first = next(stages)
        uv = np.zeros(2)
        for spec in first:
            total += move_time(float(np.linalg.norm(np.asarray(spec.start_uv) - uv)), drives.rapid_speed_m_s,
                               drives.accel_m_s2)
            total += move_time(spec.length, drives.scan_speed_m_s, drives.accel_m_s2)
            uv = np.asarray(spec.end_uv)
        stages.close()
    return total * (1.25 if planner.describe()["kind"] == "adaptive" else 1.0)


def open_for_resume(log_path: str | Path, wall_path: str | Path | None = None) -> tuple[ScanLog, Wall]:
    """Open a log to continue it (as its one writer); the wall comes from --wall (checked against the log) or
    the log itself. Whatever refuses it closes the log again, so its writer lock is never left held."""
    log = ScanLog.open(log_path, writable=True)
    try:
        return log, _resumable_wall(log, log_path, wall_path)
    except BaseException:
        log.close()
        raise


def _resumable_wall(log: ScanLog, log_path: str | Path, wall_path: str | Path | None) -> Wall:
    plan = log.meta.get("plan") or {}
    if plan.get("kind") == "adaptive":
        check_planner_version(plan, str(log_path), logged=True)
    if wall_path is not None:
        wall = load_wall(wall_path)
        log.check_wall(wall.fingerprint(), str(wall_path))
    elif log.meta.get("wall_json"):
        wall = wall_from_dict(log.meta["wall_json"], f"{log_path} (wall_json)")
        log.check_wall(wall.fingerprint(), "the wall stored in the log")
    else:
        path = log.meta.get("wall_path")
        if not path or not Path(path).is_file():
            raise InputError(f"{log_path}: the log does not hold its wall and wall_path {path!r} is not readable",
                             "pass --wall FILE")
        wall = load_wall(path)
        log.check_wall(wall.fingerprint(), str(path))
    return wall


def simulated_site(wall: Wall, sensor: SensorConfig, drives: DriveConfig, seed: int) -> tuple[SimWorld, SimRobot]:
    return SimWorld(wall, sensor, drives, seed), SimRobot(drives, seed, wall.width_m,
                                                          LaserConfig().room_for_wall(wall.height_m))


def config_from_meta(meta: dict[str, Any]) -> tuple[SensorConfig, DriveConfig]:
    return SensorConfig.from_dict(meta["sensor"]), DriveConfig(**meta["drives"])

