"""The demo's report: report.html from a Jinja2 template (templates/report.html.j2: inline CSS, no scripts, no
network) beside the pictures it shows, linked by relative path so the folder can be moved or zipped as a whole;
and report.pdf, the same page printed by headless Chromium (arproj.report.pdf) where it is installed.

    write_report(ctx)  → OUT/report.html (and OUT/report.pdf)   (ctx: arproj.demo.DemoContext)

Order: what a craftsman looks at first (the wall with the map on it), then every object of the wall against the
map, the accuracy against the truth and the limitations, then every stage's pictures and figures for the
engineer, then the time each stage took and anything missing.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

ACCURACY_ROWS = [  # (stage, figure, what, unit, how it is measured)
    ("map", "recall", "pipes and cables found (recall)", "%",
     "pipes and cables of the wall file within the sensors' depth found by the map; every class is in the "
     "table above"),
    ("map", "fasteners found", "fasteners found", "", "screws and nails of the wall file with a mapped fastener "
     "within 15 mm"),
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

TEMPLATES = Path(__file__).parent / "templates"
STYLE_FILE = TEMPLATES / "report.css"


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


def _label(cls: str | None) -> str:
    from mapping.mapfile import CLASS_LABELS

    if cls is None:
        return "—"
    return {"plastic_pipe": "plastic pipe (dry)"}.get(cls, CLASS_LABELS.get(cls, cls.replace("_", " ")))


def _robot_position(ctx: Any) -> str:
    pose = ctx.figures.get("wall pose", {})
    where = pose.get("robot position in the wall frame m (truth)")
    if where is None:
        return (f"planned {ctx.robot_distance_m():.2f} m in front of the wall's middle (the wall pose did not run, "
                "so no measured position)")
    text = f"x {where[0]:.3f} m, y {where[1]:.3f} m, {where[2]:.3f} m out from the wall (wall frame, simulated truth)"
    if "distance to the wall m" in pose:
        text += (f"; measured: {_fmt(pose['distance to the wall m'])} m from the wall at "
                 f"{_fmt(pose.get('incidence deg', float('nan')))}° incidence")
    return text


def limitations(ctx: Any) -> dict[str, list[str]]:
    """What the map cannot tell, in the sections a handheld scanner's manual has, with this run's figures."""
    from mapping.evaluate import MAX_DEPTH_M
    from scanner.channels import CHANNELS

    fig = ctx.figures.get("map", {})
    cannot = [f"The {c.label} sees {c.sees}; nothing else." for c in CHANNELS]
    cannot += ["A dry plastic pipe answers no channel: it is invisible to this scanner, and a map is no proof that "
               "none runs there.",
               "A wooden stud and a water-filled plastic pipe both only raise the capacitive level: the map calls "
               "either “non-metal”, never one or the other.",
               "A cable that carries no current has no AC field: it reads as metal, not as a power line.",
               "Screws and nails are found only where a pass came within about 4 cm of them (adaptive plan, 25 cm "
               "rows): loose fasteners between rows can be missed (`arproj scan --row-spacing 0.075` finds them)."]
    depth = [f"The figures count pipes and cables up to {MAX_DEPTH_M * 1000:.0f} mm deep; the inductive reading "
             "falls with the cube of the depth, so deeper objects fade into the noise and may be missed.",
             "Depth labels are estimates from the footprint's width, with their σ in objects.json."]
    deep = [s for s in ctx.figures.get("map scores", {}).get("objects", [])
            if s.get("depth_mm", 0) > MAX_DEPTH_M * 1000]
    if deep:
        depth.append("In this wall deeper than that: " + ", ".join(f"{s['id']} ({s['depth_mm']:.0f} mm)"
                                                                 for s in deep) + ".")
    unknown = ["Where no safety channel (inductive and capacitive) covered the ground, the map says unknown, "
               "shown pale red in map.png and unlit on the wall; the drill check answers “unknown” there, never "
               "“safe”.",
               "Beyond the wall's edges and the scanned area, nothing is known."]
    if "wall looked at by both safety channels %" in fig:
        unknown.append(f"This scan: {_fmt(fig['wall looked at by both safety channels %'])} % of the wall was "
                       f"looked at by both safety channels; {_fmt(fig.get('hazard length unknown %', float('nan')))}"
                       " % of the hazards' length lies in unknown ground.")
    inferred = ["A line joined across ground no sensor covered is inferred: an estimate, not a reading; drawn "
                "dashed in map.png and treated as unknown by the drill check."]
    if "inferred stretches" in fig:
        inferred.append(f"This map: {fig['inferred stretches']} inferred stretch(es), "
                        f"{100 * float(fig.get('inferred length m', 0.0)):.1f} cm in all.")
    run = ["Every figure of this report is measured on a simulated site against its exact truth; on a real wall "
           "the sensors' noise, the material and the wall's contents differ."]
    if ctx.design_rig_used:
        run.append("The calibrated rig failed; the projection used the robot's design values (uncalibrated).")
    return {"cannot_see": cannot, "depth": depth, "unknown": unknown, "inferred": inferred, "run": run}


def render_report(ctx: Any, no_pdf: str = "") -> str:
    """The report's HTML for the demo context; no_pdf: why there is no report.pdf beside it ("": there is)."""
    import jinja2
    from markupsafe import Markup, escape

    from arproj.session.robot_io import TRUTH_PRIOR
    from geometry import provenance

    out: Path = ctx.out
    figures: dict[str, dict[str, Any]] = ctx.figures

    def figure(pic: dict[str, str]) -> Markup:
        file, caption = pic["file"], pic["caption"]
        if not (out / file).exists():
            return Markup('<p class="bad">missing picture {}</p>').format(file)
        return Markup('<figure><a href="{0}"><img src="{0}" alt="{1}"></a><figcaption>{1}</figcaption>'
                      "</figure>").format(file, caption)

    by_stage: dict[str, list[dict[str, str]]] = {}
    for pic in ctx.pictures:
        by_stage.setdefault(pic["stage"], []).append(pic)
    truth_figures = [p for p in by_stage.get("map", []) if p["file"] == "map_vs_truth.png"]
    accuracy = [{"what": what, "unit": unit, "how": how,
                 "value": None if figures.get(stage, {}).get(key) is None else _fmt(figures[stage][key], unit)}
                for stage, key, what, unit, how in ACCURACY_ROWS]
    notes = []
    source = str(figures.get("wall pose", {}).get("in-plane position of the wall frame from", ""))
    if source == TRUTH_PRIOR:
        notes.append({"cls": "muted", "text": "Note: the wall plane and the projector's pose are measured from the "
                      "projected pattern; the wall frame's in-plane position (along the wall, height, rotation "
                      f"about the normal) comes from “{source}”, as the projection session does on the simulated "
                      "site — the registration figures do not include a localization error."})
    if ctx.design_rig_used:
        failed = figures.get("wall pose", {}).get("calibrated rig failed", "")
        notes.append({"cls": "bad", "text": f"The calibrated rig failed in the wall pose ({failed}); the projection "
                      "stages used the robot's design values (an uncalibrated rig)."})
    stages = []
    for record in ctx.stages.values():
        pictures = [] if record.name == "photograph" else [p for p in by_stage.get(record.name, [])
                                                            if p not in truth_figures]
        stages.append({"name": record.name, "status": record.status, "reason": record.reason,
                       "seconds": "—" if record.seconds is None else f"{record.seconds:.1f}", "pictures": pictures,
                       "rows": [(k, _fmt(v)) for k, v in figures.get(record.name, {}).items()]})
    scores = figures.get("map scores", {})
    from mapping.evaluate import ObjectScore, class_summary

    objects = [ObjectScore(**s) for s in scores.get("objects", [])]
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(TEMPLATES), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    return env.get_template("report.html.j2").render(
        style=Markup(STYLE_FILE.read_text(encoding="utf-8")), version=provenance.version(),
        command=provenance.command(), date=time.strftime("%Y-%m-%d %H:%M %Z"), wall=ctx.wall,
        wall_path=str(ctx.wall_path), robot=_robot_position(ctx), seed=ctx.options.seed, quick=ctx.options.quick,
        problems=[r for r in ctx.stages.values() if r.status in ("failed", "not run")],
        hero=by_stage.get("photograph", []), scores=objects, summary=class_summary(objects),
        on_nothing=scores.get("on nothing", []), truth_figures=truth_figures, accuracy=accuracy,
        accuracy_notes=notes, limits=limitations(ctx), stages=stages,
        total_seconds=f"{sum(r.seconds or 0.0 for r in ctx.stages.values()):.1f}", no_pdf=no_pdf, figure=figure,
        label=lambda c: escape(_label(c)))


def write_report(ctx: Any) -> Path:
    """Write OUT/report.html from the demo context, and OUT/report.pdf where headless Chromium is installed
    (else, or when printing fails, the report says there is none and why); returns the HTML's path."""
    from arproj.report.pdf import chromium, print_pdf

    path = ctx.out / "report.html"
    pdf = ctx.out / "report.pdf"
    pdf.unlink(missing_ok=True)  # never an earlier run's PDF beside this report
    browser = chromium()
    if browser is None:
        path.write_text(render_report(ctx, "no headless Chromium found (Debian: apt-get install chromium)"),
                        encoding="utf-8")
        return path
    path.write_text(render_report(ctx), encoding="utf-8")
    try:
        print_pdf(path, pdf, browser)
    except (RuntimeError, OSError, subprocess.TimeoutExpired) as err:
        path.write_text(render_report(ctx, f"printing failed: {err}"), encoding="utf-8")
    return path
