"""Finding the wall again from a site file: the projection robot's 2-D laser scan against the room the scanning
robot's laser saw (arproj.site_file), by the scanning robot's own line fix (scanner.laser.measure_fix).

The scan is turned into the wall's frame — by the measured wall plane's normal once the pattern has been seen,
before that by the heading (in CANDIDATE_STEP_DEG steps over the half turn the wall can lie in) whose fixes
against the left and the right side wall agree best on the room's width from the site file — and each side wall
the laser sees gives the laser's position along the wall (the right one mirrored, from the room's width), the
scanned wall its distance. Heights come from the floor the robot stands on and the wall frame's height above it.

The fix starts the full wall-pose fusion (wallpose.pose.estimate_wall_pose with the site's room, the same laser
returns and the plane), whose covariance the gate then uses: the fix's own σ is not given to it as a second
prior (the fusion uses the same returns), it starts with START_SIGMA_M / START_SIGMA_DEG, a navigation stack's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from arproj.site_file import SiteWall
from geometry.errors import InputError
from geometry.poses import make_pose
from scanner.laser import measure_fix

START_SIGMA_M = 0.03       # the fusion's start: a navigation stack's σ, not the fix's (see the docstring)
START_SIGMA_DEG = 1.0
CANDIDATE_STEP_DEG = 10.0  # within the line finder's 15° tilt tolerance
WIDTH_AGREEMENT_SIGMAS = 5.0  # both side walls' fixes must agree this well on the room's width


@dataclass
class RoomFix:
    """Where the robot stands against the site's room: T_wall_from_robot (the map's wall frame) and
    T_room_from_robot, the 1σ along the wall, and which side walls the laser saw."""

    T_wall_from_robot: NDArray[np.float64]
    T_room_from_robot: NDArray[np.float64]
    sigma_along_m: float
    sides: list[str]


@dataclass
class _Fix:
    x: float
    x_sigma: float
    dist: float
    angle: float
    sides: list[str]
    disagreement: float  # |x_left − x_right| in σ (0 with one side)


def _fix_at(points: NDArray[np.float64], normal_xy: NDArray[np.float64], site: SiteWall, seed: int) -> _Fix | None:
    """The fix with the scan (n, 2) (robot-frame xy relative to the laser) turned so that the wall's normal
    (robot-frame unit (2,), into the room) is the b axis; None when no side wall is found."""
    along = np.array([-normal_xy[1], normal_xy[0]])  # the wall's x axis: up × normal
    a, b = points @ along, points @ normal_xy
    ranges = np.hypot(a, b)
    results: list[tuple[str, float, float, float, float]] = []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        try:
            fix = measure_fix(np.arctan2(b, sign * a), ranges, 0.0, seed, "scanned wall")
        except InputError:
            continue
        # the left side wall stands at x = −side_margin, the right one the room's width further
        x = fix["x"] - site.side_margin_m if sign > 0 else site.room_width_m - site.side_margin_m - fix["x"]
        results.append((side, x, fix["x_sigma"], fix["dist"], sign * fix["angle"]))
    if not results:
        return None
    w = np.array([r[2] for r in results]) ** -2.0
    x = float(w @ [r[1] for r in results] / w.sum())
    disagreement = 0.0
    if len(results) == 2:
        width_sigma = (site.measured.get("width").sigma_m if "width" in site.measured else None) or 0.0
        disagreement = abs(results[0][1] - results[1][1]) / math.sqrt(
            results[0][2] ** 2 + results[1][2] ** 2 + width_sigma ** 2 + 1e-6 ** 2)
    best = min(results, key=lambda r: r[2])
    return _Fix(x, float(w.sum() ** -0.5), best[3], best[4], [r[0] for r in results], disagreement)


def _turned(normal_xy: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * normal_xy[0] - s * normal_xy[1], s * normal_xy[0] + c * normal_xy[1]])


def fix_in_site(points_robot: NDArray[np.float64], laser_origin_robot: NDArray[np.float64], site: SiteWall,
                normal_robot: NDArray[np.float64] | None = None, seed: int = 0) -> RoomFix:
    """Where the robot stands against the site's room from one laser scan: points_robot (n, 3) robot-frame
    returns, laser_origin_robot (3,) the laser's centre; normal_robot (3,) the measured wall plane's normal
    (into the room) when known. Raises InputError when the laser sees neither side wall of the scanned wall."""
    p = np.asarray(points_robot, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    o = np.asarray(laser_origin_robot, dtype=np.float64).reshape(3)
    rel = p[:, :2] - o[:2]
    if normal_robot is not None:
        n = np.asarray(normal_robot, dtype=np.float64)[:2]
        candidates = [n / np.linalg.norm(n)]
    else:  # the robot faces the wall: its normal points back towards the robot's half-space behind x = 0
        candidates = [np.array([math.cos(t), math.sin(t)])
                      for t in np.radians(np.arange(90.0, 270.0 + 1e-9, CANDIDATE_STEP_DEG))]
    found = [(c, f) for c in candidates if (f := _fix_at(rel, c, site, seed)) is not None]
    if not found:
        raise InputError(f"laser: neither side wall of {site.key!r} is in view, so the robot cannot find where "
                         "it stands along the wall", "clear the laser's view of the room's side walls")
    if normal_robot is None:
        consistent = [cf for cf in found if len(cf[1].sides) == 2 and cf[1].disagreement < WIDTH_AGREEMENT_SIGMAS]
        pool = consistent or found
        normal, fix = min(pool, key=lambda cf: abs(cf[1].angle))
        for sign in (-1.0, 1.0):  # the candidate's heading corrected by the wall line's own slope
            turned = _turned(normal, sign * fix.angle)
            better = _fix_at(rel, turned, site, seed)
            if better is not None and abs(better.angle) < abs(fix.angle):
                normal, fix = turned, better
                break
    else:
        normal, fix = found[0]
    up = np.array([0.0, 0.0, 1.0])
    along = np.array([-normal[1], normal[0], 0.0])
    R_robot_from_wall = np.column_stack([along, up, [normal[0], normal[1], 0.0]])
    q = R_robot_from_wall.T @ o  # the laser's centre in wall axes, from the robot's origin
    # the robot's origin stands on the floor, the wall frame's origin T_room_from_wall[2, 3] above it
    t = np.array([fix.x - q[0], -site.T_room_from_wall[2, 3], fix.dist - q[2]])
    T_wall_from_robot = make_pose(R_robot_from_wall.T, t)
    return RoomFix(T_wall_from_robot, site.T_room_from_wall @ T_wall_from_robot, fix.x_sigma, fix.sides)
