"""Occupancy grid: ROS metadata and cell convention, unknown vs free, inverse sensor model, clamping."""

import numpy as np
import pytest

from geometry.errors import InputError
from mapping import tolerances as tol
from mapping.grid import GridInfo, SensorModel, WallGrid, build_grid


def test_cell_centre_convention_and_ros_metadata():
    info = GridInfo(0.01, 30, 20, origin_x=-0.1, origin_y=0.2)
    xs, ys = info.cell_centres()
    assert xs[0] == pytest.approx(-0.1 + 0.005) and ys[3] == pytest.approx(0.2 + 3.5 * 0.01)
    rows, cols, inside = info.cell_of([[-0.1 + 0.0149, 0.2 + 0.0251], [-0.2, 0.0]])
    assert (rows[0], cols[0], inside[0], inside[1]) == (2, 1, True, False)
    pix = info.to_pixel([[xs[7], ys[4]]])
    np.testing.assert_allclose(pix, [[7.0, 4.0]])
    np.testing.assert_allclose(info.to_wall(pix), [[xs[7], ys[4]]])
    ros = info.to_ros()["info"]
    assert ros["width"] == 30 and ros["height"] == 20 and ros["origin"]["position"]["x"] == -0.1
    assert ros["origin"]["orientation"]["w"] == 1.0


def test_bad_grid_and_thresholds_raise_input_error():
    with pytest.raises(InputError):
        GridInfo(0.0, 10, 10)
    with pytest.raises(InputError):
        SensorModel("ac", threshold_occupied=0.1, threshold_free=0.5)
    with pytest.raises(InputError):
        build_grid(np.zeros((3, 2)), {"ac": np.full(3, np.nan)})


def _raster(x0=0.0, x1=0.5, y0=0.0, y1=0.3, step=0.002, spacing=0.01):
    ys = np.arange(y0, y1 + 1e-9, spacing)
    xs = np.arange(x0, x1 + 1e-9, step)
    X, Y = np.meshgrid(xs, ys)
    return np.column_stack([X.ravel(), Y.ravel()])


def test_inverse_sensor_model_occupied_free_unknown():
    xy = _raster()
    # a vertical "cable" at x = 0.2: a reading peak of width 4 mm; 5 % noise
    rng = np.random.default_rng(0)
    reading = 0.02 + np.exp(-0.5 * ((xy[:, 0] - 0.2) / 0.004) ** 2) + 0.005 * rng.standard_normal(len(xy))
    info = GridInfo.covering(-0.05, -0.05, 0.6, 0.35, 0.004)
    grid = WallGrid(info, {"ac": SensorModel.from_readings("ac", reading)})
    grid.add_samples(xy, {"ac": reading})
    p = grid.probability("ac")
    xs, ys = info.cell_centres()
    row = int(np.argmin(np.abs(ys - 0.15)))
    on = int(np.argmin(np.abs(xs - 0.2)))
    off = int(np.argmin(np.abs(xs - 0.35)))
    outside = int(np.argmin(np.abs(xs - 0.58)))  # 8 cm right of the last sample: never observed
    # Decisive cells: log-odds beyond ±2.2 (p 0.9 / 0.1); the clamp at ±4 caps them at p 0.982 / 0.018.
    assert p[row, on] > 0.9
    assert p[row, off] < 0.1
    assert np.isnan(p[row, outside])  # unknown is not free
    occ = grid.occupancy_int8("ac")
    assert occ[row, outside] == -1 and occ[row, on] > 90 and 0 <= occ[row, off] < 10  # the same 0.9 / 0.1, in %
    lo = grid.log_odds["ac"]
    assert lo.min() >= tol.LOG_ODDS_MIN and lo.max() <= tol.LOG_ODDS_MAX  # clamped
    sig = grid.signal("ac")
    assert abs(xs[np.nanargmax(sig[row])] - 0.2) <= 0.004  # one cell of the 4 mm grid


def test_nan_readings_skip_only_that_sensor():
    xy = _raster(step=0.005)
    a = np.where(xy[:, 0] < 0.25, np.nan, 0.3)
    b = np.full(len(xy), 0.1)
    grid = build_grid(xy, {"ac": a, "inductive": b}, resolution=0.005)
    xs, ys = grid.info.cell_centres()
    row = int(np.argmin(np.abs(ys - 0.1)))
    left = int(np.argmin(np.abs(xs - 0.1)))
    assert not grid.known("ac")[row, left] and grid.known("inductive")[row, left]
    assert grid.signal("inductive")[row, left] == pytest.approx(0.1)
