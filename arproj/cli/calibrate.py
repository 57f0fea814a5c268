"""`arproj calibrate`: the calibration wizard, and its steps as non-interactive commands.

    arproj calibrate [--sim] [--out DIR] [--restart] [--stop-after STEP]   the wizard, resumable
    arproj calibrate stereo --left 'DIR/left*.jpg' --right 'DIR/right*.jpg' --board chessboard:9x6:0.025 --out RIG
    arproj calibrate camera --images 'DIR/left*.jpg' --board chessboard:9x6:0.025 --out DIR
    arproj calibrate projector --captures 'DIR/capture_*' --projector 1920x1080 --board chessboard:9x7:0.075 --out DIR
    arproj calibrate projector --live --screen N|tcp://… --left CAM [--right CAM --head URL [--laser URL]] --rig DIR
    arproj calibrate projector --live --sim --rig DIR [--stereo N]      the same against the simulated site
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from arproj.console import console, err_console, progress_bar, track, working
from calibration.defaults import DEFAULT_BOARD
from geometry.errors import InputError

if TYPE_CHECKING:
    from arproj.wizard.live_run import LiveOptions
    from calibration.boards import Board

BOARD_HELP = ("Board spec: chessboard:COLSxROWS:SQUARE_M (inner corners) or "
              "charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]; the square size in metres.")
MODEL_HELP = "Distortion model: k1k2, k1k2k3, k1k2p1p2, k1k2p1p2k3."
ACCEPT_POOR_HELP = ("Write the result even when its residuals are far outside what a sound calibration gives "
                    "(by default it is refused and the earlier result kept).")
STEREO_FILES = ("camera_left.yaml", "camera_right.yaml", "rig.yaml", "stereo_coverage.png")  # a stereo rig folder
CAMERA_FILES = ("camera.yaml", "camera_quality.json")
BOARD_CHECK_HINT = ("check --board: COLSxROWS counts inner corners (a board of 10x7 squares is 9x6) and the square "
                    "size is in metres")


def _refuse_poor(problems: list[str], out: Path, accept_poor: bool) -> None:
    """The quality gate: one line naming every figure far out of range; the earlier result stays."""
    if not problems:
        return
    if accept_poor:
        err_console.print(f"[yellow]warning:[/] written although poor (--accept-poor): {'; '.join(problems)}",
                          highlight=False)
        return
    raise InputError(f"calibration refused: {'; '.join(problems)}; {out} is left as it was",
                     f"{BOARD_CHECK_HINT}; --accept-poor writes it anyway")


def _parse_size(text: str, option: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"{option} {text!r} is not WIDTHxHEIGHT", "e.g. 1920x1080") from None
    if w <= 0 or h <= 0:
        raise InputError(f"{option} {text!r}: width and height must be positive")
    return w, h


def stereo_command(left: str, right: str, board_spec: str, out: Path, model: str, as_json: bool,
                   accept_poor: bool = False) -> dict:
    """Run stereo calibration on image files and write the rig folder whole (refused, the earlier rig kept,
    when its residuals or baseline are far out of range); returns the quality figures."""
    from arproj.outputs import OutputFolder
    from calibration.boards import parse_board
    from calibration.image_sets import detect_stereo_set
    from calibration.plots import plot_stereo_coverage
    from calibration.stereo import calibrate_stereo, coverage_advice, stereo_quality_problems
    from geometry.rig import Rig

    folder = OutputFolder(out, STEREO_FILES, "stereo rig folder")
    folder.check()
    board = parse_board(board_spec)
    images = detect_stereo_set(left, right, board, track=lambda it, d, n: track(it, d, total=n))
    _warn_no_board(images.no_board, board)
    with working("calibrating each camera, then the pair (joint refinement)") as step:
        try:
            calib = calibrate_stereo(images.left, images.right, board, model=model)
        except InputError as err:
            raise _too_few_boards(err, images.no_board) from None
        _refuse_poor(stereo_quality_problems(calib), out, accept_poor)
        rig = Rig(intrinsics={"camera_left": calib.left, "camera_right": calib.right},
                  poses={"T_camera_right_from_camera_left": calib.T_right_from_left},
                  quality={"stereo": calib.quality() | {"board": board_spec, "images_without_board":
                                                        images.no_board}})
        step(f"writing {out}")
        with folder as tmp:
            rig.save(tmp)
            plot_stereo_coverage(calib, [lv for lv in images.left if lv is not None],
                                 [rv for rv in images.right if rv is not None], tmp / "stereo_coverage.png")
    figures = calib.quality()
    summary = {
        "out": str(out),
        "reprojection_rms_px": figures["reprojection_rms_px"],
        "epipolar_error_px_per_image": figures["epipolar_error_px_per_image"],
        "baseline_m": figures["baseline_m"],
        "pairs_used": figures["pairs_used"],
        "pairs_rejected": figures["pairs_rejected"],
        "pairs_rejected_why": figures["pairs_rejected_why"],
        "images_without_board": images.no_board,
        "advice": coverage_advice(calib.coverage),
        "camera_left": {"fx": calib.left.fx, "fy": calib.left.fy, "cx": calib.left.cx, "cy": calib.left.cy},
        "camera_right": {"fx": calib.right.fx, "fy": calib.right.fy, "cx": calib.right.cx,
                         "cy": calib.right.cy},
    }
    if as_json:
        print(json.dumps(summary, indent=2))
    else:
        console.print(f"stereo calibration of {figures['pairs_used']} pairs → {out}", highlight=False)
        console.print(f"  reprojection RMS {summary['reprojection_rms_px']:.3f} px, epipolar error "
                      f"{summary['epipolar_error_px_per_image']:.3f} px per image, baseline "
                      f"{1000 * summary['baseline_m']:.2f} mm", highlight=False)
        _print_rejected_and_advice([f"{name}: {calib.rejected_why[name]}" for name in calib.rejected],
                                   summary["advice"])
    return summary


def _print_rejected_and_advice(rejected: list[str], advice: list[str]) -> None:
    for name in rejected:
        console.print(f"  rejected as outlier: {name}", highlight=False)
    for line in advice:
        console.print(f"  next: {line}", highlight=False)


def _warn_no_board(names: list[str], board: Board) -> None:
    for name in names:
        err_console.print(f"[yellow]warning:[/] no {board.cols}x{board.rows} board found in {name} "
                          "(skipped; check the board is fully in view, sharp and the size is right)",
                          highlight=False)


def _too_few_boards(err: InputError, no_board: list[str]) -> InputError:
    """The calibration's refusal for too few views, naming the images without a board and pointing at the board
    option (a spec of another size finds no board at all in them)."""
    if not no_board:
        return err
    hint = f"{err.hint}; " if err.hint else ""
    return InputError(f"{err.message} (no board in: {', '.join(no_board)})",
                      f"{hint}if the board is in view in those images, {BOARD_CHECK_HINT}")


def camera_command(images: str, board_spec: str, out: Path, model: str, as_json: bool,
                   accept_poor: bool = False) -> dict:
    """Calibrate one camera from image files: writes OUT/camera.yaml and OUT/camera_quality.json whole (refused,
    the earlier ones kept, when the residuals are far out of range)."""
    from arproj.outputs import OutputFolder
    from calibration.boards import parse_board
    from calibration.image_sets import detect_image_set
    from calibration.stereo import calibrate_camera, camera_quality_problems, coverage_advice
    from geometry.intrinsics import write_camera_info

    folder = OutputFolder(out, CAMERA_FILES, "camera folder")
    folder.check()
    board = parse_board(board_spec)
    found = detect_image_set(images, board, track=lambda it, d, n: track(it, d, total=n))
    _warn_no_board(found.no_board, board)
    try:
        calib = calibrate_camera([v for v in found.views if v is not None], model=model)
    except InputError as err:
        raise _too_few_boards(err, found.no_board) from None
    _refuse_poor(camera_quality_problems(calib), out, accept_poor)
    figures = calib.quality() | {"board": board_spec, "images_without_board": found.no_board}
    with folder as tmp:
        write_camera_info(tmp / "camera.yaml", calib.intrinsics, camera_name="camera")
        (tmp / "camera_quality.json").write_text(json.dumps(figures, indent=2))
    intr = calib.intrinsics
    summary = figures | {"out": str(out), "advice": coverage_advice(figures["coverage"]),
                         "camera": {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy,
                                    "dist": list(intr.dist)}}
    if as_json:
        print(json.dumps(summary, indent=2))
    else:
        console.print(f"camera calibration of {figures['views_used']} views → {out / 'camera.yaml'}",
                      highlight=False)
        console.print(f"  reprojection RMS {figures['reprojection_rms_px']:.3f} px, fx {intr.fx:.1f} fy "
                      f"{intr.fy:.1f} cx {intr.cx:.1f} cy {intr.cy:.1f}", highlight=False)
        _print_rejected_and_advice([f"{r['view']} ({r['why']})" for r in figures["views_rejected"]],
                                   summary["advice"])
    return summary


def projector_command(captures: str, projector: str, board_spec: str, camera: Path | None, out: Path,
                      as_json: bool) -> dict:
    """Moreno & Taubin projector calibration from Gray-code capture folders; writes projector.yaml."""
    from calibration.boards import parse_board
    from calibration.projector import calibrate_projector_from_folders
    from geometry.intrinsics import read_camera_info, write_camera_info

    board = parse_board(board_spec)
    size = _parse_size(projector, "--projector")
    cam = read_camera_info(camera) if camera is not None else None
    result = calibrate_projector_from_folders(captures, size, board, cam,
                                              track=lambda it, d, n: track(it, d, total=n))
    out.mkdir(parents=True, exist_ok=True)
    write_camera_info(out / "projector.yaml", result.projector, camera_name="projector")
    write_camera_info(out / "camera.yaml", result.camera, camera_name="camera")
    figures = result.quality()
    (out / "projector_quality.json").write_text(json.dumps(figures, indent=2))
    if as_json:
        print(json.dumps(figures, indent=2))
    else:
        console.print(f"projector calibration from {figures['poses_used']} board poses → {out}", highlight=False)
        console.print(f"  projector RMS {figures['projector_rms_px']:.3f} px, camera RMS "
                      f"{figures['camera_rms_px']:.3f} px, fx {result.projector.fx:.1f} fy "
                      f"{result.projector.fy:.1f} cx {result.projector.cx:.1f} cy {result.projector.cy:.1f}",
                      highlight=False)
        for line in figures["warnings"]:
            console.print(f"  [yellow]warning:[/] {line}", highlight=False)
    return figures


def live_projector_command(opts: LiveOptions, size: str, sim: bool = False, small: bool = False, seed: int = 0,
                           as_json: bool = False) -> dict:
    """`calibrate projector --live`: on the devices named in opts, or (sim) on the simulated site started in its
    own process; prints the figures with their 95 % bounds (and, sim, the errors against its truth)."""
    from dataclasses import replace

    from arproj.sim.live import SpawnedLiveSite
    from arproj.wizard.live_run import check_before_devices, run_live

    bar = (lambda items, description, total: track(items, description, total=total))  # noqa: E731
    if not sim:
        if not opts.screen or not opts.left or not size:
            raise InputError("--live needs --screen, --left and --projector (or --sim)")
        summary = run_live(replace(opts, projector_size=_parse_size(size, "--projector")), bar)
    else:
        check_before_devices(opts, two_cameras=True)  # the simulated site has both: refused before it starts
        with working("starting the simulated site (its own process)"):
            site = SpawnedLiveSite(seed=seed, small=small)  # its start: until it serves its URLs
        with site:
            u = site.urls
            truth = site.truth()
            opts = replace(opts, screen=u.screen, left=u.camera_left, right=u.camera_right, head=u.head,
                           laser=u.laser, mover=u.board, projector_size=site.projector_size)
            summary = run_live(opts, bar, design_mount=truth["T_robot_from_camera_left_design"], truth=truth)
    if as_json:
        from geometry.plain import plain  # numpy: not at import, for `arproj --help`

        print(json.dumps(summary, indent=2, default=plain))
    else:
        _print_live(summary)
    return summary


def _print_live(summary: dict) -> None:
    console.print(f"live calibration ({summary.get('captures', 0)} captures) → {summary['rig']}", highlight=False)
    if "stereo" in summary:
        q = summary["stereo"]
        console.print(f"  stereo RMS {q['reprojection_rms_px']:.3f} px, baseline {1000 * q['baseline_m']:.2f} mm",
                      highlight=False)
    p, b = summary["projector"], summary["projector"].get("projector_95") or {}
    console.print(f"  projector RMS {p['projector_rms_px']:.3f} px from {p['poses_used']} poses: "
                  + ", ".join(f"{k} {p['projector'][k]:.2f} ± {b.get(k, float('nan')):.2f}" for k in
                              ("fx", "fy", "cx", "cy")) + " px (95 %)", highlight=False)
    for line in p.get("warnings", []):
        console.print(f"  [yellow]warning:[/] {line}", highlight=False)
    if "mount" in summary:
        m = summary["mount"]
        console.print(f"  mount from the laser ({m['views']} panel poses, laser RMS {m['laser_rms_mm']:.1f} mm): "
                      f"± {m['mount_95']['rotation_deg']:.3f}°, ± {m['mount_95']['position_mm']:.2f} mm (95 %)"
                      + ("" if m["adopted"] else "; less certain than the design value "
                         f"(± {m['design_tolerance_95']['rotation_deg']}°, ± {m['design_tolerance_95']['position_mm']} "
                         "mm): the rig keeps the design value"), highlight=False)
    if "head" in summary:
        h = summary["head"]
        console.print(f"  head model residual {h['rotation_rms_deg']:.4f}° / {h['position_rms_mm']:.3f} mm from "
                      f"{h['poses']} poses", highlight=False)
        for c in h["check_angles"]:
            console.print(f"    projector pose at {[round(a, 2) for a in c['angles_deg']]}: ± "
                          f"{c['rotation_95_deg']:.4f}°, ± {c['position_95_mm']:.2f} mm (95 %)", highlight=False)
    for name, t in summary.get("truth", {}).items():
        extra = f" (design value: {t['design_error']:.3g} {t['unit']})" if "design_error" in t else ""
        console.print(f"  vs simulated truth: {name} error {t['error']:.3g} {t['unit']}, bound {t['bound']:.3g} "
                      f"{t['unit']}: {'within' if t['within'] else 'OUTSIDE'}{extra}", highlight=False)


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    del bench_app
    calibrate_app = typer.Typer(help="Calibrate cameras, projector and pan/tilt head. Without a subcommand: "
                                "the step-by-step wizard.", no_args_is_help=False)

    @calibrate_app.callback(invoke_without_command=True)
    def wizard(
        ctx: typer.Context,
        out: Path = typer.Option(Path("calibration"), "--out", help="Folder for every result and the wizard's "
                                 "state (re-running resumes where it stopped)."),
        sim: bool = typer.Option(False, "--sim", help="Run every step on the simulated site (no hardware)."),
        restart: bool = typer.Option(False, "--restart", help="Forget finished steps and start over."),
        seed: int = typer.Option(0, "--seed", help="Seed of the simulated site."),
        stop_after: str = typer.Option("", "--stop-after", help="Stop after this step (stereo, projector, "
                                       "head, validation); run again to resume."),
        as_json: bool = typer.Option(False, "--json", help="Print the results as JSON."),
    ) -> None:
        """The calibration wizard: stereo → projector → head → validation, resumable."""
        if ctx.invoked_subcommand is not None:
            return
        from arproj.wizard import run_wizard

        state = run_wizard(out, sim=sim, restart=restart, seed=seed, stop_after=stop_after or None)
        if as_json:
            print(json.dumps(state, indent=2))

    @calibrate_app.command("stereo")
    def stereo(
        left: str = typer.Option(..., "--left", help="Glob of the left images, e.g. 'DIR/left*.jpg' (quoted)."),
        right: str = typer.Option(..., "--right", help="Glob of the right images; paired by sorted name."),
        board: str = typer.Option(DEFAULT_BOARD, "--board", help=BOARD_HELP),
        out: Path = typer.Option(..., "--out", help="Rig folder: camera_left.yaml, camera_right.yaml, rig.yaml."),
        model: str = typer.Option("k1k2p1p2k3", "--model", help=MODEL_HELP),
        as_json: bool = typer.Option(False, "--json", help="Print the quality figures as JSON."),
        accept_poor: bool = typer.Option(False, "--accept-poor", help=ACCEPT_POOR_HELP),
    ) -> None:
        """Stereo calibration from image files; writes ROS camera_info files and the rig file (refused, the
        earlier rig kept, when its residuals or baseline are far out of range)."""
        stereo_command(left, right, board, out, model, as_json, accept_poor)

    @calibrate_app.command("camera")
    def camera(
        images: str = typer.Option(..., "--images", help="Glob of one camera's images, e.g. 'DIR/left*.jpg' "
                                   "(quoted)."),
        board: str = typer.Option(DEFAULT_BOARD, "--board", help=BOARD_HELP),
        out: Path = typer.Option(..., "--out", help="Folder for camera.yaml (ROS camera_info) and "
                                 "camera_quality.json."),
        model: str = typer.Option("k1k2p1p2k3", "--model", help=MODEL_HELP),
        as_json: bool = typer.Option(False, "--json", help="Print the quality figures as JSON."),
        accept_poor: bool = typer.Option(False, "--accept-poor", help=ACCEPT_POOR_HELP),
    ) -> None:
        """Calibrate one camera from image files (chessboard or ChArUco); writes a ROS camera_info file."""
        camera_command(images, board, out, model, as_json, accept_poor)

    @calibrate_app.command("capture")
    def capture(
        left_camera: str = typer.Option(..., "--left-camera", help="Left camera: an index (0), a video file or "
                                        "a stream URL (anything cv2.VideoCapture opens)."),
        right_camera: str = typer.Option(..., "--right-camera", help="Right camera, likewise."),
        board: str = typer.Option(DEFAULT_BOARD, "--board", help="Board spec, as for `stereo`."),
        out: Path = typer.Option(..., "--out", help="Folder for left_NN.png / right_NN.png."),
        pairs: int = typer.Option(20, "--pairs", min=1, help="Stop after this many new views of the board."),
        max_frames: int = typer.Option(3000, "--max-frames", min=1, help="Give up after this many frames."),
    ) -> None:
        """Capture stereo pairs from live cameras: keeps frames where both see the board from a new view.

        Move the board through every part of the image and tilt it left/right and up/down; then run
        `arproj calibrate stereo --left 'OUT/left_*.png' --right 'OUT/right_*.png' --board … --out RIG`.
        """
        from calibration.boards import parse_board
        from calibration.capture import capture_pairs, open_source

        spec = parse_board(board)
        left_cap = open_source(left_camera, "left")
        try:
            right_cap = open_source(right_camera, "right")
            try:
                with progress_bar() as bar:
                    task = bar.add_task("views kept", total=pairs)
                    result = capture_pairs(left_cap, right_cap, spec, out, pairs, max_frames,
                                           on_frame=lambda _frames, kept: bar.update(task, completed=kept))
            finally:
                right_cap.release()
        finally:
            left_cap.release()
        console.print(f"{len(result.left_files)} pairs kept from {result.frames_read} frames "
                      f"({result.frames_with_board} with the board in both) → {out}")
        if len(result.left_files) < pairs:
            err_console.print("[yellow]fewer views than asked for:[/] show the board in more places and tilts")
        console.print(f"next: arproj calibrate stereo --left '{out}/left_*.png' --right '{out}/right_*.png' "
                      f"--board {board} --out RIG")

    @calibrate_app.command("projector")
    def projector(
        captures: str = typer.Option("", "--captures", help="Glob of the capture folders, one per board pose: "
                                     "Gray code images in GrayCodePattern.generate() order, then white, black."),
        size: str = typer.Option("", "--projector", help="Projector resolution WIDTHxHEIGHT."),
        board: str = typer.Option("", "--board", help="Printed board spec (default: chessboard:9x7:0.075 for "
                                  f"--captures, {DEFAULT_BOARD} live)."),
        camera: Path | None = typer.Option(None, "--camera", help="camera_info YAML of the camera (else the "
                                           "camera is calibrated from the same captures)."),
        out: Path | None = typer.Option(None, "--out", help="Folder for projector.yaml, camera.yaml and the "
                                        "figures (--captures)."),
        live: bool = typer.Option(False, "--live", help="Show the Gray code on the beamer and capture it now."),
        screen: str = typer.Option("", "--screen", help="Live: the beamer's display number (a fullscreen "
                                   "window) or tcp://HOST:PORT (a screen server, e.g. the simulated site's)."),
        left: str = typer.Option("", "--left", help="Live: the left camera (index, file or stream URL)."),
        right: str = typer.Option("", "--right", help="Live: the right camera; with it the projector is found "
                                  "from triangulated wall points at the head's angles, and the head is fitted."),
        head: str = typer.Option("", "--head", help="Live: the Pelco-D head's URL (/dev/ttyUSB0, socket://…)."),
        laser: str = typer.Option("", "--laser", help="Live: the laser's scan endpoint (JSON over HTTP); with it "
                                  "the cameras' mount on the robot is calibrated."),
        mover: str = typer.Option("", "--mover", help="Live: a URL that moves the board (the simulated site's "
                                  "person); without it you are asked to move the board and press Enter."),
        rig: Path | None = typer.Option(None, "--rig", help="Live: the rig folder (read, and written to)."),
        sim: bool = typer.Option(False, "--sim", help="Live: start the simulated site in its own process and use "
                                 "its screen, cameras, head, laser and board mover."),
        small: bool = typer.Option(False, "--small", help="--sim: 640x400 cameras and a 320x200 projector."),
        seed: int = typer.Option(0, "--seed", help="--sim: seed of the simulated site."),
        stereo: int = typer.Option(0, "--stereo", min=0, help="Live: first calibrate the stereo pair from this "
                                   "many board views."),
        poses: int = typer.Option(5, "--poses", min=3, help="Live, one camera: board poses on the wall."),
        head_poses: int = typer.Option(0, "--head-poses", min=0, help="Live: head angles of the plan to use "
                                       "(0: all; at least 7 for the head)."),
        mount_poses: int = typer.Option(8, "--mount-poses", min=4, help="Live: panel poses for the mount."),
        settle: float = typer.Option(0.15, "--settle", help="Live: seconds to wait after showing a pattern."),
        settle_timeout: float = typer.Option(10.0, "--settle-timeout", help="Live: give up when no two frames "
                                             "agree within this many seconds."),
        record: Path | None = typer.Option(None, "--record", help="Live: also write every capture (the pattern "
                                           "shown, each camera's frame) and the rig's intrinsics at the end as "
                                           "ROS 2 messages into this .mcap (a rosbag2 folder's metadata.yaml "
                                           "beside it)."),
        view: str | None = typer.Option(None, "--view", help="Live: show the captures and the board corners "
                                        "found so far (the coverage) in a Rerun viewer: `--view live` spawns the "
                                        "viewer, `--view FILE.rrd` saves the recording instead."),
        as_json: bool = typer.Option(False, "--json", help="Print the quality figures as JSON."),
    ) -> None:
        """Projector calibration: from capture folders (one camera and a printed board, Moreno & Taubin), or
        --live: the Gray code shown on the beamer and captured; with two cameras also the head and (--laser)
        the cameras' mount. Every recovered quantity is given with its 95 % bound."""
        if not live:
            if record is not None or view is not None:
                raise InputError("--record and --view watch a live calibration", "add --live, or leave them out")
            if not captures or not size or out is None:
                raise InputError("--captures, --projector and --out are needed (or --live)",
                                 "see `arproj calibrate projector --help`")
            projector_command(captures, size, board or "chessboard:9x7:0.075", camera, out, as_json)
            return
        if rig is None:
            raise InputError("--live needs --rig DIR (the rig folder to read and write)")
        from arproj.run.watch import check_targets
        from arproj.wizard.live_run import LiveOptions

        check_targets(record, view)  # a bad --record or --view refused before any work

        opts = LiveOptions(screen=screen, left=left, projector_size=(0, 0), rig=rig, right=right or None,
                           head=head or None, laser=laser or None, mover=mover or None, board=board or DEFAULT_BOARD,
                           poses=poses, head_poses=head_poses or None, mount_poses=mount_poses,
                           stereo_poses=stereo, settle_s=settle, settle_timeout_s=settle_timeout, record=record,
                           view=view)
        live_projector_command(opts, size, sim, small, seed, as_json)

    app.add_typer(calibrate_app, name="calibrate")
