"""The wizard on the simulated site: a step's results vs truth, state file, resume safety."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from arproj.wizard import STATE_FILE, next_step, run_wizard, truth_summary
from geometry.errors import InputError
from geometry.rig import Rig


@pytest.mark.gl
def test_sim_stereo_step_meets_targets_and_state_resumes(tmp_path: Path) -> None:
    state = run_wizard(tmp_path, sim=True, seed=0, stop_after="stereo", stereo_poses=10)
    stereo = state["steps"]["stereo"]
    assert stereo["status"] == "done" and next_step(state) == "projector"
    errors = stereo["truth_errors"]
    # the calibration bench's targets (arproj.bench.calibration.SIM_TARGETS): 0.2 % focal, 1 px centre, 0.5 mm
    for cam in ("camera_left", "camera_right"):
        assert abs(errors[cam]["fx_pct"]) < 0.2 and abs(errors[cam]["fy_pct"]) < 0.2
        assert abs(errors[cam]["cx_px"]) < 1.0 and abs(errors[cam]["cy_px"]) < 1.0
    assert abs(errors["baseline_mm"]) < 0.5
    # each camera's 95 % bounds from the joint refinement (the live calibration's truth checks judge them)
    bounds = stereo["quality"]["cameras_95"]
    assert set(bounds) == {"camera_left", "camera_right"}
    assert all(set(b) == {"fx", "fy", "cx", "cy"} and all(0 < v < 5.0 for v in b.values()) for b in bounds.values())
    rig = Rig.load(tmp_path)
    assert set(rig.intrinsics) == {"camera_left", "camera_right"}
    saved = json.loads((tmp_path / STATE_FILE).read_text())
    assert saved["steps"]["stereo"]["quality"] == stereo["quality"] and saved["next"] == "projector"
    # Resuming with other options would mix two sites: refused, with the way out named.
    with pytest.raises(InputError, match="--restart"):
        run_wizard(tmp_path, sim=True, seed=1)
    # Hardware mode on a fresh folder says what to capture first, and keeps a state.
    guide = run_wizard(tmp_path / "hw")
    assert guide["next"] == "stereo"


def test_corrupt_state_file_is_an_input_error(tmp_path: Path) -> None:
    (tmp_path / STATE_FILE).write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        run_wizard(tmp_path, sim=True)
    with pytest.raises(InputError, match="not a step"):
        run_wizard(tmp_path, sim=True, restart=True, stop_after="lunch")


def test_truth_errors_are_printed_as_named_figures_with_units() -> None:
    line = truth_summary({"camera_left": {"fx_pct": 0.0157, "cx_px": -0.1}, "baseline_mm": -0.02,
                          "stereo_rotation_deg": 0.0031, "distance_m": 2.016, "position_mm": [1.2, 1.5]})
    assert line == "camera left: fx 0.0157 %, cx -0.1 px; baseline -0.02 mm; stereo rotation 0.0031°; distance 2.02 m"
