"""`arproj calibrate projector --live --sim` end to end: the simulated site in its own process (screen, cameras,
head, laser, board mover), the stereo pair, the projector from the Gray code, the mount and the head, each with
its 95 % bound, against the site's truth."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from geometry.rig import Rig


@pytest.mark.gl
def test_live_calibration_through_the_cli(tmp_path: Path) -> None:
    rig_dir = tmp_path / "rig"
    # A process of its own, as a user runs it: nothing left behind by earlier tests in this process (signal
    # handlers, GL contexts, threads) shares its capture timing.
    done = subprocess.run([sys.executable, "-c", "from arproj.cli import main; main()", "calibrate", "projector",
                           "--live", "--sim", "--small", "--seed", "0", "--rig", str(rig_dir), "--stereo", "16",
                           "--head-poses", "7", "--mount-poses", "6", "--json"], capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    summary = json.loads(done.stdout[done.stdout.index("{"):])
    truth = summary["truth"]
    p = summary["projector"]
    # Every figure comes with a bound, and the bound is honest: no error beyond twice its 95 % bound (that 95 % of
    # seeds fall within it is the bench's row, not a test). The principal point within 2 px (the bench's
    # simulated target); the focal length within 2 % (a flat wall seen over ±15° of pan fixes it to about 1.5 %,
    # and the bound says so) and the predicted head poses within 40 mm at 2 m (the focal error along the axis).
    assert set(p["projector_95"]) == {"fx", "fy", "cx", "cy"}
    assert all(check["bound"] > 0 and abs(check["error"]) <= 2 * check["bound"] for name, check in truth.items()
               if not name.startswith("mount")), truth
    assert abs(truth["projector cx"]["error"]) < 2.0 and abs(truth["projector cy"]["error"]) < 2.0, truth
    assert abs(truth["projector fx"]["error"]) < 0.02 * p["projector"]["fx"]
    assert len(summary["head"]["check_angles"]) == 3
    assert all(truth[f"head check {k} position"]["error"] < 40.0 for k in (1, 2, 3))  # mm, at 2 m
    m = summary["mount"]
    assert m["adopted"] == (m["mount_95"]["rotation_deg"] <= 1.0 and m["mount_95"]["position_mm"] <= 10.0)
    rig = Rig.load(rig_dir)
    assert {"camera_left", "camera_right", "projector"} <= set(rig.intrinsics) and rig.head is not None
    assert "projector_95" in rig.quality["projector"] and "check_angles_95" in rig.quality["head"]
    assert truth["mount rotation"]["design_error"] > 0  # the site's mount is off its drawing
    assert summary["captures"] > 7 * 36  # every Gray-code pattern at every head angle was shown and captured
