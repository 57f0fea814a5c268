"""Polylines in the plane: distance of points to one, its length, and points along it.

A polyline is a (k, 2) float64 array of vertices in metres (wall coordinates), k >= 1; a single vertex is a point.
Segments may have zero length (repeated vertices): they count as their end point.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray


def nearest_segments(points: ArrayLike, polyline: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """(distance (n,) of each point (n, 2) to the polyline (k, 2), index (n,) of the nearest segment), metres.

    Segment i joins vertices i and i + 1; of equally near segments the first wins. A single-vertex polyline has
    no segment: the distances are to its point and the indices 0. One loop over segments keeps the memory at
    O(n) however long the polyline is.
    """
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    polyline = np.atleast_2d(np.asarray(polyline, dtype=np.float64))
    if len(polyline) == 1:
        return np.linalg.norm(points - polyline[0], axis=1), np.zeros(len(points), np.int64)
    best = np.full(len(points), np.inf)
    index = np.zeros(len(points), np.int64)
    for i, (a, b) in enumerate(itertools.pairwise(polyline)):
        ab = b - a
        t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-18), 0.0, 1.0)
        d = np.linalg.norm(points - (a + t[:, None] * ab), axis=1)
        index[d < best] = i
        best = np.minimum(best, d)  # NaN points stay NaN
    return best, index


def distances_to_polyline(points: ArrayLike, polyline: ArrayLike) -> NDArray[np.float64]:
    """Distance (n,) of each point (n, 2) to a polyline (k, 2), metres."""
    return nearest_segments(points, polyline)[0]


def polyline_length(polyline: ArrayLike) -> float:
    """Length (metres) of a polyline (k, 2); 0 for a single point."""
    p = np.asarray(polyline, dtype=np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def densify(polyline: ArrayLike, step_m: float) -> NDArray[np.float64]:
    """The polyline's vertices and points between them, consecutive points at most step_m apart, (m, 2).

    Each segment is cut into equal parts; the first vertex is kept, so a single point stays itself."""
    p = np.asarray(polyline, dtype=np.float64)
    out = [p[:1]]
    for a, b in itertools.pairwise(p):
        n = max(1, math.ceil(np.linalg.norm(b - a) / step_m))
        t = np.linspace(0, 1, n + 1)[1:, None]
        out.append(a + t * (b - a))
    return np.concatenate(out)


def midpoint_samples(polyline: ArrayLike, step_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points along a polyline at the middles of equal parts at most step_m long, and the unit normal (the
    segment's direction turned +90°) at each, (m, 2) each. Zero-length segments give none; a polyline without
    length gives its first vertex and the normal (1, 0)."""
    p = np.asarray(polyline, dtype=np.float64)
    pts, normals = [], []
    for a, b in itertools.pairwise(p):
        d = b - a
        length = float(np.linalg.norm(d))
        if length < 1e-9:
            continue
        n = max(1, int(np.ceil(length / step_m)))
        t = (np.arange(n) + 0.5) / n
        pts.append(a + t[:, None] * d)
        normals.append(np.repeat([[-d[1] / length, d[0] / length]], n, axis=0))
    if not pts:
        return p[:1], np.array([[1.0, 0.0]])
    return np.vstack(pts), np.vstack(normals)
