"""Hard-case walls for benchmarks: the layouts that trip up a wall-scanning mapper, in the `arproj-wall/1` format.

Each wall (2.5 m x 2.0 m) combines two to four of the cases in `HARD_CASES` with a few ordinary straight runs;
its name says which, e.g. "hard-04 detour between coarse rows + bends and elbows + filled plastic pipe":

- bends and elbows: pipes (and a cable) turning by 90° (L- and Z-shapes) and by 45° (offsets, elbows);
- detour between coarse rows: a vertical run that leaves its course by 9-11 cm over a 20-40 cm long path and
  returns, entirely between two horizontal rows y = k·0.25 m (the adaptive planner's coarse passes, 25 cm
  apart from the wall's bottom edge), so the coarse passes see a straight line;
- junction and dead ends at socket boxes: three or four cables ending at the edges of a junction box (a thin
  steel plate 6-7 cm square) in a T or a star, their far ends at socket boxes where a single cable ends;
- X crossing of a pipe and a cable (perpendicular or oblique, the cable in front);
- parallel cables 5 cm apart, centre to centre;
- a pipe 5 cm deep beside a shallow (1.5-3 cm) one;
- filled plastic pipe: invisible to the inductive and AC channels, seen only by the capacitive one;
- wood and steel studs (4.5-6 cm wide, full height) with nails or screws on their centre line every 30-40 cm;
- loose screws and nails away from everything else;
- cavities (rectangles and L-shapes) behind drywall;
- live and dead cables side by side.

Object ids read "<group>-<role>" (e.g. "junction1-cable-up"): objects of one group belong to one case and may
touch; objects of different groups keep at least `MIN_GAP_M` apart (centre lines, outlines and points).
Walls with studs or cavities are drywall; the others cycle through brick, concrete and aerated concrete.
Every wall is built from a dict through `wall_from_dict`, so it passes the same checks as a wall file.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, partial
from typing import Any

import numpy as np

from geometry.polyline import densify, distances_to_polyline
from scanner.sensor_model import points_in_polygon
from scanner.wall import FORMAT, Wall, wall_from_dict

HARD_CASES: tuple[str, ...] = (
    "bends and elbows",
    "detour between coarse rows",
    "junction and dead ends at socket boxes",
    "X crossing of a pipe and a cable",
    "parallel cables 5 cm apart",
    "pipe 5 cm deep",
    "filled plastic pipe",
    "wood stud with fasteners",
    "steel stud with fasteners",
    "loose screws and nails",
    "cavity behind drywall",
    "live and dead cables",
)
(BENDS, DETOUR, JUNCTION, CROSSING, PARALLEL, DEEP_PIPE, PLASTIC_PIPE, WOOD_STUD, STEEL_STUD, LOOSE_FASTENERS,
 CAVITY, LIVE_AND_DEAD) = HARD_CASES

WALL_WIDTH_M = 2.5
WALL_HEIGHT_M = 2.0
COARSE_ROW_SPACING_M = 0.25  # AdaptivePlanner's default coarse_row_spacing_m
MIN_GAP_M = 0.08  # between objects of different groups
PARALLEL_PITCH_M = 0.05
DEEP_PIPE_DEPTH_M = 0.05
BOARD_DEPTH_M = 0.0125  # behind a 12.5 mm plasterboard
MASONRY = ("brick", "concrete", "aerated_concrete")

_PLACEMENT_TRIES = 200  # candidate draws per case group before the wall is started again
_ORDINARY_TRIES = 40  # an ordinary run is left out if it finds no room in this many draws
_WALL_RESTARTS = 40

_Size = tuple[float, float]
_Group = list[dict[str, Any]]
_Builder = Callable[[np.random.Generator, _Size], _Group]


# ---------------------------------------------------------------------------------------------- object dicts
def _coords(points: Any) -> list[list[float]]:
    # 0.1 mm rounding keeps files short; it moves a 5 cm pitch or a 45° angle by far less than any tolerance
    return [[round(float(x), 4), round(float(y), 4)] for x, y in np.asarray(points, dtype=np.float64)]


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _metal_pipe(rng: np.random.Generator, role: str, points: Any, depth_m: float | None = None) -> dict[str, Any]:
    return {"kind": "pipe", "id": role, "points_m": _coords(points),
            "depth_m": round(depth_m if depth_m is not None else _u(rng, 0.015, 0.03), 4),
            "material": str(rng.choice(["copper", "copper", "steel"])),
            "diameter_m": float(rng.choice([0.012, 0.015, 0.018, 0.022])), "water_filled": bool(rng.random() < 0.8)}


def _plastic_pipe_dict(rng: np.random.Generator, role: str, points: Any, depth_m: float) -> dict[str, Any]:
    return {"kind": "pipe", "id": role, "points_m": _coords(points), "depth_m": round(depth_m, 4),
            "material": "plastic", "diameter_m": float(rng.choice([0.016, 0.02, 0.025])), "water_filled": True}


def _cable(rng: np.random.Generator, role: str, points: Any, live: bool = True) -> dict[str, Any]:
    # live unless the case asks for a dead one, so "live and dead cables" is in a wall's name whenever it holds
    return {"kind": "cable", "id": role, "points_m": _coords(points), "depth_m": round(_u(rng, 0.01, 0.03), 4),
            "live": live, "diameter_m": 0.008}


def _line(rng: np.random.Generator, kind: str, role: str, points: Any) -> dict[str, Any]:
    return _metal_pipe(rng, role, points) if kind == "pipe" else _cable(rng, role, points)


def _box(rng: np.random.Generator, role: str, centre: Any, side_m: float) -> dict[str, Any]:
    """A socket or junction box: its steel is what the scanner sees, modelled as a thin square plate."""
    cx, cy = centre
    h = side_m / 2
    return {"kind": "plate", "id": role, "outline_m": _coords([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h],
                                                               [cx - h, cy + h]]),
            "depth_m": round(_u(rng, 0.015, 0.025), 4), "material": "steel", "thickness_m": 0.001}


def _fastener(rng: np.random.Generator, kind: str, role: str, x: float, y: float) -> dict[str, Any]:
    return {"kind": kind, "id": role, "points_m": _coords([[x, y]]), "depth_m": round(_u(rng, 0.002, 0.006), 4),
            "diameter_m": 0.004 if kind == "screw" else 0.003, "length_m": float(rng.choice([0.035, 0.045]))}


def _mirror(points: Any, size: _Size, flip_x: bool, flip_y: bool) -> np.ndarray:
    out = np.array(points, dtype=np.float64)
    if flip_x:
        out[:, 0] = size[0] - out[:, 0]
    if flip_y:
        out[:, 1] = size[1] - out[:, 1]
    return out


def _to_edge(start: np.ndarray, direction: np.ndarray, size: _Size) -> float:
    """Distance from start (inside the wall) along a unit direction to the wall's edge, metres."""
    reach = math.inf
    for axis, limit in enumerate(size):
        if direction[axis] > 1e-12:
            reach = min(reach, (limit - start[axis]) / direction[axis])
        elif direction[axis] < -1e-12:
            reach = min(reach, -start[axis] / direction[axis])
    return reach


# ---------------------------------------------------------------------------------------------- case builders
def _bend(rng: np.random.Generator, size: _Size, shape: str, kind: str = "pipe") -> _Group:
    """A run that changes direction: L90, Z90 (two opposite 90° turns), Z45 / offset45 (two 45° turns), elbow45."""
    w, h = size
    if shape == "L90":
        x, y = _u(rng, 0.3, w - 0.3), _u(rng, 0.3, h - 0.3)
        points = [[x, h], [x, y], [w, y]]
    elif shape == "Z90":
        x0, y = _u(rng, 0.2, w - 1.0), _u(rng, 0.4, h - 0.4)
        x1 = x0 + _u(rng, 0.3, 0.7)
        top = h if rng.random() < 0.5 else _u(rng, y + 0.3, h)
        points = [[x0, 0.0], [x0, y], [x1, y], [x1, top]]
    elif shape == "Z45":
        rise = _u(rng, 0.15, 0.35)
        y0, x1 = _u(rng, 0.2, h - 0.2 - rise), _u(rng, 0.5, w - 0.5 - rise)
        left, right = _u(rng, 0.0, x1 - 0.3), _u(rng, x1 + rise + 0.3, w)
        points = [[left, y0], [x1, y0], [x1 + rise, y0 + rise], [right, y0 + rise]]
    elif shape == "offset45":
        shift = _u(rng, 0.12, 0.25)
        x, y1 = _u(rng, 0.2, w - 0.2 - shift), _u(rng, 0.4, h - 0.4 - shift)
        points = [[x, 0.0], [x, y1], [x + shift, y1 + shift], [x + shift, h]]
    elif shape == "elbow45":
        run = _u(rng, 0.3, 0.6) / math.sqrt(2.0)
        x, y1 = _u(rng, 0.2, w - 0.2 - run), _u(rng, 0.3, h - 0.2 - run)
        points = [[x, 0.0], [x, y1], [x + run, y1 + run]]
    else:
        raise ValueError(f"unknown bend shape {shape!r}")
    return [_line(rng, kind, kind, _mirror(points, size, rng.random() < 0.5, rng.random() < 0.5))]


def _detour(rng: np.random.Generator, size: _Size, kind: str, jogs: str) -> _Group:
    """A vertical run that jogs aside by 9-11 cm between two coarse rows and comes back before the next one.

    jogs "square": 90° steps, 12-18 cm along the course offset (path 30-40 cm); "slanted": 45° steps
    (path 26-31 cm). The detour keeps at least 1 cm from both rows, so each row crosses the straight course.
    """
    w, h = size
    offset = _u(rng, 0.09, 0.11) if jogs == "square" else _u(rng, 0.09, 0.10)
    side = _sign(rng)
    x0 = _u(rng, 0.15, w - 0.15)
    if not 0.05 < x0 + side * offset < w - 0.05:
        side = -side
    bottom = 0.0 if rng.random() < 0.5 else 0.3  # to the floor or to a socket's height
    n_rows = round(h / COARSE_ROW_SPACING_M)
    first_row = 1 if bottom == 0.0 else 2
    row = int(rng.integers(first_row, n_rows - 1)) * COARSE_ROW_SPACING_M
    xs = x0 + side * offset
    if jogs == "square":
        flat = _u(rng, 0.12, 0.18)
        start = row + _u(rng, 0.01, COARSE_ROW_SPACING_M - 0.01 - flat)
        course = [[x0, start], [xs, start], [xs, start + flat], [x0, start + flat]]
    elif jogs == "slanted":
        flat = _u(rng, 0.01, 0.03)
        start = row + _u(rng, 0.01, COARSE_ROW_SPACING_M - 0.01 - flat - 2 * offset)
        course = [[x0, start], [xs, start + offset], [xs, start + offset + flat], [x0, start + 2 * offset + flat]]
    else:
        raise ValueError(f"unknown detour jogs {jogs!r}")
    points = [[x0, h], *course[::-1], [x0, bottom]]
    return [_line(rng, kind, kind, points)]


def _junction(rng: np.random.Generator, size: _Size, arms: tuple[str, ...],
              reach_m: tuple[float, float] = (0.2, 0.5)) -> _Group:
    """A junction box with cables ending at its edges; "up" feeds from the wall's top edge, the other arms end at
    socket boxes (dead ends). One arm (only) gives a single socket fed from above."""
    w, h = size
    side = _u(rng, 0.06, 0.07)
    centre = np.array([_u(rng, 0.45, w - 0.45), _u(rng, 0.45, h - 0.35)])
    group = [_box(rng, "box", centre, side)]
    directions = {"up": (0.0, 1.0), "down": (0.0, -1.0), "left": (-1.0, 0.0), "right": (1.0, 0.0)}
    for arm in arms:
        direction = np.array(directions[arm])
        start = centre + direction * side / 2
        if arm == "up":
            group.append(_cable(rng, f"cable-{arm}", [start, [start[0], h]]))
            continue
        socket_side = _u(rng, 0.06, 0.07)
        room = _to_edge(start, direction, size) - socket_side - 0.02
        length = min(_u(rng, *reach_m), room)
        end = start + direction * length
        group.append(_cable(rng, f"cable-{arm}", [start, end]))
        group.append(_box(rng, f"socket-{arm}", end + direction * socket_side / 2, socket_side))
    return group


def _crossing(rng: np.random.Generator, size: _Size, pipe_angle_deg: float, cable_angle_deg: float) -> _Group:
    """A pipe and a cable crossing in an X at the given directions (0° = horizontal)."""
    w, h = size
    centre = np.array([_u(rng, 0.5, w - 0.5), _u(rng, 0.5, h - 0.5)])
    group = []
    for kind, angle in (("pipe", pipe_angle_deg), ("cable", cable_angle_deg)):
        direction = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle))])
        ahead = min(_u(rng, 0.3, 0.7), _to_edge(centre, direction, size))
        behind = min(_u(rng, 0.3, 0.7), _to_edge(centre, -direction, size))
        points = [centre - behind * direction, centre + ahead * direction]
        if kind == "pipe":
            group.append(_metal_pipe(rng, "pipe", points, depth_m=_u(rng, 0.025, 0.035)))
        else:
            group.append({**_cable(rng, "cable", points), "depth_m": round(_u(rng, 0.01, 0.018), 4)})
    return group


def _parallel(rng: np.random.Generator, size: _Size, vertical: bool,
              lives: tuple[bool, ...] = (True, True)) -> _Group:
    """Cables side by side PARALLEL_PITCH_M apart (centre to centre), at least 60 cm long, ends staggered."""
    w, h = size
    spread = (len(lives) - 1) * PARALLEL_PITCH_M
    group = []
    if vertical:
        x0 = _u(rng, 0.2, w - 0.2 - spread)
        bottom = 0.0 if rng.random() < 0.4 else _u(rng, 0.1, h - 0.8)
        for i, live in enumerate(lives):
            x = x0 + i * PARALLEL_PITCH_M
            group.append(_cable(rng, f"cable-{i + 1}", [[x, h], [x, bottom + _u(rng, 0.0, 0.08)]], live))
    else:
        y0 = _u(rng, 0.15, h - 0.15 - spread)
        left = 0.0 if rng.random() < 0.3 else _u(rng, 0.0, 1.2)
        right = w if rng.random() < 0.3 else _u(rng, left + 0.7, min(w, left + 1.5))
        for i, live in enumerate(lives):
            y = y0 + i * PARALLEL_PITCH_M
            group.append(_cable(rng, f"cable-{i + 1}", [[left + _u(rng, 0.0, 0.08), y], [right, y]], live))
    points = [np.asarray(o["points_m"]) for o in group]
    flip_x, flip_y = rng.random() < 0.5, rng.random() < 0.5
    for obj, pts in zip(group, points, strict=True):
        obj["points_m"] = _coords(_mirror(pts, size, flip_x, flip_y))
    return group


def _deep_pipe(rng: np.random.Generator, size: _Size, vertical: bool, material: str = "metal") -> _Group:
    """A pipe DEEP_PIPE_DEPTH_M deep with a usual shallow pipe (1.5-3 cm) running alongside 12-30 cm away."""
    w, h = size
    gap = _u(rng, 0.12, 0.3) * _sign(rng)
    if vertical:
        x = _u(rng, 0.35, w - 0.35)
        top = h if rng.random() < 0.4 else _u(rng, 0.8, h)
        deep, shallow = [[x, 0.0], [x, top]], [[x + gap, 0.0], [x + gap, _u(rng, 0.6, top)]]
    else:
        y, length = _u(rng, 0.35, h - 0.35), _u(rng, 0.8, 2.0)
        left = _u(rng, 0.0, w - length)
        right = left + length
        deep, shallow = [[left, y], [right, y]], [[left + _u(rng, 0.0, 0.3), y + gap], [right, y + gap]]
    flip_x, flip_y = rng.random() < 0.5, rng.random() < 0.5
    deep_m, shallow_m = _mirror(deep, size, flip_x, flip_y), _mirror(shallow, size, flip_x, flip_y)
    if material == "plastic":
        deep_pipe = _plastic_pipe_dict(rng, "deep-pipe", deep_m, DEEP_PIPE_DEPTH_M)
    else:
        deep_pipe = _metal_pipe(rng, "deep-pipe", deep_m, DEEP_PIPE_DEPTH_M)
    shallow_pipe = _metal_pipe(rng, "shallow-pipe", shallow_m)
    return [deep_pipe, shallow_pipe]


def _plastic_pipe(rng: np.random.Generator, size: _Size, shape: str) -> _Group:
    """A water-filled plastic pipe: only the capacitive channel sees it."""
    w, h = size
    if shape == "vertical":
        x = _u(rng, 0.2, w - 0.2)
        points = [[x, 0.0], [x, _u(rng, 0.9, h)]]
    elif shape == "horizontal":
        y, length = _u(rng, 0.2, h - 0.2), _u(rng, 0.6, 1.6)
        left = _u(rng, 0.0, w - length)
        points = [[left, y], [left + length, y]]
    elif shape == "L90":
        x, y = _u(rng, 0.3, w - 0.3), _u(rng, 0.3, h - 0.3)
        points = [[x, 0.0], [x, y], [w if rng.random() < 0.5 else 0.0, y]]
    else:
        raise ValueError(f"unknown plastic pipe shape {shape!r}")
    return [_plastic_pipe_dict(rng, "plastic-pipe", _mirror(points, size, rng.random() < 0.5, False),
                               _u(rng, 0.02, 0.035))]


def _studs(rng: np.random.Generator, size: _Size, material: str, count: int, fastener: str) -> _Group:
    """Full-height studs 60-62.5 cm apart, boards fixed to them by fasteners on the centre line every 30-40 cm."""
    w, h = size
    width = _u(rng, 0.045, 0.06) if material == "wood" else _u(rng, 0.048, 0.05)
    spacing = float(rng.choice([0.6, 0.625]))
    x0 = _u(rng, 0.25, w - 0.25 - width - (count - 1) * spacing)
    group = []
    for i in range(count):
        x = x0 + i * spacing
        group.append({"kind": "stud", "id": f"stud-{i + 1}", "depth_m": BOARD_DEPTH_M, "material": material,
                      "outline_m": _coords([[x, 0.0], [x + width, 0.0], [x + width, h], [x, h]])})
        centre_x = round(x + width / 2, 4)  # exactly halfway between the rounded outline's sides
        y, n = _u(rng, 0.08, 0.25), 1
        while y < h - 0.05:
            group.append(_fastener(rng, fastener, f"stud-{i + 1}-{fastener}-{n}", centre_x, y))
            y, n = y + _u(rng, 0.30, 0.40), n + 1
    return group


def _cavity(rng: np.random.Generator, size: _Size, shape: str) -> _Group:
    """A hollow behind the board: a rectangle or an L (where a rectangle's corner was filled)."""
    w, h = size
    cw, ch = _u(rng, 0.2, 0.4), _u(rng, 0.2, 0.6)
    x0, y0 = _u(rng, 0.1, w - 0.1 - cw), _u(rng, 0.1, h - 0.1 - ch)
    outline: Any  # corner points: a list, or the mirrored array
    if shape == "rectangle":
        outline = [[x0, y0], [x0 + cw, y0], [x0 + cw, y0 + ch], [x0, y0 + ch]]
    elif shape == "L":
        nx, ny = _u(rng, 0.35, 0.65) * cw, _u(rng, 0.35, 0.65) * ch
        outline = [[x0, y0], [x0 + cw, y0], [x0 + cw, y0 + ny], [x0 + nx, y0 + ny], [x0 + nx, y0 + ch],
                   [x0, y0 + ch]]
        outline = _mirror(outline, size, rng.random() < 0.5, rng.random() < 0.5)
    else:
        raise ValueError(f"unknown cavity shape {shape!r}")
    return [{"kind": "cavity", "id": "cavity", "outline_m": _coords(outline), "depth_m": BOARD_DEPTH_M}]


def _loose_fastener(rng: np.random.Generator, size: _Size) -> _Group:
    w, h = size
    kind = "screw" if rng.random() < 0.5 else "nail"
    return [_fastener(rng, kind, kind, _u(rng, 0.05, w - 0.05), _u(rng, 0.05, h - 0.05))]


def _live_and_dead(rng: np.random.Generator, size: _Size, vertical: bool) -> _Group:
    """A live cable and a dead one (disconnected, or an abandoned run) 10-30 cm apart."""
    w, h = size
    gap = _u(rng, 0.1, 0.3)
    if vertical:
        x = _u(rng, 0.15, w - 0.15 - gap)
        runs = [[[x, h], [x, h - _u(rng, 0.6, 1.4)]], [[x + gap, h], [x + gap, h - _u(rng, 0.5, 1.2)]]]
    else:
        y, right = _u(rng, 0.15, h - 0.15 - gap), _u(rng, 1.2, w)
        runs = [[[right - _u(rng, 0.7, 1.2), y], [right, y]], [[right - _u(rng, 0.5, 1.0), y + gap], [right, y + gap]]]
    flip_x, flip_y = rng.random() < 0.5, rng.random() < 0.5
    dead = int(rng.integers(2))
    return [_cable(rng, "dead-cable" if i == dead else "live-cable", _mirror(run, size, flip_x, flip_y),
                   live=i != dead) for i, run in enumerate(runs)]


def _ordinary_run(rng: np.random.Generator, size: _Size) -> _Group:
    """A straight vertical or horizontal pipe or cable, in the installation zones."""
    w, h = size
    kind = "pipe" if rng.random() < 0.5 else "cable"
    if rng.random() < 0.6:
        x = _u(rng, 0.08, w - 0.08)
        points = [[x, h], [x, float(rng.choice([0.0, 0.3, 1.05]))]]
    else:
        y = _u(rng, 0.15, 0.45) if rng.random() < 0.5 else h - _u(rng, 0.15, 0.45)
        left = 0.0 if rng.random() < 0.6 else _u(rng, 0.0, 1.0)
        points = [[left, y], [w if rng.random() < 0.6 else _u(rng, left + 0.4, w), y]]
    return [_line(rng, kind, kind, points)]


# ---------------------------------------------------------------------------------------------- layout
class _Shape:
    """An object's geometry prepared for gap tests: samples along it and the path they are measured to."""

    def __init__(self, obj: dict[str, Any]) -> None:
        if "outline_m" in obj:
            self.polygon: np.ndarray | None = np.asarray(obj["outline_m"], dtype=np.float64)
            self.path = np.vstack([self.polygon, self.polygon[:1]])  # closed
        else:
            self.polygon = None
            self.path = np.asarray(obj["points_m"], dtype=np.float64)
        (self.x_min, self.y_min), (self.x_max, self.y_max) = self.path.min(axis=0), self.path.max(axis=0)

    @cached_property
    def samples(self) -> np.ndarray:
        # 1 cm sampling measured against the exact path of the other object: gaps come out within 1 mm
        return densify(self.path, 0.01) if len(self.path) > 1 else self.path

    def gap(self, other: _Shape) -> float:
        """Smallest distance between the two objects (0 if one overlaps an area), metres."""
        if (self.x_min - MIN_GAP_M > other.x_max or other.x_min - MIN_GAP_M > self.x_max
                or self.y_min - MIN_GAP_M > other.y_max or other.y_min - MIN_GAP_M > self.y_max):
            return math.inf  # far apart: skip the exact test
        for inner, area in ((self, other), (other, self)):
            if area.polygon is not None and points_in_polygon(inner.samples, area.polygon).any():
                return 0.0
        return min(float(distances_to_polyline(self.samples, other.path).min()),
                   float(distances_to_polyline(other.samples, self.path).min()))


def _inside(group: _Group, size: _Size) -> bool:
    return all(0.0 <= x <= size[0] and 0.0 <= y <= size[1]
               for obj in group for x, y in (obj["points_m"] if "points_m" in obj else obj.get("outline_m", ())))


def _place(builder: _Builder, rng: np.random.Generator, size: _Size, placed: list[_Shape],
           tries: int) -> _Group | None:
    """Draw the group until it lies inside the wall and MIN_GAP_M from everything placed; None if it never does."""
    for _ in range(tries):
        group = builder(rng, size)
        if not _inside(group, size):
            continue
        shapes = [_Shape(obj) for obj in group]
        if all(new.gap(old) >= MIN_GAP_M for new in shapes for old in placed):
            placed.extend(shapes)
            return group
    return None


@dataclass(frozen=True)
class _WallSpec:
    """Which cases a wall holds and the groups that make them: (tag, builder, how many), placed in this order
    (the widest first: they are the hardest to fit)."""

    cases: tuple[str, ...]
    groups: tuple[tuple[str, _Builder, int], ...]
    ordinary_runs: int = 1
    drywall: bool = False


_SPECS: tuple[_WallSpec, ...] = (
    _WallSpec((BENDS, DEEP_PIPE, LOOSE_FASTENERS), (
        ("bend", partial(_bend, shape="Z45"), 1),
        ("bend", partial(_bend, shape="L90"), 1),
        ("deep", partial(_deep_pipe, vertical=True), 1),
        ("loose", _loose_fastener, 4))),
    _WallSpec((DETOUR, PARALLEL, LIVE_AND_DEAD), (
        ("detour", partial(_detour, kind="cable", jogs="square"), 1),
        ("parallel", partial(_parallel, vertical=True), 1),
        ("livedead", partial(_live_and_dead, vertical=False), 1))),
    _WallSpec((JUNCTION, CROSSING), (
        ("junction", partial(_junction, arms=("up", "left", "right")), 1),
        ("crossing", partial(_crossing, pipe_angle_deg=0.0, cable_angle_deg=90.0), 1)), ordinary_runs=2),
    _WallSpec((STEEL_STUD, CAVITY, PLASTIC_PIPE), (
        ("studs", partial(_studs, material="steel", count=2, fastener="screw"), 1),
        ("cavity", partial(_cavity, shape="rectangle"), 1),
        ("plastic", partial(_plastic_pipe, shape="vertical"), 1)), drywall=True),
    _WallSpec((DETOUR, BENDS, PLASTIC_PIPE), (
        ("detour", partial(_detour, kind="pipe", jogs="slanted"), 1),
        ("bend", partial(_bend, shape="Z90"), 1),
        ("plastic", partial(_plastic_pipe, shape="horizontal"), 1))),
    _WallSpec((WOOD_STUD, LIVE_AND_DEAD, CAVITY), (
        ("studs", partial(_studs, material="wood", count=2, fastener="nail"), 1),
        ("livedead", partial(_live_and_dead, vertical=True), 1),
        ("cavity", partial(_cavity, shape="L"), 1)), drywall=True),
    _WallSpec((CROSSING, PARALLEL, DEEP_PIPE), (
        ("crossing", partial(_crossing, pipe_angle_deg=90.0, cable_angle_deg=0.0), 1),
        ("parallel", partial(_parallel, vertical=False), 1),
        ("deep", partial(_deep_pipe, vertical=False), 1))),
    _WallSpec((JUNCTION, BENDS, LOOSE_FASTENERS), (
        ("junction", partial(_junction, arms=("up", "down", "left", "right")), 1),
        ("bend", partial(_bend, shape="elbow45"), 1),
        ("loose", _loose_fastener, 5))),
    _WallSpec((STEEL_STUD, DETOUR, JUNCTION), (
        ("studs", partial(_studs, material="steel", count=3, fastener="screw"), 1),
        ("detour", partial(_detour, kind="cable", jogs="slanted"), 1),
        ("junction", partial(_junction, arms=("up", "down", "left"), reach_m=(0.12, 0.25)), 1)),
        ordinary_runs=0, drywall=True),
    _WallSpec((DEEP_PIPE, PLASTIC_PIPE, CROSSING, BENDS), (  # the plastic pipe is an L
        ("deep", partial(_deep_pipe, vertical=True), 1),
        ("plastic", partial(_plastic_pipe, shape="L90"), 1),
        ("crossing", partial(_crossing, pipe_angle_deg=45.0, cable_angle_deg=90.0), 1))),
    _WallSpec((PARALLEL, DETOUR, LOOSE_FASTENERS, LIVE_AND_DEAD), (
        ("parallel", partial(_parallel, vertical=True, lives=(True, False, True)), 1),
        ("detour", partial(_detour, kind="cable", jogs="square"), 1),
        ("loose", _loose_fastener, 3))),
    _WallSpec((WOOD_STUD, BENDS, PLASTIC_PIPE), (
        ("studs", partial(_studs, material="wood", count=2, fastener="screw"), 1),
        ("bend", partial(_bend, shape="offset45"), 1),
        ("plastic", partial(_plastic_pipe, shape="vertical"), 1)), drywall=True),
    _WallSpec((JUNCTION, PARALLEL, LIVE_AND_DEAD), (
        ("junction", partial(_junction, arms=("down", "left", "right")), 1),
        ("parallel", partial(_parallel, vertical=False), 1),
        ("livedead", partial(_live_and_dead, vertical=True), 1))),
    _WallSpec((BENDS, CROSSING, DEEP_PIPE), (
        ("crossing", partial(_crossing, pipe_angle_deg=135.0, cable_angle_deg=0.0), 1),
        ("bend", partial(_bend, shape="L90", kind="cable"), 1),
        ("bend", partial(_bend, shape="elbow45"), 1),
        ("deep", partial(_deep_pipe, vertical=True), 1))),
    _WallSpec((CAVITY, STEEL_STUD, LOOSE_FASTENERS, LIVE_AND_DEAD), (
        ("studs", partial(_studs, material="steel", count=1, fastener="screw"), 1),
        ("livedead", partial(_live_and_dead, vertical=True), 1),
        ("cavity", partial(_cavity, shape="L"), 1),
        ("cavity", partial(_cavity, shape="rectangle"), 1),
        ("loose", _loose_fastener, 3)), drywall=True),
    _WallSpec((DETOUR, DEEP_PIPE), (
        ("deep", partial(_deep_pipe, vertical=True), 1),
        ("detour", partial(_detour, kind="cable", jogs="square"), 1),
        ("detour", partial(_detour, kind="cable", jogs="slanted"), 1))),
    _WallSpec((JUNCTION, PLASTIC_PIPE), (
        ("junction", partial(_junction, arms=("up", "left", "right")), 1),
        ("socket", partial(_junction, arms=("up",)), 1),
        ("plastic", partial(_plastic_pipe, shape="horizontal"), 1))),
    _WallSpec((PARALLEL, BENDS, LIVE_AND_DEAD), (
        ("bend", partial(_bend, shape="Z45"), 1),
        ("parallel", partial(_parallel, vertical=False, lives=(True, False)), 1),
        ("livedead", partial(_live_and_dead, vertical=True), 1))),
    _WallSpec((WOOD_STUD, CAVITY, DETOUR), (
        ("studs", partial(_studs, material="wood", count=2, fastener="nail"), 1),
        ("detour", partial(_detour, kind="cable", jogs="square"), 1),
        ("cavity", partial(_cavity, shape="rectangle"), 1)), drywall=True),
    _WallSpec((CROSSING, JUNCTION, LOOSE_FASTENERS), (
        ("crossing", partial(_crossing, pipe_angle_deg=45.0, cable_angle_deg=90.0), 1),
        ("junction", partial(_junction, arms=("down", "left", "right")), 1),
        ("loose", _loose_fastener, 4))),
    _WallSpec((BENDS, DEEP_PIPE, PLASTIC_PIPE, PARALLEL), (
        ("deep", partial(_deep_pipe, vertical=False), 1),
        ("bend", partial(_bend, shape="Z90"), 1),
        ("parallel", partial(_parallel, vertical=True), 1),
        ("plastic", partial(_plastic_pipe, shape="vertical"), 1)), ordinary_runs=0),
    _WallSpec((STEEL_STUD, JUNCTION, LIVE_AND_DEAD, CAVITY), (
        ("studs", partial(_studs, material="steel", count=2, fastener="screw"), 1),
        ("junction", partial(_junction, arms=("up", "down", "right"), reach_m=(0.12, 0.25)), 1),
        ("livedead", partial(_live_and_dead, vertical=True), 1),
        ("cavity", partial(_cavity, shape="rectangle"), 1)), ordinary_runs=0, drywall=True),
    _WallSpec((DETOUR, CROSSING, PARALLEL), (
        ("detour", partial(_detour, kind="pipe", jogs="square"), 1),
        ("crossing", partial(_crossing, pipe_angle_deg=0.0, cable_angle_deg=90.0), 1),
        ("parallel", partial(_parallel, vertical=False, lives=(True, True, True)), 1))),
    _WallSpec((DEEP_PIPE, PLASTIC_PIPE, LOOSE_FASTENERS), (
        ("deep", partial(_deep_pipe, vertical=True, material="plastic"), 1),
        ("deep", partial(_deep_pipe, vertical=False), 1),
        ("loose", _loose_fastener, 5))),
)

N_HARD_CASE_WALLS = len(_SPECS)


def hard_case_wall(index: int, seed: int = 0) -> Wall:
    """Hard-case wall number `index` (0 <= index < N_HARD_CASE_WALLS); the same (index, seed) gives the same wall.

    seed >= 0 moves, resizes and re-draws everything; which cases the wall holds depends on the index only.
    """
    if not 0 <= index < N_HARD_CASE_WALLS:
        raise IndexError(f"hard-case wall index {index} out of range 0..{N_HARD_CASE_WALLS - 1}")
    spec = _SPECS[index]
    size = (WALL_WIDTH_M, WALL_HEIGHT_M)
    rng = np.random.default_rng([seed, index])
    for _ in range(_WALL_RESTARTS):
        objects = _layout(spec, rng, size)
        if objects is not None:
            break
    else:  # not reached for the shipped specs; a crowded new spec would need fewer or smaller groups
        raise RuntimeError(f"hard-case wall {index} (seed {seed}): could not place its groups "
                           f"{MIN_GAP_M:g} m apart in {_WALL_RESTARTS} attempts")
    material = "drywall" if spec.drywall else MASONRY[(index + seed) % len(MASONRY)]
    raw = {"format": FORMAT, "name": f"hard-{index:02d} " + " + ".join(spec.cases), "width_m": size[0],
           "height_m": size[1], "material": material, "objects": objects}
    return wall_from_dict(raw, source=f"hard_case_wall({index}, seed={seed})")


def _layout(spec: _WallSpec, rng: np.random.Generator, size: _Size) -> list[dict[str, Any]] | None:
    """All groups of the spec placed MIN_GAP_M apart, ordinary runs where there is room; None if a case group
    found no room (the caller starts again)."""
    placed: list[_Shape] = []
    objects: list[dict[str, Any]] = []
    used_tags: dict[str, int] = {}
    wanted = [(tag, builder, True) for tag, builder, count in spec.groups for _ in range(count)]
    wanted += [("run", _ordinary_run, False)] * spec.ordinary_runs
    for tag, builder, required in wanted:
        group = _place(builder, rng, size, placed, _PLACEMENT_TRIES if required else _ORDINARY_TRIES)
        if group is None:
            if required:
                return None
            continue
        used_tags[tag] = used_tags.get(tag, 0) + 1
        prefix = f"{tag}{used_tags[tag]}"
        objects.extend({**obj, "id": f"{prefix}-{obj['id']}"} for obj in group)
    return objects


def hard_case_walls(seed: int = 0) -> list[Wall]:
    """All hard-case walls for a seed (see the module docstring for the cases), in index order."""
    return [hard_case_wall(index, seed) for index in range(N_HARD_CASE_WALLS)]
