"""The render benchmark's untextured floor draws the same triangles and the same picture, without the texture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from arproj.bench.render import _untextured, oblique_pose, projector_intrinsics
from geometry.poses import invert
from render import MeshRenderer
from render.sample_wall import sample_wall_mesh


def test_untextured_wall_keeps_the_triangles_and_takes_each_vertex_colour_from_the_texture() -> None:
    textured = sample_wall_mesh(grid=41, texture_px=512)
    plain = _untextured(textured)
    np.testing.assert_array_equal(plain.faces, textured.faces)
    np.testing.assert_array_equal(plain.vertices, textured.vertices)
    # The red cable runs along the wall at y = 1.25 m (v = 0.625); x = 0.75 m (u = 0.3) is clear of other lines.
    uv = textured.visual.uv
    on_cable = int(np.flatnonzero(np.isclose(uv, [0.3, 0.625]).all(axis=1))[0])
    np.testing.assert_array_equal(plain.visual.vertex_colors[on_cable], [220, 40, 40, 255])


@pytest.mark.gl
def test_untextured_wall_renders_the_same_scene_as_the_textured_one(gl_context) -> None:
    textured = sample_wall_mesh(grid=160, texture_px=512)
    intr = projector_intrinsics(320, 200)
    with MeshRenderer(gl_context) as renderer:
        renderer.set_mesh(textured)
        a = renderer.render(intr, oblique_pose()).color
        renderer.set_mesh(_untextured(textured))
        b = renderer.render(intr, oblique_pose()).color
    covered_a, covered_b = a.sum(axis=2) > 0, b.sum(axis=2) > 0
    assert covered_b.mean() > 0.5  # the wall fills most of the view
    # The same triangles through the same transform cover the same pixels; only a pixel whose centre lies on
    # the silhouette within float round-off may differ (the silhouette is ~0.5 % of the pixels).
    assert (covered_a != covered_b).mean() < 0.001
    # Bare plaster, 2.5 cm from any drawn line or label, comes out in the plaster colour in both pictures, at
    # the pixel where OpenCV projects that wall point: same pose, same intrinsics, same colour.
    T_projector_from_wall = invert(oblique_pose())
    rvec, _ = cv2.Rodrigues(T_projector_from_wall[:3, :3])
    plaster = np.array([[x + 0.055, y + 0.27, 0.0] for x in (1.0, 1.5, 2.0) for y in (0.5, 1.0)])
    px, _ = cv2.projectPoints(plaster, rvec, T_projector_from_wall[:3, 3], intr.K, intr.dist_array)
    seen = 0
    for col, row in np.round(px.reshape(-1, 2)).astype(int):
        if 0 <= col < intr.width and 0 <= row < intr.height:
            seen += 1
            for picture in (a, b):
                np.testing.assert_allclose(picture[row, col, :3], [236, 232, 224], atol=2)  # 8-bit rounding
    assert seen >= 2
