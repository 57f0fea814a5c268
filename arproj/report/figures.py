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
            for colour, thick in ((TRUTH_SHADOW, 3), (TRUTH_COLOUR, 1)):
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
                cv2.line(out, pa, pb, TRUTH_SHADOW, 3, cv2.LINE_AA)
                cv2.line(out, pa, pb, TRUTH_COLOUR, 1, cv2.LINE_AA)
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
