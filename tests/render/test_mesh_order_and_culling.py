"""The renderer's speed-ups change nothing in the picture: reordering keeps every triangle, culling only drops
chunks that cannot show, and a culled render equals an unculled one pixel for pixel."""

from __future__ import annotations

import moderngl
import numpy as np
import pytest

from geometry import Intrinsics, look_at
from render import MeshRenderer
from render.culling import CHUNK_TRIANGLES, ChunkBounds
from render.projection import projection_matrix, view_matrix
from render.sample_wall import sample_wall_mesh
from render.vertex_order import cache_friendly, morton_triangle_order

INTR = Intrinsics(fx=700.0, fy=700.0, cx=300.0, cy=180.0, width=640, height=400)


def _triangle_set(vertices: np.ndarray, faces: np.ndarray) -> set[tuple[float, ...]]:
    """Each triangle as its three corners, rotated to start at the smallest (winding kept)."""
    out = set()
    for tri in np.asarray(vertices)[faces]:
        corners = [tuple(c) for c in tri]
        k = corners.index(min(corners))
        out.add(tuple(np.concatenate(corners[k:] + corners[:k])))
    return out


def test_cache_friendly_order_keeps_every_triangle_and_its_winding() -> None:
    rng = np.random.default_rng(3)
    vertices = rng.uniform(-1, 1, (400, 3))
    faces = rng.integers(0, 350, (900, 3))  # vertices 350..399 are unused
    vertex_order, new_faces = cache_friendly(vertices, faces)
    assert sorted(vertex_order.tolist()) == sorted(set(faces.ravel().tolist()))
    assert _triangle_set(vertices[vertex_order], new_faces) == _triangle_set(vertices, faces)


def test_morton_order_keeps_consecutive_triangles_close() -> None:
    mesh = sample_wall_mesh(grid=60, texture_px=1024)
    faces = np.asarray(mesh.faces)
    centroids = mesh.triangles_center
    row_order_step = np.linalg.norm(np.diff(centroids, axis=0), axis=1)
    morton_step = np.linalg.norm(np.diff(centroids[morton_triangle_order(mesh.vertices, faces)], axis=0), axis=1)
    # A row-major grid jumps across the whole wall at the end of every row; along the Z-order curve the
    # jumps are rare and short, and the mean step between consecutive triangles halves.
    assert np.percentile(morton_step, 99.5) < 0.2 * np.percentile(row_order_step, 99.5)
    assert morton_step.mean() < 0.6 * row_order_step.mean()


def _clip(T_world_from_camera: np.ndarray) -> np.ndarray:
    return projection_matrix(INTR, 0.1, 10.0) @ view_matrix(T_world_from_camera)


def test_culling_keeps_every_triangle_that_lands_in_the_image() -> None:
    mesh = sample_wall_mesh(grid=120, texture_px=1024)
    vertex_order, faces = cache_friendly(mesh.vertices, mesh.faces)
    vertices = np.asarray(mesh.vertices)[vertex_order]
    chunks = ChunkBounds.of(vertices, faces)
    T = look_at([0.4, 0.5, 0.9], [0.3, 0.6, 0.0], up=[0, 1, 0])  # sees the wall's lower-left part
    kept = np.zeros(len(faces), dtype=bool)
    for first, count in chunks.visible_ranges(_clip(T)):
        kept[first:first + count] = True
    cam = (np.linalg.inv(T) @ np.column_stack([vertices, np.ones(len(vertices))]).T).T[:, :3]
    uv = INTR.project(cam)
    on_image = ((uv[:, 0] >= 0) & (uv[:, 0] < INTR.width) & (uv[:, 1] >= 0) & (uv[:, 1] < INTR.height)
                & (cam[:, 2] > 0))
    lands = on_image[faces].any(axis=1)
    assert lands.any()
    assert kept[lands].all()
    assert kept.mean() < 0.5  # and most of the wall, out of view, is not drawn (most: over half)
    away = look_at([1.0, 1.0, 1.5], [1.0, 1.0, 3.0], up=[0, 1, 0])  # looking away from the wall
    assert chunks.visible_ranges(_clip(away)) == []


def test_ranges_cover_whole_chunks_and_the_last_partial_one() -> None:
    mesh = sample_wall_mesh(grid=40, texture_px=1024)
    faces = np.asarray(mesh.faces)
    chunks = ChunkBounds.of(mesh.vertices, faces)
    T = look_at([1.25, 1.0, 4.0], [1.25, 1.0, 0.0], up=[0, 1, 0])  # the whole wall in view
    assert chunks.visible_ranges(_clip(T)) == [(0, len(faces))]
    assert len(chunks.lo) == -(-len(faces) // CHUNK_TRIANGLES)


@pytest.mark.gl
def test_a_culled_render_equals_an_unculled_one(gl_context: moderngl.Context) -> None:
    mesh = sample_wall_mesh(grid=160, texture_px=1024)
    T = look_at([0.7, 0.4, 0.8], [0.5, 0.6, 0.0], up=[0, 1, 0])
    with MeshRenderer(ctx=gl_context) as renderer:
        renderer.set_mesh(mesh)
        culled = renderer.render(INTR, T, depth=True)
        geometry = renderer._items[0].geometry
        drawn = sum(count for _, count in geometry.chunks.visible_ranges(
            np.diag([1.0, -1.0, 1.0, 1.0]) @ _clip(T)))
        assert drawn == renderer.triangles_drawn
        assert drawn < 0.5 * len(mesh.faces)  # culling leaves most of the wall undrawn (this view sees a corner)
        n_chunks = len(geometry.chunks.lo)
        geometry.chunks = ChunkBounds(lo=np.full((n_chunks, 3), -1e9), hi=np.full((n_chunks, 3), 1e9),
                                  n_faces=len(mesh.faces))  # every chunk in view: everything drawn
        unculled = renderer.render(INTR, T, depth=True)
        assert renderer.triangles_drawn == len(mesh.faces)
    assert (culled.color == unculled.color).all()
    np.testing.assert_array_equal(culled.depth, unculled.depth)
    assert (culled.color[..., :3] > 0).mean() > 0.9  # the wall fills the view
