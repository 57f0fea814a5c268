"""A scan, a map and their poses as ROS 2 messages (mapping.ros.bag writes them).

Topics (stamps: the scan's own clock, from the log's creation time on):
  /tf_static  tf2_msgs/msg/TFMessage  room → wall (the scan knows no room: identity), robot → laser, robot →
              laser_vertical (both 2-D lasers sit at the drive frame's origin, standoff in front of the wall)
  /tf         tf2_msgs/msg/TFMessage  room → robot at each frame (the localised pose the log holds; robot is the
              drive frame, on the wall plane, x along the wall, y up, z into the room: REP 105's one-parent
              tree), robot → scanner along every pass (the drives' position)
  /scanner/pass  arproj_msgs/msg/ScannerPass  every pass with its samples (msg/arproj_msgs__ScannerPass.msg)
  /laser, /laser/vertical  sensor_msgs/msg/LaserScan  the two lasers' turns at each frame (a live scan only:
              the log keeps the fix, not the turns)
  /map        nav_msgs/msg/OccupancyGrid  the drill verdict of each cell (mapping.drill.verdict_raster, as
              map_server.pgm): 0 safe, 100 keep away, −1 unknown
  /map/<channel>  nav_msgs/msg/OccupancyGrid  the same verdicts, −1 also wherever that channel did not look and
              100 where it responded with nothing mapped to explain it: no grid calls free what /map does not
  /objects    visualization_msgs/msg/MarkerArray  line strips coloured by class (ns "measured"), inferred
              stretches pale (ns "inferred"), fasteners as cylinders, the class and depth as text (ns "label")
"""

from __future__ import annotations

import math
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping import drill
from mapping.evidence import Coverage
from mapping.mapfile import MappedObject
from mapping.ros.bag import CdrBuffer, RosBag, header, tf_message
from mapping.scandata import ScanData
from mapping.texture import CLASS_COLOURS
from scanner.channels import NAMES as CHANNEL_NAMES
from scanner.laser import LaserConfig, Scan
from scanner.sim.world import FrameReport

TF, TF_STATIC = "tf2_msgs/msg/TFMessage", "tf2_msgs/msg/TFMessage"
PASS_TYPE = "arproj_msgs/msg/ScannerPass"
GRID_TYPE = "nav_msgs/msg/OccupancyGrid"
MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
LASER_TYPE = "sensor_msgs/msg/LaserScan"
LASER_TOPICS = {"H": ("/laser", "laser"), "V": ("/laser/vertical", "laser_vertical")}
FREE, OCCUPIED, UNKNOWN = 0, 100, -1
_GRID_VALUE = {drill.VERDICT_CODES[drill.SAFE]: FREE, drill.VERDICT_CODES[drill.KEEP_AWAY]: OCCUPIED,
               drill.VERDICT_CODES[drill.UNKNOWN]: UNKNOWN}
TF_PERIOD_S = 0.5  # the scanner's pose along a pass, this often in scan time (RViz draws it moving)
NS = 1_000_000_000
PASS_ARRAYS = ("time_s", "drive_u_m", "drive_v_m", "x_m", "y_m", *CHANNEL_NAMES)
AXIS_CODES = {"x": 0, "y": 1}  # as the log codes a pass's axis; 2: a following pass along both drives
# marker types (visualization_msgs/msg/Marker)
LINE_STRIP, CYLINDER, TEXT_VIEW_FACING = 4, 3, 9


def start_ns(meta: dict[str, Any]) -> int:
    """The scan's time zero as ROS time: the log's creation (ISO-8601 UTC), 0 when the log does not say."""
    try:
        return int(datetime.fromisoformat(str(meta["created"])).timestamp()) * NS
    except (KeyError, ValueError):
        return 0


def robot_pose(x_m: float, y_m: float, phi_rad: float) -> NDArray[np.float64]:
    """T_room_from_robot of a frame pose (x, y, roll φ in the wall plane; the room frame is the wall's)."""
    T = np.eye(4)
    c, s = math.cos(phi_rad), math.sin(phi_rad)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = (x_m, y_m)
    return T


def static_transforms(t_ns: int, laser: LaserConfig | None = None
                      ) -> list[tuple[NDArray[np.float64], str, str, int]]:
    laser = laser or LaserConfig()
    # the horizontal laser's plane: x along the wall, y into the room (z = x × y points down)
    T_h = np.eye(4)
    T_h[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    T_h[2, 3] = laser.standoff_m
    T_v = np.eye(4)  # the vertical laser's plane is parallel to the wall: the robot's own axes
    T_v[2, 3] = laser.standoff_m
    return [(np.eye(4), "room", "wall", t_ns), (T_h, "robot", "laser", t_ns), (T_v, "robot", "laser_vertical", t_ns)]


def _drive(u_m: float, v_m: float) -> NDArray[np.float64]:
    T = np.eye(4)
    T[:2, 3] = (u_m, v_m)
    return T


class ScanRecorder:
    """Writes a scan into a RosBag as it happens (scanner.run.ScanWatcher), or from a log (`replay`)."""

    def __init__(self, bag: RosBag, t0_ns: int = 0, laser: LaserConfig | None = None) -> None:
        self.bag, self.t0_ns, self.laser = bag, int(t0_ns), laser or LaserConfig()
        self.bag.write_cdr("/tf_static", TF_STATIC, tf_message(static_transforms(self.t0_ns, self.laser)), self.t0_ns)
        self.last_ns = self.t0_ns

    def at(self, t_s: float) -> int:
        t = self.t0_ns + round(float(t_s) * NS)
        self.last_ns = max(self.last_ns, t)
        return t

    def frame(self, row: dict[str, Any], report: FrameReport | None = None) -> None:
        t = self.at(row["time_s"])
        pose = robot_pose(float(row["est_x_m"]), float(row["est_y_m"]), float(row["est_phi_rad"]))
        self.bag.write_cdr("/tf", TF, tf_message([(pose, "room", "robot", t)]), t)
        if report is not None and report.scans:
            for head, scan in report.scans.items():
                topic, frame_id = LASER_TOPICS[head]
                self.bag.write_cdr(topic, LASER_TYPE, self.laser_scan(scan, frame_id, t), t)

    def laser_scan(self, scan: Scan, frame_id: str, t_ns: int) -> bytes:
        """sensor_msgs/LaserScan, CDR-encoded."""
        angles, ranges = (np.asarray(a, dtype=np.float64) for a in scan)
        step = float(angles[1] - angles[0]) if len(angles) > 1 else self.laser.angular_step_rad
        out = np.where(np.isfinite(ranges), ranges, np.inf)  # REP 117: no return is +inf
        cdr = CdrBuffer().header(t_ns, frame_id)
        for value in (angles[0], angles[-1], step, 0.0, 0.0, 0.05, self.laser.max_range_m):
            cdr.number("f4", float(value))
        return cdr.array("f4", out).array("f4", []).bytes()

    def scanned(self, row: dict[str, Any], samples: dict[str, NDArray[Any]]) -> None:
        t = self.at(row["t_start_s"])
        nan = np.full(len(samples["time_s"]), np.nan)
        axis = int(samples["axis"][0]) if len(samples.get("axis", ())) else AXIS_CODES.get(row["axis"], 2)
        cdr = CdrBuffer().header(t, "wall").number("i4", int(row["pass_id"])).number("i4", int(row["frame_id"]))
        cdr.number("i1", axis).number("i1", int(row["direction"]))
        for key in PASS_ARRAYS:
            cdr.array("f8", samples.get(key, nan))
        self.bag.write_cdr("/scanner/pass", PASS_TYPE, cdr.bytes(), t)
        times = np.asarray(samples["time_s"], dtype=np.float64)
        if len(times) == 0:
            return
        # the drives' position through the pass, every TF_PERIOD_S and at its last sample
        keep = np.unique(np.r_[np.searchsorted(times, np.arange(times[0], times[-1], TF_PERIOD_S)), len(times) - 1])
        u, v = samples["drive_u_m"], samples["drive_v_m"]
        for i in keep:
            ti = self.at(times[i])
            self.bag.write_cdr("/tf", TF, tf_message([(_drive(u[i], v[i]), "robot", "scanner", ti)]), ti)

    def replay(self, data: ScanData) -> None:
        """The scan a log holds: its frames and passes in the order they were made."""
        f = data.frames
        frame_time = {int(fid): float(t) for fid, t in zip(f.get("frame_id", []), f.get("time_s", []), strict=True)}
        s = data.samples
        if "pass_id" not in s or len(s["pass_id"]) == 0:
            for i in np.argsort(list(frame_time.values())):
                self.frame({k: v[i] for k, v in f.items()})
            return
        order = np.argsort(s["time_s"], kind="stable")
        pass_ids, first = np.unique(s["pass_id"][order], return_index=True)
        done_frames: set[int] = set()
        for pid in pass_ids[np.argsort(first)]:
            idx = order[s["pass_id"][order] == pid]
            fid = int(s["frame_id"][idx[0]])
            if fid not in done_frames and fid in frame_time:
                done_frames.add(fid)
                i = list(frame_time).index(fid)
                self.frame({k: v[i] for k, v in f.items()})
            direction = int(s["direction"][idx[0]]) if "direction" in s else 0
            self.scanned({"pass_id": int(pid), "frame_id": fid, "axis": "", "direction": direction,
                          "t_start_s": float(s["time_s"][idx[0]])}, {k: v[idx] for k, v in s.items()})

    def map(self, objects: list[MappedObject], coverage: Coverage, t_s: float | None = None) -> None:
        """/map, one grid per channel and /objects, at t_s (default: after the last message so far)."""
        t = self.at(t_s) if t_s is not None else self.last_ns
        for topic, grid in map_grids(objects, coverage).items():
            self.bag.write_cdr(topic, GRID_TYPE, occupancy_grid(grid, coverage, t), t)
        self.bag.write("/objects", MARKERS_TYPE, markers(objects, t), t)


def map_grids(objects: list[MappedObject], coverage: Coverage) -> dict[str, NDArray[np.int8]]:
    """{topic: (height, width) int8 grid}: /map the drill verdicts, /map/<channel> those verdicts where the
    channel looked (unknown elsewhere), occupied where it responded unexplained."""
    verdicts = drill.verdict_raster(objects, coverage, coverage.wall_bounds)
    lut = np.full(256, UNKNOWN, np.int8)
    for code, value in _GRID_VALUE.items():
        lut[code] = value
    base = lut[verdicts.astype(np.uint8)]
    grids = {"/map": base}
    for channel in coverage.channels:
        g = base.copy()
        g[~coverage.covered[channel]] = UNKNOWN
        g[coverage.covered[channel] & coverage.response[channel]] = OCCUPIED
        grids[f"/map/{channel}"] = g
    return grids


def occupancy_grid(grid: NDArray[np.int8], coverage: Coverage, t_ns: int) -> bytes:
    """nav_msgs/OccupancyGrid in the wall frame, CDR-encoded."""
    info = coverage.info.to_ros()["info"]
    origin = info["origin"]
    cdr = CdrBuffer().header(t_ns, "wall").number("i4", t_ns // NS).number("u4", t_ns % NS)
    cdr.number("f4", info["resolution"]).number("u4", info["width"]).number("u4", info["height"])
    for value in (*origin["position"].values(), *origin["orientation"].values()):
        cdr.number("f8", value)
    # row-major from the origin cell (the lower-left): the grid's row 0 is its lowest row already
    return cdr.array("i1", grid).bytes()


def _colour(cls: str, alpha: float) -> dict[str, float]:
    r, g, b = CLASS_COLOURS.get(cls, CLASS_COLOURS["unknown"])
    return {"r": r / 255.0, "g": g / 255.0, "b": b / 255.0, "a": alpha}


def _points(xy: NDArray[np.float64]) -> list[dict[str, float]]:
    return [{"x": float(x), "y": float(y), "z": 0.0} for x, y in xy]


def _marker(t_ns: int, ns: str, marker_id: int, kind: int, colour: dict[str, float], **fields: Any) -> dict[str, Any]:
    pose = fields.pop("pose", {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                               "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}})
    scale = fields.pop("scale", {"x": 0.0, "y": 0.0, "z": 0.0})
    return {"header": header(t_ns, "wall"), "ns": ns, "id": marker_id, "type": kind, "action": 0, "pose": pose,
            "scale": scale, "color": colour, "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False,
            "points": fields.pop("points", []), "colors": [], "texture_resource": "",
            "texture": {"header": header(t_ns, ""), "format": "", "data": []},
            "uv_coordinates": [], "text": fields.pop("text", ""), "mesh_resource": "",
            "mesh_file": {"filename": "", "data": []}, "mesh_use_embedded_materials": False}


def stretches(obj: MappedObject) -> list[tuple[bool, NDArray[np.float64]]]:
    """(measured, points) of each run of equally measured segments of a line or outline, in order."""
    pts = obj.points_m
    if obj.shape == "outline":
        ring = pts if np.allclose(pts[0], pts[-1]) else np.vstack([pts, pts[:1]])
        return [(bool(np.all(obj.measured_segments())), ring)]
    flags = obj.measured_segments()
    out: list[tuple[bool, NDArray[np.float64]]] = []
    start = 0
    for i in range(1, len(flags) + 1):
        if i == len(flags) or flags[i] != flags[start]:
            out.append((bool(flags[start]), pts[start:i + 1]))
            start = i
    return out


def label(obj: MappedObject) -> str:
    depth = "depth unknown" if obj.depth_m is None else f"depth {1000 * obj.depth_m:.0f} mm"
    inferred = "" if bool(np.all(obj.measured_segments())) else ", partly inferred"
    return f"{obj.cls.replace('_', ' ')}, {depth}{inferred}"


def markers(objects: list[MappedObject], t_ns: int) -> dict[str, Any]:
    """visualization_msgs/MarkerArray of the map's objects in the wall frame."""
    out: list[dict[str, Any]] = []
    for obj in objects:
        width = max(float(obj.width_m), 0.002)
        if obj.shape == "point":
            (x, y), = obj.points_m
            out.append(_marker(t_ns, "measured", len(out), CYLINDER, _colour(obj.cls, 1.0),
                               pose={"position": {"x": float(x), "y": float(y), "z": 0.0},
                                     "orientation": {"x": 0.7071067811865476, "y": 0.0, "z": 0.0,
                                                     "w": 0.7071067811865476}},
                               scale={"x": width, "y": width, "z": 0.002}))
        else:
            for measured, pts in stretches(obj):
                out.append(_marker(t_ns, "measured" if measured else "inferred", len(out), LINE_STRIP,
                                   _colour(obj.cls, 1.0 if measured else 0.35), points=_points(pts),
                                   scale={"x": width, "y": 0.0, "z": 0.0}))
        x, y = obj.points_m[0]
        out.append(_marker(t_ns, "label", len(out), TEXT_VIEW_FACING, _colour(obj.cls, 1.0), text=label(obj),
                           pose={"position": {"x": float(x), "y": float(y), "z": 0.02},
                                 "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                           scale={"x": 0.0, "y": 0.0, "z": 0.02}))
    return {"markers": out}


def record_map(path: str | Path, data: ScanData, objects: list[MappedObject], coverage: Coverage) -> Path:
    """A bag at `path` of the scan a log holds and the map made from it (`arproj map --record`, `arproj export
    mcap`): tf, the passes, then the grids and objects after the last pass."""
    with RosBag(path) as bag:
        recorder = ScanRecorder(bag, start_ns(data.meta))
        recorder.replay(data)
        recorder.map(objects, coverage)
    return bag.path
