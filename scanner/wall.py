"""Wall description files: what is inside a wall, in wall coordinates (the simulation's ground truth).

Format (YAML; JSON with the same keys is accepted; file extension .yaml/.yml/.json):

    format: arproj-wall/1          # required, exactly this string
    name: paper test plate         # free text
    width_m: 2.0                   # wall size, metres (x right, y up from the lower-left corner seen from
    height_m: 1.0                  #   the room, as the geometry package's `wall` frame)
    material: wood                 # wall material: drywall | wood | brick | concrete | aerated_concrete
    objects:                       # list (may be empty); every object has kind, id (unique), depth_m
      - kind: pipe                 # water pipe: a polyline
        id: pipe-45
        points_m: [[0.70, 0.05], [0.90, 0.25]]   # (n>=2, 2) polyline, metres, centre line of the pipe
        depth_m: 0.03              # surface to the object's nearest face, metres, > 0 and < 0.30
        material: copper           # copper | steel | plastic
        diameter_m: 0.015          # outer diameter, 0.004 .. 0.2
        water_filled: true         # optional, default true
      - kind: cable                # electric cable: a polyline
        id: cord
        points_m: [[0.35, 0.0], [0.35, 1.0]]
        depth_m: 0.02
        live: true                 # carries mains AC (the AC sensor sees it); optional, default true
        diameter_m: 0.008          # optional, default 0.008
        material: copper           # optional, the only choice (conductors)
      - kind: screw | nail         # a point: points_m has exactly one point
        id: s1
        points_m: [[1.0, 0.5]]
        depth_m: 0.005
        diameter_m: 0.004          # optional (screw 0.004, nail 0.003 default)
        length_m: 0.04             # optional (default 0.04)
        material: steel            # optional, the only choice
      - kind: stud | beam          # framing member: a closed polygon outline (n>=3, 2), metres
        id: stud-1
        outline_m: [[0.6, 0], [0.66, 0], [0.66, 2], [0.6, 2]]
        depth_m: 0.0125
        material: wood             # wood | steel (steel studs of drywall walls are metal)
      - kind: plate                # mounting plate (metal): polygon outline
        id: plate
        outline_m: [[0.08, 0.45], [0.16, 0.45], [0.16, 0.55], [0.08, 0.55]]
        depth_m: 0.02
        material: steel            # steel | aluminium | copper
        thickness_m: 0.002         # optional, default 0.002
      - kind: cavity               # hollow space: polygon outline
        id: c1
        outline_m: [[1.5, 0.2], [1.8, 0.2], [1.8, 0.6], [1.5, 0.6]]
        depth_m: 0.03

What is known of the wall's surroundings may be added (all optional; files without them are read as before).
The adaptive planner uses them only to order its passes (scanner/priors.py: DIN 18015-3 installation zones),
never in place of a measurement; the simulation ignores them:

    room:                          # the room's floor and ceiling in wall coordinates (default: the site
      floor_y_m: -0.3              #   survey's, LaserConfig.floor_margin_m below y = 0 and room_height_m
      ceiling_y_m: 2.4             #   above the floor); floor_y_m <= 0, ceiling_y_m >= height_m
    openings:                      # doors and windows in the wall: polygon outlines inside the wall
      - kind: door                 # door | window
        outline_m: [[0.8, 0.0], [1.7, 0.0], [1.7, 2.0], [0.8, 2.0]]
    sockets: [[0.45, 0.30]]        # known sockets and switches (centres of their boxes), [x, y] metres

All coordinates must lie inside the wall (tolerance 1 mm). Unknown keys are errors, so typos are caught.
Objects carry their kind-specific fields; fields that do not apply are None in `WallObject`.

Python API: `load_wall(path) -> Wall`, `save_wall(wall, path)`, `Wall.fingerprint()` (sha256 of the
canonical JSON of the content; equal for the same wall whether stored as YAML or JSON — scan logs record it
to refuse mixing walls), `random_wall(seed, ...)` for benchmarks.
Every problem raises geometry.errors.InputError naming the file, the field (e.g. `objects[2].depth_m`) and
the value.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from geometry.errors import InputError
from geometry.inputs import fail, float_array, load_document, number
from geometry.polyline import densify, distances_to_polyline, polyline_length

FORMAT = "arproj-wall/1"
WALL_MATERIALS = ("drywall", "wood", "brick", "concrete", "aerated_concrete")
LINE_KINDS = ("pipe", "cable")
POINT_KINDS = ("screw", "nail")
AREA_KINDS = ("stud", "beam", "plate", "cavity")
KINDS = LINE_KINDS + POINT_KINDS + AREA_KINDS
METALS = ("copper", "steel", "aluminium")
PIPE_MATERIALS = ("copper", "steel", "plastic")
STUD_MATERIALS = ("wood", "steel")
OPENING_KINDS = ("door", "window")
PLATE_MATERIALS = ("steel", "aluminium", "copper")

INSIDE_TOLERANCE_M = 1e-3
MAX_POINTS = 100_000  # points of one polyline or outline: more is no object of one wall
MAX_OBJECTS = 100_000
MAX_DEPTH_M = 0.30

# Per-kind optional fields and their defaults; required fields are listed in _REQUIRED.
_DEFAULTS: dict[str, dict[str, Any]] = {
    "pipe": {"water_filled": True},
    "cable": {"live": True, "diameter_m": 0.008, "material": "copper"},
    "screw": {"diameter_m": 0.004, "length_m": 0.04, "material": "steel"},
    "nail": {"diameter_m": 0.003, "length_m": 0.04, "material": "steel"},
    "stud": {"material": "wood"},
    "beam": {"material": "wood"},
    "plate": {"material": "steel", "thickness_m": 0.002},
    "cavity": {},
}
_REQUIRED: dict[str, tuple[str, ...]] = {
    "pipe": ("material", "diameter_m"),
}
_ALLOWED_MATERIALS: dict[str, tuple[str, ...]] = {
    "pipe": PIPE_MATERIALS, "cable": ("copper",), "screw": ("steel",), "nail": ("steel",),
    "stud": STUD_MATERIALS, "beam": STUD_MATERIALS, "plate": PLATE_MATERIALS,
}
_COMMON_KEYS = {"kind", "id", "depth_m", "points_m", "outline_m"}
_KIND_KEYS = {
    "pipe": {"material", "diameter_m", "water_filled"},
    "cable": {"live", "diameter_m", "material"},
    "screw": {"diameter_m", "length_m", "material"},
    "nail": {"diameter_m", "length_m", "material"},
    "stud": {"material"},
    "beam": {"material"},
    "plate": {"material", "thickness_m"},
    "cavity": set(),
}


@dataclass
class WallObject:
    """One object inside the wall.

    points_m : (n, 2) float64, metres — polyline for pipes/cables (n >= 2), one point for screws/nails;
        None for area objects.
    outline_m : (n, 3+) closed polygon (first point not repeated) for studs, beams, plates, cavities; else None.
    depth_m : metres behind the surface (to the object's nearest face).
    """

    kind: str
    id: str
    depth_m: float
    points_m: np.ndarray | None = None
    outline_m: np.ndarray | None = None
    material: str | None = None
    diameter_m: float | None = None
    water_filled: bool | None = None
    live: bool | None = None
    length_m: float | None = None
    thickness_m: float | None = None

    @property
    def is_metal(self) -> bool:
        return self.material in METALS

    @property
    def is_line(self) -> bool:
        return self.kind in LINE_KINDS

    @property
    def geometry_m(self) -> np.ndarray:
        """The object's points (polyline, point or outline), (n, 2) metres."""
        points = self.points_m if self.points_m is not None else self.outline_m
        if points is None:  # the wall file's reader never makes one; a WallObject built by hand might
            raise ValueError(f"{self.kind} {self.id!r} has neither points_m nor outline_m")
        return points

    def length(self) -> float:
        """Polyline length in metres (0 for points and areas)."""
        if self.kind not in LINE_KINDS:
            return 0.0
        return polyline_length(self.geometry_m)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "id": self.id}
        if self.points_m is not None:
            out["points_m"] = [[round(float(v), 6) for v in p] for p in self.points_m]
        if self.outline_m is not None:
            out["outline_m"] = [[round(float(v), 6) for v in p] for p in self.outline_m]
        out["depth_m"] = round(float(self.depth_m), 6)
        for key in sorted(_KIND_KEYS[self.kind]):
            value = getattr(self, key)
            if value is not None:
                out[key] = round(float(value), 6) if isinstance(value, float) else value
        return out


@dataclass
class Opening:
    """A door or window in the wall: outline_m (n >= 3, 2) closed polygon, metres, wall coordinates."""

    kind: str
    outline_m: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "outline_m": [[round(float(v), 6) for v in p] for p in self.outline_m]}


@dataclass
class Room:
    """The room's floor and ceiling heights in wall coordinates (y up from the wall's bottom edge), metres."""

    floor_y_m: float
    ceiling_y_m: float

    def to_dict(self) -> dict[str, float]:
        return {"floor_y_m": round(float(self.floor_y_m), 6), "ceiling_y_m": round(float(self.ceiling_y_m), 6)}


@dataclass
class Wall:
    """A wall and what is inside it. width_m, height_m in metres; objects in wall coordinates.

    room, openings and sockets are what is known of it beforehand (optional; see the module docstring):
    sockets : (n, 2) float64, metres, the centres of known socket and switch boxes."""

    width_m: float
    height_m: float
    material: str = "brick"
    name: str = ""
    objects: list[WallObject] = field(default_factory=list)
    source: str = ""  # the file it was loaded from, for messages
    room: Room | None = None
    openings: list[Opening] = field(default_factory=list)
    sockets: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"format": FORMAT, "name": self.name, "width_m": round(float(self.width_m), 6),
                               "height_m": round(float(self.height_m), 6), "material": self.material,
                               "objects": [o.to_dict() for o in self.objects]}
        # only what the file declares: a wall without them keeps the fingerprint it always had
        if self.room is not None:
            out["room"] = self.room.to_dict()
        if self.openings:
            out["openings"] = [o.to_dict() for o in self.openings]
        if len(self.sockets):
            out["sockets"] = [[round(float(v), 6) for v in p] for p in self.sockets]
        return out

    def fingerprint(self) -> str:
        """sha256 hex of the canonical JSON content (independent of file format, key order and name)."""
        content = self.to_dict()
        content.pop("name")
        return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()

    def by_id(self, object_id: str) -> WallObject:
        for obj in self.objects:
            if obj.id == object_id:
                return obj
        raise KeyError(object_id)

    def targets(self) -> list[WallObject]:
        """Pipes and cables: what a craftsman must not drill into (the benchmark's recall set)."""
        return [o for o in self.objects if o.kind in LINE_KINDS]


def _number(source: str, where: str, value: Any, lo: float, hi: float) -> float:
    return number(source, where, value, lo, hi, "metres")


def _points(source: str, where: str, value: Any, wall_w: float, wall_h: float, min_n: int,
            max_n: int | None = None) -> np.ndarray:
    arr = float_array(source, where, value, (None, 2), unit="[x, y] pairs in metres", max_rows=MAX_POINTS)
    if arr.shape[0] < min_n or (max_n is not None and arr.shape[0] > max_n):
        count = f"exactly {min_n}" if max_n == min_n else f"at least {min_n}"
        raise fail(source, where, value, f"needs {count} point(s), has {arr.shape[0]}")
    tol = INSIDE_TOLERANCE_M
    outside = (arr[:, 0] < -tol) | (arr[:, 0] > wall_w + tol) | (arr[:, 1] < -tol) | (arr[:, 1] > wall_h + tol)
    if outside.any():
        bad = arr[np.argmax(outside)].tolist()
        raise fail(source, where, value, f"point {bad} lies outside the wall (0..{wall_w:g} x 0..{wall_h:g} m)")
    if min_n >= 2 and np.any(np.linalg.norm(np.diff(arr, axis=0), axis=1) < 1e-6):
        raise fail(source, where, value, "has repeated consecutive points")
    return arr


def _bool(source: str, where: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise fail(source, where, value, "must be true or false")
    return value


def _parse_object(source: str, index: int, raw: Any, wall_w: float, wall_h: float) -> WallObject:
    where = f"objects[{index}]"
    if not isinstance(raw, dict):
        raise fail(source, where, raw, "must be a mapping with kind, id, depth_m, ...")
    kind = raw.get("kind")
    if kind not in KINDS:
        raise fail(source, f"{where}.kind", kind, f"must be one of {', '.join(KINDS)}")
    unknown = set(raw) - _COMMON_KEYS - _KIND_KEYS[kind]
    if unknown:
        key = sorted(unknown)[0]
        raise fail(source, f"{where}.{key}", raw[key], f"is not a field of a {kind} "
                    f"(allowed: {', '.join(sorted(_COMMON_KEYS - {'points_m', 'outline_m'} | _KIND_KEYS[kind]))}"
                    f", {'outline_m' if kind in AREA_KINDS else 'points_m'})")
    obj_id = raw.get("id")
    if isinstance(obj_id, int) and not isinstance(obj_id, bool) and abs(obj_id) < 10**18:
        obj_id = str(obj_id)
    if not isinstance(obj_id, str) or not 0 < len(obj_id) <= 200:
        raise fail(source, f"{where}.id", obj_id, "must be a non-empty string (at most 200 characters)")
    where = f"objects[{index}] (id {obj_id})"
    if "depth_m" not in raw:
        raise fail(source, f"{where}.depth_m", None, "is required (metres behind the surface)")
    depth = _number(source, f"{where}.depth_m", raw["depth_m"], 0.0, MAX_DEPTH_M)
    obj = WallObject(kind=kind, id=str(obj_id), depth_m=depth)
    if kind in AREA_KINDS:
        if "points_m" in raw:
            raise fail(source, f"{where}.points_m", raw["points_m"], f"a {kind} has an outline_m, not points_m")
        if "outline_m" not in raw:
            raise fail(source, f"{where}.outline_m", None, "is required (polygon of [x, y] in metres)")
        obj.outline_m = _points(source, f"{where}.outline_m", raw["outline_m"], wall_w, wall_h, 3)
        if abs(_polygon_area(obj.outline_m)) < 1e-6:
            raise fail(source, f"{where}.outline_m", raw["outline_m"], "encloses no area")
    else:
        if "outline_m" in raw:
            raise fail(source, f"{where}.outline_m", raw["outline_m"], f"a {kind} has points_m, not outline_m")
        if "points_m" not in raw:
            raise fail(source, f"{where}.points_m", None, "is required (list of [x, y] in metres)")
        if kind in POINT_KINDS:
            obj.points_m = _points(source, f"{where}.points_m", raw["points_m"], wall_w, wall_h, 1, 1)
        else:
            obj.points_m = _points(source, f"{where}.points_m", raw["points_m"], wall_w, wall_h, 2)
    for key in _REQUIRED.get(kind, ()):
        if key not in raw:
            raise fail(source, f"{where}.{key}", None, f"is required for a {kind}")
    values = {**_DEFAULTS[kind], **{k: v for k, v in raw.items() if k in _KIND_KEYS[kind]}}
    for key, value in values.items():
        field_name = f"{where}.{key}"
        if key == "material":
            allowed = _ALLOWED_MATERIALS[kind]
            if value not in allowed:
                raise fail(source, field_name, value, f"must be one of {', '.join(allowed)}")
            obj.material = value
        elif key == "diameter_m":
            obj.diameter_m = _number(source, field_name, value, 0.001, 0.2)
        elif key == "length_m":
            obj.length_m = _number(source, field_name, value, 0.005, 0.3)
        elif key == "thickness_m":
            obj.thickness_m = _number(source, field_name, value, 0.0002, 0.05)
        elif key in ("water_filled", "live"):
            setattr(obj, key, _bool(source, field_name, value))
    return obj


def _polygon_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def wall_from_dict(raw: Any, source: str = "<wall>") -> Wall:
    """Validate a parsed wall description (see the module docstring) into a `Wall`."""
    if not isinstance(raw, dict):
        raise InputError(f"{source}: the wall description must be a mapping with format, width_m, height_m, "
                         f"material and objects (got {type(raw).__name__})")
    if raw.get("format") != FORMAT:
        raise fail(source, "format", raw.get("format"), f"must be {FORMAT!r}")
    allowed = {"format", "name", "width_m", "height_m", "material", "objects", "room", "openings", "sockets"}
    unknown = set(raw) - allowed
    if unknown:
        key = sorted(unknown)[0]
        raise fail(source, key, raw[key], f"is not a wall field (allowed: {', '.join(sorted(allowed))})")
    for key in ("width_m", "height_m"):
        if key not in raw:
            raise fail(source, key, None, "is required (metres)")
    width = _number(source, "width_m", raw["width_m"], 0.05, 50.0)
    height = _number(source, "height_m", raw["height_m"], 0.05, 10.0)
    material = raw.get("material", "brick")
    if material not in WALL_MATERIALS:
        raise fail(source, "material", material, f"must be one of {', '.join(WALL_MATERIALS)}")
    name = raw.get("name", "")
    if not isinstance(name, str):
        raise fail(source, "name", name, "must be text")
    objects_raw = raw.get("objects", [])
    if objects_raw is None:
        objects_raw = []
    if not isinstance(objects_raw, list):
        raise fail(source, "objects", objects_raw, "must be a list")
    if len(objects_raw) > MAX_OBJECTS:
        raise fail(source, "objects", objects_raw, f"has {len(objects_raw):,} objects; at most {MAX_OBJECTS:,}")
    objects = [_parse_object(source, i, o, width, height) for i, o in enumerate(objects_raw)]
    seen: set[str] = set()
    for i, obj in enumerate(objects):
        if obj.id in seen:
            raise fail(source, f"objects[{i}].id", obj.id, "is used twice; ids must be unique")
        seen.add(obj.id)
    return Wall(width_m=width, height_m=height, material=material, name=name, objects=objects, source=source,
                room=_parse_room(source, raw.get("room"), height), openings=parse_openings(
                    source, raw.get("openings"), width, height), sockets=parse_sockets(
                    source, raw.get("sockets"), width, height))


def _parse_room(source: str, raw: Any, wall_h: float) -> Room | None:
    if raw is None:
        return None
    if not isinstance(raw, dict) or set(raw) != {"floor_y_m", "ceiling_y_m"}:
        raise fail(source, "room", raw, "must be a mapping with floor_y_m and ceiling_y_m (metres, wall y)")
    tol = INSIDE_TOLERANCE_M
    floor = _number(source, "room.floor_y_m", raw["floor_y_m"], -10.0, tol)  # the wall stands on or above it
    ceiling = _number(source, "room.ceiling_y_m", raw["ceiling_y_m"], wall_h - tol, 20.0)
    return Room(floor, ceiling)


def parse_openings(source: str, raw: Any, wall_w: float, wall_h: float) -> list[Opening]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise fail(source, "openings", raw, "must be a list of {kind: door|window, outline_m: [[x, y], ...]}")
    openings = []
    for i, item in enumerate(raw):
        where = f"openings[{i}]"
        if not isinstance(item, dict):
            raise fail(source, where, item, "must be a mapping with kind (door | window) and outline_m")
        unknown = set(item) - {"kind", "outline_m"}
        if unknown:
            key = sorted(unknown)[0]
            raise fail(source, f"{where}.{key}", item[key], "is not a field of an opening (allowed: kind, "
                        "outline_m)")
        if item.get("kind") not in OPENING_KINDS:
            raise fail(source, f"{where}.kind", item.get("kind"), f"must be one of {', '.join(OPENING_KINDS)}")
        if "outline_m" not in item:
            raise fail(source, f"{where}.outline_m", None, "is required (polygon of [x, y] in metres)")
        outline = _points(source, f"{where}.outline_m", item["outline_m"], wall_w, wall_h, 3)
        if abs(_polygon_area(outline)) < 1e-6:
            raise fail(source, f"{where}.outline_m", item["outline_m"], "encloses no area")
        openings.append(Opening(item["kind"], outline))
    return openings


def parse_sockets(source: str, raw: Any, wall_w: float, wall_h: float) -> np.ndarray:
    if raw is None or raw == []:
        return np.zeros((0, 2))
    if not isinstance(raw, list):
        raise fail(source, "sockets", raw, "must be a list of [x, y] socket centres in metres")
    centres = []
    for i, item in enumerate(raw):
        if not (isinstance(item, (list, tuple)) and len(item) == 2):
            raise fail(source, f"sockets[{i}]", item, "must be one [x, y] point in metres")
        centres.append(_points(source, f"sockets[{i}]", [item], wall_w, wall_h, 1, 1)[0])
    return np.array(centres, dtype=np.float64)


def load_wall(path: str | Path) -> Wall:
    """Read and validate a wall description file (YAML or JSON)."""
    raw = load_document(path, "wall file", "give the path of a wall description (.yaml or .json); shipped walls "
                        "are in scanner/walls/")
    source = str(path)
    return wall_from_dict(raw, source)


def save_wall(wall: Wall, path: str | Path) -> None:
    """Write a wall description (YAML unless the suffix is .json)."""
    path = Path(path)
    content = wall.to_dict()
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps(content, indent=2) + "\n", encoding="utf-8")
    else:
        path.write_text(yaml.safe_dump(content, sort_keys=False, default_flow_style=None, width=110),
                        encoding="utf-8")


def shipped_walls() -> dict[str, Path]:
    """name -> path of the wall files shipped in scanner/walls/."""
    folder = Path(__file__).parent / "walls"
    return {p.stem: p for p in sorted(folder.glob("*.yaml"))}


def wall_file(wall: str | Path, option: str = "--wall") -> Path:
    """The path of a wall file, or of a shipped wall given by its name (`paper_test_plate`); an InputError
    naming `option` when neither exists, so every command accepts the same names and says the same."""
    path = Path(wall)
    if not path.exists() and path.parent == Path() and path.stem in shipped_walls():
        return shipped_walls()[path.stem]
    if not path.exists():
        raise InputError(f"{option} {wall}: no such file",
                         f"pass a wall file (YAML) or a shipped wall: {', '.join(shipped_walls())}")
    return path


def random_wall(seed: int, width_m: float = 2.5, height_m: float = 2.0, n_pipes: int = 3, n_cables: int = 4,
                n_screws: int = 6, with_stud: bool = True, material: str = "brick") -> Wall:
    """A plausible random wall: pipes and cables run in installation zones, mostly horizontal or vertical.

    Cables drop vertically from the top horizontal zone to sockets/switches (ending at 0.3 m or 1.05 m) or run
    horizontally in the zones 0.15-0.45 m below the ceiling / above the floor; pipes run horizontally or
    vertically, sometimes with one bend, sometimes diagonally (as on the paper's experimental wall). Parallel
    runs keep at least MIN_SEPARATION_M apart so each is a distinct object. Screws/nails are scattered.
    """
    rng = np.random.default_rng(seed)
    objects: list[WallObject] = []
    used_x: list[float] = []  # x of vertical runs
    used_y: list[float] = []  # y of horizontal runs
    min_sep = 0.08

    def free_coordinate(lo: float, hi: float, used: list[float]) -> float | None:
        for _ in range(50):
            value = float(rng.uniform(lo, hi))
            if all(abs(value - u) >= min_sep for u in used):
                used.append(value)
                return round(value, 4)
        return None

    def line_points(kind: str) -> np.ndarray | None:
        shape = rng.choice(["vertical", "horizontal", "bend", "diagonal"],
                           p=[0.4, 0.3, 0.2, 0.1] if kind == "cable" else [0.35, 0.35, 0.2, 0.1])
        if shape == "vertical":
            x = free_coordinate(0.08, width_m - 0.08, used_x)
            if x is None:
                return None
            top = height_m if rng.random() < 0.7 else round(float(rng.uniform(0.7, height_m - 0.3)), 4)
            bottom = float(rng.choice([0.0, 0.3, 1.05])) if top == height_m else 0.0
            if top - bottom < 0.3:
                bottom = 0.0
            return np.array([[x, bottom], [x, top]])
        if shape == "horizontal":
            y = free_coordinate(0.12, height_m - 0.12, used_y)
            if y is None:
                return None
            left = 0.0 if rng.random() < 0.6 else round(float(rng.uniform(0.0, width_m * 0.5)), 4)
            right = width_m if rng.random() < 0.6 else round(float(rng.uniform(left + 0.4, width_m)), 4)
            return np.array([[left, y], [min(right, width_m), y]])
        if shape == "bend":
            x = free_coordinate(0.15, width_m - 0.15, used_x)
            y = free_coordinate(0.15, height_m - 0.15, used_y)
            if x is None or y is None:
                return None
            end_x = 0.0 if rng.random() < 0.5 else width_m
            return np.array([[x, height_m if rng.random() < 0.5 else 0.0], [x, y], [end_x, y]])
        # diagonal at 30..60 degrees, kept short enough to stay separate from the rest
        angle = math.radians(float(rng.uniform(30, 60))) * (1 if rng.random() < 0.5 else -1)
        length = float(rng.uniform(0.4, 0.8))
        cx, cy = float(rng.uniform(0.4, width_m - 0.4)), float(rng.uniform(0.4, height_m - 0.4))
        d = 0.5 * length * np.array([math.cos(angle), math.sin(angle)])
        centre = np.array([cx, cy])
        pts = np.array([centre - d, centre + d])
        pts[:, 0] = np.clip(pts[:, 0], 0, width_m)
        pts[:, 1] = np.clip(pts[:, 1], 0, height_m)
        return np.round(pts, 4)

    for kind, count in (("pipe", n_pipes), ("cable", n_cables)):
        made = 0
        for _ in range(count * 10):
            if made == count:
                break
            pts = line_points(kind)
            if pts is None or _too_close(pts, objects, min_sep):
                continue
            made += 1
            if kind == "pipe":
                objects.append(WallObject(
                    kind="pipe", id=f"pipe-{made}", points_m=pts,
                    depth_m=round(float(rng.uniform(0.015, 0.05)), 4),
                    material=str(rng.choice(["copper", "copper", "steel"])),
                    diameter_m=float(rng.choice([0.012, 0.015, 0.018, 0.022])),
                    water_filled=bool(rng.random() < 0.8)))
            else:
                objects.append(WallObject(
                    kind="cable", id=f"cable-{made}", points_m=pts,
                    depth_m=round(float(rng.uniform(0.01, 0.04)), 4),
                    live=bool(rng.random() < 0.85), diameter_m=0.008, material="copper"))
    if with_stud and material in ("drywall", "wood"):
        x = float(rng.uniform(0.3, width_m - 0.4))
        objects.append(WallObject(kind="stud", id="stud-1", depth_m=0.0125, material="wood",
                                  outline_m=np.array([[x, 0], [x + 0.06, 0], [x + 0.06, height_m], [x, height_m]])))
    for i in range(n_screws):
        p = np.round([[rng.uniform(0.05, width_m - 0.05), rng.uniform(0.05, height_m - 0.05)]], 4)
        kind = "screw" if rng.random() < 0.5 else "nail"
        objects.append(WallObject(kind=kind, id=f"{kind}-{i + 1}", points_m=p,
                                  depth_m=round(float(rng.uniform(0.002, 0.01)), 4),
                                  diameter_m=_DEFAULTS[kind]["diameter_m"], length_m=0.04, material="steel"))
    wall = Wall(width_m=width_m, height_m=height_m, material=material, name=f"random wall seed {seed}",
                objects=objects, source=f"random_wall({seed})")
    return wall_from_dict(wall.to_dict(), wall.source)  # validated like a file


def _too_close(points: np.ndarray, objects: list[WallObject], min_sep: float) -> bool:
    """True if the polyline comes within min_sep of an existing pipe/cable (crossings excepted)."""
    probe = densify(points, 0.02)
    for obj in objects:
        if obj.kind not in LINE_KINDS:
            continue
        d = distances_to_polyline(probe, obj.geometry_m)
        near = d < min_sep
        # A perpendicular crossing touches only briefly; a parallel run stays close: reject only the latter.
        if near.sum() * 0.02 > 2.5 * min_sep:
            return True
    return False
