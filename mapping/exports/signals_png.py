"""signals.png: raw inductive and AC readings of the samples along one horizontal line, one curve per pass (as
the paper's figures 5 and 6)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mapping.exports.common import ExportJob
from mapping.pipeline import MapResult
from mapping.scandata import ScanData
from mapping.texture import CLASS_COLOURS
from scanner.channels import CHANNELS, LINE_PEAKS

FILE_NAME = "signals.png"
ORDER = 50


def write(job: ExportJob) -> Path:
    return write_signal_plot(job.data, job.result, job.out_dir / FILE_NAME, job.signal_y)


def signals_along_line(data: ScanData, xy: NDArray[np.float64], y_m: float,
                       rows: int = 3) -> list[dict[str, NDArray[np.float64]]]:
    """Raw readings of the `rows` horizontal raster rows nearest wall height y_m, each joined across frames
    and sorted by wall x: a list of dicts (x, y, direction, inductive, ac, capacitive)."""
    s = data.samples
    horizontal = (s["axis"] == 0) & np.all(np.isfinite(xy), axis=1)
    if not horizontal.any():
        return []
    v = np.round(s["drive_v_m"][horizontal], 5)
    levels = np.unique(v)
    # drive v of the rows whose wall height is nearest y_m (frames stand at about the same height)
    mean_y = np.array([np.mean(xy[horizontal][v == lv, 1]) for lv in levels])
    chosen = levels[np.argsort(np.abs(mean_y - y_m))[:rows]]
    runs: list[dict[str, NDArray[np.float64]]] = []
    for lv in sorted(chosen):
        sel = np.flatnonzero(horizontal)[v == lv]
        order = np.argsort(xy[sel, 0])
        sel = sel[order]
        runs.append({"x": xy[sel, 0], "y": xy[sel, 1], "direction": s["direction"][sel].astype(np.float64),
                     **{c.name: s[c.name][sel] for c in CHANNELS if c.name in s}})
    return runs


def _busiest_height(result: MapResult) -> float:
    """The wall height crossed by the most line objects (the most telling row to plot)."""
    _x0, y0, _x1, y1 = result.bounds
    candidates = np.linspace(y0 + 0.05 * (y1 - y0), y1 - 0.05 * (y1 - y0), 40)
    best, best_n = 0.5 * (y0 + y1), -1
    for y in candidates:
        n = sum(_crossings(o.points_m, y) != [] for o in result.objects if o.kind == "line")
        if n > best_n:
            best, best_n = float(y), n
    return best


def _crossings(p: NDArray[np.float64], y_m: float) -> list[float]:
    out = []
    for a, b in itertools.pairwise(p):
        if (a[1] - y_m) * (b[1] - y_m) <= 0 and abs(b[1] - a[1]) > 1e-9:
            out.append(float(a[0] + (y_m - a[1]) * (b[0] - a[0]) / (b[1] - a[1])))
    return out


def write_signal_plot(data: ScanData, result: MapResult, path: str | Path, y_m: float | None = None) -> Path:
    """Raw inductive and AC readings along horizontal raster rows (the paper's figures 5 and 6): three
    neighbouring rows 1 raster step apart, with the objects found marked where they cross."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    if y_m is None:
        y_m = _busiest_height(result)
    runs = signals_along_line(data, result.sample_xy, y_m)
    fig, axes = plt.subplots(len(LINE_PEAKS), 1, figsize=(10, 5.5), sharex=True)
    for ax, ch in zip(axes, LINE_PEAKS, strict=True):
        key, label = ch.name, ch.label
        for run in runs:
            if key in run:
                ax.plot(run["x"], run[key], lw=0.9, label=f"row at y ≈ {np.mean(run['y']):.3f} m")
        ax.set_ylabel(f"{label}\n[{ch.units}]")
        ax.grid(alpha=0.3)
        for o in result.objects:
            if o.kind == "line":
                for x_cross in _crossings(o.points_m, y_m):
                    ax.axvline(x_cross, color=np.array(CLASS_COLOURS.get(o.cls, (0, 0, 0))) / 255.0, ls="--",
                               lw=0.8)
    if runs:
        axes[0].legend(fontsize=7, loc="upper right")
    axes[1].set_xlabel("wall x [m]")
    axes[0].set_title(f"Raw readings along y ≈ {y_m:.3f} m; dashed: objects found (red power line, blue pipe)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
