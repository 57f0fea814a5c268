"""The render benchmark's untextured floor draws the same triangles and the same picture, without the texture."""

from __future__ import annotations

import numpy as np

from arproj.bench.render import _same_picture, _untextured, oblique_pose, projector_intrinsics
from arproj.render import MeshRenderer
from arproj.render.sample_wall import sample_wall_mesh


def test_untextured_wall_keeps_the_triangles_and_takes_each_vertex_colour_from_the_texture() -> None:
    textured = sample_wall_mesh(grid=41, texture_px=512)
    plain = _untextured(textured)
    np.testing.assert_array_equal(plain.faces, textured.faces)
    np.testing.assert_array_equal(plain.vertices, textured.vertices)
    # The red cable runs along the wall at y = 1.25 m (v = 0.625); x = 0.75 m (u = 0.3) is clear of other lines.
    uv = textured.visual.uv
    on_cable = int(np.flatnonzero(np.isclose(uv, [0.3, 0.625]).all(axis=1))[0])
    np.testing.assert_array_equal(plain.visual.vertex_colors[on_cable], [220, 40, 40, 255])


def test_untextured_wall_renders_the_same_scene_as_the_textured_one() -> None:
    textured = sample_wall_mesh(grid=160, texture_px=512)
    intr = projector_intrinsics(320, 200)
    with MeshRenderer() as renderer:
        renderer.set_mesh(textured)
        a = renderer.render(intr, oblique_pose()).color
        renderer.set_mesh(_untextured(textured))
        b = renderer.render(intr, oblique_pose()).color
    assert (b.sum(axis=2) > 0).mean() > 0.5  # the wall fills most of the view
    assert _same_picture(a, b) > 0.8
