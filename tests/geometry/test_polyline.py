"""Polylines against distances and lengths worked out by hand."""

import numpy as np
import pytest

from geometry.polyline import densify, distances_to_polyline, midpoint_samples, nearest_segments, polyline_length

# An L: 3 m along x, then 4 m up.
L_SHAPE = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]])


def test_distances_to_an_l_shape() -> None:
    points = np.array([
        [1.0, 2.0],    # above the first leg: 2 m to it (and 2 m to the second: a tie, the first segment wins)
        [1.0, -0.5],   # below the first leg: 0.5 m
        [-3.0, -4.0],  # beyond the start: 5 m to (0, 0)
        [3.0, 0.0],    # on the corner
        [5.0, 3.0],    # right of the second leg: 2 m
        [6.0, 8.0],    # beyond the end: 5 m to (3, 4)
    ])
    d, seg = nearest_segments(points, L_SHAPE)
    # exact in float64 but for the square root of a sum of squares (one ulp)
    np.testing.assert_allclose(d, [2.0, 0.5, 5.0, 0.0, 2.0, 5.0], rtol=0, atol=1e-15)
    assert seg.tolist() == [0, 0, 0, 0, 1, 1]
    np.testing.assert_array_equal(distances_to_polyline(points, L_SHAPE), d)


def test_a_single_point_a_repeated_vertex_and_nan() -> None:
    np.testing.assert_allclose(distances_to_polyline([[3.0, 4.0], [0.0, 0.0]], [[0.0, 0.0]]), [5.0, 0.0])
    # a zero-length segment counts as its end point
    d = distances_to_polyline([[1.0, 1.0], [-3.0, 4.0]], [[0.0, 0.0], [0.0, 0.0], [3.0, 0.0]])
    np.testing.assert_allclose(d, [1.0, 5.0], rtol=0, atol=1e-15)
    # one point (2,) is one row; a NaN point has no distance
    d = distances_to_polyline(np.array([[np.nan, 0.0], [1.0, 1.0]]), L_SHAPE)
    assert np.isnan(d[0]) and d[1] == pytest.approx(1.0)
    assert distances_to_polyline(np.array([1.0, 1.0]), L_SHAPE).shape == (1,)


def test_length() -> None:
    assert polyline_length(L_SHAPE) == 7.0
    assert polyline_length([[1.0, 2.0]]) == 0.0
    assert polyline_length([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0]]) == pytest.approx(np.sqrt(2.0), abs=1e-15)


def test_densify_keeps_the_vertices_and_cuts_segments_into_equal_parts() -> None:
    p = densify(L_SHAPE, 0.7)
    # 3 m in ceil(3 / 0.7) = 5 parts of 0.6 m, 4 m in 6 parts of 2/3 m
    assert len(p) == 1 + 5 + 6
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    np.testing.assert_allclose(steps, [0.6] * 5 + [4.0 / 6.0] * 6, rtol=0, atol=1e-15)
    for vertex in L_SHAPE:
        assert np.min(np.linalg.norm(p - vertex, axis=1)) == 0.0
    np.testing.assert_array_equal(densify([[1.0, 2.0]], 0.1), [[1.0, 2.0]])


def test_midpoint_samples_and_their_normals() -> None:
    pts, normals = midpoint_samples([[0.0, 0.0], [0.0, 0.0], [0.0, 1.0]], 0.3)
    # 1 m in ceil(1 / 0.3) = 4 parts: their middles; the repeated vertex adds nothing
    np.testing.assert_allclose(pts, [[0.0, 0.125], [0.0, 0.375], [0.0, 0.625], [0.0, 0.875]], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(normals, np.tile([-1.0, 0.0], (4, 1)))  # the direction (0, 1) turned +90°
    pts, normals = midpoint_samples([[2.0, 1.0], [2.0, 1.0]], 0.3)
    np.testing.assert_array_equal(pts, [[2.0, 1.0]])
    np.testing.assert_array_equal(normals, [[1.0, 0.0]])
