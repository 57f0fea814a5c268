"""The in-wall map the session projects: the mapping's mesh (wall.glb), its objects (objects.json) and the
evidence behind them (coverage.npz), as `arproj map --out DIR` writes them.

    wall.glb      textured triangle mesh in the WALL frame (metres); its RGBA texture is the in-wall map,
                  alpha 0 where the wall was not scanned; a second, untextured primitive (if any) holds the
                  measured surfaces that are not the wall (floor, clutter): no map, drawn dark
    objects.json  the mapped objects (mapping.mapfile): class, polyline, width, σ, depth, measured/inferred
    coverage.npz  per sensor channel, what its footprint covered and where it responded (mapping.evidence):
                  the drill check judges by it

Classes are the mapping's: power_line, metal_pipe, metal, fastener, non_metal, cavity. Pipes and cables are
polylines, fasteners single points, studs and cavities closed outlines; non_metal (what only the capacitive
channel shows: a wooden stud or a water-filled plastic pipe) is an outline or a line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray

from arproj.session import tolerances as tol
from geometry.errors import InputError
from geometry.inputs import check_file
from geometry.poses import invert
from mapping.evidence import FILE_NAME as COVERAGE_FILE
from mapping.evidence import Coverage
from mapping.grid import GridInfo
from mapping.mapfile import FILE_NAME as OBJECTS_FILE
from mapping.mapfile import MAP_CLASSES, OUTLINE_CLASSES, MappedObject, check_objects_within, read_objects
from scanner.priors import room_heights

MAX_GLB_BYTES = 1 << 30  # a wall's textured mesh is tens of MB
MAX_WALL_M = 100.0       # a wall map's vertices, metres from the wall frame's origin

__all__ = [
    "MAP_CLASSES",
    "OUTLINE_CLASSES",
    "MappedObject",
    "WallMap",
    "WallRoom",
    "load_wall_map",
    "wall_map_from_wall",
    "wall_map_from_wall_file",
    "wall_room_in_room",
]


@dataclass
class WallRoom:
    """What is known of the map's wall in its room, in the map's wall frame (metres): the floor's and the
    ceiling's height (y), the room corners at the wall's two ends (x), doors and windows as (kind, x0, y0, x1,
    y1) boxes, the centres (n, 2) of known sockets and switches; source: where it came from. The DIN 18015-3
    zones are drawn from it (overlays.room_zones) where the wall was not scanned."""

    floor_y_m: float
    ceiling_y_m: float
    corner_x_m: tuple[float, float]
    openings: list[tuple[str, float, float, float, float]] = field(default_factory=list)
    sockets: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    source: str = ""


def opening_boxes(openings: list) -> list[tuple[str, float, float, float, float]]:
    """(kind, x0, y0, x1, y1) of scanner.wall.Opening outlines."""
    out = []
    for o in openings:
        p = np.asarray(o.outline_m, dtype=np.float64)
        out.append((str(o.kind), float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()),
                    float(p[:, 1].max())))
    return out


def wall_room_in_room(T_room_from_wall: NDArray[np.float64], corners_m: NDArray[np.float64], height_m: float,
                      wall_index: int, openings: list | None = None, sockets: NDArray[np.float64] | None = None,
                      source: str = "") -> WallRoom:
    """The WallRoom of a map whose wall frame sits at T_room_from_wall on room wall wall_index of the floor
    polygon corners_m (room frame: z up, floor z = 0; wall i from corner i to i + 1), height_m high. openings:
    scanner.wall.Opening items in the map's wall frame; sockets (n, 2) there."""
    c = np.asarray(corners_m, dtype=np.float64).reshape(-1, 2)
    a, b = c[wall_index], c[(wall_index + 1) % len(c)]
    ends = np.array([[a[0], a[1], 0.0], [b[0], b[1], 0.0], [a[0], a[1], float(height_m)]])
    local = ends @ invert(T_room_from_wall)[:3, :3].T + invert(T_room_from_wall)[:3, 3]
    xs = sorted((float(local[0, 0]), float(local[1, 0])))
    return WallRoom(float(local[0, 1]), float(local[2, 1]), (xs[0], xs[1]), opening_boxes(openings or []),
                    np.zeros((0, 2)) if sockets is None else np.asarray(sockets, dtype=np.float64).reshape(-1, 2),
                    source)


@dataclass
class WallMap:
    """mesh: in the wall frame (metres); texture: the mapping's RGBA map with the affine wall-xy → uv it uses
    (uv_from_xy: (2, 3)); coverage: the scan's evidence (None: nothing was looked at, every point unknown)."""

    mesh: trimesh.Trimesh
    objects: list[MappedObject] = field(default_factory=list)
    texture: NDArray[np.uint8] | None = None
    uv_from_xy: NDArray[np.float64] | None = None
    coverage: Coverage | None = None
    source: str = ""
    room: WallRoom | None = None  # the wall in its room (floor, ceiling, corners, openings): None, not known
    # measured surfaces that are not the wall (floor at its foot, clutter), wall frame: no map, unknown, dark
    other: trimesh.Trimesh | None = None

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) of the mesh in wall coordinates, metres."""
        lo, hi = self.mesh.bounds
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def load_wall_map(glb_path: str | Path, objects_path: str | Path | None = None) -> WallMap:
    """Read wall.glb, objects.json and coverage.npz (default: beside the GLB). InputError names the file and
    the problem; a map folder without its coverage layer is refused (no point could be judged)."""
    glb_path = Path(glb_path)
    if not glb_path.exists():
        raise InputError(f"{glb_path}: no such map file", "pass the wall.glb written by `arproj map … --out DIR`")
    check_file(glb_path, "map file (GLB)", MAX_GLB_BYTES, "pass the wall.glb written by `arproj map … --out DIR`")
    try:
        loaded = trimesh.load(glb_path, file_type="glb" if glb_path.suffix.lower() != ".gltf" else None,
                              force=None)
    except Exception as err:  # trimesh raises many exception types for bad files
        raise InputError(f"{glb_path}: not a readable GLB mesh ({type(err).__name__}: {err})",
                         "re-export it with `arproj map`") from None
    mesh, other = _wall_and_other_meshes(loaded, glb_path)
    texture, uv_from_xy = _texture_and_uv_map(mesh, glb_path)
    objects_path = Path(objects_path) if objects_path is not None else glb_path.with_name(OBJECTS_FILE)
    objects = read_objects(objects_path) if objects_path.exists() else []
    coverage = Coverage.load(glb_path.with_name(COVERAGE_FILE))
    check_objects_within(objects, coverage.wall_bounds, objects_path)
    return WallMap(mesh, objects, texture, uv_from_xy, coverage, source=str(glb_path), other=other)


def plane_mesh(x0: float, y0: float, x1: float, y1: float) -> trimesh.Trimesh:
    """A flat wall rectangle (two triangles) at z = 0 in the wall frame."""
    vertices = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    return trimesh.Trimesh(vertices, np.array([[0, 1, 2], [0, 2, 3]]), process=False)


def _wall_and_other_meshes(loaded: object, path: Path) -> tuple[trimesh.Trimesh, trimesh.Trimesh | None]:
    """The GLB's wall mesh and its other surfaces (None: none). The mapping exports one textured mesh (the
    wall) and at most one untextured (the rest); other layouts are concatenated into one (textures dropped)."""
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geometries:
            raise InputError(f"{path}: the GLB holds no triangle mesh", "re-export it with `arproj map`")
        textured = [g for g in geometries if getattr(g.visual, "kind", None) == "texture"]
        rest = [g for g in geometries if getattr(g.visual, "kind", None) != "texture"]
        if len(textured) == 1 and len(rest) <= 1:
            return _checked_mesh(textured[0], path), _checked_mesh(rest[0], path) if rest else None
        mesh = geometries[0] if len(geometries) == 1 else trimesh.util.concatenate(geometries)
        assert isinstance(mesh, trimesh.Trimesh)  # meshes concatenate to a mesh (trimesh types it as Geometry)
    elif isinstance(loaded, trimesh.Trimesh):
        mesh = loaded
    else:
        raise InputError(f"{path}: the GLB holds a {type(loaded).__name__}, not a triangle mesh")
    return _checked_mesh(mesh, path), None


def _checked_mesh(mesh: trimesh.Trimesh, path: Path) -> trimesh.Trimesh:
    if len(mesh.faces) == 0 or not np.all(np.isfinite(mesh.vertices)):
        raise InputError(f"{path}: the mesh is empty or has non-finite vertices")
    if np.abs(mesh.vertices).max() > MAX_WALL_M:
        raise InputError(f"{path}: the mesh reaches {np.abs(mesh.vertices).max():.3g} m from the wall's origin; a "
                         f"wall map lies within {MAX_WALL_M:g} m", "re-export it with `arproj map`")
    return mesh


def mesh_texture(mesh: trimesh.Trimesh) -> NDArray[np.uint8] | None:
    """The RGBA image (h, w, 4) a textured mesh's UVs point into (None: no UVs or no image)."""
    visual = mesh.visual
    if getattr(visual, "kind", None) != "texture" or getattr(visual, "uv", None) is None:
        return None
    material = getattr(visual, "material", None)
    image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    return None if image is None else np.asarray(image.convert("RGBA"), dtype=np.uint8)


def _texture_and_uv_map(mesh: trimesh.Trimesh, path: Path
                        ) -> tuple[NDArray[np.uint8] | None, NDArray[np.float64] | None]:
    """The mesh's RGBA texture and the affine map wall (x, y) → uv it uses, when the UVs are affine in x, y."""
    rgba = mesh_texture(mesh)
    if rgba is None:
        return None, None
    uv = np.asarray(getattr(mesh.visual, "uv", None), dtype=np.float64)
    xy1 = np.column_stack([mesh.vertices[:, :2], np.ones(len(mesh.vertices))])
    A, *_ = np.linalg.lstsq(xy1, np.asarray(uv, dtype=np.float64), rcond=None)
    residual = np.abs(xy1 @ A - uv).max() if len(uv) else np.inf
    if not np.isfinite(residual) or residual > 1e-3:
        raise InputError(f"{path}: the texture is not laid out in wall coordinates (uv not affine in x, y; "
                         f"residual {residual:.3g})", "export the map with `arproj map`")
    return rgba, A.T


# Truth objects of a wall description file (scanner.wall) in the mapping's classes, for `--truth` and tests.
def _class_of(obj: object) -> str:
    kind, material = obj.kind, obj.material  # type: ignore[attr-defined]
    if kind == "cable":
        return "power_line" if obj.live else "metal"  # type: ignore[attr-defined]
    if kind == "pipe":
        # A plastic pipe is what the channels would call it: non-metal (a water-filled one raises the
        # capacitive level; a dry one no channel sees, but the truth knows it is there and a driller must avoid
        # it, so it is drawn in the same colour rather than left out)
        return "metal_pipe" if obj.is_metal else "non_metal"  # type: ignore[attr-defined]
    if kind in ("screw", "nail"):
        return "fastener"
    if kind in ("stud", "beam"):
        return "non_metal" if material == "wood" else "metal"
    if kind == "plate":
        return "metal"
    return "cavity"


def wall_map_from_wall_file(path: str | Path) -> WallMap:
    """A WallMap from a wall description file's truth: a flat mesh of the wall and its objects, fully scanned.

    Used when no mapping output exists yet (`arproj project --truth WALL.yaml`), so the session can be tried
    end to end; a real session projects what the mapping found (wall.glb + objects.json).
    """
    from scanner.wall import load_wall

    return wall_map_from_wall(load_wall(path), source=str(path))


def wall_map_from_wall(wall: object, source: str = "wall truth") -> WallMap:
    """wall_map_from_wall_file for a scanner.wall.Wall already in memory (e.g. scanner.wall.random_wall)."""
    objects = []
    for o in wall.objects:  # type: ignore[attr-defined]
        width = float(o.diameter_m or 0.0)
        geometry = np.asarray(o.geometry_m, dtype=np.float64)
        shape = "point" if o.kind in ("screw", "nail") else "outline" if len(geometry) >= 3 and o.kind in (
            "stud", "beam", "plate", "cavity") else "line"
        objects.append(MappedObject(_class_of(o), geometry, width, 1.0, tol.TRUTH_MAP_SIGMA_M,
                                    depth_m=float(o.depth_m), depth_sigma_m=0.0, shape=shape))
    w, h = wall.width_m, wall.height_m  # type: ignore[attr-defined]
    # The truth is known everywhere: what a complete, perfect scan would have covered.
    coverage = Coverage.complete(GridInfo.covering(0.0, 0.0, w, h, tol.TRUTH_COVERAGE_CELL_M), bounds=(0.0, 0.0, w, h))
    # its room as the scan's priors take it: floor and ceiling from the wall file or the survey, its ends the corners
    floor, ceiling, origin = room_heights(wall)  # type: ignore[arg-type]
    room = WallRoom(floor, ceiling, (0.0, float(w)), opening_boxes(wall.openings),  # type: ignore[attr-defined]
                    np.asarray(wall.sockets, dtype=np.float64).reshape(-1, 2), f"{origin}")  # type: ignore[attr-defined]
    return WallMap(plane_mesh(0.0, 0.0, w, h), objects, coverage=coverage, source=source, room=room)
