"""Live calibration's steps on a LiveStation: the Gray code shown on the beamer and captured, the projector
calibrated from it (one camera and a printed board, or the stereo pair and triangulated wall points), the head
fitted from the projector's pose at the head plan's angles, the cameras' mount from the laser and a board.

Every recovered quantity carries a 95 % bound from its fit's covariance: the projector's fx, fy, cx, cy
(1.96 σ), the projector's predicted pose at head angles not used for fitting (the head model's covariance
carried to it; ellipsoid bounds) and the mount (calibration/laser_mount.py). `truth_check` compares them with
the simulated site's truth (arproj.sim.live's truth.json).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from arproj.wizard.live_station import LiveStation
from arproj.wizard.steps import Track, step_head
from calibration.boards import Board, detect
from calibration.head import head_plan
from calibration.laser_mount import (
    CHI2_3_95,
    MountFit,
    board_plane_view,
    calibrate_mount,
    mount_errors,
    within_bound,
)
from calibration.projector import (
    BoardCaptures,
    ProjectorCalibration,
    calibrate_inverse_camera,
    calibrate_projector_with_board,
    decode_gray_code,
    gray_code_patterns,
    projector_size_warning,
    wall_points_from_stereo,
)
from geometry.errors import InputError
from geometry.head import HeadModel
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, rotation_vector
from geometry.rig import Rig

PAN_TILT_PLAN_DEG = (15.0, 10.0)  # pan and tilt excursions about the aim: the projected image stays in view
WALL_POINT_STEP_PX = 16  # projector-pixel grid of triangulated wall points per head pose
ROLL = 2  # the joint a Pelco-D pan/tilt head does not have
# A mount is drawn and built to about this (95 %): a calibrated mount less certain than that is not adopted.
MOUNT_DESIGN_TOLERANCE = {"rotation_deg": 1.0, "position_mm": 10.0}


def pan_tilt_plan(aim_deg: NDArray[np.float64], n_fit: int | None = None
                  ) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]]]:
    """(fit, check) absolute angles for a pan/tilt head: the head plan without roll, about the aim (roll 0)."""
    fit, check = head_plan(*PAN_TILT_PLAN_DEG, 0.0)
    unique: list[NDArray[np.float64]] = []
    for a in fit:
        if not any(np.allclose(a, b) for b in unique):
            unique.append(a)
    aim = np.array([aim_deg[0], aim_deg[1], 0.0])
    return [aim + a for a in unique[:n_fit]], [aim + a for a in check]


def gray_code_captures(station: LiveStation, track: Track, what: str) -> list[list[NDArray[np.uint8]]]:
    """Show every Gray-code pattern (and its inverse, then white and black); the captures per camera."""
    patterns = gray_code_patterns(*station.projector_size)
    per_camera: list[list[NDArray[np.uint8]]] = [[] for _ in station.cameras]
    for pattern in track(patterns, what, len(patterns)):
        for images, frame in zip(per_camera, station.capture(pattern), strict=True):
            images.append(frame)
    return per_camera


def step_projector_stereo(station: LiveStation, rig: Rig, out: Path, angles: list[NDArray[np.float64]],
                          track: Track) -> tuple[dict, Rig, ProjectorCalibration]:
    """The Gray code at each head angle, decoded in both cameras and triangulated → the projector as an inverse
    camera, and its pose at every angle (the head step's measurements)."""
    left, right = rig.intrinsics["camera_left"], rig.intrinsics["camera_right"]
    T_rl = rig.pose("T_camera_right_from_camera_left")
    size = station.projector_size
    points, pixels, used, skipped, warnings = [], [], [], [], []
    for k, a in enumerate(angles):
        station.command_head(a)
        caps_l, caps_r = gray_code_captures(station, track, f"head pose {k + 1}/{len(angles)}: Gray code")
        if k == 0 and (warning := projector_size_warning(caps_l, size)) is not None:
            warnings.append(warning)
        X, px = wall_points_from_stereo(decode_gray_code(caps_l, size), decode_gray_code(caps_r, size), left,
                                        right, T_rl, size, step_px=WALL_POINT_STEP_PX)
        if len(X) == 0:
            skipped.append([float(v) for v in a])
            continue
        points.append(X)
        pixels.append(px)
        used.append(a)
    try:
        calib = calibrate_inverse_camera(points, pixels, size, sources=[f"head {a.tolist()}" for a in used])
    except InputError as err:
        raise InputError(f"projector: {err.message} (too few wall points at head angles {skipped})", err.hint
                         ) from None
    calib.warnings.extend(warnings)
    rig.intrinsics["projector"] = calib.projector
    rig.quality["projector"] = {"rms_px": round(calib.projector_rms_px, 4), "poses": len(used),
                                "projector_95": calib.quality()["projector_95"], "method": "live Gray code, stereo"}
    rig.save(out)
    measurements = [{"angles_deg": [float(v) for v in a], "T_camera_left_from_projector": invert(T).tolist()}
                    for a, T in zip(used, calib.T_projector_from_view, strict=True)]
    return ({"quality": calib.quality() | {"head_angles_skipped": skipped}, "measurements": measurements},
            rig, calib)


def step_projector_board(station: LiveStation, board: Board, n_poses: int, camera: Intrinsics | None,
                         track: Track) -> ProjectorCalibration:
    """One camera: the printed board on the wall in the beam at n poses, the Gray code at each (Moreno-Taubin)."""
    captures = []
    for k in range(n_poses):
        station.mover.place("wall", f"board pose {k + 1}/{n_poses}: put the printed board on the wall in the "
                            "projector's beam, turned or tilted by 15-30° differently from before")
        images = gray_code_captures(station, track, f"board pose {k + 1}/{n_poses}: Gray code")[0]
        captures.append(BoardCaptures(images, f"live board pose {k:02d}"))
    return calibrate_projector_with_board(board, captures, station.projector_size, camera, track=track)


def step_head_live(rig: Rig, out: Path, measurements: list[dict], T_robot_from_camera_left: NDArray[np.float64],
                   check_angles: list[NDArray[np.float64]]) -> dict:
    """The head model (roll fixed: a pan/tilt head) and the projector's predicted pose at the check angles with
    its 95 % bounds (largest semi-axes of the rotation's and the position's ellipsoids)."""
    result, rig, fit = step_head(rig, out, measurements, T_robot_from_camera_left, fixed_joints=(ROLL,))
    per_angle = []
    for a in check_angles:
        cov_rot, cov_pos = fit.pose_covariance(a)
        per_angle.append({
            "angles_deg": [float(v) for v in a],
            "rotation_95_deg": float(np.degrees(np.sqrt(CHI2_3_95 * np.linalg.eigvalsh(cov_rot).max()))),
            "position_95_mm": float(1000 * np.sqrt(CHI2_3_95 * np.linalg.eigvalsh(cov_pos).max())),
            "covariance_rotation": cov_rot.tolist(), "covariance_position": cov_pos.tolist()})
    result["quality"]["check_angles"] = per_angle
    rig.quality["head"] = {k: v for k, v in result["quality"].items() if k != "check_angles"} | {
        "check_angles_95": [{k: p[k] for k in ("angles_deg", "rotation_95_deg", "position_95_mm")}
                            for p in per_angle]}
    rig.save(out)
    return result


def step_mount(station: LiveStation, rig: Rig, out: Path, board: Board, n_poses: int,
               T_robot_from_camera_left_design: NDArray[np.float64]) -> tuple[dict, MountFit]:
    """The board at the top of a tall panel on the floor across the laser's plane, n poses → the mount."""
    camera = rig.intrinsics["camera_left"]
    views, scans, missed = [], [], []
    for k in range(n_poses):
        station.mover.place("mount", f"mount pose {k + 1}/{n_poses}: stand the panel with the board on the floor "
                            "1.3-1.8 m in front of the robot, across the laser's plane, leaning back 0-25° and "
                            "turned up to ±25°")
        view = detect(board, station.capture(station.black)[0], source=f"live mount pose {k:02d}")
        scan = station.laser_points()
        if view is None:
            missed.append(k)
            continue
        views.append(board_plane_view(view, camera))
        scans.append(scan)
    fit = calibrate_mount(views, scans, T_robot_from_camera_left_design)
    bounds = fit.bounds_95()
    adopted = all(bounds[k] <= MOUNT_DESIGN_TOLERANCE[k] for k in bounds)
    if adopted:
        rig.poses["T_robot_from_camera_left"] = fit.T_robot_from_camera_left
    note = {"adopted": adopted, "design_tolerance_95": MOUNT_DESIGN_TOLERANCE, "poses_without_board": missed}
    rig.quality["mount"] = {k: v for k, v in fit.quality().items() if k != "covariance"} | note | {
        "method": "laser and board (Zhang & Pless)"}
    rig.save(out)
    return {"quality": fit.quality() | note}, fit


# -- against the simulated site's truth ------------------------------------------------------------------------

def _truth_intrinsics(d: dict) -> Intrinsics:
    return Intrinsics(d["fx"], d["fy"], d["cx"], d["cy"], d["width"], d["height"], tuple(d["dist"]))


def truth_check(truth: dict, projector: ProjectorCalibration | None = None, rig: Rig | None = None,
                head: dict | None = None, mount: MountFit | None = None) -> dict[str, dict[str, Any]]:
    """Each recovered quantity: its error against the truth, its 95 % bound and whether the error is within.

    Scalars (projector fx, fy, cx, cy, px): |error| ≤ 1.96 σ. Vectors (the projector's orientation and position at
    each check angle, the mount's rotation and offset): the error inside the 95 % ellipsoid (χ²₃); the bound given
    is the ellipsoid's largest semi-axis. The design mount's error is reported beside the calibrated one.
    """
    out: dict[str, dict[str, Any]] = {}
    if projector is not None and projector.projector_sigma is not None:
        true = _truth_intrinsics(truth["projector"])
        for k in ("fx", "fy", "cx", "cy"):
            err = float(getattr(projector.projector, k) - getattr(true, k))
            bound = 1.96 * projector.projector_sigma[k]
            out[f"projector {k}"] = {"error": err, "bound": bound, "unit": "px", "within": abs(err) <= bound}
    if rig is not None and head is not None:
        true_head = HeadModel.from_dict(truth["head"])
        offset = np.asarray(truth["head_angle_offset_deg"])
        T_left_from_robot = invert(np.asarray(truth["T_robot_from_camera_left"]))
        T_used = rig.pose("T_robot_from_camera_left")
        for k, p in enumerate(head["quality"]["check_angles"]):
            a = np.asarray(p["angles_deg"])
            true_T = T_left_from_robot @ true_head.T_robot_from_projector(a + offset)
            pred_T = invert(T_used) @ rig.head.T_robot_from_projector(a) if rig.head is not None else None
            assert pred_T is not None
            e_rot = rotation_vector(pred_T[:3, :3] @ true_T[:3, :3].T)
            e_pos = pred_T[:3, 3] - true_T[:3, 3]
            out[f"head check {k + 1} orientation"] = {
                "error": float(np.degrees(np.linalg.norm(e_rot))), "bound": p["rotation_95_deg"], "unit": "°",
                "within": within_bound(e_rot, np.asarray(p["covariance_rotation"]))}
            out[f"head check {k + 1} position"] = {
                "error": float(1000 * np.linalg.norm(e_pos)), "bound": p["position_95_mm"], "unit": "mm",
                "within": within_bound(e_pos, np.asarray(p["covariance_position"]))}
    if mount is not None:
        T_true = np.asarray(truth["T_robot_from_camera_left"])
        e_rot, e_pos = mount_errors(mount.T_robot_from_camera_left, T_true)
        d_rot, d_pos = mount_errors(np.asarray(truth["T_robot_from_camera_left_design"]), T_true)
        bounds = mount.bounds_95()
        out["mount rotation"] = {"error": float(np.degrees(np.linalg.norm(e_rot))), "bound": bounds["rotation_deg"],
                                 "unit": "°", "within": within_bound(e_rot, mount.covariance[:3, :3]),
                                 "design_error": float(np.degrees(np.linalg.norm(d_rot)))}
        out["mount position"] = {"error": float(1000 * np.linalg.norm(e_pos)), "bound": bounds["position_mm"],
                                 "unit": "mm", "within": within_bound(e_pos, mount.covariance[3:, 3:]),
                                 "design_error": float(1000 * np.linalg.norm(d_pos))}
    return out
