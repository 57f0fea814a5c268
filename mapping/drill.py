"""May one drill here? One verdict per wall point, from the map's evidence: the only place this is decided.

For a hole of radius r at wall point p (metres, wall frame), in this order:
1. outside the wall → unknown ("outside the wall");
2. a measured stretch of an object whose safety band reaches the hole → keep_away, naming the object, its
   class, distance and depth. The band: the object's half-width + BASE_SAFETY_MARGIN_M + Z95·√(σ_map² +
   σ_registration²);
3. an inferred stretch (joined across unmeasured ground) whose band reaches it → unknown ("inferred only");
4. the disc of radius r + BASE_SAFETY_MARGIN_M + Z95·σ_registration around p not wholly covered by every
   channel in mapping.evidence.SAFETY_CHANNELS → unknown ("not scanned", or "channel missing");
5. a sensor response in that disc that the mapped objects do not explain (mapping.evidence.unexplained_cells)
   → unknown ("unexplained response");
6. else safe: the channels that see every kind of object that matters looked there and found nothing.

So "safe" is never a guess: each step that cannot prove absence says unknown, and says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.polyline import distances_to_polyline
from mapping.evidence import CHANNEL_SEES, SAFETY_CHANNELS, Coverage
from mapping.mapfile import CLASS_LABELS, MappedObject
from scanner.sensor_model import points_in_polygon

SAFE, KEEP_AWAY, UNKNOWN = "safe", "keep_away", "unknown"
VERDICTS = (SAFE, KEEP_AWAY, UNKNOWN)
DRILL_RADIUS_M = 0.004  # an 8 mm bit
BASE_SAFETY_MARGIN_M = 0.010  # beyond the object's edge and its uncertainty: what a craftsman keeps anyway
Z95 = 1.96  # two-sided 95 % of a Gaussian position error


@dataclass
class DrillVerdict:
    """verdict: safe | keep_away | unknown; reason: why, in a craftsman's words; nearest: the object nearest
    the point (None when the map has none); distance_m: to its edge (0 inside it)."""

    x_m: float
    y_m: float
    verdict: str
    reason: str
    nearest: MappedObject | None
    distance_m: float
    clearance_m: float

    @property
    def message(self) -> str:
        word = self.verdict.replace("_", " ")
        return f"{word}: {self.reason}"

    def to_json(self) -> dict:
        nearest = None
        if self.nearest is not None:
            nearest = {"class": self.nearest.cls, "distance_m": round(self.distance_m, 4),
                       "depth_m": None if self.nearest.depth_m is None else round(self.nearest.depth_m, 4)}
        return {"x_m": round(self.x_m, 4), "y_m": round(self.y_m, 4), "verdict": self.verdict,
                "reason": self.reason, "nearest": nearest}


def safety_margin_m(obj: MappedObject, registration_sigma_m: float = 0.0) -> float:
    """Margin beyond the object's own half-width, metres."""
    return BASE_SAFETY_MARGIN_M + Z95 * float(np.hypot(obj.sigma_m, registration_sigma_m))


def band_half_width_m(obj: MappedObject, registration_sigma_m: float = 0.0) -> float:
    """Half-width of the object's safety band (drawn and judged alike), metres."""
    return 0.5 * obj.width_m + safety_margin_m(obj, registration_sigma_m)


def distances_to_part(part: NDArray[np.float64], obj: MappedObject, p: ArrayLike) -> NDArray[np.float64]:
    """Distances (n,) from wall points p (n, 2) to the edge of one part of obj (0 on or inside it)."""
    q = np.asarray(p, dtype=np.float64).reshape(-1, 2)
    if obj.is_outline:
        ring = part[:-1] if len(part) > 3 and np.allclose(part[0], part[-1]) else part
        d = distances_to_polyline(q, np.vstack([ring, ring[:1]]))
        return np.where(points_in_polygon(q, ring), 0.0, d)
    return np.maximum(distances_to_polyline(q, part) - 0.5 * obj.width_m, 0.0)


def distance_to_object_m(obj: MappedObject, xy: ArrayLike, measured: bool | None = None) -> float:
    """Distance (metres) from wall point xy to the object's edge (or to its measured / inferred stretches
    only); inf where it has no such stretch."""
    parts = [obj.points_m] if measured is None else obj.parts(measured)
    if not parts:
        return math.inf
    return float(min(distances_to_part(part, obj, xy)[0] for part in parts))


def _label(obj: MappedObject) -> str:
    return CLASS_LABELS.get(obj.cls, obj.cls.replace("_", " "))


def check_point(xy: ArrayLike, objects: list[MappedObject], coverage: Coverage,
                bounds: tuple[float, float, float, float], registration_sigma_m: float = 0.0,
                drill_radius_m: float = DRILL_RADIUS_M) -> DrillVerdict:
    """The verdict for a hole of radius drill_radius_m at wall point xy (see the module docstring)."""
    p = np.asarray(xy, dtype=np.float64).reshape(2)
    x, y = float(p[0]), float(p[1])
    x0, y0, x1, y1 = bounds
    # nearest object by clearance to its band (measured stretches), for the answer whatever the verdict
    nearest, near_d, near_c = None, math.inf, math.inf
    inferred_hit: MappedObject | None = None
    for obj in objects:
        margin = drill_radius_m + safety_margin_m(obj, registration_sigma_m)
        d = distance_to_object_m(obj, p, measured=True)
        if d - margin < near_c:
            nearest, near_d, near_c = obj, d, d - margin
        if inferred_hit is None and distance_to_object_m(obj, p, measured=False) - margin < 0:
            inferred_hit = obj

    def verdict(kind: str, reason: str) -> DrillVerdict:
        return DrillVerdict(x, y, kind, reason, nearest, near_d, near_c)

    if not (np.isfinite(p).all() and x0 <= x <= x1 and y0 <= y <= y1):
        return verdict(UNKNOWN, "outside the wall")
    if nearest is not None and near_c < 0:
        depth = "" if nearest.depth_m is None else f", {nearest.depth_m * 1000:.0f} mm deep"
        return verdict(KEEP_AWAY, f"{_label(nearest)} {near_d * 1000:.0f} mm away{depth}")
    if inferred_hit is not None:
        return verdict(UNKNOWN, f"inferred only: a {_label(inferred_hit)} may run here; it was "
                                "joined across unmeasured ground, not measured")
    radius = drill_radius_m + BASE_SAFETY_MARGIN_M + Z95 * registration_sigma_m
    rows, cols, whole = coverage.cells_within(p, radius)
    if not whole or rows.size == 0:
        return verdict(UNKNOWN, "not scanned (the edge of the scanned area)")
    for channel in SAFETY_CHANNELS:
        if channel not in coverage.covered:
            return verdict(UNKNOWN, f"channel missing: no {channel} readings, so {CHANNEL_SEES[channel]} "
                                    "cannot be ruled out")
    seen = [coverage.covered[c][rows, cols] for c in SAFETY_CHANNELS]
    if not any(s.any() for s in seen):
        return verdict(UNKNOWN, "not scanned")
    for channel, s in zip(SAFETY_CHANNELS, seen, strict=True):
        if not s.all():
            return verdict(UNKNOWN, f"not scanned all round: the {channel} sensor covered {s.mean():.0%} of the "
                                    f"{radius * 1000:.0f} mm around it")
    for channel, layer in coverage.response.items():
        if layer[rows, cols].any():
            return verdict(UNKNOWN, f"unexplained {channel} response: something is there that the map does not "
                                    "name")
    where = "no mapped object" if nearest is None else \
        f"{near_d * 1000:.0f} mm from the nearest {_label(nearest)}"
    return verdict(SAFE, f"scanned, nothing found ({where})")


def check_points(points: ArrayLike, objects: list[MappedObject], coverage: Coverage,
                 bounds: tuple[float, float, float, float], registration_sigma_m: float = 0.0,
                 drill_radius_m: float = DRILL_RADIUS_M) -> list[DrillVerdict]:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return [check_point(p, objects, coverage, bounds, registration_sigma_m, drill_radius_m) for p in pts]


VERDICT_CODES = {SAFE: 0, KEEP_AWAY: 1, UNKNOWN: 2}


def _disc_offsets(radius_m: float, resolution: float, lo: tuple[int, int], hi: tuple[int, int]
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(row offsets, col offsets) of the cells Coverage.cells_within counts for a disc about a cell's centre
    whose search box spans lo..hi cells (rows, cols) about it."""
    dr, dc = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    near = np.hypot(dr * resolution, dc * resolution) <= radius_m + 0.7072 * resolution
    return dr[near], dc[near]


def _any_within(mask: NDArray[np.bool_], dr: NDArray[np.int64], dc: NDArray[np.int64]) -> NDArray[np.bool_]:
    """out[r, c] = any(mask[r + dr, c + dc]) over the offsets inside the grid."""
    h, w = mask.shape
    out = np.zeros_like(mask)
    for a, b in zip(dr.tolist(), dc.tolist(), strict=True):
        src = mask[max(a, 0):h + min(a, 0), max(b, 0):w + min(b, 0)]
        out[max(-a, 0):h + min(-a, 0), max(-b, 0):w + min(-b, 0)] |= src
    return out


def verdict_raster(objects: list[MappedObject], coverage: Coverage, bounds: tuple[float, float, float, float],
                   registration_sigma_m: float = 0.0, drill_radius_m: float = DRILL_RADIUS_M) -> NDArray[np.int8]:
    """check_point's verdict at the centre of every cell of coverage's grid, as VERDICT_CODES (height, width),
    computed for the whole grid at once (exports such as the map_server grid); the same rules in the same order,
    and equal to check_point cell for cell (tests/mapping/test_drill.py)."""
    info = coverage.info
    h, w, res = info.height, info.width, info.resolution
    xs = info.origin_x + (np.arange(w) + 0.5) * res
    ys = info.origin_y + (np.arange(h) + 0.5) * res
    x0, y0, x1, y1 = bounds
    out = np.full((h, w), VERDICT_CODES[UNKNOWN], np.int8)
    # rules 4 and 5: the disc wholly inside the grid, covered by every safety channel, with no response in it
    radius = drill_radius_m + BASE_SAFETY_MARGIN_M + Z95 * registration_sigma_m
    # the search box about each centre, computed as cells_within computes it (its rounding decides whether a
    # disc that just reaches a cell's edge counts it), so the raster equals check_point at every cell
    c0 = np.floor((xs - radius - info.origin_x) / res).astype(np.int64)
    c1 = np.floor((xs + radius - info.origin_x) / res).astype(np.int64)
    r0 = np.floor((ys - radius - info.origin_y) / res).astype(np.int64)
    r1 = np.floor((ys + radius - info.origin_y) / res).astype(np.int64)
    col_box = np.column_stack([c0 - np.arange(w), c1 - np.arange(w)])
    row_box = np.column_stack([r0 - np.arange(h), r1 - np.arange(h)])
    whole = ((r0 >= 0) & (r1 < h))[:, None] & ((c0 >= 0) & (c1 < w))[None, :]
    responded = np.zeros((h, w), bool)
    for layer in coverage.response.values():
        responded |= layer
    missing = any(channel not in coverage.covered for channel in SAFETY_CHANNELS)
    for rb in np.unique(row_box, axis=0):
        for cb in np.unique(col_box, axis=0):
            sel = np.all(row_box == rb, axis=1)[:, None] & np.all(col_box == cb, axis=1)[None, :] & whole
            if missing or not sel.any():
                continue
            dr, dc = _disc_offsets(radius, res, (int(rb[0]), int(cb[0])), (int(rb[1]), int(cb[1])))
            ok = sel & ~_any_within(responded, dr, dc)
            for channel in SAFETY_CHANNELS:
                ok &= ~_any_within(~coverage.covered[channel], dr, dc)
            out[ok] = VERDICT_CODES[SAFE]
    # rules 2 and 3, over each object's reach only: inferred stretches make unknown, measured ones keep away
    keep = np.zeros((h, w), bool)
    inferred = np.zeros((h, w), bool)
    for obj in objects:
        margin = drill_radius_m + safety_margin_m(obj, registration_sigma_m)
        reach = margin + 0.5 * obj.width_m + res
        for measured, hit in ((True, keep), (False, inferred)):
            for part in obj.parts(measured):
                (px0, py0), (px1, py1) = part.min(axis=0) - reach, part.max(axis=0) + reach
                c = np.flatnonzero((xs >= px0) & (xs <= px1))
                r = np.flatnonzero((ys >= py0) & (ys <= py1))
                if c.size == 0 or r.size == 0:
                    continue
                gx, gy = np.meshgrid(xs[c], ys[r])
                d = distances_to_part(part, obj, np.column_stack([gx.ravel(), gy.ravel()]))
                hit[np.ix_(r, c)] |= (d - margin < 0).reshape(r.size, c.size)
    out[inferred] = VERDICT_CODES[UNKNOWN]
    out[keep] = VERDICT_CODES[KEEP_AWAY]
    # rule 1: outside the wall
    inside = (xs[None, :] >= x0) & (xs[None, :] <= x1) & (ys[:, None] >= y0) & (ys[:, None] <= y1)
    out[~inside] = VERDICT_CODES[UNKNOWN]
    return out
