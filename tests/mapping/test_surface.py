"""Surface meshes from range images: grid triangulation, no bridging of depth jumps, merged views, walls."""

import numpy as np
import pytest

from geometry.intrinsics import Intrinsics
from geometry.poses import look_at
from mapping.surface import (
    flat_wall_mesh,
    merge_meshes,
    to_wall_frame,
    triangulate_range_image,
    walls_in_mesh,
)

# Room frame: z up. Wall A is the plane y = 3 (seen from y < 3), wall B the plane x = 2; they meet in a corner.
PLANES = [(np.array([0.0, 1.0, 0.0]), 3.0), (np.array([1.0, 0.0, 0.0]), 2.0)]
BOX = (np.array([0.5, 2.0, 0.8]), 0.25)  # a cube (centre, half size) standing 1 m in front of wall A


def _range_image(intr: Intrinsics, T_room_from_cam: np.ndarray) -> np.ndarray:
    """z-depth (h, w) of the corner and the cube by ray casting; NaN where nothing is hit within 8 m."""
    rr, cc = np.mgrid[0:intr.height, 0:intr.width]
    rays_cam = intr.rays(np.column_stack([cc.ravel(), rr.ravel()]).astype(float))
    dirs = rays_cam @ T_room_from_cam[:3, :3].T
    origin = T_room_from_cam[:3, 3]
    t_best = np.full(len(dirs), np.inf)
    for n, d in PLANES:
        denom = dirs @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (d - origin @ n) / denom
        t_best = np.where((t > 0) & (t < t_best), t, t_best)
    c, h = BOX
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (c - h - origin) / dirs
        t1 = (c + h - origin) / dirs
    tmin = np.nanmax(np.minimum(t0, t1), axis=1)
    tmax = np.nanmin(np.maximum(t0, t1), axis=1)
    hit = (tmax >= tmin) & (tmin > 0)
    t_best = np.where(hit & (tmin < t_best), tmin, t_best)
    depth = t_best * 1.0  # rays have unit z in the camera: t is the z-depth
    depth[~np.isfinite(depth) | (depth > 8)] = np.nan
    return depth.reshape(intr.height, intr.width)


@pytest.fixture(scope="module")
def views():
    intr = Intrinsics.from_fov(80, 60, 70.0)
    poses = [look_at([0.3, 0.0, 1.2], [1.0, 3.0, 1.0]), look_at([-0.2, 0.2, 1.4], [1.6, 2.8, 1.2])]
    return intr, poses, [_range_image(intr, T) for T in poses]


def test_grid_triangulation_does_not_bridge_depth_jumps(views):
    intr, poses, depths = views
    mesh = triangulate_range_image(depths[0], intr, poses[0])
    assert len(mesh.faces) > 0.8 * 2 * 79 * 59  # nearly every 2x2 block gives two triangles
    edges = mesh.vertices[mesh.edges_unique]
    lengths = np.linalg.norm(edges[:, 0] - edges[:, 1], axis=1)
    # neighbouring pixels 3 m away are ~5 cm apart; the cube's silhouette is a 1 m jump: never joined
    assert lengths.max() < 0.25
    # faces look at the camera
    to_cam = poses[0][:3, 3] - mesh.triangles_center
    assert np.mean(np.einsum("ij,ij->i", mesh.face_normals, to_cam) > 0) > 0.99  # all but grazing faces


def test_views_merge_and_walls_are_recognised(views):
    intr, poses, depths = views
    merged = merge_meshes([triangulate_range_image(d, intr, T) for d, T in zip(depths, poses, strict=True)])
    walls = walls_in_mesh(merged, viewpoint=poses[0][:3, 3])
    normals = [w.plane.normal for w in walls[:2]]
    assert len(walls) >= 2
    found = sorted((abs(n @ [0, 1, 0]), abs(n @ [1, 0, 0])) for n in normals)
    # Noise-free depth: normals within 0.8° (1 - cos = 1e-4) of the true axes, < 0.6° of cross-talk (0.01)
    assert found[0][0] < 0.01 and found[0][1] > 0.9999 and found[1][0] > 0.9999  # walls x = 2 and y = 3
    wall_a = next(w for w in walls if abs(w.plane.normal @ [0, 1, 0]) > 0.99)
    R = wall_a.T_world_from_wall[:3, :3]
    # 1e-3: the frame's axes within 0.06° of the room's (noise-free planes)
    np.testing.assert_allclose(R[:, 2], [0, -1, 0], atol=1e-3)  # z into the room
    np.testing.assert_allclose(R[:, 1], [0, 0, 1], atol=1e-3)  # y up
    np.testing.assert_allclose(R[:, 0], [1, 0, 0], atol=1e-3)  # x right, seen from the room
    local = to_wall_frame(merged, wall_a)
    on_wall = np.abs(local.vertices[:, 2]) < 0.01  # the plane inlier band (PLANE_INLIER_M, 1 cm)
    assert on_wall.sum() > 1000  # about half the 2 x 4,800 range pixels land on wall A; 1,000 is a fifth of that
    assert local.vertices[on_wall, 0].min() > -0.01 and local.vertices[on_wall, 1].min() > -0.01  # same 1 cm


def test_flat_wall_mesh_faces_the_room():
    mesh = flat_wall_mesh(0.0, 0.0, 2.5, 2.0, step_m=0.5)
    assert mesh.vertices[:, 2].max() == 0.0 and mesh.area == pytest.approx(5.0)
    assert np.all(mesh.face_normals[:, 2] > 0.999)  # exactly +z up to round-off; a flipped face gives -1


def test_range_images_file_to_wall_frame_mesh(views, tmp_path):
    from geometry.errors import InputError
    from geometry.poses import make_pose
    from mapping.surface import load_range_images, wall_mesh_from_range_images

    intr, poses, depths = views
    # wall A's frame: origin at room (-1, 3, 0), x right along +x, y up, z into the room (−y)
    T_world_from_wall = make_pose(np.column_stack([[1, 0, 0], [0, 0, 1], [0, -1, 0]]), [-1.0, 3.0, 0.0])
    arrays = {"T_world_from_wall": T_world_from_wall}
    for k, (d, T) in enumerate(zip(depths, poses, strict=True)):
        arrays |= {f"depth_{k}": d, f"K_{k}": intr.K, f"T_world_from_camera_{k}": T}
    path = tmp_path / "range.npz"
    np.savez(path, **arrays)
    loaded, T = load_range_images(str(path))
    assert len(loaded) == 2 and np.allclose(T, T_world_from_wall)
    mesh = wall_mesh_from_range_images(loaded, (0.0, 0.0, 2.5, 2.0), T)
    v = mesh.vertices
    # cropped to the wall's bounds ± margin_m (0.05 m, wall_mesh_from_range_images' default)
    assert v[:, 0].min() >= -0.05 and v[:, 0].max() <= 2.55 and v[:, 1].min() >= -0.05
    on_wall = np.abs(v[:, 2]) < 1e-6
    assert on_wall.mean() > 0.5  # wall points lie at z = 0 exactly (noise-free images)
    assert (v[:, 2] > 0.5).any()  # the cube stands in front of the wall (z into the room)
    np.savez(tmp_path / "bad.npz", depth_0=depths[0])
    with pytest.raises(InputError, match="K_0"):
        load_range_images(str(tmp_path / "bad.npz"))


def test_the_floor_at_the_wall_foot_is_not_the_wall():
    """Simulated site (seed 0): the x-y crop keeps the floor strip in front of the wall; classify_faces gives none
    of its faces to the wall, and every face it gives the wall lies on the true wall plane (z = 0)."""
    from mapping.surface import OTHER_SURFACE, classify_faces, split_wall_faces
    from tests.support.wall_foot_range import truth_floor_faces, wall_foot_mesh

    mesh, T_room_from_wall = wall_foot_mesh()
    floor = truth_floor_faces(mesh, T_room_from_wall)
    assert floor.sum() > 100  # the floor is in the mesh
    labels = classify_faces(mesh, [np.eye(4)])
    assert set(np.unique(labels)) == {0, OTHER_SURFACE}
    assert not (labels[floor] == 0).any()
    on_wall = mesh.vertices[mesh.faces[labels == 0]]
    assert np.abs(on_wall[..., 2]).max() < 0.02  # range noise (mm), far inside the 5 cm gate
    assert (labels == 0).sum() > 0.6 * len(labels)
    # and the wall keeps its own faces: one face's normal is range noise (some tilt past 45°), so the facing is
    # judged over its neighbourhood; no face left dark rises above the floor's 5 cm
    from geometry.poses import transform_points

    room_z = transform_points(T_room_from_wall, mesh.vertices)[:, 2][mesh.faces]
    assert not (room_z[labels == OTHER_SURFACE].min(axis=1) > 0.05).any()
    wall, other = split_wall_faces(mesh)
    assert other is not None and len(wall.faces) + len(other.faces) == len(mesh.faces)
    assert len(wall.faces) == (labels == 0).sum()


def test_faces_of_a_room_corner_go_to_their_own_wall(views):
    """Two walls meeting in a corner and a cube before one: each wall's faces carry its index, the cube's none."""
    from geometry.poses import make_pose
    from mapping.surface import OTHER_SURFACE, classify_faces

    intr, poses, depths = views
    mesh = merge_meshes([triangulate_range_image(d, intr, T) for d, T in zip(depths, poses, strict=True)])
    # wall frames (z into the room): wall A the plane y = 3, wall B the plane x = 2
    T_a = make_pose(np.column_stack([[1, 0, 0], [0, 0, 1], [0, -1, 0]]), [-1.0, 3.0, 0.0])
    T_b = make_pose(np.column_stack([[0, 1, 0], [0, 0, 1], [-1, 0, 0]]), [2.0, 0.0, 0.0])
    labels = classify_faces(mesh, [T_a, T_b])
    centroids = mesh.triangles_center
    truth_a = np.abs(centroids[:, 1] - 3.0) < 1e-6
    truth_b = np.abs(centroids[:, 0] - 2.0) < 1e-6
    assert truth_a.sum() > 100 and truth_b.sum() > 100
    assert (labels[truth_a & ~truth_b] == 0).all() and (labels[truth_b & ~truth_a] == 1).all()
    c, h = BOX
    on_cube = np.all(np.abs(centroids - c) < h + 1e-6, axis=1)
    assert on_cube.sum() > 20 and (labels[on_cube] == OTHER_SURFACE).all()
