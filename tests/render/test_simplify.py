"""Simplifying at upload draws the picture of the full mesh: rendered on llvmpipe (EGL, headless) from several
poses, depth within 0.2 mm and texture edges within 0.1 px; and the same comparison fails when the bound is
loosened, so it can tell."""

from __future__ import annotations

import moderngl
import numpy as np
import pytest
import trimesh
from PIL import Image

from geometry import Intrinsics, look_at
from render import MeshRenderer
from render.compare import PictureDifference, picture_difference
from render.sample_wall import sample_wall_mesh
from render.simplify import PROJECTED_ERROR_PX, decimation_of, tolerance_m

# A projector with lens shift (the image above the optical axis), as the benchmark's, at a small size.
INTR = Intrinsics(fx=896.0, fy=896.0, cx=319.5, cy=392.0, width=640, height=400)
NEAREST_M = 0.7  # the nearest depth the poses below see the wall from
DEPTH_MM = 0.2
EDGE_PX = 0.1
POSES = {  # T_wall_from_projector, all seeing the wall from ≥ NEAREST_M
    "frontal": ([1.25, 1.0, 1.0], [1.25, 1.0, 0.0]),
    "oblique": ([2.0, 0.6, 0.95], [1.2, 1.0, 0.0]),
    "steep": ([2.1, 1.0, 0.85], [1.25, 1.0, 0.0]),  # 45° off the wall's normal, 65° at the image's far edge
    "corner_from_below": ([0.45, 0.1, 0.75], [0.25, 0.3, 0.0]),
}


def checker_wall() -> trimesh.Trimesh:
    """The benchmark's wall geometry (2 mm relief, 51,200 triangles) with a checker texture: sharp edges
    everywhere, and texels larger than a pixel in every view below, so that the texture is magnified (mip
    level 0) and what moves is the geometry and the UVs, not a mip level chosen from screen derivatives (a
    different level at a handful of edge pixels changes their grey, not where the edge is)."""
    mesh = sample_wall_mesh(grid=161, texture_px=1024)
    px, cells = 256, 16
    grey = ((np.indices((px, px)) // (px // cells)).sum(axis=0) % 2 * 215 + 20).astype(np.uint8)
    mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.visual.uv, image=Image.fromarray(np.dstack([grey] * 3)))
    return mesh


@pytest.fixture(scope="module")
def wall() -> trimesh.Trimesh:
    return checker_wall()


@pytest.fixture(scope="module")
def full_renders(gl_context: moderngl.Context, wall: trimesh.Trimesh) -> dict:
    with MeshRenderer(ctx=gl_context) as full:
        full.set_mesh(wall)
        return {name: full.render(INTR, look_at(*pose, up=[0, 1, 0]), depth=True) for name, pose in POSES.items()}


def failures(diff: PictureDifference) -> list[str]:
    """What keeps two renders from being the same picture (empty: they are)."""
    out = []
    if not diff.depth_mm <= DEPTH_MM:
        out.append(f"depth {diff.depth_mm:.3f} mm")
    if not diff.edge_shift_px <= EDGE_PX:
        out.append(f"texture edges moved {diff.edge_shift_px:.3f} px")
    if diff.coverage_px:
        out.append(f"{diff.coverage_px} pixels drawn in one picture only")
    return out


def test_the_bound_is_what_a_point_moved_that_far_moves_in_the_image() -> None:
    tol = tolerance_m(INTR, NEAREST_M)
    rng = np.random.default_rng(5)
    # points at the nearest depth over the whole image, moved by tol in random directions
    pixels = np.column_stack([rng.uniform(-0.5, INTR.width - 0.5, 2000), rng.uniform(-0.5, INTR.height - 0.5, 2000)])
    points = INTR.rays(pixels) * NEAREST_M / INTR.rays(pixels)[:, 2:]
    moves = rng.normal(size=(2000, 3))
    moves *= tol / np.linalg.norm(moves, axis=1, keepdims=True)
    shift = np.linalg.norm(INTR.project(points + moves) - INTR.project(points), axis=1)
    assert shift.max() <= PROJECTED_ERROR_PX * 1.001  # (first order: a 1e-4 relative step is second order)
    # and it is not loose: at the image corner farthest off the axis, moved along the projection's most
    # sensitive direction (its Jacobian's first right singular vector), a point moves by the whole bound
    corner = INTR.rays([[-0.5, -0.5]])[0] * NEAREST_M
    step = 1e-6
    J = np.column_stack([(INTR.project([corner + step * e]) - INTR.project([corner]))[0] / step for e in np.eye(3)])
    worst = np.linalg.svd(J)[2][0]
    moved = np.linalg.norm(INTR.project([corner + tol * worst]) - INTR.project([corner]))
    assert moved == pytest.approx(PROJECTED_ERROR_PX, rel=0.01)


def test_simplified_mesh_keeps_borders_and_seams_and_stays_within_the_bound() -> None:
    mesh = sample_wall_mesh(grid=81, texture_px=1024)
    v, f, uv = np.asarray(mesh.vertices), np.asarray(mesh.faces), np.asarray(mesh.visual.uv)
    # A UV seam down the middle: the right half's faces get their own copies of the seam's vertices, with UVs
    # of their own (the right half's texture sits 0.01 further right in the image)
    seam = np.flatnonzero(np.isclose(v[:, 0], v[40, 0]))
    right = v[f].mean(axis=1)[:, 0] > v[40, 0]
    copies = np.arange(len(v), len(v) + len(seam))
    remap = np.arange(len(v))
    remap[seam] = copies
    f = f.copy()
    f[right] = remap[f[right]]
    v, uv = np.vstack([v, v[seam]]), np.vstack([uv, uv[seam]])
    uv[np.unique(f[right])] += [0.01, 0.0]
    tol = tolerance_m(INTR, NEAREST_M)
    simplified = decimation_of(v, f, uv).within(tol)
    assert len(simplified.faces) < 0.6 * len(f)  # a small mesh: its border and seam strips are much of it
    assert simplified.deviation_m <= tol
    outline = trimesh.Trimesh(v, f, process=False).outline().vertex_nodes.ravel()
    border = np.unique(np.concatenate([outline, seam, copies]))
    index = {int(s): i for i, s in enumerate(simplified.source)}
    kept = [index.get(int(b)) for b in border]
    assert None not in kept  # every border and seam vertex is still there ...
    np.testing.assert_array_equal(simplified.positions[kept], v[border])  # ... exactly where it was
    np.testing.assert_array_equal(simplified.uv[kept], uv[border])        # ... with its own UV


@pytest.mark.parametrize("pose", sorted(POSES))
def test_the_simplified_mesh_draws_the_full_meshs_picture(gl_context: moderngl.Context, wall: trimesh.Trimesh,
                                                           full_renders: dict, pose: str) -> None:
    with MeshRenderer(ctx=gl_context, max_error_px=PROJECTED_ERROR_PX) as simple:
        simple.set_mesh(wall, INTR, NEAREST_M)
        triangles = simple.triangles
        got = simple.render(INTR, look_at(*POSES[pose], up=[0, 1, 0]), depth=True)
        assert simple.triangles == triangles  # this view is within what the upload assumed: no new simplification
    full = full_renders[pose]
    diff = picture_difference(full.color, got.color, full.depth, got.depth)
    assert not failures(diff), f"{pose}: {failures(diff)} ({diff})"
    assert diff.edges > 3000  # the comparison saw the checker's edges
    # A tenth of the triangles (4,888 of 51,200): collapses are replayed cheapest first down to this bound
    # (fast_simplification at its default aggressiveness on metres kept 13,994).
    assert triangles < 0.15 * len(wall.faces)


def test_a_loosened_bound_fails_the_same_comparison(gl_context: moderngl.Context, wall: trimesh.Trimesh,
                                                    full_renders: dict) -> None:
    with MeshRenderer(ctx=gl_context, max_error_px=10.0) as loose:
        loose.set_mesh(wall, INTR, NEAREST_M)
        diffs = {name: picture_difference(full_renders[name].color, got.color, full_renders[name].depth, got.depth)
                 for name, got in ((n, loose.render(INTR, look_at(*p, up=[0, 1, 0]), depth=True))
                                   for n, p in POSES.items())}
    assert all(failures(d) for d in diffs.values()), diffs
    # Both measures tell: seen obliquely, the surface moved off the wall's plane shifts texture edges too (seen
    # head-on it moves mostly along the rays, which the depth shows and the edges hardly do).
    oblique = diffs["oblique"]
    assert oblique.depth_mm > DEPTH_MM and oblique.edge_shift_px > EDGE_PX


def test_coming_closer_simplifies_again_within_the_bound(gl_context: moderngl.Context, wall: trimesh.Trimesh
                                                         ) -> None:
    close = look_at([1.0, 0.8, 0.3], [1.0, 0.8, 0.0], up=[0, 1, 0])  # 0.3 m: less than half the distance assumed
    with MeshRenderer(ctx=gl_context) as full:
        full.set_mesh(wall)
        truth = full.render(INTR, close, depth=True)
    with MeshRenderer(ctx=gl_context, max_error_px=PROJECTED_ERROR_PX) as simple:
        simple.set_mesh(wall, INTR, NEAREST_M)
        before = simple.triangles
        got = simple.render(INTR, close, depth=True)
        assert simple.triangles > before
    diff = picture_difference(truth.color, got.color, truth.depth, got.depth)
    assert not failures(diff), diff


def test_first_view_chooses_the_simplification_and_a_mesh_without_uvs_is_drawn_in_full(
        gl_context: moderngl.Context, wall: trimesh.Trimesh) -> None:
    T = look_at(*POSES["frontal"], up=[0, 1, 0])
    with MeshRenderer(ctx=gl_context, max_error_px=PROJECTED_ERROR_PX) as r:
        r.set_mesh(wall)
        assert r.triangles == len(wall.faces)  # nothing known of the view yet
        r.render(INTR, T)
        assert r.triangles < 0.4 * len(wall.faces)
        coloured = trimesh.Trimesh(wall.vertices, wall.faces, vertex_colors=[200, 100, 50, 255], process=False)
        r.set_mesh(coloured)
        r.render(INTR, T)
        assert r.triangles == len(wall.faces)


def test_a_mesh_stored_one_triangle_at_a_time_is_welded_and_simplified() -> None:
    mesh = sample_wall_mesh(grid=81, texture_px=1024)
    v, f, uv = np.asarray(mesh.vertices), np.asarray(mesh.faces), np.asarray(mesh.visual.uv)
    loose_v, loose_uv, loose_f = v[f].reshape(-1, 3), uv[f].reshape(-1, 2), np.arange(3 * len(f)).reshape(-1, 3)
    tol = tolerance_m(INTR, NEAREST_M)
    welded = decimation_of(loose_v, loose_f, loose_uv).within(tol)
    indexed = decimation_of(v, f, uv).within(tol)
    assert len(welded.faces) == len(indexed.faces) < 0.6 * len(f)
    np.testing.assert_array_equal(loose_v[welded.source], v[indexed.source])  # the same vertices, found again
