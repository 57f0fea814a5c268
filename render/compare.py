"""How far apart two renders of the same view are: texture edges, depth, coverage, grey levels.

Used to prove that a simplified mesh draws the picture of the full one (tests) and to print the difference
beside the frame times (`arproj bench render`). Texture edges are located to a fraction of a pixel where the
grey level crosses fixed levels between two neighbouring pixels, along rows and along columns; each edge of
the first picture is looked for in the same row (column) of the second, with the same direction, within a
pixel. An edge that is not found there counts as moved by infinity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

EDGE_LEVELS = (64.0, 128.0, 192.0)  # grey levels whose crossings mark texture edges
# Only steep crossings are edges: a step of this many grey levels between neighbours puts an 8-bit value's
# rounding (half a level) at ≤ 0.02 px of the position.
EDGE_MIN_STEP = 24.0
EDGE_SEARCH_PX = 1.0  # how far an edge is looked for in the other picture
# A crossing whose pixels lie this close to the level is not an edge of the first picture: a grey level or two
# of difference would move it to the next pixel pair (X-junctions of a checker have such pixels).
EDGE_LEVEL_MARGIN = 4.0


@dataclass(frozen=True)
class PictureDifference:
    """edge_shift_px: largest shift of a texture edge (inf: an edge vanished); edge_shift_p99_px: its 99th
    percentile; edges: how many were compared; depth_mm: largest depth difference where both drew;
    coverage_px: pixels drawn in one picture only; max_grey: largest grey-level difference of a pixel;
    grey_over_16: fraction of pixels more than 16 grey levels apart."""

    edge_shift_px: float
    edge_shift_p99_px: float
    edges: int
    depth_mm: float
    coverage_px: int
    max_grey: int
    grey_over_16: float


def _grey(color: NDArray[np.uint8]) -> NDArray[np.float64]:
    return np.asarray(color, dtype=np.float64)[..., :3].mean(axis=2)


def _crossings(g: NDArray[np.float64], level: float, min_step: float, margin: float
               ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int8]]:
    """Crossings of level along each row of g: (row, sub-pixel column, direction ±1)."""
    a, b = g[:, :-1], g[:, 1:]
    step = b - a
    cross = ((a < level) & (b >= level)) | ((a >= level) & (b < level))
    cross &= (np.abs(step) >= min_step) & (np.abs(a - level) >= margin) & (np.abs(b - level) >= margin)
    rows, cols = np.nonzero(cross)
    pos = cols + (level - a[rows, cols]) / step[rows, cols]
    return rows, pos, np.sign(step[rows, cols]).astype(np.int8)


def _row_shifts(ga: NDArray[np.float64], gb: NDArray[np.float64]) -> NDArray[np.float64]:
    """For every steep crossing of ga, the distance to the same crossing in gb (inf when there is none)."""
    out = []
    for level in EDGE_LEVELS:
        ra, pa, sa = _crossings(ga, level, EDGE_MIN_STEP, EDGE_LEVEL_MARGIN)
        rb, pb, sb = _crossings(gb, level, 1e-9, 0.0)
        if len(ra) == 0:
            continue
        # Sort b's crossings by (row, direction, position) and search each of a's among its own row/direction.
        key_b = (rb.astype(np.int64) * 2 + (sb > 0)) * (gb.shape[1] + 1)
        order = np.lexsort((pb, key_b))
        sorted_key = key_b[order] + pb[order]
        key_a = (ra.astype(np.int64) * 2 + (sa > 0)) * (ga.shape[1] + 1) + pa
        i = np.searchsorted(sorted_key, key_a)
        best = np.full(len(ra), np.inf)
        for j in (i - 1, i):
            ok = (j >= 0) & (j < len(sorted_key))
            d = np.full(len(ra), np.inf)
            d[ok] = np.abs(sorted_key[j[ok]] - key_a[ok])
            best = np.minimum(best, d)
        best[best > EDGE_SEARCH_PX] = np.inf
        out.append(best)
    return np.concatenate(out) if out else np.zeros(0)


def picture_difference(color_a: NDArray[np.uint8], color_b: NDArray[np.uint8],
                       depth_a: NDArray[np.float32] | None = None, depth_b: NDArray[np.float32] | None = None
                       ) -> PictureDifference:
    """The difference of picture b from picture a (same size; depth in metres, NaN where nothing was drawn)."""
    ga, gb = _grey(color_a), _grey(color_b)
    shifts = np.concatenate([_row_shifts(ga, gb), _row_shifts(ga.T, gb.T)])
    grey = np.abs(ga - gb)
    depth_mm, coverage = 0.0, 0
    if depth_a is not None and depth_b is not None:
        fa, fb = np.isfinite(depth_a), np.isfinite(depth_b)
        coverage = int(np.sum(fa != fb))
        both = fa & fb
        if both.any():
            depth_mm = float(np.max(np.abs(depth_a[both].astype(np.float64) - depth_b[both])) * 1e3)
    return PictureDifference(
        edge_shift_px=float(shifts.max()) if len(shifts) else 0.0,
        edge_shift_p99_px=float(np.percentile(shifts, 99, method="nearest")) if len(shifts) else 0.0,
        edges=len(shifts), depth_mm=depth_mm, coverage_px=coverage, max_grey=int(np.round(grey.max())),
        grey_over_16=float(np.mean(grey > 16)))
