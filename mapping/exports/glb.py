"""wall.glb, what the projection session loads.

A binary glTF 2.0 file with one textured triangle mesh, readable with `trimesh.load(path, force="mesh")`.
Vertices are in the WALL frame, metres: x right along the wall, y up, z out of the wall into the room;
the wall surface lies at z ≈ 0 (exactly 0 for the flat wall built from a scan log; the measured surface
when range images were merged). Faces are wound counter-clockwise seen from the room (+z).
Texture coordinates: u = (x − x_min)/(x_max − x_min), v = (y − y_min)/(y_max − y_min) over the map's
bounds (trimesh convention, v = 0 at the image's bottom row). The texture is an RGBA PNG of the in-wall
map (mapping.texture): class colours (power_line red, metal_pipe blue, metal purple, non_metal brown, cavity
teal, fastener yellow); scanned areas where nothing was found faint grey (alpha 24); alpha 0 exactly
where the wall was not scanned (the projection session reads coverage from the alpha).
The glTF scene's `extras` carry {"frame": "wall", "units": "m", "bounds_m": [x_min, y_min, x_max, y_max],
"other_surface_faces": n}.

A measured mesh (range images) also holds surfaces that are not the wall: the floor at its foot, clutter in
front of it. mapping.surface.split_wall_faces tells them apart; only the wall's faces (geometry "wall") carry
the map. The others are a second, untextured primitive (geometry "other_surfaces") with black, opaque vertex
colours: the surface is there (it hides what is behind it) but nothing is known of what lies in it, and a
projector draws nothing on it.

room.glb (write_room_glb) is the same for several walls of one room, in the ROOM frame: the measured mesh's
faces classified against each wall's plane (mapping.surface.classify_faces), each wall's faces textured by its
own map through one texture atlas (each wall a tile, side by side; the geometry "walls" holds every wall's
faces, which tile a face's UVs fall in says whose it is), the rest the dark "other_surfaces". A tile covers the
wall's map bounds and every face of that wall, alpha 0 (not scanned) outside the map. The scene's `extras`
carry {"frame": "room", "units": "m", "atlas_px": [W, H], "walls": [{"index", "T_room_from_wall" (4x4 rows),
"size_m": [w, h], "bounds_m": the map's, "extent_m": [x0, y0, x1, y1] the tile's in the wall frame,
"tile_px": [col, row, w, h] in the atlas image, "faces": n}, …], "other_surface_faces": n}.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray
from PIL import Image

from geometry import provenance
from geometry.errors import InputError
from geometry.poses import invert, transform_points
from mapping import mapfile
from mapping.exports.common import ExportJob, looked
from mapping.fusion import CLASSES, class_map
from mapping.pipeline import MapResult
from mapping.surface import classify_faces, flat_wall_mesh, split_wall_faces
from mapping.texture import bake_texture, textured_wall_mesh

FILE_NAME = "wall.glb"
ROOM_FILE_NAME = "room.glb"
WALLS_GEOMETRY = "walls"
MAX_ATLAS_PX = 16384  # the widest texture a GL context is sure to take
WALL_GEOMETRY = "wall"
OTHER_GEOMETRY = "other_surfaces"
OTHER_RGBA = (0, 0, 0, 255)  # dark: not mapped, unknown
ORDER = 10  # first: the file the projection session needs


def write(job: ExportJob) -> Path:
    return write_wall_glb(job.result, job.out_dir / FILE_NAME, job.mesh, objects=job.objects)


def wall_texture(result: MapResult, px_per_m: float = 500.0,
                 objects: list[mapfile.MappedObject] | None = None) -> NDArray[np.uint8]:
    """RGBA texture (H, W, 4) of the map over result.bounds (objects: result.mapped_objects() if not given)."""
    idx, prob = class_map(result.grid)
    return bake_texture(result.grid.info, idx, prob, list(CLASSES), looked(result),
                        result.mapped_objects() if objects is None else objects, result.bounds, px_per_m)


def write_wall_glb(result: MapResult, path: str | Path, mesh: trimesh.Trimesh | None = None,
                   px_per_m: float = 500.0, objects: list[mapfile.MappedObject] | None = None) -> Path:
    """wall.glb: `mesh` (wall frame; default a flat tessellated wall over the bounds), its wall faces with the
    map texture and its other faces (floor, clutter) as a dark untextured primitive."""
    path = Path(path)
    x0, y0, x1, y1 = result.bounds
    base = mesh if mesh is not None else flat_wall_mesh(x0, y0, x1, y1)
    wall, other = split_wall_faces(base)
    if not len(wall.faces):
        raise InputError("no face of the measured surface lies on the wall (z = 0 of the wall frame)",
                         "check T_world_from_wall and the range cameras' poses")
    textured = textured_wall_mesh(wall, wall_texture(result, px_per_m, objects), result.bounds)
    scene = trimesh.Scene()
    scene.add_geometry(textured, geom_name=WALL_GEOMETRY, node_name=WALL_GEOMETRY)
    if other is not None:
        other.visual = trimesh.visual.ColorVisuals(other, vertex_colors=np.tile(OTHER_RGBA, (len(other.vertices), 1)))
        scene.add_geometry(other, geom_name=OTHER_GEOMETRY, node_name=OTHER_GEOMETRY)
    scene.metadata["extras"] = {"frame": "wall", "units": "m", "bounds_m": list(result.bounds),
                                "other_surface_faces": 0 if other is None else len(other.faces),
                                "made_by": provenance.record()}
    path.write_bytes(scene.export(file_type="glb"))
    return path


@dataclass(frozen=True)
class AtlasWall:
    """One wall of a room map: its index in the room, its wall frame in the room (wall surface at z = 0), its
    map's RGBA texture over bounds (x0, y0, x1, y1) in that frame (wall_texture) and the wall's size (w, h) m."""

    index: int
    T_room_from_wall: NDArray[np.float64]
    texture: NDArray[np.uint8]
    bounds: tuple[float, float, float, float]
    size_m: tuple[float, float]


def _tile(wall: AtlasWall, xy: NDArray[np.float64]) -> tuple[NDArray[np.uint8], tuple[float, float, float, float]]:
    """The wall's texture padded (alpha 0: not scanned) to cover its faces' points xy too, and the tile's extent
    (whole texels, the map's texel grid kept)."""
    x0, y0, x1, y1 = wall.bounds
    h, w = wall.texture.shape[:2]
    sx, sy = w / (x1 - x0), h / (y1 - y0)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    left, right = max(0, int(np.ceil((x0 - lo[0]) * sx))), max(0, int(np.ceil((hi[0] - x1) * sx)))
    bottom, top = max(0, int(np.ceil((y0 - lo[1]) * sy))), max(0, int(np.ceil((hi[1] - y1) * sy)))
    image = np.zeros((h + top + bottom, w + left + right, 4), np.uint8)
    image[top:top + h, left:left + w] = wall.texture
    return image, (x0 - left / sx, y0 - bottom / sy, x1 + right / sx, y1 + top / sy)


def write_room_glb(path: str | Path, mesh: trimesh.Trimesh, walls: list[AtlasWall]) -> Path:
    """room.glb: the room-frame `mesh`, each wall's faces textured by its own map through one atlas, the other
    faces (floor, ceiling, clutter, walls without a map) dark (see the module docstring)."""
    path = Path(path)
    if not walls:
        raise InputError("a room map needs at least one wall with a map")
    labels = classify_faces(mesh, [w.T_room_from_wall for w in walls])
    parts, tiles = [], []
    for k, wall in enumerate(walls):
        faces = np.asarray(mesh.faces)[labels == k]
        if not len(faces):
            raise InputError(f"no face of the measured surface lies on wall {wall.index}'s plane",
                             "check its T_room_from_wall and the range cameras' poses")
        used, inverse = np.unique(faces, return_inverse=True)
        local = transform_points(invert(wall.T_room_from_wall), np.asarray(mesh.vertices)[used])
        image, extent = _tile(wall, local[:, :2])
        parts.append((np.asarray(mesh.vertices)[used], inverse.reshape(-1, 3), local[:, :2], extent))
        tiles.append(image)
    width, height = sum(t.shape[1] for t in tiles), max(t.shape[0] for t in tiles)
    if width > MAX_ATLAS_PX or height > MAX_ATLAS_PX:
        raise InputError(f"the walls' maps make a {width}x{height} px atlas; at most {MAX_ATLAS_PX} px a side",
                         "export the maps at fewer pixels per metre")
    atlas = np.zeros((height, width, 4), np.uint8)
    vertices, faces_out, uv, entries, col, offset = [], [], [], [], 0, 0
    for wall, image, (v, f, xy, (ex0, ey0, ex1, ey1)) in zip(walls, tiles, parts, strict=True):
        th, tw = image.shape[:2]
        atlas[:th, col:col + tw] = image  # top-aligned: the tile's rows 0..th of the atlas
        u = (col + (xy[:, 0] - ex0) / (ex1 - ex0) * tw) / width
        vv = 1.0 - (th - (xy[:, 1] - ey0) / (ey1 - ey0) * th) / height  # trimesh: v = 0 at the bottom row
        vertices.append(v)
        faces_out.append(f + offset)
        uv.append(np.column_stack([u, vv]))
        entries.append({"index": int(wall.index), "T_room_from_wall": np.asarray(wall.T_room_from_wall).tolist(),
                        "size_m": [float(s) for s in wall.size_m], "bounds_m": [float(b) for b in wall.bounds],
                        "extent_m": [ex0, ey0, ex1, ey1], "tile_px": [col, 0, tw, th], "faces": len(f)})
        col, offset = col + tw, offset + len(v)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(atlas, "RGBA"),
                                                   alphaMode="BLEND", doubleSided=True, metallicFactor=0.0,
                                                   roughnessFactor=1.0)
    textured = trimesh.Trimesh(np.vstack(vertices), np.vstack(faces_out), process=False,
                               visual=trimesh.visual.TextureVisuals(uv=np.vstack(uv), material=material))
    scene = trimesh.Scene()
    scene.add_geometry(textured, geom_name=WALLS_GEOMETRY, node_name=WALLS_GEOMETRY)
    rest = labels < 0
    if rest.any():
        other = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)[rest], process=False)
        other.remove_unreferenced_vertices()
        other.visual = trimesh.visual.ColorVisuals(other, vertex_colors=np.tile(OTHER_RGBA, (len(other.vertices), 1)))
        scene.add_geometry(other, geom_name=OTHER_GEOMETRY, node_name=OTHER_GEOMETRY)
    scene.metadata["extras"] = {"frame": "room", "units": "m", "atlas_px": [width, height], "walls": entries,
                                "other_surface_faces": int(rest.sum()), "made_by": provenance.record()}
    path.write_bytes(scene.export(file_type="glb"))
    return path
