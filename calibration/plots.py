"""Pictures of calibration results (PNG via matplotlib's Agg backend, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from calibration.boards import BoardView
from calibration.stereo import COVERAGE_GRID, StereoCalibration, view_tilt_deg


def plot_stereo_coverage(calib: StereoCalibration, left: list[BoardView], right: list[BoardView],
                         path: str | Path) -> Path:
    """Where the corners fell in each image (coverage grid drawn), and the board tilts of the used pairs."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, views, name in ((axes[0], left, "camera_left"), (axes[1], right, "camera_right")):
        if views:
            w, h = views[0].image_size
            for v in views:
                ax.plot(v.image_points[:, 0], v.image_points[:, 1], ".", ms=2)
            for k in range(1, COVERAGE_GRID):
                ax.axvline(w * k / COVERAGE_GRID, color="0.7", lw=0.8)
                ax.axhline(h * k / COVERAGE_GRID, color="0.7", lw=0.8)
            ax.set_xlim(0, w)
            ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: board corners of {len(views)} views")
    tilts = [view_tilt_deg(T) for T in calib.T_left_from_board]
    axes[2].scatter([t[0] for t in tilts], [t[1] for t in tilts])
    axes[2].axhline(0, color="0.7")
    axes[2].axvline(0, color="0.7")
    axes[2].set_xlabel("yaw (°, + turned right)")
    axes[2].set_ylabel("pitch (°, + tilted down)")
    axes[2].set_title(f"board tilts; RMS {calib.rms_px:.3f} px, epipolar {calib.epipolar_px_per_image:.3f} px")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
