"""map.png: the classified map with legend and scale bar."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mapping import mapfile
from mapping.exports.common import ExportJob, looked
from mapping.fusion import CLASSES
from mapping.pipeline import MapResult
from mapping.texture import CLASS_COLOURS
from scanner.channels import INDUCTIVE

if TYPE_CHECKING:
    from matplotlib.axes import Axes

FILE_NAME = "map.png"
ORDER = 40


def write(job: ExportJob) -> Path:
    return write_map_png(job.result, job.out_dir / FILE_NAME, title=job.title, objects=job.objects)


def _scale_bar(ax: Axes, bounds: tuple[float, float, float, float]) -> None:
    x0, y0, x1, y1 = bounds
    span = x1 - x0
    length = next(v for v in (1.0, 0.5, 0.2, 0.1, 0.05, 0.02, 0.01) if v <= span / 4 or v == 0.01)
    bx, by = x0 + 0.03 * span, y0 + 0.04 * (y1 - y0)
    ax.plot([bx, bx + length], [by, by], color="black", lw=4, solid_capstyle="butt")
    ax.text(bx + length / 2, by + 0.015 * (y1 - y0), f"{length * 100:g} cm", ha="center", va="bottom",
            fontsize=9, bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none"})


def write_map_png(result: MapResult, path: str | Path, title: str = "",
                  objects: list[mapfile.MappedObject] | None = None) -> Path:
    """The classified map: inductive signal in grey, objects in class colours, legend and scale bar."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    path = Path(path)
    x0, y0, x1, y1 = result.bounds
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    fig, ax = plt.subplots(figsize=(10, max(3.0, 10 * aspect) + 0.8))
    grid = result.grid
    layer = INDUCTIVE.name if INDUCTIVE.name in grid.models else grid.sensors[0]
    sig = grid.signal(layer)
    cmap = plt.get_cmap("Greys").with_extremes(bad=(1.0, 0.85, 0.85))  # unknown: pale red
    sig = np.where(looked(result), sig, np.nan)  # only what both safety channels covered counts as looked at
    ax.imshow(np.ma.masked_invalid(sig), origin="lower", extent=grid.info.extent, cmap=cmap, alpha=0.8)
    used = set()
    any_inferred = False
    for o in result.mapped_objects() if objects is None else objects:
        colour = np.array(CLASS_COLOURS.get(o.cls, CLASS_COLOURS["unknown"])) / 255.0
        used.add(o.cls)
        if o.shape == "point":
            p = o.points_m
            ax.plot(p[:, 0], p[:, 1], "o", color=colour, ms=6, mec="black", mew=0.5)
            continue
        for measured, style in ((True, "-"), (False, "--")):
            for p in o.parts(measured):
                p = np.vstack([p, p[:1]]) if o.is_outline else p
                ax.plot(p[:, 0], p[:, 1], style, color=colour, lw=2.5 if o.shape == "line" else 1.5)
                any_inferred |= not measured
    # an RGB array is a colour to matplotlib; its stubs list only tuples
    handles = [Line2D([0], [0], color=np.array(CLASS_COLOURS[c]) / 255.0, lw=3,  # type: ignore[arg-type]
                      label=mapfile.CLASS_LABELS.get(c, c.replace("_", " "))) for c in CLASSES if c in used]
    if any_inferred:
        handles.append(Line2D([0], [0], color="black", lw=2, ls="--", label="inferred, not measured"))
    handles.append(Line2D([0], [0], color=(1.0, 0.85, 0.85), lw=8, label="not scanned"))
    ax.legend(handles=handles, loc="upper right", fontsize=8, framealpha=0.85)
    _scale_bar(ax, result.bounds)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("wall x [m]")
    ax.set_ylabel("wall y [m]")
    ax.set_aspect("equal")
    ax.set_title(title or f"In-wall map ({layer} signal, {len(result.objects)} objects)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
