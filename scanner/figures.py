"""Pictures of scans for people: a scan log's readings on the wall, and the paper's figures 5 and 6 re-made
with the sensor simulator (matplotlib, Agg backend, PNG files)."""

from __future__ import annotations

import itertools
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from scanner.channels import LINE_PEAKS
from scanner.log import ScanLog
from scanner.sensor_model import SensorModel
from scanner.wall import Wall, load_wall, shipped_walls, wall_from_dict

if TYPE_CHECKING:
    from matplotlib.axes import Axes


def _pyplot() -> ModuleType:  # matplotlib.pyplot, imported late (slow) with the Agg backend
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_log(log_path: str | Path, out_path: str | Path, max_points: int = 400_000) -> Path:
    """Inductive and AC readings at their measured wall positions, with the wall's truth if the log has it."""
    plt = _pyplot()
    with ScanLog.open(log_path) as log:
        samples, meta = log.samples(), log.meta
    wall = wall_from_dict(meta["wall_json"], str(log_path)) if meta.get("wall_json") else None
    step = max(1, len(samples["seq"]) // max_points)
    fig, axes = plt.subplots(1, len(LINE_PEAKS), figsize=(14, 6.5), constrained_layout=True)
    for ax, ch in zip(axes, LINE_PEAKS, strict=True):
        channel, cmap = ch.name, ch.cmap
        order = np.argsort(samples[channel][::step])  # strong readings on top
        x, y, v = (samples[k][::step][order] for k in ("x_m", "y_m", channel))
        points = ax.scatter(x, y, c=v, s=1.5, cmap=cmap, vmin=0, vmax=1, linewidths=0)
        if wall is not None:
            _draw_truth(ax, wall)
        ax.set_aspect("equal")
        ax.set_xlabel("x on the wall [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"{channel} reading (display units)")
        fig.colorbar(points, ax=ax, shrink=0.8)
    plan = (meta.get("plan") or {}).get("kind", "?")
    fig.suptitle(f"{Path(log_path).name}: {meta.get('wall_name', '')} — {plan} plan, {len(samples['seq'])} samples"
                 + (" (truth dashed)" if wall is not None else ""))
    out = Path(out_path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _draw_truth(ax: Axes, wall: Wall) -> None:
    for obj in wall.objects:
        g = obj.geometry_m
        if obj.is_line:
            ax.plot(g[:, 0], g[:, 1], "--", color="tab:red" if obj.kind == "cable" else "tab:cyan", lw=0.8)
        elif obj.points_m is not None:
            ax.plot(g[:, 0], g[:, 1], "+", color="white", ms=5)
        else:
            ring = np.vstack([g, g[:1]])
            ax.plot(ring[:, 0], ring[:, 1], ":", color="white", lw=0.8)


def plot_paper_figures(out_path: str | Path, runs: int = 3, y_m: float = 0.30) -> Path:
    """Figures 5 and 6 of the paper re-made: inductive and AC readings along the test plate, `runs` runs each,
    alternating direction (so the inductive hysteresis shows)."""
    plt = _pyplot()
    wall = load_wall(shipped_walls()["paper_test_plate"])
    model = SensorModel(wall)
    x = np.arange(0.0, wall.width_m, 0.001)
    xy = np.column_stack([x, np.full_like(x, y_m)])
    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True, constrained_layout=True)
    for run in range(runs):
        direction = 1.0 if run % 2 == 0 else -1.0
        readings = model.display(xy, np.tile([direction, 0.0], (len(x), 1)), rng=np.random.default_rng(run))
        label = f"run {run + 1} ({'left to right' if direction > 0 else 'right to left'})"
        axes[0].plot(x, readings[:, 0], lw=0.9, label=label)
        axes[1].plot(x, readings[:, 2], lw=0.9, label=label)
    for ax, title in zip(axes, ("Figure 5 — inductive sensor", "Figure 6 — AC sensor"), strict=True):
        for obj in wall.objects:
            crossing = _crossing_x(obj.geometry_m, y_m)
            if crossing is not None:
                ax.axvline(crossing, color="0.7", lw=0.6)
                ax.text(crossing, 1.02, obj.id, rotation=0, ha="center", fontsize=7, color="0.4")
        ax.set_ylim(0, 1.1)
        ax.set_ylabel("reading (display units)")
        ax.set_title(title, loc="left")
        ax.legend(fontsize=7, loc="upper right")
    axes[1].set_xlabel("sensor position along the plate [m]")
    out = Path(out_path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _crossing_x(points: np.ndarray, y: float) -> float | None:
    """x where a polyline first crosses height y (outlines: their centre if they span y), or None."""
    if len(points) >= 3:  # an outline (plate, stud, cavity)
        return float(points[:, 0].mean()) if points[:, 1].min() <= y <= points[:, 1].max() else None
    for a, b in itertools.pairwise(points):
        if (a[1] - y) * (b[1] - y) <= 0 and a[1] != b[1]:
            return float(a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1]))
    return None
