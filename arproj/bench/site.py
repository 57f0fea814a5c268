"""Simulated site: time to photograph the projector-lit room (1280×800, all effects) and the accuracy of
projected points in the photo against analytic projection. Peer: the same photo made on the CPU by exact
ray casting, cv2.projectPoints into the projector and cv2.remap of its image (same camera model after)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from arproj.bench import BenchTable, cells, column, columns
from arproj.sim import Site, optics, patterns
from arproj.sim.room import KIND_TARGET, raycast
from arproj.sim.site import pixel_directions
from geometry.poses import invert, transform_points

TARGET_MS = 100.0
TARGET_PX = 0.05
DENSE_SAMPLES = 20000   # lit camera pixels checked per placement
PEER = "CPU ray cast + cv2.projectPoints + remap"


def _sample(image: NDArray[np.float32], px: NDArray[np.float32], border: int) -> NDArray[np.float32]:
    """Bilinear samples of image at pixel positions px (n, 2): cv2.remap on maps folded into rows."""
    n = len(px)
    cols = 1024
    padded = np.zeros((-(-n // cols) * cols, 2), np.float32)
    padded[:n] = px
    maps = padded.reshape(-1, cols, 2)
    out = cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=border)
    return out.reshape(-1, *image.shape[2:])[:n]


def _cpu_photograph(site: Site, camera: str, image: NDArray[np.uint8], noise: bool) -> NDArray[np.uint8]:
    """The peer: the same photo, every pixel by exact ray casting and OpenCV on the CPU (no shadows: the
    bench scene has no targets)."""
    model = site.camera_models[camera]
    intr = model.intr
    surfaces, _ = site._surfaces()
    if any(s.kind == KIND_TARGET for s in surfaces):
        raise ValueError("the CPU peer does not model shadows; run it on a scene without targets")
    T_cam = site.T_room_from(camera)
    xy = pixel_directions(intr)                      # cached per camera, like the GL path's distortion map
    rays = np.column_stack([xy, np.ones(len(xy))]) @ T_cam[:3, :3].T
    hits = raycast(surfaces, T_cam[:3, 3], rays)
    hit = np.isfinite(hits.t)
    points = T_cam[:3, 3] + np.where(hit, hits.t, 0.0)[:, None] * rays
    albedo = np.zeros((len(points), 3), np.float32)
    normals = np.zeros((len(points), 3))
    for k, s in enumerate(surfaces):
        sel = hits.surface == k
        if not sel.any():
            continue
        uv = hits.local[sel] * np.asarray(s.uv_scale) + np.asarray(s.uv_offset)
        tex = s.albedo.astype(np.float32) / 255.0
        px = (uv * [tex.shape[1], tex.shape[0]] - 0.5).astype(np.float32)
        albedo[sel] = _sample(tex, px, cv2.BORDER_REPLICATE).reshape(-1, 3)
        normals[sel] = s.normal
    # Projector: pixel coordinates by cv2.projectPoints, light by remap, irradiance by the same law.
    p = site.scene["projector"]
    proj = site.projector
    T_proj = site.T_room_from("projector")
    q = transform_points(invert(T_proj), points[hit])
    uv = proj.project(q).astype(np.float32)
    z = q[:, 2]
    xy = q[:, :2] / z[:, None]
    to_proj = T_proj[:3, 3] - points[hit]
    d2 = np.sum(to_proj**2, axis=1)
    cos_inc = np.abs(np.sum(to_proj * normals[hit], axis=1)) / np.sqrt(d2)
    from_centre = (uv - 0.5 * (np.array([proj.width, proj.height]) - 1)) / (0.5 * np.array([proj.width, proj.height]))
    intensity = (p["lumens"] * proj.fx * proj.fy / (proj.width * proj.height) * (1 + np.sum(xy**2, axis=1)) ** 1.5
                 * (1.0 - 0.5 * (1.0 - p["uniformity"]) * np.sum(from_centre**2, axis=1)))
    irradiance = np.where(z > 0, intensity * cos_inc / d2, 0.0)
    sigma = optics.defocus_sigma_px(p["aperture_mm"], proj.fx, site.projector_focus_m, z, p["lens_blur_px"])
    levels = optics.blur_levels(float(sigma.min()), float(sigma.max()))
    light_levels = optics.projector_light(image, proj, p["gamma"], p["contrast_ratio"], levels)
    position = np.interp(sigma, levels, np.arange(len(levels)))
    light = np.zeros(len(uv), np.float32)
    for k in range(len(levels)):
        weight = np.clip(1.0 - np.abs(position - k), 0.0, 1.0)
        light += weight * _sample(light_levels[k], uv, cv2.BORDER_CONSTANT)
    total = np.full(len(points), site.room.ambient_lux, np.float32)
    total[hit] += irradiance * light
    radiance = (albedo @ optics.LUMA_RGB) * total / np.pi
    depth = np.where(hit, hits.t, 0.0).reshape(intr.height, intr.width).astype(np.float32)
    return model.expose(radiance.reshape(intr.height, intr.width).astype(np.float32), depth, None,
                        site._rng["photo"] if noise else None)


def _timed(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median wall-clock and mean process CPU time (all threads, so GL included) per call, ms."""
    times = []
    cpu0 = time.process_time()
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3, (time.process_time() - cpu0) / repeats * 1e3


def _dot_errors(site: Site, camera: str, make: Callable[[NDArray[np.uint8]], NDArray[np.uint8]]
                ) -> NDArray[np.float64]:
    positions = patterns.dot_grid(site.projector, cols=9, rows=6)
    pattern = patterns.dot_pattern(site.projector, positions, sigma_px=3.0)
    expected = patterns.expected_camera_pixels(site, camera, positions)
    found = patterns.dot_centroids(make(pattern), make(np.zeros_like(pattern)), expected, radius_px=7)
    err = np.linalg.norm(found - expected, axis=1)
    return err[np.isfinite(err)]


@dataclass
class SiteRow:
    """One placement of the robot: photo times (ms; CPU ms of all threads) and projected-point errors (px)."""

    placement: str = column("placement")
    cold_ms: float = column("new view ms")       # first photo after the robot/head moved
    cold_cpu_ms: float = column("(CPU ms)")
    warm_ms: float = column("new pattern ms")    # another projector image at the same pose
    warm_cpu_ms: float = column("(CPU ms)")
    peer_ms: float = column("peer ms")
    dense_max_px: float = column("point err max px")
    dense_p999_px: float = column("(p99.9)")
    dots_px: float = column("dots max px")
    dots_direct_px: float = column("dots direct-GL px")
    dots_peer_px: float = column("dots peer px")
    dots_noisy_px: float = column("dots noisy med px")
    peer_cpu_ms: float = float("nan")


def _measure(site: Site, camera: str, cycle: list[NDArray[np.uint8]], repeats: int, placement: str) -> SiteRow:
    """Timings (ms) and errors (px) at the site's current placement."""
    counter = iter(range(10**9))

    def cold() -> object:
        site._views.clear()
        return site.photograph(camera, cycle[next(counter) % len(cycle)])

    def warm() -> object:
        return site.photograph(camera, cycle[next(counter) % len(cycle)])

    def peer() -> object:
        return _cpu_photograph(site, camera, cycle[next(counter) % len(cycle)], True)

    cold_ms, cold_cpu = _timed(cold, repeats)
    warm_ms, warm_cpu = _timed(warm, repeats)
    peer_ms, peer_cpu = _timed(peer, max(2, repeats // 3))
    model = site.camera_models[camera]
    dots = float(np.max(_dot_errors(site, camera, lambda img: site.photograph(camera, img, noise=False).image)))
    direct = float(np.max(_dot_errors(
        site, camera, lambda img: model.develop(site.render_radiance(camera, img), None, None))))
    dots_peer = float(np.max(_dot_errors(site, camera, lambda img: _cpu_photograph(site, camera, img, False))))
    noisy = float(np.median(_dot_errors(site, camera, lambda img: site.photograph(camera, img).image)))
    # Dense check, no estimator involved: for sampled lit camera pixels, the projector pixel whose light the
    # renderer put there is cast onto the room exactly and projected back into the camera (cv2.projectPoints):
    # the distance to the pixel itself is the position error of projected points in the image.
    seen = site.projector_pixels_seen(camera)
    inner = np.isfinite(seen[..., 0])
    inner[:8], inner[-8:], inner[:, :8], inner[:, -8:] = False, False, False, False
    rows, cols = np.nonzero(inner)
    pick = np.random.default_rng(0).choice(len(rows), size=min(DENSE_SAMPLES, len(rows)), replace=False)
    rows, cols = rows[pick], cols[pick]
    projector_px = seen[rows, cols].astype(np.float64)
    landing = site.raycast("projector", projector_px).points_room
    back = site.intrinsics(camera).project(transform_points(invert(site.T_room_from(camera)), landing))
    dense = np.hypot(back[:, 0] - cols, back[:, 1] - rows)
    return SiteRow(placement, cold_ms, cold_cpu, warm_ms, warm_cpu, peer_ms, float(np.max(dense)),
                   float(np.percentile(dense, 99.9)), dots, direct, dots_peer, noisy, peer_cpu)


def run(quick: bool = False, seed: int = 0) -> BenchTable:
    repeats = 3 if quick else 9
    rows = _experiment(repeats, [(2.5, 0.0), (2.0, 25.0), (3.0, -35.0)][: 2 if quick else 3], seed)
    cold = float(np.median([r.cold_ms for r in rows]))
    warm = float(np.median([r.warm_ms for r in rows]))
    peer_t = float(np.median([r.peer_ms for r in rows]))
    table = BenchTable(
        name="site",
        title="arproj bench site — simulated camera photo of the projector-lit room (1280×800, all effects)",
        columns=columns(SiteRow), rows=[cells(r) for r in rows],
        notes=[
            "new view: first photo after the robot/head moved (GL pass + readback + warp + sensor); new "
            "pattern: another projector image at the same pose (projector lookup + sensor only).",
            f"peer: {PEER}, the full photo from scratch each time (same camera model).",
            f"point err: at {DENSE_SAMPLES} lit camera pixels per placement, the projector pixel the renderer "
            "lit it with, cast onto the room exactly and projected back with cv2.projectPoints; distance to the "
            "pixel (noise-free geometry of the photo). The largest errors sit on pixels straddling a room "
            "corner, where resampling the pinhole render through the lens distortion bends a kinked field.",
            "dots: centroids of 54 Gaussian dots (σ 3 projector px) in the noise-free 8-bit photo vs the analytic "
            "projection of their centres; includes the centroid estimator's perspective bias and 8-bit "
            "quantisation of faint far dots, which the peer shows equally (direct-GL: the projector image "
            "textured in the shader).",
            f"timings: median wall clock of {repeats} trials per placement on a shared 2-core machine "
            f"(load average {os.getloadavg()[0]:.1f} at the end); CPU ms: process CPU time of all threads "
            "(llvmpipe's included), which the machine's load does not inflate.",
            f"speed vs peer: new pattern {peer_t / warm:.1f}× faster, new view {peer_t / cold:.1f}× faster",
        ],
        headline=_headline(rows, cold, warm, peer_t),
        environment={"renderer": "Mesa llvmpipe (EGL)", "trials_per_placement": repeats},
    )
    return table


def _experiment(repeats: int, placements: list[tuple[float, float]], seed: int) -> list[SiteRow]:
    """Photos and their errors at each placement (distance m, incidence °) of the robot, camera_left."""
    camera = "camera_left"
    rows = []
    with Site.build(seed=seed) as site:
        cycle = [patterns.dot_pattern(site.projector, patterns.dot_grid(site.projector), sigma_px=2.0 + k)
                 for k in range(4)]
        site.photograph(camera, cycle[0])          # compile shaders, build lookup tables
        for distance, incidence in placements:
            site.place_robot(distance, incidence)
            rows.append(_measure(site, camera, cycle, repeats, f"{distance} m, {incidence:+.0f}°"))
    return rows


def _headline(rows: list[SiteRow], cold: float, warm: float, peer_t: float) -> dict[str, dict]:
    """Median photo times over the placements; the largest errors."""
    cold_cpu = float(np.median([r.cold_cpu_ms for r in rows]))
    err_dense = max(r.dense_max_px for r in rows)
    err_dots, err_peer = max(r.dots_px for r in rows), max(r.dots_peer_px for r in rows)
    return {
        "photo, new pattern (ms)": {"arproj": round(warm, 1), "peer": round(peer_t, 1), "peer_name": PEER,
                                    "unit": " ms", "target": f"≤ {TARGET_MS:.0f} ms", "met": warm <= TARGET_MS},
        "photo, new view (ms)": {"arproj": round(cold, 1), "peer": round(peer_t, 1), "peer_name": PEER,
                                 "unit": " ms", "target": f"≤ {TARGET_MS:.0f} ms", "met": cold <= TARGET_MS},
        "photo, new view (CPU ms)": {"arproj": round(cold_cpu, 1), "peer": "–",
                                     "peer_name": "process CPU time, all threads", "unit": " ms",
                                     "target": f"≤ {TARGET_MS:.0f} ms", "met": cold_cpu <= TARGET_MS},
        "projected point error, max (px)": {"arproj": round(err_dense, 4), "peer": "exact (by construction)",
                                            "peer_name": PEER, "unit": " px", "target": f"≤ {TARGET_PX} px",
                                            "met": err_dense <= TARGET_PX},
        "dot centroid error, max (px)": {"arproj": round(err_dots, 4), "peer": round(err_peer, 4),
                                         "peer_name": PEER, "unit": " px",
                                         "target": "info: 8-bit photo + centroid estimator", "met": None},
    }
