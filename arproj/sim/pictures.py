"""Pictures of a simulated site: what each camera sees with a projected test pattern, the ground truth drawn
over it, and a plan view of the room with the robot, its sensors and a laser scan."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from arproj.sim.patterns import expected_camera_pixels
from arproj.sim.site import CAMERAS, Site
from geometry.intrinsics import Intrinsics
from geometry.poses import transform_points

GRID_STEP_PX = 80          # test pattern grid pitch (projector pixels)
WALL_ISOLINE_M = 0.25      # spacing of the wall-coordinate lines in the overlay
CONTOUR_STEP_PX = 4        # the overlay's lines are traced on every 4th pixel (smooth, and quick)


def test_pattern(intr: Intrinsics) -> NDArray[np.uint8]:
    """(h, w, 3) uint8 projector test pattern: a grid, a frame, a centre cross, circles and colour bars."""
    w, h = intr.width, intr.height
    img = np.zeros((h, w, 3), dtype=np.uint8)
    for x in range(0, w, GRID_STEP_PX):
        cv2.line(img, (x, 0), (x, h - 1), (160, 160, 160), 2)
    for y in range(0, h, GRID_STEP_PX):
        cv2.line(img, (0, y), (w - 1, y), (160, 160, 160), 2)
    cv2.rectangle(img, (2, 2), (w - 3, h - 3), (255, 255, 255), 4)
    cx, cy = w // 2, h // 2
    cv2.line(img, (cx - 60, cy), (cx + 60, cy), (255, 255, 255), 3)
    cv2.line(img, (cx, cy - 60), (cx, cy + 60), (255, 255, 255), 3)
    cv2.circle(img, (cx, cy), min(w, h) // 3, (255, 255, 255), 3)
    bars = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (255, 0, 255), (0, 255, 255)]
    bw = w // (2 * len(bars))
    for i, colour in enumerate(bars):
        x0 = w // 4 + i * bw
        cv2.rectangle(img, (x0, h - 3 * GRID_STEP_PX // 2), (x0 + bw - 4, h - GRID_STEP_PX - 4), colour, -1)
    cv2.putText(img, "arproj", (GRID_STEP_PX + 10, GRID_STEP_PX - 16), cv2.FONT_HERSHEY_SIMPLEX, 1.4,
                (255, 255, 255), 3, cv2.LINE_AA)
    return img


def grid_points(intr: Intrinsics) -> NDArray[np.float64]:
    """(n, 2) projector pixels of the test pattern's inner grid crossings."""
    u, v = np.meshgrid(np.arange(GRID_STEP_PX, intr.width, GRID_STEP_PX),
                       np.arange(GRID_STEP_PX, intr.height, GRID_STEP_PX))
    return np.column_stack([u.ravel(), v.ravel()]).astype(np.float64) + 0.5   # centre of the 2-px line


def write_site_pictures(site: Site, out_dir: str | Path) -> list[Path]:
    """Write camera_left.png, camera_right.png (what each camera sees with the test pattern projected),
    ground_truth.png (truth drawn over both) and site_plan.png (top view). Returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pattern = test_pattern(site.projector)
    paths = []
    photos = {}
    for camera in CAMERAS:
        photo = site.photograph(camera, projector_image=pattern)
        photos[camera] = photo
        path = out / f"{camera}.png"
        image = photo.image if photo.image.ndim == 2 else cv2.cvtColor(photo.image, cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(path), image)
        paths.append(path)

    crossings = grid_points(site.projector)
    fig, axes = plt.subplots(1, 2, figsize=(16, 5.6), constrained_layout=True)
    for ax, camera in zip(axes, CAMERAS, strict=True):
        photo = photos[camera]
        truth = photo.truth
        ax.imshow(photo.image, cmap="gray", vmin=0, vmax=255)
        step = CONTOUR_STEP_PX
        index = truth.wall_index[::step, ::step]
        cols, rows = np.arange(0, photo.intr.width, step), np.arange(0, photo.intr.height, step)
        for wall in np.unique(index[index >= 0]):
            for axis, colour in ((0, "tab:orange"), (1, "tab:cyan")):
                values = np.where(index == wall, truth.wall_xy[::step, ::step, axis], np.nan)
                lo, hi = np.nanmin(values), np.nanmax(values)
                levels = np.arange(np.ceil(lo / WALL_ISOLINE_M), np.floor(hi / WALL_ISOLINE_M) + 1) * WALL_ISOLINE_M
                if len(levels):
                    ax.contour(cols, rows, values, levels=levels, colors=colour, linewidths=0.6, alpha=0.8)
        expected = expected_camera_pixels(site, camera, crossings)
        inside = ((expected[:, 0] >= 0) & (expected[:, 0] < photo.intr.width) & (expected[:, 1] >= 0)
                  & (expected[:, 1] < photo.intr.height))
        ax.plot(expected[inside, 0], expected[inside, 1], "+", color="tab:red", ms=7, mew=1.2,
                label="pattern crossings, analytic")
        ax.set_title(f"{camera}: wall x (orange) / y (cyan) every {WALL_ISOLINE_M} m; + = truth")
        ax.set_xlim(0, photo.intr.width)
        ax.set_ylim(photo.intr.height, 0)
        ax.legend(loc="lower right", fontsize=8)
    path = out / "ground_truth.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    paths.append(path)
    paths.append(_plan(site, out / "site_plan.png"))
    return paths


def _plan(site: Site, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6), constrained_layout=True)
    corners = np.vstack([site.room.corners, site.room.corners[:1]])
    ax.plot(corners[:, 0], corners[:, 1], "k-", lw=2)
    for wall in site.walls:
        mid = wall.to_room([[wall.width_m / 2, 0.0]])[0]
        ax.annotate(f"wall {wall.index}", mid[:2] + 0.25 * wall.normal[:2], ha="center", fontsize=9)
        ax.arrow(*wall.T_room_from_wall[:2, 3], *(0.4 * wall.T_room_from_wall[:2, 0]), width=0.01, color="0.4")
    robot = site.T_room_from_robot
    ax.add_patch(plt.Circle(robot[:2, 3], site.scene["robot"]["footprint_radius_m"], fill=False, color="tab:blue"))
    believed = site.localized_T_room_from_robot
    ax.plot(*believed[:2, 3], "x", color="tab:purple", label="localization")
    scan = site.laser_scan()
    points = transform_points(robot, scan.points_robot())
    ax.plot(points[:, 0], points[:, 1], ".", ms=1.5, color="tab:green", label="laser scan")
    w, h = site.projector.width - 1, site.projector.height - 1
    t = np.linspace(0.0, 1.0, 64)
    border = np.concatenate([np.column_stack([t * w, 0 * t]), np.column_stack([w + 0 * t, t * h]),
                             np.column_stack([(1 - t) * w, h + 0 * t]), np.column_stack([0 * t, (1 - t) * h])])
    outline = site.raycast("projector", border).points_room
    centre = site.T_room_from("projector")[:3, 3]
    for p in outline[:: max(len(outline) // 8, 1)]:
        ax.plot([centre[0], p[0]], [centre[1], p[1]], "-", color="tab:orange", lw=0.5)
    ax.plot(outline[:, 0], outline[:, 1], "-", color="tab:orange", lw=2, label="projected image")
    for camera, colour in zip(CAMERAS, ("tab:red", "tab:pink"), strict=True):
        T = site.T_room_from(camera)
        ax.arrow(*T[:2, 3], *(0.5 * T[:2, 2]), width=0.015, color=colour, label=camera)
    ax.set_aspect("equal")
    ax.set_xlabel("room x (m)")
    ax.set_ylabel("room y (m)")
    ax.set_title("site plan (top view)")
    ax.legend(loc="upper right", fontsize=8)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
