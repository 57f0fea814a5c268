from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from geometry import InputError, Intrinsics, look_at, make_pose, rotation_about
from geometry.head import HeadModel
from geometry.intrinsics import write_camera_info
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


def test_the_head_frame_sits_on_the_tilt_axis_and_carries_the_projector_still() -> None:
    head = _head()
    zero = head.T_robot_from_head(-head.zero_offsets_deg)  # the joints at their true zero: the plate unturned
    np.testing.assert_allclose(zero, make_pose(None, head.points[1]), atol=1e-12)
    mount = [np.linalg.inv(head.T_robot_from_head(a)) @ head.T_robot_from_projector(a)
             for a in ([0, 0, 0], [35, -20, 0], [-60, 15, 4])]
    for T in mount[1:]:  # whatever the angles, the projector holds still on the head
        np.testing.assert_allclose(T, mount[0], atol=1e-12)
    roll_zero = -head.zero_offsets_deg[2]  # the roll joint (about a line beside the tilt point) at its true zero
    turned = head.T_robot_from_head([35, -20, roll_zero])
    # the pan (about z through points[0]) moves the tilt point; the tilt turns about it, moving it no further
    pan_only = head.T_robot_from_head([35, -head.zero_offsets_deg[1], roll_zero])
    np.testing.assert_allclose(turned[:3, 3], pan_only[:3, 3], atol=1e-12)
    assert not np.allclose(turned[:3, 3], head.points[1], atol=1e-3)


def test_rig_with_a_broken_pose_is_refused(tmp_path: Path) -> None:
    Rig(poses={"T_robot_from_camera_left": np.eye(4)}).save(tmp_path)
    text = (tmp_path / "rig.yaml").read_text().replace("[1.0, 0.0, 0.0, 0.0]", "[2.0, 0.0, 0.0, 0.0]", 1)
    (tmp_path / "rig.yaml").write_text(text)
    with pytest.raises(InputError, match="not a rotation"):
        Rig.load(tmp_path)


def test_missing_rig_says_what_to_do(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="arproj calibrate"):
        Rig.load(tmp_path)


def _stereo_rig() -> Rig:
    """A known stereo rig: distorted cameras 0.12 m apart, the right one turned and tilted a little."""
    left = Intrinsics(810, 805, 652, 395, 1280, 800, (0.08, -0.12, 0.001, -0.0005, 0.02))
    right = Intrinsics(790, 792, 628, 410, 1280, 800, (-0.05, 0.07, -0.0008, 0.0004, 0.0))
    R = rotation_about([0.2, 1, 0.1], np.radians(1.5))
    return Rig(intrinsics={"camera_left": left, "camera_right": right},
               poses={"T_camera_right_from_camera_left": make_pose(R, R @ [-0.12, 0.004, -0.002])})


def _camera_info_matrices(path: Path) -> tuple[np.ndarray, np.ndarray]:
    doc = yaml.safe_load(path.read_text())
    return (np.reshape(doc["rectification_matrix"]["data"], (3, 3)),
            np.reshape(doc["projection_matrix"]["data"], (3, 4)))


def test_stereo_camera_info_carries_the_rectification(tmp_path: Path) -> None:
    rig = _stereo_rig()
    rig.save(tmp_path)
    T = rig.poses["T_camera_right_from_camera_left"]
    baseline = float(np.linalg.norm(T[:3, 3]))
    (R1, P1), (R2, P2) = (_camera_info_matrices(tmp_path / f"{d}.yaml") for d in ("camera_left", "camera_right"))
    assert P2[0, 3] / P2[0, 0] == pytest.approx(-baseline, rel=1e-9)
    assert P1[0, 3] == 0.0
    np.testing.assert_allclose(R1 @ R1.T, np.eye(3), atol=1e-9)
    # Exact projections of the same points, rectified as ROS image_proc does, land on the same row.
    rng = np.random.default_rng(18)
    p_left = np.column_stack([rng.uniform(-0.8, 0.8, 40), rng.uniform(-0.5, 0.5, 40), rng.uniform(1.5, 4.0, 40)])
    p_right = p_left @ T[:3, :3].T + T[:3, 3]
    rows = []
    for device, p, R, P in (("camera_left", p_left, R1, P1), ("camera_right", p_right, R2, P2)):
        intr = rig.intrinsics[device]
        uv = intr.project(p).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
        rect = cv2.undistortPoints(uv, intr.K, intr.dist_array, None, R, P, criteria).reshape(-1, 2)
        rows.append(rect[:, 1])
    np.testing.assert_allclose(rows[0], rows[1], atol=1e-6)
    # The raw calibration is what is read back: K, D and the extrinsics, untouched by the rectification.
    back = Rig.load(tmp_path)
    assert back.intrinsics == rig.intrinsics
    np.testing.assert_allclose(back.pose("T_camera_right_from_camera_left"), T, atol=1e-12)


def test_rig_written_before_rectification_still_reads(tmp_path: Path) -> None:
    rig = _stereo_rig()
    rig.save(tmp_path)
    for device, intr in rig.intrinsics.items():  # as rig folders were written before: R = I, P = [K|0]
        write_camera_info(tmp_path / f"{device}.yaml", intr, camera_name=device)
        R, P = _camera_info_matrices(tmp_path / f"{device}.yaml")
        np.testing.assert_array_equal(R, np.eye(3))
        assert P[0, 3] == 0.0
    back = Rig.load(tmp_path)
    assert back.intrinsics == rig.intrinsics


def test_a_slipped_joint_is_explained_and_a_moved_projector_is_not() -> None:
    head = _head()
    reported = (12.0, -4.0)
    # the mount slipped: the projector is where other joint angles put it
    slipped = head.T_robot_from_projector([reported[0] + 0.4, reported[1] - 0.3, 0.0])
    slip = head.joint_slip(reported, slipped, rotation_sigma_deg=0.2, translation_sigma_m=0.003)
    assert slip.pan_deg == pytest.approx(0.4, abs=1e-4) and slip.tilt_deg == pytest.approx(-0.3, abs=1e-4)
    assert slip.unexplained_deg < 1e-4 and slip.unexplained_m < 1e-6
    # a camera mount or projector that differs from the model: 25 mm sideways, which no turn gives back
    moved = make_pose(None, [0.0, 0.025, 0.0]) @ head.T_robot_from_projector([*reported, 0.0])
    other = head.joint_slip(reported, moved, rotation_sigma_deg=0.2, translation_sigma_m=0.003)
    assert other.unexplained_m > 0.012  # beyond 4σ of the head model's translation prior
    assert np.linalg.norm(other.unexplained_translation_m) == pytest.approx(other.unexplained_m)
