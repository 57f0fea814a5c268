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
from render.vertex_order import cache_friendly

# Flip NDC y so the framebuffer's first row is the image's top row: read-back needs no flip or copy.
_IMAGE_ROWS_DOWN = np.diag([1.0, -1.0, 1.0, 1.0])
# The depth range is fitted to the mesh; this keeps 24-bit depth precise whatever the scene size.
_NEAR_FAR_RATIO = 1e-4
# Bilinear within the nearest mip level: on llvmpipe, trilinear costs ~20 % and anisotropic filtering 2-3x the
# frame time of a textured wall, for differences a projected picture does not show.
_TEXTURE_FILTER = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)


@dataclass
class RenderResult:
    """color: (h, w, 3) uint8 RGB (RGBA with alpha=True); depth: (h, w) float32 metres along the optical
    axis, NaN where nothing was drawn (only when asked for)."""

    color: NDArray[np.uint8]
    depth: NDArray[np.float32] | None = None


@dataclass
class _DrawItem:
    vbo: moderngl.Buffer
    ibo: moderngl.Buffer
    vao: moderngl.VertexArray
    texture: moderngl.Texture | None
    chunks: ChunkBounds


@dataclass
class _Target:
    fbo: moderngl.Framebuffer
    color: moderngl.Texture
    depth: moderngl.Texture


class MeshRenderer:
    """Draws one mesh (or a scene of meshes) into offscreen framebuffers of any size."""

    def __init__(self, ctx: moderngl.Context | None = None, background: ArrayLike = (0, 0, 0, 0)) -> None:
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
        self._maps: dict[Intrinsics, tuple[moderngl.Texture, Intrinsics]] = {}
        self._released = False

    # -- scene -----------------------------------------------------------------------------------------
    def set_mesh(self, mesh: trimesh.Trimesh | trimesh.Scene) -> None:
        """Upload a mesh (textured via UVs + image, or with vertex colours) replacing the previous one.

        A trimesh.Scene (e.g. from a GLB file) is drawn with each node's transform applied.
        """
        geometries = _scene_geometries(mesh)
        if not geometries:
            raise InputError("the mesh to render has no triangles")
        corners = []
        with self.ctx:
            self._release_items()
            for geometry in geometries:
                self._items.append(self._upload(geometry))
                corners.append(geometry.bounds)
        b = np.vstack(corners)
        self._bounds = np.array([b.min(axis=0), b.max(axis=0)])

    def _upload(self, mesh: trimesh.Trimesh) -> _DrawItem:
        vertex_order, faces = cache_friendly(mesh.vertices, mesh.faces)
        positions = np.asarray(mesh.vertices, dtype=np.float32)[vertex_order]
        textured = _texture_of(mesh)
        if textured is not None:
            image, uv = textured
            uv = uv[vertex_order]
            # trimesh's UV v runs up the image; GL textures here are stored top row first.
            uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)
            vertices = np.hstack([positions, uv])
            layout = ("3f 2f", "in_position", "in_uv")
            texture = self.ctx.texture((image.shape[1], image.shape[0]), 4, np.ascontiguousarray(image))
            texture.build_mipmaps()
            texture.filter = _TEXTURE_FILTER
            texture.repeat_x = texture.repeat_y = False
        else:
            colors = _vertex_colors(mesh)[vertex_order]
            vertices = np.hstack([positions, colors])
            layout = ("3f 4f", "in_position", "in_color")
            texture = None
        program = self._programs[texture is not None]
        vbo = self.ctx.buffer(np.ascontiguousarray(vertices, dtype=np.float32))
        ibo = self.ctx.buffer(np.ascontiguousarray(faces))
        vao = self.ctx.vertex_array(program, [(vbo, *layout)], index_buffer=ibo, index_element_size=4)
        return _DrawItem(vbo, ibo, vao, texture, ChunkBounds.of(positions, faces))

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
        for item in self._items:
            program = item.vao.program
            clip_uniform = program["u_clip_from_world"]
            assert isinstance(clip_uniform, moderngl.Uniform)  # the mesh shader declares it a uniform mat4
            clip_uniform.write(clip_bytes)
            if item.texture is not None:
                item.texture.use(0)
                program["u_texture"] = 0
            for first, count in item.chunks.visible_ranges(clip):
                item.vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first)
        return target

    def _read_color(self, fbo: moderngl.Framebuffer, intr: Intrinsics, components: int) -> NDArray[np.uint8]:
        out = np.empty((intr.height, intr.width, components), dtype=np.uint8)
        fbo.read_into(out, components=components, alignment=1)
        return out

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
            item.vao.release()
            item.vbo.release()
            item.ibo.release()
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
        self._targets, self._maps = {}, {}

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
