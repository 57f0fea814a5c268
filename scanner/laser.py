"""The robot's two 2-D laser scanners (paper §4.2): what they see of the room when the robot aligns to the wall.

Both sit at the drive frame's origin (their mounting offsets are calibrated out) and see a rectangle of room:
  * the horizontal laser scans the plane parallel to the floor. Coordinates (x along the wall = wall frame x,
    z away from the wall): scanned wall z = 0, side walls x = −m and x = W + m (m = side_margin_m), back wall
    z = room_depth_m. It gives the frame's x (against the left side wall), its distance to the wall and its
    yaw against the wall;
  * the vertical laser scans the plane parallel to the wall. Coordinates (x, y = wall frame): floor
    y = −floor_margin_m, the same side walls, ceiling room_height_m above the floor. It gives the frame's x
    again, its height y above the floor and its roll φ in the wall plane (the floor line's slope).
A horizontal laser alone cannot see y or φ, and φ matters most (1° turns a 2 m tall frame's top by 35 mm).

Each scan is reduced the same way (`measure_fix`): RANSAC + least-squares lines for the reference surface
behind the laser (wall or floor) and the left side wall; their corner gives the position along the surface,
the reference line the distance and angle. Standard deviations come from the line fits' residuals (σ²(XᵀX)⁻¹
propagated through the corner geometry), not assumed.

Simulation (`simulate_scan_2d`): exact ray casting of the rectangle, Gaussian range noise, a fraction of
outliers (returns from clutter in front of the surfaces: uniform between 5 % of and the true range), ranges in
whole millimetres as the laser's protocol sends them (devices/laser2d.py), deterministic from the generator given.
`simulated_head_scan` is one head's turn on the simulated site (the in-process robot and the laser simulator give
the same), `fix_from_scans` the fix of one turn of each head.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import numpy as np
from numpy.typing import NDArray

from devices.laser2d import ranges_from_mm, ranges_to_mm, ray_angles
from geometry.errors import InputError
from geometry.robust import best_hypothesis, draw_samples, refine

LINE_INLIER_M = 0.02  # RANSAC inlier distance for wall lines (several range-noise σ; outliers lie far)
LINE_MAX_TILT_RAD = math.radians(15.0)  # a wall line must run within this of its expected direction
LINE_MIN_POINTS = 20  # fewer inliers cannot give a trustworthy wall line
RANSAC_ITERATIONS = 300
CEILING_CLEARANCE_M = 0.10  # a simulated room's ceiling above the scanned wall's top, at least

# Frame columns the laser adds to the scan log (NaN/NULL when no laser fix is available)
LASER_KEYS: tuple[str, ...] = ("laser_x_m", "laser_x_sigma_m", "laser_y_m", "laser_y_sigma_m",
                               "laser_phi_rad", "laser_phi_sigma_rad", "laser_dist_m", "laser_dist_sigma_m",
                               "laser_yaw_rad", "laser_yaw_sigma_rad")
_LINE_KEYS = ("x", "x_sigma", "dist", "dist_sigma", "angle", "angle_sigma")


@dataclass(frozen=True)
class LaserConfig:
    """A typical 2-D safety/measurement laser (e.g. SICK TiM/LMS class) and the simulated room."""

    angular_step_rad: float = math.radians(0.25)
    range_sigma_m: float = 0.003
    max_range_m: float = 10.0
    outlier_fraction: float = 0.02
    room_depth_m: float = 4.0
    room_height_m: float = 2.7  # floor to ceiling (a taller wall's simulated room: room_for_wall)
    floor_margin_m: float = 0.3  # the floor lies this far below the wall frame's y = 0 (site survey)
    side_margin_m: float = 0.3  # the side walls stand this far left of x = 0 and right of x = W (the scanned
    # area lies inside the room); the site survey gives it, the fix reports x in wall coordinates with it
    standoff_m: float = 0.5  # laser (drive frame origin) distance from the wall when aligned
    standoff_sigma_m: float = 0.01  # how well the robot keeps that distance
    yaw_sigma_rad: float = math.radians(0.5)  # how well the robot aligns to the wall

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def room_for_wall(self, wall_height_m: float) -> LaserConfig:
        """This room, its ceiling raised where the scanned wall (from floor_margin_m up) would not fit under
        it with CEILING_CLEARANCE_M to spare: a simulated room always holds the wall it is scanned on."""
        needed = self.floor_margin_m + wall_height_m + CEILING_CLEARANCE_M
        return self if self.room_height_m >= needed else replace(self, room_height_m=needed)


def simulate_scan_2d(x_m: float, standoff_m: float, yaw_rad: float, wall_width_m: float, depth_m: float,
                     cfg: LaserConfig, rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One 360° scan from a laser standoff_m in front of the reference surface (wall or floor) at x_m, turned
    by yaw_rad; the rectangle is depth_m deep. Returns (angles (n,) rad in the laser frame, ranges (n,) m;
    NaN where nothing is within max_range_m)."""
    angles = ray_angles(-math.pi, cfg.angular_step_rad, math.ceil(2 * math.pi / cfg.angular_step_rad - 1e-9))
    world = angles + yaw_rad
    d = np.column_stack([np.cos(world), np.sin(world)])
    o = np.array([x_m, standoff_m])
    L, R, D = -cfg.side_margin_m, wall_width_m + cfg.side_margin_m, depth_m
    best = np.full(angles.shape, np.inf)
    # (axis of the surface's constant coordinate, its value, other-coordinate span)
    for axis, value, lo, hi in ((1, 0.0, L, R), (0, L, 0.0, D), (0, R, 0.0, D), (1, D, L, R)):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - o[axis]) / d[:, axis]
        other = o[1 - axis] + t * d[:, 1 - axis]
        hit = (t > 0) & (other >= lo) & (other <= hi)
        best = np.where(hit & (t < best), t, best)
    ranges = best + cfg.range_sigma_m * rng.standard_normal(angles.shape)
    outlier = rng.random(angles.shape) < cfg.outlier_fraction
    ranges[outlier] = rng.uniform(0.05, 1.0, int(outlier.sum())) * np.minimum(best[outlier], cfg.max_range_m)
    ranges[~np.isfinite(best) | (ranges > cfg.max_range_m)] = np.nan
    return angles, ranges_from_mm(ranges_to_mm(ranges))  # the device reports whole millimetres (devices/laser2d)


def _ransac_line(p: NDArray[np.float64], direction: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.bool_]:
    """Inliers (n,) of the line through p (n, 2) with most points within LINE_INLIER_M whose direction is
    within LINE_MAX_TILT_RAD of `direction` (unit (2,))."""
    if len(p) < LINE_MIN_POINTS:
        return np.zeros(len(p), bool)
    pairs = draw_samples(rng, len(p), 2, RANSAC_ITERATIONS)
    a, b = p[pairs[:, 0]], p[pairs[:, 1]]
    v = b - a
    length = np.linalg.norm(v, axis=1)
    ok = length > 0.05
    v = v[ok] / length[ok, None]
    a = a[ok]
    ok = np.abs(v @ direction) > math.cos(LINE_MAX_TILT_RAD)
    v, a = v[ok], a[ok]
    if len(v) == 0:
        return np.zeros(len(p), bool)
    n = np.column_stack([-v[:, 1], v[:, 0]])
    dist = np.abs(np.einsum("kj,knj->kn", n, p[None, :, :] - a[:, None, :]))
    best = best_hypothesis(len(v), lambda h: (dist[h] < LINE_INLIER_M).sum(axis=1))
    return dist[best] < LINE_INLIER_M


def _fit_line(p: NDArray[np.float64], inliers: NDArray[np.bool_], swap: bool, what: str
              ) -> tuple[float, float, float, NDArray[np.float64]]:
    """Least squares s = c0 + c1 (r − r̄) over the inliers, refined twice at 3× rms. r, s = a, b (or b, a if
    swap). Returns (c0, c1, r̄, covariance (2, 2) of (c0, c1))."""
    r, s = (p[:, 1], p[:, 0]) if swap else (p[:, 0], p[:, 1])

    def refit(keep: NDArray[np.bool_]) -> tuple[tuple[NDArray[np.float64], float, NDArray[np.float64]],
                                                 NDArray[np.bool_]]:
        if keep.sum() < LINE_MIN_POINTS:
            raise InputError(f"laser: only {int(keep.sum())} points on the {what}, too few for a line "
                             f"(need {LINE_MIN_POINTS})", "clear the laser's view of the walls")
        rm = float(r[keep].mean())
        X = np.column_stack([np.ones(int(keep.sum())), r[keep] - rm])
        coef = np.asarray(np.linalg.lstsq(X, s[keep], rcond=None)[0], dtype=np.float64)
        resid = np.asarray(s - coef[0] - coef[1] * (r - rm), dtype=np.float64)
        rms = float(np.sqrt(np.mean(resid[keep] ** 2)))
        return (coef, rm, resid), inliers & (np.abs(resid) < max(3.0 * rms, 1e-4))

    fitted, keep = refine(inliers.copy(), refit, rounds=3)
    assert fitted is not None  # without min_inliers every round fits (or raises)
    coef, rm, resid = fitted
    sigma2 = float(np.sum(resid[keep] ** 2)) / max(int(keep.sum()) - 2, 1)
    X = np.column_stack([np.ones(int(keep.sum())), r[keep] - rm])
    return float(coef[0]), float(coef[1]), rm, sigma2 * np.linalg.inv(X.T @ X)


def _corner(e: NDArray[np.float64], c: NDArray[np.float64], am: float, bm: float) -> NDArray[np.float64]:
    """(a, b) where the reference line b = e0 + e1 (a − am) meets a side wall line a = c0 + c1 (b − bm)."""
    e0, e1 = e[0] - e[1] * am, e[1]  # b = e0 + e1 a
    c0, c1 = c[0] - c[1] * bm, c[1]  # a = c0 + c1 b
    a_corner = (c0 + c1 * e0) / (1.0 - c1 * e1)
    return np.array([a_corner, e0 + e1 * a_corner])


def _fix_from_lines(e: NDArray[np.float64], c: NDArray[np.float64], am: float, bm: float) -> NDArray[np.float64]:
    """(x along the wall, distance to the wall, yaw) from the wall line b = e0 + e1 (a − am) and the left side
    wall line a = c0 + c1 (b − bm), both in the laser frame."""
    a_corner, b_corner = _corner(e, c, am, bm)
    e0, e1 = e[0] - e[1] * am, e[1]
    norm = math.hypot(1.0, e1)
    x = -(a_corner + e1 * b_corner) / norm  # origin's foot minus corner, along the wall direction (1, e1)/norm
    return np.array([x, -e0 / norm, -math.atan(e1)])


def _points(angles: NDArray[np.float64], ranges: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 2) laser-frame points (a, b) of the finite returns."""
    ok = np.isfinite(ranges)
    return np.column_stack([ranges[ok] * np.cos(angles[ok]), ranges[ok] * np.sin(angles[ok])])


@dataclass(frozen=True)
class _Lines:
    """A scan's reference surface b = e0 + e1 (a − am) and left side wall a = c0 + c1 (b − bm) (laser frame),
    with their fits' (2, 2) covariances and inlier masks over the scan's points."""

    e: NDArray[np.float64]
    am: float
    cov_e: NDArray[np.float64]
    c: NDArray[np.float64]
    bm: float
    cov_c: NDArray[np.float64]
    wall_in: NDArray[np.bool_]
    side_in: NDArray[np.bool_]


def _reference_and_left(p: NDArray[np.float64], rng: np.random.Generator, what: str) -> _Lines:
    """The reference surface behind the laser (b < 0) and the left side wall in front of it (a < 0)."""
    behind = p[:, 1] < 0  # the scanned wall lies behind the laser (b < 0)
    wall_in = np.zeros(len(p), bool)
    wall_in[behind] = _ransac_line(p[behind], np.array([1.0, 0.0]), rng)
    e0, e1, am, cov_e = _fit_line(p, wall_in, swap=False, what=what)
    left = (p[:, 0] < 0) & ~wall_in & (p[:, 1] > e0 + e1 * (p[:, 0] - am) + LINE_INLIER_M)
    side_in = np.zeros(len(p), bool)
    side_in[left] = _ransac_line(p[left], np.array([0.0, 1.0]), rng)
    c0, c1, bm, cov_c = _fit_line(p, side_in, swap=True, what="left side wall")
    return _Lines(np.array([e0, e1]), am, cov_e, np.array([c0, c1]), bm, cov_c, wall_in, side_in)


def _propagate(f: Callable[[NDArray[np.float64]], NDArray[np.float64]], params: NDArray[np.float64],
               cov: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """f(params) and its 1σ by central differences, cov the (k, k) covariance of params."""
    value = f(params)
    J = np.empty((len(value), len(params)))
    for k in range(len(params)):
        h = 1e-6 * max(1.0, abs(params[k]))
        dq = np.zeros(len(params))
        dq[k] = h
        J[:, k] = (f(params + dq) - f(params - dq)) / (2 * h)
    return value, np.sqrt(np.diag(J @ cov @ J.T))


def measure_fix(angles: NDArray[np.float64], ranges: NDArray[np.float64], side_margin_m: float,
                seed: int = 0, what: str = "scanned wall") -> dict[str, float]:
    """One scan's fix: dict x, dist, angle (m, m, rad) and their 1σ x_sigma, dist_sigma, angle_sigma. x is in
    wall coordinates: the distance along the reference surface from the left side wall minus side_margin_m;
    dist the distance to the reference surface, angle the laser's turn against it. Raises InputError when
    the reference surface (`what`) or the left side wall cannot be found."""
    lines = _reference_and_left(_points(angles, ranges), np.random.default_rng(seed), what)
    params = np.concatenate([lines.e, lines.c])
    cov = np.zeros((4, 4))
    cov[:2, :2], cov[2:, 2:] = lines.cov_e, lines.cov_c
    value, sig = _propagate(lambda q: _fix_from_lines(q[:2], q[2:], lines.am, lines.bm), params, cov)
    return dict(zip(_LINE_KEYS, (value[0] - side_margin_m, sig[0], value[1], sig[1], value[2], sig[2]), strict=True))


def measure_room(angles: NDArray[np.float64], ranges: NDArray[np.float64], seed: int = 0,
                 what: str = "scanned wall") -> dict[str, float]:
    """What one scan sees of the room's size: `width` (m), the distance along the reference surface from the
    left side wall to the right one (their corners with it), and `far` (m), the distance from the reference
    surface to the opposite one (the back wall, or the ceiling), each with its 1σ (`width_sigma`,
    `far_sigma`) from the line fits; NaN where that wall is out of view. Raises InputError as measure_fix."""
    p = _points(angles, ranges)
    rng = np.random.default_rng([seed, 7])
    lines = _reference_and_left(p, rng, what)
    e0, e1 = lines.e
    free = ~lines.wall_in & ~lines.side_in & (p[:, 1] > e0 + e1 * (p[:, 0] - lines.am) + LINE_INLIER_M)
    out = {"width": math.nan, "width_sigma": math.nan, "far": math.nan, "far_sigma": math.nan}
    right = free & (p[:, 0] > 0)
    right_in = np.zeros(len(p), bool)
    right_in[right] = _ransac_line(p[right], np.array([0.0, 1.0]), rng)
    if right_in.sum() >= LINE_MIN_POINTS:
        r0, r1, rm, cov_r = _fit_line(p, right_in, swap=True, what="right side wall")
        params = np.concatenate([lines.e, lines.c, [r0, r1]])
        cov = np.zeros((6, 6))
        cov[:2, :2], cov[2:4, 2:4], cov[4:, 4:] = lines.cov_e, lines.cov_c, cov_r

        def width(q: NDArray[np.float64]) -> NDArray[np.float64]:
            corners = [_corner(q[:2], side, lines.am, bm) for side, bm in ((q[2:4], lines.bm), (q[4:], rm))]
            return np.array([float(np.linalg.norm(corners[1] - corners[0]))])

        value, sig = _propagate(width, params, cov)
        out["width"], out["width_sigma"] = float(value[0]), float(sig[0])
        free &= ~right_in
    far = free & (p[:, 1] > 0)
    far_in = np.zeros(len(p), bool)
    far_in[far] = _ransac_line(p[far], np.array([1.0, 0.0]), rng)
    if far_in.sum() >= LINE_MIN_POINTS:
        f0, f1, fm, cov_f = _fit_line(p, far_in, swap=False, what="opposite wall")
        params = np.concatenate([lines.e, [f0, f1]])
        cov = np.zeros((4, 4))
        cov[:2, :2], cov[2:, 2:] = lines.cov_e, cov_f

        def distance(q: NDArray[np.float64]) -> NDArray[np.float64]:
            # the opposite line's point above the laser, off the reference line (both nearly parallel)
            b_far = q[2] + q[3] * (0.0 - fm)
            b_ref = q[0] + q[1] * (0.0 - lines.am)
            return np.array([(b_far - b_ref) / math.hypot(1.0, q[1])])

        value, sig = _propagate(distance, params, cov)
        out["far"], out["far_sigma"] = float(value[0]), float(sig[0])
    return out


HEADS: tuple[str, ...] = ("H", "V")  # the horizontal laser (fix against the wall), the vertical one (the floor)
Scan = tuple[NDArray[np.float64], NDArray[np.float64]]  # (angles (n,) rad, ranges (n,) m, NaN: no return)


def draw_alignment(rng: np.random.Generator, cfg: LaserConfig) -> tuple[float, float]:
    """How the robot really stands to the wall after aligning: (standoff m, yaw rad)."""
    standoff = cfg.standoff_m + cfg.standoff_sigma_m * float(rng.standard_normal())
    return standoff, cfg.yaw_sigma_rad * float(rng.standard_normal())


def head_scan(head: str, pose: tuple[float, float, float], alignment: tuple[float, float], wall_width_m: float,
              cfg: LaserConfig, rng: np.random.Generator) -> Scan:
    """One turn of laser `head` (HEADS) with the frame at its true pose (x m, y m, φ rad) and the robot aligned
    as `alignment` (standoff m, yaw rad)."""
    x, y, phi = (float(v) for v in pose)
    if head == "H":
        return simulate_scan_2d(x, alignment[0], alignment[1], wall_width_m, cfg.room_depth_m, cfg, rng)
    if head == "V":
        return simulate_scan_2d(x, y + cfg.floor_margin_m, phi, wall_width_m, cfg.room_height_m, cfg, rng)
    raise ValueError(f"no laser head {head!r}: the robot has {', '.join(HEADS)}")


def simulated_head_scan(head: str, pose: tuple[float, float, float], alignment: tuple[float, float],
                        wall_width_m: float, cfg: LaserConfig, seed: int, tag: int) -> Scan:
    """head_scan with the noise of the simulated site's stream for (seed, frame tag, head): the in-process robot
    and the laser simulator (scanner/sim/devices.py) give the same scan."""
    rng = np.random.default_rng([seed, int(tag), 104 + HEADS.index(head)])
    return head_scan(head, pose, alignment, wall_width_m, cfg, rng)


def fix_from_scans(horizontal: Scan, vertical: Scan, cfg: LaserConfig, seed: int = 0) -> dict[str, float]:
    """Both lasers' fix (dict of LASER_KEYS; x is the inverse-variance mean of both lasers' x) from one turn of
    each; seed: their RANSAC's. Raises InputError when a laser cannot see its reference surface or side wall."""
    h = measure_fix(*horizontal, cfg.side_margin_m, 2 * seed, "scanned wall")
    v = measure_fix(*vertical, cfg.side_margin_m, 2 * seed + 1, "floor")
    w = np.array([h["x_sigma"], v["x_sigma"]]) ** -2.0
    return {"laser_x_m": float(w @ [h["x"], v["x"]] / w.sum()), "laser_x_sigma_m": float(w.sum() ** -0.5),
            "laser_y_m": v["dist"] - cfg.floor_margin_m, "laser_y_sigma_m": v["dist_sigma"],
            "laser_phi_rad": v["angle"], "laser_phi_sigma_rad": v["angle_sigma"],
            "laser_dist_m": h["dist"], "laser_dist_sigma_m": h["dist_sigma"],
            "laser_yaw_rad": h["angle"], "laser_yaw_sigma_rad": h["angle_sigma"]}


def pose_from_fix(fix: dict[str, float]) -> tuple[tuple[float, float, float], NDArray[np.float64]]:
    """The frame pose (x m, y m, φ rad) a laser fix gives and its (3, 3) covariance (the coordinates' σ², the
    fix's correlations not kept): the robot's pose where no navigation stack reports one."""
    pose = (fix["laser_x_m"], fix["laser_y_m"], fix["laser_phi_rad"])
    sigma = np.array([fix["laser_x_sigma_m"], fix["laser_y_sigma_m"], fix["laser_phi_sigma_rad"]])
    return pose, np.diag(sigma**2)


def simulate_fix(pose: tuple[float, float, float], wall_width_m: float, rng: np.random.Generator,
                 cfg: LaserConfig | None = None) -> tuple[dict[str, float], tuple[float, float]]:
    """A simulated robot alignment with the frame at its true pose (x m, y m, φ rad), all drawn from one
    generator: the fix of both lasers (fix_from_scans) and the true (standoff m, yaw rad)."""
    cfg = cfg or LaserConfig()
    alignment = draw_alignment(rng, cfg)
    horizontal = head_scan("H", pose, alignment, wall_width_m, cfg, rng)
    vertical = head_scan("V", pose, alignment, wall_width_m, cfg, rng)
    return fix_from_scans(horizontal, vertical, cfg, int(rng.integers(0, 2**30))), alignment


ROOM_KEYS: tuple[str, ...] = ("room_width_m", "room_width_sigma_m", "room_depth_m", "room_depth_sigma_m",
                              "room_height_m", "room_height_sigma_m")


def room_from_scans(horizontal: Scan, vertical: Scan, seed: int = 0) -> dict[str, float] | None:
    """The room's size as one alignment's two laser turns see it (dict of ROOM_KEYS, NaN: out of view): width
    between the side walls (both heads, inverse-variance mean), depth from the scanned wall to the back wall
    (horizontal head), height from the floor to the ceiling (vertical head); seed: their RANSAC's. None when a
    head cannot see its reference surface or the left side wall (the fix then fails too)."""
    try:
        h = measure_room(*horizontal, 2 * seed, "scanned wall")
        v = measure_room(*vertical, 2 * seed + 1, "floor")
    except InputError:
        return None
    widths = [(m["width"], m["width_sigma"]) for m in (h, v) if math.isfinite(m["width"])]
    width, width_sigma = math.nan, math.nan
    if widths:
        w = np.array([s for _, s in widths]) ** -2.0
        width = float(w @ [x for x, _ in widths] / w.sum())
        width_sigma = float(w.sum() ** -0.5)
    return dict(zip(ROOM_KEYS, (width, width_sigma, h["far"], h["far_sigma"], v["far"], v["far_sigma"]),
                    strict=True))
