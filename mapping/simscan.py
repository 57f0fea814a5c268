"""Simulated raster scans of a wall file, straight into mapping's ScanData (and optionally a scan log).

For tests and benchmarks of the mapping: frames side by side as scanner.plan lays them out, serpentine
passes along u at `line_spacing_m`, readings from scanner.sensor_model (hysteresis, noise, quantisation to
device counts), frame poses with a robot placement error (truth) and a localization estimate with its own
error and covariance, and (laser=True) the robot's 2-D lasers' fix of each frame's x, y, φ against side walls and floor
(scanner.laser: simulated room scan, range noise and outliers, line fits). The samples are what scanner.log
would hold; `write_log` stores them in that format.
The scanning subsystem's own executor (`arproj scan --sim`) is the full-fidelity path; this one skips the
devices and the time model so a benchmark can scan 20 walls quickly.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mapping.scandata import ScanData
from scanner.channels import CHANNELS
from scanner.laser import LASER_KEYS, simulate_fix
from scanner.log import FORMAT, SAMPLE_COLUMNS, ScanLog
from scanner.sensor_model import COUNTS_FULL_SCALE, SensorConfig
from scanner.sensor_model import SensorModel as ForwardModel
from scanner.wall import Wall


def simulate_scan(wall: Wall, seed: int = 0, line_spacing_m: float = 0.01, sample_step_m: float = 0.001,
                  frame_width_m: float = 0.35, overlap_m: float = 0.005, robot_sigma: tuple = (0.01, 0.01, 0.002),
                  loc_sigma: tuple = (0.002, 0.002, 0.0003), vertical_spacing_m: float | None = None,
                  sensor: SensorConfig | None = None, laser: bool = True) -> ScanData:
    """A dense raster scan of `wall`. sigmas: (x m, y m, phi rad). vertical_spacing_m adds vertical passes.
    laser: log each frame's 2-D laser fix (else the laser columns are NaN, as in a version 1 log)."""
    rng = np.random.default_rng(seed)
    cfg = sensor or SensorConfig()
    model = ForwardModel(wall, cfg)
    n_frames = max(1, math.ceil(wall.width_m / frame_width_m - 1e-9))
    frames: dict[str, list] = {k: [] for k in ("frame_id", "time_s", "cmd_x_m", "cmd_y_m", "cmd_phi_rad",
                                               "est_x_m", "est_y_m", "est_phi_rad", "true_x_m", "true_y_m",
                                               "true_phi_rad", "cov", *LASER_KEYS)}
    cols: dict[str, list[np.ndarray]] = {c: [] for c in SAMPLE_COLUMNS if c != "seq"}
    pass_id = 0
    t = 0.0
    for f in range(n_frames):
        x0 = f * frame_width_m
        cmd = np.array([x0, 0.0, 0.0])
        true = cmd + rng.normal(size=3) * np.asarray(robot_sigma)
        est = true + rng.normal(size=3) * np.asarray(loc_sigma)
        for key, arr in (("cmd", cmd), ("est", est), ("true", true)):
            frames[f"{key}_x_m"].append(arr[0])
            frames[f"{key}_y_m"].append(arr[1])
            frames[f"{key}_phi_rad"].append(arr[2])
        frames["frame_id"].append(f)
        frames["time_s"].append(t)
        frames["cov"].append(np.diag(np.asarray(loc_sigma, dtype=np.float64) ** 2))
        fix = simulate_fix(tuple(true), wall.width_m, np.random.default_rng([seed, f, 103]))[0] if laser \
            else dict.fromkeys(LASER_KEYS, np.nan)  # own stream: the scan's other draws stay as they were
        for key in LASER_KEYS:
            frames[key].append(fix[key])
        u_hi = min(frame_width_m + overlap_m, wall.width_m - x0)
        passes = []
        n_rows = math.floor(wall.height_m / line_spacing_m + 1e-9) + 1
        for k in range(n_rows):
            v = min(k * line_spacing_m, wall.height_m)
            passes.append((0, 1 if k % 2 == 0 else -1, v, 0.0, u_hi))
        if vertical_spacing_m:
            for k in range(math.floor(u_hi / vertical_spacing_m + 1e-9) + 1):
                passes.append((1, 1 if k % 2 == 0 else -1, k * vertical_spacing_m, 0.0, wall.height_m))
        c, s = math.cos(true[2]), math.sin(true[2])
        ce, se = math.cos(est[2]), math.sin(est[2])
        for axis, direction, fixed, lo, hi in passes:
            along = np.arange(lo, hi + 1e-9, sample_step_m)
            if direction < 0:
                along = along[::-1]
            uv = np.column_stack([along, np.full_like(along, fixed)]) if axis == 0 else \
                np.column_stack([np.full_like(along, fixed), along])
            xy_true = np.column_stack([true[0] + c * uv[:, 0] - s * uv[:, 1], true[1] + s * uv[:, 0] + c * uv[:, 1]])
            xy_est = np.column_stack([est[0] + ce * uv[:, 0] - se * uv[:, 1], est[1] + se * uv[:, 0] + ce * uv[:, 1]])
            motion_uv = np.array([direction, 0.0]) if axis == 0 else np.array([0.0, direction])
            motion = np.broadcast_to([c * motion_uv[0] - s * motion_uv[1], s * motion_uv[0] + c * motion_uv[1]],
                                     xy_true.shape)
            counts = model.counts(xy_true, motion, uv, rng) / COUNTS_FULL_SCALE
            n = uv.shape[0]
            times = t + np.arange(n) * sample_step_m / 0.05
            t = float(times[-1]) + 0.5
            values = {"time_s": times, "frame_id": np.full(n, f), "pass_id": np.full(n, pass_id),
                      "drive_u_m": uv[:, 0], "drive_v_m": uv[:, 1],
                      "cmd_x_m": cmd[0] + uv[:, 0], "cmd_y_m": cmd[1] + uv[:, 1],
                      "x_m": xy_est[:, 0], "y_m": xy_est[:, 1], "true_x_m": xy_true[:, 0],
                      "true_y_m": xy_true[:, 1], "axis": np.full(n, axis), "direction": np.full(n, direction),
                      **{c.name: counts[:, c.index] for c in CHANNELS}}
            for key, arr in values.items():
                cols[key].append(np.asarray(arr))
            pass_id += 1
    samples = {k: np.concatenate(v) for k, v in cols.items()}
    int_cols = ("frame_id", "pass_id", "axis", "direction")
    for name in int_cols:
        samples[name] = samples[name].astype(np.int64)
    samples["seq"] = np.arange(samples["time_s"].shape[0])
    frame_arrays = {k: np.asarray(v, dtype=np.int64 if k == "frame_id" else np.float64)
                    for k, v in frames.items()}
    meta = {"format": FORMAT, "status": "complete", "wall_name": wall.name,
            "wall_width_m": wall.width_m, "wall_height_m": wall.height_m, "wall_fingerprint": wall.fingerprint(),
            "wall_json": wall.to_dict(), "sensor": cfg.to_dict(), "seed": seed,
            "plan": {"kind": "dense", "line_spacing_m": line_spacing_m}}
    return ScanData(f"simulated scan of {wall.name or 'wall'} (seed {seed})", samples, frame_arrays, meta)


def write_log(data: ScanData, path: str | Path, overwrite: bool = True) -> Path:
    """Store a ScanData in the scanner's SQLite scan-log format (one pass per transaction)."""
    path = Path(path)
    meta = {k: v for k, v in data.meta.items() if k not in ("format", "created", "status")}
    log = ScanLog.create(path, meta, overwrite=overwrite)
    with log:
        f = data.frames
        for k in range(f["frame_id"].shape[0]):
            row: dict[str, Any] = {c: (int(f[c][k]) if c == "frame_id" else float(f[c][k]))
                   for c in f if c != "cov"}
            row["cov"] = f["cov"][k]
            log.append_frame(row)
        s = data.samples
        pids = s["pass_id"]
        starts = np.flatnonzero(np.r_[True, pids[1:] != pids[:-1]])
        ends = np.r_[starts[1:], pids.shape[0]]
        for a, b in zip(starts, ends, strict=True):
            sl = {c: s[c][a:b] for c in SAMPLE_COLUMNS if c != "seq"}
            ax = int(sl["axis"][0])
            row = {"pass_id": int(pids[a]), "frame_id": int(sl["frame_id"][0]), "stage": "raster",
                   "axis": "x" if ax == 0 else "y", "direction": int(sl["direction"][0]),
                   "start_u_m": float(sl["drive_u_m"][0]), "start_v_m": float(sl["drive_v_m"][0]),
                   "end_u_m": float(sl["drive_u_m"][-1]), "end_v_m": float(sl["drive_v_m"][-1]),
                   "t_start_s": float(sl["time_s"][0]), "t_end_s": float(sl["time_s"][-1])}
            log.append_pass(row, sl)
        log.set_meta("status", data.meta.get("status", "complete"))
    return path
