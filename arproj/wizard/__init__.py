"""The calibration wizard: stereo → projector → head → validation, one step at a time, resumable.

Every finished step is recorded in OUT/wizard_state.json (with its quality figures) and its results are
written to the rig folder OUT (camera_left.yaml, camera_right.yaml, projector.yaml, rig.yaml) before the next
step starts, so an interruption or a failing step keeps everything already done; running the wizard again
resumes at the first unfinished step (--restart starts over).

--sim runs every step on the simulated site (arproj.sim): boards held in front of the cameras, grids
projected at commanded head angles, photographs from both cameras; the state then also records each
recovered quantity's error against the simulated truth. Without --sim the wizard says what to capture and
which command runs each step on the captured files.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from arproj.console import console, track, working
from calibration.boards import parse_board
from calibration.defaults import DEFAULT_BOARD
from geometry.errors import InputError
from geometry.plain import plain
from geometry.rig import RIG_FILE, Rig

_BOARD = parse_board(DEFAULT_BOARD)
STATE_FILE = "wizard_state.json"
STEPS = ("stereo", "projector", "head", "validation")

INSTRUCTIONS = {
    "stereo": f"Print a chessboard ({_BOARD.cols}x{_BOARD.rows} inner corners, {1000 * _BOARD.square_m:g} mm "
              "squares). Take 12-20 pairs with both cameras: "
              "the board filling each image region (corners and centre) and turned left/right and tilted "
              "up/down by 20-45°. Then run: arproj calibrate stereo --left 'DIR/left*.png' --right "
              f"'DIR/right*.png' --board {DEFAULT_BOARD} --out OUT",
    "projector": "With the stereo rig calibrated, project the Gray code (or a chessboard) onto the wall at "
                 "≥ 3 head poses turned ≥ 15° apart (a flat wall seen from one pose cannot fix the "
                 "projector's focal length); or capture a printed board at ≥ 3 tilted poses and run: arproj "
                 "calibrate projector --captures 'DIR/capture_*' --projector WxH --board chessboard:9x7:0.075 "
                 "--camera OUT/camera_left.yaml --out OUT",
    "head": "Measure the projector's pose at ≥ 7 head angles: each joint alone (both directions) and combined, "
            "always approaching each angle from the same side.",
    "validation": "Project a known grid at a head angle not used before and measure it with the stereo pair.",
}


def _load_state(out: Path) -> dict[str, Any] | None:
    path = out / STATE_FILE
    if not path.exists():
        return None
    from geometry.inputs import parse_json, read_text

    # written by json.dumps, which writes NaN for a figure that has none: those constants are ours
    hint = "delete it or run with --restart"
    state = parse_json(read_text(path, "wizard state", 64 << 20, hint), str(path), hint, constants=True)
    if not isinstance(state, dict) or state.get("version") != 1 or not isinstance(state.get("steps"), dict):
        raise InputError(f"{path}: not an arproj wizard state file", "delete it or run with --restart")
    return state


def _save_state(out: Path, state: dict[str, Any]) -> None:
    tmp = out / (STATE_FILE + ".tmp")
    tmp.write_text(json.dumps(state, indent=2, default=plain))
    tmp.replace(out / STATE_FILE)  # atomic: an interruption never leaves half a state file


def next_step(state: dict[str, Any]) -> str | None:
    for step in STEPS:
        if state["steps"].get(step, {}).get("status") != "done":
            return step
    return None


def run_wizard(out: Path, sim: bool = False, restart: bool = False, seed: int = 0,
               stop_after: str | None = None, stereo_poses: int | None = None) -> dict[str, Any]:
    """Run (or resume) the wizard; returns the state (also in OUT/wizard_state.json)."""
    if stop_after is not None and stop_after not in STEPS:
        raise InputError(f"--stop-after {stop_after!r} is not a step", f"use one of {', '.join(STEPS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    state = None if restart else _load_state(out)
    mode = "sim" if sim else "hardware"
    if state is not None and (state.get("mode") != mode or (sim and state.get("seed") != seed)):
        raise InputError(f"{out / STATE_FILE}: was started in {state.get('mode')} mode (seed {state.get('seed')}), "
                         f"now asked for {mode} (seed {seed})", "use the same options, or --restart")
    if state is None:
        state = {"version": 1, "mode": mode, "seed": seed, "steps": {}}
        _save_state(out, state)
    if not sim:
        return _guide(out, state)
    from arproj.wizard import steps
    from arproj.wizard.sim_station import STEREO_BOARD, SimStation

    station = SimStation(seed)
    bar = (lambda items, description, total: track(items, description, total=total))  # noqa: E731
    try:
        while (step := next_step(state)) is not None:
            console.print(f"[bold]step {STEPS.index(step) + 1}/{len(STEPS)}: {step}[/]", highlight=False)
            started = time.time()
            with working(f"step {STEPS.index(step) + 1}/{len(STEPS)}: {step}"):  # bars inside it nest
                rig = Rig.load(out) if (out / RIG_FILE).exists() else None
                if step == "stereo":
                    result, rig = steps.step_stereo(station, out, STEREO_BOARD,
                                                    stereo_poses or steps.STEREO_POSES)
                    result["truth_errors"] = steps.stereo_truth_errors(rig, station.truth)
                elif step == "projector":
                    result, rig = steps.step_projector(station, _need(rig, out), out, bar)
                    result["truth_errors"] = steps.projector_truth_errors(rig, station.truth)
                elif step == "head":
                    measurements = state["steps"]["projector"]["measurements"]
                    result, rig, _ = steps.step_head(_need(rig, out), out, measurements,
                                                  station.T_robot_from_camera_left_design)
                    result["truth_errors"] = steps.head_truth_errors(station, rig)
                else:
                    result = steps.step_validation(station, _need(rig, out), out, bar)
                    result["truth_errors"] = steps.validation_truth_errors(station, _need(Rig.load(out), out))
            result["status"] = "done"
            result["seconds"] = round(time.time() - started, 1)
            state["steps"][step] = result
            _save_state(out, state)
            _report(step, result)
            if step == stop_after:
                break
    finally:
        station.release()
    following = _record_next_step(out, state)
    if following is not None:
        console.print(f"stopped before step {following}; run the same command again to resume", highlight=False)
    return state


def _record_next_step(out: Path, state: dict[str, Any]) -> str | None:
    """The step to do next (None: all done), saved in the state; says so when calibration is complete."""
    following = next_step(state)
    state["next"] = following
    _save_state(out, state)
    if following is None:
        console.print(f"calibration complete → {out / RIG_FILE}", highlight=False)
    return following


def _need(rig: Rig | None, out: Path) -> Rig:
    if rig is None:
        raise InputError(f"{out / RIG_FILE}: missing, but an earlier step is marked done",
                         "run the wizard with --restart")
    return rig


def _report(step: str, result: dict[str, Any]) -> None:
    q = result.get("quality", {})
    if step == "stereo":
        console.print(f"  reprojection RMS {q['reprojection_rms_px']:.3f} px, epipolar "
                      f"{q['epipolar_error_px_per_image']:.3f} px/image, baseline {1000 * q['baseline_m']:.2f} mm",
                      highlight=False)
        for line in result.get("advice", []):
            console.print(f"  next time: {line}", highlight=False)
    elif step == "projector":
        console.print(f"  projector RMS {q['projector_rms_px']:.3f} px from {q['poses_used']} head poses",
                      highlight=False)
    elif step == "head":
        console.print(f"  head model residual {q['rotation_rms_deg']:.4f}° / {q['position_rms_mm']:.3f} mm",
                      highlight=False)
    else:
        console.print(f"  validation: 3-D error {q['rms_mm']:.3f} mm RMS (max {q['max_mm']:.3f} mm)",
                      highlight=False)
    truth = result.get("truth_errors")
    if truth:
        console.print(f"  vs simulated truth: {truth_summary(truth)}", highlight=False)


# Unit of a figure by the end of its key, as the truth checks name them.
_UNITS = {"_pct": " %", "_px": " px", "_mm": " mm", "_deg": "°", "_m": " m"}


def truth_summary(truth: dict[str, Any]) -> str:
    """A truth check's errors on one line with their units: "fx 0.016 %, cx 0.03 px; baseline -0.02 mm".

    Per-angle lists are left out (their worst is a figure of its own); the wizard's JSON state keeps them.
    """
    parts = []
    for key, value in truth.items():
        if isinstance(value, dict):
            parts.append(f"{key.replace('_', ' ')}: " + truth_summary(value).replace("; ", ", "))
        elif not isinstance(value, list | tuple):
            suffix = next((s for s in _UNITS if key.endswith(s)), "")
            name = key[: len(key) - len(suffix)].replace("_", " ")
            parts.append(f"{name} {float(value):.3g}{_UNITS.get(suffix, '')}")
    return "; ".join(parts)


def _guide(out: Path, state: dict[str, Any]) -> dict[str, Any]:
    """Hardware mode: say which step is next and how to capture for it."""
    rig_exists = (out / RIG_FILE).exists()
    if rig_exists and "stereo" not in state["steps"]:
        rig = Rig.load(out)
        if "camera_left" in rig.intrinsics and "stereo" in rig.quality:
            state["steps"]["stereo"] = {"status": "done", "quality": rig.quality["stereo"]}
        if "projector" in rig.intrinsics:
            state["steps"]["projector"] = {"status": "done", "quality": rig.quality.get("projector", {})}
        _save_state(out, state)
    step = _record_next_step(out, state)
    if step is not None:
        done = [s for s in STEPS if state["steps"].get(s, {}).get("status") == "done"]
        console.print(f"done: {', '.join(done) or 'nothing yet'}; next: [bold]{step}[/]", highlight=False)
        console.print(f"  {INSTRUCTIONS[step].replace('OUT', str(out))}", highlight=False)
        console.print("  (or run `arproj calibrate --sim` to see every step on the simulated site)",
                      highlight=False)
    return state
