"""The full wall pose: the plane from the cameras fixes 3 degrees of freedom (the normal's direction and the
distance); the robot's localization, the floor it stands on and the 2-D laser scan of the room's walls (the
side walls and room corner fix the position along the wall) fix the rest; where the wall's own edges (room
corners, floor and ceiling lines) are in the cameras' view, their image lines do too (wallpose.edges).

The robot's roll and pitch come from a prior (limits.FLOOR_TILT_SIGMA_DEG: "it stands on a floor about this
level") unless an inclinometer on the robot measured them (TiltMeasurement): then its reading replaces the
prior, and the estimate is as sure of the tilts as the inclinometer is.

All are Gaussian measurements of one unknown, the robot's pose in the room, T_room_from_robot = T0 · exp(δ)
with δ = (rotation vector, translation) in the robot frame around the localized pose T0; a few Gauss–Newton
steps give δ and its covariance. T_wall_from_robot = inv(T_room_from_wall) · T_room_from_robot, so the same δ
and covariance describe it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import (
    invert,
    make_pose,
    pose_from_vector,
    roll_pitch,
    rotation_about,
    tilt_rotation,
    transform_points,
)
from wallpose import limits
from wallpose.edges import CameraImage, EdgeObservation, Projector, find_wall_edges, project_undistorted
from wallpose.estimate import PlaneEstimate
from wallpose.evidence import EvidenceCode, NotEnoughEvidenceError

POSE_ITERATIONS = 6
LASER_GATES_M = (0.4, 0.15, limits.LASER_GATE_M)  # association gates, coarse to fine (localization can be off)
CHI2_3_9999 = 21.1                                # the plane contradicts the map and localization beyond this


@dataclass
class WallPose:
    """T_wall_from_robot and T_wall_from_projector (head at its current angles) with covariances (6, 6) of
    δ = (rotation vector rad, translation m) in the robot (projector) frame: T_true ≈ T · exp(δ).

    sigma_along_m / sigma_height_m / sigma_distance_m / sigma_normal_deg / sigma_roll_deg: 1-σ of the robot's
    position along the wall, height, distance from it, its heading relative to the normal and rotation about
    the normal, from the covariance; sources: which measurements were used; edges: the wall edges seen by the
    cameras that were fused, edges_rejected: those found but not where the other measurements put them."""

    T_wall_from_robot: NDArray[np.float64]
    covariance: NDArray[np.float64]
    T_wall_from_projector: NDArray[np.float64]
    projector_covariance: NDArray[np.float64]
    T_room_from_robot: NDArray[np.float64]
    sigma_along_m: float
    sigma_height_m: float
    sigma_distance_m: float
    sigma_normal_deg: float
    sigma_roll_deg: float
    sources: list[str] = field(default_factory=list)
    edges: list[EdgeObservation] = field(default_factory=list)
    edges_rejected: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class TiltMeasurement:
    """The robot's roll (about its x, forward) and pitch (about its y, left) against gravity with their 1-σ,
    degrees, as an inclinometer on its body reads them (geometry.poses.roll_pitch names the angles)."""

    roll_deg: float
    pitch_deg: float
    sigma_roll_deg: float
    sigma_pitch_deg: float

    def __post_init__(self) -> None:
        values = (self.roll_deg, self.pitch_deg, self.sigma_roll_deg, self.sigma_pitch_deg)
        if not all(np.isfinite(values)) or not (self.sigma_roll_deg > 0 and self.sigma_pitch_deg > 0):
            raise InputError(f"a tilt measurement needs finite angles and positive σ, got {values}")


@dataclass
class RoomMap:
    """The room's walls (room frame): T_room_from_wall 4x4 each and their (width, height) in metres."""

    T_room_from_walls: list[NDArray[np.float64]]
    sizes_m: list[tuple[float, float]]

    @classmethod
    def from_floor_polygon(cls, corners_m: NDArray[np.float64], height_m: float) -> RoomMap:
        """The walls of a room with this floor polygon (k, 2) (room frame, clockwise seen from above) and height."""
        frames = wall_frames(corners_m)
        return cls([T for T, _ in frames], [(width, float(height_m)) for _, width in frames])


def wall_frames(corners_m: NDArray[np.float64]) -> list[tuple[NDArray[np.float64], float]]:
    """(T_room_from_wall, width m) of each wall of a floor polygon (k, 2) in clockwise order seen from above
    (room frame: z up, floor z = 0): wall i runs from corner i to corner i + 1, its frame's origin at corner i on
    the floor, x along the wall, y up, z into the room."""
    corners = np.asarray(corners_m, dtype=np.float64).reshape(-1, 2)
    out = []
    for i in range(len(corners)):
        d = corners[(i + 1) % len(corners)] - corners[i]
        width = float(np.linalg.norm(d))
        x = np.array([d[0], d[1], 0.0]) / width
        z = np.array([d[1], -d[0], 0.0]) / width  # into the room for a clockwise polygon
        out.append((make_pose(np.column_stack([x, [0.0, 0.0, 1.0], z]), [corners[i, 0], corners[i, 1], 0.0]), width))
    return out


def _plane_whitener(plane: PlaneEstimate) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Basis (3, 4) mapping a (normal, distance) difference to 3 independent numbers, and their whitener."""
    n = plane.normal
    e1 = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    basis = np.zeros((3, 4))
    basis[0, :3], basis[1, :3], basis[2, 3] = e1, e2, 1.0
    cov = basis @ plane.covariance @ basis.T + np.eye(3) * 1e-16
    return basis, np.linalg.inv(np.linalg.cholesky(cov))


def estimate_wall_pose(plane: PlaneEstimate, wall: int, room: RoomMap, localized_T_room_from_robot: NDArray,
                       T_robot_from_projector: NDArray, laser_points_robot: NDArray | None = None,
                       localization_sigma_m: float = 0.03, localization_sigma_deg: float = 1.0,
                       projector_covariance: NDArray | None = None, *,
                       camera_images: Sequence[CameraImage] | None = None,
                       projector: Intrinsics | None = None, tilt: TiltMeasurement | None = None) -> WallPose:
    """Fuse the measured plane of wall `wall` with localization, floor and (optionally) a laser scan.

    laser_points_robot: (n, 3) scan returns in the robot frame; T_robot_from_projector: the projector's pose
    (e.g. T_robot_from_camera_left · plane.T_camera_left_from_projector, the measured one);
    projector_covariance: (6, 6) of the projector pose relative to the robot, added to the result's;
    camera_images: the photos (wallpose.edges.camera_images) in which to look for the wall's edges
    (room corners, floor and ceiling lines) around where the other measurements put them; each edge found and
    consistent with them adds its image line as a measurement; projector: its intrinsics, when it was on for the
    photos (the stretches of an edge it lights are not searched); tilt: the robot's roll and pitch measured by an
    inclinometer, which replace the floor's tilt prior (the start pose takes its tilt from it too: a floor
    localization is level) unless the other measurements with the tilts left free contradict it beyond the 99.9 %
    quantile (limits.TILT_CHI2_2_999): then the prior stays and `sources` says why the reading was not used. The
    plane sees the tilt about the wall's horizontal axis, so a crooked or unzeroed inclinometer (or a wall out of
    plumb) is caught there; the rotation about the wall's normal nothing else sees, so it is not checked.
    Raises NotEnoughEvidenceError when the plane contradicts the map (the pattern is on another wall).
    """
    if not 0 <= wall < len(room.T_room_from_walls):
        raise InputError(f"wall index {wall} is not in the room map (walls 0..{len(room.T_room_from_walls) - 1})")
    T0_level = T0 = np.asarray(localized_T_room_from_robot, dtype=np.float64)
    # the tilt rows: the floor prior (tilt_rad None) or a reading, each with its σ (the closures read them)
    tilt_rad: NDArray[np.float64] | None = None
    tilt_sigma = np.radians([limits.FLOOR_TILT_SIGMA_DEG] * 2)
    T_wall_from_room = invert(room.T_room_from_walls[wall])
    basis, whiten = _plane_whitener(plane)
    measured = np.append(plane.normal, plane.distance)
    sources = ["localization", "floor", "wall plane (cameras + projector)"]
    walls_room = [(Tw[:3, 2], Tw[:3, 3], size) for Tw, size in zip(room.T_room_from_walls, room.sizes_m, strict=True)]
    laser = None if laser_points_robot is None or len(laser_points_robot) == 0 \
        else np.asarray(laser_points_robot, dtype=np.float64)
    if laser is not None:
        sources.append(f"laser scan ({len(laser)} returns)")

    edge_block: list[tuple[EdgeObservation, NDArray[np.float64], Intrinsics, NDArray[np.float64]]] = []

    def residuals(delta: NDArray[np.float64], gate: float) -> NDArray[np.float64]:
        T = T0 @ pose_from_vector(delta)
        out = [delta[[3, 4]] / localization_sigma_m, delta[[2]] / np.radians(localization_sigma_deg),
               [T[2, 3] / limits.FLOOR_HEIGHT_SIGMA_M]]
        if tilt_rad is None:  # the floor prior: the robot's up axis near the room's
            out.append(T[:2, 2] / tilt_sigma)
        else:
            out.append((np.array(roll_pitch(T)) - tilt_rad) / tilt_sigma)
        T_robot_from_wall = invert(T_wall_from_room @ T)
        n = T_robot_from_wall[:3, 2]
        predicted = np.append(n, -n @ T_robot_from_wall[:3, 3])
        out.append(whiten @ (basis @ (predicted - measured)))
        if laser is not None:
            p = laser @ T[:3, :3].T + T[:3, 3]
            best = np.full(len(p), np.inf)
            for normal, origin, (width, _) in walls_room:
                dist = (p - origin) @ normal
                along = (p - origin) @ np.cross([0.0, 0.0, 1.0], normal)
                # only returns beside the wall's extent (a little beyond: corners) belong to it
                inside = (along > -0.1) & (along < width + 0.1)
                dist = np.where(inside, dist, np.inf)
                best = np.where(np.abs(dist) < np.abs(best), dist, best)
            use = np.abs(best) < gate
            out.append(np.where(use, best, 0.0) / limits.LASER_RANGE_SIGMA_M)
        for obs, T_robot_from_camera, intr, whitener in edge_block:
            out.append(whitener @ _edge_offsets(obs, T @ T_robot_from_camera, intr))
        return np.concatenate([np.ravel(o) for o in out])

    def solve(delta: NDArray[np.float64], gates: Sequence[float]) -> tuple[NDArray[np.float64], NDArray]:
        J = np.zeros((0, 6))
        for gate in gates:
            for _ in range(POSE_ITERATIONS):
                r = residuals(delta, gate)
                J = _numeric_jacobian(partial(residuals, gate=gate), delta, r)
                step = np.linalg.solve(J.T @ J, -(J.T @ r))
                delta = delta + step
                if np.linalg.norm(step) < 1e-10:
                    break
        return delta, J

    gates = LASER_GATES_M if laser is not None else (np.inf,)
    if tilt is not None:
        reading = np.radians([tilt.roll_deg, tilt.pitch_deg])
        # the start pose's heading and position, standing as the inclinometer says
        T0 = make_pose(rotation_about([0.0, 0.0, 1.0], float(np.arctan2(T0[1, 0], T0[0, 0])))
                       @ tilt_rotation(*reading), T0[:3, 3])
        # first what the rest says of the tilts, left almost free: the plane sees the tilt about the wall's
        # horizontal axis; a reading it contradicts (a crooked or unzeroed device, a wall out of plumb) is not used
        tilt_sigma = np.radians([limits.TILT_CHECK_PRIOR_DEG] * 2)
        d2 = _tilt_innovation(residuals, solve, gates, T0, reading, np.radians([tilt.sigma_roll_deg,
                                                                                 tilt.sigma_pitch_deg]))
        if d2 <= limits.TILT_CHI2_2_999:
            tilt_rad, tilt_sigma = reading, np.radians([tilt.sigma_roll_deg, tilt.sigma_pitch_deg])
            sources.insert(2, "inclinometer")
        else:
            T0, tilt_sigma = T0_level, np.radians([limits.FLOOR_TILT_SIGMA_DEG] * 2)
            sources.insert(2, f"inclinometer not used: roll {tilt.roll_deg:.3f}°, pitch {tilt.pitch_deg:.3f}° "
                              f"disagree with the wall plane (Mahalanobis² {d2:.0f})")
    _check_innovation(whiten, basis, measured, T0, T_wall_from_room, wall, localization_sigma_m,
                      localization_sigma_deg, float(np.degrees(tilt_sigma.max())))
    delta, J = solve(np.zeros(6), gates)
    covariance = np.linalg.inv(J.T @ J)
    rejected: list[str] = []
    if camera_images:
        cameras = {cam.name: cam for cam in camera_images}
        lit = None if projector is None else Projector(projector, np.asarray(T_robot_from_projector, dtype=float))
        found = find_wall_edges(list(camera_images), room.T_room_from_walls, room.sizes_m, wall,
                                T0 @ pose_from_vector(delta), covariance, projector=lit)
        for obs in found:
            cam = cameras[obs.camera]
            T_rc = np.asarray(cam.T_robot_from_camera, dtype=np.float64)
            if _edge_innovation(obs, T0, delta, covariance, T_rc, cam.intrinsics) > limits.EDGE_CHI2_2_999:
                rejected.append(f"{obs.edge} in {obs.camera}")
                continue
            edge_block.append((obs, T_rc, cam.intrinsics, np.linalg.inv(np.linalg.cholesky(obs.covariance))))
        while edge_block:
            delta_e, J_e = solve(delta, gates[-1:])
            T_e = T0 @ pose_from_vector(delta_e)
            # after fusing: an edge that still disagrees with everything else is dropped (and the rest refitted)
            chi2 = [float(np.sum((W @ _edge_offsets(o, T_e @ T_rc, intr)) ** 2)) for o, T_rc, intr, W in edge_block]
            worst = int(np.argmax(chi2))
            if chi2[worst] <= limits.EDGE_CHI2_2_999:
                delta, J = delta_e, J_e
                covariance = np.linalg.inv(J.T @ J)
                break
            rejected.append(f"{edge_block[worst][0].edge} in {edge_block[worst][0].camera}")
            del edge_block[worst]
        if edge_block:
            sources.append("camera edges (" + ", ".join(f"{o.edge} in {o.camera}" for o, *_ in edge_block) + ")")
    T_room_from_robot = T0 @ pose_from_vector(delta)
    T_wall_from_robot = T_wall_from_room @ T_room_from_robot
    T_robot_from_projector = np.asarray(T_robot_from_projector, dtype=np.float64)
    T_projector_from_robot = invert(T_robot_from_projector)
    adjoint = _adjoint(T_projector_from_robot)
    cov_projector = adjoint @ covariance @ adjoint.T
    if projector_covariance is not None:
        cov_projector = cov_projector + np.asarray(projector_covariance)
    # 1-σ along the wall's axes: rotate the robot-frame translation covariance into the wall frame
    R = T_wall_from_robot[:3, :3]
    cov_t_wall = R @ covariance[3:, 3:] @ R.T
    cov_r_wall = R @ covariance[:3, :3] @ R.T
    return WallPose(
        T_wall_from_robot=T_wall_from_robot, covariance=covariance,
        T_wall_from_projector=T_wall_from_robot @ T_robot_from_projector, projector_covariance=cov_projector,
        T_room_from_robot=T_room_from_robot,
        sigma_along_m=float(np.sqrt(cov_t_wall[0, 0])), sigma_height_m=float(np.sqrt(cov_t_wall[1, 1])),
        sigma_distance_m=float(np.sqrt(cov_t_wall[2, 2])),
        sigma_normal_deg=float(np.degrees(np.sqrt(max(cov_r_wall[0, 0], cov_r_wall[1, 1])))),
        sigma_roll_deg=float(np.degrees(np.sqrt(cov_r_wall[2, 2]))), sources=sources,
        edges=[o for o, *_ in edge_block], edges_rejected=rejected)


def _tilt_innovation(residuals: Callable[..., NDArray[np.float64]],
                     solve: Callable[[NDArray[np.float64], Sequence[float]], tuple[NDArray[np.float64], NDArray]],
                     gates: Sequence[float], T0: NDArray[np.float64], reading_rad: NDArray[np.float64],
                     sigma_rad: NDArray[np.float64]) -> float:
    """Mahalanobis² (2 degrees of freedom) of an inclinometer's (roll, pitch) reading against the pose the other
    measurements give (residuals with the tilt rows weak, around T0)."""
    delta, J = solve(np.zeros(6), gates)
    covariance = np.linalg.inv(J.T @ J)

    def rp(d: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.array(roll_pitch(T0 @ pose_from_vector(d)))

    z = reading_rad - rp(delta)
    G = _numeric_jacobian(rp, delta, rp(delta))
    S = G @ covariance @ G.T + np.diag(np.asarray(sigma_rad) ** 2)
    return float(z @ np.linalg.solve(S, z))


def _numeric_jacobian(f: Callable[[NDArray[np.float64]], NDArray[np.float64]], delta: NDArray[np.float64],
                      f0: NDArray[np.float64], step: float = 1e-7) -> NDArray[np.float64]:
    """(len(f0), 6) forward differences of f around the pose increment delta (f0 = f(delta))."""
    J = np.empty((len(f0), len(delta)))
    for k in range(len(delta)):
        h = np.zeros(len(delta))
        h[k] = step
        J[:, k] = (f(delta + h) - f0) / step
    return J


def _edge_offsets(obs: EdgeObservation, T_room_from_camera: NDArray, intr: Intrinsics) -> NDArray[np.float64]:
    """(2,) px: perpendicular distances of the seen stretch's two ends (3-D, from the map) from the image line
    found, both in undistorted pixels (lens distortion is undone on the detected points instead)."""
    uv = project_undistorted(intr, transform_points(invert(T_room_from_camera), obs.points_room))
    return uv @ obs.line[:2] + obs.line[2]


def _edge_innovation(obs: EdgeObservation, T0: NDArray, delta: NDArray, covariance: NDArray,
                     T_robot_from_camera: NDArray, intr: Intrinsics) -> float:
    """Mahalanobis² of an edge line against where the pose (δ, covariance) without it predicts it."""
    def offsets(d: NDArray[np.float64]) -> NDArray[np.float64]:
        return _edge_offsets(obs, T0 @ pose_from_vector(d) @ T_robot_from_camera, intr)

    z = offsets(delta)
    G = _numeric_jacobian(offsets, delta, z)
    S = obs.covariance + G @ covariance @ G.T
    return float(z @ np.linalg.solve(S, z))


def _predicted_plane(T_room_from_robot: NDArray, T_wall_from_room: NDArray) -> NDArray[np.float64]:
    """(normal, distance) of the wall in the robot frame for a robot pose."""
    T_robot_from_wall = invert(T_wall_from_room @ T_room_from_robot)
    n = T_robot_from_wall[:3, 2]
    return np.append(n, -n @ T_robot_from_wall[:3, 3])


def _check_innovation(whiten: NDArray, basis: NDArray, measured: NDArray, T0: NDArray,
                      T_wall_from_room: NDArray, wall: int, sigma_m: float, sigma_deg: float,
                      tilt_sigma_deg: float = limits.FLOOR_TILT_SIGMA_DEG) -> None:
    """Before fusing: is the measured plane where the map and the localization expect that wall to be? (T0's
    tilt known to tilt_sigma_deg: the floor prior's, or the inclinometer's.)"""
    z0 = basis @ (_predicted_plane(T0, T_wall_from_room) - measured)
    G = np.empty((3, 6))
    for k in range(6):
        h = np.zeros(6)
        h[k] = 1e-7
        G[:, k] = (basis @ (_predicted_plane(T0 @ pose_from_vector(h), T_wall_from_room) - measured) - z0) / 1e-7
    tilt = np.radians(tilt_sigma_deg)
    prior = np.diag([tilt, tilt, np.radians(sigma_deg), sigma_m, sigma_m, limits.FLOOR_HEIGHT_SIGMA_M]) ** 2
    cov_z = np.linalg.inv(whiten.T @ whiten)
    S = cov_z + G @ prior @ G.T
    d2 = float(z0 @ np.linalg.solve(S, z0))
    if d2 > CHI2_3_9999:
        raise NotEnoughEvidenceError(EvidenceCode.NO_WALL_FRAME,
                                     f"the measured plane is not where wall {wall} of the map "
                                     f"should be by the robot's localization (Mahalanobis² {d2:.0f})",
                                     "is the pattern on that wall? check the room map and the localization")


def _adjoint(T: NDArray[np.float64]) -> NDArray[np.float64]:
    """6x6 adjoint of T for (rotation, translation)-ordered right perturbations: exp(Ad·δ) = T exp(δ) T⁻¹."""
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, 3:] = R
    A[3:, :3] = tx @ R
    return A
