"""Where to look first: DIN 18015-3 installation zones and known sockets and openings, in wall coordinates.

DIN 18015-3 lays electric cables in walls in installation zones: horizontal bands 15–45 cm below the ceiling,
15–45 cm above the floor and (where work surfaces are) 100–130 cm above the floor; vertical bands 10–30 cm
beside openings (doors, windows) and corners. A cable outside them is against the standard, not impossible,
so the zones and the known sockets only *order* the adaptive planner's passes (scanner/plan.py): what lies
in a zone is measured first, everything is measured just the same, and nothing is mapped from a zone alone.

The floor and ceiling come from the wall file's `room` if it has one, else from the site survey
(LaserConfig: the floor `floor_margin_m` below the wall frame's y = 0, the ceiling `room_height_m` above the
floor, raised as the simulated site raises it for a taller wall); the wall's two ends are its corners.
Wall frame: x right along the wall, y up from the wall's bottom edge, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from geometry.polyline import distances_to_polyline
from scanner.laser import LaserConfig
from scanner.wall import Wall

HORIZONTAL_ZONE_M = (0.15, 0.45)  # below the ceiling and above the floor
MIDDLE_ZONE_M = (1.00, 1.30)  # above the floor
VERTICAL_ZONE_M = (0.10, 0.30)  # beside a corner or an opening's side
SOCKET_NEAR_M = 0.10  # a pass or a find this close to a known socket lies at it (a box is 6-7 cm, its cable
# leaves it from an edge)
ALONG_COS = 0.9  # a pass runs along a zone's course within ~25°, else it crosses it
ALONG_SCORE = 1.0  # a pass in a zone running along its cables, a find in a zone on a course along it
CROSS_SCORE = 0.5  # a pass across a zone: it crosses the zone's cables


@dataclass(frozen=True)
class Zone:
    """One installation zone: a band lo_m..hi_m of y (course 'x': its cables run horizontally) or of x
    (course 'y': vertically), metres in wall coordinates, over the whole wall along its course."""

    name: str
    course: str
    lo_m: float
    hi_m: float

    def describe(self) -> str:
        coordinate = "y" if self.course == "x" else "x"
        return f"{self.name} ({coordinate} {self.lo_m:.2f}..{self.hi_m:.2f} m)"

    def contains(self, xy: np.ndarray) -> bool:
        c = float(xy[1] if self.course == "x" else xy[0])
        return self.lo_m <= c <= self.hi_m


@dataclass
class Priors:
    """A wall's installation zones and its known sockets (sockets : (n, 2) float64, metres); `origin` says
    where the floor and ceiling came from."""

    zones: list[Zone]
    sockets: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    origin: str = ""

    def describe(self) -> str:
        zones = "; ".join(z.describe() for z in self.zones) or "none on this wall"
        sockets = f"; known sockets at {', '.join(f'({x:.2f}, {y:.2f})' for x, y in self.sockets)}" \
            if len(self.sockets) else ""
        return f"DIN 18015-3 zones (floor and ceiling from {self.origin}): {zones}{sockets}"

    def pass_hits(self, start_xy: np.ndarray, end_xy: np.ndarray) -> list[tuple[str, float]]:
        """[(zone or socket name, score)] of a straight pass from start_xy to end_xy (wall metres): ALONG_SCORE
        where it runs along a zone's course inside the zone or passes a known socket, CROSS_SCORE where it runs
        across a zone's band from one side to the other."""
        a, b = np.asarray(start_xy, dtype=np.float64), np.asarray(end_xy, dtype=np.float64)
        length = float(np.linalg.norm(b - a))
        d = (b - a) / length if length > 0 else np.array([1.0, 0.0])
        hits = []
        for zone in self.zones:
            i = 1 if zone.course == "x" else 0  # the coordinate across the zone's band
            along = abs(float(d[1 - i])) >= ALONG_COS
            if along and zone.contains(0.5 * (a + b)):
                hits.append((zone.name, ALONG_SCORE))
            elif not along and min(a[i], b[i]) <= zone.lo_m and max(a[i], b[i]) >= zone.hi_m:
                hits.append((zone.name, CROSS_SCORE))
        for k, socket in enumerate(self.sockets):
            if distances_to_polyline(socket[None], np.array([a, b]))[0] <= SOCKET_NEAR_M:
                hits.append((f"socket {k + 1}", ALONG_SCORE))
        return hits

    def pass_score(self, start_xy: np.ndarray, end_xy: np.ndarray) -> float:
        """How much a pass looks where the zones and sockets say cables are: the best of pass_hits, 0 if none."""
        return max((score for _, score in self.pass_hits(start_xy, end_xy)), default=0.0)

    def point_hit(self, xy: np.ndarray, course: str | None = None) -> str | None:
        """The zone or socket a find at xy (wall metres) lies in, or None. course 'x' (a find on a vertical pass:
        the object runs roughly horizontally) or 'y' counts only zones whose cables run that way; None any."""
        p = np.asarray(xy, dtype=np.float64)
        for k, socket in enumerate(self.sockets):
            if float(np.linalg.norm(p - socket)) <= SOCKET_NEAR_M:
                return f"socket {k + 1}"
        for zone in self.zones:
            if (course is None or zone.course == course) and zone.contains(p):
                return zone.name
        return None

    def point_score(self, xy: np.ndarray, course: str | None = None) -> float:
        """ALONG_SCORE if a find at xy lies in a zone along its course or at a known socket, else 0."""
        return ALONG_SCORE if self.point_hit(xy, course) is not None else 0.0


def room_heights(wall: Wall, survey: LaserConfig | None = None) -> tuple[float, float, str]:
    """(floor y, ceiling y, where they came from) in wall coordinates: the wall file's room, else the survey's."""
    if wall.room is not None:
        return wall.room.floor_y_m, wall.room.ceiling_y_m, "the wall file"
    room = (survey or LaserConfig()).room_for_wall(wall.height_m)
    floor = -room.floor_margin_m
    return floor, floor + room.room_height_m, "the site survey"


def installation_zones(wall: Wall, floor_y_m: float, ceiling_y_m: float) -> list[Zone]:
    """The DIN 18015-3 zones that reach into the wall: three horizontal bands from the floor and ceiling, and
    vertical bands beside the wall's ends (corners) and each opening's left and right sides."""
    lo, hi = HORIZONTAL_ZONE_M
    mid_lo, mid_hi = MIDDLE_ZONE_M
    side_lo, side_hi = VERTICAL_ZONE_M
    zones = [Zone("top", "x", ceiling_y_m - hi, ceiling_y_m - lo),
             Zone("middle", "x", floor_y_m + mid_lo, floor_y_m + mid_hi),
             Zone("bottom", "x", floor_y_m + lo, floor_y_m + hi),
             Zone("left corner", "y", side_lo, side_hi),
             Zone("right corner", "y", wall.width_m - side_hi, wall.width_m - side_lo)]
    for k, opening in enumerate(wall.openings):
        left, right = float(opening.outline_m[:, 0].min()), float(opening.outline_m[:, 0].max())
        name = f"{opening.kind} {k + 1}"
        zones += [Zone(f"left of {name}", "y", left - side_hi, left - side_lo),
                  Zone(f"right of {name}", "y", right + side_lo, right + side_hi)]
    extent = {"x": (0.0, wall.height_m), "y": (0.0, wall.width_m)}  # the band's coordinate on the wall
    return [z for z in zones if z.hi_m >= extent[z.course][0] and z.lo_m <= extent[z.course][1]]


def wall_priors(wall: Wall, survey: LaserConfig | None = None) -> Priors:
    """The zones and known sockets of a wall (see the module docstring)."""
    floor, ceiling, origin = room_heights(wall, survey)
    return Priors(installation_zones(wall, floor, ceiling), np.asarray(wall.sockets, dtype=np.float64), origin)

