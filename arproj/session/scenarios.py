"""Degraded scenes for the safety gate, rendered on the simulated site: the cameras see what they would.

A scene starts from a registration the session really made from photographs (a Station), changes the physical
site — the robot nudged, the head's mount slipped, a board hiding part of the pattern, a person in the beam,
sunlight through a window, or the session started with another robot's rig file — and runs the session's own
update() on it: the pattern and the check marks are rendered by the site's camera model, their corners and
centroids found in both images, triangulated, the closed loop measured and the gate's decision taken, exactly
as on site. The judge is the site's truth: where the registration the session holds after the update (the one
it would show) truly puts the map's features and a grid over the drawn area (ray casting with the true
projector pose and lens).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from arproj.session import registration
from arproj.session import tolerances as tol
from arproj.session.evaluate import map_features
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, transform_points
from geometry.rig import Rig

if TYPE_CHECKING:
    from arproj.session.session import ProjectionSession
    from arproj.sim.protocols import SiteTruth

KINDS = ("robot moved", "head slipped", "pattern occluded", "wrong rig file", "person in the beam", "sunlight")
# Scene seeds: the gate's reserve is fitted on the tuning seeds and judged on the others (never the same).
TUNING_SEED_START = 20_000
JUDGED_SEED_START = 10_000


def scene_seeds(start: int, n: int, offset: int = 0) -> range:
    """Seeds of n scenes from start (offset: the bench's --seed moves the whole set, keeping the two apart)."""
    return range(start + 100_000 * offset, start + 100_000 * offset + n)


@dataclass
class Truth:
    """The physical state of a simulated robot (all true values)."""

    T_wall_from_robot: NDArray[np.float64]
    T_robot_from_projector: NDArray[np.float64]
    projector: Intrinsics
    camera_left: Intrinsics
    camera_right: Intrinsics
    T_robot_from_camera_left: NDArray[np.float64]
    T_camera_right_from_camera_left: NDArray[np.float64]

    @property
    def T_wall_from_projector(self) -> NDArray[np.float64]:
        return self.T_wall_from_robot @ self.T_robot_from_projector


def truth_of(site: SiteTruth, wall_index: int) -> Truth:
    s = site
    T_wall_from_room = invert(s.walls[wall_index].T_room_from_wall)
    return Truth(T_wall_from_room @ s.T_room_from_robot, s.T_robot_from_projector, s.projector, s.camera_left,
                 s.camera_right, s.T_robot_from_camera_left, s.T_camera_right_from_camera_left)


@dataclass
class Belief:
    """What the session believes (its rig and registration)."""

    rig: Rig
    T_wall_from_robot: NDArray[np.float64]
    T_wall_from_projector: NDArray[np.float64]
    sigma_m: float
    distance_m: float


def drawn_pixels(belief: Belief, points_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Projector pixels (n, 2) at which the session draws wall points (its rig's projector model)."""
    p = transform_points(invert(belief.T_wall_from_projector), np.column_stack([points_xy, np.zeros(len(points_xy))]))
    return belief.rig.intrinsics["projector"].project(p)


def true_errors(belief: Belief, truth: Truth, points_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance (n,) metres between where the session's drawing of each wall point truly lands and the point."""
    landed = registration.rays_to_wall(truth.T_wall_from_projector, truth.projector,
                                       drawn_pixels(belief, points_xy))[:, :2]
    return np.linalg.norm(landed - points_xy, axis=1)

@dataclass
class Outcome:
    """One rendered scene: what the gate decided, its statistic, and the truth of the registration it held.
    true_max_m / true_mean_m: NaN when the session holds no registration (nothing could be shown)."""

    kind: str
    magnitude: str
    seed: int
    show_map: bool
    reasons: list[str]
    true_max_m: float
    true_mean_m: float
    bound_m: float       # the gate's 95 % bound (pose's 95 % error + the loop's worst mark + robot motion)
    loop_max_m: float    # the closed loop's worst check mark after its correction (NaN: no loop)
    verified: bool       # a pose was estimated (one refused for its rig too) and the pattern not lost
    shown_share: float = float("nan")  # share of the drawn area inside the trusted region

    @property
    def judged(self) -> bool:
        return bool(np.isfinite(self.true_max_m))

    @property
    def fine(self) -> bool:
        return self.judged and self.true_max_m <= tol.REGISTRATION_TOLERANCE_M

    @property
    def unsafe(self) -> bool:
        return self.show_map and not (self.true_max_m <= tol.REGISTRATION_TOLERANCE_M)

    @property
    def false_alarm(self) -> bool:
        """Warned although the map was fine and the check could be made (not for hidden marks or no pose)."""
        return self.fine and self.verified and not self.show_map


@dataclass
class Station:
    """A registered placement on the simulated site, the start of every degraded scene: the session after its
    first update (registration kept as a snapshot), its robot and the site, and the GL context for the
    sessions a wrong rig file needs."""

    site: Any
    session: ProjectionSession
    robot: Any
    ctx: object | None = None
    wall_index: int = 0
    snapshot: Any = field(init=False)
    area_xy: NDArray[np.float64] = field(init=False)

    def __post_init__(self) -> None:
        reg = self.session.registration
        if reg is None:
            raise ValueError("a station needs a registered session")
        self.snapshot = copy.deepcopy(reg)
        # the drawn area at the start: where occluders and people are put
        self.area_xy = registration.choose_marks(reg.T_wall_from_projector, self.session.projector_intr,
                                                 self.session.wall_map.extent, grid=(16, 10), border=0.02)
        self.T_room_from_robot = self.site.T_room_from_robot.copy()
        self.ambient_lux = float(self.site.room.ambient_lux)

    def close(self) -> None:
        self.session.close()
        self.robot.close()
        self.site.release()

    def restore(self) -> None:
        """Back to the registered state (the site's physical state is restored by each scene's undo)."""
        self.session.registration = copy.deepcopy(self.snapshot)
        self.session.pose_failure = None
        self.session.rig_failure = None
        self.session.refused_registration = None


def judge(session: ProjectionSession, site: SiteTruth, wall_index: int = 0
          ) -> tuple[float, float, float]:
    """(max, mean) true error (metres) of the registration the session holds, over the map's features and a
    grid over the drawn area inside the trusted region, and the region's share; NaN without a registration."""
    reg = session.registration or session.refused_registration  # a refused rig: judged by what it would show
    if reg is None:
        return float("nan"), float("nan"), float("nan")
    intr = session.projector_intr
    points = np.concatenate([map_features(session.wall_map, reg.T_wall_from_projector, intr),
                             registration.choose_marks(reg.T_wall_from_projector, intr, session.wall_map.extent,
                                                       grid=(16, 10), border=0.02)])
    share = 1.0
    if reg.trusted is not None:
        share = reg.trusted.share
        if reg.trusted.polygon is not None:
            points = points[registration.inside_polygon(points, reg.trusted.polygon)]
    belief = Belief(session.rig, reg.T_wall_from_robot, reg.T_wall_from_projector, reg.sigma_m, reg.distance_m)
    errors = true_errors(belief, truth_of(site, wall_index), points)
    errors = errors[np.isfinite(errors)]
    if not len(errors):
        return float("inf"), float("inf"), share
    return float(errors.max()), float(errors.mean()), share


def _board(rng: np.random.Generator, grey: tuple[int, int], size_px: tuple[int, int] = (48, 48)
           ) -> NDArray[np.uint8]:
    """A board's printed side: smooth random shading between grey levels (cardboard, clothes)."""
    import cv2

    small = rng.uniform(grey[0], grey[1], (size_px[1] // 8 + 1, size_px[0] // 8 + 1)).astype(np.float32)
    return np.clip(cv2.resize(small, size_px, interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)


def _wall_parallel(site: Any, wall_index: int, x_left: float, y_top: float, offset_m: float) -> NDArray[np.float64]:
    """T_room_from_target of a board parallel to the wall, its top-left corner at wall (x_left, y_top),
    offset_m in front of it, its printed side facing the room (room.Target's frame: x right, y down)."""
    return site.walls[wall_index].T_room_from_wall @ make_pose(np.diag([1.0, -1.0, -1.0]), [x_left, y_top, offset_m])


Undo = Callable[[], None]


@dataclass
class Scene:
    """A degraded scene: what it is, how it changes the site (apply() returns the undo), whether it happens
    before the wall pose is estimated (the session re-estimates with it in view) and, for a wrong rig file, the
    rig the session is started with instead."""

    kind: str
    what: str
    apply: Callable[[], Undo]
    before: bool = False
    rig: Rig | None = None


def _when(before: bool) -> str:
    return "at the estimate" if before else "after it"


def robot_moved(station: Station, t_xy_m: tuple[float, float], yaw_deg: float) -> Scene:
    """The robot pushed on the floor by t_xy_m (robot frame) and turned by yaw_deg after the estimate."""
    from geometry.poses import rotation_about

    site = station.site
    delta = make_pose(rotation_about([0, 0, 1], np.radians(yaw_deg)), [t_xy_m[0], t_xy_m[1], 0.0])

    def apply() -> Undo:
        site.move_robot(station.T_room_from_robot @ delta)
        return lambda: site.move_robot(station.T_room_from_robot)

    return Scene("robot moved", f"{1000 * np.hypot(*t_xy_m):.0f} mm, {yaw_deg:+.2f}°", apply)


def head_slipped(station: Station, slip_deg: tuple[float, float]) -> Scene:
    """The head's mount slipped by (pan, tilt) degrees; its encoder still reports the command."""
    robot = station.robot

    def apply() -> Undo:
        robot.head_sim.faults.slip_deg = (float(slip_deg[0]), float(slip_deg[1]))
        robot.sync_head()

        def undo() -> None:
            robot.head_sim.faults.slip_deg = (0.0, 0.0)
            robot.sync_head()

        return undo

    return Scene("head slipped", f"pan {slip_deg[0]:+.2f}°, tilt {slip_deg[1]:+.2f}°", apply)


def _board_scene(station: Station, kind: str, what: str, texture: NDArray[np.uint8], size_m: tuple[float, float],
                 top_left_xy: tuple[float, float], offset_m: float, albedo: tuple[float, float], before: bool
                 ) -> Scene:
    site = station.site
    T = _wall_parallel(site, station.wall_index, top_left_xy[0], top_left_xy[1], offset_m)

    def apply() -> Undo:
        site.add_target(texture, size_m, T, paper_albedo=albedo[0], ink_albedo=albedo[1])
        return site.remove_targets

    return Scene(kind, f"{what}, {_when(before)}", apply, before)


def pattern_occluded(station: Station, fraction: float, left_m: float, offset_m: float, before: bool,
                     rng: np.random.Generator) -> Scene:
    """A board (cardboard) offset_m before the wall over `fraction` of the drawn area's width from left_m."""
    x0, y0 = station.area_xy.min(axis=0)
    x1, y1 = station.area_xy.max(axis=0)
    width = fraction * (x1 - x0 + 0.1)
    return _board_scene(station, "pattern occluded", f"board over {100 * fraction:.0f} % of the width, "
                        f"{100 * offset_m:.0f} cm off the wall", _board(rng, (140, 230)), (width, y1 - y0 + 0.1),
                        (left_m, y1 + 0.05), offset_m, (0.7, 0.2), before)


def person_in_beam(station: Station, centre_m: float, offset_m: float, before: bool,
                   rng: np.random.Generator) -> Scene:
    """A person (0.45 × 1.75 m, dark clothes) standing offset_m before the wall at centre_m along it."""
    return _board_scene(station, "person in the beam", f"at {centre_m:.2f} m along, {offset_m:.2f} m before the "
                        "wall", _board(rng, (20, 180)), (0.45, 1.75), (centre_m - 0.225, 1.75), offset_m, (0.6, 0.05),
                        before)


def sunlight(station: Station, lux: float, before: bool) -> Scene:
    """Sunlight through a window: the room lit with lux instead of its own light."""
    site = station.site

    def apply() -> Undo:
        site.room.ambient_lux = float(lux)

        def undo() -> None:
            site.room.ambient_lux = station.ambient_lux

        return undo

    return Scene("sunlight", f"{lux:.0f} lux on the wall, {_when(before)}", apply, before)


def wrong_rig_file(station: Station, variant: int, rng: np.random.Generator) -> Scene:
    """The session started with another robot's rig file (see perturbed_rig)."""
    rig, what = perturbed_rig(station.session.rig, variant, rng)
    return Scene("wrong rig file", what, lambda: (lambda: None), True, rig)


def draw_scene(station: Station, kind: str, rng: np.random.Generator) -> Scene:
    """A random scene of a kind, its magnitude drawn from rng. Occluders, people and sunlight come before the
    wall pose is estimated (the pattern is photographed with them) or after it (the closed loop meets them),
    half and half."""
    x0 = float(station.area_xy[:, 0].min())
    x1 = float(station.area_xy[:, 0].max())
    if kind == "robot moved":
        t = rng.normal(size=2)
        t *= rng.uniform(0.0, 0.04) / max(float(np.linalg.norm(t)), 1e-9)
        return robot_moved(station, (float(t[0]), float(t[1])), float(rng.uniform(-1.0, 1.0)))
    if kind == "head slipped":
        slip = rng.uniform(-0.6, 0.6, 2)
        return head_slipped(station, (float(slip[0]), float(slip[1])))
    if kind == "wrong rig file":
        return wrong_rig_file(station, int(rng.integers(4)), rng)
    before = bool(rng.random() < 0.5)
    if kind == "pattern occluded":
        fraction = float(rng.uniform(0.05, 0.95))
        width = fraction * (x1 - x0 + 0.1)
        return pattern_occluded(station, fraction, float(rng.uniform(x0 - 0.05, x1 + 0.05 - width)),
                                float(rng.uniform(0.01, 0.15)), before, rng)
    if kind == "person in the beam":
        T_wall_from_room = invert(station.site.walls[station.wall_index].T_room_from_wall)
        projector_z = float(transform_points(T_wall_from_room, station.site.T_room_from("projector")[:3, 3])[2])
        # between the wall and the robot, never closer than 0.7 m to the projector
        offset = float(rng.uniform(0.3, max(0.35, min(1.5, projector_z - 0.7))))
        return person_in_beam(station, float(rng.uniform(x0, x1)), offset, before, rng)
    if kind == "sunlight":
        return sunlight(station, float(np.exp(rng.uniform(np.log(300.0), np.log(30_000.0)))), before)
    raise ValueError(f"unknown scene kind {kind!r}")


def run_scene(station: Station, scene: Scene | str, seed: int = 0) -> Outcome:
    """One rendered degraded scene from the station's registration: the session's update() on the changed
    site (a wrong rig file: a session started with it), judged by the site's truth; the site is put back.
    scene: a Scene, or a kind whose magnitude is drawn from the seed."""
    from arproj.session.session import ProjectionSession

    station.restore()
    if isinstance(scene, str):
        scene = draw_scene(station, scene, np.random.default_rng(seed))
    if scene.rig is not None:
        with ProjectionSession(scene.rig, station.session.wall_map, station.robot, ctx=station.ctx) as wrong:
            decision = wrong.update(force=True, show=False)
            return _outcome(wrong, station, scene, seed, decision)
    undo = scene.apply()
    try:
        decision = station.session.update(force=scene.before, show=False)
        return _outcome(station.session, station, scene, seed, decision)
    finally:
        undo()


def _outcome(session: ProjectionSession, station: Station, scene: Scene, seed: int, decision: Any) -> Outcome:
    ev = session.last_evidence
    loop = ev.closed_loop_errors_m if ev is not None else None
    loop_max = float(np.max(loop)) if loop is not None and len(loop) else float("nan")
    lost = any(r.startswith(("pattern lost", "wall pose")) for r in decision.reasons)
    true_max, true_mean, share = judge(session, station.site, station.wall_index)
    judged = session.registration is not None or session.refused_registration is not None
    return Outcome(scene.kind, scene.what, seed, decision.show_map, list(decision.reasons), true_max, true_mean,
                   float(decision.bound_m), loop_max, judged and not lost, share)


def perturbed_rig(rig: Rig, variant: int, rng: np.random.Generator) -> tuple[Rig, str]:
    """Another robot's rig file (same devices, other unit): stereo extrinsics, projector, head or camera mount."""
    from dataclasses import replace

    from geometry.head import HeadModel
    from geometry.poses import rotation_about

    intr = dict(rig.intrinsics)
    poses = dict(rig.poses)
    head = rig.head
    kind = variant % 4
    if kind == 0:
        axis = rng.normal(size=3)
        angle = np.radians(rng.uniform(0.3, 1.5))
        T = rig.pose("T_camera_right_from_camera_left").copy()
        T = make_pose(rotation_about(axis, angle), rng.normal(0, 0.004, 3)) @ T
        poses["T_camera_right_from_camera_left"] = T
        poses.pop("T_camera_left_from_camera_right", None)
        what = f"stereo extrinsics off by {np.degrees(angle):.2f}°"
    elif kind == 1:
        p = intr["projector"]
        scale = 1 + rng.choice([-1, 1]) * rng.uniform(0.01, 0.04)
        intr["projector"] = replace(p, fx=p.fx * scale, fy=p.fy * scale, cy=p.cy + rng.uniform(-25, 25))
        what = f"projector focal length off by {100 * (scale - 1):+.1f} %"
    elif kind == 2:
        assert head is not None
        offsets = head.zero_offsets_deg + np.array([*rng.uniform(-1.0, 1.0, 2), 0.0])
        head = HeadModel(head.axes, head.points, head.T_robot_from_projector_zero, offsets)
        what = f"head zero offsets off by {np.abs(offsets - rig.head.zero_offsets_deg).max():.2f}°"  # type: ignore
    else:
        T = rig.pose("T_robot_from_camera_left")
        poses["T_robot_from_camera_left"] = T @ make_pose(rotation_about(rng.normal(size=3),
                                                                          np.radians(rng.uniform(0.5, 2.0))),
                                                            rng.normal(0, 0.015, 3))
        poses.pop("T_camera_left_from_robot", None)
        what = "camera mount on the robot differs"
    return Rig(intr, poses, head, {"source": "another robot's rig"}), what
