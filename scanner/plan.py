"""Scan planning: frames set by robot positions, passes within each frame, and the time model.

The robot stands in front of the wall at one position per *frame*; two linear drives move the scanner over
a window of the wall: u (right) up to `travel_u_m`, v (up) up to `travel_v_m`. A frame's pose (x, y, phi)
maps drive coordinates to wall coordinates (see scanner/log.py). Frames are `frame_width_m` (≈0.35 m, the
paper's) apart along the wall.

A *pass* is one measuring move at scan speed along u (axis 'x') or v (axis 'y'); between passes the drives
move rapidly. The time model: trapezoidal velocity profiles (acceleration, speed limit) for every move, the
scanner's speed limit on measuring moves, and the robot's move plus alignment per frame.

Planners are generators per frame: they yield a list of passes (a stage), receive the measured samples of
those passes (dict pass_id -> samples dict as in scanner/log.py), and may yield more (adaptive planning).
`DensePlanner` is the paper's way: a serpentine raster with 1 cm line spacing. `AdaptivePlanner`: coarse
horizontal and vertical passes first, then short passes placed to confirm, localize and trace what the
coarse passes found (using the 1-D peak detector in scanner/peaks.py).
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from geometry.errors import InputError
from scanner.peaks import PeakConfig, detect_peaks
from scanner.wall import Wall

REACH_TOLERANCE_M = 1e-6


@dataclass
class DriveConfig:
    """The xy linear drives and the robot carrying them. Metres, seconds."""

    travel_u_m: float = 0.40
    travel_v_m: float = 2.10
    rapid_speed_m_s: float = 0.25  # G0 moves (not measuring)
    accel_m_s2: float = 0.5
    scan_speed_m_s: float = 0.05  # measuring moves; must not exceed the scanner's speed limit
    frame_width_m: float = 0.35
    robot_move_s: float = 20.0  # drive the platform to the next frame
    robot_align_s: float = 15.0  # align to the wall with the laser scanners (paper, figure 10)
    robot_sigma_m: float = 0.01  # where the robot actually stops vs. commanded (1 sigma per axis)
    robot_sigma_rad: float = 0.002
    loc_sigma_m: float = 0.002  # localization estimate error (1 sigma per axis)
    loc_sigma_rad: float = 0.0003

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class PassSpec:
    """One measuring move in drive coordinates (metres)."""

    frame_id: int
    stage: str
    axis: str  # 'x' (along u) or 'y' (along v)
    start_uv: tuple[float, float]
    end_uv: tuple[float, float]

    @property
    def length(self) -> float:
        return math.dist(self.start_uv, self.end_uv)

    @property
    def direction(self) -> int:
        i = 0 if self.axis == "x" else 1
        return 1 if self.end_uv[i] >= self.start_uv[i] else -1

    def row(self, pass_id: int, t_start: float, t_end: float) -> dict[str, Any]:
        return {"pass_id": pass_id, "frame_id": self.frame_id, "stage": self.stage, "axis": self.axis,
                "direction": self.direction, "start_u_m": self.start_uv[0], "start_v_m": self.start_uv[1],
                "end_u_m": self.end_uv[0], "end_v_m": self.end_uv[1], "t_start_s": t_start, "t_end_s": t_end}


# ---------------------------------------------------------------------- time model
def move_time(length: float, speed: float, accel: float) -> float:
    """Duration of a trapezoidal (or triangular) move from rest to rest, seconds."""
    if length <= 0.0:
        return 0.0
    if length <= speed * speed / accel:  # never reaches full speed
        return 2.0 * math.sqrt(length / accel)
    return length / speed + speed / accel


def move_position(t: np.ndarray, length: float, speed: float, accel: float) -> np.ndarray:
    """Distance travelled at times t (s) along a rest-to-rest trapezoidal move. Returns metres, same shape."""
    t = np.asarray(t, dtype=np.float64)
    total = move_time(length, speed, accel)
    if total == 0.0:
        return np.zeros_like(t)
    peak = min(speed, math.sqrt(length * accel))
    t_acc = peak / accel
    d_acc = 0.5 * accel * t_acc * t_acc
    tc = np.clip(t, 0.0, total)
    accel_part = 0.5 * accel * tc * tc
    cruise = d_acc + peak * (tc - t_acc)
    left = total - tc
    decel = length - 0.5 * accel * left * left
    return np.where(tc < t_acc, accel_part, np.where(tc <= total - t_acc, cruise, decel))


def sample_times(duration: float, rate_hz: float) -> np.ndarray:
    """The scanner's sample instants within a move, s: k * (integer µs period), as the device timestamps them."""
    period_us = round(1e6 / rate_hz)
    n = round(duration * 1e6) // period_us + 1  # the device clock counts whole µs
    return np.arange(n, dtype=np.int64) * period_us / 1e6


def frame_pose_apply(pose: tuple[float, float, float], uv: np.ndarray) -> np.ndarray:
    """Wall coordinates of drive positions. pose (x, y, phi rad), uv : (n, 2) metres -> (n, 2) metres."""
    x, y, phi = pose
    c, s = math.cos(phi), math.sin(phi)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([x + c * uv[:, 0] - s * uv[:, 1], y + s * uv[:, 0] + c * uv[:, 1]])


def frame_pose_inverse(pose: tuple[float, float, float], xy: np.ndarray) -> np.ndarray:
    """Drive coordinates of wall points (inverse of frame_pose_apply)."""
    x, y, phi = pose
    c, s = math.cos(phi), math.sin(phi)
    d = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - [x, y]
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


@dataclass
class FrameTarget:
    """Where the robot is commanded for a frame, and the part of the wall (drive u range) this frame covers."""

    frame_id: int
    x_m: float
    u_lo: float
    u_hi: float


def frame_targets(wall: Wall, drives: DriveConfig) -> list[FrameTarget]:
    """Frames side by side, `frame_width_m` apart; each scans as far right as the drives reach, so that
    neighbouring frames overlap by travel_u_m - frame_width_m (objects at a frame's edge are seen whole)."""
    if wall.height_m > drives.travel_v_m + REACH_TOLERANCE_M:
        raise InputError(f"{wall.source or 'wall'}: height_m = {wall.height_m:g} exceeds the drives' reach "
                         f"(travel_v_m = {drives.travel_v_m:g} m)",
                         "scan the wall in parts (split the wall file) or configure longer drives")
    if drives.frame_width_m > drives.travel_u_m + REACH_TOLERANCE_M:
        raise InputError(f"frame_width_m = {drives.frame_width_m:g} exceeds the drives' reach "
                         f"(travel_u_m = {drives.travel_u_m:g} m)")
    width = drives.frame_width_m
    count = max(1, math.ceil(wall.width_m / width - 1e-9))
    frames = []
    for i in range(count):
        x0 = i * width
        u_hi = min(wall.width_m - x0, drives.travel_u_m)
        frames.append(FrameTarget(i, x0, 0.0, u_hi))
    return frames


def check_pass_in_reach(spec: PassSpec, drives: DriveConfig) -> None:
    """InputError if a pass leaves the drives' travel."""
    for name, (u, v) in (("start", spec.start_uv), ("end", spec.end_uv)):
        if not (-REACH_TOLERANCE_M <= u <= drives.travel_u_m + REACH_TOLERANCE_M
                and -REACH_TOLERANCE_M <= v <= drives.travel_v_m + REACH_TOLERANCE_M):
            raise InputError(f"plan: pass {name} (u={u:.4f} m, v={v:.4f} m) in frame {spec.frame_id} is outside "
                             f"the drives' reach (u 0..{drives.travel_u_m:g}, v 0..{drives.travel_v_m:g} m)")


Samples = dict[str, np.ndarray]
StageGenerator = Generator[list[PassSpec], dict[int, Samples], None]


# ---------------------------------------------------------------------- planners
@dataclass
class DensePlanner:
    """The paper's way: horizontal serpentine raster lines `line_spacing_m` apart over each frame's strip."""

    wall: Wall
    drives: DriveConfig
    line_spacing_m: float = 0.01

    def describe(self) -> dict[str, Any]:
        return {"kind": "dense", "line_spacing_m": self.line_spacing_m}

    def frames(self) -> list[FrameTarget]:
        return frame_targets(self.wall, self.drives)

    def frame_stages(self, frame: FrameTarget) -> StageGenerator:
        n = math.floor(self.wall.height_m / self.line_spacing_m + 1e-9) + 1
        passes = []
        for k in range(n):
            v = round(min(k * self.line_spacing_m, self.wall.height_m), 6)
            a, b = (frame.u_lo, frame.u_hi) if k % 2 == 0 else (frame.u_hi, frame.u_lo)
            passes.append(PassSpec(frame.frame_id, "raster", "x", (a, v), (b, v)))
        yield passes


@dataclass
class AdaptiveConfig:
    coarse_row_spacing_m: float = 0.25  # horizontal passes (find vertical / oblique objects)
    coarse_columns: tuple[float, ...] = (0.06, 0.29)  # u of vertical passes per frame (find horizontal ones)
    confirm_offset_m: float = 0.03  # second short pass beside each find: direction of the object
    confirm_half_length_m: float = 0.09  # long enough to see a 45° object shifted by the offset
    trace_half_length_m: float = 0.05
    end_search_steps: int = 3  # bisection passes to localize where an object ends between coarse passes

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass
class AdaptivePlanner:
    """Coarse grid first, then passes placed to confirm, localize and trace what was found.

    Per frame: (1) coarse horizontal passes every `coarse_row_spacing_m` and vertical passes at
    `coarse_columns`; (2) for every peak found on a coarse pass, a short parallel *confirm* pass offset by
    `confirm_offset_m` — the peak's shift gives the object's direction; (3) *trace* passes: where an object's
    predicted course reaches the next coarse pass but is not found there, bisection passes localize its end.
    """

    wall: Wall
    drives: DriveConfig
    sensor_hysteresis_m: float = 0.003
    config: AdaptiveConfig = field(default_factory=AdaptiveConfig)
    peaks: PeakConfig = field(default_factory=PeakConfig)

    def describe(self) -> dict[str, Any]:
        return {"kind": "adaptive", **self.config.to_dict()}

    def frames(self) -> list[FrameTarget]:
        return frame_targets(self.wall, self.drives)

    def _coarse(self, frame: FrameTarget) -> list[PassSpec]:
        cfg = self.config
        height = self.wall.height_m
        rows = np.arange(0.0, height + 1e-9, cfg.coarse_row_spacing_m)
        if height - rows[-1] > 0.05:
            rows = np.append(rows, height)
        passes = []
        for k, v in enumerate(np.round(rows, 6)):
            a, b = (frame.u_lo, frame.u_hi) if k % 2 == 0 else (frame.u_hi, frame.u_lo)
            passes.append(PassSpec(frame.frame_id, "coarse", "x", (a, float(v)), (b, float(v))))
        for k, u in enumerate(cfg.coarse_columns):
            u = float(min(u, frame.u_hi))
            a, b = (0.0, height) if k % 2 == 0 else (height, 0.0)
            passes.append(PassSpec(frame.frame_id, "coarse", "y", (u, a), (u, b)))
        return passes

    def _short(self, frame: FrameTarget, stage: str, axis: str, fixed: float, centre: float,
               half: float) -> PassSpec | None:
        """A short pass along `axis` at `fixed` (the other coordinate), centred at `centre`, clipped to reach."""
        if axis == "x":
            lo, hi = max(frame.u_lo, centre - half), min(frame.u_hi, centre + half)
            if hi - lo < 0.02 or not 0.0 <= fixed <= self.wall.height_m:
                return None
            lo, hi, fixed = round(lo, 6), round(hi, 6), round(fixed, 6)  # µm: exact on the G-code wire
            return PassSpec(frame.frame_id, stage, "x", (lo, fixed), (hi, fixed))
        lo, hi = max(0.0, centre - half), min(self.wall.height_m, centre + half)
        if hi - lo < 0.02 or not frame.u_lo <= fixed <= frame.u_hi:
            return None
        lo, hi, fixed = round(lo, 6), round(hi, 6), round(fixed, 6)
        return PassSpec(frame.frame_id, stage, "y", (fixed, lo), (fixed, hi))

    def _find(self, samples: Samples, axis: str) -> list[tuple[float, float, float]]:
        """Peaks along a pass in drive coordinates: [(position along axis, height, width)], corrected for the
        inductive hysteresis (the sensor lags by hysteresis_m along the motion)."""
        coord = samples["drive_u_m"] if axis == "x" else samples["drive_v_m"]
        direction = float(np.median(samples["direction"])) if len(coord) else 1.0
        found = []
        for channel in ("inductive", "ac"):
            lag = self.sensor_hysteresis_m * direction if channel == "inductive" else 0.0
            for peak in detect_peaks(coord, samples[channel], self.peaks):
                found.append((peak.position - lag, peak.height, peak.width))
        found.sort()
        merged: list[tuple[float, float, float]] = []
        for item in found:  # the same object in both channels: keep one
            if merged and abs(item[0] - merged[-1][0]) < self.peaks.merge_distance_m:
                if item[1] > merged[-1][1]:
                    merged[-1] = item
                continue
            merged.append(item)
        return merged

    def frame_stages(self, frame: FrameTarget) -> StageGenerator:
        cfg = self.config
        coarse = self._coarse(frame)
        results = yield coarse
        by_spec = _by_spec(coarse, results)
        rows = sorted({p.start_uv[1] for p in coarse if p.axis == "x"})
        columns = sorted({p.start_uv[0] for p in coarse if p.axis == "y"})
        finds: list[tuple[PassSpec, float]] = []
        for spec in coarse:
            finds += [(spec, pos) for pos, _, _ in self._find(by_spec[spec], spec.axis)]
        # (2) confirm: a parallel short pass beside every find gives the object's local direction.
        confirm: list[PassSpec] = []
        for spec, pos in finds:
            fixed = spec.start_uv[1] if spec.axis == "x" else spec.start_uv[0]
            limit = self.wall.height_m if spec.axis == "x" else frame.u_hi
            offset = cfg.confirm_offset_m if fixed + cfg.confirm_offset_m <= limit else -cfg.confirm_offset_m
            short = self._short(frame, "confirm", spec.axis, fixed + offset, pos, cfg.confirm_half_length_m)
            if short is not None:
                confirm.append(short)
        if not confirm:
            return
        results = yield confirm
        by_confirm = _by_spec(confirm, results)
        # (3) trace: follow each confirmed object to the next coarse line; where it is not found there, bisect
        # the gap with short passes across its predicted course to localize where it ends.
        open_ends: list[dict[str, Any]] = []
        for spec, pos in finds:
            fixed = spec.start_uv[1] if spec.axis == "x" else spec.start_uv[0]
            limit = self.wall.height_m if spec.axis == "x" else frame.u_hi
            offset = cfg.confirm_offset_m if fixed + cfg.confirm_offset_m <= limit else -cfg.confirm_offset_m
            short = self._short(frame, "confirm", spec.axis, fixed + offset, pos, cfg.confirm_half_length_m)
            if short is None or short not in by_confirm:
                continue
            near = [p for p, _, _ in self._find(by_confirm[short], spec.axis)
                    if abs(p - pos) < cfg.confirm_half_length_m * 0.8]
            if not near:
                continue  # a point object (screw, nail) or an object parallel to the pass
            slope = (min(near, key=lambda p: abs(p - pos)) - pos) / offset  # d(along) / d(fixed)
            lines = rows if spec.axis == "x" else columns
            for sign in (1.0, -1.0):  # both neighbours: the object may end on either side
                nxt = [c for c in lines if (c - fixed) * sign > 1e-9]
                if not nxt:
                    continue
                target = min(nxt, key=lambda c: abs(c - fixed))
                predicted = pos + slope * (target - fixed)
                line = _line_spec(coarse, spec.axis, target)
                if line is not None and any(abs(p - predicted) < 0.02 for p, _, _ in self._find(by_spec[line],
                                                                                                  spec.axis)):
                    continue  # found on the next coarse line too: the segment between is traced
                open_ends.append({"axis": spec.axis, "pos": pos, "fixed": fixed, "slope": slope,
                                  "lo": fixed, "hi": target})
        unique: dict[tuple[Any, ...], dict[str, Any]] = {}
        for end in open_ends:  # the same end reached from two finds (e.g. both channels) is searched once
            unique.setdefault((end["axis"], round(end["lo"], 3), round(end["hi"], 3),
                               round(end["pos"] + end["slope"] * (end["hi"] - end["fixed"]), 2)), end)
        open_ends = list(unique.values())
        for _ in range(cfg.end_search_steps):
            trace: list[PassSpec] = []
            owners: list[dict[str, Any]] = []
            for end in open_ends:
                mid = round(0.5 * (end["lo"] + end["hi"]), 6)
                centre = end["pos"] + end["slope"] * (mid - end["fixed"])
                short = self._short(frame, "trace", end["axis"], mid, centre, cfg.trace_half_length_m)
                if short is not None:
                    end["mid"], end["centre"] = mid, centre
                    trace.append(short)
                    owners.append(end)
            if not trace:
                return
            results = yield trace
            for end, (_, samples) in zip(owners, sorted(results.items()), strict=True):
                seen = any(abs(p - end["centre"]) < 0.02 for p, _, _ in self._find(samples, end["axis"]))
                end["lo" if seen else "hi"] = end["mid"]
            open_ends = owners


def _line_spec(passes: list[PassSpec], axis: str, fixed: float) -> PassSpec | None:
    for p in passes:
        if p.axis == axis and abs((p.start_uv[1] if axis == "x" else p.start_uv[0]) - fixed) < 1e-9:
            return p
    return None


def _by_spec(passes: list[PassSpec], results: dict[int, Samples]) -> dict[PassSpec, Samples]:
    """Pair each spec with its samples; results are keyed by pass id in yield order."""
    ids = sorted(results)
    return dict(zip(passes, (results[i] for i in ids), strict=True))


def make_planner(kind: str, wall: Wall, drives: DriveConfig, hysteresis_m: float = 0.003,
                 options: dict[str, Any] | None = None) -> DensePlanner | AdaptivePlanner:
    """A planner by name ('dense' or 'adaptive') with optional parameters (as recorded in a log's meta)."""
    options = {k: v for k, v in (options or {}).items() if k != "kind"}
    if kind == "dense":
        return DensePlanner(wall, drives, **options)
    if kind == "adaptive":
        cfg = AdaptiveConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in options.items()})
        return AdaptivePlanner(wall, drives, hysteresis_m, cfg)
    raise InputError(f"plan = {kind!r}: unknown plan", "use dense or adaptive")
