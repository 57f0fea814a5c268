"""Line and plane fits on exact points, RANSAC's pieces, and the random streams the seeded fits rely on."""

import numpy as np
import pytest

from geometry.robust import best_hypothesis, draw_samples, fit_line, fit_plane, principal_axes, refine


def test_fits_recover_an_exact_line_and_plane() -> None:
    rng = np.random.default_rng(0)
    direction = np.array([3.0, 4.0, 12.0]) / 13.0
    line = np.array([1.0, -2.0, 0.5]) + rng.uniform(-2, 2, (30, 1)) * direction
    c, u = fit_line(line)
    # exact points: float64 round-off of metre-scale coordinates, ~1e-15
    np.testing.assert_allclose(c, line.mean(axis=0), rtol=0, atol=1e-12)
    assert abs(abs(float(u @ direction)) - 1.0) < 1e-12
    normal = np.array([2.0, -1.0, 2.0]) / 3.0
    a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    plane = 1.5 * normal + rng.uniform(-1, 1, (40, 1)) * a + rng.uniform(-1, 1, (40, 1)) * b
    c, n = fit_plane(plane)
    assert abs(abs(float(n @ normal)) - 1.0) < 1e-12 and abs(abs(float(n @ c)) - 1.5) < 1e-12


def test_principal_axes_come_by_decreasing_spread() -> None:
    rng = np.random.default_rng(1)
    p = rng.normal(size=(500, 3)) * [3.0, 0.1, 1.0]
    _, axes = principal_axes(p)
    np.testing.assert_allclose(np.abs(axes), np.eye(3)[[0, 2, 1]], atol=0.05)  # 500 samples: axes within ~1°


def test_the_sampling_streams_are_the_ones_the_seeded_fits_were_measured_with() -> None:
    n, size, iterations = 37, 3, 50
    rows = draw_samples(np.random.default_rng(7), n, size, iterations)
    np.testing.assert_array_equal(rows, np.random.default_rng(7).integers(0, n, size=(iterations, size)))
    # by column: one rng.integers call of `iterations` per position, as two separate calls drew them
    rng = np.random.default_rng(7)
    columns = np.column_stack([rng.integers(0, n, iterations) for _ in range(size)])
    np.testing.assert_array_equal(draw_samples(np.random.default_rng(7), n, size, iterations, by_column=True),
                                  columns)
    rng = np.random.default_rng(7)
    distinct = np.array([rng.choice(n, size, replace=False) for _ in range(iterations)])
    got = draw_samples(np.random.default_rng(7), n, size, iterations, distinct=True)
    np.testing.assert_array_equal(got, distinct)
    assert all(len(set(row)) == size for row in got.tolist())


def test_best_hypothesis_takes_the_first_of_the_most_supported_in_any_chunking() -> None:
    support = np.array([3, 9, 2, 9, 1, 9, 0])
    calls = []

    def score(h: slice) -> np.ndarray:
        calls.append((h.start, h.stop))
        return support[h]

    assert best_hypothesis(len(support), score) == 1 and calls == [(0, 7)]
    calls.clear()
    assert best_hypothesis(len(support), score, chunk=3) == 1 and calls == [(0, 3), (3, 6), (6, 9)]
    with pytest.raises(ValueError, match="at least one"):
        best_hypothesis(0, score)


def test_refine_alternates_fit_and_inliers_and_stops_when_too_few_remain() -> None:
    seen = []

    def drop_one(inliers: np.ndarray) -> tuple[int, np.ndarray]:
        seen.append(int(inliers.sum()))
        out = inliers.copy()
        out[np.flatnonzero(out)[0]] = False
        return len(seen), out

    model, inliers = refine(np.ones(5, bool), drop_one, rounds=3)
    assert (model, int(inliers.sum()), seen) == (3, 2, [5, 4, 3])
    seen.clear()
    model, inliers = refine(np.ones(5, bool), drop_one, rounds=10, min_inliers=3)
    assert (model, int(inliers.sum()), seen) == (3, 2, [5, 4, 3])
    model, indices = refine(np.array([4, 7]), lambda i: ("never", i), rounds=2, min_inliers=3)
    assert model is None and indices.tolist() == [4, 7]  # index arrays count by length


def test_the_pieces_make_a_ransac_line_that_ignores_outliers() -> None:
    rng = np.random.default_rng(3)
    t = rng.uniform(-1, 1, 60)
    on_line = np.column_stack([t, 0.5 * t + 0.2]) + rng.normal(0, 0.001, (60, 2))
    points = np.vstack([on_line, rng.uniform(-1, 1, (40, 2))])
    pairs = draw_samples(rng, len(points), 2, 100, distinct=True)
    a, b = points[pairs[:, 0]], points[pairs[:, 1]]
    n = np.column_stack([a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    dist = np.abs(np.einsum("hj,hnj->hn", n, points[None] - a[:, None]))
    best = best_hypothesis(len(n), lambda h: (dist[h] < 0.005).sum(axis=1))

    def refit(inl: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
        c, u = fit_line(points[inl])
        return (c, u), np.abs((points - c) @ np.array([-u[1], u[0]])) < 0.005

    (c, u), inl = refine(dist[best] < 0.005, refit, rounds=2)
    assert inl[:60].all() and inl[60:].sum() <= 2  # a few of 40 random points may fall within 5 mm of it
    # 60 points with 1 mm noise over 2 m: slope within a few thousandths, offset within a millimetre or so
    assert u[1] / u[0] == pytest.approx(0.5, abs=0.005) and c[1] - 0.5 * c[0] == pytest.approx(0.2, abs=0.002)
