"""Projector calibration: Gray-code decoding vs OpenCV, Moreno & Taubin on rendered captures, inverse camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.boards import parse_board
from calibration.projector import (
    BoardCaptures,
    calibrate_inverse_camera,
    calibrate_projector_with_board,
    decode_gray_code,
    gray_code_patterns,
    projector_samples,
    projector_size_warning,
    small_sample_widening,
    wall_inliers,
)
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, look_at, rotation_angle_deg, transform_points
from tests.support.synthetic_calibration import PlaneRenderer, board_poses, chessboard_albedo, plane_facing

# No camera distortion: rendering then needs no per-pixel undistortion, which keeps the fixture fast.
CAMERA = Intrinsics(470.0, 470.0, 241.0, 178.0, 480, 360)
PROJECTOR = Intrinsics(400.0, 400.0, 127.5, 140.0, 256, 160, (0.02, -0.01, 0.0, 0.0, 0.0))  # lens shift
T_PROJECTOR_FROM_CAMERA = invert(look_at([0.12, 0.02, 0.0], [0.0, 0.1, 0.8], up=[0, -1, 0]))
BOARD = "chessboard:8x6:0.028"
PROJ_SIZE = (PROJECTOR.width, PROJECTOR.height)


@pytest.fixture(scope="module")
def board_captures() -> list[BoardCaptures]:
    rng = np.random.default_rng(1)
    board = parse_board(BOARD)
    patterns = gray_code_patterns(*PROJ_SIZE)
    out = []
    for k, T in enumerate(board_poses(board, 5, rng, distance_m=0.8, max_tilt_deg=30.0)):
        # 3x3 supersampling: 2x2 edge sampling biases corners (and so the focal length) by ~0.5 %.
        r = PlaneRenderer(CAMERA, T, chessboard_albedo(board), PROJECTOR, T_PROJECTOR_FROM_CAMERA, supersample=3)
        out.append(BoardCaptures([r.render(p, rng) for p in patterns], f"pose_{k}"))
    return out


def test_vectorised_decoding_matches_opencv_get_proj_pixel(board_captures: list[BoardCaptures]) -> None:
    rng = np.random.default_rng(0)
    captures = board_captures[0].images
    decoded = decode_gray_code(captures, PROJ_SIZE)
    gray = cv2.structured_light.GrayCodePattern.create(*PROJ_SIZE)
    gray.setWhiteThreshold(4)  # getProjPixel compares pattern vs inverse against the white threshold
    ys, xs = np.nonzero(np.isfinite(decoded[..., 0]))
    # The projector's 0.51 x 0.32 m field at 0.8 m covers ~56,000 camera pixels (470 px/0.8 m): most must decode.
    assert len(ys) > 25000
    pick = rng.choice(len(ys), 300, replace=False)
    patterns = captures[:-2]
    for y, x in zip(ys[pick], xs[pick], strict=True):
        error, pixel = gray.getProjPixel(patterns, int(x), int(y))
        assert not error
        assert tuple(pixel) == (int(decoded[y, x, 0]), int(decoded[y, x, 1]))


def test_projector_size_given_height_first_is_warned(board_captures: list[BoardCaptures]) -> None:
    images = board_captures[0].images
    assert projector_size_warning(images, PROJ_SIZE) is None
    # 160x256 has the same Gray-code bit counts as 256x160, so the capture count cannot tell them apart;
    # the decoded column codes (up to 255) reaching past a width of 160 do.
    warning = projector_size_warning(images, (PROJ_SIZE[1], PROJ_SIZE[0]))
    assert warning is not None and "looks swapped" in warning and "did you mean 256x160" in warning
    # Too small in one direction only: not a swap, but still a warning to check --projector.
    warning = projector_size_warning(images, (200, 160))
    assert warning is not None and "looks swapped" not in warning and "check --projector" in warning


def test_wrong_number_of_captures_is_an_input_error() -> None:
    with pytest.raises(InputError, match="needs 34"):
        decode_gray_code([np.zeros((4, 4), np.uint8)] * 7, PROJ_SIZE)


def test_moreno_taubin_recovers_projector_with_known_camera(board_captures: list[BoardCaptures]) -> None:
    board = parse_board(BOARD)
    result = calibrate_projector_with_board(board, board_captures, PROJ_SIZE, camera=CAMERA)
    p = result.projector
    # The bench's projector targets (arproj/bench/calibration.py SIM_TARGETS): focal 0.5 %, principal point 2 px.
    assert abs(p.fx / PROJECTOR.fx - 1) < 0.005 and abs(p.fy / PROJECTOR.fy - 1) < 0.005
    assert abs(p.cx - PROJECTOR.cx) < 2.0 and abs(p.cy - PROJECTOR.cy) < 2.0
    assert result.projector_rms_px < 0.3  # integer Gray-code pixels alone give 1/√12 = 0.29 px: must do no worse
    T = result.T_projector_from_camera
    # Position trades with focal length along the axis: the 0.5 % focal target x the 0.8 m board distance = 4 mm.
    assert np.linalg.norm(T[:3, 3] - T_PROJECTOR_FROM_CAMERA[:3, 3]) < 0.004


def test_moreno_taubin_also_calibrates_the_camera(board_captures: list[BoardCaptures]) -> None:
    board = parse_board(BOARD)
    result = calibrate_projector_with_board(board, board_captures, PROJ_SIZE)
    # Five views calibrate the camera only loosely (~0.6 %); the projector still meets its 0.5 % target.
    assert abs(result.camera.fx / CAMERA.fx - 1) < 0.01
    assert abs(result.projector.fx / PROJECTOR.fx - 1) < 0.005
    assert abs(result.projector.cx - PROJECTOR.cx) < 2.0 and abs(result.projector.cy - PROJECTOR.cy) < 2.0  # 2 px


def _wall_views(yaw_pitch: list[tuple[float, float]], noise_px: float, seed: int = 0) -> tuple[list, list]:
    """Points on walls at given orientations (projector frame = reference) and their noisy projector pixels."""
    rng = np.random.default_rng(seed)
    pts, pix = [], []
    for yaw, pitch in yaw_pitch:
        T = plane_facing(2.0, yaw, pitch)  # T_projector_from_plane
        xy = rng.uniform(-0.8, 0.8, (150, 2))
        X = transform_points(T, np.column_stack([xy, np.zeros(150)]))
        uv = PROJECTOR.project(X)
        ok = (uv[:, 0] > 0) & (uv[:, 0] < PROJECTOR.width) & (uv[:, 1] > 0) & (uv[:, 1] < PROJECTOR.height)
        pts.append(X[ok])
        pix.append(uv[ok] + rng.normal(0, noise_px, (ok.sum(), 2)))
    return pts, pix


def test_inverse_camera_from_wall_points_at_varied_poses() -> None:
    pts, pix = _wall_views([(0, 0), (20, 0), (-20, 5), (0, 15), (10, -15), (15, 15)], noise_px=0.1)
    result = calibrate_inverse_camera(pts, pix, PROJ_SIZE)
    p = result.projector
    # Exact 3-D wall points and only 0.1 px noise: the board path's targets (0.5 %, 2 px) tightened to 0.2 %, 1 px.
    assert abs(p.fx / PROJECTOR.fx - 1) < 0.002 and abs(p.cy - PROJECTOR.cy) < 1.0
    for T in result.T_projector_from_view:  # reference frame = projector here
        assert rotation_angle_deg(T) < 0.25  # trades with the principal point: 1 px ≈ 0.14°
        assert np.linalg.norm(T[:3, 3]) < 0.005  # focal error x 2 m along the axis


def test_flat_wall_at_one_orientation_is_degenerate() -> None:
    pts, pix = _wall_views([(5, 0), (5.5, 0.5), (4.5, -0.5), (5, 1)], noise_px=0.1)
    with pytest.raises(InputError, match="degenerate"):
        calibrate_inverse_camera(pts, pix, PROJ_SIZE)
    with pytest.raises(InputError, match="at least 3"):
        calibrate_inverse_camera(pts[:2], pix[:2], PROJ_SIZE)


def test_stereo_gray_code_path_recovers_projector_as_inverse_camera() -> None:
    """Gray code on a bare wall at four orientations, decoded in both cameras, triangulated, inverse camera."""
    from calibration.projector import wall_points_from_stereo
    from geometry.poses import make_pose
    from tests.support.synthetic_calibration import uniform_albedo

    left = Intrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    right = Intrinsics(305.0, 305.0, 161.0, 118.0, 320, 240)
    T_right_from_left = make_pose(None, [-0.15, 0.0, 0.0])
    projector = Intrinsics(160.0, 160.0, 63.5, 70.0, 128, 80, (0.02, 0.0, 0.0, 0.0, 0.0))
    T_projector_from_left = invert(look_at([0.07, 0.03, 0.0], [0.07, 0.1, 1.5], up=[0, -1, 0]))
    patterns = gray_code_patterns(projector.width, projector.height)
    rng = np.random.default_rng(4)
    points, pixels = [], []
    for yaw, pitch in ((0, 0), (18, 4), (-16, -6), (5, 16)):
        T_left_from_wall = plane_facing(1.5, yaw, pitch)
        decoded = []
        for intr, T_cam_from_left in ((left, np.eye(4)), (right, T_right_from_left)):
            r = PlaneRenderer(intr, T_cam_from_left @ T_left_from_wall, uniform_albedo(), projector,
                              T_projector_from_left @ invert(T_cam_from_left), supersample=1)
            decoded.append(decode_gray_code([r.render(p, rng) for p in patterns], projector.size))
        X, uv = wall_points_from_stereo(decoded[0], decoded[1], left, right, T_right_from_left, projector.size,
                                        step_px=8)
        assert len(X) > 144  # 90 % of the 16 x 10 projector grid at step 8: the wall fills both views
        points.append(X)
        pixels.append(uv)
    result = calibrate_inverse_camera(points, pixels, projector.size)
    p = result.projector
    # The bench's projector targets (focal 0.5 %, principal point 2 px).
    assert abs(p.fx / projector.fx - 1) < 0.005 and abs(p.fy / projector.fy - 1) < 0.005
    assert abs(p.cx - projector.cx) < 2.0 and abs(p.cy - projector.cy) < 2.0
    for T in result.T_projector_from_view:  # every wall pose: the same projector pose in camera_left
        # Pose trades with the intrinsics: 0.5 % focal x 1.5 m = 7.5 mm; 0.3° ≈ 0.8 px of principal point at f = 160
        assert np.linalg.norm(T[:3, 3] - T_projector_from_left[:3, 3]) < 0.01
        assert rotation_angle_deg(T, T_projector_from_left) < 0.3


def test_points_off_the_wall_are_found_and_a_collapsed_fit_is_refused() -> None:
    pts, pix = _wall_views([(0, 0), (20, 0), (-20, 5), (0, 15), (10, -15), (15, 15)], noise_px=0.1)
    # A board still held up in the beam: a third of the points 30 cm before the wall, on a plane of its own.
    X = pts[0].copy()
    front = np.arange(len(X)) % 3 == 0
    X[front] *= (1.7 / 2.0)
    inliers = wall_inliers(X)
    assert np.array_equal(inliers, ~front)
    # Garbage in (projector pixels that belong to other points): refused with the reason, no intrinsics.
    rng = np.random.default_rng(3)
    scrambled = [rng.permutation(u) for u in pix]
    with pytest.raises(InputError, match="degenerate") as err:
        calibrate_inverse_camera(pts, scrambled, PROJ_SIZE)
    assert "nothing written" in err.value.message


def test_pose_jackknife_agrees_with_the_fit_covariance_when_errors_are_independent() -> None:
    # Independent pixel noise, the fit covariance's own assumption: the jackknife over poses (what the live
    # calibration's bounds use, as it also sees errors shared within a pose) finds about the same σ.
    angles = [(0, 0), (20, 0), (-20, 5), (0, 15), (10, -15), (15, 15), (-12, -10)]
    for seed in range(2):
        pts, pix = _wall_views(angles, noise_px=0.3, seed=seed)
        fit = calibrate_inverse_camera(pts, pix, PROJ_SIZE)
        assert fit.projector_sigma is not None
        cov = projector_samples(pts, pix, PROJ_SIZE, [], []).covariance(
            lambda p, poses: np.array([p.fx, p.cy]))
        jackknife = np.sqrt(np.diag(cov)) / (2.447 / 1.96)  # without its allowance for 6 degrees of freedom
        formal = np.array([fit.projector_sigma["fx"], fit.projector_sigma["cy"]])
        assert np.all(jackknife > formal / 3) and np.all(jackknife < 3 * formal), (jackknife, formal)
        err = np.array([fit.projector.fx - PROJECTOR.fx, fit.projector.cy - PROJECTOR.cy])
        assert np.all(np.abs(err) <= 1.96 * np.sqrt(np.diag(cov)))


@pytest.mark.parametrize("dims", [1, 3])
def test_a_covariance_from_few_samples_widened_bounds_95_percent(dims: int) -> None:
    # The jackknife's covariance has n - 1 degrees of freedom: a χ² region from it holds too few errors unless
    # widened (a 3-vector more than a scalar: Student's t² does not do for it). Errors independent of the
    # estimate: the widened 95 % region holds 95 % of them, the plain one visibly fewer.
    from scipy.stats import chi2

    rng = np.random.default_rng(7)
    trials, dof = 20000, 9
    samples = rng.normal(size=(trials, dof + 1, dims))
    d = samples - samples.mean(axis=1, keepdims=True)
    cov = np.einsum("tki,tkj->tij", d, d) / dof
    err = rng.normal(size=(trials, dims))
    m2 = np.einsum("ti,tij,tj->t", err, np.linalg.inv(cov), err)
    limit = chi2.ppf(0.95, dims)
    plain = np.mean(m2 <= limit)
    widened = np.mean(m2 <= limit * small_sample_widening(dims, dof))
    assert abs(widened - 0.95) < 4 * np.sqrt(0.95 * 0.05 / trials), widened  # Monte Carlo's own error
    assert plain < 0.93, plain


def test_wall_points_on_their_plane_lose_the_stereo_depth_noise() -> None:
    # The stereo pair's pixels of wall points 2 m away with 0.3 px noise: triangulated, they scatter ~1 cm in
    # depth (taken as exact by the inverse-camera fit, that pulled the live calibration's projector focal length
    # 0.9 % short, cy 1 px off); moved onto their fitted plane along the rays, a few tenths of a millimetre.
    from calibration.projector import on_wall_plane
    from geometry.poses import make_pose
    from geometry.triangulation import triangulate

    left = Intrinsics(700.0, 700.0, 319.5, 199.5, 640, 400)
    right = Intrinsics(702.0, 702.0, 321.0, 198.0, 640, 400)
    T_right_from_left = make_pose(None, [-0.15, 0.0, 0.0])
    T_left_from_wall = plane_facing(2.0, 12.0, -5.0)
    rng = np.random.default_rng(7)
    X = transform_points(T_left_from_wall, np.column_stack([rng.uniform(-0.8, 0.8, (300, 2)), np.zeros(300)]))
    cl = left.project(X) + rng.normal(0, 0.3, (len(X), 2))
    cr = right.project(transform_points(T_right_from_left, X)) + rng.normal(0, 0.3, (len(X), 2))
    normal = T_left_from_wall[:3, 2]
    triangulated = (triangulate(left, right, T_right_from_left, cl, cr) - X) @ normal
    on_plane = on_wall_plane(left, right, T_right_from_left, cl, cr) - X
    assert np.std(triangulated) > 0.006
    assert np.sqrt(np.mean((on_plane @ normal) ** 2)) < 0.001  # off the true wall
    assert np.sqrt(np.mean(np.sum(on_plane ** 2, axis=1))) < 0.002  # and laterally: a ray's precision
