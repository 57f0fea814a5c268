"""GPU part of the simulated site: the room mesh lit by the projector, seen through a pinhole camera.

The room's surfaces are drawn with shaders/sim_room.glsl through the camera's pinhole (enlarged for its lens
distortion), with shadows from a shadow map (shaders/sim_shadow.glsl) when something can occlude. Two modes:

- deferred (what Site.photograph uses): per pixel the albedo, depth, the projector's illuminance per unit
  light, and which projector pixel (u, v) lights it with what blur — everything but the projector image, so
  a view is rendered once per pose and any number of patterns are looked up on the CPU;
- direct (Site.render_radiance, the cross-check): the projector image's blur levels textured in the shader,
  giving linear radiance plus depth.

Optional multisampling (cameras.msaa_samples) integrates silhouettes over the pixel. The camera-side effects
(lens distortion, defocus, noise, exposure, gamma) are applied on the CPU (arproj.sim.optics).
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np
from numpy.typing import NDArray

import shaders
from arproj.sim.room import KIND_TARGET, Surface, triangulate
from geometry.intrinsics import Intrinsics
from geometry.poses import invert
from render.gl import release_framebuffer
from render.projection import projection_matrix, view_matrix

# Flip NDC y so the framebuffer's first row is the image's top row.
_IMAGE_ROWS_DOWN = np.diag([1.0, -1.0, 1.0, 1.0])
NEAR_M, FAR_M = 0.02, 200.0
MSAA_SAMPLES = 4              # the direct path's multisampling
MAX_ANISOTROPY = 8.0          # for printed targets and the projector image: sharp at oblique views
ROOM_ANISOTROPY = 1.0         # walls, floor, ceiling: faint textures, and anisotropy costs ~1/3 of the shading
MAX_BLUR_LEVELS = 8


@dataclass
class ProjectorState:
    """What the shader needs of the projector: its optics and pose, and its image as linear blur levels."""

    intr: Intrinsics                       # with distortion
    T_room_from_projector: NDArray[np.float64]
    levels: NDArray[np.float32] | None     # (L, h, w[, 3]) linear light 0..1, one layer per blur level
    blur_levels_px: tuple[float, ...]      # σ of each layer, ascending
    intensity_cd: float                    # Φ·fx·fy / (W·H)
    defocus_px_m: float                    # aperture · f_px
    focus_distance_m: float
    lens_blur_px: float
    bounds: tuple[float, float, float, float]  # undistorted normalised x0, y0, x1, y1
    shadow_intr: Intrinsics                # pinhole view that holds every ray of the image
    shadows: bool = True                   # walls can shadow walls (non-convex room); targets always can
    uniformity: float = 1.0                # corner / centre brightness of the projected image


@dataclass
class _Item:
    surface: Surface
    vbo: moderngl.Buffer
    vao: moderngl.VertexArray
    shadow_vao: moderngl.VertexArray
    texture: moderngl.Texture


def _set(program: moderngl.Program, name: str, value: object) -> None:
    """Set a uniform if the program uses it (GLSL compilers drop unused ones)."""
    uniform = program.get(name, None)
    if uniform is not None:
        uniform.value = value


def _write(program: moderngl.Program, name: str, data: bytes) -> None:
    uniform = program.get(name, None)
    if uniform is not None:
        uniform.write(data)


def _collect_garbage(ctx: moderngl.Context) -> None:
    """Free GL objects of dropped sites (queued when the context's gc_mode is "context_gc"). Objects that were
    released explicitly are queued too, as stubs without release(): skip those."""
    if ctx.gc_mode != "context_gc":
        return
    queue = ctx.objects
    while queue:
        obj = queue.popleft()
        release = getattr(obj, "release", None)
        if release is not None:
            release()


def _release(obj: moderngl.Framebuffer | moderngl.Texture | moderngl.Renderbuffer) -> None:
    if isinstance(obj, moderngl.Framebuffer):
        release_framebuffer(obj)
    else:
        obj.release()


def _vertex_array(ctx: moderngl.Context, program: moderngl.Program, vbo: moderngl.Buffer
                  ) -> moderngl.VertexArray:
    """Vertices are (room xyz, local xy) float32; skip the local part where the program does not use it."""
    if program.get("in_local", None) is None:
        return ctx.vertex_array(program, [(vbo, "3f 8x", "in_position")])
    return ctx.vertex_array(program, [(vbo, "3f 2f", "in_position", "in_local")])


def _clip_from_room(intr: Intrinsics, T_room_from_camera: NDArray[np.float64]) -> bytes:
    m = _IMAGE_ROWS_DOWN @ projection_matrix(intr, NEAR_M, FAR_M) @ view_matrix(T_room_from_camera)
    return m.astype(np.float32).T.tobytes()


class SceneRenderer:
    """Owns every GL object of one site; release() frees them (the context is the caller's)."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        with ctx:
            self._create_programs()
        self._items: list[_Item] = []
        self._projector_texture: moderngl.TextureArray | None = None
        self._projector_key: object = None
        self._shadow: tuple[moderngl.Framebuffer, moderngl.Texture, moderngl.Renderbuffer] | None = None
        self._shadow_key: object = None
        self._targets: dict[tuple[int, int], tuple[moderngl.Framebuffer, ...]] = {}
        self._deferred_vaos: list[moderngl.VertexArray] = []

    def _create_programs(self) -> None:
        ctx = self.ctx
        self.program = ctx.program(**shaders.program_source("sim_room"))
        self.deferred_program = ctx.program(**shaders.program_source("sim_room", {"DEFERRED": 1}))
        self.shadow_program = ctx.program(**shaders.program_source("sim_shadow"))
        self._blank = ctx.texture_array((1, 1, 1), 3, np.zeros(3, np.float32).tobytes(), dtype="f4")

    # -- scene ------------------------------------------------------------------------------------------
    def set_surfaces(self, surfaces: list[Surface]) -> None:
        """Upload surfaces (re-using uploads of surfaces already present, matched by serial)."""
        if [i.surface.serial for i in self._items] == [s.serial for s in surfaces]:
            return
        with self.ctx:
            keep = {item.surface.serial: item for item in self._items}
            items = []
            for s in surfaces:
                items.append(keep.pop(s.serial) if s.serial in keep else self._upload(s))
            for item in keep.values():
                self._release_item(item)
            self._items = items
            for vao in self._deferred_vaos:
                vao.release()
            self._deferred_vaos = [_vertex_array(self.ctx, self.deferred_program, i.vbo) for i in items]
            self._shadow_key = None

    def _upload(self, s: Surface) -> _Item:
        outline = s.outline_local()
        tris = triangulate(outline)
        local = outline[tris.ravel()]
        room = local @ s.T_room_from_surface[:3, :2].T + s.T_room_from_surface[:3, 3]
        data = np.hstack([room, local]).astype(np.float32)
        vbo = self.ctx.buffer(data.tobytes())
        vao = _vertex_array(self.ctx, self.program, vbo)
        shadow_vao = _vertex_array(self.ctx, self.shadow_program, vbo)
        img = np.ascontiguousarray(s.albedo)
        texture = self.ctx.texture((img.shape[1], img.shape[0]), 3, img.tobytes())
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        texture.anisotropy = MAX_ANISOTROPY if s.kind == KIND_TARGET else ROOM_ANISOTROPY
        texture.repeat_x = texture.repeat_y = False
        return _Item(s, vbo, vao, shadow_vao, texture)

    @staticmethod
    def _release_item(item: _Item) -> None:
        for obj in (item.vao, item.shadow_vao, item.vbo, item.texture):
            obj.release()

    # -- projector --------------------------------------------------------------------------------------
    def _upload_projector(self, state: ProjectorState, key: object) -> None:
        if state.levels is None or key == self._projector_key:
            return
        if self._projector_texture is not None:
            self._projector_texture.release()
        levels = state.levels if state.levels.ndim == 4 else np.repeat(state.levels[..., None], 3, axis=3)
        n, h, w, _ = levels.shape
        tex = self.ctx.texture_array((w, h, n), 3, np.ascontiguousarray(levels).tobytes(), dtype="f4")
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        tex.anisotropy = MAX_ANISOTROPY
        tex.repeat_x = tex.repeat_y = False
        self._projector_texture = tex
        self._projector_key = key

    def _shadow_map(self, state: ProjectorState) -> moderngl.Texture:
        key = (state.shadow_intr, state.T_room_from_projector.tobytes(), tuple(i.surface.serial for i in self._items))
        intr = state.shadow_intr
        if self._shadow is None or self._shadow[1].size != (intr.width, intr.height):
            if self._shadow is not None:
                for obj in self._shadow:
                    _release(obj)
            depth_tex = self.ctx.texture((intr.width, intr.height), 1, dtype="f4")
            depth_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            depth_rb = self.ctx.depth_renderbuffer((intr.width, intr.height))
            fbo = self.ctx.framebuffer([depth_tex], depth_rb)
            self._shadow = (fbo, depth_tex, depth_rb)
            self._shadow_key = None
        if key != self._shadow_key:
            fbo = self._shadow[0]
            fbo.use()
            fbo.clear(FAR_M, FAR_M, FAR_M, FAR_M, depth=1.0)
            self.ctx.enable(moderngl.DEPTH_TEST)
            self.ctx.disable(moderngl.CULL_FACE)
            _write(self.shadow_program, "u_clip_from_room", _clip_from_room(intr, state.T_room_from_projector))
            _write(self.shadow_program, "u_projector_from_room",
                invert(state.T_room_from_projector).astype(np.float32).T.tobytes())
            for item in self._items:
                item.shadow_vao.render(moderngl.TRIANGLES)
            self._shadow_key = key
        return self._shadow[1]

    # -- camera -----------------------------------------------------------------------------------------
    def _target(self, w: int, h: int, attachments: int, samples: int) -> tuple[moderngl.Framebuffer, ...]:
        """(drawing fbo, read fbo, …) with `attachments` RGBA float colour targets; with samples > 0 the
        drawing one is multisampled and resolved into the read one."""
        key = (w, h, attachments, samples)
        if key not in self._targets:
            color_ms = [self.ctx.renderbuffer((w, h), 4, samples=samples, dtype="f4")
                        for _ in range(attachments)]
            depth_ms = self.ctx.depth_renderbuffer((w, h), samples=samples)
            fbo_ms = self.ctx.framebuffer(color_ms, depth_ms)
            if samples == 0:
                self._targets[key] = (fbo_ms, fbo_ms, *color_ms, depth_ms)
                return self._targets[key]
            color = [self.ctx.renderbuffer((w, h), 4, dtype="f4") for _ in range(attachments)]
            fbo = self.ctx.framebuffer(color)
            self._targets[key] = (fbo_ms, fbo, *color_ms, depth_ms, *color)
        return self._targets[key]

    def render(self, intr: Intrinsics, T_room_from_camera: NDArray[np.float64], ambient_lux: float,
               projector: ProjectorState | None, projector_key: object = None) -> NDArray[np.float32]:
        """(h, w, 4) float32 for pinhole intr: linear radiance rgb (cd/m²) and depth along the camera axis
        (metres; 0 where nothing), the projector image textured in the shader."""
        with self.ctx:
            _collect_garbage(self.ctx)
            if projector is not None:
                self._upload_projector(projector, projector_key)
            (out,) = self._draw(self.program, [i.vao for i in self._items], 1, intr, T_room_from_camera,
                                ambient_lux, projector)
        return out

    def render_deferred(self, intr: Intrinsics, T_room_from_camera: NDArray[np.float64],
                        projector: ProjectorState, samples: int = 0, footprint_scale: float = 1.0
                        ) -> tuple[NDArray[np.float32], ...]:
        """What any projector image needs to light this view, each (h, w, 4) float32 for pinhole intr:
        (albedo rgb, depth along the axis in metres, 0 where nothing) and (projector irradiance per unit
        linear light in lux, projector pixel u, v, blur σ in projector pixels incl. the camera pixel's
        footprint). samples: multisampling (0: none); footprint_scale: camera pixels per rendered pixel (a view
        rendered finer than the sensor, then averaged onto it)."""
        with self.ctx:
            _collect_garbage(self.ctx)
            _set(self.deferred_program, "u_footprint_scale", float(footprint_scale))
            return self._draw(self.deferred_program, self._deferred_vaos, 2, intr, T_room_from_camera, 0.0,
                              projector, samples)

    def _draw(self, program: moderngl.Program, vaos: list[moderngl.VertexArray], attachments: int,
              intr: Intrinsics, T_room_from_camera: NDArray[np.float64], ambient_lux: float,
              projector: ProjectorState | None, samples: int = MSAA_SAMPLES) -> tuple[NDArray[np.float32], ...]:
        occluders = projector is not None and (
            projector.shadows or any(i.surface.kind == KIND_TARGET for i in self._items))
        shadow_tex = self._shadow_map(projector) if occluders else None
        fbo_ms, fbo, *_ = self._target(intr.width, intr.height, attachments, samples)
        fbo_ms.use()
        fbo_ms.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        self._set_common(program, intr, T_room_from_camera, ambient_lux, projector, shadow_tex)
        for item, vao in zip(self._items, vaos, strict=True):
            s = item.surface
            _set(program, "u_uv_scale", s.uv_scale)
            _set(program, "u_uv_offset", s.uv_offset)
            _set(program, "u_normal", tuple(s.normal))
            _set(program, "u_back_albedo", -1.0 if s.back_albedo is None else float(s.back_albedo))
            item.texture.use(0)
            vao.render(moderngl.TRIANGLES)
        if fbo is not fbo_ms:
            self.ctx.copy_framebuffer(fbo, fbo_ms)
        return tuple(np.frombuffer(fbo.read(components=4, dtype="f4", attachment=k), dtype=np.float32)
                     .reshape(intr.height, intr.width, 4) for k in range(attachments))

    def _set_common(self, program: moderngl.Program, intr: Intrinsics, T_room_from_camera: NDArray[np.float64],
                    ambient_lux: float, projector: ProjectorState | None,
                    shadow_tex: moderngl.Texture | None) -> None:
        _write(program, "u_clip_from_room", _clip_from_room(intr, T_room_from_camera))
        _set(program, "u_albedo", 0)
        _set(program, "u_camera_position", tuple(T_room_from_camera[:3, 3]))
        _set(program, "u_camera_axis", tuple(T_room_from_camera[:3, 2]))
        _set(program, "u_ambient_lux", float(ambient_lux))
        _set(program, "u_projector_levels", 1)
        _set(program, "u_shadow_depth", 2)
        if projector is None:
            _set(program, "u_projector_on", 0)
            _set(program, "u_shadows_on", 0)
            _set(program, "u_n_levels", 1)
            self._blank.use(1)
            return
        p = projector
        _set(program, "u_projector_on", 1)
        _write(program, "u_projector_from_room", invert(p.T_room_from_projector).astype(np.float32).T.tobytes())
        _set(program, "u_projector_position", tuple(p.T_room_from_projector[:3, 3]))
        _set(program, "u_projector_fc", (p.intr.fx, p.intr.fy, p.intr.cx, p.intr.cy))
        _set(program, "u_projector_size", (float(p.intr.width), float(p.intr.height)))
        dist = list(p.intr.dist) + [0.0] * (8 - len(p.intr.dist))
        _write(program, "u_projector_dist", np.asarray(dist[:8], dtype=np.float32).tobytes())
        _set(program, "u_projector_bounds", p.bounds)
        _set(program, "u_projector_intensity", float(p.intensity_cd))
        _set(program, "u_projector_falloff", 1.0 - float(p.uniformity))
        levels = list(p.blur_levels_px)[:MAX_BLUR_LEVELS]
        _write(program, "u_blur_levels", np.asarray(levels + [1e9] * (MAX_BLUR_LEVELS - len(levels)),
                                                  dtype=np.float32).tobytes())
        _set(program, "u_n_levels", len(levels))
        _set(program, "u_defocus_px_m", float(p.defocus_px_m))
        _set(program, "u_inverse_focus", 1.0 / float(p.focus_distance_m))
        _set(program, "u_lens_blur_px", float(p.lens_blur_px))
        (self._projector_texture or self._blank).use(1)
        _set(program, "u_shadows_on", 1 if shadow_tex is not None else 0)
        if shadow_tex is not None:
            shadow_tex.use(2)
        _set(program, "u_shadow_fc", (p.shadow_intr.fx, p.shadow_intr.fy, p.shadow_intr.cx, p.shadow_intr.cy))
        _set(program, "u_shadow_size", (float(p.shadow_intr.width), float(p.shadow_intr.height)))

    def release(self) -> None:
        with self.ctx:
            self._release_all()

    def _release_all(self) -> None:
        for item in self._items:
            self._release_item(item)
        self._items = []
        for vao in self._deferred_vaos:
            vao.release()
        self._deferred_vaos = []
        for objs in self._targets.values():
            for obj in dict.fromkeys(objs):      # the read fbo may be the drawing fbo
                _release(obj)
        self._targets = {}
        if self._shadow is not None:
            for obj in self._shadow:
                _release(obj)
            self._shadow = None
        if self._projector_texture is not None:
            self._projector_texture.release()
            self._projector_texture = None
        for obj in (self.program, self.deferred_program, self.shadow_program, self._blank):
            obj.release()
