import numpy as np
import pytest

from geometry.errors import InputError
from tests.support.synthetic_wallpose import default_views
from wallpose import limits
from wallpose.detect import find_markers
from wallpose.pattern import choose_pattern, layout


def test_corner_pixels_sit_between_the_four_squares() -> None:
    pattern = layout((1280, 800), 20, (100, 100, 900, 700), block=3)
    img = pattern.image().astype(int)
    for (x, y), black_first in zip(pattern.corner_projector_px, pattern.corner_parity, strict=True):
        # pixel centres half a pixel either side of the corner
        ul, dr = img[int(y - 0.5), int(x - 0.5)], img[int(y + 0.5), int(x + 0.5)]
        ur, dl = img[int(y - 0.5), int(x + 0.5)], img[int(y + 0.5), int(x - 0.5)]
        assert ul == dr and ur == dl and ul != ur
        assert (ul == 0) == bool(black_first)


def test_markers_read_back_from_the_projector_image() -> None:
    pattern = layout((1280, 800), 24, (40, 40, 1240, 760), block=4)
    found = find_markers(pattern.image(), pattern)
    assert set(found) == set(range(len(pattern.marker_blocks)))
    for marker_id, corners in found.items():
        # unrefined, from a downscaled copy: good to a couple of pixels, enough to seed the homography
        assert np.abs(corners - pattern.marker_corners_px(marker_id)).max() < 2.5


def test_choose_pattern_covers_what_both_cameras_see() -> None:
    views = default_views()
    for distance in (1.0, 4.0):
        pattern = choose_pattern(views, distance, 30.0)
        w, _ = pattern.projector_size
        assert pattern.n_corners > 150  # a dense board: over ten times limits.MIN_CORNERS
        assert pattern.cols * pattern.square_px > 0.5 * w  # over half the projector's width
        assert pattern.origin_px[0] >= 0 and pattern.origin_px[0] + pattern.cols * pattern.square_px <= w
        # squares big enough for the cameras to resolve
        # 1e-9 px: float round-off of the product
        assert pattern.square_px * pattern.camera_px_per_projector_px >= limits.MIN_SQUARE_CAMERA_PX - 1e-9


def test_bad_layouts_are_input_errors() -> None:
    with pytest.raises(InputError, match="does not fit"):
        layout((640, 400), 40, (0, 0, 640, 400), block=2).__class__(
            projector_size=(640, 400), square_px=40, origin_px=(100, 0), cols=15, rows=5, block=2,
            marker_blocks=np.zeros((0, 2), np.int64))
    with pytest.raises(InputError, match="distance"):
        choose_pattern(default_views(), 50.0)
