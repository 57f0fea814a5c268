"""Stereo calibration: synthetic ground truth (cv2.projectPoints), the OpenCV convention, bad input, real data."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.boards import BoardView, parse_board
from calibration.stereo import calibrate_camera, calibrate_stereo
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import make_pose, rotation_about, rotation_angle_deg, transform_points
from tests.support.synthetic_calibration import board_poses

LEFT = Intrinsics(700.0, 702.0, 318.0, 243.0, 640, 480, (-0.2, 0.07, 0.001, -0.0005, 0.0))
RIGHT = Intrinsics(695.0, 696.0, 325.0, 236.0, 640, 480, (-0.18, 0.05, -0.0008, 0.0004, 0.0))
T_RIGHT_FROM_LEFT = make_pose(rotation_about([0.1, 1, 0.05], np.radians(2.0)), [-0.12, 0.002, 0.001])
BOARD = parse_board("chessboard:9x6:0.03")
NOISE_PX = 0.05


def synthetic_pairs(n: int, seed: int = 0, frontal: bool = False) -> tuple[list[BoardView], list[BoardView]]:
    """Board corners projected with cv2.projectPoints (through Intrinsics.project) plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    left, right = [], []
    for k, T in enumerate(board_poses(BOARD, n, rng, distance_m=0.7, max_tilt_deg=2.0 if frontal else 35.0)):
        if frontal:
            T[:3, :3] = np.eye(3)
        pl = transform_points(T, BOARD.object_points())
        pr = transform_points(T_RIGHT_FROM_LEFT, pl)
        for intr, pts, out, side in ((LEFT, pl, left, "left"), (RIGHT, pr, right, "right")):
            uv = intr.project(pts) + rng.normal(0, NOISE_PX, (len(pts), 2))
            out.append(BoardView(uv, BOARD.object_points(), np.arange(len(uv)), (640, 480), f"{side}{k:02d}.png"))
    return left, right


def test_recovers_intrinsics_and_right_from_left_pose() -> None:
    left, right = synthetic_pairs(12)
    calib = calibrate_stereo(left, right, BOARD)
    for est, true in ((calib.left, LEFT), (calib.right, RIGHT)):
        # The bench's camera targets (arproj/bench/calibration.py SIM_TARGETS): focal 0.2 %, principal point 1 px.
        assert abs(est.fx / true.fx - 1) < 0.002 and abs(est.fy / true.fy - 1) < 0.002
        # With tangential distortion free, OpenCV's own σ(cx) on these 12 views is ≈ 0.7 px: 3 σ = 2.1 px (the
        # 1 px bench target is judged over many seeds in `arproj bench calibration`, not on one draw).
        assert abs(est.cx - true.cx) < 2.1 and abs(est.cy - true.cy) < 2.1
    # OpenCV's R, T (X_right = R X_left + T) must come out as T_right_from_left.
    # The relative pose trades with the principal points: 1 px / 700 px = 0.08° (seeds 0-7 give 0.003-0.09°),
    # and that angle over the 0.7 m board distance is 1 mm.
    assert np.allclose(calib.T_right_from_left[:3, 3], T_RIGHT_FROM_LEFT[:3, 3], atol=1e-3)
    assert rotation_angle_deg(calib.T_right_from_left, T_RIGHT_FROM_LEFT) < 0.1
    assert abs(calib.baseline_m - 0.12) < 5e-4  # the bench's baseline target, 0.5 mm
    assert calib.rms_px < 2 * NOISE_PX
    assert calib.epipolar_px_per_image < 1.5 * NOISE_PX  # both points noisy: E|d| ≈ 1.13 σ


def test_outlier_view_is_rejected_and_named() -> None:
    left, right = synthetic_pairs(10, seed=3)
    bad = left[4]
    bad.image_points = bad.image_points + np.random.default_rng(5).normal(0, 3.0, bad.image_points.shape)
    calib = calibrate_stereo(left, right, BOARD)
    assert any("left04.png" in name for name in calib.rejected)
    assert abs(calib.left.fx / LEFT.fx - 1) < 0.003  # the 0.2 % focal target with 50 % slack: 9 views left, not 12


def test_pair_whose_board_moved_between_exposures_is_rejected_on_its_epipolar_error() -> None:
    """The right image of pair 5 taken after the board moved 0.6 mm across the baseline (cameras not in sync).

    Its reprojection RMS stays under the RMS test's 0.5 px floor (the shared board pose splits the shift between
    the two images), but its epipolar error (≈ 0.3 px per image against ≈ 0.06 px) fails the epipolar test.
    """
    left, right = synthetic_pairs(12, seed=4)
    rng = np.random.default_rng(11)
    pose = board_poses(BOARD, 12, np.random.default_rng(4), distance_m=0.7, max_tilt_deg=35.0)[5]
    moved = make_pose(None, [0.0, 0.0006, 0.0]) @ pose  # 0.6 mm down in the left camera's frame
    pr = transform_points(T_RIGHT_FROM_LEFT, transform_points(moved, BOARD.object_points()))
    right[5].image_points = RIGHT.project(pr) + rng.normal(0, NOISE_PX, (len(pr), 2))
    kept = calibrate_stereo(left, right, BOARD, reject_outliers=False)
    assert max(kept.per_pair_rms_px) < 0.5  # the RMS test alone cannot see it
    calib = calibrate_stereo(left, right, BOARD)
    assert calib.rejected == ["left05.png | right05.png"]
    assert "epipolar error" in calib.rejected_why["left05.png | right05.png"]
    assert calib.epipolar_px_per_image < 1.5 * NOISE_PX  # the good pairs alone, as in the first test


def test_good_pairs_are_not_rejected_by_the_epipolar_test() -> None:
    for seed in range(4):
        left, right = synthetic_pairs(12, seed=seed)
        assert calibrate_stereo(left, right, BOARD).rejected == []


def test_too_few_views_and_frontal_only_are_input_errors() -> None:
    left, right = synthetic_pairs(3)
    with pytest.raises(InputError, match="at least 4"):
        calibrate_stereo(left, right, BOARD)
    left, right = synthetic_pairs(8, frontal=True)
    with pytest.raises(InputError, match="frontal"):
        calibrate_camera(left, camera="camera_left")
    with pytest.raises(InputError, match="3 left images but 2 right"):
        calibrate_stereo(left[:3], right[:2], BOARD)


def test_coverage_names_missing_tilts_and_regions() -> None:
    left, right = synthetic_pairs(8)
    calib = calibrate_stereo(left, right, BOARD)
    assert set(calib.coverage) >= {"regions_missing", "tilts_missing", "region_share"}
    # The nine shares are reported rounded to 3 decimals: their sum is 1 within 9 x 0.0005.
    assert abs(sum(map(sum, calib.coverage["region_share"])) - 1.0) < 0.005
    # All boards near the centre: the image corners are reported missing.
    assert "top-left" in calib.coverage["regions_missing"]


@pytest.mark.realdata
def test_real_images_held_out_beat_the_two_stage_opencv_pipeline(shared_data) -> None:
    from arproj.bench.calibration import held_out_comparison

    folder = shared_data / "opencv-stereo-chessboard"
    if not folder.is_dir():
        pytest.skip(f"{folder} is absent")
    figures = held_out_comparison(folder, attribution=False)
    held_out = figures.held_out
    ours, two_stage, sample = held_out["arproj"], held_out["opencv two-stage"], held_out["opencv stereo_calib"]
    best_epi = min(two_stage.epipolar_px_per_image, sample.epipolar_px_per_image)
    best_rms = min(two_stage.reprojection_rms_px, sample.reprojection_rms_px)
    assert ours.epipolar_px_per_image < best_epi
    assert ours.reprojection_rms_px < best_rms
    # The reference figures of the data's README are reproduced by the peers (all 13 pairs).
    # 0.01 px (~2 %): the README's figures are 3 decimals from another OpenCV build; far below the gaps above.
    assert abs(figures.training_rms_px["opencv stereo_calib"] - 0.605) < 0.01
    assert abs(figures.training_rms_px["opencv two-stage"] - 0.447) < 0.01


def test_the_quality_gate_passes_sound_figures_and_names_each_bad_one() -> None:
    """Limits from the problem: residuals up to max(1 px, diagonal / 1000), a baseline up to twice the board's
    median distance (issue 24 item 6)."""
    from calibration.stereo import StereoCalibration, residual_limit_px, stereo_quality_problems

    assert residual_limit_px((640, 480)) == 1.0 and residual_limit_px((4000, 3000)) == pytest.approx(5.0)
    cam = Intrinsics(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    boards = [make_pose(np.eye(3), np.array([0.0, 0.0, z])) for z in (0.4, 0.5, 0.6)]

    def calib(rms: float, epipolar: float, baseline_m: float) -> StereoCalibration:
        return StereoCalibration(cam, cam, make_pose(np.eye(3), np.array([-baseline_m, 0.0, 0.0])), rms, epipolar,
                                 [], [], boards)

    assert stereo_quality_problems(calib(0.2, 0.11, 0.083)) == []  # OpenCV's sample pairs, as calibrated
    problems = stereo_quality_problems(calib(20.6, 1170.0, 6.4))  # the wrong board of the issue
    assert len(problems) == 3 and problems[0].startswith("reprojection RMS 20.60 px")
    assert problems[1].startswith("epipolar error 1170.00 px") and problems[2].startswith("baseline 6.400 m")
    assert stereo_quality_problems(calib(float("nan"), 0.1, 0.08))[0].startswith("reprojection RMS nan")
    assert stereo_quality_problems(calib(0.3, 0.2, 1.1)) == ["baseline 1.100 m, implausible with the board 0.50 m "
                                                             "away (at most 2x that, or one camera could not see "
                                                             "it)"]
