"""`arproj demo`: the system end to end on the simulated site, written to an output folder with a report.

Stages run in order; each writes its files and figures, and a finished stage is skipped by --resume.
"""

from __future__ import annotations

import html
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from arproj.console import console, err_console
from arproj.render import MeshRenderer
from arproj.render.sample_wall import WALL_SIZE_M, sample_wall_mesh, sample_wall_texture
from geometry import Intrinsics, invert, look_at, transform_points
from geometry.errors import InputError

STATE_FILE = "demo-state.json"
WALL_SAMPLE_M = 0.002  # the projected picture is checked on a 2 mm grid over the wall


@dataclass
class DemoContext:
    out: Path
    figures: dict[str, Any] = field(default_factory=dict)
    pictures: list[tuple[str, str]] = field(default_factory=list)  # (file, caption)
    timings_s: dict[str, float] = field(default_factory=dict)


def demo_projector() -> tuple[Intrinsics, np.ndarray]:
    """A 1280×800 beamer with lens shift and mild distortion, 2 m from the wall and 35° off its normal."""
    intr = Intrinsics(fx=1400.0, fy=1400.0, cx=652.0, cy=905.0, width=1280, height=800,
                      dist=(-0.08, 0.05, 0.0006, -0.0004, 0.0))
    target = np.array([1.25, 0.45, 0.0])  # below the picture: the lens shift throws it upwards
    direction = np.array([np.sin(np.radians(35)), -0.25, np.cos(np.radians(35))])
    eye = target + 2.0 * direction / np.linalg.norm(direction)
    return intr, look_at(eye, target, up=[0, 1, 0])


def stage_prewarp(ctx: DemoContext) -> None:
    """Render the textured wall from the projector's exact viewpoint: the pre-warped frame."""
    intr, T_wall_from_projector = demo_projector()
    with MeshRenderer() as renderer:
        renderer.set_mesh(sample_wall_mesh(grid=200, texture_px=2048))
        start = time.perf_counter()
        frame = renderer.render(intr, T_wall_from_projector).color
        ctx.figures["render_ms"] = (time.perf_counter() - start) * 1e3
    cv2.imwrite(str(ctx.out / "prewarped_frame.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    ctx.pictures.append(("prewarped_frame.png", "The pre-warped frame the beamer shows (1280×800): skewed and "
                         "bent on purpose, so that it lands straight on the oblique wall."))
    ctx.figures["projector"] = {"distance_m": 2.0, "incidence_deg": 35.0, "principal_point_px": [intr.cx, intr.cy],
                                "distortion": list(intr.dist)}


def stage_on_wall(ctx: DemoContext) -> None:
    """Project the frame onto the wall (each wall point takes the light of its projector pixel) and compare."""
    intr, T_wall_from_projector = demo_projector()
    frame = cv2.cvtColor(cv2.imread(str(ctx.out / "prewarped_frame.png")), cv2.COLOR_BGR2RGB)
    w_m, h_m = WALL_SIZE_M
    xs = np.arange(0.0, w_m, WALL_SAMPLE_M) + WALL_SAMPLE_M / 2
    ys = np.arange(h_m, 0.0, -WALL_SAMPLE_M) - WALL_SAMPLE_M / 2  # image rows run down the wall
    gx, gy = np.meshgrid(xs, ys)
    wall_points = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    uv = intr.project(transform_points(invert(T_wall_from_projector), wall_points)).astype(np.float32)
    map_x, map_y = uv[:, 0].reshape(gx.shape), uv[:, 1].reshape(gx.shape)
    on_wall = cv2.remap(frame, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    lit = (map_x >= 0) & (map_x <= intr.width - 1) & (map_y >= 0) & (map_y <= intr.height - 1)
    truth = cv2.resize(sample_wall_texture(2048)[..., :3], (gx.shape[1], gx.shape[0]), interpolation=cv2.INTER_AREA)
    error = np.abs(on_wall.astype(np.int16) - truth.astype(np.int16)).mean(axis=2)
    cv2.imwrite(str(ctx.out / "on_wall.png"), cv2.cvtColor(on_wall, cv2.COLOR_RGB2BGR))
    ctx.pictures.append(("on_wall.png", "What lands on the wall, seen straight on: the grid is square and the "
                         "lines straight again (black: outside the beamer's image)."))
    ctx.figures["lit_fraction_of_wall"] = float(lit.mean())
    ctx.figures["mean_abs_difference_on_wall_grey_levels"] = float(error[lit].mean())
    # Registration: where do the 10 cm grid crossings land? Compare by local cross-correlation.
    ctx.figures["registration_px_at_2mm_sampling"] = _grid_shift_px(on_wall, truth, lit)


def _grid_shift_px(on_wall: np.ndarray, truth: np.ndarray, lit: np.ndarray) -> float:
    """Overall shift (in 2 mm wall samples) between what landed and the truth, by phase correlation."""
    a = cv2.cvtColor(on_wall, cv2.COLOR_RGB2GRAY).astype(np.float32)
    b = cv2.cvtColor(truth, cv2.COLOR_RGB2GRAY).astype(np.float32)
    a[~lit], b[~lit] = 0, 0
    (dx, dy), _ = cv2.phaseCorrelate(a, b)
    return float(np.hypot(dx, dy))


STAGES: list[tuple[str, Callable[[DemoContext], None]]] = [
    ("pre-warp", stage_prewarp),
    ("on the wall", stage_on_wall),
]


def run_demo(out: Path, resume: bool = False) -> DemoContext:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as err:
        raise InputError(f"cannot write to the output folder {out}: {err.strerror}",
                         "pass --out with a folder you can write to") from None
    ctx = DemoContext(out)
    state_path = out / STATE_FILE
    done: dict[str, Any] = {}
    if resume and state_path.exists():
        done = json.loads(state_path.read_text())
        ctx.figures.update(done.get("figures", {}))
        ctx.pictures.extend(tuple(p) for p in done.get("pictures", []))
        ctx.timings_s.update(done.get("timings_s", {}))
    for name, stage in STAGES:
        if name in done.get("finished", []):
            err_console.print(f"[dim]{name}: done in an earlier run, skipped (--resume)[/]")
            continue
        err_console.print(f"[bold]{name}[/] …")
        start = time.perf_counter()
        stage(ctx)
        ctx.timings_s[name] = time.perf_counter() - start
        done.setdefault("finished", []).append(name)
        state_path.write_text(json.dumps({"finished": done["finished"], "figures": ctx.figures,
                                          "pictures": ctx.pictures, "timings_s": ctx.timings_s}, indent=2))
    write_report(ctx)
    return ctx


def write_report(ctx: DemoContext) -> Path:
    """A self-contained report.html beside the pictures it shows."""
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(_show(v))}</td></tr>"
                   for k, v in ctx.figures.items())
    times = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.2f} s</td></tr>" for k, v in ctx.timings_s.items())
    pics = "".join(f'<figure><img src="{html.escape(f)}" style="max-width:100%"><figcaption>{html.escape(c)}'
                   "</figcaption></figure>" for f, c in ctx.pictures)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>arproj demo</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}td{{padding:2px 12px}}
figure{{margin:1.5em 0}}</style></head><body>
<h1>arproj demo — simulated site</h1>
{pics}
<h2>Figures</h2><table>{rows}</table>
<h2>Time per stage</h2><table>{times}</table>
</body></html>"""
    path = ctx.out / "report.html"
    path.write_text(page)
    return path


def _show(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return ", ".join(f"{k}: {_show(x)}" for k, x in v.items())
    if isinstance(v, list):
        return "[" + ", ".join(_show(x) for x in v) + "]"
    return str(v)


def print_summary(ctx: DemoContext) -> None:
    console.print(f"\n[bold green]Report:[/] {ctx.out / 'report.html'}")
    for key in ("render_ms", "lit_fraction_of_wall", "mean_abs_difference_on_wall_grey_levels",
                "registration_px_at_2mm_sampling"):
        if key in ctx.figures:
            console.print(f"  {key}: {_show(ctx.figures[key])}")
