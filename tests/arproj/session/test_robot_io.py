"""Hardware cameras through OpenCV (a video file stands in for a camera), the wall-prior file and the
robot's 2-D laser through its line protocol."""

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
    with pytest.raises(InputError, match="must be a list of 4x4 numbers"):
        read_wall_prior(bad)
    with pytest.raises(InputError, match="no such wall-prior file"):
        read_wall_prior(tmp_path / "missing.yaml")


@pytest.mark.gl
def test_device_laser_reads_the_sites_laser_through_the_laser_protocol():
    """DeviceLaser (devices/laser2d.py on a socket:// URL) gives the robot-frame returns the site's own laser
    gives: ray for ray the same range to within the two sweeps' noise (σ 1 cm each, mm on the wire)."""
    from arproj.session.robot_io import DeviceLaser
    from arproj.sim.live import serve_live_site
    from devices.errors import DeviceError

    with serve_live_site(seed=0, small=True) as live:
        doc = live.laser_scan()
        T = np.asarray(doc["T_robot_from_laser"])
        laser = DeviceLaser(live.urls.laser2d, T)
        try:
            assert laser.head == "H"
            points = laser.points()
            np.testing.assert_allclose(laser.origin, T[:3, 3])
            with pytest.raises(DeviceError, match="'SCAN V 1' -> ERR 4 no head V"):  # the one head it has
                laser.laser.scan("V", 1)
        finally:
            laser.close()
        angles = np.asarray(doc["angles_rad"])
        ranges = np.array([np.nan if r is None else r for r in doc["ranges_m"]])
        rel = points[:, :2] - T[:2, 3]
        assert np.allclose(points[:, 2], T[2, 3])  # the laser's plane, at its height on the robot
        k = np.rint((np.arctan2(rel[:, 1], rel[:, 0]) - angles[0]) / (angles[1] - angles[0])).astype(int)
        difference = np.abs(np.hypot(rel[:, 0], rel[:, 1]) - ranges[k])
        ok = np.isfinite(difference)
        assert ok.sum() > 0.9 * len(angles)
        # 5σ of the difference of two sweeps (σ 1 cm each); the few outlier beams (0.5 % a sweep) aside
        assert np.mean(difference[ok] < 5 * np.hypot(0.01, 0.01)) > 0.98


@pytest.mark.parametrize("text", ["T_wall_from_robot: [[1e400, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
                                  "T_wall_from_robot: [[" + "9" * 400 + ", 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], "
                                  "[0, 0, 0, 1]]", "a: &a [1, 1]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
                                  "c: [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: [*c, *c, *c, *c, *c, *c, *c, *c]",
                                  "[1, 2]", "\x00\x01binary"])
def test_a_bad_wall_prior_is_one_clear_error(tmp_path, text):
    bad = tmp_path / "prior.yaml"
    bad.write_text(text)
    with pytest.raises(InputError, match=str(bad)):
        read_wall_prior(bad)
