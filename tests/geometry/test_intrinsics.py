from pathlib import Path

import numpy as np
import pytest

from geometry import InputError, Intrinsics, read_camera_info, write_camera_info

ROS_CAMERA_INFO = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [430.215550, 0.000000, 306.691343, 0.000000, 430.531693, 227.224800, 0.000000, 0.000000, 1.000000]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.337586, 0.111612, -0.000218, -0.000030, 0.0000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [0.987497, -0.005093, 0.157603, 0.005109, 0.999987, 0.000299, -0.157602, 0.000509, 0.987510]
projection_matrix:
  rows: 3
  cols: 4
  data: [505.5, 0.0, 267.3, 0.0, 0.0, 505.5, 205.1, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


def test_reads_the_layout_ros_camera_calibration_writes(tmp_path: Path) -> None:
    path = tmp_path / "left.yaml"
    path.write_text(ROS_CAMERA_INFO)
    intr = read_camera_info(path)
    assert (intr.width, intr.height) == (640, 480)
    assert intr.fx == pytest.approx(430.215550) and intr.cy == pytest.approx(227.2248)
    assert intr.dist[0] == pytest.approx(-0.337586)


def test_round_trip_with_lens_shift_and_rational_model(tmp_path: Path) -> None:
    projector = Intrinsics(1650.5, 1651.25, 639.5, 905.75, 1280, 800,
                           (0.01, -0.02, 0.0005, -0.0003, 0.001, 0.0, 0.0, 0.002))
    write_camera_info(tmp_path / "projector.yaml", projector, camera_name="projector")
    text = (tmp_path / "projector.yaml").read_text()
    assert "distortion_model: rational_polynomial" in text
    assert read_camera_info(tmp_path / "projector.yaml") == projector


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("image_width: [unclosed", "not valid YAML"),
        ("- just\n- a list\n", "expected a camera_info mapping"),
        (ROS_CAMERA_INFO.replace("camera_matrix:", "camera_matrx:"), "'camera_matrix' is missing"),
        (ROS_CAMERA_INFO.replace("cols: 5\n  data: [-0.337586,", "cols: 5\n  data: ["), "4 values for rows=1, cols=5"),
        (ROS_CAMERA_INFO.replace("430.215550", "-430.2"), "non-positive focal length"),
        (ROS_CAMERA_INFO.replace("227.224800", "abc"), "list of numbers"),
    ],
)
def test_bad_yaml_gives_a_clear_error_naming_the_file(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text(content)
    with pytest.raises(InputError, match=message) as err:
        read_camera_info(path)
    assert str(path) in str(err.value)


def test_missing_file_says_how_to_get_one(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such camera_info file"):
        read_camera_info(tmp_path / "nope.yaml")


def test_rays_invert_projection_with_distortion() -> None:
    intr = Intrinsics(900, 905, 700.3, 620.7, 1280, 800, (-0.25, 0.09, 0.001, -0.0005, -0.01))
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-0.6, 0.6, 50), rng.uniform(-0.4, 0.4, 50), np.ones(50)])
    rays = intr.rays(intr.project(p))
    np.testing.assert_allclose(rays, p, atol=1e-9)  # undistortion iterates to 1e-12 px; 1e-9 x 900 px = 1e-6 px


def test_no_points_project_to_no_pixels() -> None:
    # the closed loop asks which of no candidate marks are in view (a small trusted region far away)
    intr = Intrinsics(900, 905, 700.3, 620.7, 1280, 800, (-0.25, 0.09, 0.001, -0.0005, -0.01))
    for distort in (True, False):
        assert intr.project(np.zeros((0, 3)), distort=distort).shape == (0, 2)


def test_scaled_keeps_the_optics() -> None:
    intr = Intrinsics(900, 900, 639.5, 399.5, 1280, 800)
    half = intr.scaled(0.5)
    p = np.array([[0.1, -0.2, 2.0]])
    # Exact rescaling: float64 round-off on ~500 px coordinates is ~1e-13 px.
    np.testing.assert_allclose((intr.project(p) + 0.5) * 0.5 - 0.5, half.project(p), atol=1e-12)


LENSES = [(), (-0.25, 0.09, 0.001, -0.0005, -0.01), (0.9, 0.2, 0.0012, -0.0007, 0.01, 1.1, 0.35, 0.03)]


@pytest.mark.parametrize("dist", LENSES)
def test_pixels_of_normalized_is_project(dist: tuple[float, ...]) -> None:
    intr = Intrinsics(900, 905, 700.3, 620.7, 1280, 800, dist)
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.uniform(-0.6, 0.6, (200, 2)), rng.uniform(0.8, 3.0, 200)])
    ours = intr.pixels_of_normalized(p[:, :2] / p[:, 2:])
    # the same formula in float64, OpenCV adding its terms in another order: agreement to ~1e-13 px
    np.testing.assert_allclose(ours, intr.project(p), rtol=0, atol=1e-9)
    assert intr.pixels_of_normalized(p[:6, :2].reshape(2, 3, 2)).shape == (2, 3, 2)
