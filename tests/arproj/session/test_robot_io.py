"""Hardware cameras through OpenCV (a video file stands in for a camera) and the wall-prior file."""

import cv2
import numpy as np
import pytest

from arproj.session.robot_io import open_camera, read_wall_prior
from geometry import Intrinsics
from geometry.errors import InputError


@pytest.fixture
def video(tmp_path):
    path = tmp_path / "camera.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (320, 240))
    if not writer.isOpened():
        pytest.skip("OpenCV cannot write MJPG video here")
    for k in range(5):
        writer.write(np.full((240, 320, 3), 40 * k, np.uint8))
    writer.release()
    return path


def test_camera_with_the_rig_size_opens(video):
    cap = open_camera(str(video), Intrinsics.from_fov(320, 240, 60.0), "camera_left")
    ok, image = cap.read()
    cap.release()
    assert ok and image.shape == (240, 320, 3)


def test_camera_of_another_size_than_the_rig_is_refused(video):
    with pytest.raises(InputError, match="delivers 320x240 but the rig file is for 1280x800"):
        open_camera(str(video), Intrinsics.from_fov(1280, 800, 60.0), "camera_left")


def test_camera_that_does_not_open_says_so(tmp_path):
    with pytest.raises(InputError, match="does not open"):
        open_camera(str(tmp_path / "no-camera.avi"), Intrinsics.from_fov(320, 240, 60.0), "camera_right")


def test_wall_prior_file(tmp_path):
    good = tmp_path / "prior.yaml"
    good.write_text("T_wall_from_robot: [[1, 0, 0, 2.5], [0, 0, 1, 0], [0, -1, 0, 2.0], [0, 0, 0, 1]]\n")
    assert read_wall_prior(good)[0, 3] == 2.5
    bad = tmp_path / "bad.yaml"
    bad.write_text("T_wall_from_robot: [[1, 0], [0, 1]]\n")
    with pytest.raises(InputError, match="must be a finite 4x4"):
        read_wall_prior(bad)
    with pytest.raises(InputError, match="no such wall-prior file"):
        read_wall_prior(tmp_path / "missing.yaml")
