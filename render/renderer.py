"""Offscreen renderer: a (textured) trimesh drawn from any intrinsics and pose, with lens distortion.

    with MeshRenderer() as renderer:
        renderer.set_mesh(trimesh.load("wall.glb"))
        frame = renderer.render(projector_intrinsics, T_wall_from_projector).color   # (h, w, 3) uint8

The mesh's coordinates are the "world" of the pose (for the projection session: the wall frame). Rendering
is unlit: a projector emits the texture's colours as they are. Where the intrinsics have distortion, a second
pass warps an (enlarged) pinhole render exactly as cv2.projectPoints distorts points. Every GPU object is
owned by the renderer and released by release() / on leaving the `with` block.

Meshes are reordered at upload for the vertex cache (vertex_order.py): the same triangles, drawn with
about 40 % less vertex work on llvmpipe; and chunks of triangles outside the view are not drawn (culling.py).

With max_error_px (e.g. simplify.PROJECTED_ERROR_PX, a tenth of a pixel), a textured mesh is drawn simplified
to what the view can resolve (simplify.py): at upload for the intrinsics and nearest depth given to set_mesh,
else for the first view drawn; and again whenever a view comes closer than the simplification allows, so that
no frame's picture moves by more than max_error_px from the full mesh's. The full mesh stays on the CPU for that.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import moderngl
import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

import shaders
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, transform_points
from render.culling import ChunkBounds
from render.distortion import distortion_map
from render.gl import create_context, release_framebuffer
from render.projection import linear_depth, projection_matrix, view_matrix
from render.simplify import Decimation, decimation_of, ladder_floor, tolerance_m
from render.vertex_order import cache_friendly

# Flip NDC y so the framebuffer's first row is the image's top row: read-back needs no flip or copy.
_IMAGE_ROWS_DOWN = np.diag([1.0, -1.0, 1.0, 1.0])
# The depth range is fitted to the mesh; this keeps 24-bit depth precise whatever the scene size.
_NEAR_FAR_RATIO = 1e-4
# Bilinear within the nearest mip level: on llvmpipe, trilinear costs ~20 % and anisotropic filtering 2-3x the
# frame time of a textured wall, for differences a projected picture does not show.
_TEXTURE_FILTER = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
# Simplifying for a view, assume the head may come this much closer before the mesh must be simplified again.
NEAR_MARGIN = 0.85
# The nearest depth a view sees is taken over the vertices that project within the image widened by this
# fraction on each side, where a triangle reaching into the image has a corner (the simplified wall's triangles
# span a few centimetres, 30-60 px at 1.7 m); one longer still could reach nearer by a few per cent of the
# depth, which NEAR_MARGIN covers.
_NEAR_IMAGE_MARGIN = 0.05


@dataclass
class RenderResult:
    """color: (h, w, 3) uint8 RGB (RGBA with alpha=True); depth: (h, w) float32 metres along the optical
    axis, NaN where nothing was drawn (only when asked for)."""

    color: NDArray[np.uint8]
    depth: NDArray[np.float32] | None = None


@dataclass
class _Geometry:
    """The GPU buffers of one version (full or simplified) of a mesh's triangles."""

    vbo: moderngl.Buffer
    ibo: moderngl.Buffer
    vao: moderngl.VertexArray
    chunks: ChunkBounds
    positions: NDArray[np.float32]  # (n, 3), for the nearest depth a view sees
    tolerance_m: float  # its measured deviation is within this (0: the full mesh)

    @property
    def n_faces(self) -> int:
        return self.chunks.n_faces

    def nearest_depth(self, clip_from_world: NDArray[np.float64]) -> float | None:
        """The least depth (metres along the optical axis) of the vertices in (or near) the view; None if
        none is in front of the camera there."""
        clip = self.positions @ clip_from_world[:, :3].T.astype(np.float32) + clip_from_world[:, 3].astype(
            np.float32)
        w = clip[:, 3]
        reach = w * (1.0 + 2.0 * _NEAR_IMAGE_MARGIN)
        near = (w > 0) & (np.abs(clip[:, 0]) <= reach) & (np.abs(clip[:, 1]) <= reach)
        return float(w[near].min()) if near.any() else None

    def release(self) -> None:
        self.vao.release()
        self.vbo.release()
        self.ibo.release()


@dataclass
class _DrawItem:
    geometry: _Geometry
    texture: moderngl.Texture | None
    decimation: Decimation | None   # None: drawn in full (no simplification asked, or no UVs)
    pending: bool                   # uploaded in full, to be simplified for the first view


@dataclass
class _Target:
    fbo: moderngl.Framebuffer
    color: moderngl.Texture
    depth: moderngl.Texture


class MeshRenderer:
    """Draws one mesh (or a scene of meshes) into offscreen framebuffers of any size."""

    def __init__(self, ctx: moderngl.Context | None = None, background: ArrayLike = (0, 0, 0, 0),
                 max_error_px: float | None = None) -> None:
        if max_error_px is not None and not max_error_px > 0:
            raise InputError(f"max_error_px={max_error_px} is not a bound; give pixels > 0 (or None: the full mesh)")
        self.max_error_px = max_error_px
        self.triangles_drawn = 0  # in the last frame, after culling
        self._owns_ctx = ctx is None
        self.ctx = create_context() if ctx is None else ctx
        rgba = np.zeros(4)  # fewer than four values: the rest 0, as Framebuffer.clear's defaults
        given = np.asarray(background, dtype=float).ravel()[:4]
        rgba[:len(given)] = given
        self.background = (float(rgba[0]), float(rgba[1]), float(rgba[2]), float(rgba[3]))
        # Every GL call runs inside `with self.ctx`: another library's context (pyrender's, say) may be
        # current in this thread, and leaving ours current would break it in turn.
        with self.ctx:
            self._programs = {
                True: self.ctx.program(**shaders.program_source("mesh", {"HAS_TEXTURE": 1})),
                False: self.ctx.program(**shaders.program_source("mesh")),
            }
            self._distort_program = self.ctx.program(**shaders.program_source("lens_distortion"))
            self._empty_vao = self.ctx.vertex_array(self._distort_program, [])
        self._items: list[_DrawItem] = []
        self._bounds: NDArray[np.float64] | None = None
        self._targets: dict[tuple[int, int], _Target] = {}
        self._rgba_scratch: dict[tuple[int, int], NDArray[np.uint8]] = {}  # per size, reused by each RGB read
        self._maps: dict[Intrinsics, tuple[moderngl.Texture, Intrinsics]] = {}
        self._released = False

    # -- scene -----------------------------------------------------------------------------------------
    def set_mesh(self, mesh: trimesh.Trimesh | trimesh.Scene, intr: Intrinsics | None = None,
                 nearest_m: float | None = None) -> None:
        """Upload a mesh (textured via UVs + image, or with vertex colours) replacing the previous one.

        A trimesh.Scene (e.g. from a GLB file) is drawn with each node's transform applied. With max_error_px
        set, a textured mesh is simplified to what intr resolves at depths ≥ nearest_m (metres along the
        optical axis), or, without them, for the first view drawn.
        """
        geometries = _scene_geometries(mesh)
        if not geometries:
            raise InputError("the mesh to render has no triangles")
        if (intr is None) != (nearest_m is None):
            raise ValueError("set_mesh needs both intr and nearest_m, or neither")
        if nearest_m is not None and not nearest_m > 0:
            raise InputError(f"nearest_m={nearest_m} is not a distance; give the nearest depth in metres (> 0)")
        corners = []
        with self.ctx:
            self._release_items()
            for geometry in geometries:
                self._items.append(self._upload(geometry, intr, nearest_m))
                corners.append(geometry.bounds)
        b = np.vstack(corners)
        self._bounds = np.array([b.min(axis=0), b.max(axis=0)])

    @property
    def triangles(self) -> int:
        """Triangles uploaded (after simplification), over all meshes of the scene."""
        return sum(item.geometry.n_faces for item in self._items)

    def _upload(self, mesh: trimesh.Trimesh, intr: Intrinsics | None, nearest_m: float | None) -> _DrawItem:
        textured = _texture_of(mesh)
        if textured is not None:
            image, uv = textured
            texture = self.ctx.texture((image.shape[1], image.shape[0]), 4, np.ascontiguousarray(image))
            texture.build_mipmaps()
            texture.filter = _TEXTURE_FILTER
            texture.repeat_x = texture.repeat_y = False
            bound_px = self.max_error_px
            decimation = None if bound_px is None else decimation_of(mesh.vertices, mesh.faces, uv)
            item = _DrawItem(self._upload_geometry(mesh.vertices, mesh.faces, uv, None, 0.0), texture,
                             decimation, pending=decimation is not None)
            if bound_px is not None and intr is not None and nearest_m is not None:
                self._simplify(item, ladder_floor(tolerance_m(intr, nearest_m, bound_px)))
            return item
        return _DrawItem(self._upload_geometry(mesh.vertices, mesh.faces, None, _vertex_colors(mesh), 0.0), None,
                         None, pending=False)

    def _upload_geometry(self, vertices: ArrayLike, faces: ArrayLike, uv: NDArray[np.float64] | None,
                         colors: NDArray[np.float32] | None, tol_m: float) -> _Geometry:
        vertex_order, order_faces = cache_friendly(np.asarray(vertices), np.asarray(faces))
        positions = np.asarray(vertices, dtype=np.float32)[vertex_order]
        if uv is not None:
            uv = uv[vertex_order]
            # trimesh's UV v runs up the image; GL textures here are stored top row first.
            attribute = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)
            layout = ("3f 2f", "in_position", "in_uv")
        else:
            assert colors is not None
            attribute = colors[vertex_order]
            layout = ("3f 4f", "in_position", "in_color")
        program = self._programs[uv is not None]
        vbo = self.ctx.buffer(np.ascontiguousarray(np.hstack([positions, attribute]), dtype=np.float32))
        ibo = self.ctx.buffer(np.ascontiguousarray(order_faces))
        vao = self.ctx.vertex_array(program, [(vbo, *layout)], index_buffer=ibo, index_element_size=4)
        return _Geometry(vbo, ibo, vao, ChunkBounds.of(positions, order_faces), positions, tol_m)

    def _simplify(self, item: _DrawItem, tol_m: float) -> None:
        """Replace the item's triangles by its mesh simplified within tol_m (the texture stays)."""
        assert item.decimation is not None
        simplified = item.decimation.within(tol_m)
        geometry = self._upload_geometry(simplified.positions, simplified.faces, simplified.uv, None, tol_m)
        item.geometry.release()
        item.geometry, item.pending = geometry, False

    def _resolve(self, item: _DrawItem, intr: Intrinsics, clip: NDArray[np.float64], near: float) -> None:
        """Simplify the item for this view if it waits for one, or again if this view comes closer than its
        simplification allows (its deviation would show by more than max_error_px)."""
        bound_px = self.max_error_px
        if item.decimation is None or bound_px is None:
            return
        nearest = item.geometry.nearest_depth(clip)
        if nearest is None:
            return  # nothing of it in view
        nearest = max(nearest, near)
        if item.pending or item.geometry.tolerance_m > tolerance_m(intr, nearest, bound_px):
            self._simplify(item, ladder_floor(tolerance_m(intr, nearest * NEAR_MARGIN, bound_px)))

    # -- drawing ---------------------------------------------------------------------------------------
    def render(self, intr: Intrinsics, T_world_from_camera: ArrayLike, depth: bool = False,
               alpha: bool = False, near: float | None = None, far: float | None = None) -> RenderResult:
        """The mesh as seen (or as to be projected) through intr at pose T_world_from_camera."""
        if self._released:
            raise RuntimeError("MeshRenderer used after release()")
        if not self._items:
            raise RuntimeError("MeshRenderer.render called before set_mesh")
        T = np.asarray(T_world_from_camera, dtype=np.float64)
        if near is None or far is None:
            auto_near, auto_far = self._depth_range(T)
            near, far = near or auto_near, far or auto_far
        components = 4 if alpha else 3
        with self.ctx:
            if not intr.has_distortion:
                target = self._draw(intr, T, near, far)
                color = self._read_color(target.fbo, intr, components)
                z = self._read_depth(target.fbo, intr, near, far) if depth else None
                return RenderResult(color, z)
            map_texture, pinhole = self._map(intr)
            source = self._draw(pinhole, T, near, far)
            out = self._target(intr.width, intr.height, with_depth=False)
            out.fbo.use()
            out.fbo.clear(*self.background)
            source.color.use(0)
            map_texture.use(1)
            self._distort_program["u_pinhole"] = 0
            self._distort_program["u_map"] = 1
            self._distort_program["u_pinhole_size"] = (float(pinhole.width), float(pinhole.height))
            self.ctx.disable(moderngl.DEPTH_TEST)
            self._empty_vao.render(moderngl.TRIANGLES, vertices=3)
            color = self._read_color(out.fbo, intr, components)
            z = None
            if depth:
                # Nearest neighbour: blending depths across an edge would invent surfaces.
                z_pinhole = self._read_depth(source.fbo, pinhole, near, far)
                dmap = distortion_map(intr)
                z = np.asarray(cv2.remap(z_pinhole, dmap.map_xy[..., 0], dmap.map_xy[..., 1], cv2.INTER_NEAREST,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan")), dtype=np.float32)
            return RenderResult(color, z)

    def _draw(self, intr: Intrinsics, T_world_from_camera: NDArray[np.float64], near: float, far: float
              ) -> _Target:
        target = self._target(intr.width, intr.height, with_depth=True)
        target.fbo.use()
        target.fbo.clear(*self.background, depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        clip = _IMAGE_ROWS_DOWN @ projection_matrix(intr, near, far) @ view_matrix(T_world_from_camera)
        clip_bytes = clip.astype(np.float32).T.tobytes()  # GLSL matrices are column-major
        self.triangles_drawn = 0
        for item in self._items:
            self._resolve(item, intr, clip, near)
            geometry = item.geometry
            program = geometry.vao.program
            clip_uniform = program["u_clip_from_world"]
            assert isinstance(clip_uniform, moderngl.Uniform)  # the mesh shader declares it a uniform mat4
            clip_uniform.write(clip_bytes)
            if item.texture is not None:
                item.texture.use(0)
                program["u_texture"] = 0
            for first, count in geometry.chunks.visible_ranges(clip):
                geometry.vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first)
                self.triangles_drawn += count
        return target

    def _read_color(self, fbo: moderngl.Framebuffer, intr: Intrinsics, components: int) -> NDArray[np.uint8]:
        """The colour attachment as a new (h, w, components) array. RGB is read as RGBA and dropped to RGB by
        OpenCV: Mesa's RGBA→RGB conversion in glReadPixels costs 2-3x as much as the RGBA read itself."""
        if components == 4:
            out = np.empty((intr.height, intr.width, 4), dtype=np.uint8)
            fbo.read_into(out, components=4, alignment=1)
            return out
        key = (intr.width, intr.height)
        rgba = self._rgba_scratch.get(key)
        if rgba is None:
            rgba = self._rgba_scratch[key] = np.empty((intr.height, intr.width, 4), dtype=np.uint8)
        fbo.read_into(rgba, components=4, alignment=1)
        return np.asarray(cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), dtype=np.uint8)

    def _read_depth(self, fbo: moderngl.Framebuffer, intr: Intrinsics, near: float, far: float
                    ) -> NDArray[np.float32]:
        raw = np.frombuffer(fbo.read(components=1, attachment=-1, dtype="f4", alignment=1), dtype=np.float32)
        return linear_depth(raw.reshape(intr.height, intr.width), near, far)

    def _depth_range(self, T_world_from_camera: NDArray[np.float64]) -> tuple[float, float]:
        assert self._bounds is not None
        lo, hi = self._bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        z = transform_points(invert(T_world_from_camera), corners)[:, 2]
        far = max(float(z.max()) * 1.01 + 1e-3, 1e-2)
        near = max(float(z.min()) * 0.99, far * _NEAR_FAR_RATIO)
        return near, far

    def _target(self, width: int, height: int, with_depth: bool) -> _Target:
        key = (width, height)
        if key not in self._targets:
            color = self.ctx.texture((width, height), 4)
            color.filter = (moderngl.LINEAR, moderngl.LINEAR)
            color.repeat_x = color.repeat_y = False
            depth_tex = self.ctx.depth_texture((width, height))
            fbo = self.ctx.framebuffer(color_attachments=[color], depth_attachment=depth_tex)
            self._targets[key] = _Target(fbo, color, depth_tex)
        return self._targets[key]

    def _map(self, intr: Intrinsics) -> tuple[moderngl.Texture, Intrinsics]:
        if intr not in self._maps:
            dmap = distortion_map(intr)
            texture = self.ctx.texture((intr.width, intr.height), 2, np.ascontiguousarray(dmap.map_xy),
                                       dtype="f4")
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._maps[intr] = (texture, dmap.pinhole)
        return self._maps[intr]

    # -- lifetime --------------------------------------------------------------------------------------
    def _release_items(self) -> None:
        for item in self._items:
            item.geometry.release()
            if item.texture is not None:
                item.texture.release()
        self._items = []

    def release(self) -> None:
        """Free every GPU object now (and the context, when the renderer created it)."""
        if self._released:
            return
        with self.ctx:
            self._release_gpu_objects()
        if self._owns_ctx:
            self.ctx.release()
        self._released = True

    def _release_gpu_objects(self) -> None:
        self._release_items()
        for target in self._targets.values():
            release_framebuffer(target.fbo)
            target.color.release()
            target.depth.release()
        for texture, _ in self._maps.values():
            texture.release()
        self._empty_vao.release()
        self._distort_program.release()
        for program in self._programs.values():
            program.release()
        self._targets, self._maps, self._rgba_scratch = {}, {}, {}

    def __enter__(self) -> MeshRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _scene_geometries(mesh: trimesh.Trimesh | trimesh.Scene) -> list[trimesh.Trimesh]:
    if isinstance(mesh, trimesh.Trimesh):
        return [mesh] if len(mesh.faces) else []
    if isinstance(mesh, trimesh.Scene):
        return [g for g in mesh.dump(concatenate=False) if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    raise InputError(f"cannot render a {type(mesh).__name__}; expected a trimesh mesh or scene (e.g. a GLB)")


def _texture_of(mesh: trimesh.Trimesh) -> tuple[NDArray[np.uint8], NDArray[np.float64]] | None:
    """(RGBA image, UVs) of a textured mesh; None when it has no UVs or no texture image."""
    visual = mesh.visual
    if not isinstance(visual, trimesh.visual.TextureVisuals) or visual.uv is None:
        return None
    material = visual.material
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)
    if image is None:
        return None
    rgba = np.asarray(image.convert("RGBA") if hasattr(image, "convert") else image, dtype=np.uint8)
    if rgba.ndim != 3 or rgba.shape[2] != 4:
        raise InputError(f"mesh texture has shape {rgba.shape}; expected an RGB(A) image")
    return rgba, np.asarray(visual.uv, dtype=np.float64)


def _vertex_colors(mesh: trimesh.Trimesh) -> NDArray[np.float32]:
    visual = mesh.visual
    n = len(mesh.vertices)
    if isinstance(visual, trimesh.visual.TextureVisuals):  # no texture image: all in the material's colour
        colors = np.broadcast_to(np.asarray(visual.material.main_color, dtype=np.float32), (n, 4))
    else:
        colors = np.asarray(visual.vertex_colors if visual is not None else None, dtype=np.float32)
    if colors.shape != (n, 4):
        colors = np.full((n, 4), 255.0, dtype=np.float32)
    return colors / 255.0
