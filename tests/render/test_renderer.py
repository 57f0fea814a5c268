"""Offscreen render tests on Mesa's llvmpipe through EGL: rendered pixels against cv2.projectPoints."""

from __future__ import annotations

from pathlib import Path

import cv2
import moderngl
import numpy as np
import pytest
import trimesh
from PIL import Image

from geometry import Intrinsics, invert, look_at, transform_points
from render import MeshRenderer
from render.distortion import apply_distortion_cpu, distortion_map
from tests.support.gl import gl_error

pytestmark = pytest.mark.gl

SQUARES = (10, 8)
SQUARE_M = 0.05
CORNER_WINDOW = (7, 7)


def checkerboard_mesh(squares: tuple[int, int] = SQUARES, square_m: float = SQUARE_M) -> trimesh.Trimesh:
    """A flat textured board in the z=0 plane, lower-left corner at the origin."""
    nx, ny = squares
    texels = 32  # magnified at these views: level-0 bilinear, no mip blur to bias the corner detector
    image = ((np.indices((ny * texels, nx * texels)) // texels).sum(axis=0) % 2 * 255).astype(np.uint8)
    w, h = nx * square_m, ny * square_m
    return trimesh.Trimesh(
        vertices=[[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]], faces=[[0, 1, 2], [0, 2, 3]],
        visual=trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                             image=Image.fromarray(np.dstack([image] * 3))),
        process=False)


def inner_corners(squares: tuple[int, int] = SQUARES, square_m: float = SQUARE_M) -> np.ndarray:
    nx, ny = squares
    return np.array([[i * square_m, j * square_m, 0.0] for j in range(1, ny) for i in range(1, nx)])


def corner_errors(color: np.ndarray, intr: Intrinsics, T_world_from_camera: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Distance (px) from each rendered corner to where cv2.projectPoints puts its 3-D corner.

    Returns (raw, fitted): raw uses each detected corner as it is; fitted takes the corners through the one
    homography that maps the board plane onto the (undistorted) image. A pinhole view of a plane *is* a
    homography, so the fit removes the detector's per-corner noise (a few hundredths of a pixel at steep
    angles) and keeps every error the renderer could make: a wrong projection or principal point shifts all
    corners and the fitted ones with them.
    """
    gray = cv2.cvtColor(color, cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCornersSB(gray, (SQUARES[0] - 1, SQUARES[1] - 1),
                                                 flags=cv2.CALIB_CB_ACCURACY)
    assert found, "the rendered checkerboard was not found"
    corners = cv2.cornerSubPix(gray, corners, CORNER_WINDOW, (-1, -1),
                               (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-5)).reshape(-1, 2)
    board = inner_corners()
    expected = intr.project(transform_points(invert(T_world_from_camera), board))
    nearest = np.linalg.norm(corners[:, None] - expected[None], axis=2).argmin(axis=1)
    assert len(set(nearest)) == len(corners)  # one detection per true corner
    expected, board = expected[nearest], board[nearest, :2]
    raw = np.linalg.norm(corners - expected, axis=1)
    # Fit in undistorted pixels (the exact inverse of the lens model), compare there.
    undistort = lambda uv: intr.rays(uv)[:, :2] * [intr.fx, intr.fy] + [intr.cx, intr.cy]  # noqa: E731
    H, _ = cv2.findHomography(board, undistort(corners), 0)
    fitted = cv2.perspectiveTransform(board[None], H)[0]
    return raw, np.linalg.norm(fitted - undistort(expected), axis=1)


# Oblique views of the board (centre at (0.25, 0.2, 0)), with the principal point well off centre.
VIEWS = {
    "oblique_left": ([-0.45, 0.05, 0.75], [0.27, 0.21, 0.0]),
    "oblique_above": ([0.3, 0.95, 0.6], [0.24, 0.18, 0.0]),
    "steep_right": ([1.1, 0.3, 0.5], [0.25, 0.2, 0.0]),
}
LENS_SHIFTED = Intrinsics(fx=1010.0, fy=1012.5, cx=702.3, cy=561.8, width=1280, height=800)


@pytest.fixture(scope="module")
def renderer(gl_context: moderngl.Context):
    # A grey surround keeps the board's outer black squares apart from the background.
    with MeshRenderer(ctx=gl_context, background=(0.5, 0.5, 0.5, 1.0)) as r:
        r.set_mesh(checkerboard_mesh())
        yield r


@pytest.mark.parametrize("view", sorted(VIEWS))
def test_checkerboard_corners_land_where_opencv_projects_them(renderer: MeshRenderer, view: str) -> None:
    T = look_at(*VIEWS[view], up=[0, 1, 0])
    raw, fitted = corner_errors(renderer.render(LENS_SHIFTED, T).color, LENS_SHIFTED, T)
    # fitted: the 0.05 px point target; raw adds the detector's own scatter (a few hundredths of a pixel,
    # more at steep angles): a tenth on average, a quarter at worst
    assert fitted.mean() <= 0.05, f"{view}: mean corner error {fitted.mean():.3f} px"
    assert raw.mean() <= 0.1 and raw.max() <= 0.25, f"{view}: detected corners off by {raw.mean():.3f} px"
    assert gl_error(renderer.ctx) == "GL_NO_ERROR"


def test_lens_distortion_pass_moves_pixels_as_opencv_distorts_points(renderer: MeshRenderer) -> None:
    distorted = Intrinsics(fx=1010.0, fy=1012.5, cx=702.3, cy=561.8, width=1280, height=800,
                           dist=(-0.21, 0.09, 0.0012, -0.0007, -0.015))
    T = look_at(*VIEWS["oblique_left"], up=[0, 1, 0])
    color = renderer.render(distorted, T).color
    raw, fitted = corner_errors(color, distorted, T)  # the same bounds as the pinhole views
    assert fitted.mean() <= 0.05, f"mean corner error {fitted.mean():.3f} px"
    assert raw.mean() <= 0.1, f"detected corners off by {raw.mean():.3f} px"
    # Without the pass the corners would be pixels away: the test can tell.
    raw_without, fitted_without = corner_errors(renderer.render(LENS_SHIFTED, T).color, distorted, T)
    assert raw_without.max() > 2.0 and fitted_without.mean() > 0.5  # ten times the bounds above
    # The GPU pass equals the same map applied on the CPU.
    pinhole = renderer.render(distortion_map(distorted).pinhole, T).color
    cpu = apply_distortion_cpu(pinhole, distortion_map(distorted))
    # 2 grey levels: GPU filtering's reduced-precision weights vs CPU float; 0.5 %: edge pixels rounding apart
    assert np.mean(np.abs(cpu.astype(int) - color.astype(int)) > 2) < 0.005


def test_depth_is_the_distance_along_the_optical_axis(renderer: MeshRenderer) -> None:
    intr = LENS_SHIFTED.scaled(0.5)
    T = look_at(*VIEWS["oblique_above"], up=[0, 1, 0])
    depth = renderer.render(intr, T, depth=True).depth
    assert depth is not None and depth.shape == (intr.height, intr.width)
    points_cam = transform_points(invert(T), inner_corners())
    uv = np.round(intr.project(points_cam)).astype(int)
    # Exact depth of the board plane through each of those pixel centres.
    rays = intr.rays(uv.astype(float))
    n_cam = invert(T)[:3, :3] @ [0, 0, 1.0]
    plane_point = transform_points(invert(T), [0.0, 0.0, 0.0])
    expected = (n_cam @ plane_point) / (rays @ n_cam)
    # 2e-4: as RENDER_DEPTH_M in tests/arproj/sim/test_site.py at ~1 m; 24-bit depth over the fitted range is finer
    np.testing.assert_allclose(depth[uv[:, 1], uv[:, 0]], expected, rtol=2e-4)
    assert np.isnan(depth[0, 0])  # nothing drawn in the top-left corner


def test_glb_scene_renders_like_the_mesh_it_was_saved_from(renderer: MeshRenderer, tmp_path: Path,
                                                           gl_context: moderngl.Context) -> None:
    path = tmp_path / "board.glb"
    checkerboard_mesh().export(path)
    T = look_at(*VIEWS["steep_right"], up=[0, 1, 0])
    intr = LENS_SHIFTED.scaled(0.5)
    direct = renderer.render(intr, T).color
    with MeshRenderer(ctx=gl_context, background=(0.5, 0.5, 0.5, 1.0)) as from_glb:
        from_glb.set_mesh(trimesh.load(path))
        loaded = from_glb.render(intr, T).color
    # the same texture through a lossless GLB round trip: a few grey levels on a handful of pixels at most
    assert np.mean(np.abs(direct.astype(int) - loaded.astype(int)) > 3) < 0.002


def test_vertex_coloured_mesh_and_alpha(gl_context: moderngl.Context) -> None:
    mesh = trimesh.Trimesh(vertices=[[-1, -1, 0], [1, -1, 0], [0, 1, 0]], faces=[[0, 1, 2]], process=False)
    mesh.visual.vertex_colors = [[255, 0, 0, 255]] * 3
    intr = Intrinsics(100, 100, 31.5, 31.5, 64, 64)
    with MeshRenderer(ctx=gl_context) as r:
        r.set_mesh(mesh)
        rgba = r.render(intr, look_at([0, 0, 3], [0, 0, 0], up=[0, 1, 0]), alpha=True).color
    assert tuple(rgba[32, 32]) == (255, 0, 0, 255)
    assert tuple(rgba[2, 2]) == (0, 0, 0, 0)


def test_untextured_material_is_drawn_in_its_colour(gl_context: moderngl.Context) -> None:
    # a GLB mesh with a PBR material but no texture image: TextureVisuals without UVs (once an AttributeError)
    mesh = trimesh.Trimesh(vertices=[[-1, -1, 0], [1, -1, 0], [0, 1, 0]], faces=[[0, 1, 2]], process=False,
                           visual=trimesh.visual.TextureVisuals(
                               material=trimesh.visual.material.PBRMaterial(baseColorFactor=[0, 200, 0, 255])))
    intr = Intrinsics(100, 100, 31.5, 31.5, 64, 64)
    with MeshRenderer(ctx=gl_context) as r:
        r.set_mesh(mesh)
        rgb = r.render(intr, look_at([0, 0, 3], [0, 0, 0], up=[0, 1, 0])).color
    assert tuple(rgb[32, 32]) == (0, 200, 0)
    assert tuple(rgb[2, 2]) == (0, 0, 0)


def test_every_gpu_object_is_released(gl_context: moderngl.Context) -> None:
    renderer = MeshRenderer(ctx=gl_context)
    renderer.set_mesh(checkerboard_mesh())
    renderer.render(LENS_SHIFTED.scaled(0.25), look_at([0.2, 0.2, 1], [0.2, 0.2, 0], up=[0, 1, 0]))
    owned = [item.geometry.vao for item in renderer._items] + [t.fbo for t in renderer._targets.values()]
    renderer.release()
    assert all(isinstance(obj.mglo, moderngl.InvalidObject) for obj in owned)
    with pytest.raises(RuntimeError, match="after release"):
        renderer.render(LENS_SHIFTED, np.eye(4))
    assert gl_error(gl_context) == "GL_NO_ERROR"  # the shared context itself is left alone
