"""Frame time of arproj's renderer vs pyrender: a ≥200k-triangle wall with a 4096² texture, read back."""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable

import numpy as np
import trimesh

from arproj.bench import BenchTable
from arproj.console import progress_bar
from geometry import Intrinsics, look_at
from geometry.poses import T_GL_FROM_CV
from render import MeshRenderer
from render.sample_wall import sample_wall_mesh

TARGET_SPEEDUP = 5.0
TARGET_FPS_1280 = 30.0
RESOLUTIONS = ((1920, 1080), (1280, 800))


def projector_intrinsics(width: int, height: int) -> Intrinsics:
    """A short-throw projector with lens shift: the image sits above the optical axis."""
    f = 1.4 * width
    return Intrinsics(f, f, (width - 1) / 2, height * 0.98, width, height)


def oblique_pose() -> np.ndarray:
    """T_wall_from_projector: 2 m from the wall, 30° off its normal, aimed at the wall's middle."""
    target = np.array([1.25, 0.9, 0.0])
    eye = target + 2.0 * np.array([np.sin(np.radians(30)), 0.0, np.cos(np.radians(30))]) + [0, -0.55, 0]
    return look_at(eye, target, up=[0, 1, 0])


def _time_frames(draw: Callable[[], object], frames: int, warmup: int = 3) -> tuple[float, object]:
    for _ in range(warmup):
        out = draw()
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        out = draw()
        times.append(time.perf_counter() - start)
    return statistics.median(times), out


def _same_picture(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two RGB pictures' grey values: near 1 when they show the same scene."""
    ga, gb = a.astype(np.float64).mean(axis=2).ravel(), b.astype(np.float64).mean(axis=2).ravel()
    return float(np.corrcoef(ga, gb)[0, 1])


def _untextured(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The same triangles with per-vertex colours (the texture's colour at each vertex) and no texture."""
    image = np.asarray(mesh.visual.material.image.convert("RGBA"))
    uv = np.asarray(mesh.visual.uv)
    rows = np.round((1.0 - uv[:, 1]) * (image.shape[0] - 1)).astype(int)
    cols = np.round(uv[:, 0] * (image.shape[1] - 1)).astype(int)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=image[rows, cols], process=False)


def run(quick: bool = False, seed: int = 0) -> BenchTable:
    """Frame time of arproj's renderer vs pyrender on the same textured wall (≥200k triangles, 4096² texture),
    at 1920×1080 and 1280×800, with read-back."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # before pyrender imports PyOpenGL
    import pyrender

    frames = 8 if quick else 30
    mesh = sample_wall_mesh()
    T_wall_from_projector = oblique_pose()
    ours_ms, ours_plain_ms, ours_depth_ms, ours_images = {}, {}, {}, {}
    peer_ms, peer_default_ms, agreement = {}, {}, {}
    with progress_bar() as bar:
        task = bar.add_task("render", total=len(RESOLUTIONS) * 4)
        with MeshRenderer() as ours:
            ours.set_mesh(mesh)
            for size in RESOLUTIONS:
                intr = projector_intrinsics(*size)
                t, ours_images[size] = _time_frames(
                    lambda intr=intr: ours.render(intr, T_wall_from_projector).color, frames)
                ours_ms[size] = t * 1e3
                bar.advance(task)
                t, _ = _time_frames(lambda intr=intr: ours.render(intr, T_wall_from_projector, depth=True), frames)
                ours_depth_ms[size] = t * 1e3
                bar.advance(task)
            # The floor: the same triangles without texture sampling. What llvmpipe needs for the geometry
            # alone bounds the ratio any texturing could reach.
            ours.set_mesh(_untextured(mesh))
            for size in RESOLUTIONS:
                intr = projector_intrinsics(*size)
                t, _ = _time_frames(lambda intr=intr: ours.render(intr, T_wall_from_projector).color, frames)
                ours_plain_ms[size] = t * 1e3
                bar.advance(task)
            with ours.ctx:
                renderer_name = ours.ctx.info["GL_RENDERER"]
        # pyrender runs after arproj is done: deleting its renderer calls eglTerminate on the process's
        # shared EGL display, which would pull the display out from under any other live context.
        scene = pyrender.Scene(bg_color=[0, 0, 0, 0], ambient_light=[1.0, 1.0, 1.0])
        # pyrender's faster setting for this mesh: shared (indexed) vertices. smooth=False would un-index it to
        # 603k vertices and cost pyrender 5-10 % more per frame.
        scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=True))
        for size in RESOLUTIONS:
            intr = projector_intrinsics(*size)
            # pyrender's principal point is measured from the image edge, OpenCV's from the first pixel centre.
            camera = pyrender.IntrinsicsCamera(intr.fx, intr.fy, intr.cx + 0.5, intr.cy + 0.5, znear=0.05,
                                               zfar=20.0)
            camera_node = scene.add(camera, pose=T_wall_from_projector @ T_GL_FROM_CV)
            peer = pyrender.OffscreenRenderer(*size)
            # FLAT: unlit textured, the same work arproj's shader does (pyrender reads colour and depth).
            t, (peer_img, _) = _time_frames(lambda peer=peer: peer.render(scene, flags=pyrender.RenderFlags.FLAT),
                                            frames)
            peer_ms[size] = t * 1e3
            # pyrender's default: its lit PBR shader, what a user gets from renderer.render(scene).
            t, _ = _time_frames(lambda peer=peer: peer.render(scene), max(3, frames // 3), warmup=1)
            peer_default_ms[size] = t * 1e3
            peer.delete()
            scene.remove_node(camera_node)
            agreement[size] = _same_picture(ours_images[size], peer_img)
            bar.advance(task)
    rows, headline = [], {}
    for size in RESOLUTIONS:
        name = f"{size[0]}×{size[1]}"
        speedup = peer_ms[size] / ours_ms[size]
        rows.append([name, ours_ms[size], 1e3 / ours_ms[size], ours_depth_ms[size], ours_plain_ms[size],
                     peer_ms[size], peer_default_ms[size], speedup, peer_ms[size] / ours_plain_ms[size],
                     peer_default_ms[size] / ours_ms[size]])
        headline[f"speed-up vs pyrender at {name}"] = {
            "arproj": round(ours_ms[size], 2), "peer": round(peer_ms[size], 2), "peer_name": "pyrender",
            "unit": " ms", "target": f"≥ {TARGET_SPEEDUP:g}× faster", "met": speedup >= TARGET_SPEEDUP}
    fps_1280 = 1e3 / ours_ms[(1280, 800)]
    headline["frames/s at 1280×800 with read-back"] = {
        "arproj": round(fps_1280, 1), "peer": round(1e3 / peer_ms[(1280, 800)], 1), "peer_name": "pyrender",
        "unit": " fps", "target": f"≥ {TARGET_FPS_1280:g}", "met": fps_1280 >= TARGET_FPS_1280}
    return BenchTable(
        name="render",
        title=f"arproj bench render — {len(mesh.faces):,} triangles, 4096² texture, median of {frames} frames",
        columns=["resolution", "arproj ms", "arproj fps", "arproj +depth ms", "arproj untextured ms",
                 "pyrender FLAT ms", "pyrender default ms", "× vs FLAT", "untextured × vs FLAT", "× vs default"],
        rows=rows,
        notes=[f"GL: {renderer_name}. Times are medians with read-back of the colour image. pyrender always "
               "reads depth too: compare it with the '+depth' column.",
               "arproj untextured: the same triangles with vertex colours instead of the texture, the floor of the "
               "geometry's own cost on this renderer; 'untextured × vs FLAT' is the most any texture sampling "
               "could leave of the ratio.",
               "pyrender FLAT draws unlit like arproj (the like-for-like peer, the one the target is judged on); "
               "pyrender default is its lit PBR shader.",
               "Same-scene check, correlation of the two pictures' grey values (pyrender darkens the texture by "
               "its sRGB handling): " + ", ".join(f"{w}×{h}: {v:.3f}" for (w, h), v in agreement.items())],
        headline=headline,
        environment={"gl_renderer": renderer_name, "triangles": len(mesh.faces), "frames": frames},
    )
