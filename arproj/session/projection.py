"""The pre-warped beamer frame: the in-wall map drawn on the wall mesh, seen from the projector.

The overlays are rasterised in wall coordinates (overlays.draw_map) and become the texture of the mapping's
mesh; the lead's MeshRenderer then draws that mesh with the projector's exact intrinsics (lens shift and
distortion included) from T_wall_from_projector. Because the mesh is rendered — not warped by a homography —
room corners and other non-planar walls land right too.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray
from PIL import Image

from arproj.session import overlays
from arproj.session import tolerances as tol
from arproj.session.wallmap import WallMap
from geometry.intrinsics import Intrinsics
from render import MeshRenderer
from render.simplify import PROJECTED_ERROR_PX

SIGMA_QUANTUM_M = 0.0005  # bands are redrawn when the registration σ changes by this much, not every frame
CHECK_MARK_RADIUS_M = 0.008


def textured_mesh(wall_map: WallMap, raster: overlays.WallRaster) -> trimesh.Trimesh:
    """The map's mesh with UVs that put the raster at the vertices' wall (x, y). Its texture's alpha tells
    the frame what lies under each pixel (overlays.frame_layers): BUSY_ALPHA on the raster's busy texels,
    MAP_ALPHA on the rest of what it draws, 0 where it draws nothing."""
    mesh = wall_map.mesh
    uv = raster.uv(np.asarray(mesh.vertices)[:, :2])
    image = raster.image
    if raster.busy is not None:
        image = image.copy()
        drawn = image[..., 3] > 0
        image[..., 3] = np.where(raster.busy, overlays.BUSY_ALPHA, np.where(drawn, overlays.MAP_ALPHA, 0))
    material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(image, "RGBA"))
    return trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, material=material))


def check_mark_raster(wall_map: WallMap, marks_xy: NDArray[np.float64],
                      radius_m: float | NDArray[np.float64] = CHECK_MARK_RADIUS_M) -> overlays.WallRaster:
    """White discs on black at wall points marks_xy (n, 2) (radius per mark or one for all): the closed
    loop's check frame."""
    import cv2

    raster = overlays.empty_raster(wall_map.extent)
    centres = raster.to_px(marks_xy)
    radii = np.broadcast_to(np.asarray(radius_m, dtype=np.float64), (len(centres),)) * raster.px_per_m
    for c, r in zip(centres, radii, strict=True):
        cv2.circle(raster.image, (round(c[0] * 16), round(c[1] * 16)), round(r * 16),
                   (255, 255, 255, 255), -1, cv2.LINE_AA, shift=4)
    return raster


class MapProjector:
    """Renders beamer frames of a wall map. Owns a MeshRenderer; use as a context manager."""

    def __init__(self, wall_map: WallMap, projector: Intrinsics, ctx: object | None = None) -> None:
        self.wall_map = wall_map
        self.projector = projector
        # The map and the closed loop's check marks each keep their own renderer (mesh and texture): every
        # update shows marks, then the map, and redrawing the map's overlays each time costs seconds.
        # Each draws its mesh simplified to what the projector resolves (render.simplify).
        self._renderers = {name: MeshRenderer(ctx=ctx, max_error_px=PROJECTED_ERROR_PX)  # type: ignore[arg-type]
                           for name in ("map", "marks")}
        self._keys: dict[str, tuple | None] = {"map": None, "marks": None}
        self._rasters: dict[str, overlays.WallRaster | None] = {"map": None, "marks": None}
        self._active = "map"
        self.last_alpha: NDArray[np.uint8] | None = None  # the last frame's alpha (overlays.frame_layers)

    @property
    def raster(self) -> overlays.WallRaster | None:
        """The wall raster of what render() draws now (the map's or the check marks')."""
        return self._rasters[self._active]

    @property
    def map_raster(self) -> overlays.WallRaster | None:
        """The wall raster of the map as last drawn (None: not drawn yet), whatever render() draws now."""
        return self._rasters["map"]

    def __enter__(self) -> MapProjector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def release(self) -> None:
        for renderer in self._renderers.values():
            renderer.release()

    def _show(self, which: str, key: tuple, make: Callable[[], overlays.WallRaster]) -> None:
        self._active = which
        if key == self._keys[which]:
            return
        raster = make()
        mesh = textured_mesh(self.wall_map, raster)
        other = self.wall_map.other  # measured surfaces with no map (floor, clutter): drawn black, they hide the
        self._renderers[which].set_mesh(mesh if other is None else trimesh.Scene([mesh, other]))  # wall behind
        self._rasters[which], self._keys[which] = raster, key

    def set_overlays(self, registration_sigma_m: float, drill_xy: ArrayLike | None = None,
                     show_zones: bool = True, clip: NDArray[np.float64] | None = None) -> None:
        """(Re)draw the wall texture when what it shows changed (σ is quantised so jitter does not redraw).
        clip: polygon (k, 2) wall metres outside which nothing is drawn (the trusted region)."""
        sigma_q = round(float(registration_sigma_m) / SIGMA_QUANTUM_M) * SIGMA_QUANTUM_M
        drill = None if drill_xy is None else tuple(np.round(np.asarray(drill_xy, dtype=float), 4))
        clip_key = None if clip is None else np.asarray(clip).round(3).tobytes()
        self._show("map", ("map", sigma_q, drill, show_zones, clip_key),
                   lambda: overlays.draw_map(self.wall_map, sigma_q, None if drill is None else np.array(drill),
                                             show_zones, clip=clip))

    def set_check_marks(self, marks_xy: NDArray[np.float64],
                        radius_m: float | NDArray[np.float64] = CHECK_MARK_RADIUS_M) -> None:
        key = ("marks", np.asarray(marks_xy).round(5).tobytes(), np.asarray(radius_m).round(5).tobytes())
        self._show("marks", key, lambda: check_mark_raster(self.wall_map, marks_xy, radius_m))

    def render(self, T_wall_from_projector: ArrayLike) -> NDArray[np.uint8]:
        """The pre-warped frame (h, w, 3) uint8 RGB for the projector at T_wall_from_projector (its alpha, what
        lies under each pixel, kept in last_alpha)."""
        if self._keys[self._active] is None:
            self.set_overlays(tol.DEFAULT_MAP_SIGMA_M)
        rgba = self._renderers[self._active].render(self.projector, T_wall_from_projector, alpha=True).color
        self.last_alpha = rgba[..., 3]
        return np.ascontiguousarray(rgba[..., :3])

    def legend_layers(self) -> tuple[NDArray[np.bool_] | None, NDArray[np.bool_] | None]:
        """(busy, mapped) pixel masks of the last frame (overlays.frame_layers); None before any."""
        return (None, None) if self.last_alpha is None else overlays.frame_layers(self.last_alpha)
