"""`arproj calibrate projector --live`: the whole live calibration on a LiveStation, in one command.

Order (each result is written to the rig folder before the next starts):
1. stereo (only with --stereo N): N board views from both cameras → camera_left/right, rig.yaml;
2. projector: one camera → the printed board on the wall at --poses poses, the Gray code at each (Moreno &
   Taubin; the camera from the rig if it has camera_left, else calibrated too); two cameras → the Gray code at
   each head angle of the pan/tilt plan (--head-poses), triangulated (the rig's stereo pair);
3. mount (two cameras and --laser): the board on a panel across the laser's plane at --mount-poses poses;
4. head (two cameras): the head model from the projector's poses of step 2, rebased to the robot frame with
   the mount of step 3 (or the rig's T_robot_from_camera_left, the design value); the projector's predicted
   pose at the plan's check angles with its 95 % bounds.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arproj.wizard.live_station import SETTLE_S, BoardMover, LiveStation, PersonMover, UrlMover
from arproj.wizard.live_steps import (
    pan_tilt_plan,
    step_head_live,
    step_mount,
    step_projector_board,
    step_projector_stereo,
    truth_check,
)
from arproj.wizard.steps import Track, step_stereo
from calibration.boards import parse_board
from calibration.capture import SETTLE_TIMEOUT_S
from geometry.errors import InputError
from geometry.rig import RIG_FILE, Rig

MOUNT_POSE = "T_robot_from_camera_left"


@dataclass
class LiveOptions:
    screen: str
    left: str
    projector_size: tuple[int, int]
    rig: Path
    right: str | None = None
    head: str | None = None
    laser: str | None = None
    mover: str | None = None  # a URL (the simulated site's person), else a person at the keyboard
    board: str = ""
    poses: int = 5
    head_poses: int | None = None
    mount_poses: int = 8
    stereo_poses: int = 0
    settle_s: float = SETTLE_S
    settle_timeout_s: float = SETTLE_TIMEOUT_S
    record: Path | None = None  # --record FILE.mcap: every capture as ROS 2 messages (arproj.wizard.live_record)
    view: str | None = None  # --view live | FILE.rrd: captures and coverage in Rerun (arproj.run.view)


def check_before_devices(opts: LiveOptions, two_cameras: bool) -> tuple[Any, Rig]:
    """What the live calibration refuses without opening a device (or starting the simulated site): the board,
    the rig folder, and for two cameras a stereo pair (from the rig, or --stereo N). Returns the board and rig."""
    board = parse_board(opts.board)
    rig = Rig.load(opts.rig) if (opts.rig / RIG_FILE).exists() else Rig()
    if opts.stereo_poses and not two_cameras:
        raise InputError("--stereo calibrates the stereo pair", "give --right CAM too")
    if two_cameras and not opts.stereo_poses and not {"camera_left", "camera_right"} <= set(rig.intrinsics):
        raise InputError(f"{opts.rig / RIG_FILE}: no calibrated stereo pair (camera_left, camera_right)",
                         "run `arproj calibrate stereo … --out RIG` first, or add --stereo N")
    return board, rig


def run_live(opts: LiveOptions, track: Track, design_mount: np.ndarray | None = None,
             truth: dict | None = None) -> dict[str, Any]:
    """Run the live calibration; returns the summary (figures with their 95 % bounds; vs truth if given)."""
    board, rig = check_before_devices(opts, two_cameras=opts.right is not None)
    mover: BoardMover = UrlMover(opts.mover) if opts.mover else PersonMover()
    rig_dir = opts.rig
    if design_mount is not None and MOUNT_POSE not in rig.poses:
        rig.poses[MOUNT_POSE] = np.asarray(design_mount, dtype=np.float64)
    summary: dict[str, Any] = {"rig": str(rig_dir)}
    with ExitStack() as stack:
        station = stack.enter_context(LiveStation.open(opts.screen, opts.projector_size, opts.left, opts.right,
                                                       opts.head, mover, opts.laser, opts.settle_s,
                                                       opts.settle_timeout_s))
        _watch(station, opts, rig_dir, stack, summary)
        _calibrate(station, opts, board, rig, rig_dir, track, summary, truth)
    return summary


def _watch(station: LiveStation, opts: LiveOptions, rig_dir: Path, stack: ExitStack, summary: dict[str, Any]) -> None:
    """--record and --view: told of every capture through the tap the projection session uses, and (the view)
    of every set of board views; the bag gets the rig's intrinsics when the calibration ends, also after an error
    (what it had reached), and is closed then (its metadata.yaml written)."""
    if opts.record is None and opts.view is None:
        return
    from arproj.session.record import Captures

    captures = Captures()
    board_listeners: list[Callable[[list[Any], list[Any]], None]] = []
    if opts.record is not None:
        from arproj.wizard.live_record import CalibrationRecorder
        from mapping.ros.bag import RosBag

        recorder = CalibrationRecorder(stack.enter_context(RosBag(opts.record)))
        stack.callback(lambda: recorder.finish(Rig.load(rig_dir) if (rig_dir / RIG_FILE).exists() else Rig()))
        captures.listeners.append(recorder.captured)
        summary["record"] = str(opts.record)
    if opts.view is not None:
        from arproj.run.view import CalibrationView

        view = CalibrationView(opts.view)
        stack.callback(view.close)
        captures.listeners.append(view.captured)
        board_listeners.append(view.boards)
    captures.watch(station)
    board_views = station.board_views

    def tapped(*args: Any, **kwargs: Any) -> tuple[list[Any], list[Any]]:
        left, right = board_views(*args, **kwargs)
        for listen in board_listeners:
            listen(left, right)
        return left, right

    station.board_views = tapped  # type: ignore[method-assign]


def _calibrate(station: LiveStation, opts: LiveOptions, board: Any, rig: Rig, rig_dir: Path, track: Track,
               summary: dict[str, Any], truth: dict | None) -> None:
    if opts.stereo_poses:  # with a right camera: check_before_devices
        result, stereo_rig = step_stereo(station, rig_dir, opts.board, opts.stereo_poses)
        rig.intrinsics.update(stereo_rig.intrinsics)
        rig.poses.update(stereo_rig.poses)
        rig.quality["stereo"] = stereo_rig.quality["stereo"]
        rig.save(rig_dir)
        summary["stereo"] = result["quality"]
        station.clear_board()  # the projector step needs the wall alone in the beam
    if opts.right is None:
        camera = rig.intrinsics.get("camera_left")
        calib = step_projector_board(station, board, opts.poses, camera, track)
        rig.intrinsics["projector"] = calib.projector
        if camera is None and calib.camera is not None:
            rig.intrinsics["camera_left"] = calib.camera
        rig.quality["projector"] = {"rms_px": round(calib.projector_rms_px, 4),
                                    "poses": len(calib.T_projector_from_view),
                                    "projector_95": calib.quality()["projector_95"],
                                    "method": "live Gray code, one camera and a printed board"}
        rig.save(rig_dir)
        summary["projector"] = calib.quality()
        summary["captures"] = station.captures
        if truth is not None:
            summary["truth"] = truth_check(truth, projector=calib)
        return
    fit_angles, check_angles = pan_tilt_plan(station.aim_deg, opts.head_poses)
    result, rig, calib, samples = step_projector_stereo(station, rig, rig_dir, fit_angles, track)
    summary["projector"] = result["quality"]
    mount = None
    if opts.laser is not None:
        if MOUNT_POSE not in rig.poses:
            raise InputError(f"{rig_dir / RIG_FILE}: no {MOUNT_POSE} to start the mount from",
                             f"add the design value of the cameras' mount as poses: {MOUNT_POSE} (4x4)")
        mount_result, mount = step_mount(station, rig, rig_dir, board, opts.mount_poses, rig.poses[MOUNT_POSE])
        summary["mount"] = mount_result["quality"]
    if MOUNT_POSE not in rig.poses:
        raise InputError(f"{rig_dir / RIG_FILE}: no {MOUNT_POSE} to put the head model in the robot frame",
                         "give --laser URL to calibrate it, or add its design value to rig.yaml's poses")
    head = step_head_live(rig, rig_dir, result["measurements"], rig.poses[MOUNT_POSE], check_angles, samples)
    summary["head"] = head["quality"]
    summary["captures"] = station.captures
    if truth is not None:
        summary["truth"] = truth_check(truth, projector=calib, rig=Rig.load(rig_dir), head=head, mount=mount,
                                       cameras_95=summary.get("stereo", {}).get("cameras_95"))
