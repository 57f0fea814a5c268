"""`arproj project --record/--view`: the session's bag read back with rosbags (independent of the writer)
against the session's own pose, the rig's intrinsics and the frames it showed; the Rerun recording's entities."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from arproj.run.project import SessionOptions, run_session
from arproj.run.view import SESSION_ENTITIES
from geometry.poses import invert
from scanner.wall import shipped_walls

pytestmark = pytest.mark.gl

TOPICS = {"/tf": "tf2_msgs/msg/TFMessage", "/gate": "std_msgs/msg/String",
          **{f"/{d}/camera_info": "sensor_msgs/msg/CameraInfo" for d in ("projector", "camera_left", "camera_right")},
          **{f"/{d}/image/compressed": "sensor_msgs/msg/CompressedImage"
             for d in ("projector", "camera_left", "camera_right")}}


def _quat_matrix(q: object) -> np.ndarray:
    x, y, z, w = q.x, q.y, q.z, q.w  # type: ignore[attr-defined]
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _pose(tr: object) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = _quat_matrix(tr.transform.rotation)  # type: ignore[attr-defined]
    t = tr.transform.translation  # type: ignore[attr-defined]
    T[:3, 3] = (t.x, t.y, t.z)
    return T


def _difference(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """How far pose T lies from `truth`: (offset mm, rotation °)."""
    error = invert(truth) @ T
    return (float(np.linalg.norm(error[:3, 3]) * 1000),
            float(np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1) / 2, -1, 1)))))


def test_the_session_bag_holds_tf_camera_info_frames_and_gate(tmp_path, monkeypatch):
    from arproj.session import session as session_module

    shown: list[np.ndarray] = []
    rigs: list = []
    sites: list = []
    real_update = session_module.ProjectionSession.update

    def update(self, *args, **kwargs):  # the frames the session showed, and its rig, kept to compare
        decision = real_update(self, *args, **kwargs)
        shown.append(self.last_frame.copy())
        rigs.append(self.rig)
        sites.append(self.robot.site)
        return decision

    monkeypatch.setattr(session_module.ProjectionSession, "update", update)
    # a placement whose map is shown (the closed loop's marks are recorded): the demo wall from 2 m
    result = run_session(SessionOptions(truth=shipped_walls()["demo_brick_wall"], sim=True, cycles=1, distance=2.0,
                                        record=tmp_path / "s.mcap", view=str(tmp_path / "s.rrd")),
                         say=lambda _: None)
    assert (tmp_path / "metadata.yaml").is_file()
    out: dict[str, list] = {}
    with AnyReader([tmp_path]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TOPICS
        for connection, _, raw in reader.messages():
            out.setdefault(connection.topic, []).append(reader.deserialize(raw, connection.msgtype))
    assert all(len(out[t]) == 1 for t in TOPICS)
    parents: dict[str, str] = {}
    poses: dict[str, np.ndarray] = {}
    for msg in out["/tf"]:
        for tr in msg.transforms:
            assert parents.setdefault(tr.child_frame_id, tr.header.frame_id) == tr.header.frame_id
            poses[tr.child_frame_id] = _pose(tr)
    assert parents == {"robot": "room", "head": "robot", "projector": "head", "camera_left": "robot",
                       "camera_right": "camera_left"}
    reg = result["registration"]
    T_wall_from_projector = poses["robot"] @ poses["head"] @ poses["projector"]
    np.testing.assert_allclose(T_wall_from_projector, reg["T_wall_from_projector"], atol=1e-9)
    np.testing.assert_allclose(poses["robot"], reg["T_wall_from_robot"], atol=1e-9)
    rig, site = rigs[-1], sites[-1]
    # the head where the simulated site has it (its true joints and kinematics, against the calibrated model at
    # the reported angles), and the projector on it where the site mounts it
    for T, truth in ((poses["head"], site.T_robot_from_head),
                     (poses["projector"], invert(site.T_robot_from_head) @ site.T_robot_from_projector)):
        offset_mm, angle_deg = _difference(T, truth)
        assert offset_mm < 5.0 and angle_deg < 1.0, (offset_mm, angle_deg)
    # the head turned with the reported pan/tilt: its frame at the joints' zero is far from where it is
    assert _difference(rig.head.T_robot_from_head([0.0, 0.0, 0.0]), site.T_robot_from_head)[1] > 5.0
    np.testing.assert_allclose(poses["camera_left"], rig.pose("T_robot_from_camera_left"), atol=1e-9)
    np.testing.assert_allclose(invert(poses["camera_right"]), rig.pose("T_camera_right_from_camera_left"), atol=1e-9)
    for name in ("projector", "camera_left", "camera_right"):
        info, intr = out[f"/{name}/camera_info"][-1], rig.intrinsics[name]
        assert (info.width, info.height) == (intr.width, intr.height) and info.header.frame_id == name
        np.testing.assert_array_equal(info.k.reshape(3, 3), intr.K)
        np.testing.assert_array_equal(info.d, intr.dist)
    for msg, frame in zip(out["/projector/image/compressed"], shown, strict=True):
        assert msg.format == "png"
        image = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)[..., ::-1]
        np.testing.assert_array_equal(image, frame)
    left = cv2.imdecode(np.frombuffer(out["/camera_left/image/compressed"][-1].data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert left.shape[:2] == (rig.intrinsics["camera_left"].height, rig.intrinsics["camera_left"].width)
    gates = [m.data for m in out["/gate"]]
    assert gates == ["MAP SHOWN" if c["show_map"] else "WARNING: " + "; ".join(c["reasons"])
                     for c in result["cycles"]]


    from rerun.chunk import RrdReader

    paths = set(RrdReader(tmp_path / "s.rrd").store().schema().entity_paths())  # --view FILE.rrd beside it
    assert {f"/{e}" for e in SESSION_ENTITIES} <= paths, paths


@pytest.mark.parametrize("args, message", [(["--record", "s.bag"], "a recording is an .mcap file"),
                                           (["--view", "s.png"], "give `live` (a viewer) or a FILE.rrd")])
def test_a_bad_record_target_is_refused_in_one_line_before_any_work(args, message, tmp_path, monkeypatch, capsys):
    import sys

    from arproj.cli import main

    monkeypatch.setattr(sys, "argv", ["arproj", "project", "--sim", "--truth", "demo_brick_wall", "--output",
                                      str(tmp_path / "frames"), *args])
    with pytest.raises(SystemExit) as exit_:
        main()
    err = capsys.readouterr().err.replace("\n", " ")
    assert exit_.value.code == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "frames").exists()  # refused before the session started
