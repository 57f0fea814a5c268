"""Simplifying a mesh at upload to what the projector can resolve.

A wall map's mesh is far finer than a projector pixel: at 2 m a 1280-pixel projector's pixel is over a
millimetre wide, and llvmpipe pays for every triangle. A mesh whose picture lies within a tenth of a pixel of
the full one's is the same picture, drawn from a few thousand triangles.

How. fast_simplification (the quadric decimation trimesh calls) runs once to the end and records its edge
collapses, cheapest first; replaying a prefix of them (its own replay, the same positions it chose) gives the
mesh it had at that point, with no triangle flipped (it checks). Open borders are kept vertex for vertex
(`preserve_border`): the wall's outline and holes, and UV seams (a seam is a border of the index buffer, its
vertices duplicated), do not move. A moved vertex takes the UV of the full surface at its position, so the
texture stays painted where it was. The prefix is the longest whose *measured* deviation stays within the
bound: every full-mesh vertex is looked up by its UV on the simplified mesh, and the distance from where the
simplified mesh draws that texture point to where the full mesh has it is the error, in metres — it holds
the surface's deviation (depth) and the texture's (edges) in one number. Meshes without UVs are drawn in full.

The bound (tolerance_m): from the intrinsics and the nearest depth the mesh is seen from, the deviation that
moves no image point by more than PROJECTED_ERROR_PX.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from dataclasses import dataclass

import fast_simplification  # type: ignore[import-untyped]  # no type information shipped
import numpy as np
from fast_simplification import _replay
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from geometry.intrinsics import Intrinsics

PROJECTED_ERROR_PX = 0.1  # the fraction of a projector pixel the simplified picture may differ by
# The search stops when the face counts of the last prefix within the bound and the first beyond it are this
# close: at most 5 % more triangles than the least possible. (1.15 drew 4-6 % more triangles on the benchmark's
# wall, each frame, to save two or three prefix measurements once, at upload.)
SEARCH_RATIO = 1.05
# Barycentric slack for "inside a triangle" in UV: points on a shared edge or vertex are found in either.
_INSIDE_EPS = 1e-9
_MAX_GRID = 1024  # cells per side of the UV lookup grid
# Tolerances are rounded down to this ladder (19 % steps), so views a little apart share one simplified mesh.
_LADDER_STEP = 2.0 ** 0.25
_CACHED_MESHES = 4  # collapse histories kept for meshes uploaded again (a new texture on the same wall)
# fast_simplification collapses, pass after pass (100 at most), every edge whose quadric error (a squared
# distance, in the units of the positions given) is below 1e-9 · (pass + 3)^agg. At its default agg = 7 on a mesh
# in metres the first pass's threshold is (1.5 mm)²: every collapse finer than that happens in that one pass, in
# index order rather than cheapest first, and a prefix within a sub-millimetre bound ends at the first collapse
# that overshoots it (the benchmark's wall: 3-7x the triangles within 0.02-0.2 mm). With agg = 3 and positions
# scaled so that the first threshold is (_FIRST_PASS_M)², the passes run from 0.01 mm to 2 mm of error, cheapest
# first, over the bounds projectors need (about 0.01 mm at 0.3 m to 0.5 mm at 5 m).
_DECIMATION_AGG = 3.0
_FIRST_PASS_M = 1e-5
_DECIMATION_SCALE = math.sqrt(1e-9 * 3.0 ** _DECIMATION_AGG) / _FIRST_PASS_M


def _slope(intr: Intrinsics) -> float:
    """sqrt(1 + tan²θ) for the image corner farthest off the optical axis (at the pixels' outer edges)."""
    a = (np.array([-0.5, intr.width - 0.5]) - intr.cx) / intr.fx
    b = (np.array([-0.5, intr.height - 0.5]) - intr.cy) / intr.fy
    return float(np.sqrt(1.0 + np.max(a ** 2) + np.max(b ** 2)))


def tolerance_m(intr: Intrinsics, nearest_m: float, max_error_px: float = PROJECTED_ERROR_PX) -> float:
    """The largest deviation (metres, any direction) of the surface or of a texture point that moves no image
    point by more than max_error_px, seen through intr from depth ≥ nearest_m (along the optical axis).

    A point at depth z, θ off the axis, moved by δ moves in the image by at most max(fx, fy) / z ·
    sqrt(1 + tan²θ) · |δ| (the largest singular value of the pinhole projection's Jacobian).
    """
    return max_error_px * nearest_m / (max(intr.fx, intr.fy) * _slope(intr))


def projected_error_px(intr: Intrinsics, nearest_m: float, deviation_m: float) -> float:
    """The image error bound (pixels) of a deviation deviation_m seen through intr from depth ≥ nearest_m."""
    return deviation_m * max(intr.fx, intr.fy) * _slope(intr) / nearest_m


def ladder_floor(tol_m: float) -> float:
    """tol_m rounded down to the ladder of tolerances (powers of 2^(1/4) metres)."""
    return float(_LADDER_STEP ** math.floor(math.log(tol_m, _LADDER_STEP) + 1e-9))


@dataclass(frozen=True)
class Simplified:
    """A simplified mesh: positions (n, 3), UVs (n, 2), faces (m, 3) into them; source (n,) the full mesh's
    vertex each one stands for (for other per-vertex attributes); deviation_m, the measured error."""

    positions: NDArray[np.float64]
    uv: NDArray[np.float64]
    faces: NDArray[np.int64]
    source: NDArray[np.int64]
    deviation_m: float
    tolerance_m: float


def geometry_key(vertices: NDArray, faces: NDArray, uv: NDArray | None) -> bytes:
    """Digest of what the simplification depends on: a new texture on the same mesh reuses its result."""
    h = hashlib.blake2b(digest_size=16)
    for a in (vertices, faces, uv):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    return h.digest()


_decimations: OrderedDict[bytes, Decimation] = OrderedDict()


def decimation_of(vertices: NDArray[np.floating], faces: NDArray[np.integer], uv: NDArray[np.floating]
                  ) -> Decimation:
    """The Decimation of this geometry, from a small cache: one collapse history per mesh, whoever uploads it."""
    key = geometry_key(np.asarray(vertices), np.asarray(faces), np.asarray(uv))
    if key in _decimations:
        _decimations.move_to_end(key)
        return _decimations[key]
    decimation = Decimation(vertices, faces, uv)
    _decimations[key] = decimation
    while len(_decimations) > _CACHED_MESHES:
        _decimations.popitem(last=False)
    return decimation


class Decimation:
    """One mesh's collapse history (computed once, on construction) and its prefixes within tolerances.

    vertices (n, 3) float64 metres, faces (m, 3), uv (n, 2).
    """

    def __init__(self, vertices: NDArray[np.floating], faces: NDArray[np.integer], uv: NDArray[np.floating]
                 ) -> None:
        # Weld vertices equal in position and UV: a mesh stored one triangle at a time (every edge a border)
        # would otherwise keep every vertex. Vertices that differ in UV (a seam) stay apart.
        v_in, uv_in = np.asarray(vertices, dtype=np.float64), np.asarray(uv, dtype=np.float64)
        _, first, inverse = np.unique(np.hstack([v_in, uv_in]), axis=0, return_index=True, return_inverse=True)
        f = inverse.ravel()[np.asarray(faces, dtype=np.int64)]
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        self._original = first  # welded vertex → a vertex of the mesh given
        self.vertices: NDArray[np.float64] = np.ascontiguousarray(v_in[first])
        self.faces = np.ascontiguousarray(f, dtype=np.int32)
        self.uv: NDArray[np.float64] = uv_in[first]
        used = np.zeros(len(self.vertices), dtype=bool)
        used[self.faces.ravel()] = True
        self._used = np.flatnonzero(used)
        self._tree = cKDTree(self.vertices[self._used])
        self._vertex_faces = _incidence(self.faces, len(self.vertices))
        # Decimated and replayed in scaled units (see _DECIMATION_SCALE); positions come back in metres.
        self._scaled = np.ascontiguousarray(self.vertices * _DECIMATION_SCALE)
        if len(self.faces) > 1:
            _, _, collapses = fast_simplification.simplify(self._scaled, self.faces, target_count=1,
                                                           agg=_DECIMATION_AGG, preserve_border=True,
                                                           return_collapses=True)
            self.collapses = np.ascontiguousarray(np.asarray(collapses, dtype=np.int32).reshape(-1, 2))
        else:
            self.collapses = np.zeros((0, 2), dtype=np.int32)
        self._cache: dict[float, Simplified] = {}

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    # -- one prefix ------------------------------------------------------------------------------------
    def prefix(self, k: int) -> Simplified:
        """The mesh after fast_simplification's first k collapses, with UVs, and its measured deviation."""
        v = self.vertices
        if k == 0:
            kept = self._used
            index = np.full(len(v), -1, dtype=np.int64)
            index[kept] = np.arange(len(kept))
            return Simplified(v[kept], self.uv[kept], index[self.faces], self._original[kept], 0.0, 0.0)
        c = self.collapses[:k]
        # Positions: fast_simplification's own replay of these collapses (the point each merge moved to).
        _replay.load_int32(len(v), len(self.faces), len(c), self._scaled, self.faces, np.ascontiguousarray(c))
        _replay.replay()
        alive = np.ones(len(v), dtype=bool)
        alive[c[:, 1]] = False
        replayed = np.empty_like(v)
        replayed[alive] = _replay.return_points() / _DECIMATION_SCALE
        positions = v.copy()  # the replay keeps float32 positions: only the merged-into vertices take them
        merged_into = np.unique(c[:, 0])
        positions[merged_into] = replayed[merged_into]
        # Faces: each vertex merged into the one that absorbed it last; faces that lost a corner are gone.
        parent = np.arange(len(v), dtype=np.int64)
        parent[c[:, 1]] = c[:, 0]
        while True:
            nxt = parent[parent]
            if np.array_equal(nxt, parent):
                break
            parent = nxt
        f = parent[self.faces]
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        kept = np.unique(f.ravel())
        index = np.full(len(v), -1, dtype=np.int64)
        index[kept] = np.arange(len(kept))
        faces = index[f]
        pos = positions[kept]
        # UVs: a vertex that did not move keeps its own; a moved one takes the full surface's at its position.
        moved = np.flatnonzero(np.any(pos != v[kept], axis=1))
        uv = self.uv[kept].copy()
        off_surface = np.zeros(len(kept))
        if len(moved):
            uv[moved], off_surface[moved] = self._surface_uv(pos[moved])
        deviation = max(float(off_surface.max()), self._texture_deviation(pos, uv, faces))
        return Simplified(pos, uv, faces, self._original[kept], deviation, 0.0)

    def _surface_uv(self, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """UV of the full surface at (or nearest to) each point, and the distance to it: among the triangles
        around the nearest full vertex (where the closest point lies on any mesh of sane triangles)."""
        _, nearest = self._tree.query(points)
        vertex = self._used[nearest]
        starts, counts = self._vertex_faces.ranges(vertex)
        q = np.repeat(np.arange(len(points)), counts)
        tri_idx = self._vertex_faces.faces[np.repeat(starts, counts) + _ramp(counts)]
        tri = self.vertices[self.faces[tri_idx]]
        closest, bary = _closest_on_triangles(tri, points[q])
        dist = np.linalg.norm(closest - points[q], axis=1)
        best = np.full(len(points), np.inf)
        np.minimum.at(best, q, dist)
        pick = np.empty(len(points), dtype=np.int64)
        is_best = dist <= best[q]
        pick[q[is_best]] = np.flatnonzero(is_best)
        uv = np.einsum("ij,ijk->ik", bary[pick], self.uv[self.faces[tri_idx[pick]]])
        return uv, best

    def _texture_deviation(self, pos: NDArray[np.float64], uv: NDArray[np.float64], faces: NDArray[np.int64]
                           ) -> float:
        """Largest distance, over the full mesh's vertices, from where the simplified mesh draws a vertex's
        UV to the vertex itself (inf if some UV falls in no simplified triangle: a fold in UV)."""
        points_uv = self.uv[self._used]
        tri_uv = uv[faces]
        hit, bary = _locate(tri_uv, points_uv)
        if np.any(hit < 0):
            return float("inf")
        drawn = np.einsum("ij,ijk->ik", bary, pos[faces[hit]])
        return float(np.linalg.norm(drawn - self.vertices[self._used], axis=1).max())

    # -- the search ------------------------------------------------------------------------------------
    def within(self, tol_m: float) -> Simplified:
        """The most simplified prefix whose measured deviation is ≤ tol_m (the full mesh when none is)."""
        if tol_m in self._cache:
            return self._cache[tol_m]
        n = len(self.collapses)
        faces_after = self.n_faces - 2 * np.arange(n + 1)  # an interior collapse removes two faces
        good: Simplified = self.prefix(0)
        good_k, bad_k = 0, n + 1
        # Start from the bracket an earlier search left: the error grows (nearly) monotonically with k.
        for t, s in self._cache.items():
            k = int(np.searchsorted(-faces_after, -len(s.faces)))
            if t <= tol_m and k > good_k:
                good_k, good = k, s
            if t > tol_m:
                bad_k = min(bad_k, k + 1)
        candidate = self.prefix(min(bad_k - 1, n)) if bad_k - 1 > good_k else None
        if candidate is not None and candidate.deviation_m <= tol_m:
            good_k, good = min(bad_k - 1, n), candidate
        elif candidate is not None:
            bad_k = min(bad_k - 1, n)
            while bad_k - good_k > 1:
                f_good, f_bad = max(faces_after[good_k], 1), max(faces_after[min(bad_k, n)], 1)
                if f_good / f_bad <= SEARCH_RATIO:
                    break
                k = int(np.clip(np.searchsorted(-faces_after, -np.sqrt(f_good * f_bad)), good_k + 1, bad_k - 1))
                s = self.prefix(k)
                if s.deviation_m <= tol_m:
                    good_k, good = k, s
                else:
                    bad_k = k
        result = Simplified(good.positions, good.uv, good.faces, good.source, good.deviation_m, tol_m)
        self._cache[tol_m] = result
        return result


@dataclass(frozen=True)
class _Incidence:
    """Faces around each vertex, CSR: faces[start[v]:start[v + 1]]."""

    start: NDArray[np.int64]
    faces: NDArray[np.int64]

    def ranges(self, vertices: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        return self.start[vertices], self.start[vertices + 1] - self.start[vertices]


def _incidence(faces: NDArray[np.integer], n_vertices: int) -> _Incidence:
    flat = faces.ravel()
    order = np.argsort(flat, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(flat, minlength=n_vertices))])
    return _Incidence(start, order // 3)


def _ramp(counts: NDArray[np.int64]) -> NDArray[np.int64]:
    """0..c-1 for each count c, concatenated."""
    return np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def _uv_area(tri_uv: NDArray[np.float64]) -> NDArray[np.float64]:
    e1, e2 = tri_uv[:, 1] - tri_uv[:, 0], tri_uv[:, 2] - tri_uv[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _barycentric_2d(tri: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 3) barycentric coordinates of points p (n, 2) in triangles tri (n, 3, 2); NaN for degenerate ones."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
        l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.column_stack([1.0 - l1 - l2, l1, l2])


def _locate(tri_uv: NDArray[np.float64], points: NDArray[np.float64]
            ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """For each 2-D point, a triangle containing it (-1 if none) and its barycentric coordinates there.

    Triangles are binned by their bounding boxes in a uniform grid over the points' extent; each point is
    tested against the triangles of its cell only.
    """
    lo = np.minimum(points.min(axis=0), tri_uv.reshape(-1, 2).min(axis=0))
    hi = np.maximum(points.max(axis=0), tri_uv.reshape(-1, 2).max(axis=0))
    span = np.maximum(hi - lo, 1e-12)
    cells = int(np.clip(np.sqrt(len(tri_uv)), 1, _MAX_GRID))
    scale = cells / span

    def cell(xy: NDArray[np.float64]) -> NDArray[np.int64]:
        return np.clip(((xy - lo) * scale).astype(np.int64), 0, cells - 1)

    c0, c1 = cell(tri_uv.min(axis=1) - 1e-12), cell(tri_uv.max(axis=1) + 1e-12)
    nx, ny = c1[:, 0] - c0[:, 0] + 1, c1[:, 1] - c0[:, 1] + 1
    per_tri = nx * ny
    t = np.repeat(np.arange(len(tri_uv)), per_tri)
    r = _ramp(per_tri)
    cx = c0[t, 0] + r % nx[t]
    cy = c0[t, 1] + r // nx[t]
    key = cy * cells + cx
    order = np.argsort(key, kind="stable")
    key, t = key[order], t[order]
    start = np.searchsorted(key, np.arange(cells * cells + 1))
    pc = cell(points)
    pkey = pc[:, 1] * cells + pc[:, 0]
    s, counts = start[pkey], start[pkey + 1] - start[pkey]
    q = np.repeat(np.arange(len(points)), counts)
    cand = t[np.repeat(s, counts) + _ramp(counts)]
    bary = _barycentric_2d(tri_uv[cand], points[q])
    inside = np.all(bary >= -_INSIDE_EPS, axis=1)
    hit = np.full(len(points), -1, dtype=np.int64)
    out = np.zeros((len(points), 3))
    hit[q[inside]] = cand[inside]
    out[q[inside]] = bary[inside]
    return hit, out


def _closest_on_triangles(tri: NDArray[np.float64], p: NDArray[np.float64]
                          ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Closest point on each triangle (n, 3, 3) to each point (n, 3), and its barycentric coordinates
    (Ericson, Real-Time Collision Detection 5.1.5, vectorised)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        v_in, w_in = vb / den, vc / den
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    bary = np.column_stack([1.0 - v_in - w_in, v_in, w_in])
    # Regions, in Ericson's order of tests (the first that applies wins): later assignments are masked off.
    regions = [
        (d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d5 <= d4), (d6 >= 0) & (d5 <= d6),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
        (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0),
    ]
    values = [
        np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]),
        np.column_stack([1.0 - t_ab, t_ab, np.zeros_like(t_ab)]),
        np.column_stack([1.0 - t_ac, np.zeros_like(t_ac), t_ac]),
        np.column_stack([np.zeros_like(t_bc), 1.0 - t_bc, t_bc]),
    ]
    taken = np.zeros(len(p), dtype=bool)
    for mask, value in zip(regions, values, strict=True):
        m = mask & ~taken
        bary[m] = value if value.ndim == 1 else value[m]
        taken |= m
    closest = np.einsum("ij,ijk->ik", bary, tri)
    return closest, bary
