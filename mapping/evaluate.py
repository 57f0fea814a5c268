"""Extracted objects against a wall file's truth: recall, precision, position and angle error, classes.

Targets are the pipes and cables within the sensors' depth range (metal pipes and copper cables no deeper than
`max_depth_m`; plastic pipes are invisible to the inductive and AC sensors and are reported apart). A target is
*found* when at least `min_coverage` of its centre line lies within `match_m` of detected lines. Precision is
the fraction of detected line length within `match_m` of any pipe or cable (plastic and deep ones included:
they are real). Position error: distance of detected line points to the truth centre line (points matched
within `match_m`). Angle error: per detected straight piece, against the nearest truth segment. Class: the
length-weighted majority class of detections along the target, against power_line (cables) or metal_pipe.
evaluate_measured() counts recall by the same rule against only the measured stretches of mapped lines
(mapping.mapfile.MappedObject: a stretch joined across unmeasured ground is inferred, not found).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from geometry.polyline import densify, distances_to_polyline, polyline_length
from mapping.evidence import Coverage
from mapping.map_object import MapObject
from mapping.mapfile import MappedObject
from scanner.wall import Wall, WallObject

MATCH_M = 0.015
MIN_COVERAGE = 0.7
MAX_DEPTH_M = 0.05


def truth_class(obj: WallObject) -> str:
    """The class a perfect map would give a wall object: what its channels can tell (a water-filled plastic
    pipe and a wooden stud both only raise the capacitive level: non-metal); a dry plastic pipe no channel
    sees is "plastic_pipe", no mapped class."""
    if obj.kind == "cable":
        return "power_line"
    if obj.kind == "pipe":
        if obj.is_metal:
            return "metal_pipe"
        return "non_metal" if obj.water_filled else "plastic_pipe"
    if obj.kind in ("screw", "nail"):
        return "fastener"
    if obj.kind in ("stud", "beam"):
        return "non_metal" if obj.material == "wood" else "metal"
    if obj.kind == "plate":
        return "metal"
    return obj.kind


def is_target(obj: WallObject, max_depth_m: float = MAX_DEPTH_M) -> bool:
    return (obj.kind == "cable" or (obj.kind == "pipe" and obj.is_metal)) and obj.depth_m <= max_depth_m


@dataclass
class Evaluation:
    n_targets: int = 0
    n_found: int = 0
    detected_length_m: float = 0.0
    true_length_m: float = 0.0  # detected length within match of a real line
    position_errors_m: list[float] = field(default_factory=list)
    angle_errors_deg: list[float] = field(default_factory=list)
    class_pairs: list[tuple[str, str]] = field(default_factory=list)  # (truth, predicted) per found target
    missed: list[str] = field(default_factory=list)

    def merge(self, other: Evaluation) -> None:
        self.n_targets += other.n_targets
        self.n_found += other.n_found
        self.detected_length_m += other.detected_length_m
        self.true_length_m += other.true_length_m
        self.position_errors_m += other.position_errors_m
        self.angle_errors_deg += other.angle_errors_deg
        self.class_pairs += other.class_pairs
        self.missed += other.missed

    @property
    def recall(self) -> float:
        return self.n_found / self.n_targets if self.n_targets else float("nan")

    @property
    def precision(self) -> float:
        return self.true_length_m / self.detected_length_m if self.detected_length_m else float("nan")

    def position_mm(self) -> tuple[float, float]:
        e = np.asarray(self.position_errors_m) * 1000.0
        return (float(e.mean()), float(np.percentile(e, 95))) if e.size else (float("nan"), float("nan"))

    def angle_deg(self) -> tuple[float, float]:
        a = np.asarray(self.angle_errors_deg)
        return (float(a.mean()), float(np.percentile(a, 95))) if a.size else (float("nan"), float("nan"))

    def class_accuracy(self, classes: tuple[str, ...] = ("power_line", "metal_pipe")) -> float:
        pairs = [(t, p) for t, p in self.class_pairs if t in classes]
        return sum(t == p for t, p in pairs) / len(pairs) if pairs else float("nan")


def _segments_angle(d1: NDArray[np.float64], d2: NDArray[np.float64]) -> float:
    c = abs(float(d1 @ d2) / (np.linalg.norm(d1) * np.linalg.norm(d2)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def evaluate(objects: list[MapObject], wall: Wall, match_m: float = MATCH_M,
             min_coverage: float = MIN_COVERAGE, max_depth_m: float = MAX_DEPTH_M,
             region: tuple[float, float, float, float] | None = None) -> Evaluation:
    """Compare detected line objects with the wall's pipes and cables (region: x0, y0, x1, y1 scanned)."""
    lines = [o for o in objects if o.kind == "line"]
    ev = _match_targets([(o.points_m, o.cls) for o in lines], wall, match_m, min_coverage, max_depth_m, region)
    real = [o for o in wall.objects if o.kind in ("pipe", "cable")]
    for o in lines:
        pts = densify(o.points_m, 0.002)
        seg_len = polyline_length(o.points_m) / max(len(pts) - 1, 1)
        d = np.min([distances_to_polyline(pts, r.points_m) for r in real], axis=0) if real else \
            np.full(len(pts), np.inf)
        ev.detected_length_m += seg_len * len(pts)
        ev.true_length_m += seg_len * float((d < match_m).sum())
        # position error: against the nearest real line; but ignore points near a crossing/bend vertex of truth
        near = d < match_m
        ev.position_errors_m += d[near].tolist()
        for a, b in zip(o.points_m[:-1], o.points_m[1:], strict=True):
            if np.linalg.norm(b - a) < 0.03:
                continue
            # the truth segment this piece follows: least mean distance over points along it (a midpoint
            # alone may sit on a crossing line)
            probe = a + np.linspace(0.1, 0.9, 9)[:, None] * (b - a)
            best = None
            for r in real:
                for ra, rb in zip(r.points_m[:-1], r.points_m[1:], strict=True):
                    dd = float(distances_to_polyline(probe, np.array([ra, rb])).mean())
                    if dd < match_m and (best is None or dd < best[0]):
                        best = (dd, rb - ra)
            if best is not None:
                ev.angle_errors_deg.append(_segments_angle(b - a, best[1]))
    return ev


def _match_targets(lines: list[tuple[NDArray[np.float64], str]], wall: Wall, match_m: float, min_coverage: float,
                   max_depth_m: float, region: tuple[float, float, float, float] | None) -> Evaluation:
    """The targets (is_target) that lines ((k, 2) polyline, class each) find: n_targets, n_found, class_pairs,
    missed. The one matching rule of evaluate() and evaluate_measured()."""
    ev = Evaluation()
    for t in wall.objects:
        if not is_target(t, max_depth_m):
            continue
        probe = densify(t.points_m, 0.005)
        if region is not None:
            x0, y0, x1, y1 = region
            probe = probe[(probe[:, 0] >= x0) & (probe[:, 0] <= x1) & (probe[:, 1] >= y0) & (probe[:, 1] <= y1)]
            if probe.shape[0] < 10:
                continue
        ev.n_targets += 1
        if not lines:
            ev.missed.append(t.id)
            continue
        dists = np.stack([distances_to_polyline(probe, points) for points, _ in lines])
        covered = dists.min(axis=0) < match_m
        if covered.mean() >= min_coverage:
            ev.n_found += 1
            votes: dict[str, float] = {}
            owner = dists.argmin(axis=0)
            for k in owner[covered]:
                votes[lines[k][1]] = votes.get(lines[k][1], 0.0) + 1.0
            ev.class_pairs.append((truth_class(t), max(votes, key=votes.get)))  # type: ignore[arg-type]
        else:
            ev.missed.append(t.id)
    return ev


def evaluate_measured(objects: list[MappedObject], wall: Wall, match_m: float = MATCH_M,
                      min_coverage: float = MIN_COVERAGE, max_depth_m: float = MAX_DEPTH_M,
                      region: tuple[float, float, float, float] | None = None) -> Evaluation:
    """Recall as evaluate() counts it, but against the measured stretches of the mapped lines only
    (MappedObject.parts(measured=True)): a target the map draws by joining across unmeasured ground is not
    found there. Fills the target fields (n_targets, n_found, class_pairs, missed), not precision or errors."""
    parts = [(part, o.cls) for o in objects if o.shape == "line" for part in o.parts(measured=True)]
    return _match_targets(parts, wall, match_m, min_coverage, max_depth_m, region)


FALSE_SAFE_STEP_M = 0.005  # the true centre lines are probed every 5 mm


def is_hazard(obj: WallObject, max_depth_m: float = MAX_DEPTH_M) -> bool:
    """What the false-safe figure guards: metal pipes, cables (live or dead) and water-filled plastic pipes
    within max_depth_m of the surface."""
    if obj.depth_m > max_depth_m:
        return False
    return obj.kind == "cable" or (obj.kind == "pipe" and (obj.is_metal or bool(obj.water_filled)))


@dataclass
class FalseSafe:
    """Per hazard (id): probed length and the length the drill check called safe, metres."""

    probed_m: dict[str, float] = field(default_factory=dict)
    safe_m: dict[str, float] = field(default_factory=dict)
    unknown_m: dict[str, float] = field(default_factory=dict)

    def merge(self, other: FalseSafe, prefix: str = "") -> None:
        for key in other.probed_m:
            self.probed_m[prefix + key] = other.probed_m[key]
            self.safe_m[prefix + key] = other.safe_m[key]
            self.unknown_m[prefix + key] = other.unknown_m[key]

    @property
    def share(self) -> float:
        """Share of all hazards' probed length called safe (0 when nothing was probed)."""
        total = sum(self.probed_m.values())
        return sum(self.safe_m.values()) / total if total else 0.0

    @property
    def unknown_share(self) -> float:
        total = sum(self.probed_m.values())
        return sum(self.unknown_m.values()) / total if total else 0.0

    def worst(self) -> tuple[str, float]:
        """(hazard id, its share called safe) of the hazard with the largest share."""
        if not self.probed_m:
            return "", 0.0
        key = max(self.probed_m, key=lambda k: self.safe_m[k] / max(self.probed_m[k], 1e-12))
        return key, self.safe_m[key] / max(self.probed_m[key], 1e-12)


def false_safe(objects: list[MappedObject], coverage: Coverage, wall: Wall, step_m: float = FALSE_SAFE_STEP_M,
               max_depth_m: float = MAX_DEPTH_M) -> FalseSafe:
    """How much of each true hazard (is_hazard) the drill check (mapping.drill, no registration error) calls
    safe, probing its centre line every step_m: the product's promise says this is zero."""
    from mapping.drill import SAFE, UNKNOWN, check_points

    out = FalseSafe()
    bounds = (0.0, 0.0, wall.width_m, wall.height_m)
    for obj in wall.objects:
        if not is_hazard(obj, max_depth_m):
            continue
        probes = densify(np.asarray(obj.geometry_m, dtype=np.float64), step_m)
        verdicts = [v.verdict for v in check_points(probes, objects, coverage, bounds)]
        n = max(len(verdicts), 1)
        length = polyline_length(obj.geometry_m) or step_m
        out.probed_m[obj.id] = length
        out.safe_m[obj.id] = length * sum(v == SAFE for v in verdicts) / n
        out.unknown_m[obj.id] = length * sum(v == UNKNOWN for v in verdicts) / n
    return out


def fastener_recall(objects: list[MapObject], wall: Wall, match_m: float = MATCH_M) -> tuple[int, int]:
    """(found, total) of the wall's screws and nails: found when a mapped fastener lies within match_m."""
    truth = [np.asarray(o.geometry_m, dtype=np.float64)[0] for o in wall.objects if o.kind in ("screw", "nail")]
    mapped = np.array([np.asarray(o.points_m)[0] for o in objects if o.cls == "fastener"]).reshape(-1, 2)
    found = sum(bool(len(mapped)) and float(np.min(np.linalg.norm(mapped - t, axis=1))) <= match_m for t in truth)
    return int(found), len(truth)


AREA_MATCH_M = 0.02  # an area object is found when a mapped object of its kind lies this close to its middle
_AREA_CLASSES = {"stud": ("non_metal", "wood", "metal"), "beam": ("non_metal", "wood", "metal"),
                 "plate": ("metal", "metal_pipe"), "cavity": ("cavity",)}


def area_recall(objects: list[MapObject], wall: Wall) -> tuple[int, int, list[str]]:
    """(found, total, missed ids) of the wall's studs, beams, plates (socket boxes) and cavities: found when a
    mapped object of a class the channels can give it (a wood stud: non-metal; a steel stud or plate: metal)
    comes within AREA_MATCH_M of the area's middle or covers it."""
    from scanner.sensor_model import points_in_polygon

    found, missed, total = 0, [], 0
    for obj in wall.objects:
        if obj.kind not in _AREA_CLASSES:
            continue
        total += 1
        ring = np.asarray(obj.geometry_m, dtype=np.float64)
        middle = ring.mean(axis=0, keepdims=True)
        reach = AREA_MATCH_M + 0.5 * float(np.ptp(ring, axis=0).min())  # a line along a stud's middle counts
        wanted = _AREA_CLASSES[obj.kind] if obj.material != "wood" else ("non_metal", "wood")
        if obj.kind in ("stud", "beam") and obj.material == "steel":
            wanted = ("metal",)
        hit = False
        for o in objects:
            if o.cls not in wanted:
                continue
            pts = np.asarray(o.points_m, dtype=np.float64)
            inside = o.kind == "outline" and len(pts) >= 3 and bool(points_in_polygon(middle, pts)[0])
            near = float(distances_to_polyline(middle, pts)[0]) <= reach
            if inside or near:
                hit = True
                break
        found += hit
        if not hit:
            missed.append(obj.id)
    return found, total, missed


def pipes_labelled_wood(objects: list[MapObject], wall: Wall, match_m: float = MATCH_M,
                        max_depth_m: float = MAX_DEPTH_M) -> list[str]:
    """Ids of the true pipes and cables within reach (is_hazard) that the map labels wood: more than half of
    the stretch of the centre line that mapped lines (within match_m) and outlines (inside) cover lies only
    under objects that read as wood. That is a non-metal outline (a stud's shape; files' former "wood"
    objects read so) or, along a metal pipe or a cable, any non-metal object (the inductive channel sees
    metal there: non-metal would say wood or water). A water-filled plastic pipe mapped as a non-metal line is
    what its channel can tell, not wood."""
    from scanner.sensor_model import points_in_polygon

    out = []
    for t in wall.objects:
        if not is_hazard(t, max_depth_m):
            continue
        probe = densify(t.points_m, 0.005)
        metal = t.kind == "cable" or t.is_metal
        wood = np.zeros(len(probe), bool)
        other = np.zeros(len(probe), bool)
        for o in objects:
            pts = np.asarray(o.points_m, dtype=np.float64)
            if o.kind == "outline" and len(pts) >= 3:
                under = points_in_polygon(probe, pts)
            elif o.kind == "line":
                under = distances_to_polyline(probe, pts) < match_m
            else:
                continue  # a fastener names a point, not a course
            if o.cls == "non_metal" and (o.kind == "outline" or metal):
                wood |= under
            else:
                other |= under
        covered = wood | other
        # a stud's outline a cable crosses covers a few cm of it: the majority of what covers it decides
        if covered.any() and (wood & ~other).sum() > 0.5 * covered.sum():
            out.append(t.id)
    return out


def truth_under(obj: MapObject, wall: Wall, match_m: float = MATCH_M) -> WallObject | None:
    """The true pipe, cable or screw a mapped line or point lies on (mean distance within match_m), or None."""
    best: tuple[float, WallObject] | None = None
    for t in wall.objects:
        if obj.kind == "point" and t.kind in ("screw", "nail"):
            d = float(np.linalg.norm(obj.points_m[0] - np.asarray(t.points_m)[0]))
        elif obj.kind == "line" and t.kind in ("pipe", "cable"):
            d = float(distances_to_polyline(densify(obj.points_m, 0.005), np.asarray(t.points_m)).mean())
        else:
            continue
        if best is None or d < best[0]:
            best = (d, t)
    return best[1] if best is not None and best[0] < match_m else None


def depth_errors(objects: list[MapObject], wall: Wall) -> list[tuple[str, float, float]]:
    """(true id, depth error m, reported σ m) of every mapped object with a depth that lies on a true one (a
    spurious object is the mapping's error, not the depth's)."""
    out = []
    for obj in objects:
        truth = truth_under(obj, wall) if obj.depth_m is not None else None
        if truth is not None:
            out.append((truth.id, float(obj.depth_m) - truth.depth_m, float(obj.depth_sigma_m or float("nan"))))
    return out


# -- every object, every class: what the report's score table lists -----------------------------------------
ACCEPTED_CLASSES = {"power_line": ("power_line",), "metal_pipe": ("metal_pipe",), "fastener": ("fastener",),
                    "non_metal": ("non_metal", "wood"), "metal": ("metal", "metal_pipe"), "cavity": ("cavity",),
                    "plastic_pipe": ()}


@dataclass
class ObjectScore:
    """One wall object against the map. verdict: found (the right class), wrong class, missed, or invisible
    (no channel can see it: a dry plastic pipe)."""

    id: str
    kind: str
    truth_class: str
    depth_mm: float
    verdict: str
    mapped_class: str | None = None
    note: str = ""


def _distances(points: NDArray[np.float64], obj: MapObject) -> NDArray[np.float64]:
    """Distance of points to a mapped object; 0 inside an outline."""
    from scanner.sensor_model import points_in_polygon

    ring = np.asarray(obj.points_m, dtype=np.float64)
    d = distances_to_polyline(points, ring) if len(ring) > 1 else np.linalg.norm(points - ring[0], axis=1)
    if obj.kind == "outline" and len(ring) >= 3:
        d = np.where(points_in_polygon(points, ring), 0.0, d)
    return d


def object_scores(objects: list[MapObject], wall: Wall, match_m: float = MATCH_M,
                  min_coverage: float = MIN_COVERAGE, max_depth_m: float = MAX_DEPTH_M) -> list[ObjectScore]:
    """Every object of the wall file, fasteners, studs, plates and cavities included, with the class the map
    gave it: a line is found where mapped objects cover min_coverage of its centre line within match_m (the
    class by length-weighted majority), a screw or nail by the nearest mapped object within match_m, an area
    by a mapped object at its middle (as area_recall). A class outside ACCEPTED_CLASSES is a wrong class
    (a screw mapped as a power line), never a find."""
    scores = []
    for t in wall.objects:
        cls = truth_class(t)
        depth_note = f"deeper than the sensors reach ({max_depth_m * 1000:.0f} mm)" if t.depth_m > max_depth_m \
            else ""
        score = ObjectScore(t.id, t.kind, cls, round(1000 * t.depth_m, 1), "missed", note=depth_note)
        scores.append(score)
        if cls == "plastic_pipe":
            score.verdict, score.note = "invisible", "dry plastic: no channel of the scanner sees it"
            continue
        geometry = np.asarray(t.geometry_m, dtype=np.float64)
        if t.kind in ("pipe", "cable"):
            probe = densify(geometry, 0.005)
            reach = match_m
        elif t.kind in ("screw", "nail"):
            probe, reach = geometry[:1], match_m
        else:  # an area: its middle, reached as area_recall reaches it
            probe = geometry.mean(axis=0, keepdims=True)
            reach = AREA_MATCH_M + 0.5 * float(np.ptp(geometry, axis=0).min())
        if not objects:
            continue
        dists = np.stack([_distances(probe, o) for o in objects])
        covered = dists.min(axis=0) <= reach
        if covered.mean() < (min_coverage if len(probe) > 1 else 1.0):
            if covered.any():
                score.note = f"{covered.mean():.0%} of its length mapped" + (f"; {depth_note}" if depth_note
                                                                               else "")
            continue
        votes: dict[str, int] = {}
        for k in dists.argmin(axis=0)[covered]:
            votes[objects[k].cls] = votes.get(objects[k].cls, 0) + 1
        accepted = [c for c in votes if c in ACCEPTED_CLASSES.get(cls, (cls,))]
        score.mapped_class = accepted[0] if accepted and len(probe) == 1 else max(votes, key=votes.__getitem__)
        score.verdict = "found" if score.mapped_class in ACCEPTED_CLASSES.get(cls, (cls,)) else "wrong class"
    return scores


def class_summary(scores: list[ObjectScore]) -> dict[str, dict[str, int]]:
    """truth class -> {"objects", "found", "wrong class", "missed", "invisible"}: every class in the wall."""
    out: dict[str, dict[str, int]] = {}
    for s in scores:
        row = out.setdefault(s.truth_class, {"objects": 0, "found": 0, "wrong class": 0, "missed": 0,
                                             "invisible": 0})
        row["objects"] += 1
        row[s.verdict] += 1
    return out


def unmatched_objects(objects: list[MapObject], wall: Wall, match_m: float = MATCH_M) -> list[MapObject]:
    """Mapped objects that lie on nothing in the wall file (no point of them within 2 match_m of any object)."""
    truth = [np.asarray(t.geometry_m, dtype=np.float64) for t in wall.objects]
    out = []
    for o in objects:
        pts = densify(np.asarray(o.points_m, dtype=np.float64), 0.005) if len(o.points_m) > 1 else \
            np.asarray(o.points_m, dtype=np.float64)
        near = False
        for g in truth:
            d = distances_to_polyline(pts, g) if len(g) > 1 else np.linalg.norm(pts - g[0], axis=1)
            if len(g) >= 3:  # an area: inside it counts as on it
                from scanner.sensor_model import points_in_polygon

                d = np.where(points_in_polygon(pts, g), 0.0, d)
            if float(d.min()) <= 2 * match_m:
                near = True
                break
        if not near:
            out.append(o)
    return out
