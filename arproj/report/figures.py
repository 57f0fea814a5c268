"""Pictures the demo report shows beside the parts' own: the truth drawn into a photograph, calibration quality."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.intrinsics import Intrinsics
from geometry.polyline import densify
from geometry.poses import invert, transform_points

TRUTH_COLOUR = (255, 255, 255)
TRUTH_SHADOW = (0, 0, 0)
DASH_PX = 10  # dash and gap length of the truth lines in the photograph
# The caption says what draw_truth_on_photo draws: kept beside its colours so that the two cannot part.
TRUTH_ON_PHOTO_TEXT = ("thin dashed lines, white with a black outline (crosses for screws and nails, the outlines "
                       "of studs and plates closed)")


def draw_truth_on_photo(image: NDArray[np.uint8], wall: Any, T_room_from_wall: NDArray[np.float64],
                        T_room_from_camera: NDArray[np.float64], intr: Intrinsics,
                        step_m: float = 0.01) -> tuple[NDArray[np.uint8], int]:
    """The wall file's objects drawn as thin dashed lines (crosses for points) into a photograph.

    image: (h, w, 3) uint8 RGB; wall: scanner.wall.Wall (truth, wall coordinates in metres); poses 4×4.
    Returns (the annotated copy, number of objects at least partly in view).
    """
    out = image.copy()
    T_camera_from_wall = invert(T_room_from_camera) @ T_room_from_wall
    h, w = out.shape[:2]
    drawn = 0
    for obj in wall.objects:
        geometry = np.asarray(obj.geometry_m, dtype=np.float64)
        closed = obj.kind in ("stud", "beam", "plate")
        if closed:
            geometry = np.concatenate([geometry, geometry[:1]])
        points = densify(geometry, step_m) if len(geometry) > 1 else geometry
        cam = transform_points(T_camera_from_wall, np.column_stack([points, np.zeros(len(points))]))
        front = cam[:, 2] > 0.05
        if not front.any():
            continue
        uv = np.full((len(points), 2), np.nan)
        uv[front] = intr.project(cam[front])
        inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        if not inside.any():
            continue
        drawn += 1
        if len(points) == 1:
            u, v = (round(float(c)) for c in uv[0])
            for colour, thick in ((TRUTH_SHADOW, 4), (TRUTH_COLOUR, 2)):
                cv2.drawMarker(out, (u, v), colour, cv2.MARKER_CROSS, 14, thick, cv2.LINE_AA)
            continue
        run = 0.0  # arc length along the projected line, for the dashes
        for i in range(len(points) - 1):
            if not (front[i] and front[i + 1]):
                continue
            a, b = uv[i], uv[i + 1]
            seg = float(np.linalg.norm(b - a))
            if (run // DASH_PX) % 2 == 0:
                pa, pb = tuple(np.round(a).astype(int)), tuple(np.round(b).astype(int))
                # white 2 px on black 4 px: a 1 px white line antialiased to grey read as a black mark
                cv2.line(out, pa, pb, TRUTH_SHADOW, 4, cv2.LINE_AA)
                cv2.line(out, pa, pb, TRUTH_COLOUR, 2, cv2.LINE_AA)
            run += seg
    return out, drawn


def calibration_figure(state: dict[str, Any], path: str | Path) -> Path:
    """Calibration quality (PNG): each step's residual and, per validation head angle, the 3-D error.

    state: the wizard's state (arproj.wizard, wizard_state.json).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = state.get("steps", {})
    q = {name: steps.get(name, {}).get("quality", {}) for name in ("stereo", "projector", "head", "validation")}
    residuals = [("stereo reprojection", q["stereo"].get("reprojection_rms_px"), "px"),
                 ("stereo epipolar", q["stereo"].get("epipolar_error_px_per_image"), "px"),
                 ("projector reprojection", q["projector"].get("projector_rms_px"), "px"),
                 ("head model (position)", q["head"].get("position_rms_mm"), "mm"),
                 ("validation 3-D RMS", q["validation"].get("rms_mm"), "mm"),
                 ("validation 3-D max", q["validation"].get("max_mm"), "mm")]
    residuals = [(n, float(v), u) for n, v, u in residuals if isinstance(v, (int, float))]
    per_angle = q["validation"].get("per_angle", []) if isinstance(q["validation"], dict) else []
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.2), constrained_layout=True)
    names = [f"{n} [{u}]" for n, _, u in residuals]
    values = [v for _, v, _ in residuals]
    bars = ax1.barh(names, values, color=["#4C72B0" if u == "px" else "#DD8452" for _, _, u in residuals])
    ax1.bar_label(bars, labels=[f"{v:.3f}" for v in values], padding=3, fontsize=8)
    ax1.invert_yaxis()
    ax1.set_title("residual of each calibration step (px: pixels, mm: millimetres)")
    ax1.set_xlim(0, max(values, default=1.0) * 1.3)
    labels, rms = [], []
    for entry in per_angle:
        value = next((entry[k] for k in ("rms_mm", "rms_3d_mm", "error_rms_mm") if k in entry), None)
        if value is None:
            value = next((v for k, v in entry.items() if "rms" in k and isinstance(v, (int, float))), None)
        if value is None:
            continue
        angles = entry.get("angles_deg", [])
        labels.append("/".join(f"{a:.0f}" for a in angles[:2]))
        rms.append(float(value))
    if rms:
        ax2.bar(range(len(rms)), rms, color="#55A868")
        ax2.set_xticks(range(len(rms)), labels, rotation=45, fontsize=8)
        ax2.set_xlabel("validation head angle pan/tilt [deg] (not used for fitting)")
        ax2.set_ylabel("3-D error RMS [mm]")
        ax2.set_title("validation: predicted vs measured projected grid")
    else:
        ax2.text(0.5, 0.5, "no per-angle validation figures in the wizard's state", ha="center", va="center")
        ax2.set_axis_off()
    out = Path(path)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


TRUTH_GREY = "#b8b8b8"
MAP_VS_TRUTH_TEXT = ("The wall file's truth drawn wide in light grey, each object with its id; over it what the map "
                     "found, thin, in its class colour (dots for fasteners). A red label marks a truth object the "
                     "map missed or gave a wrong class, with the class it gave; an orange one a mapped object on "
                     "nothing in the wall.")


def map_vs_truth_figure(objects: list[Any], wall: Any, scores: list[Any], unmatched: list[Any],
                        path: str | Path) -> Path:
    """The map against the truth (PNG): wall objects wide and grey with their ids, mapped objects (MapObject:
    cls, kind, points_m) thin in class colours, misses and wrong classes (scores: mapping.evaluate.ObjectScore)
    labelled in red, unmatched mapped objects in orange. What it draws is MAP_VS_TRUTH_TEXT."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mapping.texture import CLASS_COLOURS

    by_id = {s.id: s for s in scores}
    aspect = wall.height_m / max(wall.width_m, 1e-9)
    fig, ax = plt.subplots(figsize=(10, max(3.0, 10 * aspect) + 0.6), constrained_layout=True)
    ax.add_patch(plt.Rectangle((0, 0), wall.width_m, wall.height_m, fill=False, ec="black", lw=1))
    for obj in wall.objects:
        g = np.asarray(obj.geometry_m, dtype=np.float64)
        if obj.kind in ("stud", "beam", "plate", "cavity"):
            g = np.vstack([g, g[:1]])
        if len(g) == 1:
            ax.plot(g[:, 0], g[:, 1], "o", color=TRUTH_GREY, ms=14, zorder=1)
        else:
            ax.plot(g[:, 0], g[:, 1], "-", color=TRUTH_GREY, lw=9, solid_capstyle="round", zorder=1)
        score = by_id.get(obj.id)
        bad = score is not None and score.verdict in ("missed", "wrong class")
        text = obj.id if not bad else (f"{obj.id}: missed" if score.verdict == "missed" else
                                       f"{obj.id}: mapped as {str(score.mapped_class).replace('_', ' ')}")
        anchor = g[len(g) // 2] if len(g) > 2 else g.mean(axis=0)
        ax.annotate(text, anchor, xytext=(4, 4), textcoords="offset points", fontsize=7,
                    color="#c00000" if bad else "#555555", fontweight="bold" if bad else "normal", zorder=4)
    used: set[str] = set()
    for o in objects:
        colour = np.array(CLASS_COLOURS.get(o.cls, CLASS_COLOURS["unknown"])) / 255.0
        p = np.asarray(o.points_m, dtype=np.float64)
        if o.kind == "outline":
            p = np.vstack([p, p[:1]])
        label = None if o.cls in used else o.cls.replace("_", " ")
        used.add(o.cls)
        if len(p) == 1:
            ax.plot(p[:, 0], p[:, 1], "o", color=colour, ms=5, mec="black", mew=0.5, zorder=3, label=label)
        else:
            ax.plot(p[:, 0], p[:, 1], "-", color=colour, lw=1.8, zorder=3, label=label)
    for o in unmatched:
        p = np.asarray(o.points_m, dtype=np.float64)
        ax.annotate(f"{o.cls.replace('_', ' ')} on nothing", p.mean(axis=0), xytext=(4, -10),
                    textcoords="offset points", fontsize=7, color="#d07000", fontweight="bold", zorder=4)
    ax.plot([], [], "-", color=TRUTH_GREY, lw=9, label="truth (wall file)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title="map", title_fontsize=8)
    ax.set_xlim(-0.02 * wall.width_m, 1.02 * wall.width_m)
    ax.set_ylim(-0.02 * wall.height_m, 1.02 * wall.height_m)
    ax.set_aspect("equal")
    ax.set_xlabel("x along the wall [m]")
    ax.set_ylabel("y up [m]")
    out = Path(path)
    fig.savefig(out, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return out
