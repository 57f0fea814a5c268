"""Scan planning: frames set by robot positions, passes within each frame, and the time model.

The robot stands in front of the wall at one position per *frame*; two linear drives move the scanner over
a window of the wall: u (right) up to `travel_u_m`, v (up) up to `travel_v_m`. A frame's pose (x, y, phi)
maps drive coordinates to wall coordinates (see scanner/log.py). Frames are `frame_width_m` (≈0.35 m, the
paper's) apart along the wall. A wall taller than the drives' reach is scanned in stacked *bands*: a lift on
the platform raises the drive frame (at most `lift_travel_m`) so that its window reaches the next band, which
overlaps the one below by `band_overlap_m`; at each robot position the robot scans band after band (upwards
at one position, downwards at the next: one lift move per band change) and re-aligns after every lift move.

A *pass* is one measuring move at scan speed along u (axis 'x') or v (axis 'y'); between passes the drives
move rapidly. The time model: trapezoidal velocity profiles (acceleration, speed limit) for every move, the
scanner's speed limit on measuring moves, and per frame the robot's move or the lift's move plus the
alignment (`reposition_time`).

Planners are generators per frame: they yield a list of passes (a stage), receive the measured samples of
those passes (dict pass_id -> samples dict as in scanner/log.py), and may yield more (adaptive planning).
`DensePlanner` is the paper's way: a serpentine raster with 1 cm line spacing. `AdaptivePlanner`: coarse
horizontal and vertical passes first, then short passes placed to confirm what they found, trace it along its
course and follow it (using the 1-D peak detector in scanner/peaks.py); STOPPING_RULE says when it stops.
The installation zones and known sockets (scanner/priors.py) order its passes, PRIORS_RULE says how.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Generator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from geometry.errors import InputError
from geometry.polyline import distances_to_polyline, nearest_segments
from geometry.robust import fit_line
from scanner.channels import CAPACITIVE, INDUCTIVE, LINE_PEAKS
from scanner.peaks import PeakConfig, detect_peaks
from scanner.priors import SOCKET_NEAR_M, Priors, wall_priors
from scanner.sensor_model import additive_units
from scanner.wall import Wall

REACH_TOLERANCE_M = 1e-6
# the adaptive plan's stages whose every pass it searches for crossings (AdaptivePlanner._peaks); it does not
# search its point, stud and follow passes
SEARCHED_STAGES = ("coarse", "socket", "confirm", "trace")
# The adaptive planner's behaviour, recorded in every log: a log is resumed only by the planner that made it.
# 2: fastener passes across bumps and weak finds, seams by localised poses, DIN priors.
ADAPTIVE_PLANNER_VERSION = 2
STOPPING_RULE = (
    "Every object a coarse pass finds is traced along its course with crossings whose spacing grows with the "
    "certainty of its direction (a coarse pass's crossing that lies where the course is predicted counts as "
    "one), until it leaves the drives' reach within a step, ends (no response on crossings down to 3 cm ahead "
    "nor on a square 4 cm around its last crossing) or meets a course already traced; a junction's every branch "
    "is traced. Every traced stretch, and its run on to the edge, is then measured by a following pass along "
    "it; where that pass's response falls below 70 % of the object's crossing peaks (more than 1.5 cm from its "
    "ends) the object may have left its band unseen, so it is crossed there and that stretch followed again "
    "(twice at most). What still falls is left inferred: the drill check calls it unknown. Objects no coarse "
    "pass crosses are not traced; studs (wide capacitive responses on two coarse rows) get one fastener pass "
    "along their centre, isolated finds one short pass across them.")
PRIORS_RULE = (
    "Priors order the passes, never replace one: in each frame the coarse passes along a DIN 18015-3 installation "
    "zone (or past a known socket) run first, then those across a zone, then the rest (the same passes either "
    "way); finds in a zone whose course runs along it, or at a known socket, are traced first; a known socket "
    "no coarse pass came near is searched by a square of short passes around it and one across it before "
    "anything is traced. "
    "Nothing is mapped from a zone or a socket alone.")


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
    lift_move_s: float = 15.0  # raise or lower the drive frame to the next band (walls taller than travel_v_m)
    lift_travel_m: float = 0.80  # how far the lift raises the drive frame: walls up to travel_v_m + this
    band_overlap_m: float = 0.05  # stacked bands overlap as much as neighbouring frames do (travel_u - width)
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
    axis: str  # 'x' (along u), 'y' (along v) or 'xy' (both drives at once: a following pass along an object)
    start_uv: tuple[float, float]
    end_uv: tuple[float, float]

    @property
    def length(self) -> float:
        return math.dist(self.start_uv, self.end_uv)

    @property
    def direction(self) -> int:
        if self.axis == "xy":
            return 0  # no single axis: mapping neither shifts its samples for the lag nor takes its peaks as crossings
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
    """Where the robot is commanded for a frame, and the part of the wall this frame covers: drive u range
    u_lo..u_hi and v range v_lo..v_hi, with the drive frame raised to y_m on the wall (its band's lift)."""

    frame_id: int
    x_m: float
    u_lo: float
    u_hi: float
    y_m: float
    v_lo: float
    v_hi: float
    column: int  # robot position along the wall, 0 at the left
    band: int  # 0 at the bottom


def band_ranges(wall: Wall, drives: DriveConfig) -> list[tuple[float, float, float]]:
    """Stacked bands of the wall, bottom first: (y_m, v_lo, v_hi) — the lift height of the drive frame on the
    wall and the drive v range scanned. Each band reaches as high as the drives do and overlaps the one below
    by band_overlap_m; the lift raises the frame no more than its band needs (y_m + travel_v_m at the band's
    top), so a wall no taller than travel_v_m is one band (0, 0, height)."""
    height, travel = wall.height_m, drives.travel_v_m
    reach = travel + drives.lift_travel_m
    if height > reach + REACH_TOLERANCE_M:
        raise InputError(f"{wall.source or 'wall'}: height_m = {height:g} exceeds what the drives reach with the "
                         f"lift (travel_v_m + lift_travel_m = {travel:g} + {drives.lift_travel_m:g} = {reach:g} m)",
                         "scan the wall in parts (split the wall file) or configure a longer lift")
    if not 0.0 <= drives.band_overlap_m < travel:
        raise InputError(f"band_overlap_m = {drives.band_overlap_m:g}: must lie in 0 ≤ overlap < travel_v_m "
                         f"({travel:g} m)")
    bands = []
    bottom = 0.0
    while True:
        top = min(bottom + travel, height)
        if height - top <= REACH_TOLERANCE_M:
            top = height
        lift = round(top - travel, 6) if top - travel > REACH_TOLERANCE_M else 0.0  # µm: exact on the wire
        bands.append((lift, round(bottom - lift, 6), top if lift == 0.0 else travel))
        if top >= height:
            return bands
        bottom = top - drives.band_overlap_m


def frame_targets(wall: Wall, drives: DriveConfig) -> list[FrameTarget]:
    """Frames side by side, `frame_width_m` apart; each scans as far right as the drives reach, so that
    neighbouring frames overlap by travel_u_m - frame_width_m (objects at a frame's edge are seen whole).
    On a wall taller than the drives' reach, each position scans its bands (band_ranges) in turn: upwards at
    even positions, downwards at odd ones, so the lift moves once per band change and never back idle."""
    if drives.frame_width_m > drives.travel_u_m + REACH_TOLERANCE_M:
        raise InputError(f"frame_width_m = {drives.frame_width_m:g} exceeds the drives' reach "
                         f"(travel_u_m = {drives.travel_u_m:g} m)")
    bands = band_ranges(wall, drives)
    width = drives.frame_width_m
    count = max(1, math.ceil(wall.width_m / width - 1e-9))
    frames: list[FrameTarget] = []
    for i in range(count):
        x0 = i * width
        u_hi = min(wall.width_m - x0, drives.travel_u_m)
        order = range(len(bands)) if i % 2 == 0 else range(len(bands) - 1, -1, -1)
        for b in order:
            y, v_lo, v_hi = bands[b]
            frames.append(FrameTarget(len(frames), x0, 0.0, u_hi, y, v_lo, v_hi, i, b))
    return frames


def reposition_time(previous: FrameTarget | None, target: FrameTarget, drives: DriveConfig) -> float:
    """Seconds from the end of the previous frame's passes (None: the scan's start) until the robot stands
    aligned at target: the platform's move to a new position, the lift's move to another band, and the
    alignment with the lasers after either."""
    moved = previous is None or target.column != previous.column
    lifted = previous is not None and target.band != previous.band
    # a new position starts at the band the lift is at (frame_targets' order): no lift move with the drive
    seconds = drives.robot_move_s if moved else 0.0
    if lifted:
        seconds += drives.lift_move_s
    return seconds + drives.robot_align_s


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
        n = math.floor((frame.v_hi - frame.v_lo) / self.line_spacing_m + 1e-9) + 1
        passes = []
        for k in range(n):
            v = round(min(frame.v_lo + k * self.line_spacing_m, frame.v_hi), 6)
            a, b = (frame.u_lo, frame.u_hi) if k % 2 == 0 else (frame.u_hi, frame.u_lo)
            passes.append(PassSpec(frame.frame_id, "raster", "x", (a, v), (b, v)))
        yield passes


@dataclass
class AdaptiveConfig:
    coarse_row_spacing_m: float = 0.25  # horizontal passes (find vertical / oblique objects)
    coarse_columns: tuple[float, ...] = (0.06, 0.29)  # u of vertical passes per frame (find horizontal ones)
    confirm_offset_m: float = 0.03  # second short pass beside each find: direction of the object
    confirm_half_length_m: float = 0.09  # long enough to see a 45° object shifted by the offset
    cross_half_m: float = 0.03  # half length of a tracing crossing, widened by 3 σ of the predicted course
    position_sigma_m: float = 0.0015  # 1 σ of a crossing's peak position
    min_step_m: float = 0.03  # tracing step between crossings: from min (new course, after a loss) ...
    max_step_m: float = 0.25  # ... to max, growing by step_growth while each crossing lands where predicted
    step_growth: float = 2.0
    join_m: float = 0.01  # a crossing this close to a traced course is that course (met, or the same object)
    ring_half_m: float = 0.04  # after a loss: a square of passes this far around the last crossing
    edge_margin_m: float = 0.005
    max_trace_stages: int = 60
    seam_m: float = 0.02  # a frame traces what it finds up to this far beyond the next frame's left edge
    free_reach: float = 1.3  # a coarse crossing in the predicted window up to max(this many steps (+2 cm),
    # max_step_m) ahead is taken as the next crossing: the following pass measures the stretch up to it
    follow_rounds: int = 2  # re-crossings where a following pass lost the response, then the stretch is inferred
    follow_min_share: float = 0.7  # of the crossings' peak height: the following pass is still on the object
    point_half_m: float = 0.08  # half length of the pass across an isolated find (a screw, a nail): a coarse
    # row sees a screw up to 47 mm beside it, so this pass crosses it with 3 cm to spare on its far side
    point_min_height: float = 0.04  # a weaker peak on a coarse pass, not traced, still gets a pass across it:
    # a nail 4 cm off the row (the sparse mapper's inductive threshold)
    fastener_half_m: float = 0.04  # half length of the pass across a bump along a stud or a course (on the pass)
    stud_min_height: float = 0.03  # capacitive peak height (display units) of a stud on a coarse pass ...
    stud_min_width_m: float = 0.04  # ... and its least FWHM: wider than any cable's or pipe's echo
    follow_min_m: float = 0.01  # a stretch shorter than this between two crossings is covered by them
    end_tolerance_m: float = 0.015  # the following pass's response may fall this near a course's end
    fastener_min_rise: float = 0.5  # additive units: a bump this high on a pass along a stud or a course (a
    # screw on a steel stud rises ~4 above the stud's 3, a nail on wood ~1) is crossed by a point pass
    priors: bool = True  # order passes by the installation zones and known sockets (PRIORS_RULE)
    socket_search_half_m: float = 0.07  # a known socket no coarse pass came near: a square this far around it
    # (a box's half side, 3.5 cm, and 3 sigma of the inductive footprint clear of it: it crosses what leaves the
    # box, not the box)

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass
class AdaptivePlanner:
    """Coarse grid first, then passes placed to confirm, trace and follow what was found.

    Per frame (one band at one robot position, within the band's drive ranges): (1) coarse horizontal
    passes every `coarse_row_spacing_m` and vertical passes at `coarse_columns`; (2) for every peak found on
    a coarse pass, a short parallel *confirm* pass offset by `confirm_offset_m` — the peak's shift gives the
    object's direction; (3) *trace* passes (stage "trace"):
    from each find, nearest first, both ends of the object are followed outward by short crossings, the step
    growing while crossings land where the fitted direction predicts and shrinking where they do not; a lost
    course is searched for on a square around its last crossing, whose every further hit starts a branch;
    (4) *follow* passes (stage "follow", axis "xy", both drives at once) along each straight run of the traced
    course, re-crossed where their response falls (STOPPING_RULE). `report` gets one row per traced object:
    its length and the share of it the following passes measured, and the zone or socket that had it traced
    first. With `config.priors` the zones and known sockets order the passes (PRIORS_RULE); `ordered_by`
    counts per frame and zone or socket the coarse passes it moved forward, the objects it had traced first and
    the socket searches.
    """

    wall: Wall
    drives: DriveConfig
    sensor_hysteresis_m: float = 0.003
    config: AdaptiveConfig = field(default_factory=AdaptiveConfig)
    peaks: PeakConfig = field(default_factory=PeakConfig)
    report: list[dict[str, Any]] = field(default_factory=list)  # one row per traced object, as frames finish
    ordered_by: dict[int, dict[str, dict[str, int]]] = field(default_factory=dict)  # frame -> zone -> what -> n
    _at: np.ndarray = field(default_factory=lambda: np.zeros(2), repr=False)  # where the last pass ended
    _frame: FrameTarget | None = field(default=None, repr=False)  # the frame being planned
    _placed: dict[int, tuple[FrameTarget, tuple[float, float, float]]] = field(default_factory=dict, repr=False)
    # the frame's searched passes: (id of the samples, axis) -> (those samples, kept so the id stays theirs,
    # the peaks per channel): each pass searched once, by the plan (coarse rows again for studs) or for a watcher
    _searched: dict[tuple[int, str], tuple[Samples, dict[str, list[tuple[float, float, float]]]]] = field(
        default_factory=dict, repr=False)
    priors: Priors | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        self.priors = wall_priors(self.wall) if self.config.priors else None

    def describe(self) -> dict[str, Any]:
        return {"kind": "adaptive", "planner_version": ADAPTIVE_PLANNER_VERSION, **self.config.to_dict()}

    def priors_lines(self) -> list[str]:
        """What ordered the passes, for the scan's summary: the zones and sockets, and what each moved forward."""
        if self.priors is None:
            return ["priors off: passes in the plain coarse order, finds traced nearest first"]
        totals: dict[str, dict[str, int]] = {}
        for zones in self.ordered_by.values():
            for name, counts in zones.items():
                for what, n in counts.items():
                    totals.setdefault(name, {}).setdefault(what, 0)
                    totals[name][what] += n
        return [self.priors.describe(), *(f"{name}: " + ", ".join(f"{what} {n}" for what, n in counts.items())
                                          for name, counts in totals.items())]

    def _count(self, frame: FrameTarget, name: str, what: str) -> None:
        counts = self.ordered_by.setdefault(frame.frame_id, {}).setdefault(name, {})
        counts[what] = counts.get(what, 0) + 1

    def frames(self) -> list[FrameTarget]:
        return frame_targets(self.wall, self.drives)

    def _coarse(self, frame: FrameTarget) -> list[PassSpec]:
        cfg = self.config
        bottom, top = frame.v_lo, frame.v_hi
        rows = np.arange(bottom, top + 1e-9, cfg.coarse_row_spacing_m)
        if top - rows[-1] > 0.05:
            rows = np.append(rows, top)
        passes = []
        for k, v in enumerate(np.round(rows, 6)):
            a, b = (frame.u_lo, frame.u_hi) if k % 2 == 0 else (frame.u_hi, frame.u_lo)
            passes.append(PassSpec(frame.frame_id, "coarse", "x", (a, float(v)), (b, float(v))))
        for k, u in enumerate(cfg.coarse_columns):
            u = float(min(u, frame.u_hi))
            a, b = (bottom, top) if k % 2 == 0 else (top, bottom)
            passes.append(PassSpec(frame.frame_id, "coarse", "y", (u, a), (u, b)))
        return passes

    def _short(self, frame: FrameTarget, stage: str, axis: str, fixed: float, centre: float,
               half: float) -> PassSpec | None:
        """A short pass along `axis` at `fixed` (the other coordinate), centred at `centre`, clipped to reach."""
        if axis == "x":
            lo, hi = max(frame.u_lo, centre - half), min(frame.u_hi, centre + half)
            if hi - lo < 0.02 or not frame.v_lo <= fixed <= frame.v_hi:
                return None
            lo, hi, fixed = round(lo, 6), round(hi, 6), round(fixed, 6)  # µm: exact on the G-code wire
            return PassSpec(frame.frame_id, stage, "x", (lo, fixed), (hi, fixed))
        lo, hi = max(frame.v_lo, centre - half), min(frame.v_hi, centre + half)
        if hi - lo < 0.02 or not frame.u_lo <= fixed <= frame.u_hi:
            return None
        lo, hi, fixed = round(lo, 6), round(hi, 6), round(fixed, 6)
        return PassSpec(frame.frame_id, stage, "y", (fixed, lo), (fixed, hi))

    def channel_peaks(self, spec: PassSpec, samples: Samples) -> dict[str, list[float]] | None:
        """Where the plan finds objects along a pass it searches (stages SEARCHED_STAGES), per LINE_PEAKS
        channel before the channels are merged: positions along the pass's drive coordinate, corrected for the
        inductive hysteresis. None for a pass the plan does not search. For a watcher (the live view): searched
        now, the plan reuses the search when it takes the pass's crossings."""
        if spec.stage not in SEARCHED_STAGES or spec.axis not in ("x", "y"):
            return None
        return {channel: [p[0] for p in peaks] for channel, peaks in self._channel_search(samples, spec.axis).items()}

    def _channel_search(self, samples: Samples, axis: str) -> dict[str, list[tuple[float, float, float]]]:
        """{channel: [(position, height, width)]} of every LINE_PEAKS channel's peaks along a pass, corrected
        for the inductive hysteresis (the sensor lags by hysteresis_m along the motion); searched once a frame."""
        key = (id(samples), axis)
        done = self._searched.get(key)
        if done is not None and done[0] is samples:
            return done[1]
        coord, inductive_lag = self._along(samples, axis)
        seams = self._seam_ends(coord, axis)
        found: dict[str, list[tuple[float, float, float]]] = {}
        for channel in (c.name for c in LINE_PEAKS):
            lag = inductive_lag if channel == INDUCTIVE.name else 0.0
            found[channel] = [(peak.position - lag, peak.height, peak.width)
                              for peak in detect_peaks(coord, samples[channel], self.peaks, keep_cut=seams)]
        self._searched[key] = (samples, found)
        return found

    def _peaks(self, samples: Samples, axis: str) -> list[tuple[float, float, float, str]]:
        """[(position, height, width, channel)] of the strongest channel per object along a pass, corrected
        for the inductive hysteresis (see _channel_search)."""
        found = [(*peak, channel) for channel, peaks in self._channel_search(samples, axis).items()
                 for peak in peaks]
        found.sort()
        merged: list[tuple[float, float, float, str]] = []
        for item in found:  # the same object in both channels: keep one
            if merged and abs(item[0] - merged[-1][0]) < self.peaks.merge_distance_m:
                if item[1] > merged[-1][1]:
                    merged[-1] = item
                continue
            merged.append(item)
        return merged

    def _along(self, samples: Samples, axis: str) -> tuple[np.ndarray, float]:
        """(drive coordinate along the pass, the inductive channel's lag along it): the sensor reports what it
        saw hysteresis_m earlier along the motion."""
        coord = samples["drive_u_m"] if axis == "x" else samples["drive_v_m"]
        direction = float(np.median(samples["direction"])) if len(coord) else 1.0
        return coord, self.sensor_hysteresis_m * direction

    def _seam_ends(self, coord: np.ndarray, axis: str) -> tuple[bool, bool]:
        """Whether a pass ends (low end, high end) at the edge of the frame's reach where a neighbouring frame
        or band takes over: an object in their overlap is cut by both, so its peak there is kept at its top."""
        f = self._frame
        if f is None or not len(coord):
            return False, False
        if axis == "x":
            return (f.x_m > 1e-9 and float(coord.min()) <= f.u_lo + 1e-3,
                    f.x_m + f.u_hi < self.wall.width_m - 1e-6 and float(coord.max()) >= f.u_hi - 1e-3)
        return (f.y_m > 1e-9 and float(coord.min()) <= f.v_lo + 1e-3,
                f.y_m + f.v_hi < self.wall.height_m - 1e-6 and float(coord.max()) >= f.v_hi - 1e-3)

    def localise(self, frame: FrameTarget, estimate: tuple[float, float, float]) -> None:
        """Where the robot's localisation puts the frame (x, y, φ on the wall), before its passes are planned:
        a frame planned after its neighbour takes over exactly where that one stopped owning finds."""
        self._placed[frame.frame_id] = (frame, tuple(float(v) for v in estimate))  # type: ignore[assignment]

    def _pose(self, frame: FrameTarget) -> tuple[float, float, float]:
        """The frame's pose on the wall (x, y, φ): as localised, else as commanded."""
        placed = self._placed.get(frame.frame_id)
        return placed[1] if placed is not None else (frame.x_m, frame.y_m, 0.0)

    def _own_limits(self, frame: FrameTarget) -> tuple[float, float, float, float]:
        """(u_lo, u_hi, v_lo, v_hi): the part of its reach where a frame traces what it finds, in its own drive
        coordinates. Neighbouring frames overlap; a find near the seam is traced by the frame that sees it clear
        of its edge (seam_m into the overlap); what crosses a band's seam is found clear of it in both bands."""
        cfg = self.config
        last = frame.u_hi < self.drives.travel_u_m - 1e-9
        u_hi = frame.u_hi if last else self.drives.frame_width_m + cfg.seam_m
        u_lo = frame.u_lo if frame.column == 0 else frame.u_lo + cfg.seam_m
        top_band = frame.y_m + frame.v_hi >= self.wall.height_m - REACH_TOLERANCE_M
        v_hi = math.inf if top_band else frame.v_hi - self.drives.band_overlap_m + cfg.seam_m
        v_lo = -math.inf if frame.band == 0 else frame.v_lo + cfg.seam_m
        return u_lo, u_hi, v_lo, v_hi

    def _owns(self, frame: FrameTarget, p: np.ndarray) -> bool:
        """Whether this frame traces a find at p (drive coordinates). Against a neighbour planned before it
        (left, or the other band at this position), the seam is where that neighbour's limit lies on the wall,
        by both frames' localised poses, less their 3-σ error: the robot stops a centimetre off its command,
        so limits in each frame's own coordinates would leave finds in a gap that neither frame traces."""
        u_lo, u_hi, v_lo, v_hi = self._own_limits(frame)
        if frame.frame_id not in self._placed:  # not localised (driven without run_scan): each frame's own limits
            return bool(u_lo <= p[0] <= u_hi and v_lo <= p[1] <= v_hi)
        d = self.drives
        margin = 3.0 * math.sqrt(2.0) * (d.loc_sigma_m + d.loc_sigma_rad * d.travel_v_m)
        wall_p = frame_pose_apply(self._pose(frame), p)
        for other, pose in self._placed.values():
            left = other.band == frame.band and other.column == frame.column - 1
            stacked = other.column == frame.column and abs(other.band - frame.band) == 1
            if not (left or stacked):
                continue
            q = frame_pose_inverse(pose, wall_p)[0]  # p in the neighbour's drive coordinates
            if left:
                u_lo = -math.inf  # the seam is the left neighbour's limit on the wall
                if q[0] <= self._own_limits(other)[1] - margin:
                    return False
            else:
                o_lo, o_hi = self._own_limits(other)[2:]
                if other.band < frame.band:
                    v_lo = -math.inf
                    if q[1] <= o_hi - margin:
                        return False
                else:
                    v_hi = math.inf
                    if q[1] >= o_lo + margin:
                        return False
        return bool(u_lo <= p[0] <= u_hi and v_lo <= p[1] <= v_hi)

    def frame_stages(self, frame: FrameTarget) -> StageGenerator:
        self._frame = frame
        self._searched = {}  # the seams, and so the searches, are the frame's
        coarse = self._coarse(frame)
        self.ordered_by[frame.frame_id] = {}  # a frame's plan is made afresh (estimates, resumes)
        if self.priors is not None:
            coarse = self._zones_first(frame, coarse, self.priors)
        results = yield coarse
        yield from self._trace(frame, coarse, _by_spec(coarse, results))

    def _zones_first(self, frame: FrameTarget, coarse: list[PassSpec], priors: Priors) -> list[PassSpec]:
        """The same coarse passes, those along a zone first, then those across one, then the rest; within each,
        nearest end next from where the drives are (they home at every frame), so rapids stay short."""
        pose = (frame.x_m, frame.y_m, 0.0)  # commanded: the zones are centimetres wide, the robot's error mm
        scored = []
        for spec in coarse:
            a, b = frame_pose_apply(pose, np.array([spec.start_uv, spec.end_uv]))
            hits = priors.pass_hits(a, b)
            scored.append((max((score for _, score in hits), default=0.0), hits, spec))
        ordered: list[PassSpec] = []
        at = np.zeros(2)
        for level in sorted({score for score, _, _ in scored}, reverse=True):
            rest = [(hits, spec) for score, hits, spec in scored if score == level]
            while rest:
                k = min(range(len(rest)), key=lambda i: min(math.dist(rest[i][1].start_uv, at),
                                                             math.dist(rest[i][1].end_uv, at)))
                hits, spec = rest.pop(k)
                if math.dist(spec.end_uv, at) < math.dist(spec.start_uv, at):
                    spec = PassSpec(spec.frame_id, spec.stage, spec.axis, spec.end_uv, spec.start_uv)
                ordered.append(spec)
                at = np.array(spec.end_uv)
                if level > 0:
                    for name in {name for name, score in hits if score == level}:
                        self._count(frame, name, "coarse passes first")
        return ordered

    def _socket_searches(self, frame: FrameTarget, coarse: list[PassSpec], priors: Priors
                         ) -> list[tuple[str, list[PassSpec]]]:
        """[(socket name, a square of short passes around it and one across it)] for each known socket in the
        part of the frame it owns that no coarse pass came within SOCKET_NEAR_M of: what leaves the box crosses
        the square, the box itself the pass across."""
        pose = self._pose(frame)
        r = self.config.socket_search_half_m
        out = []
        for k, socket in enumerate(priors.sockets):
            c = [float(v) for v in frame_pose_inverse(pose, socket)[0]]
            if not (frame.u_lo <= c[0] <= frame.u_hi and frame.v_lo <= c[1] <= frame.v_hi
                    and self._owns(frame, np.array(c))):
                continue
            if any(distances_to_polyline(np.array([c]), np.array([p.start_uv, p.end_uv]))[0] <= SOCKET_NEAR_M
                   for p in coarse):
                continue  # a coarse pass saw the box or its cable's start: its finds are traced first anyway
            sides = [self._short(frame, "socket", "x", c[1] - r, c[0], r),
                     self._short(frame, "socket", "y", c[0] + r, c[1], r),
                     self._short(frame, "socket", "x", c[1] + r, c[0], r),
                     self._short(frame, "socket", "y", c[0] - r, c[1], r),
                     self._short(frame, "socket", "x", c[1], c[0], r)]  # and across the box itself
            square = [self._oriented(p) for p in sides if p is not None]
            if square:
                out.append((f"socket {k + 1}", square))
        return out

    def _find_channels(self, samples: Samples, axis: str) -> list[tuple[float, float, str]]:
        """[(position, height, channel)] of the strongest channel per object along a pass (see _peaks)."""
        return [(pos, height, channel) for pos, height, _, channel in self._peaks(samples, axis)]

    def _cross(self, frame: FrameTarget, q: np.ndarray, d: np.ndarray, half: float,
               stage: str = "trace") -> PassSpec | None:
        """A short pass across a course of direction d at q: along u for steep courses, along v for flat ones."""
        if abs(d[1]) >= abs(d[0]):
            return self._short(frame, stage, "x", float(q[1]), float(q[0]), half)
        return self._short(frame, stage, "y", float(q[0]), float(q[1]), half)

    def _fastener_passes(self, frame: FrameTarget, along: list[tuple[PassSpec, Samples]],
                         coarse: list[PassSpec]) -> list[PassSpec]:
        """A short pass across every bump of the inductive response along a stud or a traced course (a screw, a
        nail, a clamp: a point there is mapped only where two passes cross it), unless a coarse pass crosses
        it already. The bumps are found in additive units: on a steel stud the display is nearly saturated."""
        cfg = self.config
        rise = PeakConfig(min_height=cfg.fastener_min_rise, min_prominence=0.6 * cfg.fastener_min_rise,
                          min_distance_m=0.03)
        seen: list[np.ndarray] = []
        passes = []
        for spec, samples in along:
            a, b = np.array(spec.start_uv), np.array(spec.end_uv)
            d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
            uv = np.column_stack([samples["drive_u_m"], samples["drive_v_m"]])
            t = (uv - a) @ d
            # a coarse pass across the course through a bump crosses it already (one along it does not)
            across, fixed = ("x", 1) if abs(d[1]) >= abs(d[0]) else ("y", 0)
            for peak in detect_peaks(t, additive_units(INDUCTIVE.name, samples[INDUCTIVE.name]), rise):
                m = a + peak.position * d
                on_coarse = any(c.axis == across and abs(c.start_uv[fixed] - m[fixed]) < 0.01 for c in coarse)
                if on_coarse or any(float(np.linalg.norm(m - q)) < 0.02 for q in seen):
                    continue
                seen.append(m)
                spec_across = self._cross(frame, m, d, cfg.fastener_half_m, "point")
                if spec_across is not None:
                    passes.append(spec_across)
        return [self._oriented(p) for p in passes]

    def _crossing_points(self, spec: PassSpec, samples: Samples) -> list[tuple[np.ndarray, float, str]]:
        """Where objects cross a pass, in drive coordinates: [(uv, height, channel)]."""
        out = []
        for pos, height, channel in self._find_channels(samples, spec.axis):
            uv = np.array([pos, spec.start_uv[1]]) if spec.axis == "x" else np.array([spec.start_uv[0], pos])
            out.append((uv, height, channel))
        return out

    def _run_track(self, frame: FrameTarget, tr: _Track, chains: list[_Chain],
                   spawn: list[_Track], known: list[tuple[np.ndarray, float, str]]) -> StageGenerator:
        """Trace one end of a course outward, crossing by crossing, until it leaves the reach, ends or meets a
        traced course; at a junction every further branch is put on `spawn`. `known`: crossings the coarse
        passes measured already; one lying on the predicted course ahead is taken as the next crossing."""
        cfg = self.config
        if len(tr.chain.points) >= 3:  # the other end was traced first: its crossings give the direction here
            tr.fit_direction(cfg.position_sigma_m)
            tr.step = float(np.clip(0.3 * cfg.cross_half_m / max(tr.sigma, 1e-6), cfg.min_step_m, cfg.max_step_m))
        for _ in range(cfg.max_trace_stages):
            head = tr.head()
            if tr.ring:
                r = cfg.ring_half_m
                # an inductive course's square runs each side on past its corners by a crossing's half length:
                # one leaving near a corner is crossed clear of the pass's end (a deep pipe's peak is 4 cm
                # wide; a live cable's AC crest, about 2 cm, is clear of it already)
                half = r + (cfg.cross_half_m if tr.chain.channel == INDUCTIVE.name else 0.0)
                sides = [self._short(frame, "trace", "x", head[1] - r, head[0], half),
                         self._short(frame, "trace", "y", head[0] + r, head[1], half),
                         self._short(frame, "trace", "x", head[1] + r, head[0], half),
                         self._short(frame, "trace", "y", head[0] - r, head[1], half)]
                batch = [self._oriented(p) for p in sides if p is not None]
                results = yield batch
                tr.ring = False
                hits = [h for spec, (_, samples) in zip(batch, sorted(results.items()), strict=True)
                        for h in self._crossing_points(spec, samples)]
                hits = [h for h in hits if all(ch.distance(h[0]) > cfg.join_m * 1.5 for ch in chains)]
                if not hits:
                    tr.stop = "end"
                    return
                sigma = math.sqrt(2.0) * cfg.position_sigma_m / cfg.ring_half_m
                for k, (p, height, channel) in enumerate(hits):
                    d = (p - head) / max(float(np.linalg.norm(p - head)), 1e-9)
                    if k == 0:
                        tr.add(p, height)
                        tr.d, tr.sigma, tr.step = d, sigma, cfg.min_step_m
                    else:  # a junction: every branch is traced
                        chain = _Chain([head, p], [height, height], channel)
                        chains.append(chain)
                        spawn.append(_Track(chain, +1, d, cfg.min_step_m, sigma))
                continue
            step = tr.step
            free = self._known_ahead(tr, head, step, known, chains)
            if free is not None:  # a coarse pass crossed the course where it is predicted: no pass needed
                p, height, innovation = free
                self._advance(tr, p, height, innovation, float((p - head) @ tr.d))
                continue
            to_edge = self._to_edge(frame, head, tr.d, cfg.edge_margin_m)
            if to_edge < step:  # the course leaves the reach within this step: the following pass runs on to
                tr.stop = "edge"  # the edge (where its response falls, it is crossed there)
                tr.edge_point = head + max(to_edge, 0.0) * tr.d
                return
            q = head + step * tr.d
            if any(ch is not tr.chain and ch.near(q, tr.d, cfg.join_m) for ch in chains):
                tr.stop = "met"  # a course traced from another find: it joins there
                return
            half = cfg.cross_half_m + 3.0 * (cfg.position_sigma_m + step * tr.sigma)
            spec = self._cross(frame, q, tr.d, half)
            if spec is None:
                tr.stop = "edge"
                return
            spec = self._oriented(spec)
            results = yield [spec]
            hits = self._crossing_points(spec, next(iter(results.values())))
            near = [h for h in hits if float(np.linalg.norm(h[0] - q)) < 0.8 * half]
            if near:
                p, height, _ = min(near, key=lambda h: float(np.linalg.norm(h[0] - q)))
                self._advance(tr, p, height, float(np.linalg.norm(p - q)), step)
            elif step > 1.5 * cfg.min_step_m:
                tr.step = 0.5 * step  # the object ends or bends before q: look nearer
            else:
                tr.ring = True  # ends or turns within min_step: look around the head for where it goes
        tr.stop = "stages"

    def _advance(self, tr: _Track, p: np.ndarray, height: float, innovation: float, step: float) -> None:
        """Add crossing p (innovation: its distance from the prediction) and set the next step from the course's
        direction certainty."""
        cfg = self.config
        tr.add(p, height)
        tr.fit_direction(cfg.position_sigma_m)
        grow = cfg.step_growth if innovation < cfg.join_m else 0.5  # off course: a bend may follow
        limit = 0.3 * cfg.cross_half_m / max(tr.sigma, 1e-6)  # the course stays inside the window
        tr.step = float(np.clip(min(step * grow, limit), cfg.min_step_m, cfg.max_step_m))

    def _known_ahead(self, tr: _Track, head: np.ndarray, step: float, known: list[tuple[np.ndarray, float, str]],
                     chains: list[_Chain]) -> tuple[np.ndarray, float, float] | None:
        """(point, height, innovation) of the coarse crossing that lies on the predicted course up to a step
        ahead (the nearest to the course), or None."""
        cfg = self.config
        best = None
        for p, height, _ in known:
            v = p - head
            along = float(v @ tr.d)
            if not 0.5 * cfg.min_step_m < along <= max(cfg.free_reach * step + 0.02, cfg.max_step_m):
                continue
            lateral = float(np.linalg.norm(v - along * tr.d))
            half = cfg.cross_half_m + 3.0 * (cfg.position_sigma_m + along * tr.sigma)
            if lateral >= 0.8 * half or (best is not None and lateral >= best[2]):
                continue
            if any(p is q for ch in chains for q in ch.points):
                continue  # a crossing of a course traced already (this one's or another's)
            best = (p, height, lateral)
        return best

    def _to_edge(self, frame: FrameTarget, p: np.ndarray, d: np.ndarray, margin: float) -> float:
        """Distance from p along d to the edge of the reach (less the margin) it runs towards; negative if p is
        beyond the reach. A course found within the margin of an edge (in the frames' overlap, cut by the edge)
        runs along it: for that edge the reach itself is the limit."""
        lo = np.array([frame.u_lo, frame.v_lo])
        hi = np.array([frame.u_hi, frame.v_hi])
        lo = np.where(p <= lo + margin + 1e-9, lo, lo + margin)
        hi = np.where(p >= hi - margin - 1e-9, hi, hi - margin)
        t = math.inf
        for i in range(2):
            if d[i] > 1e-12:
                t = min(t, (hi[i] - p[i]) / d[i])
            elif d[i] < -1e-12:
                t = min(t, (lo[i] - p[i]) / d[i])
        return float(t)

    def _weak_finds(self, frame: FrameTarget, coarse: list[PassSpec], by_spec: dict[PassSpec, Samples],
                    known: list[tuple[np.ndarray, float, str]], chains: list[_Chain]) -> list[PassSpec]:
        """A pass across every inductive peak on a coarse pass too weak to trace (point_min_height up to the
        tracing threshold) that no traced course or stronger find explains: a screw or nail several centimetres
        off the pass shows only this weakly, and only a pass across places it."""
        cfg = self.config
        weak_cfg = PeakConfig(min_height=cfg.point_min_height, min_prominence=0.6 * cfg.point_min_height)
        passes = []
        for spec in coarse:
            samples = by_spec[spec]
            coord, lag = self._along(samples, spec.axis)
            fixed = spec.start_uv[1] if spec.axis == "x" else spec.start_uv[0]
            for peak in detect_peaks(coord, samples[INDUCTIVE.name], weak_cfg):
                if peak.height >= self.peaks.min_height:
                    continue  # a find the tracing took
                pos = peak.position - lag
                p = np.array([pos, fixed]) if spec.axis == "x" else np.array([fixed, pos])
                if (any(float(np.linalg.norm(p - q)) < 0.03 for q, _, _ in known)
                        or any(ch.distance(p) < 0.03 for ch in chains) or not self._owns(frame, p)):
                    continue
                across = self._short(frame, "point", "y" if spec.axis == "x" else "x", pos, fixed,
                                     cfg.point_half_m)
                if across is not None:
                    passes.append(across)
        return [self._oriented(p) for p in passes]

    def _studs(self, frame: FrameTarget, coarse: list[PassSpec], by_spec: dict[PassSpec, Samples]
               ) -> list[PassSpec]:
        """Fastener passes: one vertical pass along each stud (a wide capacitive peak on two or more horizontal
        coarse passes at the same u, no inductive or AC find there), over the rows it was seen on and one row
        spacing beyond."""
        cfg = self.config
        wide = PeakConfig(min_height=cfg.stud_min_height, min_prominence=0.5 * cfg.stud_min_height)
        found: list[tuple[float, float]] = []  # (u, v)
        for spec in coarse:
            if spec.axis != "x":
                continue
            samples = by_spec[spec]
            metal = [pos for pos, _, _ in self._find_channels(samples, "x")]
            for peak in detect_peaks(samples["drive_u_m"], samples[CAPACITIVE.name], wide):
                if peak.width >= cfg.stud_min_width_m and all(abs(peak.position - m) > 0.03 for m in metal):
                    found.append((peak.position, spec.start_uv[1]))
        found.sort()
        passes = []
        while found:
            u0 = found[0][0]
            group = [f for f in found if abs(f[0] - u0) < 0.02]
            found = [f for f in found if abs(f[0] - u0) >= 0.02]
            u = float(np.mean([g[0] for g in group]))
            if len(group) < 2 or not self._owns(frame, np.array([u, float(np.mean([g[1] for g in group]))])):
                continue
            lo = max(frame.v_lo, min(g[1] for g in group) - cfg.coarse_row_spacing_m)
            hi = min(frame.v_hi, max(g[1] for g in group) + cfg.coarse_row_spacing_m)
            spec = self._short(frame, "stud", "y", u, 0.5 * (lo + hi), 0.5 * (hi - lo))
            if spec is not None:
                passes.append(spec)
        return passes

    def _oriented(self, spec: PassSpec) -> PassSpec:
        """The pass run from its end nearer the drives' position (short rapids); remembers where it ends."""
        a, b = np.array(spec.start_uv), np.array(spec.end_uv)
        if np.linalg.norm(b - self._at) < np.linalg.norm(a - self._at):
            spec = PassSpec(spec.frame_id, spec.stage, spec.axis, spec.end_uv, spec.start_uv)
        self._at = np.array(spec.end_uv)
        return spec

    def _trace(self, frame: FrameTarget, coarse: list[PassSpec], by_spec: dict[PassSpec, Samples]
               ) -> StageGenerator:
        """(2) confirming, (3) tracing and (4) following; see AdaptivePlanner and STOPPING_RULE."""
        cfg = self.config
        base = {c: float(np.percentile(np.concatenate([by_spec[p][c] for p in coarse]), 20))
                for c in (ch.name for ch in LINE_PEAKS)}
        chains: list[_Chain] = []
        tracks: list[_Track] = []
        known: list[tuple[np.ndarray, float, str]] = []  # the coarse passes' crossings, in drive coordinates
        seeds: list[tuple[np.ndarray, PassSpec, float, str | None]] = []  # (find, its pass, position, zone)
        pose = self._pose(frame)

        def add_finds(spec: PassSpec, samples: Samples) -> None:
            for p, height, channel in self._crossing_points(spec, samples):
                known.append((p, height, channel))
                # a find on a horizontal pass lies on a course running roughly vertically, and vice versa
                zone = None if self.priors is None else self.priors.point_hit(
                    frame_pose_apply(pose, p)[0], "y" if spec.axis == "x" else "x")
                seeds.append((p, spec, float(p[0] if spec.axis == "x" else p[1]), zone))

        for spec in coarse:
            add_finds(spec, by_spec[spec])
        self._at = np.array(coarse[-1].end_uv)
        if self.priors is not None:  # a known socket no coarse pass came near is looked at before any tracing
            for name, square in self._socket_searches(frame, coarse, self.priors):
                results = yield square
                self._count(frame, name, "searched")
                for spec, samples in _by_spec(square, results).items():
                    add_finds(spec, samples)
        while seeds:
            # zone first (priors), then nearest, and one object traced to its ends before the next: short
            # rapids, and the finds of the same object on other coarse passes are then on a traced course
            k = min(range(len(seeds)), key=lambda i: (seeds[i][3] is None,
                                                      float(np.linalg.norm(seeds[i][0] - self._at))))
            p0, spec, pos, zone = seeds.pop(k)
            if not self._owns(frame, p0):
                continue  # the neighbouring frame traces it
            if any(ch.distance(p0) < 2 * cfg.join_m for ch in chains):
                continue  # the same object, already traced from another find
            # (2) confirm: a parallel short pass beside the find gives the object's local direction
            fixed = spec.start_uv[1] if spec.axis == "x" else spec.start_uv[0]
            limit = frame.v_hi if spec.axis == "x" else frame.u_hi
            offset = cfg.confirm_offset_m if fixed + cfg.confirm_offset_m <= limit else -cfg.confirm_offset_m
            short = self._short(frame, "confirm", spec.axis, fixed + offset, pos, cfg.confirm_half_length_m)
            if short is None:
                continue
            short = self._oriented(short)
            results = yield [short]
            near = [c for c in self._crossing_points(short, next(iter(results.values())))
                    if abs(c[0][0 if spec.axis == "x" else 1] - pos) < cfg.confirm_half_length_m * 0.8]
            if not near:  # a point object (screw, nail), an object's end or an object parallel to the pass:
                # a short pass across the find in the other axis, so that a point response is seen in both
                other = "y" if spec.axis == "x" else "x"
                across = self._short(frame, "point", other, pos, fixed, cfg.point_half_m)
                if across is not None:
                    yield [self._oriented(across)]
                continue
            p1, h1, ch1 = min(near, key=lambda c: float(np.linalg.norm(c[0] - p0)))
            d = (p1 - p0) / max(float(np.linalg.norm(p1 - p0)), 1e-9)
            chain = _Chain([p0, p1], [h1, h1], ch1, zone)
            chains.append(chain)
            if zone is not None:
                self._count(frame, zone, "objects traced first")
            sigma = math.sqrt(2.0) * cfg.position_sigma_m / float(np.linalg.norm(p1 - p0))
            step = float(np.clip(0.3 * cfg.cross_half_m / sigma, cfg.min_step_m, cfg.max_step_m))  # see _advance
            queue = [_Track(chain, +1, d, step, sigma), _Track(chain, -1, -d, step, sigma)]
            while queue:
                tr = queue.pop(0)
                tracks.append(tr)
                yield from self._run_track(frame, tr, chains, queue, known)
        for tr in tracks:
            tr.stop = tr.stop or "stages"
        weak = self._weak_finds(frame, coarse, by_spec, known, chains)
        if weak:
            yield weak
        # studs: a fastener pass along the centre of every wide capacitive response that no metal explains,
        # found on two coarse rows or more
        along: list[tuple[PassSpec, Samples]] = []  # passes along studs and courses: where fasteners show
        studs = [self._oriented(p) for p in self._studs(frame, coarse, by_spec)]
        if studs:
            results = yield studs
            along += zip(studs, [results[i] for i in sorted(results)], strict=True)
        # (4) following: a pass along every traced stretch; where the response falls, cross there and follow again
        for chain in chains:
            course = list(chain.points)
            for tr in tracks:  # where tracing stopped short of the edge, the following pass runs on to it
                if tr.chain is chain and tr.edge_point is not None:
                    end = course[-1] if tr.end > 0 else course[0]
                    if float(np.linalg.norm(tr.edge_point - end)) > 1e-4:
                        course = [*course, tr.edge_point] if tr.end > 0 else [tr.edge_point, *course]
            chain.segments = [[a, b, None] for a, b in itertools.pairwise(_straight_runs(course,
                                                                                       cfg.position_sigma_m))]
        for round_ in range(cfg.follow_rounds + 1):
            todo = []
            for ch in chains:
                for seg in ch.segments:
                    if seg[2] is None and float(np.linalg.norm(seg[1] - seg[0])) < cfg.follow_min_m:
                        seg[2] = 1.0  # the crossings at its ends cover it
                    elif seg[2] is None:
                        todo.append((ch, seg))
            if not todo:
                break
            follow = []
            rest = list(todo)
            todo = []
            while rest:  # nearest stretch next
                k = min(range(len(rest)), key=lambda i: min(float(np.linalg.norm(rest[i][1][0] - self._at)),
                                                            float(np.linalg.norm(rest[i][1][1] - self._at))))
                item = rest.pop(k)
                todo.append(item)
                follow.append(self._oriented(PassSpec(frame.frame_id, "follow", "xy", _uv(item[1][0]),
                                                      _uv(item[1][1]))))
            results = yield follow
            got = [results[i] for i in sorted(results)]
            along += zip(follow, got, strict=True)
            cross: list[PassSpec] = []
            cross_owner: list[tuple[_Chain, list[Any], np.ndarray, float, float]] = []
            for (chain, seg), samples in zip(todo, got, strict=True):
                channel = chain.channel
                level = base[channel] + cfg.follow_min_share * float(np.median(chain.heights))
                a, b = seg[0], seg[1]
                length = max(float(np.linalg.norm(b - a)), 1e-9)
                d = (b - a) / length
                t = (np.column_stack([samples["drive_u_m"], samples["drive_v_m"]]) - a) @ d
                ok = samples[channel] >= level
                # where a course ends, the response falls within a footprint of its end: not a departure
                ok |= (t < cfg.end_tolerance_m) & (seg is chain.segments[0])
                ok |= (t > length - cfg.end_tolerance_m) & (seg is chain.segments[-1])
                seg[2] = float(ok.mean())
                if ok.all() or round_ == cfg.follow_rounds:
                    continue
                bad = np.flatnonzero(~ok)
                k = int(bad[len(bad) // 2])
                m = np.array([samples["drive_u_m"][k], samples["drive_v_m"][k]])
                spec = self._cross(frame, m, d, cfg.cross_half_m + 0.03)
                if spec is not None:
                    cross.append(self._oriented(spec))
                    cross_owner.append((chain, seg, m, float(np.clip(t[bad[0]] - 0.01, 0.0, length)),
                                        float(np.clip(t[bad[-1]] + 0.01, 0.0, length))))
            if not cross:
                break
            results = yield cross
            got = [results[i] for i in sorted(results)]
            for (chain, seg, m, t_lo, t_hi), spec, samples in zip(cross_owner, cross, got, strict=True):
                hits = self._crossing_points(spec, samples)
                if not hits:
                    continue  # the object is not there: that stretch stays inferred
                p, height, _ = min(hits, key=lambda h: float(np.linalg.norm(h[0] - m)))
                a, b = seg[0], seg[1]
                d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
                # the stretches before and after the fall were followed on the object: only the fall is redone
                parts = []
                if t_lo > cfg.follow_min_m:
                    parts.append([a, a + t_lo * d, 1.0])
                g1 = a + t_lo * d if t_lo > cfg.follow_min_m else a
                g2 = a + t_hi * d if float(np.linalg.norm(b - a)) - t_hi > cfg.follow_min_m else b
                parts += [[g1, p, None], [p, g2, None]]
                if g2 is not b:
                    parts.append([g2, b, 1.0])
                i = next(k for k, other in enumerate(chain.segments) if other is seg)
                chain.segments[i:i + 1] = parts
                chain.heights.append(height)
        points = self._fastener_passes(frame, along, coarse)
        if points:
            yield points
        for k, chain in enumerate(chains):
            length = sum(float(np.linalg.norm(b - a)) for a, b, _ in chain.segments)
            measured = sum(float(np.linalg.norm(b - a)) * (s or 0.0) for a, b, s in chain.segments)
            ends = sorted(t.stop for t in tracks if t.chain is chain)
            self.report.append({"frame_id": frame.frame_id, "object": k, "channel": chain.channel,
                                "length_m": round(length, 3), "measured_share": round(measured / length, 3)
                                if length > 0 else 0.0, "ends": ends, "first_in": chain.zone})

@dataclass
class _Chain:
    """One traced object in a frame: crossing points in drive coordinates along its course, in order."""

    points: list[np.ndarray]
    heights: list[float]  # peak heights of its crossings (display units over the pass baseline)
    channel: str  # the channel that saw it best: the following passes are judged in it
    zone: str | None = None  # the zone or socket its first find lay in: why it was traced first (priors)
    segments: list[list[Any]] = field(default_factory=list)  # [a, b, share of the follow pass that saw it]

    def distance(self, p: np.ndarray) -> float:
        return _distance_to_polyline(p, self.points)[0]

    def near(self, p: np.ndarray, d: np.ndarray, radius: float) -> bool:
        """p lies within radius of this course and d runs along it (not a crossing at an angle)."""
        dist, seg = _distance_to_polyline(p, self.points)
        return dist < radius and (seg is None or abs(float(seg @ d)) > 0.9)


@dataclass
class _Track:
    """One end of a chain being traced outward."""

    chain: _Chain
    end: int  # +1: the chain's last point is the head, -1: its first
    d: np.ndarray  # unit direction of travel
    step: float  # distance to the next crossing, metres
    sigma: float  # 1-σ uncertainty of the direction, rad
    stop: str = ""  # why tracing stopped: edge, end, met, stages
    ring: bool = False
    ring_done: bool = False
    pending: tuple[np.ndarray, float, float] | None = None
    edge_point: np.ndarray | None = None  # where the course leaves the reach, if tracing stopped short of it

    def head(self) -> np.ndarray:
        return self.chain.points[-1] if self.end > 0 else self.chain.points[0]

    def add(self, p: np.ndarray, height: float) -> None:
        if self.end > 0:
            self.chain.points.append(p)
        else:
            self.chain.points.insert(0, p)
        self.chain.heights.append(height)

    def fit_direction(self, position_sigma_m: float, n: int = 3) -> None:
        """Direction and its σ from the last n crossings (a least-squares slope over their span)."""
        pts = np.array(self.chain.points[-n:] if self.end > 0 else self.chain.points[:n][::-1])
        _, u = fit_line(pts)
        d = u if float(u @ self.d) >= 0 else -u
        span = float(np.linalg.norm(pts[-1] - pts[0]))
        self.d = d
        self.sigma = position_sigma_m * math.sqrt(12.0 / len(pts)) / max(span, 1e-3)


def _distance_to_polyline(p: np.ndarray, points: list[np.ndarray]) -> tuple[float, np.ndarray | None]:
    """(distance from p to the polyline, unit direction of the nearest segment or None for a single point)."""
    dist, seg = nearest_segments(p, np.array(points))
    if len(points) == 1:
        return float(dist[0]), None
    ab = points[seg[0] + 1] - points[seg[0]]
    return float(dist[0]), ab / max(float(np.linalg.norm(ab)), 1e-12)


def _straight_runs(points: list[np.ndarray], tolerance_m: float) -> list[np.ndarray]:
    """The crossing points that start and end straight runs: one following pass per run, not per crossing."""
    keep = [points[0]]
    i = 0
    while i < len(points) - 1:
        j = i + 1
        while j + 1 < len(points) and all(
                _distance_to_polyline(points[k], [points[i], points[j + 1]])[0] <= tolerance_m
                for k in range(i + 1, j + 1)):
            j += 1
        keep.append(points[j])
        i = j
    return keep


def _uv(p: np.ndarray) -> tuple[float, float]:
    return round(float(p[0]), 6), round(float(p[1]), 6)  # µm: exact on the G-code wire


def _line_spec(passes: list[PassSpec], axis: str, fixed: float) -> PassSpec | None:
    for p in passes:
        if p.axis == axis and abs((p.start_uv[1] if axis == "x" else p.start_uv[0]) - fixed) < 1e-9:
            return p
    return None


def _by_spec(passes: list[PassSpec], results: dict[int, Samples]) -> dict[PassSpec, Samples]:
    """Pair each spec with its samples; results are keyed by pass id in yield order."""
    ids = sorted(results)
    return dict(zip(passes, (results[i] for i in ids), strict=True))


def check_planner_version(plan: dict[str, Any], source: str = "plan", logged: bool = False) -> None:
    """InputError unless an adaptive plan's recorded planner version is this one's (a log's plan without one
    was made by version 1); a new plan's options need not name it."""
    version = plan.get("planner_version", 1 if logged else ADAPTIVE_PLANNER_VERSION)
    if version != ADAPTIVE_PLANNER_VERSION:
        raise InputError(f"{source}: planned by adaptive planner version {version}; this arproj plans version "
                         f"{ADAPTIVE_PLANNER_VERSION} (passes across fasteners, seams by the robot's "
                         "localisation, DIN 18015-3 priors), which would lay other passes",
                         "finish the scan with the arproj that started it, or start a new log")


def make_planner(kind: str, wall: Wall, drives: DriveConfig, hysteresis_m: float = 0.003,
                 options: dict[str, Any] | None = None) -> DensePlanner | AdaptivePlanner:
    """A planner by name ('dense' or 'adaptive') with optional parameters (as recorded in a log's meta)."""
    options = {k: v for k, v in (options or {}).items() if k != "kind"}
    if kind == "dense":
        return DensePlanner(wall, drives, **options)
    if kind == "adaptive":
        check_planner_version(options)
        options.pop("planner_version", None)
        given: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in options.items()}
        cfg = AdaptiveConfig(**given)
        return AdaptivePlanner(wall, drives, hysteresis_m, cfg)
    raise InputError(f"plan = {kind!r}: unknown plan", "use dense or adaptive")
