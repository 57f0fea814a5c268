"""Board specs and subpixel detection against rendered boards with known corner positions."""

import re

import cv2
import numpy as np
import pytest

from calibration.boards import (
    SB_RNG_SEED,
    SUBPIX_CRITERIA,
    canonical_order,
    detect,
    outer_squares_alternate,
    parse_board,
    refine_corners,
)
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import make_pose, rotation_about, transform_points
from tests.support.synthetic_calibration import PlaneRenderer, chessboard_albedo

CORNER_TOLERANCE_PX = 0.1  # noise 1 grey level, blur 0.6 px, 4x4 supersampled edges


def test_parse_chessboard_and_charuco() -> None:
    b = parse_board("chessboard:9x6:0.025")
    assert (b.kind, b.pattern_size, b.square_m) == ("chessboard", (9, 6), 0.025)
    assert b.object_points().shape == (54, 3)
    assert np.allclose(b.object_points()[10], [0.025, 0.025, 0.0])
    c = parse_board("charuco:7x5:0.04:0.03:DICT_4X4_50")
    assert (c.kind, c.pattern_size, c.marker_m) == ("charuco", (6, 4), 0.03)


@pytest.mark.parametrize("spec", ["chessboard:9x6", "chess:9x6:0.02", "chessboard:9by6:0.02",
                                  "chessboard:9x6:-1", "chessboard:7x7:0.02", "charuco:7x5:0.04:0.05",
                                  "charuco:7x5:0.04:0.03:DICT_NOPE"])
def test_bad_specs_raise_input_error_naming_the_spec(spec: str) -> None:
    with pytest.raises(InputError, match="board spec"):
        parse_board(spec)


@pytest.mark.parametrize(("spec", "suggestion"), [("chessboard:9x6:25", "did you mean 0.025 m (25 mm)"),
                                                  ("charuco:7x5:40:30", "did you mean 0.04 m (40 mm)"),
                                                  ("chessboard:9x6:8", "0.008 m (8 mm) or 0.08 m (8 cm)"),
                                                  ("chessboard:9x6:0.5", "did you mean 0.005 m (0.5 cm)"),
                                                  ("chessboard:9x6:2000", "give the square size in metres")])
def test_implausible_square_size_suggests_metres(spec: str, suggestion: str) -> None:
    with pytest.raises(InputError, match=re.escape(suggestion)):
        parse_board(spec)
    assert parse_board("chessboard:9x6:0.3").square_m == 0.3  # the limit itself is accepted


def _rendered_board(distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A 9x6 board of 30 mm squares rendered tilted at distance_m, and its true corners (n, 2) px."""
    board = parse_board("chessboard:9x6:0.03")
    cam = Intrinsics(600.0, 600.0, 319.5, 239.5, 640, 480, (-0.05, 0.01, 0.0, 0.0, 0.0))
    R = rotation_about([1, 0.4, 0], np.radians(25))
    T = make_pose(R, np.array([0.0, 0.0, distance_m]) - R @ np.array([0.12, 0.075, 0.0]))
    img = PlaneRenderer(cam, T, chessboard_albedo(board), supersample=4).render(
        None, np.random.default_rng(0), ambient=250.0, noise=1.0)
    return img, cam.project(transform_points(T, board.object_points()))


def test_subpixel_corners_match_the_rendered_truth() -> None:
    img, truth = _rendered_board(0.75)
    view = detect(parse_board("chessboard:9x6:0.03"), img)
    assert view is not None
    err = np.linalg.norm(view.image_points - truth, axis=1)
    assert np.sqrt(np.mean(err ** 2)) < CORNER_TOLERANCE_PX


@pytest.fixture(scope="module")
def small_squares() -> tuple[np.ndarray, np.ndarray]:
    """Squares ~20 px wide: the adaptive half-window is 5 px."""
    return _rendered_board(0.9)


@pytest.mark.parametrize(("corner", "offset_px"), [(0, (-6.0, 2.0)), (0, (7.0, 0.0)), (13, (5.0, 3.0)),
                                                   (22, (4.0, -5.0)), (53, (-6.0, 2.0))])
def test_a_raw_corner_pixels_off_is_recovered(small_squares: tuple[np.ndarray, np.ndarray], corner: int,
                                              offset_px: tuple[float, float]) -> None:
    """findChessboardCorners now and then puts one raw corner 4-7 px off, beyond the adaptive window's reach."""
    img, truth = small_squares
    board = parse_board("chessboard:9x6:0.03")
    raw = truth.copy()
    raw[corner] += offset_px
    # One pass at the adaptive half-window (a quarter of the ~20 px spacing) does not reach the true corner ...
    once = cv2.cornerSubPix(img, raw[corner:corner + 1].reshape(1, 1, 2).astype(np.float32), (5, 5), (-1, -1),
                            SUBPIX_CRITERIA).reshape(2)
    assert np.linalg.norm(once - truth[corner]) > 3.0
    # ... the retry from where the neighbours put it does, and leaves the other corners where they belong.
    refined = refine_corners(img, raw, board.pattern_size)
    err = np.linalg.norm(refined - truth, axis=1)
    assert err[corner] < 2 * CORNER_TOLERANCE_PX
    assert np.delete(err, corner).max() < 3 * CORNER_TOLERANCE_PX


def _grid_shifted(corners: np.ndarray, pattern_size: tuple[int, int], di: int, dj: int) -> np.ndarray:
    """The image points a grid numbered (di, dj) squares off would have: the board's own homography, moved."""
    c, r = pattern_size
    grid = np.stack(np.meshgrid(np.arange(c), np.arange(r)), axis=-1).reshape(-1, 2).astype(np.float64)
    H, _ = cv2.findHomography(grid, corners)
    return cv2.perspectiveTransform((grid + np.array([di, dj], dtype=np.float64)).reshape(-1, 1, 2), H).reshape(-1, 2)


@pytest.mark.parametrize(("di", "dj"), [(-1, 0), (1, 0), (0, -1), (0, 1)])
def test_a_grid_numbered_a_square_off_is_told_by_the_outer_squares(small_squares: tuple[np.ndarray, np.ndarray],
                                                                   di: int, dj: int) -> None:
    """The board's outer squares alternate all round its corner grid; a grid one square off has the white margin
    on one side where they should alternate."""
    img, truth = small_squares
    size = parse_board("chessboard:9x6:0.03").pattern_size
    assert outer_squares_alternate(img, truth, size)
    assert not outer_squares_alternate(img, _grid_shifted(truth, size, di, dj), size)


def test_a_partly_hidden_board_on_the_simulated_site_is_not_numbered_a_square_off() -> None:
    """Seed 9's board view 7 (the live site's stereo plan, small cameras): the board's far side is hidden and
    the sector-based detector finds a 9x6 grid that takes the board's left edge for its first column, every
    corner one square (~23 px) from its number. In a stereo pair with the other camera's right numbering that
    is a disparity error the epipolar test cannot see. detect must give the true corners or no view."""
    from arproj.sim.room import Target
    from arproj.sim.site import Site
    from arproj.wizard.sim_station import board_pose_plan
    from calibration.defaults import DEFAULT_BOARD

    board = parse_board(DEFAULT_BOARD)
    site = Site.build(seed=9, cameras={"width": 640, "height": 400}, projector={"width": 320, "height": 200})
    try:
        site.place_robot(2.0, 0.0)
        T_left_from_board = board_pose_plan(board, 16, np.random.default_rng(9 + 1000))[7]
        texture = board.render(pixels_per_square=48, margin_squares=1.0)
        sq = board.square_m
        size_m = (texture.shape[1] / 48 * sq, texture.shape[0] / 48 * sq)
        target = Target(texture, size_m, site.T_room_from("camera_left") @ T_left_from_board
                        @ make_pose(None, [-2 * sq, -2 * sq, 0.0]))
        black = np.zeros((site.projector.height, site.projector.width), np.uint8)
        image = site.photograph("camera_left", projector_image=black, targets=[target]).image
        truth = site.camera_left.project(transform_points(T_left_from_board, board.object_points()))
    finally:
        site.release()
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    cv2.setRNGSeed(SB_RNG_SEED)
    found, raw = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=cv2.CALIB_CB_EXHAUSTIVE)
    if found:  # what the detector alone makes of it (OpenCV 5.0): a grid a square off
        raw_error = np.abs(canonical_order(raw.reshape(-1, 2), board.pattern_size) - truth).max()
        assert raw_error > 10.0
    view = detect(board, image)
    assert view is None or np.abs(view.image_points - truth).max() < 1.0


@pytest.mark.realdata
def test_every_real_board_opencv_finds_is_still_found(shared_data) -> None:
    """The outer-squares check refuses no board of OpenCV's stereo sample images (their prints are trimmed
    close to the outer squares)."""
    folder = shared_data / "opencv-stereo-chessboard"
    board = parse_board("chessboard:9x6:0.025")
    images = sorted(folder.glob("*.jpg"))
    if not images:
        pytest.skip(f"no images in {folder}")
    for path in images:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        found, _ = cv2.findChessboardCorners(gray, board.pattern_size,
                                             flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if found:
            assert detect(board, gray) is not None, path.name


def test_no_board_gives_none() -> None:
    board = parse_board("chessboard:9x6:0.03")
    assert detect(board, np.full((240, 320), 128, np.uint8)) is None


def test_charuco_detection_finds_known_corners() -> None:
    board = parse_board("charuco:7x5:0.04:0.03")
    img = board.render(pixels_per_square=60, margin_squares=1.0)
    view = detect(board, img)
    assert view is not None and len(view.ids) >= 20
    # In the printed image, corner id k sits at (margin + (1 + col) squares) with pixel centres at integers.
    cols = board.pattern_size[0]
    expected = np.column_stack([60 + 60 * (1 + view.ids % cols), 60 + 60 * (1 + view.ids // cols)]) - 0.5
    # Noise-free print, corners on pixel centres: exact up to float32 (~1e-5 px); a half-pixel slip would fail.
    assert np.max(np.abs(view.image_points - expected)) < CORNER_TOLERANCE_PX


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["left01", "left13"])
def test_a_detection_depends_on_the_image_alone_not_on_opencvs_random_state(shared_data, name: str) -> None:
    """findChessboardCornersSB samples with OpenCV's global RNG: on OpenCV's sample images with the wrong 7x5
    board it found a board after one RNG state and none after another (left01: none after state 0, left13: none
    after state 6), so a calibration used different pairs and gave different baselines from run to run. Whatever
    the RNG's state before, the same image gives the same view."""
    path = shared_data / "opencv-stereo-chessboard" / f"{name}.jpg"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    board = parse_board("chessboard:7x5:0.025")
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    views = []
    for state in (0, 1, 6, 7):
        cv2.setRNGSeed(state)  # as other code would leave it
        views.append(detect(board, image))
    found = [v is not None for v in views]
    assert len(set(found)) == 1
    if found[0]:
        assert all(np.array_equal(v.image_points, views[0].image_points) for v in views)  # type: ignore[union-attr]
