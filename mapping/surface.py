"""Surface meshes from range images (paper section 4.1), merged views, and the wall planes in them.

A range image is laid out like the scan itself: each pixel (r, c) is joined to its right and lower
neighbours, two triangles per 2×2 block, which is a triangulation in image space carried over to 3-D. A
triangle is kept only if its three depths are valid (finite, > 0) and agree within DEPTH_JUMP_RATIO, so
depth discontinuities (an object in front of the wall, a room corner seen edge-on) are never bridged.
Several views are merged into one mesh (vertices welded where they coincide), and the wall planes are
recognised by sequential RANSAC over the merged vertices.

Inputs are plain arrays: depth (h, w) float metres along the optical axis (NaN/0 = no return), geometry's
`Intrinsics` and the pose T_world_from_camera (OpenCV camera: x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from geometry.errors import InputError
from geometry.inputs import NpzFile
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, transform_points
from mapping import tolerances as tol
from mapping.stitching import Plane, fit_plane


def range_image_points(depth: ArrayLike, intr: Intrinsics, T_world_from_camera: ArrayLike) -> NDArray[np.float64]:
    """(h, w, 3) world points of a depth image, NaN where the depth is invalid."""
    d = np.asarray(depth, dtype=np.float64)
    if d.shape != (intr.height, intr.width):
        raise InputError(f"range image is {d.shape[1]}x{d.shape[0]} pixels but the intrinsics are for "
                         f"{intr.width}x{intr.height}", "pass the camera_info of the camera that took it")
    rr, cc = np.mgrid[0:intr.height, 0:intr.width]
    rays = intr.rays(np.column_stack([cc.ravel(), rr.ravel()]).astype(np.float64))  # unit-z rays
    valid = np.isfinite(d) & (d > 0)
    p_cam = rays * np.where(valid, d, np.nan).reshape(-1, 1)
    return transform_points(T_world_from_camera, p_cam).reshape(intr.height, intr.width, 3)


def triangulate_range_image(depth: ArrayLike, intr: Intrinsics, T_world_from_camera: ArrayLike,
                            max_jump_ratio: float = tol.DEPTH_JUMP_RATIO) -> trimesh.Trimesh:
    """Grid triangulation of one range image; faces wound to face the camera."""
    d = np.asarray(depth, dtype=np.float64)
    pts = range_image_points(d, intr, T_world_from_camera)
    h, w = d.shape
    valid = np.isfinite(d) & (d > 0)
    index = np.full((h, w), -1, np.int64)
    index[valid] = np.arange(int(valid.sum()))
    a, b = index[:-1, :-1], index[:-1, 1:]
    c, e = index[1:, :-1], index[1:, 1:]
    da, db, dc, de = d[:-1, :-1], d[:-1, 1:], d[1:, :-1], d[1:, 1:]

    def ok(*depths: NDArray) -> NDArray[np.bool_]:
        stack = np.stack(depths)
        with np.errstate(invalid="ignore"):
            finite = np.all(np.isfinite(stack) & (stack > 0), axis=0)
            lo = np.where(finite, np.nanmin(np.where(finite, stack, np.nan), axis=0), 1.0)
            hi = np.where(finite, np.nanmax(np.where(finite, stack, np.nan), axis=0), 1.0)
        return finite & (hi - lo <= max_jump_ratio * lo)

    # (a, c, b) and (b, c, e) face the camera (image y points down, the camera looks along +z)
    t1 = ok(da, dc, db)
    t2 = ok(db, dc, de)
    faces = np.vstack([np.column_stack([a[t1], c[t1], b[t1]]), np.column_stack([b[t2], c[t2], e[t2]])])
    return trimesh.Trimesh(vertices=pts[valid], faces=faces, process=False)


def merge_meshes(meshes: list[trimesh.Trimesh], weld_m: float = 1e-4) -> trimesh.Trimesh:
    """One mesh from several views: concatenated, vertices within weld_m welded, unused vertices dropped."""
    meshes = [m for m in meshes if len(m.faces)]
    if not meshes:
        raise InputError("no triangles in any range image to merge (all depths invalid?)")
    merged = trimesh.util.concatenate(meshes)
    assert isinstance(merged, trimesh.Trimesh)  # meshes concatenate to a mesh (trimesh types it as any Geometry)
    digits = max(0, int(-np.floor(np.log10(weld_m))))
    merged.merge_vertices(digits_vertex=digits)
    merged.remove_unreferenced_vertices()
    return merged


@dataclass(frozen=True)
class WallPlane:
    """A recognised wall: its plane, T_world_from_wall (wall frame convention) and size in metres."""

    plane: Plane
    T_world_from_wall: NDArray[np.float64]
    width_m: float
    height_m: float
    n_points: int


def find_planes(points: ArrayLike, max_planes: int = 4, inlier_m: float = tol.PLANE_INLIER_M,
                min_fraction: float = 0.05, seed: int = 0) -> list[Plane]:
    """Sequential RANSAC: the largest planes among points (n, 3), each with ≥ min_fraction of the points."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    remaining = np.arange(p.shape[0])
    planes: list[Plane] = []
    need = max(tol.PLANE_MIN_POINTS, int(min_fraction * p.shape[0]))
    for k in range(max_planes):
        if remaining.size < need:
            break
        plane = fit_plane(p[remaining], inlier_m=inlier_m, seed=seed + k, what="range points")
        if plane.inliers.sum() < need:
            break
        mask = np.zeros(p.shape[0], bool)
        mask[remaining[plane.inliers]] = True
        planes.append(Plane(plane.normal, plane.d, plane.centroid, mask, plane.rms_m))
        remaining = remaining[~plane.inliers]
    return planes


def wall_from_plane(plane: Plane, points: ArrayLike, viewpoint: ArrayLike,
                    up: ArrayLike = (0.0, 0.0, 1.0)) -> WallPlane:
    """The wall frame of a plane: z towards the viewpoint (into the room), y up, x right seen from the room,
    origin at the lower-left corner of the plane's inlier points."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)[plane.inliers]
    n = plane.normal.copy()
    if (np.asarray(viewpoint, dtype=np.float64) - plane.centroid) @ n < 0:
        n = -n
    up = np.asarray(up, dtype=np.float64)
    y = up - (up @ n) * n
    if np.linalg.norm(y) < 1e-6:
        raise InputError("this plane is horizontal (a floor or ceiling), not a wall")
    y /= np.linalg.norm(y)
    x = np.cross(y, n)  # seen from the room (looking along −n), x points right
    R = np.column_stack([x, y, n])
    local = (p - plane.centroid) @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    origin = plane.centroid + R @ np.array([lo[0], lo[1], 0.0])
    return WallPlane(plane, make_pose(R, origin), float(hi[0] - lo[0]), float(hi[1] - lo[1]), int(p.shape[0]))


def walls_in_mesh(mesh: trimesh.Trimesh, viewpoint: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0),
                  max_planes: int = 4) -> list[WallPlane]:
    """Vertical planes (walls) among a mesh's vertices, largest first; floors/ceilings are skipped."""
    up = np.asarray(up, dtype=np.float64)
    out = []
    for plane in find_planes(mesh.vertices, max_planes=max_planes):
        if abs(plane.normal @ up) > np.sin(np.radians(20.0)):
            continue
        out.append(wall_from_plane(plane, mesh.vertices, viewpoint, up))
    return out


def to_wall_frame(mesh: trimesh.Trimesh, wall: WallPlane) -> trimesh.Trimesh:
    """A copy of the mesh with vertices in the wall frame (metres; the wall surface at z ≈ 0)."""
    out = mesh.copy()
    out.vertices = transform_points(invert(wall.T_world_from_wall), mesh.vertices)
    return out


def flat_wall_mesh(x_min: float, y_min: float, x_max: float, y_max: float, step_m: float = 0.05) -> trimesh.Trimesh:
    """A tessellated rectangle at z = 0 in the wall frame, faces towards +z (the room): the wall when no
    range images were taken."""
    nx = max(1, int(np.ceil((x_max - x_min) / step_m)))
    ny = max(1, int(np.ceil((y_max - y_min) / step_m)))
    xs, ys = np.linspace(x_min, x_max, nx + 1), np.linspace(y_min, y_max, ny + 1)
    X, Y = np.meshgrid(xs, ys)
    verts = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(X.size).reshape(ny + 1, nx + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.vstack([np.column_stack([a, b, d]), np.column_stack([a, d, c])])  # counter-clockwise from +z
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


WALL_SURFACE_GATE_M = 0.05   # a face farther than this from a wall's plane is another surface (floor, clutter)
WALL_FACING_DEG = 45.0       # … and one turned more than this from the wall's normal (the floor at its foot)
FACING_SMOOTHING_RINGS = 2   # … judged by the faces around it, this many vertex rings out (range noise)
OTHER_SURFACE = -1           # classify_faces' label of a face on no given wall: not mapped, unknown


def classify_faces(mesh: trimesh.Trimesh, T_frame_from_walls: list[NDArray[np.float64]],
                   gate_m: float = WALL_SURFACE_GATE_M, facing_deg: float = WALL_FACING_DEG) -> NDArray[np.int64]:
    """For each face of mesh (in some frame F), the index of the wall it lies on, or OTHER_SURFACE.

    T_frame_from_walls: each wall's frame in F (wall surface at its z = 0). A face lies on a wall when its
    three vertices are within gate_m of the wall's plane and its normal — or that averaged over the faces
    around it, as one face's is range noise — is within facing_deg of the wall's normal (either side: the winding of a
    merged mesh is not trusted). A face on two walls' planes (along the
    inside corner) goes to the one its centroid is nearer. Everything else (floor, ceiling, clutter, a wall
    not given) is OTHER_SURFACE: its map is unknown.
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    labels = np.full(len(f), OTHER_SURFACE, np.int64)
    if not len(f):
        return labels
    normals = np.asarray(mesh.face_normals, dtype=np.float64)
    best = np.full(len(f), np.inf)
    cos_gate = np.cos(np.radians(facing_deg))
    for k, T in enumerate(T_frame_from_walls):
        T = np.asarray(T, dtype=np.float64)
        n, origin = T[:3, 2], T[:3, 3]
        dist = (v - origin) @ n  # signed distance of each vertex to the wall plane
        near = (np.abs(dist[f]) < gate_m).all(axis=1)
        own = np.abs(normals @ n)
        facing = np.maximum(own, _neighbourhood_mean(mesh, own)) > cos_gate  # own: a face by the corner line
        centroid_dist = np.abs(dist[f].mean(axis=1))
        take = near & facing & (centroid_dist < best)
        labels[take], best[take] = k, centroid_dist[take]
    return labels


def _neighbourhood_mean(mesh: trimesh.Trimesh, per_face: NDArray[np.float64],
                        rings: int = FACING_SMOOTHING_RINGS) -> NDArray[np.float64]:
    """per_face averaged (area-weighted) over the faces around each face, `rings` vertex rings out. A small
    face's own normal is range noise over a pixel's footprint (a wall face 1.3 m away tilts 18° at the median,
    more than 45° for about 1 in 200); its neighbourhood's is the surface's."""
    incidence = mesh.faces_sparse  # (vertices, faces)
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    value = per_face
    with np.errstate(invalid="ignore", divide="ignore"):
        for _ in range(rings):
            at_vertex = (incidence @ (value * area)) / (incidence @ area)
            value = np.nan_to_num(at_vertex, nan=0.0)[faces].mean(axis=1)
    return value


def split_wall_faces(mesh: trimesh.Trimesh, gate_m: float = WALL_SURFACE_GATE_M,
                     facing_deg: float = WALL_FACING_DEG) -> tuple[trimesh.Trimesh, trimesh.Trimesh | None]:
    """A wall-frame mesh split into the faces on the wall (z ≈ 0, facing ±z) and all other faces (None if
    there are none): the wall's map textures the first; the second is measured surface with no map."""
    on_wall = classify_faces(mesh, [np.eye(4)], gate_m, facing_deg) == 0
    return _faces_subset(mesh, on_wall), (_faces_subset(mesh, ~on_wall) if (~on_wall).any() else None)


def _faces_subset(mesh: trimesh.Trimesh, keep: NDArray[np.bool_]) -> trimesh.Trimesh:
    out = trimesh.Trimesh(vertices=np.asarray(mesh.vertices).copy(), faces=np.asarray(mesh.faces)[keep].copy(),
                          process=False)
    out.remove_unreferenced_vertices()
    return out


MAX_RANGE_VIEWS = 1000
MAX_RANGE_PIXELS = 4096  # per side of one range image
MAX_RANGE_M = 100.0      # depths and camera positions, metres
RangeView = tuple[NDArray[np.float64], Intrinsics, NDArray[np.float64]]  # depth (h, w), intr, T_world_from_camera


def load_range_images(path: str) -> tuple[list[RangeView], NDArray[np.float64] | None]:
    """Range images from an .npz file: for k = 0, 1, …: `depth_k` (h, w) metres (NaN/0 = no return),
    `K_k` (3, 3), `T_world_from_camera_k` (4, 4) (OpenCV camera); optional `T_world_from_wall` (4, 4).
    Returns ([(depth, Intrinsics, T)], T_world_from_wall or None)."""
    from pathlib import Path

    p = Path(path)
    hint = "store depth_0, K_0, T_world_from_camera_0, … (metres, OpenCV camera frame)"
    views: list[RangeView] = []
    with NpzFile(p, "range image file", hint) as z:
        k = 0
        while f"depth_{k}" in z:
            for key in (f"K_{k}", f"T_world_from_camera_{k}"):
                if key not in z:
                    raise InputError(f"{p}: {key} is missing for depth_{k}",
                                     "each depth_k needs K_k (3x3) and T_world_from_camera_k (4x4)")
            if k >= MAX_RANGE_VIEWS:
                raise InputError(f"{p}: more than {MAX_RANGE_VIEWS} range images", hint)
            depth = z.floats(f"depth_{k}", (None, None), finite=False)  # NaN: no return
            if not (0 < depth.shape[0] <= MAX_RANGE_PIXELS and 0 < depth.shape[1] <= MAX_RANGE_PIXELS):
                raise InputError(f"{p}: depth_{k} is {depth.shape[1]}x{depth.shape[0]} pixels; a range image has "
                                 f"1 to {MAX_RANGE_PIXELS} per side", hint)
            valid = depth[np.isfinite(depth)]
            if (np.isinf(depth).any() or (valid < 0).any() or (valid > MAX_RANGE_M).any()):
                raise InputError(f"{p}: depth_{k} holds depths outside 0..{MAX_RANGE_M:g} m (NaN or 0: no return)",
                                 hint)
            K = z.floats(f"K_{k}", (3, 3))
            T = z.floats(f"T_world_from_camera_{k}", (4, 4))
            if np.abs(T[:3, 3]).max() > MAX_RANGE_M or not np.allclose(T[3], [0, 0, 0, 1]):
                raise InputError(f"{p}: T_world_from_camera_{k} is not a pose within {MAX_RANGE_M:g} m", hint)
            try:
                intr = Intrinsics.from_K(K, depth.shape[1], depth.shape[0])
            except InputError as err:
                raise InputError(f"{p}: K_{k}: {err.message}", hint) from None
            views.append((depth, intr, T))
            k += 1
        if not views:
            raise InputError(f"{p}: no depth_0 array", hint)
        T_wall = z.floats("T_world_from_wall", (4, 4)) if "T_world_from_wall" in z else None
    return views, T_wall


def merged_range_mesh(views: list[RangeView]) -> trimesh.Trimesh:
    """Every range view triangulated and merged into one mesh, in the views' world frame (uncropped)."""
    return merge_meshes([triangulate_range_image(d, intr, T) for d, intr, T in views])


def wall_mesh_from_range_images(views: list[RangeView], bounds: tuple[float, float, float, float],
                                T_world_from_wall: NDArray[np.float64] | None = None,
                                margin_m: float = 0.05, merged: trimesh.Trimesh | None = None) -> trimesh.Trimesh:
    """The measured surface in the wall frame, cropped to bounds (x_min, y_min, x_max, y_max) ± margin in x
    and y only, so other surfaces in front of the wall (the floor at its foot, clutter) come along:
    split_wall_faces tells them apart (wall.glb draws them dark). Views triangulated and merged (or `merged`,
    merged_range_mesh's of these views); without T_world_from_wall the largest wall facing the first camera is
    recognised and its lower-left inlier corner taken as the origin."""
    if merged is None:
        merged = merged_range_mesh(views)
    if T_world_from_wall is None:
        walls = walls_in_mesh(merged, viewpoint=views[0][2][:3, 3])
        if not walls:
            raise InputError("no wall plane found in the range images", "give T_world_from_wall in the file")
        T_world_from_wall = walls[0].T_world_from_wall
    local = merged.copy()
    local.vertices = transform_points(invert(T_world_from_wall), merged.vertices)
    x0, y0, x1, y1 = bounds
    v = local.vertices
    inside = (v[:, 0] >= x0 - margin_m) & (v[:, 0] <= x1 + margin_m) & (v[:, 1] >= y0 - margin_m) & \
        (v[:, 1] <= y1 + margin_m)
    keep = inside[local.faces].all(axis=1)
    if not keep.any():
        raise InputError("the range images do not cover the mapped wall area",
                         "check T_world_from_wall and the cameras' poses")
    local.update_faces(keep)
    local.remove_unreferenced_vertices()
    return local


OTHER_WALL_MIN_SIDE_M = 0.2  # a vertical plane of the range mesh this wide and high (at least) is another wall
OTHER_WALL_MAX_PARALLEL_DEG = 20.0  # … turned this far from the mapped wall at least (not the same wall again)


def other_walls_in_mesh(mesh: trimesh.Trimesh, T_world_from_wall: NDArray[np.float64],
                        viewpoint: ArrayLike) -> list[WallPlane]:
    """The walls a merged range mesh (world frame) holds besides the mapped one (T_world_from_wall: its plane
    at z = 0, y up): vertical planes among the faces off that wall, turned from it, at least
    OTHER_WALL_MIN_SIDE_M a side. Any: the range images cover more than one wall (a room corner)."""
    T = np.asarray(T_world_from_wall, dtype=np.float64)
    off = classify_faces(mesh, [T]) == OTHER_SURFACE
    if off.sum() < tol.PLANE_MIN_POINTS:
        return []
    found = walls_in_mesh(_faces_subset(mesh, off), viewpoint, up=T[:3, 1])
    turned = np.cos(np.radians(OTHER_WALL_MAX_PARALLEL_DEG))
    return [w for w in found if abs(float(w.plane.normal @ T[:3, 2])) < turned
            and min(w.width_m, w.height_m) >= OTHER_WALL_MIN_SIDE_M]


def wall_size_in_mesh(mesh: trimesh.Trimesh, T_frame_from_wall: NDArray[np.float64],
                      bounds: tuple[float, float, float, float]) -> tuple[float, float]:
    """(width, height) m of a wall whose frame (origin its lower-left corner) is T_frame_from_wall in the
    mesh's frame: as far as its faces in the mesh reach (classify_faces), never less than the map's bounds."""
    faces = np.asarray(mesh.faces)[classify_faces(mesh, [T_frame_from_wall]) == 0]
    local = transform_points(invert(np.asarray(T_frame_from_wall, dtype=np.float64)),
                             np.asarray(mesh.vertices)[np.unique(faces)]) if len(faces) else np.zeros((0, 3))
    reach = local[:, :2].max(axis=0) if len(local) else np.zeros(2)
    return float(max(bounds[2], reach[0])), float(max(bounds[3], reach[1]))
