"""What `arproj project --room room.glb` runs: the room session (arproj.session.room.RoomSession) over the walls of
room.glb, the head turned to each --aim/--follow point in turn (a point on any of the room's walls), one cycle
each: the session registers on the wall the beam falls on most and judges every other wall in view."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from arproj.session.room import RoomMap, RoomSession, load_room_map
from devices.errors import DeviceError
from geometry.errors import InputError
from geometry.rig import Rig

PLANE_MATCH_M = 0.05  # --sim: room.glb's first wall must lie this close to the site's room wall it names


def parse_room_point(text: str, option: str) -> tuple[int, tuple[float, float]]:
    """'K:X,Y' (point X,Y m on room.glb's wall K) or 'X,Y' (on its first wall) → (wall index K, (x, y))."""
    wall, _, xy = text.rpartition(":")
    try:
        x, y = (float(v) for v in xy.split(","))
        return (int(wall) if wall else -1), (x, y)
    except ValueError:
        raise InputError(f"{option} {text!r} is not K:X,Y (wall K of room.glb, metres) or X,Y",
                         f"e.g. {option} 1:0.4,1.2") from None


def open_room_map(options: Any) -> RoomMap:
    """room.glb for the session (InputError naming what does not fit: other map options, --wall)."""
    if options.map_path is not None or options.truth is not None or options.site is not None:
        raise InputError("--room projects room.glb's own maps: not with --map, --truth or --site",
                         "drop them, or drop --room")
    room = load_room_map(options.room)
    if options.wall_index != room.walls[0].index:
        raise InputError(f"--wall {options.wall_index}: the robot starts before room.glb's first wall, wall "
                         f"{room.walls[0].index}", f"pass --wall {room.walls[0].index} (or leave it out)")
    return room


def room_robot_placement(room: RoomMap, options: Any) -> dict[str, float]:
    """--sim: the robot stands before the first aim point when it lies on room.glb's first wall (its along and
    height on that room wall: room.glb's first wall frame is the site's room wall's, check_room_on_site)."""
    if not options.room_aims or options.room_aims[0][0] not in (-1, room.walls[0].index):
        return {}
    x, y = options.room_aims[0][1]
    return {"along_m": float(x), "aim_height_m": float(y)}


def _position(room: RoomMap, index: int) -> int:
    """Where wall `index` (-1: the first) is in room.walls; InputError naming the walls there are."""
    if index < 0:
        return 0
    for k, w in enumerate(room.walls):
        if w.index == index:
            return k
    raise InputError(f"room.glb has no wall {index} (walls: {', '.join(str(w.index) for w in room.walls)})",
                     "aim at one of them, e.g. --aim 0:1.2,1.1")


def check_room_on_site(room: RoomMap, site: Any) -> None:
    """--sim: room.glb's walls must lie in the simulated room's walls they name (it was made in this room)."""
    for w in room.walls:
        if not 0 <= w.index < len(site.walls):
            raise InputError(f"{room.source}: wall {w.index} is not a wall of the simulated room")
        T = site.walls[w.index].T_room_from_wall
        off = abs(float(T[:3, 2] @ (w.T_room_from_wall[:3, 3] - T[:3, 3])))
        if off > PLANE_MATCH_M or float(T[:3, 2] @ w.T_room_from_wall[:3, 2]) < 0.99:
            raise InputError(f"{room.source}: wall {w.index} lies {off * 1000:.0f} mm off the simulated room's "
                             "wall of that index: it was made in another room",
                             "make it on this site (`arproj demo`, or `arproj map --range-images`)")


def run_room(rig: Rig, room: RoomMap, robot: Any, options: Any, say: Callable[[str], None],
             ctx: object | None = None) -> dict:
    """The room session's cycles: for each aim point (--follow, else --aim, else the first wall's map centre)
    turn the head there and update; a JSON-able summary of each cycle with every judged wall's verdict."""
    site = getattr(robot, "site", None)
    if site is not None:
        check_room_on_site(room, site)
    aims = list(options.room_aims)
    if not aims:
        x0, y0, x1, y1 = room.walls[0].wall_map.extent
        aims = [(-1, ((x0 + x1) / 2, (y0 + y1) / 2))]
    result: dict = {"cycles": [], "map": room.source, "rig": rig.quality.get("source", "rig file")
                    if isinstance(rig.quality, dict) else "rig file",
                    "frames": str(options.output) if options.output else None}
    with RoomSession(rig, room.walls, robot, ctx=ctx, other=room.other) as session:
        repeat = 1 if options.room_aims else max(1, options.cycles)  # --cycles N: N cycles at the one aim
        aimed: tuple[int, tuple[float, float]] | None = None
        for cycle, (index, xy) in enumerate(aims * repeat):
            k = _position(room, index)
            if aimed != (index, xy):  # turn the head only to a new point: a repeated cycle keeps its registration
                aimed = (index, xy)
                try:
                    session.aim_at(k, xy)
                except (DeviceError, InputError) as err:
                    say(f"[yellow]warning:[/] {err} — projecting from where the head is now")
            verdicts = session.update()
            walls = {str(session.walls[j].index): {
                "shown": v.shown, "reasons": v.decision.reasons,
                "bound_mm": None if not np.isfinite(v.decision.bound_m) else round(v.decision.bound_m * 1000, 3)}
                for j, v in sorted(verdicts.items())}
            shown = any(v.shown for v in verdicts.values())
            reasons = [f"wall {i}: {r}" for i, w in walls.items() if not w["shown"] for r in w["reasons"]]
            if not verdicts:
                reasons = [f"wall {session.walls[session.anchor].index}: "
                           f"{session.session.pose_failure or 'no registration'}"]
            result["cycles"].append({"cycle": cycle, "aim": {"wall": room.walls[k].index, "xy": list(xy)},
                                     "registered_on": session.walls[session.anchor].index, "walls": walls,
                                     "show_map": shown, "reasons": reasons, "frame_says": list(session.last_words)})
            say(f"cycle {cycle}: registered on wall {session.walls[session.anchor].index}; " + ", ".join(
                f"wall {i} {'shown' if w['shown'] else 'dark'}" for i, w in walls.items()))
        result["log"] = session.log + [line for s in session.sessions.values() for line in s.log]
    return result
