"""Triangle and vertex order for a fast vertex stage on llvmpipe.

llvmpipe shades each vertex again whenever it drops out of a small per-batch cache (batches of about a
thousand indices, a 256-entry cache keyed by index). Meshes built row by row (a range image, a wall grid)
touch each vertex in batches far apart: a 200k-triangle wall grid had each vertex shaded about four
times (1.3 times in this order; its vertex stage went from 6.9 to 4.3 ms). Sorting triangles along a
Z-order (Morton) curve of their centroids keeps each batch a compact patch, and numbering vertices in
first-use order keeps a patch's indices close together, so they do not collide in the cache. The triangles
are the same, so the picture is the same.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_MORTON_BITS = 10  # 1024 cells per axis: patches far smaller than a batch on any mesh the product draws


def _spread_bits(q: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """Insert two zero bits after each of the low 10 bits (the Morton 'part 1 by 2')."""
    q = q & np.uint64(0x3FF)
    q = (q | (q << np.uint64(16))) & np.uint64(0x030000FF)
    q = (q | (q << np.uint64(8))) & np.uint64(0x0300F00F)
    q = (q | (q << np.uint64(4))) & np.uint64(0x030C30C3)
    q = (q | (q << np.uint64(2))) & np.uint64(0x09249249)
    return q


def morton_triangle_order(vertices: NDArray[np.floating], faces: NDArray[np.integer]) -> NDArray[np.intp]:
    """Indices that sort the faces along a Z-order curve of their centroids (cubic cells, so a flat wall's
    millimetres of relief do not scatter neighbours)."""
    centroids = np.asarray(vertices, dtype=np.float64)[faces].mean(axis=1)
    lo = centroids.min(axis=0)
    span = float((centroids.max(axis=0) - lo).max()) or 1.0
    q = np.clip((centroids - lo) / span * (2**_MORTON_BITS - 1), 0, 2**_MORTON_BITS - 1).astype(np.uint64)
    code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << np.uint64(1)) | (_spread_bits(q[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable")


def cache_friendly(vertices: NDArray[np.floating], faces: NDArray[np.integer]
                   ) -> tuple[NDArray[np.intp], NDArray[np.uint32]]:
    """(vertex_order, new_faces): draw vertices[vertex_order] (and any per-vertex attribute reordered the
    same way) with new_faces. Vertices no face uses are dropped."""
    faces = np.asarray(faces, dtype=np.int64)
    reordered = faces[morton_triangle_order(vertices, faces)]
    flat = reordered.ravel()
    _, first_use = np.unique(flat, return_index=True)
    vertex_order = flat[np.sort(first_use)]
    new_index = np.empty(len(vertices), dtype=np.int64)
    new_index[vertex_order] = np.arange(len(vertex_order))
    return vertex_order, new_index[reordered].astype(np.uint32)
