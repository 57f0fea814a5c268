"""The demo's report: one self-contained report.html (inline CSS, no scripts, no network) beside the pictures
it shows, which are linked by relative path so the folder can be moved or zipped as a whole.

    write_report(ctx)  → OUT/report.html   (ctx: arproj.demo.DemoContext)

Order: what a craftsman looks at first (the wall with the map on it), then the accuracy against the truth, then
every stage's pictures and figures for the engineer, then the time each stage took and anything missing.
"""

from __future__ import annotations

import html
import time
from pathlib import Path
from typing import Any

ACCURACY_ROWS = [  # (stage, figure, what, unit, how it is measured)
    ("map", "recall", "objects found (recall)", "%", "pipes and cables of the wall file found by the map"),
    ("map", "precision", "precision", "%", "mapped line length that lies on a real object"),
    ("map", "position error mean mm", "map position error, mean", "mm", "mapped lines vs the wall file"),
    ("map", "position error p95 mm", "map position error, p95", "mm", "mapped lines vs the wall file"),
    ("map", "sample position error after stitching mm", "sample positions after stitching", "mm",
     "mean distance of each reading's position from where it truly was"),
    ("mesh", "surface median off the true wall mm", "wall surface mesh, median", "mm",
     "distance of the mesh's vertices from the true wall plane"),
    ("mesh", "surface p95 off the true wall mm", "wall surface mesh, p95", "mm", "as above (depth edges included)"),
    ("calibrate", "validation 3-D error RMS mm", "calibration validation", "mm",
     "projected grid at unseen head angles, predicted vs measured"),
    ("wall pose", "wall normal error deg", "wall pose: normal", "°", "estimated vs true wall normal"),
    ("wall pose", "wall distance error mm", "wall pose: distance", "mm", "estimated vs true wall plane offset"),
    ("wall pose", "projector position error mm", "projector position", "mm", "estimated vs true, in the wall frame"),
    ("pre-warp", "registration error mean mm", "registration on the wall, mean", "mm",
     "where each drawn map point truly lands (exact ray casting) vs where it belongs"),
    ("pre-warp", "registration error p95 mm", "registration on the wall, p95", "mm", "as above"),
    ("pre-warp", "closed loop: measured error mean mm", "registration as the cameras measure it", "mm",
     "check marks photographed by both cameras (the session's own check)"),
]

STYLE = """body{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;padding:0 1em;color:#222}
h1{margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.5em 0}td,th{padding:3px 12px;border-bottom:1px solid #eee;text-align:left}
td.num{text-align:right;font-variant-numeric:tabular-nums}figure{margin:1.2em 0}img{max-width:100%;
border:1px solid #ddd}figcaption{color:#555;font-size:.92em}.bad{color:#b00;font-weight:bold}.ok{color:#070}
.muted{color:#777}"""


def _fmt(value: Any, unit: str = "") -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if unit == "%":
            return f"{100 * value:.1f}"
        return f"{value:.3g}" if abs(value) < 100 else f"{value:.0f}"
    if isinstance(value, list):
        return ", ".join(_fmt(v) for v in value)
    return str(value)


def _figure(out: Path, file: str, caption: str) -> str:
    if not (out / file).exists():
        return f'<p class="bad">missing picture {html.escape(file)}</p>'
    return (f'<figure><a href="{html.escape(file)}"><img src="{html.escape(file)}" alt="{html.escape(caption)}">'
            f"</a><figcaption>{html.escape(caption)}</figcaption></figure>")


def write_report(ctx: Any) -> Path:
    """Write OUT/report.html from the demo context (figures, pictures, stage records); returns its path."""
    from arproj.session.robot_io import TRUTH_PRIOR
    from geometry import provenance

    out: Path = ctx.out
    figures: dict[str, dict[str, Any]] = ctx.figures
    parts = [f"<!doctype html><html lang=en><head><meta charset=utf-8><title>arproj demo — "
             f"{html.escape(ctx.wall.name)}</title><style>{STYLE}</style></head><body>",
             "<h1>arproj demo — simulated site</h1>",
             f"<p class=muted>Wall file {html.escape(str(ctx.wall_path))} ({html.escape(ctx.wall.name)}, "
             f"{ctx.wall.width_m} × {ctx.wall.height_m} m, {len(ctx.wall.objects)} objects); seed "
             f"{ctx.options.seed}{', quick settings' if ctx.options.quick else ''}; written "
             f"{time.strftime('%Y-%m-%d %H:%M')} by arproj {html.escape(provenance.version())}, command "
             f"<code>{html.escape(provenance.command())}</code>.</p>"]
    problems = [r for r in ctx.stages.values() if r.status in ("failed", "not run")]
    if problems:
        parts.append("<p class=bad>Not complete: " + "; ".join(
            f"stage “{html.escape(r.name)}” {html.escape(r.status)} — {html.escape(r.reason)}" for r in problems)
            + ". Figures of those stages are missing below; nothing was substituted.</p>")
    by_stage: dict[str, list[dict[str, str]]] = {}
    for pic in ctx.pictures:
        by_stage.setdefault(pic["stage"], []).append(pic)
    hero = [p for p in by_stage.get("photograph", [])]
    if hero:
        parts.append("<h2>The map on the wall</h2>")
        parts += [_figure(out, p["file"], p["caption"]) for p in hero]
    parts.append("<h2>Measured accuracy against the truth</h2><table><tr><th>what</th><th>value</th><th>unit</th>"
                 "<th>how it is measured</th></tr>")
    for stage, key, what, unit, how in ACCURACY_ROWS:
        value = figures.get(stage, {}).get(key)
        shown = _fmt(value, unit) if value is not None else '<span class="bad">not measured</span>'
        parts.append(f"<tr><td>{html.escape(what)}</td><td class=num>{shown}</td><td>{unit}</td>"
                     f"<td class=muted>{html.escape(how)}</td></tr>")
    parts.append("</table>")
    pose = figures.get("wall pose", {})
    source = str(pose.get("in-plane position of the wall frame from", ""))
    if source == TRUTH_PRIOR:
        parts.append("<p class=muted>Note: the wall plane and the projector's pose are measured from the projected "
                     "pattern; the wall frame's in-plane position (along the wall, height, rotation about the "
                     f"normal) comes from “{html.escape(source)}”, as the projection session does on the "
                     "simulated site — the registration figures do not include a localization error.</p>")
    if ctx.design_rig_used:
        parts.append(f"<p class=bad>The calibrated rig failed in the wall pose "
                     f"({html.escape(str(pose.get('calibrated rig failed', '')))}); the projection stages used the "
                     "robot's design values (an uncalibrated rig).</p>")
    for record in ctx.stages.values():
        name = record.name
        parts.append(f"<h2>{html.escape(name)}</h2>")
        if record.status in ("failed", "not run"):
            parts.append(f'<p class="bad">{html.escape(record.status)}: {html.escape(record.reason)}</p>')
        if name != "photograph":
            parts += [_figure(out, p["file"], p["caption"]) for p in by_stage.get(name, [])]
        rows = figures.get(name, {})
        if rows:
            parts.append("<table>" + "".join(
                f"<tr><td>{html.escape(k)}</td><td class=num>{html.escape(_fmt(v))}</td></tr>"
                for k, v in rows.items()) + "</table>")
    parts.append("<h2>Time per stage</h2><table><tr><th>stage</th><th>status</th><th>seconds</th></tr>")
    for record in ctx.stages.values():
        cls = "ok" if record.status in ("done", "skipped") else "bad"
        seconds = f"{record.seconds:.1f}" if record.seconds is not None else "—"
        note = " (earlier run)" if record.status == "skipped" else ""
        parts.append(f"<tr><td>{html.escape(record.name)}</td><td class={cls}>{html.escape(record.status)}{note}"
                     f"</td><td class=num>{seconds}</td></tr>")
    total = sum(r.seconds or 0.0 for r in ctx.stages.values())
    parts.append(f"<tr><td><b>total</b></td><td></td><td class=num><b>{total:.1f}</b></td></tr></table>")
    parts.append("<p class=muted>Files: scan.db (scan log), map/ (wall.glb, objects.json, map.png, signals.png, "
                 "objects.dxf, map_server.yaml/.pgm, range_images.npz), rig/ (calibration), demo-state.json "
                 "(for --resume).</p>")
    parts.append("</body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
