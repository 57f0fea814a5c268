"""Line and plane fits: least squares through points, and the RANSAC loop that finds the points to fit.

RANSAC is three shared steps; each caller brings its model (a line, a plane, a plane seen by stereo transfer
error, a line of step edges) and its rule for which points agree with it:

1. `draw_samples`: minimal samples of point indices from the caller's seeded Generator. The two ways of
   drawing give different random streams, and each caller keeps the one its seeded results were measured with.
2. `best_hypothesis`: the caller turns the samples into hypotheses and scores them (how many points agree, in
   chunks where a score matrix would be large); the first hypothesis with the most support wins.
3. `refine`: least squares on the inliers and re-collecting them, for a few rounds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

Model = TypeVar("Model")
Inliers = TypeVar("Inliers", NDArray[np.bool_], NDArray[np.int64])


def principal_axes(points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(centroid (d,), axes (d, d)) of points (n, d): the rows of axes are unit directions by decreasing spread
    of the points along them (the SVD of the centred points)."""
    p = np.asarray(points, dtype=np.float64)
    centroid = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - centroid, full_matrices=False)
    return centroid, vt


def fit_line(points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(centroid (d,), unit direction (d,)) of the total-least-squares line through points (n >= 2, d)."""
    centroid, axes = principal_axes(points)
    return centroid, axes[0]


def fit_plane(points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(centroid (3,), unit normal (3,)) of the least-squares plane through points (n >= 3, 3)."""
    centroid, axes = principal_axes(points)
    return centroid, axes[-1]


def draw_samples(rng: np.random.Generator, n: int, size: int, iterations: int, distinct: bool = False,
                 by_column: bool = False) -> NDArray[np.int64]:
    """Minimal samples (iterations, size) of indices into n points.

    distinct: `size` different indices per sample (one rng.choice without replacement per sample, in order);
    otherwise indices drawn independently in one rng.integers call (a sample may repeat a point: the caller's
    hypothesis rejects degenerate ones), row by row, or column by column with by_column (all samples' first
    index, then all their second ...)."""
    if distinct:
        return np.array([rng.choice(n, size, replace=False) for _ in range(iterations)],
                        dtype=np.int64).reshape(iterations, size)
    if by_column:
        return rng.integers(0, n, size=(size, iterations)).T
    return rng.integers(0, n, size=(iterations, size))


def best_hypothesis(count: int, score: Callable[[slice], ArrayLike], chunk: int | None = None) -> int:
    """Index of the best of `count` >= 1 hypotheses: score(slice) gives the support (e.g. inlier counts) of the
    hypotheses in that slice, called for consecutive slices of `chunk` (all at once by default); the first of
    equally supported hypotheses wins."""
    if count < 1:
        raise ValueError("best_hypothesis needs at least one hypothesis")
    step = count if chunk is None else chunk
    support = np.concatenate([np.asarray(score(slice(s, s + step))).ravel() for s in range(0, count, step)])
    return int(np.argmax(support))


def _size(inliers: NDArray[np.bool_] | NDArray[np.int64]) -> int:
    return int(inliers.sum()) if inliers.dtype == np.bool_ else len(inliers)


def refine(inliers: Inliers, refit: Callable[[Inliers], tuple[Model, Inliers]], rounds: int,
           min_inliers: int = 0) -> tuple[Model | None, Inliers]:
    """Alternate a least-squares fit and re-collecting its inliers: `rounds` times, refit(inliers) fits the model
    to the inliers (a mask or indices) and returns (model, the points that agree with it). Stops early when
    fewer than min_inliers remain. Returns (the last model or None if none was fitted, the last inliers)."""
    model = None
    for _ in range(rounds):
        if _size(inliers) < min_inliers:
            break
        model, inliers = refit(inliers)
    return model, inliers
