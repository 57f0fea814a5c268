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
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray

from geometry import provenance
from geometry.errors import InputError
from mapping import mapfile
from mapping.exports.common import ExportJob, looked
from mapping.fusion import CLASSES, class_map
from mapping.pipeline import MapResult
from mapping.surface import flat_wall_mesh, split_wall_faces
from mapping.texture import bake_texture, textured_wall_mesh

FILE_NAME = "wall.glb"
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
