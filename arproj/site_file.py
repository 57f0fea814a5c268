"""The site file (`site.yaml`, format `arproj-site/1`): where each scanned wall is in its room, as the scanning
robot's 2-D laser saw it, so that the projection robot can find the wall again days later (`arproj project
--site site.yaml --wall K`) without a hand-made prior.

One file per site, one entry per wall under `walls:` (key K, by default the wall's name):

    format: arproj-site/1
    walls:
      K:
        wall: {name, width_m, height_m, fingerprint}   # the scanned wall (scanner.wall.Wall.fingerprint)
        map: map                                       # the map folder (`arproj map LOG --out DIR`), and
        scan_log: scan.db                              # the scan log, both relative to the site file
        T_room_from_wall: [[4x4]]                      # the wall frame (the map's) in the room frame
        wall_in_room_sigma_m: {along, height}          # 1σ of that placement (the frames' laser fixes)
        room:                                          # the room as the laser saw it (room frame: z up, floor
          corners_m: [[x, y], ...]                     #   z = 0; floor polygon clockwise seen from above,
          height_m: H                                  #   wall i from corner i to i + 1, arproj/sim's layout)
          wall_index: 0                                # the room wall the scanned wall lies in
          measured: {width, depth, height: {value_m, sigma_m, frames}}   # sigma_m null: not seen, assumed
        laser: {side_margin_m, floor_margin_m}         # the fixes' reference: the wall frame's x = 0 lies
                                                       #   side_margin_m right of the left side wall, y = 0
                                                       #   floor_margin_m above the floor

The room is the laser's rectangle (scanner.laser): the scanned wall, the side walls its ends meet and the wall
opposite; its width, depth and height are each frame's look at them (scanner.laser.room_from_scans), averaged
by inverse variance. The wall frame's place in it is the fixes' own reference (the left side wall and the
floor), so the map, stitched on those fixes, sits where the file says to within `wall_in_room_sigma_m`.

Reading validates every field and raises InputError with one line naming the file, key and value and what to
do; writing adds or replaces one wall in an existing site file, refuses any other kind of file, and writes
atomically (a temporary file renamed over the old one).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from geometry.errors import InputError
from geometry.inputs import fail, float_array, load_document, number, text
from geometry.poses import invert, make_pose
from scanner.laser import ROOM_KEYS, LaserConfig
from scanner.wall import Opening, Wall, parse_openings, parse_sockets
from wallpose.pose import RoomMap, wall_frames

FORMAT = "arproj-site/1"
RESCAN = "scan the wall again with `arproj scan ... --site FILE`, or fix the file by hand"
MAX_M = 1000.0  # any length or coordinate of a site, metres
DIMENSIONS = ("width", "depth", "height")  # the room's, in scanner.laser.ROOM_KEYS order


@dataclass(frozen=True)
class RoomSize:
    """One room dimension as the laser saw it: value (m), 1σ (m; None: no frame saw it, the survey's value)."""

    value_m: float
    sigma_m: float | None
    frames: int


@dataclass
class SiteWall:
    """One wall of the site file (see the module docstring); paths resolved against the site file's folder."""

    key: str
    name: str
    width_m: float
    height_m: float
    fingerprint: str
    T_room_from_wall: NDArray[np.float64]
    sigma_along_m: float
    sigma_height_m: float
    corners_m: NDArray[np.float64]
    room_height_m: float
    wall_index: int
    side_margin_m: float
    floor_margin_m: float
    map_dir: Path
    scan_log: Path
    measured: dict[str, RoomSize] = field(default_factory=dict)
    openings: list[Opening] = field(default_factory=list)  # the wall's doors and windows (its wall frame)
    sockets: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))  # known socket centres

    def room_map(self) -> RoomMap:
        """The room's walls as the full wall-pose estimate takes them."""
        return RoomMap.from_floor_polygon(self.corners_m, self.room_height_m)

    @property
    def room_width_m(self) -> float:
        return float(wall_frames(self.corners_m)[self.wall_index][1])

    def to_dict(self, folder: Path) -> dict[str, Any]:
        def rel(path: Path) -> str:
            return os.path.relpath(path.resolve(), folder.resolve())

        return {
            "wall": {"name": self.name, "width_m": self.width_m, "height_m": self.height_m,
                     "fingerprint": self.fingerprint},
            "map": rel(self.map_dir), "scan_log": rel(self.scan_log),
            "T_room_from_wall": [[float(v) for v in row] for row in self.T_room_from_wall],
            "wall_in_room_sigma_m": {"along": self.sigma_along_m, "height": self.sigma_height_m},
            "room": {"corners_m": [[float(x), float(y)] for x, y in self.corners_m], "height_m": self.room_height_m,
                     "wall_index": self.wall_index,
                     "measured": {k: {"value_m": s.value_m, "sigma_m": s.sigma_m, "frames": s.frames}
                                  for k, s in self.measured.items()}},
            "laser": {"side_margin_m": self.side_margin_m, "floor_margin_m": self.floor_margin_m},
            **({"openings": [o.to_dict() for o in self.openings]} if self.openings else {}),
            **({"sockets": [[float(v) for v in p] for p in self.sockets]} if len(self.sockets) else {}),
        }


def room_layout(width_m: float, depth_m: float, side_margin_m: float, floor_margin_m: float
                ) -> tuple[NDArray[np.float64], int, NDArray[np.float64]]:
    """The laser's rectangular room in the room frame: (floor corners (4, 2) clockwise, the scanned wall's room
    wall index, T_room_from_wall of the scanned wall's own frame, side_margin_m from the left side wall and
    floor_margin_m above the floor). Laid out as arproj/sim's default room: wall 0 from (width, 0) to (0, 0)."""
    corners = np.array([[width_m, 0.0], [0.0, 0.0], [0.0, depth_m], [width_m, depth_m]])
    T_room_from_room_wall = wall_frames(corners)[0][0]
    return corners, 0, T_room_from_room_wall @ make_pose(None, [side_margin_m, floor_margin_m, 0.0])


def simulated_room(wall_width_m: float, wall_height_m: float, survey: LaserConfig | None = None
                   ) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """The simulated scanning site's true room (scanner.laser's rectangle around a wall of this size):
    (floor corners (4, 2), height m, T_room_from_wall of the scanned wall), as the simulated projection
    site is built on it."""
    cfg = (survey or LaserConfig()).room_for_wall(wall_height_m)
    corners, _, T = room_layout(wall_width_m + 2 * cfg.side_margin_m, cfg.room_depth_m, cfg.side_margin_m,
                                cfg.floor_margin_m)
    return corners, cfg.room_height_m, T


def simulated_projection_scene(wall_width_m: float, wall_height_m: float, distance_m: float = 2.5,
                               incidence_deg: float = 0.0, aim_xy: tuple[float, float] | None = None
                               ) -> tuple[dict[str, Any], NDArray[np.float64]]:
    """The simulated projection site around a scanned wall of this size: arproj.sim.site.Site.build's section
    overrides (the scanning simulator's true room, simulated_room; the robot distance_m before the wall, aimed
    at wall point aim_xy, default its centre) and the wall's true T_room_from_wall there. One layout for
    `arproj project --sim --site` and the projection site `arproj devices serve --projection` serves."""
    corners, height, T_room_from_map = simulated_room(wall_width_m, wall_height_m)
    offset = invert(wall_frames(corners)[0][0]) @ T_room_from_map  # the wall's corner on room wall 0
    aim = aim_xy or (wall_width_m / 2, wall_height_m / 2)
    scene = {"room": {"corners_m": corners.tolist(), "height_m": height},
             "robot": {"distance_m": distance_m, "incidence_deg": incidence_deg, "wall": 0,
                       "along_m": float(offset[0, 3] + aim[0]), "aim_height_m": float(offset[1, 3] + aim[1])}}
    return scene, T_room_from_map


def _combine(rooms: list[dict[str, float]], key: str) -> tuple[float, float, int]:
    """Inverse-variance mean of one ROOM_KEYS dimension over the frames that saw it: (value, σ, frames)."""
    pairs = [(r[key], r[key.replace("_m", "_sigma_m")]) for r in rooms
             if math.isfinite(r[key]) and math.isfinite(r[key.replace("_m", "_sigma_m")])]
    if not pairs:
        return math.nan, math.nan, 0
    w = np.array([max(s, 1e-6) for _, s in pairs]) ** -2.0
    return float(w @ [v for v, _ in pairs] / w.sum()), float(w.sum() ** -0.5), len(pairs)


def site_wall_from_scan(key: str, wall: Wall, rooms: list[dict[str, float]], frames: list[dict[str, Any]],
                        survey: LaserConfig, map_dir: Path, scan_log: Path) -> SiteWall:
    """The site file's entry for a scanned wall: the room from each frame's look at it (`rooms`, scanner.laser
    ROOM_KEYS), the wall's place in it from the frames' laser fixes (`frames`: the scan's frame rows), the
    survey's reference geometry (side and floor margin). A dimension no frame saw takes the survey's value
    (recorded with sigma_m null)."""
    cfg = survey.room_for_wall(wall.height_m)
    assumed = {"width": wall.width_m + 2 * cfg.side_margin_m, "depth": cfg.room_depth_m, "height": cfg.room_height_m}
    measured: dict[str, RoomSize] = {}
    for name, value_key in zip(DIMENSIONS, ROOM_KEYS[::2], strict=True):
        value, sigma, n = _combine(rooms, value_key)
        measured[name] = RoomSize(value, sigma, n) if n else RoomSize(assumed[name], None, 0)
    corners, index, T = room_layout(measured["width"].value_m, measured["depth"].value_m, cfg.side_margin_m,
                                    cfg.floor_margin_m)

    def placement(sigma_key: str) -> float:
        # each frame sits on its own fix; the map (all frames stitched) on their mean
        s = np.array([float(f[sigma_key]) for f in frames if math.isfinite(float(f.get(sigma_key, math.nan)))])
        return float(np.sum(s ** -2.0) ** -0.5) if len(s) else math.nan

    along, height = placement("laser_x_sigma_m"), placement("laser_y_sigma_m")
    if not (math.isfinite(along) and math.isfinite(height)):
        raise InputError(f"scan of {wall.name}: no frame has a laser fix, so nothing says where the wall is in "
                         "the room", "scan with the 2-D laser (--laser URL, or --sim) to write a site file")
    return SiteWall(key, wall.name, wall.width_m, wall.height_m, wall.fingerprint(), T, along, height, corners,
                    measured["height"].value_m, index, cfg.side_margin_m, cfg.floor_margin_m, Path(map_dir),
                    Path(scan_log), measured, list(wall.openings), np.asarray(wall.sockets, dtype=np.float64))


# -- reading ---------------------------------------------------------------------------------------------------
def _load_document(path: Path) -> dict[str, Any]:
    """The site file's top level, checked to be one; InputError (one line) otherwise."""
    document = load_document(path, "site file", "scan the site with `arproj scan ... --site FILE`")
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        found = document.get("format") if isinstance(document, dict) else type(document).__name__
        raise InputError(f"{path}: format = {found!r}, not a site file ({FORMAT})",
                         "pass the site.yaml that `arproj scan --site` wrote")
    if not isinstance(document.get("walls"), dict) or not document["walls"]:
        raise InputError(f"{path}: walls = {document.get('walls')!r}: expected a mapping of wall keys", RESCAN)
    return document


class _Fields:
    """Typed access to one wall's entry; every failure names the file, the key path and the value."""

    def __init__(self, path: Path, key: str, entry: Any) -> None:
        self.path, self.key = path, key
        if not isinstance(entry, dict):
            self.fail("", entry, "expected a mapping")
        self.entry = entry

    def fail(self, name: str, value: Any, what: str) -> None:
        raise fail(str(self.path), f"walls.{self.key}{'.' + name if name else ''}", value, what, RESCAN)

    def get(self, name: str) -> Any:
        node: Any = self.entry
        parts = name.split(".")
        for k, part in enumerate(parts):
            if not isinstance(node, dict) or part not in node:
                raise InputError(f"{self.path}: walls.{self.key}.{'.'.join(parts[:k + 1])} is missing", RESCAN)
            node = node[part]
        return node

    def number(self, name: str, positive: bool = False, non_negative: bool = False) -> float:
        value = self.get(name)
        v = number(str(self.path), f"walls.{self.key}.{name}", value, -MAX_M, MAX_M, hint=RESCAN)
        if (positive and v <= 0) or (non_negative and v < 0):
            self.fail(name, value, "must be positive" if positive else "must not be negative")
        return v

    def text(self, name: str) -> str:
        value = text(str(self.path), f"walls.{self.key}.{name}", self.get(name), hint=RESCAN)
        if not value:
            self.fail(name, value, "expected a text")
        return value

    def array(self, name: str, shape: tuple[int, ...]) -> NDArray[np.float64]:
        return float_array(str(self.path), f"walls.{self.key}.{name}", self.get(name),
                           [None if s < 0 else s for s in shape], -MAX_M, MAX_M, max_rows=1000, hint=RESCAN)


def _read_wall(path: Path, key: str, entry: Any) -> SiteWall:
    f = _Fields(path, key, entry)
    T = f.array("T_room_from_wall", (4, 4))
    R = T[:3, :3]
    if not (np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0 and np.allclose(T[3], [0, 0, 0, 1])):
        f.fail("T_room_from_wall", T.tolist(), "not a rigid transform (rotation and translation)")
    corners = f.array("room.corners_m", (-1, 2))
    if len(corners) < 3:
        f.fail("room.corners_m", corners.tolist(), "a floor polygon needs at least 3 corners")
    area2 = float(np.sum(corners[:, 0] * np.roll(corners[:, 1], -1) - np.roll(corners[:, 0], -1) * corners[:, 1]))
    if area2 >= 0:
        f.fail("room.corners_m", corners.tolist(), "must run clockwise seen from above (wall i from corner i)")
    index = f.get("room.wall_index")
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(corners):
        f.fail("room.wall_index", index, f"expected a wall of the room, 0..{len(corners) - 1}")
    width, height = f.number("wall.width_m", positive=True), f.number("wall.height_m", positive=True)
    T_room_from_room_wall, room_wall_width = wall_frames(corners)[index]
    local = np.linalg.solve(T_room_from_room_wall, T)  # the wall frame in its room wall's frame
    if not np.allclose(local[:3, :3], np.eye(3), atol=1e-6) or abs(local[2, 3]) > 1e-6:
        f.fail("T_room_from_wall", T.tolist(), f"does not lie in room wall {index} (its plane and axes)")
    room_height = f.number("room.height_m", positive=True)
    if local[0, 3] < -1e-6 or local[0, 3] + width > room_wall_width + 1e-6 or local[1, 3] < -1e-6 \
            or local[1, 3] + height > room_height + 1e-6:
        f.fail("wall.width_m", width, f"the wall does not fit on room wall {index} "
               f"({room_wall_width:.3f} m wide, {room_height:.3f} m high) where T_room_from_wall puts it")
    measured: dict[str, RoomSize] = {}
    raw = f.get("room.measured")
    if not isinstance(raw, dict):
        f.fail("room.measured", raw, "expected a mapping of width, depth, height")
    for name in DIMENSIONS:
        if name not in raw:
            continue
        at = f"room.measured.{name}"
        sigma = None if f.get(f"{at}.sigma_m") is None else f.number(f"{at}.sigma_m", non_negative=True)
        measured[name] = RoomSize(f.number(f"{at}.value_m", positive=True), sigma,
                                  int(f.number(f"{at}.frames", non_negative=True)))
    folder = path.parent
    # doors, windows and sockets (optional; the DIN zones are drawn beside them), read as the wall file reads them
    where = f"{path}: walls.{key}"
    openings = parse_openings(where, entry.get("openings"), width, height)
    sockets = parse_sockets(where, entry.get("sockets"), width, height)
    return SiteWall(key, f.text("wall.name"), width, height, f.text("wall.fingerprint"), T,
                    f.number("wall_in_room_sigma_m.along", non_negative=True),
                    f.number("wall_in_room_sigma_m.height", non_negative=True), corners, room_height, index,
                    f.number("laser.side_margin_m", non_negative=True), f.number("laser.floor_margin_m"),
                    (folder / f.text("map")).resolve(), (folder / f.text("scan_log")).resolve(), measured,
                    openings, sockets)


def read_site(path: str | Path) -> dict[str, SiteWall]:
    """Every wall of a site file, validated (InputError naming file, key and value)."""
    path = Path(path)
    document = _load_document(path)
    return {str(key): _read_wall(path, str(key), entry) for key, entry in document["walls"].items()}


def read_site_wall(path: str | Path, key: str) -> SiteWall:
    """Wall `key` of a site file; InputError naming the keys there are when it holds no such wall."""
    path = Path(path)
    document = _load_document(path)
    if key not in {str(k) for k in document["walls"]}:
        raise InputError(f"{path}: no wall {key!r} in the site file (walls: "
                         f"{', '.join(sorted(str(k) for k in document['walls']))})", "pass --wall with one of them")
    entry = next(v for k, v in document["walls"].items() if str(k) == key)
    return _read_wall(path, key, entry)


# -- writing ---------------------------------------------------------------------------------------------------
def check_writable(path: str | Path) -> None:
    """Before a scan: the site file may be written there (absent, or a site file; never another kind)."""
    path = Path(path)
    if path.exists():
        _load_document(path)  # not a site file: refused (one line), it is not overwritten
    elif not path.parent.is_dir():
        raise InputError(f"--site {path}: folder {path.parent} does not exist", "create it or pass another path")


class _Dumper(yaml.SafeDumper):
    """Rows of numbers (matrices, corners) on one line each, as a person reads them."""


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def write_site_wall(path: str | Path, wall: SiteWall) -> bool:
    """Add wall `wall.key` to the site file at `path` (made when absent; its other walls kept), atomically.
    Returns True when an entry of that key was replaced. InputError when `path` holds another kind of file."""
    path = Path(path)
    document: dict[str, Any] = {"format": FORMAT, "walls": {}}
    if path.exists():
        document = _load_document(path)
    replaced = wall.key in document["walls"]
    document["walls"][wall.key] = wall.to_dict(path.parent)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(yaml.dump(document, Dumper=_Dumper, sort_keys=False, allow_unicode=True))
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise InputError(f"--site {path}: cannot write it ({err.strerror})") from None
    return replaced
