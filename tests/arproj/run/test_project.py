"""`arproj project` from the command line: bad input gives one line, and the session stays up where it can."""

import subprocess
import sys

import numpy as np
import pytest

from arproj.run.project import SessionOptions, run_session
from geometry import Intrinsics
from geometry.errors import InputError
from geometry.rig import Rig
from scanner.wall import shipped_walls

pytestmark = pytest.mark.gl


def _arproj(*args):
    return subprocess.run([sys.executable, "-c", "from arproj.cli import main; main()", *args],
                          capture_output=True, text=True, timeout=120)


def test_missing_glb_is_one_line_and_exit_2(tmp_path):
    result = _arproj("project", "--map", str(tmp_path / "wall.glb"), "--sim")
    assert result.returncode == 2
    assert "no such map file" in result.stderr and "Traceback" not in result.stderr


def test_rig_for_other_cameras_is_refused(tmp_path):
    cam = Intrinsics.from_fov(640, 480, 60.0)
    Rig(intrinsics={"camera_left": cam, "camera_right": cam, "projector": cam}).save(tmp_path / "rig")
    with pytest.raises(InputError, match="camera_left is 640x480 but the device delivers 1280x800"):
        run_session(SessionOptions(truth=shipped_walls()["small_test_wall"], rig_dir=tmp_path / "rig", sim=True),
                    say=lambda _: None)


def test_dead_head_and_no_display_keep_the_session_up_with_a_warning(tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    said = []
    result = run_session(SessionOptions(truth=shipped_walls()["demo_brick_wall"], sim=True, head_fault="dead",
                                        window=True, output=tmp_path / "frames", drill=(1.5, 1.2)),
                         say=said.append)
    assert any("no display" in s for s in said)
    assert any("did not answer" in s for s in said)
    cycle = result["cycles"][0]
    assert not cycle["show_map"] and any("head not answering" in r for r in cycle["reasons"])
    frames = sorted((tmp_path / "frames").glob("frame_*.png"))
    assert frames, "the warning frame is recorded"
    import cv2

    last = cv2.imread(str(frames[-1]))[..., ::-1]
    assert np.array_equal(last[4, 640], [255, 40, 40])  # the red border of the warning


def test_interactive_commands_aim_check_and_survive_bad_input(tmp_path):
    said = []
    commands = ["check 1.18,0.9", "drill 1.5,1.2", "aim nonsense", "fly 1,2", "status", "quit", "update"]
    result = run_session(SessionOptions(truth=shipped_walls()["demo_brick_wall"], sim=True, commands=commands,
                                        record=tmp_path / "s.mcap"), say=said.append)
    assert any(s.startswith("(1.180, 0.900) m: keep away") for s in said)
    assert any("drill point (1.500, 1.200) m: safe" in s for s in said)
    assert any("could not read 'aim nonsense'" in s for s in said)
    assert any("unknown command 'fly'" in s for s in said)
    assert [c.get("command") for c in result["cycles"]] == [None, "drill 1.5,1.2"]  # "update" after quit: not run
    assert result["cycles"][-1]["show_map"]
    from rosbags.highlevel import AnyReader

    with AnyReader([tmp_path]) as reader:  # --record: the typed update is a cycle of the bag too
        gates = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()
                 if c.topic == "/gate"]
    assert gates == ["MAP SHOWN", "MAP SHOWN"]
