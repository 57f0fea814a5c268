"""Exports of a map: wall.glb, objects.json, map PNG, raw-signal plots, DXF.

wall.glb (what the projection session loads)
    A binary glTF 2.0 file with one textured triangle mesh, readable with `trimesh.load(path, force="mesh")`.
    Vertices are in the WALL frame, metres: x right along the wall, y up, z out of the wall into the room;
    the wall surface lies at z ≈ 0 (exactly 0 for the flat wall built from a scan log; the measured surface
    when range images were merged). Faces are wound counter-clockwise seen from the room (+z).
    Texture coordinates: u = (x − x_min)/(x_max − x_min), v = (y − y_min)/(y_max − y_min) over the map's
    bounds (trimesh convention, v = 0 at the image's bottom row). The texture is an RGBA PNG of the in-wall
    map (mapping.texture): class colours (power_line red, metal_pipe blue, metal purple, non_metal brown, cavity
    teal, fastener yellow); scanned areas where nothing was found faint grey (alpha 24); alpha 0 exactly
    where the wall was not scanned (the projection session reads coverage from the alpha).
    The glTF scene's `extras` carry {"frame": "wall", "units": "m", "bounds_m": [x_min, y_min, x_max, y_max]}.

objects.json
    The mapped objects (format arproj-objects/2, read by mapping.mapfile): class, shape, polyline, width,
    confidence, position σ, depth and its σ, and per segment whether it was measured or inferred;
    scanned_regions_m: the area both safety channels covered, as polygons with holes (for drawing only).

coverage.npz
    The evidence layers (mapping.evidence): per channel, the cells its footprint covered and where it
    responded. The drill check (`arproj drill`, the projection session) judges by these, never by outlines.

map.png: the classified map with legend and scale bar. signals.png: raw inductive and AC readings of the
samples along one horizontal line, one curve per pass (as the paper's figures 5 and 6). objects.dxf: one
layer per class; LWPOLYLINE for lines and outlines, CIRCLE for fasteners, in millimetres (CAD's habit).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from numpy.typing import NDArray

from mapping import mapfile
from mapping.evidence import FILE_NAME as COVERAGE_FILE
from mapping.evidence import SAFETY_CHANNELS, regions
from mapping.fusion import CLASSES, class_map
from mapping.pipeline import MapResult
from mapping.scandata import ScanData
from mapping.surface import flat_wall_mesh
from mapping.texture import CLASS_COLOURS, bake_texture, textured_wall_mesh
from scanner.channels import CHANNELS, INDUCTIVE, LINE_PEAKS

if TYPE_CHECKING:
    from matplotlib.axes import Axes


def _looked(result: MapResult) -> NDArray[np.bool_]:
    """Cells both safety channels covered (what may ever be called free), from the coverage layer."""
    if result.coverage is None:
        raise ValueError("the map result has no coverage layer")
    return result.coverage.covered_by_all(SAFETY_CHANNELS)


def scanned_regions(result: MapResult) -> list[dict]:
    """The area both safety channels covered, as polygons with holes in wall metres (for drawing)."""
    return regions(_looked(result), result.grid.info)


def wall_texture(result: MapResult, px_per_m: float = 500.0,
                 objects: list[mapfile.MappedObject] | None = None) -> NDArray[np.uint8]:
    """RGBA texture (H, W, 4) of the map over result.bounds (objects: result.mapped_objects() if not given)."""
    idx, prob = class_map(result.grid)
    return bake_texture(result.grid.info, idx, prob, list(CLASSES), _looked(result),
                        result.mapped_objects() if objects is None else objects, result.bounds, px_per_m)


def write_wall_glb(result: MapResult, path: str | Path, mesh: trimesh.Trimesh | None = None,
                   px_per_m: float = 500.0, objects: list[mapfile.MappedObject] | None = None) -> Path:
    """wall.glb: `mesh` (wall frame; default a flat tessellated wall over the bounds) with the map texture."""
    path = Path(path)
    x0, y0, x1, y1 = result.bounds
    base = mesh if mesh is not None else flat_wall_mesh(x0, y0, x1, y1)
    textured = textured_wall_mesh(base, wall_texture(result, px_per_m, objects), result.bounds)
    scene = trimesh.Scene(textured)
    scene.metadata["extras"] = {"frame": "wall", "units": "m", "bounds_m": list(result.bounds)}
    path.write_bytes(scene.export(file_type="glb"))
    return path


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
    sig = np.where(_looked(result), sig, np.nan)  # only what both safety channels covered counts as looked at
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


def write_dxf(objects: list[mapfile.MappedObject], path: str | Path) -> Path:
    """objects.dxf: a layer per class (inferred stretches on CLASS_INFERRED, dashed), millimetres, wall frame
    (x right, y up); each object's depth in a text label beside it."""
    import ezdxf

    path = Path(path)
    doc = ezdxf.new(units=ezdxf.units.MM, setup=True)
    msp = doc.modelspace()
    aci = {"power_line": 1, "metal_pipe": 5, "metal": 6, "non_metal": 30, "cavity": 4, "fastener": 2}
    for cls in CLASSES:
        doc.layers.add(cls.upper(), color=aci.get(cls, 7))
        doc.layers.add(f"{cls.upper()}_INFERRED", color=aci.get(cls, 7), linetype="DASHED")
    doc.layers.add("LABELS", color=7)
    for o in objects:
        layer = o.cls.upper() if o.cls in CLASSES else "0"
        if o.shape == "point":
            pts = [(float(x) * 1000.0, float(y) * 1000.0) for x, y in o.points_m]
            msp.add_circle(pts[0], radius=max(o.width_m, 0.004) * 500.0, dxfattribs={"layer": layer})
        for measured in (True, False):
            for part in ([] if o.shape == "point" else o.parts(measured)):
                pts = [(float(x) * 1000.0, float(y) * 1000.0) for x, y in part]
                closed = o.is_outline
                name = layer if measured or layer == "0" else f"{layer}_INFERRED"
                poly = msp.add_lwpolyline(pts[:-1] if closed and len(pts) > 3 else pts, dxfattribs={"layer": name})
                poly.closed = closed
                if o.shape == "line":
                    poly.dxf.const_width = o.width_m * 1000.0
        if o.depth_m is not None:
            sigma = "" if o.depth_sigma_m is None else f" ±{o.depth_sigma_m * 1000:.0f}"
            anchor = o.points_m[len(o.points_m) // 2] * 1000.0
            msp.add_text(f"{o.cls.replace('_', ' ')} {o.depth_m * 1000:.0f}{sigma} mm deep", height=12.0,
                         dxfattribs={"layer": "LABELS"}).set_placement((float(anchor[0]) + 15.0,
                                                                        float(anchor[1]) + 15.0))
    doc.saveas(path)
    return path


def export_steps(data: ScanData, result: MapResult, out_dir: str | Path, mesh: trimesh.Trimesh | None = None,
                 title: str = "", signal_y: float | None = None) -> list[tuple[str, Callable[[], Path]]]:
    """(file name, writer) for every export into out_dir, in the order `arproj map` writes them."""
    out = Path(out_dir)
    if result.coverage is None:
        raise ValueError("the map result has no coverage layer")
    coverage = result.coverage
    objects = result.mapped_objects()  # cut into measured and inferred stretches once, for every export
    return [
        ("wall.glb", lambda: write_wall_glb(result, out / "wall.glb", mesh, objects=objects)),
        (mapfile.FILE_NAME, lambda: mapfile.write_objects(out / mapfile.FILE_NAME, objects,
                                                          scanned_regions(result))),
        (COVERAGE_FILE, lambda: coverage.save(out / COVERAGE_FILE)),
        ("map.png", lambda: write_map_png(result, out / "map.png", title=title, objects=objects)),
        ("signals.png", lambda: write_signal_plot(data, result, out / "signals.png", signal_y)),
        ("objects.dxf", lambda: write_dxf(objects, out / "objects.dxf")),
    ]


def export_all(data: ScanData, result: MapResult, out_dir: str | Path,
               mesh: trimesh.Trimesh | None = None) -> dict[str, Path]:
    """Every export into out_dir; returns {name: path}."""
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    return {name: write() for name, write in export_steps(data, result, out_dir, mesh)}
