from pathlib import Path

import numpy as np
import pytest

from geometry import InputError, Intrinsics, look_at, make_pose, rotation_about
from geometry.head import HeadModel
from geometry.rig import Rig


def _head() -> HeadModel:
    return HeadModel(axes=[[0, 0, 1], [0, 1, 0], [1, 0, 0]],
                     points=[[0.0, 0.0, 1.2], [0.02, 0.0, 1.3], [0.0, 0.01, 1.3]],
                     T_robot_from_projector_zero=look_at([0.1, 0, 1.3], [3, 0, 1.3]),
                     zero_offsets_deg=[0.3, -0.2, 0.1])


def test_rig_round_trip(tmp_path: Path) -> None:
    rig = Rig(
        intrinsics={"camera_left": Intrinsics(800, 800, 640, 400, 1280, 800, (0.1, -0.05, 0, 0, 0)),
                    "projector": Intrinsics(1500, 1500, 640, 880, 1280, 800)},
        poses={"T_camera_right_from_camera_left": make_pose(rotation_about([0, 1, 0], 0.01), [-0.2, 0, 0])},
        head=_head(),
        quality={"reprojection_rms_px": np.float64(0.21)},
    )
    rig.save(tmp_path)
    back = Rig.load(tmp_path)
    assert back.intrinsics == rig.intrinsics
    # The YAML keeps floats at full precision (repr); only the inversion's round-off (~1e-16) remains.
    np.testing.assert_allclose(back.pose("T_camera_left_from_camera_right"),
                               np.linalg.inv(rig.poses["T_camera_right_from_camera_left"]), atol=1e-12)
    np.testing.assert_allclose(back.head.T_robot_from_projector([10, -5, 2]),
                               rig.head.T_robot_from_projector([10, -5, 2]), atol=1e-12)
    assert back.quality["reprojection_rms_px"] == pytest.approx(0.21)


def test_head_model_turns_about_its_axes() -> None:
    head = HeadModel(axes=[[0, 0, 1], [0, 1, 0], [1, 0, 0]], points=np.zeros((3, 3)),
                     T_robot_from_projector_zero=np.eye(4))
    T = head.T_robot_from_projector([90, 0, 0])
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # cos 90° in float64 is 6e-17


def test_rig_with_a_broken_pose_is_refused(tmp_path: Path) -> None:
    Rig(poses={"T_robot_from_camera_left": np.eye(4)}).save(tmp_path)
    text = (tmp_path / "rig.yaml").read_text().replace("[1.0, 0.0, 0.0, 0.0]", "[2.0, 0.0, 0.0, 0.0]", 1)
    (tmp_path / "rig.yaml").write_text(text)
    with pytest.raises(InputError, match="not a rotation"):
        Rig.load(tmp_path)


def test_missing_rig_says_what_to_do(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="arproj calibrate"):
        Rig.load(tmp_path)
