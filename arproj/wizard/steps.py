"""The wizard's steps on a calibration station (the simulated site, or real devices with the same methods).

A station offers: board_views(board, n) → (left views, right views); aim_deg (head angles that put the
projected image in the cameras' view); command_head(absolute head angles, as the head itself counts them);
project(image) → (left photo, right photo); projector_size; T_robot_from_camera_left_design.
The head plan's excursions are added to aim_deg, and every measurement records the absolute commanded
angles: the head model maps those, and nothing else, to the projector's pose.
Each step returns a JSON-ready dict (quality figures; for later steps, the measurements they need).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from calibration.boards import Board, BoardView, parse_board
from calibration.bundle import intrinsics_95
from calibration.head import HeadFit, fit_head, head_plan, rebase_head
from calibration.projector import calibrate_inverse_camera
from calibration.stereo import StereoCalibration, calibrate_stereo, coverage_advice, stereo_covariance_doc
from calibration.validation import (
    GridMeasurement,
    ProjectedGrid,
    cast_onto_plane,
    measure_grid,
    projected_charuco,
    validate_grid,
)
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, rotation_angle_deg
from geometry.rig import Rig
from geometry.robust import fit_plane

STEREO_POSES = 24
PROJECTOR_SQUARE_PX = 64  # projected ChArUco board for projector calibration
VALIDATION_SQUARE_PX = 56  # a different grid for validation
HEAD_PLAN_DEG = (15.0, 10.0, 10.0)  # pan, tilt, roll excursions: the projected image stays in view

Track = Callable[[Iterable, str, int], Iterator]


class Station(Protocol):
    projector_size: tuple[int, int]
    aim_deg: NDArray[np.float64]

    def board_views(self, board: Board, n: int) -> tuple[list[BoardView | None], list[BoardView | None]]: ...
    def command_head(self, angles_deg: NDArray[np.float64]) -> None: ...
    def project(self, image: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]: ...


def step_stereo(station: Station, out: Path, board_spec: str, n_poses: int = STEREO_POSES) -> tuple[dict, Rig]:
    """Photograph the board, calibrate the pair, write camera_left.yaml, camera_right.yaml and rig.yaml."""
    board = parse_board(board_spec)
    left, right = station.board_views(board, n_poses)
    calib = calibrate_stereo(left, right, board)
    rig = Rig(intrinsics={"camera_left": calib.left, "camera_right": calib.right},
              poses={"T_camera_right_from_camera_left": calib.T_right_from_left},
              quality={"stereo": calib.quality() | {"parameter_covariance": stereo_covariance_doc(calib)}})
    rig.save(out)
    missing = [v.source if v is not None else f"pose {k:02d}" for k, v in enumerate(left) if v is None]
    result = {"quality": calib.quality() | {"cameras_95": cameras_95(calib)}, "advice": coverage_advice(calib.coverage),
              "views_without_board": missing}
    return result, rig


def cameras_95(calib: StereoCalibration) -> dict[str, dict[str, float]]:
    """Each camera's fx, fy, cx, cy 95 % bound (1.96 σ of the joint refinement), px; empty without it."""
    if calib.bundle is None or not calib.bundle.intrinsics_sigma:
        return {}
    sigmas = zip(("camera_left", "camera_right"), calib.bundle.intrinsics_sigma, strict=True)
    return {name: intrinsics_95(sigma) for name, sigma in sigmas if sigma is not None}


def head_angles(station: Any) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]]]:
    """(fitting, checking) absolute head angles: the head plan's excursions about the station's aim."""
    fit, check = head_plan(*HEAD_PLAN_DEG)
    aim = np.asarray(station.aim_deg, dtype=np.float64)
    return [aim + np.asarray(a) for a in fit], [aim + np.asarray(a) for a in check]


def _stereo_of(rig: Rig) -> tuple[Intrinsics, Intrinsics, NDArray[np.float64]]:
    return (rig.intrinsics["camera_left"], rig.intrinsics["camera_right"],
            rig.pose("T_camera_right_from_camera_left"))


def _measure(station: Station, rig: Rig, grid: ProjectedGrid, angles: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Project grid at head angles; (3-D points in camera_left (n, 3), projector pixels (n, 2)) or None."""
    left, right, T_rl = _stereo_of(rig)
    station.command_head(angles)
    img_l, img_r = station.project(grid.image)
    m = measure_grid(grid, img_l, img_r, left, right, T_rl)
    if m is None:
        return None
    return m.points_left, m.projector_px


def step_projector(station: Station, rig: Rig, out: Path, track: Track) -> tuple[dict, Rig]:
    """Projected chessboard at the head plan's angles → projector intrinsics and its pose at every angle."""
    w, h = station.projector_size
    grid = projected_charuco(w, h, PROJECTOR_SQUARE_PX)
    fit_angles, _ = head_angles(station)
    points, pixels, used, skipped = [], [], [], []
    for angles in track(fit_angles, "projector: projecting the grid", len(fit_angles)):
        m = _measure(station, rig, grid, angles)
        if m is None:
            skipped.append([float(a) for a in angles])
            continue
        points.append(m[0])
        pixels.append(m[1])
        used.append(angles)
    try:
        calib = calibrate_inverse_camera(points, pixels, (w, h), sources=[f"head {a.tolist()}" for a in used])
    except InputError as err:
        raise InputError(f"projector step: {err.message} (grid not seen by both cameras at head angles "
                         f"{skipped})", err.hint) from None
    rig.intrinsics["projector"] = calib.projector
    rig.quality["projector"] = {"rms_px": round(calib.projector_rms_px, 4), "poses": len(used)}
    rig.save(out)
    measurements = [{"angles_deg": [float(v) for v in a], "T_camera_left_from_projector": invert(T).tolist()}
                    for a, T in zip(used, calib.T_projector_from_view, strict=True)]
    return {"quality": calib.quality() | {"head_angles_skipped": skipped}, "measurements": measurements}, rig


def step_head(rig: Rig, out: Path, measurements: list[dict], T_robot_from_camera_left: NDArray[np.float64],
              fixed_joints: tuple[int, ...] = ()) -> tuple[dict, Rig, HeadFit]:
    """Fit the head model to the projector poses measured in the projector step (fixed_joints: joints the head
    does not have, e.g. roll on a pan/tilt head)."""
    angles = [np.asarray(m["angles_deg"]) for m in measurements]
    poses = [np.asarray(m["T_camera_left_from_projector"]) for m in measurements]
    fit = fit_head(angles, poses, fixed_joints=fixed_joints)
    # The model is fitted in camera_left's frame; the rig keeps it in the robot frame.
    rig.head = rebase_head(fit.model, T_robot_from_camera_left)
    rig.poses["T_robot_from_camera_left"] = np.asarray(T_robot_from_camera_left, dtype=np.float64)
    rig.quality["head"] = fit.quality()
    rig.save(out)
    return {"quality": fit.quality()}, rig, fit


def predicted_T_left_from_projector(rig: Rig, angles: NDArray[np.float64]) -> NDArray[np.float64]:
    if rig.head is None:
        raise InputError("the rig has no head model yet", "run the head step first")
    return invert(rig.pose("T_robot_from_camera_left")) @ rig.head.T_robot_from_projector(angles)


def step_validation(station: Station, rig: Rig, out: Path, track: Track) -> dict:
    """Project a different grid at head angles not used for fitting; 3-D error of the prediction, mm."""
    w, h = station.projector_size
    grid = projected_charuco(w, h, VALIDATION_SQUARE_PX)
    _, check_angles = head_angles(station)
    projector = rig.intrinsics["projector"]
    errors, per_angle = [], []
    for angles in track(check_angles, "validation: projecting a known grid", len(check_angles)):
        m = _measure(station, rig, grid, angles)
        if m is None:
            continue
        points, pixels = m
        measurement = GridMeasurement(pixels, points, np.zeros_like(pixels), np.zeros_like(pixels))
        result, predicted = validate_grid(measurement, projector, predicted_T_left_from_projector(rig, angles))
        errors.append(np.linalg.norm(points - predicted, axis=1))
        per_angle.append({"angles_deg": [float(v) for v in angles]} | result.quality())
    if not errors:
        raise InputError("validation: the projected grid was not found by both cameras at any check angle",
                         "check that the projector lights the wall in the cameras' view")
    d = np.concatenate(errors)
    quality = {"rms_mm": round(float(1000 * np.sqrt(np.mean(d ** 2))), 4),
               "max_mm": round(float(1000 * d.max()), 4), "per_angle": per_angle}
    rig.quality["validation"] = {k: quality[k] for k in ("rms_mm", "max_mm")}
    rig.save(out)
    return {"quality": quality}


# --- errors against the simulated site's truth (reports and the benchmark) -----------------------------------

def stereo_truth_errors(rig: Rig, truth: Any) -> dict:
    left, right, T_rl = _stereo_of(rig)
    out = {}
    for name, est, true in (("camera_left", left, truth.camera_left), ("camera_right", right, truth.camera_right)):
        out[name] = {"fx_pct": 100 * (est.fx / true.fx - 1), "fy_pct": 100 * (est.fy / true.fy - 1),
                     "cx_px": est.cx - true.cx, "cy_px": est.cy - true.cy}
    out["baseline_mm"] = 1000 * (np.linalg.norm(T_rl[:3, 3]) - np.linalg.norm(truth.T_right_from_left[:3, 3]))
    out["stereo_rotation_deg"] = rotation_angle_deg(T_rl, truth.T_right_from_left)
    return out


def projector_truth_errors(rig: Rig, truth: Any) -> dict:
    est, true = rig.intrinsics["projector"], truth.projector
    return {"fx_pct": 100 * (est.fx / true.fx - 1), "fy_pct": 100 * (est.fy / true.fy - 1),
            "cx_px": est.cx - true.cx, "cy_px": est.cy - true.cy}


def head_truth_errors(station: Any, rig: Rig) -> dict:
    """Predicted vs true projector pose at the check angles (never used for fitting)."""
    _, check_angles = head_angles(station)
    rot, pos = [], []
    for angles in check_angles:
        true = station.true_T_left_from_projector(angles)
        pred = predicted_T_left_from_projector(rig, angles)
        rot.append(rotation_angle_deg(pred, true))
        pos.append(1000 * float(np.linalg.norm(pred[:3, 3] - true[:3, 3])))
    return {"rotation_max_deg": max(rot), "position_max_mm": max(pos), "rotation_deg": rot, "position_mm": pos}


def validation_truth_errors(station: Any, rig: Rig) -> dict:
    """Predicted landing of a projected grid vs where it truly lands (simulated truth), at the check angles."""
    w, h = station.projector_size
    grid = projected_charuco(w, h, VALIDATION_SQUARE_PX)
    _, check_angles = head_angles(station)
    d = []
    for angles in check_angles:
        station.command_head(angles)
        true = station.true_landing_left(grid.corners_px)
        ok = np.all(np.isfinite(true), axis=1)
        point, normal = fit_plane(true[ok])
        pred = cast_onto_plane(rig.intrinsics["projector"], predicted_T_left_from_projector(rig, angles),
                               grid.corners_px[ok], point, normal)
        d.append(np.linalg.norm(pred - true[ok], axis=1))
    dd = np.concatenate(d)
    return {"rms_mm": float(1000 * np.sqrt(np.mean(dd ** 2))), "max_mm": float(1000 * dd.max()),
            "distance_m": float(np.mean(np.linalg.norm(true[ok], axis=1)))}
