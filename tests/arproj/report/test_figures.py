"""The report's captions say what its figures draw (issue 23: a caption said "white dashes" for marks that
read black)."""

from __future__ import annotations

import numpy as np

from arproj.report.figures import TRUTH_ON_PHOTO_TEXT, draw_truth_on_photo
from geometry.intrinsics import Intrinsics
from geometry.poses import look_at
from scanner.wall import load_wall, shipped_walls


def test_the_truth_on_the_photo_is_white_on_black_as_its_caption_says() -> None:
    wall = load_wall(shipped_walls()["small_test_wall"])
    photo = np.full((300, 400, 3), 128, np.uint8)
    T_room_from_camera = look_at([0.175, 0.15, 0.5], [0.175, 0.15, 0.0], up=[0.0, 1.0, 0.0])
    drawn, n = draw_truth_on_photo(photo, wall, np.eye(4), T_room_from_camera, Intrinsics.from_fov(400, 300, 60.0))
    assert n == len(wall.objects)
    changed = drawn[(drawn != 128).any(axis=2)]
    white, dark = (changed >= 240).all(axis=1).sum(), (changed <= 60).all(axis=1).sum()
    assert white > 300 and dark > 300  # a white line that reads white (a 1 px one antialiased to grey did not)
    assert "white with a black outline" in TRUTH_ON_PHOTO_TEXT and "dashed" in TRUTH_ON_PHOTO_TEXT
