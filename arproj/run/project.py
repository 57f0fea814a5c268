"""What `arproj project` runs: builds the session from options, keeps it up where it can, reports results."""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from arproj.session import registration
from arproj.session.output import BeamerWindow, FileOutput, MemoryOutput, ScreenStream
from arproj.session.wallmap import WallMap, load_wall_map, wall_map_from_wall_file, wall_room_in_room
from arproj.site_file import SiteWall, read_site_wall, simulated_projection_scene
from devices.errors import DeviceError
from devices.pelco_d import PanTiltHead
from devices.sim import HeadFaults
from geometry.errors import InputError
from geometry.poses import invert
from geometry.rig import Rig


@dataclass
class SessionOptions:
    map_path: Path | None = None
    objects: Path | None = None
    truth: Path | None = None
    rig_dir: Path | None = None
    sim: bool = False
    seed: int = 0
    wall_index: int = 0
    distance: float = 2.5
    incidence: float = 0.0
    aim: tuple[float, float] | None = None
    drill: tuple[float, float] | None = None
    follow: list[tuple[float, float]] = field(default_factory=list)
    cycles: int = 1
    output: Path | None = None
    window: bool = False
    screen: str = "0"     # --window's display, or a screen server tcp://HOST:PORT (frames sent there)
    head_url: str | None = None
    laser_url: str | None = None  # hardware: the projection robot's 2-D laser (devices/laser2d.py)
    inclinometer_url: str | None = None  # the robot's inclinometer (devices/inclinometer.py), hardware or served
    inclinometer: bool = True  # --sim without inclinometer_url: a simulated one on the site (False: the prior)
    left: str = "0"
    right: str = "1"
    wall_prior: Path | None = None
    site: Path | None = None          # a site file (arproj-site/1): find wall `site_key` again by the laser
    site_key: str | None = None
    head_fault: str | None = None
    view: str | None = None    # --view live | FILE.rrd: the session in Rerun (arproj.run.view.SessionView)
    record: Path | None = None  # --record FILE.mcap: every cycle as ROS 2 messages (arproj.session.record)
    commands: Iterable[str] | None = None  # interactive: lines such as "aim 1.2,1.1", "drill 1.3,1.0", "update"
    room: Path | None = None   # --room room.glb: several walls of one room (arproj.run.room), instead of --map
    room_aims: list[tuple[int, tuple[float, float]]] = field(default_factory=list)  # (wall position, x, y) each


class MultiOutput:
    """Shows a frame on several outputs; an output that fails is dropped with a message, the rest go on."""

    def __init__(self, outputs: list, say: Callable[[str], None]) -> None:
        self.outputs = outputs
        self.say = say

    def show(self, frame: NDArray[np.uint8]) -> None:
        for out in list(self.outputs):
            try:
                out.show(frame)
            except InputError as err:
                self.say(f"[yellow]warning:[/] {err} — that output is dropped, the session goes on")
                self.outputs.remove(out)

    def close(self) -> None:
        for out in self.outputs:
            out.close()


def load_map(options: SessionOptions, site_wall: SiteWall | None = None) -> WallMap:
    if options.map_path is not None:
        return load_wall_map(options.map_path, options.objects)
    if options.truth is not None:
        return wall_map_from_wall_file(options.truth)
    if site_wall is not None:
        glb = site_wall.map_dir / "wall.glb"
        if not glb.is_file():
            raise InputError(f"--site: wall {site_wall.key!r}'s map {glb} does not exist",
                             f"map the scan first: `arproj map {site_wall.scan_log} --out {site_wall.map_dir}`, "
                             "or pass --map")
        wall_map = load_wall_map(glb, options.objects)
        # the DIN zones from the site's room: its floor, ceiling and corners, the wall's doors, windows, sockets
        wall_map.room = wall_room_in_room(site_wall.T_room_from_wall, site_wall.corners_m, site_wall.room_height_m,
                                          site_wall.wall_index, site_wall.openings, site_wall.sockets,
                                          f"site file, wall {site_wall.key!r}")
        return wall_map
    raise InputError("no map given", "pass --map WALL.glb (from `arproj map`) or --truth WALL.yaml")


def open_site_wall(options: SessionOptions) -> SiteWall | None:
    """The site file's wall the session projects on (None without --site)."""
    if options.site is None:
        return None
    if options.wall_prior is not None:
        raise InputError("give --site FILE or --wall-prior FILE, not both")
    if not options.site_key:
        raise InputError(f"--site {options.site}: say which wall with --wall KEY")
    return read_site_wall(options.site, options.site_key)


def simulated_site_for(site_wall: SiteWall, options: SessionOptions, ctx: object) -> tuple[Any, NDArray[np.float64]]:
    """The simulated projection site in the scanning simulator's true room around the site file's wall (what
    its simulated scan measured), the robot aimed at --aim (default: the wall's centre); and the wall's true
    T_room_from_wall there."""
    from arproj.sim.site import Site

    scene, T_room_from_map = simulated_projection_scene(site_wall.width_m, site_wall.height_m, options.distance,
                                                        options.incidence, options.aim)
    return Site.build(seed=options.seed, ctx=ctx, **scene), T_room_from_map


def _head_faults(spec: str | None) -> HeadFaults:
    if not spec:
        return HeadFaults()
    if spec == "dead":
        return HeadFaults(dead=True)
    if spec == "flaky":
        return HeadFaults(drop_reply_rate=0.2, corrupt_reply_rate=0.1, garbage_rate=0.2, ignore_command_rate=0.1)
    if spec.startswith("slip:"):
        try:
            pan, tilt = (float(v) for v in spec[5:].split(","))
        except ValueError:
            raise InputError(f"--head-fault {spec!r}: slip needs two angles, e.g. slip:0.3,0.0") from None
        return HeadFaults(slip_deg=(pan, tilt))
    raise InputError(f"--head-fault {spec!r} is unknown", "use dead, flaky or slip:PAN,TILT")


def check_rig_matches(rig: Rig, cameras: dict) -> None:
    """The rig's intrinsics must be for these cameras/projector (same image sizes)."""
    for name, intr in cameras.items():
        mine = rig.intrinsics.get(name)
        if mine is not None and (mine.width, mine.height) != (intr.width, intr.height):
            raise InputError(f"the rig file's {name} is {mine.width}x{mine.height} but the device delivers "
                             f"{intr.width}x{intr.height}", "pass the rig calibrated for this robot (--rig)")


def run_session(options: SessionOptions, say: Callable[[str], None] = print) -> dict:
    """Run the session as the options say; returns a JSON-able summary of every cycle."""
    from arproj.session.robot_io import SimulatedRobot, nominal_rig
    from arproj.session.session import ProjectionSession

    site_wall = open_site_wall(options)
    room_map = None
    if options.room is not None:
        from arproj.run.room import open_room_map, room_robot_placement

        room_map = open_room_map(options)
    wall_map = room_map.walls[0].wall_map if room_map is not None else load_map(options, site_wall)
    outputs: list = []
    memory = MemoryOutput()
    outputs.append(memory)
    if options.output is not None:
        outputs.append(FileOutput(options.output))
    rig = Rig.load(options.rig_dir) if options.rig_dir is not None else None
    robot = None
    site = None
    ctx = None  # one GL context for the simulated site and the map renderer, released at the end
    projector_size = (1280, 800) if rig is None else rig.intrinsics["projector"].size \
        if "projector" in rig.intrinsics else (1280, 800)
    if options.screen.startswith("tcp://"):  # a screen server (one beside the beamer, or a simulated site's)
        outputs.append(ScreenStream(options.screen))
    elif not options.screen.isdigit():
        raise InputError(f"--screen {options.screen!r} is neither a display number nor tcp://HOST:PORT",
                         "e.g. --screen 1 --window, or --screen tcp://127.0.0.1:5000")
    elif options.window:
        try:
            outputs.append(BeamerWindow(*projector_size, screen=int(options.screen)))
        except InputError as err:
            say(f"[yellow]warning:[/] {err} — going on without the window" +
                (f"; frames are written to {options.output}" if options.output else ""))
    multi = MultiOutput(outputs, say)
    try:
        if options.sim and options.laser_url is not None:
            raise InputError("--laser reads the robot's laser at a URL on hardware; with --sim the simulated "
                             "site's laser is read", "drop --laser, or run without --sim")
        if options.inclinometer_url is not None and not options.inclinometer:
            raise InputError("--inclinometer URL and --no-inclinometer contradict each other", "give one")
        if options.sim:
            from arproj.sim.site import Site
            from render.gl import create_context

            ctx = create_context()
            T_room_from_map = None if room_map is None else room_map.walls[0].T_room_from_wall
            if site_wall is not None:  # the scanned site's room, found again from the file (truth kept apart)
                site, T_room_from_map = simulated_site_for(site_wall, options, ctx)
            else:
                placed: dict = {} if room_map is None else room_robot_placement(room_map, options)
                site = Site.build(seed=options.seed, ctx=ctx, robot={"distance_m": options.distance,
                                                            "incidence_deg": options.incidence,
                                                            "wall": options.wall_index, **placed})
            if rig is None:
                rig = nominal_rig(site)
                say("[yellow]note:[/] no --rig given: using the simulated robot's design values (uncalibrated); "
                    "run `arproj calibrate --sim --out RIG` and pass --rig RIG for a calibrated rig")
            check_rig_matches(rig, {"camera_left": site.camera_left, "camera_right": site.camera_right,
                                    "projector": site.projector})
            if options.head_url is not None and options.head_fault:
                raise InputError("--head-fault injects faults into the in-process head: not with --head URL",
                                 "start `arproj devices serve --faults P` for a faulty head at a URL")
            robot = SimulatedRobot.on_site(site, 0 if site_wall is not None else options.wall_index, multi,
                                           seed=options.seed, head_faults=_head_faults(options.head_fault),
                                           timeout_s=0.1 if options.head_url is None else 0.5,
                                           head_url=options.head_url, T_room_from_map=T_room_from_map,
                                           site_wall=site_wall, inclinometer=options.inclinometer,
                                           inclinometer_url=options.inclinometer_url)
        else:
            if rig is None:
                raise InputError("no rig given", "pass --rig RIG_DIR (from `arproj calibrate`), or --sim")
            if site_wall is not None and options.laser_url is None:
                raise InputError(f"--site {options.site}: finding wall {site_wall.key!r} again on hardware needs "
                                 "the projection robot's 2-D laser", "pass --laser URL (or --wall-prior FILE)")
            if site_wall is None and options.wall_prior is None:
                raise InputError("hardware sessions need --wall-prior FILE (T_wall_from_robot), or --site FILE "
                                 "--wall KEY with the robot's 2-D laser (--laser URL)")
            if site_wall is None and options.inclinometer_url is not None:
                # with a prior file the plane is snapped onto it: no fusion would read the inclinometer
                raise InputError("--inclinometer is read by the full wall-pose fusion, which needs --site FILE "
                                 "--wall KEY and --laser URL; with --wall-prior it would not be used",
                                 "give --site and --laser, or drop --inclinometer")
            robot = _hardware_robot(options, rig, multi, site_wall)
        if room_map is not None:
            from arproj.run.room import run_room

            return run_room(rig, room_map, robot, options, say, ctx)
        result = _run(ProjectionSession, rig, wall_map, robot, options, memory, say, ctx)
        if site is not None and isinstance(robot, SimulatedRobot) and result.get("registration"):
            result["registration"]["truth"] = _registration_truth(site, robot, result["registration"], rig)
        return result
    finally:
        if robot is not None:
            robot.close()
        multi.close()
        if site is not None:
            site.release()
        if ctx is not None:
            ctx.release()


def _hardware_robot(options: SessionOptions, rig: Rig, output: MultiOutput, site_wall: SiteWall | None) -> Any:
    """The robot on hardware: cameras, head and (--laser) the 2-D laser, at their URLs; whatever was opened is
    closed again when a later device fails."""
    from arproj.session.robot_io import DeviceInclinometer, DeviceLaser, HardwareRobot

    laser = None
    if options.laser_url is not None:
        try:
            T_robot_from_laser = rig.pose("T_robot_from_laser")
        except InputError:
            raise InputError(f"--laser: the rig {options.rig_dir} does not say where the laser sits on the robot "
                             "(poses: T_robot_from_laser)", "add T_robot_from_laser (4x4, metres, from the "
                             "robot's drawing) to the rig file's poses") from None
        laser = DeviceLaser(options.laser_url, T_robot_from_laser)
    head = inclinometer = None
    try:
        head = PanTiltHead(options.head_url) if options.head_url else None
        inclinometer = DeviceInclinometer(options.inclinometer_url) if options.inclinometer_url else None
        return HardwareRobot(options.left, options.right, rig.intrinsics["camera_left"],
                             rig.intrinsics["camera_right"], output, head, options.wall_prior, laser=laser,
                             site_wall=site_wall, inclinometer=inclinometer)
    except BaseException:
        for device in (head, laser, inclinometer):
            if device is not None:
                device.close()
        raise


def _run(session_cls: type, rig: Rig, wall_map: WallMap, robot: object, options: SessionOptions,
         memory: MemoryOutput, say: Callable[[str], None], ctx: object | None = None) -> dict:
    result: dict = {"cycles": [], "map": wall_map.source, "rig": rig.quality.get("source", "rig file")
                    if isinstance(rig.quality, dict) else "rig file",
                    "frames": str(options.output) if options.output else None}
    from arproj.session.record import Captures, SessionRecorder
    from mapping.ros.bag import RosBag

    watchers: list[Any] = []  # --record, --view: each told of every cycle
    captures = Captures()
    stack = contextlib.ExitStack()
    with stack, session_cls(rig, wall_map, robot, ctx=ctx) as session:  # the watchers closed also on an error
        if options.record is not None:
            watchers.append(SessionRecorder(stack.enter_context(RosBag(options.record)), rig, captures))
            result["record"] = str(options.record)
        if options.view is not None:
            from arproj.run.view import SessionView

            view = SessionView(options.view, captures)
            stack.callback(view.close)
            watchers.append(view)
        if watchers:
            captures.watch(robot)
        x0, y0, x1, y1 = wall_map.extent
        # --cycles 0: keep updating (re-estimate on motion, verify, show) until interrupted (Ctrl-C)
        targets = options.follow or ([None] * options.cycles if options.cycles > 0 else itertools.repeat(None))
        aim = options.aim if options.aim is not None else ((x0 + x1) / 2, (y0 + y1) / 2)
        try:
            session.aim_at(options.follow[0] if options.follow else aim)
        except (DeviceError, InputError) as err:
            say(f"[yellow]warning:[/] {err} — projecting from where the head is now")
        if options.drill is not None:
            session.set_drill_point(options.drill)
        for k, target in enumerate(targets):
            if target is not None:
                session.set_drill_point(target)
                if not _inside_image(session, target):
                    try:
                        session.aim_at(target)
                    except (DeviceError, InputError) as err:
                        say(f"[yellow]warning:[/] {err}")
            decision = session.update()
            for watcher in watchers:
                watcher.cycle(session, decision)
            cycle = {"cycle": k, "show_map": decision.show_map, "reasons": decision.reasons,
                     "bound_mm": None if not np.isfinite(decision.bound_m) else round(decision.bound_m * 1000, 3),
                     "frame_says": list(session.last_words)}
            legend = session.last_legend
            if decision.show_map and legend is not None:  # where the legend went, what it lists
                cycle["legend"] = {"box": list(legend.box), "placed": legend.placed,
                                   "classes": list(session.legend_classes())}
            reg = session.registration
            if reg is not None and reg.loop is not None and len(reg.loop.errors_xy):
                e = np.linalg.norm(reg.loop.errors_xy, axis=1) * 1000
                cycle["closed_loop_mm"] = {"seen": int(reg.loop.seen.sum()), "mean": float(e.mean()),
                                           "p95": float(np.percentile(e, 95)),
                                           "corrected": bool(np.any(reg.correction_xy != 0))}
            if session.drill_xy is not None:
                check = session.drill_check(session.drill_xy)
                cycle["drill"] = {"xy": [round(float(v), 4) for v in session.drill_xy], "verdict": check.verdict,
                                  "distance_mm": None if not np.isfinite(check.distance_m)
                                  else round(check.distance_m * 1000, 1), "message": check.message}
            result["cycles"].append(cycle)
            say(f"cycle {k}: " + ("map shown" if decision.show_map else "WARNING: " + "; ".join(decision.reasons)))
        if options.commands is not None:
            _interactive(session, options.commands, result, say, watchers)
        reg = session.registration
        if reg is not None:
            result["registration"] = {"T_wall_from_projector": reg.T_wall_from_projector.tolist(),
                                      "T_wall_from_robot": reg.T_wall_from_robot.tolist(),
                                      "sigma_mm": round(reg.sigma_m * 1000, 4), "source": reg.prior_source,
                                      "aim_xy_m": registration.aim_point_on_wall(reg.T_wall_from_projector,
                                                                                 session.projector_intr)[:2].tolist()}
        result["log"] = list(session.log)
    return result


COMMAND_HELP = ("commands: aim X,Y | drill X,Y | check X,Y | update | estimate (re-estimate now) | "
                "status | quit")


def _interactive(session: object, commands: Iterable[str], result: dict, say: Callable[[str], None],
                 watchers: Iterable[Any] = ()) -> None:
    """Run typed commands; a bad command or a failing device is reported and the session goes on."""
    say(COMMAND_HELP)
    for line in commands:
        words = line.strip().split(maxsplit=1)
        if not words:
            continue
        verb, arg = words[0].lower(), (words[1] if len(words) > 1 else "")
        try:
            if verb in ("quit", "exit", "q"):
                break
            if verb == "aim":
                x, y = (float(v) for v in arg.split(","))
                session.aim_at((x, y))  # type: ignore[attr-defined]
                verb = "update"
            if verb == "drill":
                x, y = (float(v) for v in arg.split(","))
                check = session.set_drill_point((x, y))  # type: ignore[attr-defined]
                say(f"drill point ({x:.3f}, {y:.3f}) m: {check.message}")
                verb = "update"
            if verb == "check":
                x, y = (float(v) for v in arg.split(","))
                say(f"({x:.3f}, {y:.3f}) m: {session.drill_check((x, y)).message}")  # type: ignore[attr-defined]
            elif verb in ("update", "estimate"):
                decision = session.update(force=verb == "estimate")  # type: ignore[attr-defined]
                for watcher in watchers:
                    watcher.cycle(session, decision)
                result["cycles"].append({"cycle": len(result["cycles"]), "show_map": decision.show_map,
                                         "reasons": decision.reasons, "command": line.strip()})
                say("map shown" if decision.show_map else "WARNING: " + "; ".join(decision.reasons))
            elif verb == "status":
                d = session.last_decision  # type: ignore[attr-defined]
                say("no decision yet" if d is None else
                    f"{'map shown' if d.show_map else 'warning'}; bound ±{d.bound_m * 1000:.1f} mm; "
                    f"{'; '.join(list(session.log)[-3:])}")  # type: ignore[attr-defined]
            elif verb not in ("aim", "drill"):
                say(f"unknown command {verb!r}; {COMMAND_HELP}")
        except ValueError:
            say(f"could not read {line.strip()!r}: points are X,Y in metres, e.g. aim 1.2,1.1")
        except (InputError, DeviceError) as err:
            say(f"[yellow]warning:[/] {err}")


def _registration_truth(site: Any, robot: Any, reg: dict, rig: Rig) -> dict:
    """The simulated site's truth for the session's registration: where the map's wall frame really has the
    projector, and how far (mm) the estimate puts the beamer's centre pixel from where it really lands."""
    from geometry.poses import rotation_angle_deg

    T_true = invert(robot.T_room_from_map) @ site.T_room_from("projector")
    T_est = np.asarray(reg["T_wall_from_projector"], dtype=np.float64)
    projector = rig.intrinsics["projector"]
    centre = registration.aim_point_on_wall(T_est, projector)[:2]
    landed = registration.aim_point_on_wall(T_true, projector)[:2]
    T_wall_from_robot = invert(robot.T_room_from_map) @ site.T_room_from_robot
    T_est_robot = np.asarray(reg["T_wall_from_robot"], dtype=np.float64)
    return {"T_wall_from_projector": T_true.tolist(), "T_wall_from_robot": T_wall_from_robot.tolist(),
            "robot_position_error_mm": float(1000 * np.linalg.norm(T_est_robot[:3, 3] - T_wall_from_robot[:3, 3])),
            "projector_position_error_mm": float(1000 * np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])),
            "projector_rotation_error_deg": rotation_angle_deg(T_est[:3, :3], T_true[:3, :3]),
            "aim_error_mm": float(1000 * np.linalg.norm(centre - landed))}


def _inside_image(session: object, xy: tuple[float, float], margin: float = 0.2) -> bool:
    """Is wall point xy inside the inner part of the beamer's current image?"""
    reg = session.registration  # type: ignore[attr-defined]
    if reg is None:
        return False
    from geometry.poses import invert, transform_points

    intr = session.projector_intr  # type: ignore[attr-defined]
    from arproj.session.registration import project_in_view

    p = transform_points(invert(reg.T_wall_from_projector), [xy[0], xy[1], 0.0])
    return bool(project_in_view(intr, p[None], margin)[1][0])
