"""The simulated site: a room, the projection robot with its head, projector, stereo cameras and laser, and
the exact truth of everything.

    site = Site.build(seed=0)                          # the default scene (arproj/sim/scenes/default.yaml)
    photo = site.photograph("camera_left", projector_image=pattern)
    photo.image, photo.wall_index, photo.wall_xy       # what the camera sees, and per-pixel truth

Frames (geometry/frames.py): room (z up, floor z = 0) ─ wall i; room ─ robot ─ head ─ projector;
robot ─ camera_left ─ camera_right. The robot stands on a floor that is not quite level: each placement draws
its true roll and pitch (robot.floor_tilt_sigma_deg), which everything rendered, cast and reported as truth
follows; its localization knows only x, y and heading. Everything random (textures, head imperfections,
localization error, floor tilt, angle noise, sensor noise, laser and range noise) comes from named streams of
one seed, so the same seed and the same calls give the same images.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from itertools import pairwise
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import moderngl
import numpy as np
from numpy.typing import ArrayLike, NDArray

from arproj.sim import optics
from arproj.sim.gl_scene import ProjectorState, SceneRenderer
from arproj.sim.robot import (
    HeadDrive,
    camera_intrinsics,
    camera_poses,
    floor_pose,
    mount_error,
    nominal_head,
    place_in_front_of_wall,
    projector_intrinsics,
    true_head,
)
from arproj.sim.room import (
    KIND_TARGET,
    KIND_WALL,
    Room,
    Surface,
    Target,
    Wall,
    raycast,
)
from arproj.sim.scene import Scene, load_scene
from geometry.errors import InputError
from geometry.head import HeadModel
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, roll_pitch, tilt_rotation, transform_points
from render.distortion import distortion_map

CAMERAS = ("camera_left", "camera_right")
MIN_CLEARANCE_M = 0.05       # cameras and projector must be this far inside the room
MAX_AIM_INCIDENCE_DEG = 85.0  # steeper than this, the projector counts as facing away from the wall
VIEW_CACHE_SIZE = 4          # camera views kept (both cameras at two poses)
# new streams go last: SeedSequence.spawn gives the first ones the same seeds whatever follows them
_STREAMS = ("room", "head", "drive", "localization", "photo", "laser", "range", "sensor", "mount", "tilt")


@dataclass
class Truth:
    """Per-pixel ground truth of a camera or the projector by exact ray casting (double precision).

    wall_index (h, w) int16: wall hit (-1: floor, ceiling, a target, or nothing); wall_xy (h, w, 2) float32
    wall coordinates in metres (NaN off the walls); target_index (h, w) int16 (-1: none) and target_xy
    (h, w, 2) float32 in the target's frame; points_room (h, w, 3) float64; depth (h, w) float32 metres along
    the optical axis (NaN: nothing).
    """

    wall_index: NDArray[np.int16]
    wall_xy: NDArray[np.float32]
    target_index: NDArray[np.int16]
    target_xy: NDArray[np.float32]
    points_room: NDArray[np.float64]
    depth: NDArray[np.float32]


@dataclass
class Photo:
    """A photograph: image (h, w) or (h, w, 3) uint8, and lazily computed ground truth for every pixel."""

    image: NDArray[np.uint8]
    camera: str
    intr: Intrinsics
    T_room_from_camera: NDArray[np.float64]
    exposure_s: float
    _truth_source: Any = field(repr=False)

    @cached_property
    def truth(self) -> Truth:
        return self._truth_source()

    @property
    def wall_index(self) -> NDArray[np.int16]:
        return self.truth.wall_index

    @property
    def wall_xy(self) -> NDArray[np.float32]:
        return self.truth.wall_xy


class LaserScan(NamedTuple):
    """angles_rad (n,) in the laser frame (0 = robot forward, counter-clockwise), ranges_m (n,) with
    noise and outliers (inf: no return), and T_robot_from_laser."""

    angles_rad: NDArray[np.float64]
    ranges_m: NDArray[np.float64]
    T_robot_from_laser: NDArray[np.float64]

    def points_robot(self) -> NDArray[np.float64]:
        """(n, 3) returns in the robot frame (rows with infinite range are dropped)."""
        ok = np.isfinite(self.ranges_m)
        r, a = self.ranges_m[ok], self.angles_rad[ok]
        local = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(ok.sum())])
        return transform_points(self.T_robot_from_laser, local)


@dataclass
class RangeImage:
    """depth (h, w) float32 metres along the optical axis (NaN: missing), the camera's intrinsics and pose.
    Unpacks as `depth, intr = site.range_image(T)`."""

    depth: NDArray[np.float32]
    intr: Intrinsics
    T_room_from_rangecam: NDArray[np.float64]

    def __iter__(self) -> Iterator[Any]:
        return iter((self.depth, self.intr))


_shared_ctx: moderngl.Context | None = None


def shared_context() -> moderngl.Context:
    """One GL context for every site built without its own (created on first use, lives with the process)."""
    global _shared_ctx
    if _shared_ctx is None:
        from render.gl import create_context

        _shared_ctx = create_context()
        # Sites that are dropped without release() queue their GPU objects; the renderer frees them (ctx.gc())
        # the next time it draws, with the context current.
        _shared_ctx.gc_mode = "context_gc"
    return _shared_ctx


def _image_key(image: NDArray) -> str:
    return hashlib.blake2b(np.ascontiguousarray(image).view(np.uint8), digest_size=16).hexdigest() + str(
        (image.shape, image.dtype))


@dataclass
class _View:
    """A camera view's image-independent part on the sensor grid (h, w): surface reflectance (albedo rgb),
    projector irradiance per unit linear light (lux), where each pixel's light comes from in the projector
    image (map_u, map_v) and with what blur σ (projector pixels), depth along the axis (0: nothing).
    Radiances (cd/m²) follow: ambient = albedo · E_ambient / π, gain = albedo · irradiance / π."""

    albedo_rgb: NDArray[np.float32]
    irradiance: NDArray[np.float32]
    ambient_lux: float
    depth: NDArray[np.float32]
    map_u: NDArray[np.float32]
    map_v: NDArray[np.float32]
    sigma_px: NDArray[np.float32]
    seen: NDArray[np.bool_]
    sigma_range: tuple[float, float] | None
    blur: optics.BlurPlan              # the camera's defocus at this view's depths
    _level_weights: dict[tuple[float, ...], list[NDArray[np.float32] | None]] = field(default_factory=dict)

    @cached_property
    def albedo_mono(self) -> NDArray[np.float32]:
        # The (h, w, 4) array albedo_rgb is a view of (with depth last) needs no copy.
        base = self.albedo_rgb.base
        whole = base if isinstance(base, np.ndarray) and base.shape == (*self.albedo_rgb.shape[:2], 4) else None
        return optics.luma(whole if whole is not None and whole.flags.c_contiguous else self.albedo_rgb)

    @cached_property
    def ambient_rgb(self) -> NDArray[np.float32]:
        return self.albedo_rgb * np.float32(self.ambient_lux / np.pi)

    @cached_property
    def ambient_mono(self) -> NDArray[np.float32]:
        return self.albedo_mono * np.float32(self.ambient_lux / np.pi)

    @cached_property
    def gain_rgb(self) -> NDArray[np.float32]:
        return self.albedo_rgb * (self.irradiance * np.float32(1.0 / np.pi))[..., None]

    @cached_property
    def gain_mono(self) -> NDArray[np.float32]:
        return self.albedo_mono * self.irradiance * np.float32(1.0 / np.pi)

    def level_weights(self, sigma_levels: tuple[float, ...]) -> list[NDArray[np.float32] | None]:
        """Per pixel, how much of each blur level's light it takes (None: that level is not used), for the
        levels a pattern was blurred to (the same for every pattern at this view: cached)."""
        cached = self._level_weights.get(sigma_levels)
        if cached is None:
            sig = np.asarray(sigma_levels, dtype=np.float32)
            # Fractional level index, linear between levels and clamped at both ends (np.interp's result as
            # a sum of one clamped ramp per gap: a few in-place passes instead of a binary search per pixel).
            position = np.zeros_like(self.sigma_px)
            ramp = np.empty_like(self.sigma_px)
            for lo, hi in pairwise(sig):
                np.subtract(self.sigma_px, lo, out=ramp)
                ramp *= np.float32(1.0) / (hi - lo)
                np.clip(ramp, 0.0, 1.0, out=ramp)
                position += ramp
            cached = []
            for k in range(len(sig)):
                weight = np.abs(position - np.float32(k))
                np.subtract(np.float32(1.0), weight, out=weight)
                np.clip(weight, 0.0, 1.0, out=weight)
                cached.append(weight if weight.any() else None)
            self._level_weights[sigma_levels] = cached
        return cached


def _lookup(image: NDArray[np.float32], map_u: NDArray[np.float32], map_v: NDArray[np.float32]
            ) -> NDArray[np.float32]:
    """Bilinear lookup of a projector image at projector pixel coordinates (0 outside the image)."""
    return cv2.remap(image, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


class Site:
    """A simulated site. Build with Site.build(); release GPU memory with release() or a `with` block."""

    def __init__(self, scene: Scene, seed: int, ctx: moderngl.Context | None = None) -> None:
        self.scene = scene
        self.seed = int(seed)
        streams = np.random.SeedSequence(self.seed).spawn(len(_STREAMS))
        self._rng = {name: np.random.default_rng(s) for name, s in zip(_STREAMS, streams, strict=True)}
        self.room = Room(scene["room"], self._rng["room"])
        h = scene["head"]
        self.head_nominal: HeadModel = nominal_head(h)
        self.head: HeadModel = true_head(h, self._rng["head"])
        self._drive = HeadDrive(h, self._rng["drive"])
        self.projector: Intrinsics = projector_intrinsics(scene["projector"])
        cams = scene["cameras"]
        self.camera_left: Intrinsics = camera_intrinsics(cams)
        self.camera_right: Intrinsics = camera_intrinsics(cams, right=True)
        right_config = {**cams, **cams["right"]}
        self.camera_models = {
            "camera_left": optics.CameraModel.from_config(self.camera_left, cams, self._rng["sensor"]),
            "camera_right": optics.CameraModel.from_config(self.camera_right, right_config, self._rng["sensor"])}
        self.T_robot_from_camera_left_design, self.T_camera_right_from_camera_left = camera_poses(cams)
        # The pair as mounted: its drawing off by cameras.mount_error_* (0 by default: the design is the truth).
        self.T_robot_from_camera_left = mount_error(cams, self._rng["mount"]) @ self.T_robot_from_camera_left_design
        laser = scene["laser"]
        self.T_robot_from_laser = make_pose(None, laser["position_m"])
        self.targets: list[Target] = []
        self._room_surfaces = self.room.surfaces()
        self._T_room_from_robot = np.eye(4)
        self._localization_error = np.eye(4)
        p = scene["projector"]
        self.projector_focus_m = p["focus_distance_m"]
        self._ctx = ctx
        self._renderer: SceneRenderer | None = None
        self._levels_cache: tuple[str, NDArray[np.float32]] | None = None
        self._truth_cache: dict[tuple, Truth] = {}
        self._views: list[tuple[tuple, _View]] = []

    # -- construction -----------------------------------------------------------------------------------
    @classmethod
    def build(cls, scene: str | Path | dict | None = None, seed: int = 0, ctx: moderngl.Context | None = None,
              **overrides: Any) -> Site:
        """A site from a scene file, dict or the default (None), updated by section overrides
        (e.g. robot={"distance_m": 3.0}); the robot placed as the scene says and its geometry checked."""
        config = load_scene(scene, **overrides)
        site = cls(config, seed, ctx)
        r = config["robot"]
        site.place_robot(r["distance_m"], r["incidence_deg"], wall=r["wall"], along_m=r["along_m"],
                         aim_height_m=r["aim_height_m"], _source="scene robot")
        if r["head_deg"] is not None:
            what = f"scene robot.head_deg = {r['head_deg']}"
            site.set_head(r["head_deg"])
            site._check_sensors(what)
        return site

    # -- GL ---------------------------------------------------------------------------------------------
    @property
    def renderer(self) -> SceneRenderer:
        if self._renderer is None:
            if self._ctx is None:
                self._ctx = shared_context()
            self._renderer = SceneRenderer(self._ctx)
        return self._renderer

    def release(self) -> None:
        """Free the site's GPU objects (the GL context is the caller's, or the shared one)."""
        if self._renderer is not None:
            self._renderer.release()
            self._renderer = None

    def __enter__(self) -> Site:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    # -- walls and poses --------------------------------------------------------------------------------
    @property
    def walls(self) -> list[Wall]:
        return self.room.walls

    @property
    def T_room_from_robot(self) -> NDArray[np.float64]:
        """The robot's true pose on the floor (its floor tilt included)."""
        return self._T_room_from_robot.copy()

    @property
    def floor_tilt_deg(self) -> tuple[float, float]:
        """The robot's true (roll, pitch) against gravity in degrees (geometry.poses.roll_pitch): what a
        perfect inclinometer on it reads."""
        roll, pitch = roll_pitch(self._T_room_from_robot)
        return float(np.degrees(roll)), float(np.degrees(pitch))

    @property
    def localized_T_room_from_robot(self) -> NDArray[np.float64]:
        """What the robot's own (laser) localization believes: the true x, y and heading on the floor with a
        seeded error (σ from the scene), level (a floor localization does not know the tilt)."""
        T = self._T_room_from_robot
        return floor_pose(T[0, 3], T[1, 3], float(np.arctan2(T[1, 0], T[0, 0]))) @ self._localization_error

    @property
    def head_angles_cmd_deg(self) -> NDArray[np.float64]:
        return self._drive.cmd_deg.copy()

    @property
    def head_angles_true_deg(self) -> NDArray[np.float64]:
        """The joint angles reached (commanded + bias + noise, short by backlash): site.head's input."""
        return self._drive.true_deg.copy()

    @property
    def head_angle_bias_deg(self) -> NDArray[np.float64]:
        return self._drive.bias_deg.copy()

    @property
    def T_robot_from_projector(self) -> NDArray[np.float64]:
        return self.head.T_robot_from_projector(self._drive.true_deg)

    @property
    def T_robot_from_head(self) -> NDArray[np.float64]:
        """The moving plate of the head: at the tilt axis point, turned with the joints."""
        return self.head.T_robot_from_head(self._drive.true_deg)

    def T_room_from(self, frame: str) -> NDArray[np.float64]:
        """True pose of a frame: room, robot, head, projector, camera_left, camera_right, laser, wall<i>."""
        robot = self._T_room_from_robot
        if frame == "room":
            return np.eye(4)
        if frame == "robot":
            return robot.copy()
        if frame == "head":
            return robot @ self.T_robot_from_head
        if frame == "projector":
            return robot @ self.T_robot_from_projector
        if frame == "camera_left":
            return robot @ self.T_robot_from_camera_left
        if frame == "camera_right":
            return robot @ self.T_robot_from_camera_left @ invert(self.T_camera_right_from_camera_left)
        if frame == "laser":
            return robot @ self.T_robot_from_laser
        if frame.startswith("wall") and frame[4:].isdigit() and int(frame[4:]) < len(self.walls):
            return self.walls[int(frame[4:])].T_room_from_wall.copy()
        raise InputError(f"unknown frame {frame!r}", "use room, robot, head, projector, camera_left, "
                         f"camera_right, laser or wall0..wall{len(self.walls) - 1}")

    def intrinsics(self, frame: str) -> Intrinsics:
        if frame == "projector":
            return self.projector
        if frame in CAMERAS:
            return self.camera_left if frame == "camera_left" else self.camera_right
        raise InputError(f"{frame!r} has no intrinsics", "use projector, camera_left or camera_right")

    # -- moving things ----------------------------------------------------------------------------------
    def set_head(self, cmd_deg: ArrayLike) -> NDArray[np.float64]:
        """Command the head to (pan, tilt, roll) degrees; returns the true angles reached."""
        self._truth_cache.clear()
        return self._drive.command(cmd_deg).copy()

    def move_robot(self, T_room_from_robot: ArrayLike) -> None:
        """Put the robot at a pose as given, tilt included (a robot pushed from site.T_room_from_robot keeps its
        tilt); its localization error is drawn anew."""
        T = np.asarray(T_room_from_robot, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError("T_room_from_robot must be a finite 4x4 pose")
        self._check_robot(T, "move_robot")
        self._T_room_from_robot = T.copy()
        self._draw_localization_error()
        self._truth_cache.clear()

    def place_robot(self, distance_m: float, incidence_deg: float, wall: int = 0, along_m: float | None = None,
                    aim_height_m: float | None = None, _source: str = "place_robot") -> None:
        """Put the robot in front of a wall: the projector's centre distance_m from the aim point, its axis
        through that point at a horizontal incidence angle, the robot body facing along that axis, standing with
        a roll and pitch drawn anew (robot.floor_tilt_sigma_deg: the floor there is not level).

        along_m: aim point along the wall (default: middle); aim_height_m: default from the scene. The
        projector refocuses on the aim point when the scene's focus_distance_m is null.
        """
        if not 0 <= int(wall) < len(self.walls):
            raise InputError(f"{_source}: wall = {wall!r}, but the room has walls 0..{len(self.walls) - 1}")
        if not distance_m > 0:
            raise InputError(f"{_source}: distance_m = {distance_m!r} must be positive")
        if not abs(incidence_deg) < MAX_AIM_INCIDENCE_DEG:
            raise InputError(f"{_source}: incidence_deg = {incidence_deg!r} is too oblique",
                             f"use |incidence| < {MAX_AIM_INCIDENCE_DEG}°")
        w = self.walls[int(wall)]
        height = self.scene["robot"]["aim_height_m"] if aim_height_m is None else float(aim_height_m)
        if along_m is not None and not 0 <= along_m <= w.width_m:
            raise InputError(f"{_source}: along_m = {along_m!r} is off wall {w.index} (0..{w.width_m:.2f} m)")
        if not 0 <= height <= w.height_m:
            raise InputError(f"{_source}: aim_height_m = {height!r} is off the wall (0..{w.height_m:.2f} m)")
        tilt_deg = self._rng["tilt"].standard_normal(2) * self.scene["robot"]["floor_tilt_sigma_deg"]
        placement = place_in_front_of_wall(w.T_room_from_wall, w.width_m, self.head, self._drive.bias_deg,
                                           float(distance_m), float(incidence_deg), along_m, height,
                                           tilt_rotation(*np.radians(tilt_deg)))
        what = f"{_source}: distance_m = {distance_m}, incidence_deg = {incidence_deg}, wall = {wall}"
        self._check_robot(placement.T_room_from_robot, what)
        try:
            self._drive.command(placement.head_cmd_deg)
        except InputError as err:
            raise InputError(f"{what}: aiming needs a head angle beyond its limits ({err.message})") from None
        self._T_room_from_robot = placement.T_room_from_robot
        self._draw_localization_error()
        self._truth_cache.clear()
        self._check_sensors(what)
        if self.scene["projector"]["focus_distance_m"] is None:
            self.projector_focus_m = float(distance_m)

    def _draw_localization_error(self) -> None:
        r = self.scene["robot"]
        rng = self._rng["localization"]
        dx, dy = rng.standard_normal(2) * r["localization_sigma_m"]
        dyaw = np.radians(rng.standard_normal() * r["localization_sigma_deg"])
        self._localization_error = floor_pose(dx, dy, dyaw)

    def _check_robot(self, T: NDArray[np.float64], what: str) -> None:
        xy = T[:2, 3]
        radius = self.scene["robot"]["footprint_radius_m"]
        if not self.room.contains(xy)[0]:
            raise InputError(f"{what}: the robot would stand outside the room, at ({xy[0]:.2f}, {xy[1]:.2f}) m",
                             "choose a shorter distance or a smaller incidence")
        clearance = float(self.room.distance_to_walls(xy)[0])
        if clearance < radius:
            raise InputError(f"{what}: the robot at ({xy[0]:.2f}, {xy[1]:.2f}) m would be {clearance:.2f} m "
                             f"from a wall, closer than its footprint radius {radius} m")

    def _check_sensors(self, what: str) -> None:
        """Cameras and projector inside the room; the projector's axis lands on a wall, not steeply."""
        for frame in ("projector", *CAMERAS):
            c = self.T_room_from(frame)[:3, 3]
            inside = self.room.contains(c[:2])[0] and MIN_CLEARANCE_M < c[2] < self.room.height_m - MIN_CLEARANCE_M
            if not inside or self.room.distance_to_walls(c[:2])[0] < MIN_CLEARANCE_M:
                raise InputError(f"{what}: the {frame} at ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m would be inside "
                                 "or beyond a wall, floor or ceiling", "check cameras.position_m and head.*_m")
        T = self.T_room_from("projector")
        hits = raycast(self._room_surfaces, T[:3, 3], T[:3, 2][None])
        s = int(hits.surface[0])
        if s < 0 or self._room_surfaces[s].kind != KIND_WALL:
            raise InputError(f"{what}: the projector faces away from the walls (its axis lands on "
                             f"{'nothing' if s < 0 else 'the floor or ceiling'})")
        incidence = np.degrees(np.arccos(abs(float(T[:3, 2] @ self._room_surfaces[s].normal))))
        if incidence > MAX_AIM_INCIDENCE_DEG:
            raise InputError(f"{what}: the projector's axis meets wall {s} at {incidence:.1f}°, too oblique "
                             "to project on")

    # -- targets ----------------------------------------------------------------------------------------
    def add_target(self, texture_image: NDArray, size_m: tuple[float, float], T_room_from_target: ArrayLike,
                   paper_albedo: float = 0.85, ink_albedo: float = 0.04) -> Target:
        """Place a printed board (see room.Target for its frame) that the cameras photograph from now on."""
        target = Target(np.asarray(texture_image), size_m, T_room_from_target, paper_albedo, ink_albedo)
        self.targets.append(target)
        self._truth_cache.clear()
        return target

    def remove_targets(self) -> None:
        self.targets = []
        self._truth_cache.clear()

    def _surfaces(self, extra_targets: Sequence[Target] = ()) -> tuple[list[Surface], list[Target]]:
        """Room surfaces, then the site's targets, then extra_targets (target k is surface len(room) + k)."""
        targets = [*self.targets, *extra_targets]
        return [*self._room_surfaces, *(t.surface() for t in targets)], targets

    # -- truth ------------------------------------------------------------------------------------------
    def truth(self, frame: str, extra_targets: Sequence[Target] = ()) -> Truth:
        """Exact per-pixel truth of a camera or the projector at the current poses (cached)."""
        surfaces, _ = self._surfaces(extra_targets)
        return self._truth_for(frame, self.T_room_from(frame), surfaces)

    def _truth_for(self, frame: str, T: NDArray[np.float64], surfaces: list[Surface]) -> Truth:
        key = (frame, T.tobytes(), tuple(s.serial for s in surfaces))
        if key not in self._truth_cache:
            self._truth_cache[key] = _pixel_truth(self.intrinsics(frame), T, surfaces)
        return self._truth_cache[key]

    def projector_landing(self) -> Truth:
        """Where every projector pixel's ray lands (wall index and wall xy, room points)."""
        return self.truth("projector")

    def raycast(self, frame: str, pixels: ArrayLike) -> Truth:
        """Truth for chosen pixels (n, 2) of a camera or the projector (arrays shaped (n, …))."""
        intr = self.intrinsics(frame)
        rays = intr.rays(pixels)
        surfaces, _ = self._surfaces()
        return _truth_of_rays(self.T_room_from(frame), rays, surfaces, (len(rays),))

    # -- image formation --------------------------------------------------------------------------------
    def _projector_state(self, image: NDArray | None, sigma_range: tuple[float, float] | None = None
                         ) -> ProjectorState:
        """The projector as the shader needs it; with an image, its light at the blur levels that cover
        sigma_range (projector pixels; default: the defocus range over the lit surfaces)."""
        p = self.scene["projector"]
        intr = self.projector
        T = self.T_room_from("projector")
        focus = float(self.projector_focus_m)
        levels: tuple[float, ...] = (p["lens_blur_px"],)
        light = None
        if image is not None:
            if sigma_range is None:
                # Depth range of the lit surfaces from a coarse grid of the projector's rays.
                u, v = np.meshgrid(np.linspace(0, intr.width - 1, 17), np.linspace(0, intr.height - 1, 11))
                rays = intr.rays(np.column_stack([u.ravel(), v.ravel()]))
                surfaces, _ = self._surfaces()
                hits = raycast(surfaces, T[:3, 3], rays @ T[:3, :3].T)
                z = hits.t[np.isfinite(hits.t)]
                sigmas = optics.defocus_sigma_px(p["aperture_mm"], intr.fx, focus, z, p["lens_blur_px"])
                sigma_range = (p["lens_blur_px"], float(np.max(sigmas)) if len(z) else p["lens_blur_px"])
            levels = optics.blur_levels(*sigma_range)
            key = _image_key(np.asarray(image)) + str(levels)
            if self._levels_cache is None or self._levels_cache[0] != key:
                self._levels_cache = (key, optics.projector_light(image, intr, p["gamma"], p["contrast_ratio"],
                                                                  levels))
            light = self._levels_cache[1]
        pin = distortion_map(intr).pinhole if intr.has_distortion else intr
        bounds = ((-0.5 - pin.cx) / pin.fx, (-0.5 - pin.cy) / pin.fy,
                  (pin.width - 0.5 - pin.cx) / pin.fx, (pin.height - 0.5 - pin.cy) / pin.fy)
        return ProjectorState(
            intr=intr, T_room_from_projector=T, levels=light, blur_levels_px=levels,
            intensity_cd=p["lumens"] * intr.fx * intr.fy / (intr.width * intr.height),
            defocus_px_m=p["aperture_mm"] * 1e-3 * intr.fx, focus_distance_m=focus,
            lens_blur_px=p["lens_blur_px"], bounds=bounds, shadow_intr=pin,
            shadows=not self.room.convex, uniformity=p["uniformity"])

    def render_radiance(self, camera: str, projector_image: NDArray | None = None,
                        targets: Sequence[Target] = ()) -> NDArray[np.float32]:
        """The direct GL path (projector image textured in the shader): (H', W', 4) float32 radiance rgb and
        depth through the camera's pinhole enlarged for its distortion. photograph() gives the same image
        faster by re-using the view's geometry (see _view); this path is its cross-check."""
        model = self._camera(camera)
        surfaces, _ = self._surfaces(targets)
        renderer = self.renderer
        renderer.set_surfaces(surfaces)
        state = self._projector_state(projector_image) if projector_image is not None else None
        key = self._levels_cache[0] if state is not None and self._levels_cache is not None else None
        # The shader takes one ambient level: the room light plus the (grey-averaged) bounced projector light.
        ambient = self.room.ambient_lux + (float(np.mean(self._indirect_lux(state))) if state is not None else 0.0)
        return renderer.render(model.render_intrinsics, self.T_room_from(camera), ambient, state, key)

    def _view(self, camera: str, surfaces: list[Surface]) -> _View:
        """Everything about a camera's view that does not depend on the projector image, on the sensor grid
        (cached per pose: a new pattern at the same pose costs only the projector lookup and the sensor)."""
        model = self._camera(camera)
        T = self.T_room_from(camera)
        key = (camera, T.tobytes(), self.T_room_from("projector").tobytes(), tuple(s.serial for s in surfaces),
               self.projector_focus_m, self.room.ambient_lux)
        for k, view in self._views:
            if k == key:
                return view
        renderer = self.renderer
        renderer.set_surfaces(surfaces)
        albedo, projector = renderer.render_deferred(model.render_intrinsics, T, self._projector_state(None),
                                                     self.scene["cameras"]["msaa_samples"], model.render_scale)
        albedo, projector = model.to_sensor(albedo), model.to_sensor(projector)
        irradiance, map_u, map_v, sigma = cv2.split(projector)
        depth = cv2.extractChannel(albedo, 3)
        seen = irradiance > 0
        view = _View(albedo_rgb=albedo[..., :3], irradiance=irradiance, ambient_lux=self.room.ambient_lux,
                     depth=depth, map_u=map_u, map_v=map_v, sigma_px=sigma, seen=seen,
                     sigma_range=(float(np.min(sigma, where=seen, initial=np.inf)),
                                  float(np.max(sigma, where=seen, initial=-np.inf))) if seen.any() else None,
                     blur=model.blur_plan(depth))
        self._views = [*self._views[-(VIEW_CACHE_SIZE - 1):], (key, view)]
        return view

    def projector_pixels_seen(self, camera: str, targets: Sequence[Target] = ()) -> NDArray[np.float32]:
        """(h, w, 2) float32: for every camera pixel, the projector pixel (u, v) whose light it sees, as the
        photo is rendered (NaN where no projector light arrives) — the ground-truth correspondence a
        structured-light decoder should find."""
        surfaces, _ = self._surfaces(targets)
        view = self._view(camera, surfaces)
        out = np.stack([view.map_u, view.map_v], axis=-1)
        out[~view.seen] = np.nan
        return out

    def projector_irradiance_lux(self, camera: str, targets: Sequence[Target] = ()) -> NDArray[np.float32]:
        """(h, w) float32: illuminance (lux) full white would cause at the surface each camera pixel sees —
        the projector's fall-off with distance, incidence and across its image, and shadows (0: unlit)."""
        surfaces, _ = self._surfaces(targets)
        return self._view(camera, surfaces).irradiance

    def _radiance(self, camera: str, view: _View, projector_image: NDArray | None) -> NDArray[np.float32]:
        """Radiance on the sensor grid: ambient + gain · (projector light looked up at each pixel's blur)."""
        color = self.camera_models[camera].color
        if projector_image is None:
            return view.ambient_rgb if color else view.ambient_mono
        state = self._projector_state(projector_image, view.sigma_range or (0.0, 0.0))
        indirect = self._indirect_lux(state)
        bounce = (np.asarray(indirect, dtype=np.float32) / np.float32(np.pi)).reshape(-1)   # (1,) or (3,)
        # Ambient and interreflected light share the albedo: one product, and only in the form needed.
        ambient_scale = np.float32(view.ambient_lux / np.pi) + bounce

        def ambient_rgb() -> NDArray[np.float32]:
            return view.albedo_rgb * ambient_scale

        if view.sigma_range is None:      # the projector lights nothing this camera sees
            if color:
                return ambient_rgb()
            return optics.luma(ambient_rgb()) if bounce.size == 3 else view.albedo_mono * ambient_scale[0]
        light = state.levels
        assert light is not None
        if len(state.blur_levels_px) == 1:
            sampled = _lookup(light[0], view.map_u, view.map_v)
        else:
            sampled = None
            for k, weight in enumerate(view.level_weights(tuple(state.blur_levels_px))):
                if weight is None:
                    continue
                part = _lookup(light[k], view.map_u, view.map_v)
                part *= weight if part.ndim == 2 else weight[..., None]
                if sampled is None:
                    sampled = part
                else:
                    sampled += part
        assert sampled is not None
        # In place on the fresh arrays: a 1280x800 photo is a few MB per temporary.
        if sampled.ndim == 2 and not color:     # grey image, mono camera (its bounce is grey too)
            sampled *= view.gain_mono
            sampled += view.albedo_mono * ambient_scale[0]
            return sampled
        rgb = view.gain_rgb * (sampled[..., None] if sampled.ndim == 2 else sampled)
        rgb += ambient_rgb()
        return rgb if color else optics.luma(rgb)

    def _indirect_lux(self, state: ProjectorState) -> NDArray[np.float64]:
        """Projector light reflected by the room onto every surface (split-flux estimate, uniform), (1,) for a
        grey image or (3,) rgb: E = ρ̄ · Φ / (A · (1 − ρ̄)), Φ the flux the image sends out, ρ̄ the room's
        mean reflectance, A its area."""
        if not self.scene["room"]["interreflection"] or state.levels is None:
            return np.zeros(1)
        level = state.levels[0]
        mean_light = level.reshape(-1, level.shape[2]).mean(axis=0) if level.ndim == 3 else np.array([level.mean()])
        flux = self.scene["projector"]["lumens"] * mean_light
        area, reflected = self.room.area_and_mean_albedo()
        return reflected * flux / (area * (1.0 - reflected))

    def photograph(self, camera: str, projector_image: NDArray | None = None,
                   exposure: float | str | None = None, targets: Sequence[Target] = (), noise: bool = True,
                   rng: np.random.Generator | None = None) -> Photo:
        """What a camera sees with the projector showing projector_image (None: projector dark).

        projector_image: (h, w) or (h, w, 3) uint8 (or float 0..1) at the projector's resolution.
        exposure: seconds, "auto" (metered on the brightest part of the view) or None (the scene's
        cameras.exposure_s); targets: boards present for this shot only; noise=False leaves out sensor noise
        (everything else stays); rng: where the sensor noise comes from (default: the site's photo stream).
        """
        model = self._camera(camera)
        surfaces, _ = self._surfaces(targets)     # the scene as photographed (also for the lazy truth)
        view = self._view(camera, surfaces)
        radiance = self._radiance(camera, view, projector_image)
        if isinstance(exposure, str):
            if exposure != "auto":
                raise InputError(f"exposure = {exposure!r}: give seconds, 'auto' or None")
            exposure = model.metered_exposure(radiance)
        exposure_s = model.exposure_s if exposure is None else float(exposure)
        noise_rng = (rng if rng is not None else self._rng["photo"]) if noise else None
        image = model.expose(radiance, view.depth, exposure_s, noise_rng, plan=view.blur)
        T = self.T_room_from(camera)
        return Photo(image, camera, model.intr, T, exposure_s,
                     _truth_source=lambda: self._truth_for(camera, T, surfaces))

    def _camera(self, camera: str) -> optics.CameraModel:
        if camera not in self.camera_models:
            raise InputError(f"unknown camera {camera!r}", f"use one of {', '.join(CAMERAS)}")
        return self.camera_models[camera]

    # -- other sensors ----------------------------------------------------------------------------------
    def laser_scan(self) -> LaserScan:
        """One sweep of the 2D laser: true ranges to walls (and targets) with noise and a few outliers."""
        c = self.scene["laser"]
        half = np.radians(c["fov_deg"]) / 2.0
        step = np.radians(c["resolution_deg"])
        angles = np.arange(-half, half + step / 2, step)
        T = self.T_room_from("laser")
        local = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
        surfaces, _ = self._surfaces()
        hits = raycast(surfaces, T[:3, 3], local @ T[:3, :3].T)
        ranges = hits.t.copy()
        rng = self._rng["laser"]
        ranges = ranges + rng.standard_normal(len(ranges)) * c["range_sigma_m"]
        outlier = rng.random(len(ranges)) < c["outlier_fraction"]
        finite = np.isfinite(ranges)
        ranges[outlier & finite] = rng.uniform(0.05, 1.0, (outlier & finite).sum()) * ranges[outlier & finite]
        ranges[~finite | (ranges > c["range_max_m"])] = np.inf
        return LaserScan(angles, ranges, self.T_robot_from_laser.copy())

    def raycast_depth(self, T_room_from_camera: ArrayLike, intr: Intrinsics) -> NDArray[np.float32]:
        """Exact z-depth (h, w) float32 metres (NaN: nothing) of any pinhole view of the scene, e.g. the truth
        behind a range image."""
        T = np.asarray(T_room_from_camera, dtype=np.float64)
        surfaces, _ = self._surfaces()
        return _pixel_truth(intr, T, surfaces).depth

    def range_image(self, T_room_from_rangecam: ArrayLike, intr: Intrinsics | None = None) -> RangeImage:
        """A Kinect-like depth image: z-depth (metres) with noise growing as z², missing pixels at depth
        edges, at grazing angles, beyond the range limits and at random."""
        from arproj.sim.rangecam import simulate_range_image

        c = self.scene["rangecam"]
        if intr is None:
            intr = Intrinsics.from_fov(c["width"], c["height"], c["hfov_deg"])
        surfaces, _ = self._surfaces()
        T = np.asarray(T_room_from_rangecam, dtype=np.float64)
        depth = simulate_range_image(surfaces, intr, T, c, self._rng["range"])
        return RangeImage(depth, intr, T)


def _truth_of_rays(T_room_from_frame: NDArray[np.float64], rays: NDArray[np.float64], surfaces: list[Surface],
                   shape: tuple[int, ...]) -> Truth:
    """Truth for unit-z rays (n, 3) in the frame's optical frame, reshaped to shape."""
    dirs = rays @ T_room_from_frame[:3, :3].T
    hits = raycast(surfaces, T_room_from_frame[:3, 3], dirs)
    kinds = np.array([s.kind for s in surfaces] + [-1])
    index = np.array([s.index for s in surfaces] + [-1])
    kind = kinds[hits.surface]
    wall = np.where(kind == KIND_WALL, index[hits.surface], -1).astype(np.int16)
    wall_xy = np.where((kind == KIND_WALL)[:, None], hits.local, np.nan).astype(np.float32)
    target_pos = np.cumsum(kinds == KIND_TARGET) - 1
    target = np.where(kind == KIND_TARGET, target_pos[hits.surface], -1).astype(np.int16)
    target_xy = np.where((kind == KIND_TARGET)[:, None], hits.local * np.array([1.0, -1.0]), np.nan)
    points = T_room_from_frame[:3, 3] + hits.t[:, None] * dirs
    depth = np.where(np.isfinite(hits.t), hits.t, np.nan).astype(np.float32)
    return Truth(wall.reshape(shape), wall_xy.reshape(*shape, 2), target.reshape(shape),
                 target_xy.astype(np.float32).reshape(*shape, 2), points.reshape(*shape, 3), depth.reshape(shape))


@lru_cache(maxsize=8)
def pixel_directions(intr: Intrinsics) -> NDArray[np.float64]:
    """(h·w, 2) undistorted normalised coordinates of every pixel's ray, row-major (cached)."""
    if not intr.has_distortion:
        u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
        return np.column_stack([(u.ravel() - intr.cx) / intr.fx, (v.ravel() - intr.cy) / intr.fy])
    # The renderer's distortion map holds these rays already (float32: ~1e-4 px, far below any tolerance).
    dmap = distortion_map(intr)
    m = dmap.map_xy.reshape(-1, 2).astype(np.float64)
    return np.column_stack([(m[:, 0] - dmap.pinhole.cx) / dmap.pinhole.fx,
                            (m[:, 1] - dmap.pinhole.cy) / dmap.pinhole.fy])


def _pixel_truth(intr: Intrinsics, T: NDArray[np.float64], surfaces: list[Surface]) -> Truth:
    xy = pixel_directions(intr)
    rays = np.column_stack([xy, np.ones(len(xy))])
    return _truth_of_rays(T, rays, surfaces, (intr.height, intr.width))
