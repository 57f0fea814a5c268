"""Several walls in one site frame: one beamer frame over an inside corner, each wall drawn with its own map,
handed over from wall to wall as the head turns.

Each update the session predicts from the head's reported angles (head model, the robot's last registered
place in the room) where the beam falls, and registers on the wall it falls on most — the anchor — as ever
(pattern, wall pose, closed loop, gate), in that wall's own ProjectionSession with the robot's prior carried to
that wall through the room; when that wall's pattern gives no pose, on the next wall in the beam. The wall
pose puts the robot in the room, so the projector's pose is known against every wall of the site's room. Each
other wall in the beam gets its own closed loop (check marks on it, photographed, each camera's ray met with
that wall's plane), its own small in-plane correction and its own gate; a wall out of the beam gets no
verdict. The frame is the walls' map meshes drawn in the room frame, each textured by its own wall's raster:
a ray from the projector meets the nearest mesh (the depth test splits the image by wall), and where no
wall's map is — or a wall's gate is closed — nothing is drawn: dark, unknown, never another wall's colours.

    walls = [RoomWall(0, map0, T_room_from_wall0, (w0, h0)), RoomWall(1, map1, T_room_from_wall1, (w1, h1))]
    with RoomSession(rig, walls, robot) as s:     # the robot's wall prior in walls[0]'s frame
        s.aim_at(1, (0.4, 1.2))                   # the beam's centre on wall 1's point (0.4, 1.2) m
        verdicts = s.update()                     # {position in walls: WallVerdict}; s.anchor registered on

The walls' maps may come from one measured room mesh (room.glb, mapping.exports.glb.write_room_glb): each
wall's faces with its own map, the faces on no mapped wall (floor, ceiling, clutter) drawn black, so they hide
what is behind them and show nothing (load_room_map, RoomSession(..., other=room_map.other)).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray

from arproj.session import gate, overlays, registration
from arproj.session import tolerances as tol
from arproj.session.projection import check_mark_raster, textured_mesh
from arproj.session.robot_io import PoseInputs, RobotIO
from arproj.session.session import CLOSED_LOOP_MARKS, ProjectionSession
from arproj.session.wallmap import MAX_GLB_BYTES, MAX_WALL_M, WallMap, mesh_texture
from geometry.errors import InputError
from geometry.inputs import check_file
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, transform_points
from geometry.rig import Rig
from render import MeshRenderer
from render.simplify import PROJECTED_ERROR_PX

MARK_GRID = (16, 10)     # projector-image grid the marks and the drawn area of each wall are taken from
DRAWN_BORDER = 0.02


@dataclass
class RoomWall:
    """A wall of the site's room with its map: index in the room, the map (in its wall frame), the map's wall
    frame in the room (T_room_from_wall) and the wall's size (width, height) metres."""

    index: int
    wall_map: WallMap
    T_room_from_wall: NDArray[np.float64]
    size_m: tuple[float, float]

    def from_room(self, T_room_from_x: NDArray[np.float64]) -> NDArray[np.float64]:
        return invert(self.T_room_from_wall) @ T_room_from_x


def first_wall_hits(walls: list[RoomWall], T_room_from_projector: NDArray[np.float64], intr: Intrinsics,
                    pixels: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Which wall (position in walls, -1: none) each projector pixel's ray (n, 2) meets first within the wall's
    size, and where on it (n, 2) wall metres (NaN: none): the beamer's image split by wall."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    n = len(px)
    best_t, which, where = np.full(n, np.inf), np.full(n, -1, dtype=np.int64), np.full((n, 2), np.nan)
    if n == 0:
        return which, where
    rays_p = intr.rays(px)
    for k, w in enumerate(walls):
        T = w.from_room(T_room_from_projector)
        rays, origin = rays_p @ T[:3, :3].T, T[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -origin[2] / rays[:, 2]
        xy = origin[:2] + t[:, None] * rays[:, :2]
        width, height = w.size_m
        ok = (t > 0) & (t < best_t) & (xy[:, 0] >= 0) & (xy[:, 0] <= width) & (xy[:, 1] >= 0) & (xy[:, 1] <= height)
        best_t[ok], which[ok], where[ok] = t[ok], k, xy[ok]
    return which, where


def _beam_grid(intr: Intrinsics, grid: tuple[int, int], border: float) -> NDArray[np.float64]:
    """Projector pixels (n, 2) of a grid over the beamer's image, `border` (a share of it) off its edges."""
    gx = np.linspace(border, 1 - border, grid[0]) * (intr.width - 1)
    gy = np.linspace(border, 1 - border, grid[1]) * (intr.height - 1)
    return np.array([[x, y] for y in gy for x in gx])


def wall_points_in_view(walls: list[RoomWall], k: int, T_room_from_projector: NDArray[np.float64],
                        intr: Intrinsics, grid: tuple[int, int] = MARK_GRID, border: float = DRAWN_BORDER
                        ) -> NDArray[np.float64]:
    """Wall points (n, 2) of walls[k] where a grid over the beamer's image meets that wall first, on its map."""
    which, xy = first_wall_hits(walls, T_room_from_projector, intr, _beam_grid(intr, grid, border))
    x0, y0, x1, y1 = walls[k].wall_map.extent
    ok = (which == k) & (xy[:, 0] > x0) & (xy[:, 0] < x1) & (xy[:, 1] > y0) & (xy[:, 1] < y1)
    return xy[ok]


def _shift(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    return make_pose(None, [float(xy[0]), float(xy[1]), 0.0])


@dataclass
class RoomMap:
    """room.glb read back: each mapped wall (its faces in its wall frame, its tile of the atlas as the map's
    texture) and the other measured surfaces in the room frame (None: none)."""

    walls: list[RoomWall]
    other: trimesh.Trimesh | None
    source: str = ""


def load_room_map(glb_path: str | Path) -> RoomMap:
    """Read room.glb (mapping.exports.glb.write_room_glb). InputError names the file and what is wrong."""
    path = Path(glb_path)
    redo = "re-export it with mapping.exports.glb.write_room_glb"
    check_file(path, "room map (room.glb)", MAX_GLB_BYTES, redo)
    try:
        loaded = trimesh.load(path, file_type="glb", process=False)
    except Exception as err:  # trimesh raises many exception types for bad files
        raise InputError(f"{path}: not a readable GLB mesh ({type(err).__name__}: {err})", redo) from None
    extras = loaded.metadata.get("extras") if isinstance(loaded, trimesh.Scene) else None
    if not isinstance(loaded, trimesh.Scene) or not isinstance(extras, dict) or extras.get("frame") != "room" \
            or not isinstance(extras.get("walls"), list):
        raise InputError(f"{path}: not a room map (its extras name no room frame and walls)", redo)
    geometries = {name: g for name, g in loaded.geometry.items() if isinstance(g, trimesh.Trimesh)}
    textured = [g for g in geometries.values() if getattr(g.visual, "kind", None) == "texture"]
    others = [g for g in geometries.values() if getattr(g.visual, "kind", None) != "texture" and len(g.faces)]
    if len(textured) != 1 or len(others) > 1:
        raise InputError(f"{path}: a room map holds one textured mesh and at most one other; this one holds "
                         f"{len(textured)} and {len(others)}", redo)
    mesh = textured[0]
    atlas = mesh_texture(mesh)
    if atlas is None or not len(mesh.faces) or not np.all(np.isfinite(mesh.vertices)) or \
            np.abs(mesh.vertices).max() > MAX_WALL_M:
        raise InputError(f"{path}: the walls' mesh has no texture, no faces or vertices beyond {MAX_WALL_M:g} m",
                         redo)
    height, width = atlas.shape[:2]
    uv = np.asarray(getattr(mesh.visual, "uv", None), dtype=np.float64)[np.asarray(mesh.faces)].mean(axis=1)
    col, row = uv[:, 0] * width, (1.0 - uv[:, 1]) * height  # each face's texel in the atlas
    walls: list[RoomWall] = []
    for i, entry in enumerate(extras["walls"]):
        try:
            index = int(entry["index"])
            T = np.asarray(entry["T_room_from_wall"], dtype=np.float64).reshape(4, 4)
            size = tuple(float(v) for v in entry["size_m"])
            ex0, ey0, ex1, ey1 = (float(v) for v in entry["extent_m"])
            c0, r0, tw, th = (int(v) for v in entry["tile_px"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: extras.walls[{i}] lacks index, T_room_from_wall, size_m, extent_m or "
                             "tile_px", redo) from None
        if not (c0 >= 0 and r0 >= 0 and c0 + tw <= width and r0 + th <= height and tw > 0 and th > 0
                and ex1 > ex0 and ey1 > ey0 and len(size) == 2 and np.all(np.isfinite(T))):
            raise InputError(f"{path}: extras.walls[{i}] (wall {index}): its tile or extent is not in the atlas",
                             redo)
        own = (col >= c0) & (col < c0 + tw) & (row >= r0) & (row < r0 + th)
        if not own.any():
            raise InputError(f"{path}: no face of the mesh lies in wall {index}'s tile of the atlas", redo)
        faces = np.asarray(mesh.faces)[own]
        used, inverse = np.unique(faces, return_inverse=True)
        local = transform_points(invert(T), np.asarray(mesh.vertices)[used])
        wall_mesh = trimesh.Trimesh(local, inverse.reshape(-1, 3), process=False)
        uv_from_xy = np.array([[1.0 / (ex1 - ex0), 0.0, -ex0 / (ex1 - ex0)],
                               [0.0, 1.0 / (ey1 - ey0), -ey0 / (ey1 - ey0)]])
        texture = np.ascontiguousarray(atlas[r0:r0 + th, c0:c0 + tw])
        wall_map = WallMap(wall_mesh, texture=texture, uv_from_xy=uv_from_xy, source=f"{path} wall {index}")
        walls.append(RoomWall(index, wall_map, T, (size[0], size[1])))
    other = others[0] if others else None
    return RoomMap(walls, other, str(path))


class RoomProjector:
    """Renders one beamer frame of several walls' rasters in the room frame. Owns its renderers; use `with`."""

    def __init__(self, walls: list[RoomWall], projector: Intrinsics, ctx: object | None = None,
                 other: trimesh.Trimesh | None = None) -> None:
        self.walls = walls
        self.projector = projector
        self.other = other  # measured surfaces on no mapped wall, room frame: drawn black (they hide the walls)
        self._renderer = MeshRenderer(ctx=ctx, max_error_px=PROJECTED_ERROR_PX)  # type: ignore[arg-type]
        self._key: tuple | None = None
        self._empty = True
        self.last_alpha: NDArray[np.uint8] | None = None  # the last frame's alpha (overlays.frame_layers)

    def __enter__(self) -> RoomProjector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def release(self) -> None:
        self._renderer.release()

    def show(self, key: tuple, rasters: dict[int, overlays.WallRaster],
             corrections: dict[int, NDArray[np.float64]]) -> None:
        """Upload the rasters (position in walls → raster; walls without one are not drawn at all) with each
        wall's in-plane correction (content meant for c is drawn at c - correction, where it lands right)."""
        if key == self._key:
            return
        scene = trimesh.Scene()
        for k, raster in rasters.items():
            w = self.walls[k]
            mesh = textured_mesh(w.wall_map, raster)
            T = w.T_room_from_wall @ _shift(-corrections.get(k, np.zeros(2)))
            mesh.vertices = transform_points(T, np.asarray(mesh.vertices))
            scene.add_geometry(mesh, node_name=f"wall{w.index}")
        if self.other is not None:
            scene.add_geometry(self.other, node_name="other_surfaces")
        self._empty = not rasters
        if rasters:
            self._renderer.set_mesh(scene)
        self._key = key

    def render(self, T_room_from_projector: NDArray[np.float64]) -> NDArray[np.uint8]:
        """The pre-warped frame (h, w, 3) uint8; black where no wall is drawn."""
        if self._empty:
            self.last_alpha = np.zeros((self.projector.height, self.projector.width), dtype=np.uint8)
            return np.zeros((self.projector.height, self.projector.width, 3), dtype=np.uint8)
        rgba = self._renderer.render(self.projector, T_room_from_projector, alpha=True).color
        self.last_alpha = rgba[..., 3]
        return np.ascontiguousarray(rgba[..., :3])


@dataclass
class WallVerdict:
    """One wall in the beam: the gate's decision on it, its closed loop, its correction, the pose of the
    projector in its frame (correction applied) and where on it the map may be drawn."""

    wall: int
    decision: gate.GateDecision
    T_wall_from_projector: NDArray[np.float64]
    loop: registration.ClosedLoopResult | None = None
    correction_xy: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    trusted: registration.TrustedRegion | None = None
    cut_by: str = ""  # what cuts the map on this wall (registration.why_cut)

    @property
    def shown(self) -> bool:
        return self.decision.show_map


class _RobotOnWall:
    """The robot as a session registering on another wall of the room sees it: the robot's wall prior (in
    the first wall's frame, where the robot was set up) and its full wall-pose inputs carried to that wall's
    frame through the room. The devices are the robot's own (the room session's caller closes them)."""

    def __init__(self, robot: RobotIO, first: RoomWall, wall: RoomWall) -> None:
        self.robot = robot
        self.head = robot.head
        self.wall = wall
        self.T_wall_from_first = invert(wall.T_room_from_wall) @ first.T_room_from_wall

    def capture(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        return self.robot.capture(frame)

    def show(self, frame: NDArray[np.uint8]) -> None:
        self.robot.show(frame)

    def laser_points(self) -> NDArray[np.float64] | None:
        return self.robot.laser_points()

    def wall_prior(self) -> tuple[NDArray[np.float64], float, str]:
        T_first_from_robot, sigma, source = self.robot.wall_prior()
        return self.T_wall_from_first @ T_first_from_robot, sigma, f"{source}, carried to wall {self.wall.index}"

    def full_pose_inputs(self, normal_robot: NDArray[np.float64] | None = None) -> PoseInputs | None:
        full = getattr(self.robot, "full_pose_inputs", lambda normal: None)(normal_robot)
        if full is None:
            return None
        # the same room and start pose; the plane the pattern measured is this wall, the map's frame its own
        return replace(full, wall_index=self.wall.index, T_room_from_map=self.wall.T_room_from_wall)

    def close(self) -> None:
        pass


def beam_share(walls: list[RoomWall], T_room_from_projector: NDArray[np.float64], intr: Intrinsics,
               grid: tuple[int, int] = MARK_GRID) -> NDArray[np.float64]:
    """Share of a grid over the beamer's image (walls,) that meets each wall first: which walls are in view."""
    which, _ = first_wall_hits(walls, T_room_from_projector, intr, _beam_grid(intr, grid, DRAWN_BORDER))
    return np.bincount(which[which >= 0], minlength=len(walls))[:len(walls)] / float(len(which))


class RoomSession:
    """A projection session over several walls of one room, handing over from wall to wall as the head turns.

    Each update predicts where the beam falls from the head's reported angles (head model, the robot's last
    known place in the room) and registers on the wall that takes most of it — the anchor: its own
    ProjectionSession (pattern, wall pose, closed loop, gate), the robot's prior carried to that wall's frame.
    Every other wall with part of its map in the beam gets its own closed loop and gate (_judge); a wall out
    of the beam gets no verdict and is not drawn. The robot's wall prior is in walls[0]'s frame."""

    def __init__(self, rig: Rig, walls: list[RoomWall], robot: RobotIO, ctx: object | None = None,
                 tolerance_m: float = tol.REGISTRATION_TOLERANCE_M, other: trimesh.Trimesh | None = None) -> None:
        if not walls:
            raise ValueError("RoomSession needs at least one wall")
        self.rig = rig
        self.walls = walls
        self.robot = robot
        self.ctx = ctx
        self.tolerance_m = tolerance_m
        self.sessions: dict[int, ProjectionSession] = {}  # position in walls → the session registering on it
        self.anchor = 0
        self.session = self._session_on(0)
        self.projector_intr = self.session.projector_intr
        self.room_projector = RoomProjector(walls, self.projector_intr, ctx, other)
        self.verdicts: dict[int, WallVerdict] = {}
        self.last_frame: NDArray[np.uint8] | None = None
        self.last_words: list[str] = []
        self.log: list[str] = []  # the handovers (each wall's session keeps its own log)
        self._T_room_from_robot_known: NDArray[np.float64] | None = None  # at the last registration

    def __enter__(self) -> RoomSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for s in self.sessions.values():
            s.close()
        self.room_projector.release()

    def _session_on(self, k: int) -> ProjectionSession:
        if k not in self.sessions:
            robot = self.robot if k == 0 else _RobotOnWall(self.robot, self.walls[0], self.walls[k])
            self.sessions[k] = ProjectionSession(self.rig, self.walls[k].wall_map, robot, ctx=self.ctx,
                                                 tolerance_m=self.tolerance_m)
        return self.sessions[k]

    @property
    def T_room_from_projector(self) -> NDArray[np.float64] | None:
        """The registered projector in the room, without any wall's closed-loop correction."""
        reg = self.session.registration
        if reg is None:
            return None
        return self.walls[self.anchor].T_room_from_wall @ _shift(-reg.correction_xy) @ reg.T_wall_from_projector

    @property
    def T_room_from_robot(self) -> NDArray[np.float64] | None:
        reg = self.session.registration
        return None if reg is None else self.walls[self.anchor].T_room_from_wall @ reg.T_wall_from_robot

    def predicted_T_room_from_projector(self) -> NDArray[np.float64]:
        """Where the projector is in the room by the head's reported angles alone: the head model on the robot's
        last registered place in the room (before any registration: its prior on walls[0])."""
        T_room_from_robot = self._T_room_from_robot_known
        if T_room_from_robot is None:
            T_room_from_robot = self.walls[0].T_room_from_wall @ self.robot.wall_prior()[0]
        return T_room_from_robot @ self.session.T_robot_from_projector_model(self.session.head_deg())

    def anchor_order(self) -> list[int]:
        """The walls in the beam by the predicted pose, the one it falls on most first (the current anchor
        first on a tie); the current anchor alone when the beam meets no wall."""
        share = beam_share(self.walls, self.predicted_T_room_from_projector(), self.projector_intr)
        order = sorted((k for k in range(len(self.walls)) if share[k] > 0),
                       key=lambda k: (-share[k], k != self.anchor))
        return order or [self.anchor]

    def aim_at(self, k: int, wall_xy: tuple[float, float]) -> tuple[float, float]:
        """Turn the head so the beam's centre lands on point (x, y) m of walls[k] (the robot's prior carried
        to that wall); the next update hands over to whichever wall the beam then falls on most."""
        return self._session_on(k).aim_at(wall_xy)

    def update(self, show: bool = True) -> dict[int, WallVerdict]:
        """One cycle: hand over to the wall the beam falls on most, its session's update, then each other wall
        in view its closed loop and gate; the frame draws each wall whose gate is open, on its own map; a
        warning when none is."""
        for tried, anchor in enumerate(self.anchor_order()):  # the next wall when the pattern measured no pose
            if anchor != self.anchor:
                why = "the beam falls on it most" if not tried else \
                    f"wall {self.walls[self.anchor].index}'s pattern gave no wall pose"
                self.log.append(f"handover: registering on wall {self.walls[anchor].index} (was wall "
                                f"{self.walls[self.anchor].index}): {why}")
                self.anchor, self.session = anchor, self._session_on(anchor)
            first = self.session.update(show=False)
            if self.session.registration is not None:
                break
        reg = self.session.registration
        anchor = self.anchor
        verdicts: dict[int, WallVerdict] = {}
        T_room_from_projector = self.T_room_from_projector
        if reg is not None and T_room_from_projector is not None:
            self._T_room_from_robot_known = self.T_room_from_robot
            verdicts[anchor] = WallVerdict(self.walls[anchor].index, first, reg.T_wall_from_projector.copy(),
                                           reg.loop, reg.correction_xy.copy(), reg.trusted, reg.cut_by)
            share = beam_share(self.walls, T_room_from_projector, self.projector_intr)
            for k in range(len(self.walls)):
                if k != anchor and share[k] > 0:
                    verdicts[k] = self._judge(k)
        self.verdicts = verdicts
        if show:
            self.last_frame = self.render_frame(first)
            self.robot.show(self.last_frame)
        return verdicts

    # -- another wall ------------------------------------------------------------------------------------
    def _judge(self, k: int) -> WallVerdict:
        """Closed loop and gate on walls[k] from the registration made on the anchor wall."""
        s, reg, w = self.session, self.session.registration, self.walls[k]
        assert reg is not None and s.last_evidence is not None
        T_room_from_projector, T_room_from_robot = self.T_room_from_projector, self.T_room_from_robot
        assert T_room_from_projector is not None and T_room_from_robot is not None
        T_wall_from_projector = w.from_room(T_room_from_projector)
        T_wall_from_robot = w.from_room(T_room_from_robot)
        drawn = wall_points_in_view(self.walls, k, T_room_from_projector, self.projector_intr)
        loop = self._closed_loop(k, drawn, T_wall_from_robot)
        correction = np.zeros(2)
        if loop.seen.sum() >= tol.CLOSED_LOOP_MIN_FEATURES and \
                np.linalg.norm(loop.offset_xy) <= tol.CLOSED_LOOP_MAX_CORRECTION_M:
            correction = loop.offset_xy
        trusted, cut_by = None, ""
        ev = gate.RegistrationEvidence(pose_failure=None, head_command_error_deg=s.last_evidence.head_command_error_deg,
                                       robot_motion_m=s.last_evidence.robot_motion_m,
                                       laser_plane_offset_m=s.last_evidence.laser_plane_offset_m,
                                       head_failure=s.last_evidence.head_failure)
        ev.closed_loop_expected = len(loop.seen)
        ev.closed_loop_errors_m = np.linalg.norm(loop.errors_xy - correction, axis=1)
        ev.stereo_residual_px = loop.residual_px if loop.seen.any() else None
        if len(drawn):
            # the pose's error on this wall, as on the first: its plane's offset and tilt, the pose's own σ, the
            # calibration — the lever from the pattern's centre measured in the room
            aim_room = transform_points(self.walls[self.anchor].T_room_from_wall,
                                        registration.aim_point_on_wall(reg.T_wall_from_projector, self.projector_intr))
            drawn_room = np.column_stack([drawn, np.zeros(len(drawn))]) @ w.T_room_from_wall[:3, :3].T \
                + w.T_room_from_wall[:3, 3]
            lever = np.linalg.norm(drawn_room - aim_room, axis=1)
            mid = transform_points(invert(T_wall_from_projector), [[*drawn[len(drawn) // 2], 0.0]])
            footprint = registration.pixel_footprint_m(T_wall_from_projector, self.projector_intr,
                                                       self.projector_intr.project(mid)[0])
            # the fused pose's own error at this wall's points, from its full covariance (as on the first wall)
            pose_sigma = None if reg.pose_covariance is None else \
                registration.pose_sigma_on_wall_m(drawn, T_wall_from_robot, reg.pose_covariance)
            terms = registration.registration_sigma_terms(
                reg.plane.centre_distance_95_m, reg.plane.normal_95_deg, T_wall_from_projector, drawn,
                drawn[0], reg.in_plane_sigma_m if pose_sigma is None else reg.frame_sigma_m, footprint,
                reg.calibration_px, reg.roll_sigma_rad, lever_m=lever, pose_sigma_m=pose_sigma)
            local = terms.total
            trusted = registration.trusted_region(drawn, local, self.tolerance_m)
            cut_by = registration.why_cut(terms, drawn, ~registration.within_tolerance(local, self.tolerance_m),
                                          T_wall_from_robot, reg.pose_covariance)
            if len(ev.closed_loop_errors_m):
                trusted, sigma = registration.checked_region(
                    trusted, float(np.max(ev.closed_loop_errors_m)) + ev.robot_motion_m, self.tolerance_m)
            else:
                sigma = trusted.sigma_m if trusted.usable else float(local.max())
            ev.pose_sigma_m = max(sigma, reg.sigma_m)
        else:
            ev.pose_failure = f"wall {w.index}: none of its map is in the beam"
        decision = gate.decide(ev, self.tolerance_m)
        return WallVerdict(w.index, decision, _shift(correction) @ T_wall_from_projector, loop, correction, trusted,
                           cut_by)

    def _closed_loop(self, k: int, drawn: NDArray[np.float64], T_wall_from_robot: NDArray[np.float64]
                     ) -> registration.ClosedLoopResult:
        """Check marks on walls[k] only (the other walls dark), photographed; each camera's ray met with that
        wall's plane."""
        s = self.session
        rig = s.rig
        step = max(1, int(np.ceil(len(drawn) / CLOSED_LOOP_MARKS)))
        marks = drawn[::step]
        if len(marks) < tol.CLOSED_LOOP_MIN_FEATURES:
            return registration.ClosedLoopResult(marks, np.zeros((0, 2)), np.zeros(len(marks), bool),
                                                 float("nan"), float("nan"))
        cam_l, cam_r = rig.intrinsics["camera_left"], rig.intrinsics["camera_right"]
        T_robot_from_left = rig.pose("T_robot_from_camera_left")
        T_right_from_left = rig.pose("T_camera_right_from_camera_left")
        T_room_from_projector = self.T_room_from_projector
        assert T_room_from_projector is not None
        aim = self.walls[k].from_room(T_room_from_projector)[:3, 3]
        distance = float(abs(aim[2]))
        radius_m = registration.mark_radius_m(max(distance, 0.3), cam_l)
        raster = check_mark_raster(self.walls[k].wall_map, marks, radius_m)
        self.room_projector.show(("marks", k, marks.round(5).tobytes()), {k: raster}, {})
        frame = self.room_projector.render(T_room_from_projector)
        left, right = self.robot.capture(frame)
        T_robot_from_right = T_robot_from_left @ invert(T_right_from_left)
        uv_l = registration.predict_camera_pixels(marks, T_wall_from_robot, T_robot_from_left, cam_l)
        uv_r = registration.predict_camera_pixels(marks, T_wall_from_robot, T_robot_from_right, cam_r)
        # each mark's radius in the camera from its own distance (the wall may run away obliquely)
        marks_robot = transform_points(invert(T_wall_from_robot), np.column_stack([marks, np.zeros(len(marks))]))
        dist = np.linalg.norm(marks_robot - T_robot_from_left[:3, 3], axis=1)
        r_px = radius_m * cam_l.fx / dist
        found_l = registration.find_marks(left, uv_l, r_px)
        found_r = registration.find_marks(right, uv_r, r_px)
        loop = registration.measure_marks(marks, found_l, found_r, cam_l, cam_r, T_right_from_left,
                                          T_wall_from_robot @ T_robot_from_left)
        s.log.append(f"wall {self.walls[k].index}: " + loop.summary())
        return loop

    # -- frame -------------------------------------------------------------------------------------------
    def render_frame(self, first: gate.GateDecision) -> NDArray[np.uint8]:
        """Each wall whose gate is open drawn with its own map (clipped to its trusted region); the others left
        dark and named; the warning frame when no wall may be shown."""
        intr = self.projector_intr
        shown = {k: v for k, v in self.verdicts.items() if v.shown}
        if not shown:
            self.last_words = list(first.craftsman) or [gate.SAY_NO_WALL_POSE]
            return overlays.warning_frame(intr.width, intr.height, self.last_words)
        rasters, corrections, key = {}, {}, []
        for k, v in shown.items():
            clip = None if v.trusted is None else v.trusted.polygon
            sigma = round(v.decision.registration_sigma_m / 0.0005) * 0.0005
            rasters[k] = overlays.draw_map(self.walls[k].wall_map, sigma, None, True, clip=clip)
            corrections[k] = v.correction_xy
            clip_key = None if clip is None else clip.round(3).tobytes()
            key.append((k, sigma, clip_key, v.correction_xy.round(5).tobytes()))
        self.room_projector.show(("map", *key), rasters, corrections)
        T = self.T_room_from_projector
        assert T is not None
        frame = self.room_projector.render(T).copy()
        bound = max(v.decision.bound_m for v in shown.values())
        lines = [overlays.say_accuracy(bound, [self.walls[k].index for k in shown])]
        if any(r.zone_texels for r in rasters.values()):
            lines.append(overlays.say_zones())
        hidden = [self.walls[k].index for k in self.verdicts if k not in shown]
        if hidden:
            lines.append(overlays.say_dark_walls(hidden))
        self.last_words = lines
        assert self.room_projector.last_alpha is not None
        busy, mapped = overlays.frame_layers(self.room_projector.last_alpha)
        present = tuple(sorted({c for r in rasters.values() for c in r.classes}))
        return overlays.draw_legend(frame, lines, present, busy, mapped)
