"""View-frustum culling of triangle chunks, on the CPU before drawing.

A projector sees part of the wall map: in the benchmark's view, about 40 % of the wall's triangles. On
llvmpipe every triangle handed to GL costs vertex shading and setup on one thread even when it lands
off-screen, so chunks of the (Morton-ordered, hence spatially compact) index buffer whose bounding box
lies wholly outside the view are not drawn at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

CHUNK_TRIANGLES = 1024  # ~200 chunks for a 200k-triangle wall: a test of a few microseconds each


@dataclass(frozen=True)
class ChunkBounds:
    """Axis-aligned boxes of consecutive runs of CHUNK_TRIANGLES faces (in draw order)."""

    lo: NDArray[np.float64]  # (n_chunks, 3)
    hi: NDArray[np.float64]
    n_faces: int

    @classmethod
    def of(cls, vertices: NDArray[np.floating], faces: NDArray[np.integer]) -> ChunkBounds:
        corners = np.asarray(vertices, dtype=np.float64)[faces]  # (n_faces, 3, 3)
        starts = np.arange(0, len(faces), CHUNK_TRIANGLES)
        lo = np.minimum.reduceat(corners.min(axis=1), starts, axis=0)
        hi = np.maximum.reduceat(corners.max(axis=1), starts, axis=0)
        return cls(lo, hi, len(faces))

    def visible_ranges(self, clip_from_world: NDArray[np.float64]) -> list[tuple[int, int]]:
        """(first_face, n_faces) runs to draw: every chunk not wholly outside one plane of the clip volume
        (conservative: a chunk that may show is always drawn)."""
        lo, hi = self.lo, self.hi
        corners = np.stack([np.column_stack([(hi if i & 1 else lo)[:, 0], (hi if i & 2 else lo)[:, 1],
                                             (hi if i & 4 else lo)[:, 2], np.ones(len(lo))]) for i in range(8)],
                           axis=1)  # (n, 8, 4)
        clip = corners @ np.asarray(clip_from_world, dtype=np.float64).T
        xyz, w = clip[..., :3], clip[..., 3:]
        outside = np.any((xyz > w).all(axis=1) | (xyz < -w).all(axis=1), axis=1)
        visible = np.flatnonzero(~outside)
        if len(visible) == 0:
            return []
        # Merge neighbouring chunks into one draw call each.
        breaks = np.flatnonzero(np.diff(visible) > 1)
        run_starts = np.concatenate([[visible[0]], visible[breaks + 1]])
        run_ends = np.concatenate([visible[breaks], [visible[-1]]]) + 1
        return [(int(s) * CHUNK_TRIANGLES, int(min(e * CHUNK_TRIANGLES, self.n_faces) - s * CHUNK_TRIANGLES))
                for s, e in zip(run_starts, run_ends, strict=True)]
