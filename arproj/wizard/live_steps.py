"""Live calibration's steps on a LiveStation: the Gray code shown on the beamer and captured, the projector
calibrated from it (one camera and a printed board, or the stereo pair and triangulated wall points), the head
fitted from the projector's pose at the head plan's angles, the cameras' mount from the laser and a board.

Every recovered quantity carries a 95 % bound. The projector's fx, fy, cx, cy (1.96 σ): σ from a jackknife over
the head poses (allowing for its few degrees of freedom) plus the stereo pair's covariance carried through
triangulation by refitting to points triangulated by draws of the pair; the fit's own covariance takes the
triangulated points as exact and independent and is several times too small. The projector's predicted pose at
head angles not used for fitting (ellipsoid bounds): the head fit's covariance plus the same samples, each
refitted. The mount: calibration/laser_mount.py. `truth_check` compares them with
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
from calibration.head import fit_head, head_plan
from calibration.laser_mount import (
    CHI2_3_95,
    MountFit,
    board_plane_view,
    bounds_95,
    calibrate_mount,
    camera_draws_covariance,
    design_covariance,
    mount_errors,
    share_of_bound,
)
from calibration.projector import (
    BoardCaptures,
    ProjectorCalibration,
    ProjectorSamples,
    calibrate_inverse_camera,
    calibrate_projector_with_board,
    decode_gray_code,
    gray_code_patterns,
    on_wall_plane,
    projector_samples,
    projector_size_warning,
    stereo_correspondences,
    wall_inliers,
)
from calibration.stereo import sample_stereo
from geometry.errors import InputError
from geometry.head import HeadModel
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, rotation_vector
from geometry.rig import Rig
from geometry.triangulation import triangulate

PAN_TILT_PLAN_DEG = (15.0, 10.0)  # pan and tilt excursions about the aim: the projected image stays in view
WALL_POINT_STEP_PX = 16  # projector-pixel grid of triangulated wall points per head pose
ROLL = 2  # the joint a Pelco-D pan/tilt head does not have
OFF_WALL_WARN_SHARE = 0.05
STEREO_DRAWS = 24  # draws of the stereo pair from its covariance, each re-triangulated and the projector refitted
STEREO_DRAW_SEED = 18


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
                          track: Track) -> tuple[dict, Rig, ProjectorCalibration, ProjectorSamples]:
    """The Gray code at each head angle, decoded in both cameras and triangulated → the projector as an inverse
    camera, and its pose at every angle (the head step's measurements)."""
    left, right = rig.intrinsics["camera_left"], rig.intrinsics["camera_right"]
    T_rl = rig.pose("T_camera_right_from_camera_left")
    size = station.projector_size
    points, pixels, camera_pixels, used, skipped, warnings = [], [], [], [], [], []
    off_wall: list[int] = []
    for k, a in enumerate(angles):
        station.command_head(a)
        caps_l, caps_r = gray_code_captures(station, track, f"head pose {k + 1}/{len(angles)}: Gray code")
        if k == 0 and (warning := projector_size_warning(caps_l, size)) is not None:
            warnings.append(warning)
        cl, cr, px = stereo_correspondences(decode_gray_code(caps_l, size), decode_gray_code(caps_r, size), size,
                                            step_px=WALL_POINT_STEP_PX)
        if len(px) == 0:
            skipped.append([float(v) for v in a])
            continue
        X = triangulate(left, right, T_rl, cl, cr)
        wall = wall_inliers(X)  # what stands in the beam before the wall is no wall point
        off_wall.append(int(np.count_nonzero(~wall)))
        points.append(on_wall_plane(left, right, T_rl, cl[wall], cr[wall]))
        pixels.append(px[wall])
        camera_pixels.append((cl[wall], cr[wall]))
        used.append(a)
    try:
        calib = calibrate_inverse_camera(points, pixels, size, sources=[f"head {a.tolist()}" for a in used])
    except InputError as err:
        where = f" (too few wall points at head angles {skipped})" if skipped else ""
        raise InputError(f"projector: {err.message}{where}", err.hint) from None
    if sum(off_wall) > OFF_WALL_WARN_SHARE * sum(len(px) for px in pixels):
        warnings.append(f"{sum(off_wall)} of {sum(off_wall) + sum(len(px) for px in pixels)} projected points "
                        "were not on the wall (something stood in the beam) and were left out")
    calib.warnings.extend(warnings)
    samples = _projector_uncertainty(calib, rig, points, pixels, camera_pixels, size, track)
    rig.intrinsics["projector"] = calib.projector
    rig.quality["projector"] = {"rms_px": round(calib.projector_rms_px, 4), "poses": len(used),
                                "projector_95": calib.quality()["projector_95"], "method": "live Gray code, stereo"}
    rig.save(out)
    measurements = [{"angles_deg": [float(v) for v in a], "T_camera_left_from_projector": invert(T).tolist()}
                    for a, T in zip(used, calib.T_projector_from_view, strict=True)]
    return ({"quality": calib.quality() | {"head_angles_skipped": skipped}, "measurements": measurements},
            rig, calib, samples)


def _projector_uncertainty(calib: ProjectorCalibration, rig: Rig, points: list[NDArray[np.float64]],
                           pixels: list[NDArray[np.float64]],
                           camera_pixels: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
                           size: tuple[int, int], track: Track) -> ProjectorSamples:
    """The projector's σ from the jackknife over head poses and from the stereo pair's covariance carried
    through triangulation (the fit's own covariance takes the triangulated points as exact and their errors
    as independent: it is far too small); the samples also carry both to the head."""
    draws = stereo_draws(rig)
    if not draws:
        calib.warnings.append("the rig has no stereo covariance (calibrated before it was kept): the projector's "
                              "and the head's bounds leave the stereo pair's uncertainty out")
    samples = projector_samples(points, pixels, size, camera_pixels,
                                list(track(draws, "projector: carrying the stereo uncertainty", len(draws))))
    cov = samples.covariance(lambda p, poses: np.array([p.fx, p.fy, p.cx, p.cy]))
    calib.projector_sigma = {k: float(np.sqrt(cov[i, i])) for i, k in enumerate(("fx", "fy", "cx", "cy"))}
    return samples


def stereo_draws(rig: Rig) -> list[tuple[Intrinsics, Intrinsics, NDArray[np.float64]]]:
    """STEREO_DRAWS draws of the stereo pair (left, right, T_right_from_left) from its calibration's covariance;
    none when the rig has no covariance."""
    stereo = rig.quality.get("stereo", {})
    if "parameter_covariance" not in stereo:
        return []
    return sample_stereo(rig.intrinsics["camera_left"], rig.intrinsics["camera_right"],
                         rig.pose("T_camera_right_from_camera_left"), stereo["parameter_covariance"],
                         stereo.get("distortion_model", "k1k2p1p2k3"), np.random.default_rng(STEREO_DRAW_SEED),
                         STEREO_DRAWS)


def step_projector_board(station: LiveStation, board: Board, n_poses: int, camera: Intrinsics | None,
                         track: Track) -> ProjectorCalibration:
    """One camera: the printed board on the wall in the beam at n poses, the Gray code at each (Moreno-Taubin)."""
    captures = []
    for k in range(n_poses):
        station.before_change()
        station.mover.place("wall", f"board pose {k + 1}/{n_poses}: put the printed board on the wall in the "
                            "projector's beam, turned or tilted by 15-30° differently from before")
        images = gray_code_captures(station, track, f"board pose {k + 1}/{n_poses}: Gray code")[0]
        captures.append(BoardCaptures(images, f"live board pose {k:02d}"))
    return calibrate_projector_with_board(board, captures, station.projector_size, camera, track=track)


def step_head_live(rig: Rig, out: Path, measurements: list[dict], T_robot_from_camera_left: NDArray[np.float64],
                   check_angles: list[NDArray[np.float64]], samples: ProjectorSamples | None = None) -> dict:
    """The head model (roll fixed: a pan/tilt head) and the projector's predicted pose at the check angles with
    its 95 % bounds (largest semi-axes of the rotation's and the position's ellipsoids).

    The head fit's covariance sees only how the measured poses scatter about the model; errors all poses share
    (the projector's intrinsics, the stereo pair) move them together and are carried by refitting the head to
    the projector fit's samples."""
    result, rig, fit = step_head(rig, out, measurements, T_robot_from_camera_left, fixed_joints=(ROLL,))
    angles = [m["angles_deg"] for m in measurements]
    nominal = [fit.model.T_robot_from_projector(a) for a in check_angles]

    def predicted(projector: Intrinsics, poses: list[NDArray[np.float64]]) -> NDArray[np.float64]:
        del projector
        model = fit_head(angles, [invert(T) for T in poses], fixed_joints=(ROLL,)).model
        out = []
        for a, T0 in zip(check_angles, nominal, strict=True):
            T = model.T_robot_from_projector(a)
            out.append(np.concatenate([rotation_vector(T[:3, :3] @ T0[:3, :3].T), T[:3, 3]]))
        return np.concatenate(out)

    # each check angle's rotation and position are judged as 3-vectors (χ²₃ ellipsoids)
    shared = samples.covariance(predicted, dims=3) if samples is not None else \
        np.zeros((6 * len(check_angles),) * 2)
    per_angle = []
    for k, a in enumerate(check_angles):
        cov_rot, cov_pos = fit.pose_covariance(a)
        block = shared[6 * k:6 * k + 6, 6 * k:6 * k + 6]
        cov_rot, cov_pos = cov_rot + block[:3, :3], cov_pos + block[3:, 3:]
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
    views, board_views, scans, missed = [], [], [], []
    for k in range(n_poses):
        station.before_change()
        station.mover.place("mount", f"mount pose {k + 1}/{n_poses}: stand the panel with the board on the floor "
                            "1.3-1.8 m in front of the robot, across the laser's plane, leaning back 0-25° and "
                            "turned up to ±25°")
        view = detect(board, station.capture(station.black)[0], source=f"live mount pose {k:02d}")
        scan = station.laser_points()
        if view is None:
            missed.append(k)
            continue
        views.append(board_plane_view(view, camera))
        board_views.append(view)
        scans.append(scan)
    fit = calibrate_mount(views, scans, T_robot_from_camera_left_design)
    draws = stereo_draws(rig)  # the camera's calibration error moves every board plane alike: carried too
    fit.covariance = fit.covariance + camera_draws_covariance(board_views, scans, T_robot_from_camera_left_design,
                                                              fit, [left for left, _, _ in draws])
    bounds = fit.bounds_95()
    design = {k: round(v, 4) for k, v in bounds_95(design_covariance(T_robot_from_camera_left_design)).items()}
    adopted = all(bounds[k] <= design[k] for k in bounds)  # the fit starts from the design: only if it gained
    if adopted:
        rig.poses["T_robot_from_camera_left"] = fit.T_robot_from_camera_left
    note = {"adopted": adopted, "design_tolerance_95": design, "poses_without_board": missed}
    rig.quality["mount"] = {k: v for k, v in fit.quality().items() if k != "covariance"} | note | {
        "method": "laser and board (Zhang & Pless), the design value as prior"}
    rig.save(out)
    return {"quality": fit.quality() | note}, fit


# -- against the simulated site's truth ------------------------------------------------------------------------

def _truth_intrinsics(d: dict) -> Intrinsics:
    return Intrinsics(d["fx"], d["fy"], d["cx"], d["cy"], d["width"], d["height"], tuple(d["dist"]))


def _check(error: float, bound: float, unit: str, share: float, **extra: float) -> dict[str, Any]:
    """One truth check: |error|, its reported 95 % bound, and the error in units of that bound (`share`: |e| / bound
    for a scalar, the Mahalanobis distance over √χ²₃,₀.₉₅ for a vector; within when ≤ 1)."""
    return {"error": error, "bound": bound, "unit": unit, "share_of_bound": share, "within": share <= 1.0} | extra


def _scalar_check(error: float, bound: float) -> dict[str, Any]:
    """One intrinsic in pixels against its 95 % bound (|e| / bound; no bound: never within)."""
    return _check(error, bound, "px", abs(error) / bound if bound > 0 else np.inf)


def truth_check(truth: dict, projector: ProjectorCalibration | None = None, rig: Rig | None = None,
                head: dict | None = None, mount: MountFit | None = None,
                cameras_95: dict[str, dict[str, float]] | None = None) -> dict[str, dict[str, Any]]:
    """Each recovered quantity: its error against the truth, its 95 % bound and whether the error is within.

    Scalars (projector fx, fy, cx, cy, px; with the stereo step's cameras_95 and the rig, each camera's fx, fy,
    cx, cy, px): |error| ≤ 1.96 σ. Vectors (the projector's orientation and position at
    each check angle, the mount's rotation and offset): the error inside the 95 % ellipsoid (χ²₃); the bound given
    is the ellipsoid's largest semi-axis. The design mount's error is reported beside the calibrated one.
    """
    out: dict[str, dict[str, Any]] = {}
    if projector is not None and projector.projector_sigma is not None:
        true = _truth_intrinsics(truth["projector"])
        for k in ("fx", "fy", "cx", "cy"):
            out[f"projector {k}"] = _scalar_check(float(getattr(projector.projector, k) - getattr(true, k)),
                                                  1.96 * projector.projector_sigma[k])
    if rig is not None and cameras_95:
        for name, bounds in cameras_95.items():
            true = _truth_intrinsics(truth[name])
            for k, bound in bounds.items():
                out[f"{name.replace('_', ' ')} {k}"] = _scalar_check(
                    float(getattr(rig.intrinsics[name], k) - getattr(true, k)), bound)
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
            out[f"head check {k + 1} orientation"] = _check(
                float(np.degrees(np.linalg.norm(e_rot))), p["rotation_95_deg"], "°",
                share_of_bound(e_rot, np.asarray(p["covariance_rotation"])))
            out[f"head check {k + 1} position"] = _check(
                float(1000 * np.linalg.norm(e_pos)), p["position_95_mm"], "mm",
                share_of_bound(e_pos, np.asarray(p["covariance_position"])))
    if mount is not None:
        T_true = np.asarray(truth["T_robot_from_camera_left"])
        e_rot, e_pos = mount_errors(mount.T_robot_from_camera_left, T_true)
        d_rot, d_pos = mount_errors(np.asarray(truth["T_robot_from_camera_left_design"]), T_true)
        bounds = mount.bounds_95()
        out["mount rotation"] = _check(float(np.degrees(np.linalg.norm(e_rot))), bounds["rotation_deg"], "°",
                                       share_of_bound(e_rot, mount.covariance[:3, :3]),
                                       design_error=float(np.degrees(np.linalg.norm(d_rot))))
        out["mount position"] = _check(float(1000 * np.linalg.norm(e_pos)), bounds["position_mm"], "mm",
                                       share_of_bound(e_pos, mount.covariance[3:, 3:]),
                                       design_error=float(1000 * np.linalg.norm(d_pos)))
    return out
