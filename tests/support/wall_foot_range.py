"""Range images of the simulated site's wall 0 at its foot (fixed seed): the wall and the floor in front of it,
meshed in the wall frame over the hazard wall's map bounds, as `arproj map --range-images` does."""

from __future__ import annotations

import functools
import warnings

import numpy as np
import trimesh

from arproj.sim.site import Site, shared_context
from geometry.intrinsics import Intrinsics
from geometry.poses import look_at, transform_points
from mapping.surface import wall_mesh_from_range_images
from tests.support.hazard_wall import hazard_wall_dense_map

SEED = 0


@functools.cache
def wall_foot_mesh() -> tuple[trimesh.Trimesh, np.ndarray]:
    """(the measured surface in wall 0's frame, T_room_from_wall). The wall frame's y = 0 is the floor (room
    z = 0); cameras 1.3 m out look down at the wall's lower 0.4 m, so the floor strip is in view."""
    result, _ = hazard_wall_dense_map()
    x0, _, x1, _ = result.bounds
    with Site.build(seed=SEED, ctx=shared_context()) as site:
        T_room_from_wall = site.walls[0].T_room_from_wall
        intr = Intrinsics.from_fov(96, 72, 60.0)
        views = []
        for vx in (x0 + 0.3, x1 - 0.3):
            eye, target = transform_points(T_room_from_wall, [[vx, 0.9, 1.3], [vx, 0.3, 0.0]])
            T_room_from_cam = look_at(eye, target, up=[0.0, 0.0, 1.0])
            image = site.range_image(T_room_from_cam, intr)
            views.append((np.asarray(image.depth, dtype=np.float64), image.intr, T_room_from_cam))
    with warnings.catch_warnings():  # all-NaN pixels (no return) at the views' edges
        warnings.simplefilter("ignore", RuntimeWarning)
        mesh = wall_mesh_from_range_images(views, result.bounds, T_room_from_wall)
    return mesh, T_room_from_wall


def truth_floor_faces(mesh: trimesh.Trimesh, T_room_from_wall: np.ndarray) -> np.ndarray:
    """Faces (bool per face) that truly lie on the floor: every vertex within 3 cm of room z = 0 and more than
    5 cm out from the wall's plane (the corner strip where both meet belongs to neither for sure)."""
    room_z = transform_points(T_room_from_wall, mesh.vertices)[:, 2][mesh.faces]
    off_wall = np.abs(np.asarray(mesh.vertices)[:, 2])[mesh.faces]
    return np.all(room_z < 0.03, axis=1) & np.all(off_wall > 0.05, axis=1)
