"""`arproj demo`: the whole system on the simulated site, end to end, written to an output folder with a report.

Stages, in order (each saves its outputs in OUT before the next starts; OUT/demo-state.json records the
finished ones, so `--resume` skips them and an interrupted run loses nothing):

    scan         adaptive scan of the wall file's wall (scanner, serial device simulators) → scan.db
    map          scan log → stitched frames → grids → objects (mapping) → map/ (map.png, signals.png, …)
    mesh         range images of the simulated site → measured wall surface → textured map/wall.glb, and (the
                 range images looking into the room corner too) map/room.glb: the mapped wall, the side wall and
                 the floor in one room frame, all but the mapped wall dark
    calibrate    the calibration wizard's simulated procedure → rig/ (rig.yaml, camera_info files)
    wall pose    projected pattern, both cameras → wall plane and projector pose (wallpose)
    pre-warp     the projection session's frame: the map pre-warped for the beamer, closed loop, safety gate
    photograph   the simulated camera photographs the wall with that frame projected on it (paper fig. 16)
    room         the room session on map/room.glb, the head turned to the room corner: the beam on the mapped
                 wall and the side wall, the mapped wall shown, the side wall (no map) left dark

Every figure compares with the simulated truth: the wall file (objects), the site (wall plane, projector pose,
where each projector pixel really lands). A stage that fails (a part not usable yet) is reported with its
reason; the stages that do not depend on it still run, and the report says plainly what is missing.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from arproj.console import console, err_console, progress_bar, working
from arproj.session.tolerances import DIN_ZONE_WORDS
from geometry.errors import InputError
from geometry.plain import plain
from geometry.poses import invert, look_at, rotation_angle_deg, transform_points

STATE_FILE = "demo-state.json"
STATE_VERSION = 2
DEFAULT_WALL = "demo_brick_wall"
QUICK_STEREO_POSES = 10        # --quick: board pairs for the stereo step (the wizard's default is 24)
ROBOT_DISTANCE_M = 2.5         # projector to the aim point on the wall
ROBOT_INCIDENCE_DEG = 20.0     # oblique, so the pre-warp has work to do
ROBOT_MIN_DISTANCE_M = 2.0     # closer, a low wall needs more head tilt than the head has
IMAGE_HALF_WIDTH_PER_M = 0.385  # half the beamer image's width / height per metre of throw (the default site's
IMAGE_HALF_HEIGHT_PER_M = 0.25  #   throw ratio 1.3, 16:10)
AIM_EDGE_CLEARANCE_M = 0.05    # the image stays this far off the floor and the room's corner (one wall only)
COVERAGE_CELL_M = 0.05         # mesh coverage: share of the mapped area's 5 cm cells holding a mesh vertex
RANGE_VIEW_DISTANCE_M = 1.5    # range camera in front of the wall: its noise grows as z² (3.4 mm σ at 1.5 m)
RANGE_FOOTPRINT_PER_M = (1.11, 0.83)  # the default site's range camera (58° × 45°) sees this much per metre
RANGE_BLOCK_PX = 4             # range images are reduced to the median of 4 × 4 pixel blocks
RANGE_VIEW_OVERLAP = 0.2       # views overlap by this fraction, so the merged mesh has no gaps
CORNER_VIEW_M = (0.9, 1.0)     # range views into the room corner at the wall's x = 0: eye this far along, out
CORNER_AIM_X_M = 0.35          # the room stage aims the beam's centre this far from that corner, on the wall
CALIBRATED_RIG = "calibrated (rig/)"
DESIGN_RIG = "design values (uncalibrated)"
TRUTH_STEP_M = 0.01            # truth polylines drawn into the photograph at 1 cm steps


@dataclass
class DemoOptions:
    out: Path
    wall: str | Path = DEFAULT_WALL   # a wall file, or the name of a shipped wall (scanner/walls)
    resume: bool = False
    quick: bool = False               # tests: in-process scan backend, fewer calibration poses
    seed: int = 0
    rig: Path | None = None           # a calibrated rig folder to use instead of running the wizard


@dataclass
class StageRecord:
    name: str
    seconds: float | None = None
    status: str = "pending"          # done | skipped (--resume) | failed | not run
    reason: str = ""


@dataclass
class DemoContext:
    options: DemoOptions
    wall: Any                         # scanner.wall.Wall: the truth
    wall_path: Path
    figures: dict[str, dict[str, Any]] = field(default_factory=dict)   # stage → {name: value}
    pictures: list[dict[str, str]] = field(default_factory=list)       # {file, caption, stage}
    stages: dict[str, StageRecord] = field(default_factory=dict)
    _map: tuple[Any, Any] | None = None          # (ScanData, MapResult), built once per process
    _site: Any = None
    _session: Any = None
    _robot: Any = None

    @property
    def out(self) -> Path:
        return self.options.out

    @property
    def design_rig_used(self) -> bool:
        """The projection stages use the robot's design values: the calibrated rig failed in the wall pose."""
        return self.figures.get("wall pose", {}).get("rig used") == DESIGN_RIG

    def picture(self, file: str, caption: str, stage: str) -> None:
        self.pictures = [p for p in self.pictures if p["file"] != file]
        self.pictures.append({"file": file, "caption": caption, "stage": stage})

    # -- shared, lazily built parts (a resumed run rebuilds them from the files on disk) -----------------------
    def map_data(self) -> tuple[Any, Any]:
        if self._map is None:
            from mapping.pipeline import MapSettings, build_map, load_scan

            data = load_scan(self.out / "scan.db")
            self._map = (data, build_map(data, MapSettings(stitch=True)))
        return self._map

    def map_centre(self) -> tuple[float, float]:
        return self.wall.width_m / 2, self.wall.height_m / 2

    def robot_distance_m(self) -> float:
        """Far enough for the beamer's image to cover most of the mapped area; never so close that the head
        would have to tilt beyond its limit to reach a low wall."""
        w, h = self.wall.width_m, self.wall.height_m
        return float(np.clip(1.3 * max(w, 1.6 * h), ROBOT_MIN_DISTANCE_M, ROBOT_DISTANCE_M))

    def aim_point(self) -> tuple[float, float]:
        """Where the beamer's image is centred: the map's centre, raised so the image stays off the floor."""
        cx, cy = self.map_centre()
        d = self.robot_distance_m()
        return (max(cx, IMAGE_HALF_WIDTH_PER_M * d + AIM_EDGE_CLEARANCE_M),
                max(cy, IMAGE_HALF_HEIGHT_PER_M * d + AIM_EDGE_CLEARANCE_M))

    def site(self) -> Any:
        """The simulated room with the projection robot in front of wall 0, aimed at the mapped area."""
        if self._site is None:
            from arproj.sim.site import Site

            cx, cy = self.aim_point()
            # Colour cameras (Bayer sensors): the photograph shows the map's colour code as the eye sees it;
            # the wall pose and the closed loop read their luminance, as they would a real colour camera's.
            overrides: dict[str, Any] = {"robot": {"distance_m": self.robot_distance_m(),
                                                   "incidence_deg": ROBOT_INCIDENCE_DEG,
                                                   "along_m": cx, "aim_height_m": cy},
                                         "cameras": {"color": True}}
            width = max(5.0, self.wall.width_m + 0.5)
            if width > 5.0 or self.wall.height_m > 2.6:  # room large enough for the wall file's wall
                overrides["room"] = {"corners_m": [[width, 0.0], [0.0, 0.0], [0.0, 4.0], [width, 4.0]],
                                     "height_m": max(2.6, self.wall.height_m + 0.2)}
            self._site = Site.build(seed=self.options.seed, **overrides)
        return self._site

    def session(self) -> Any:
        """The projection session with the rig (calibrated, or the design values after the calibrated one
        failed: figures["wall pose"]["rig used"]) and the map, its head aimed at the aim point."""
        if self._session is None:
            from arproj.session.output import MemoryOutput
            from arproj.session.robot_io import SimulatedRobot
            from arproj.session.session import ProjectionSession
            from arproj.session.wallmap import load_wall_map, wall_room_in_room
            from geometry.rig import Rig

            site = self.site()
            if self.design_rig_used:
                from arproj.session.robot_io import nominal_rig

                rig = nominal_rig(site)
            else:
                rig = Rig.load(self.out / "rig")
            wall_map = load_wall_map(self.out / "map" / "wall.glb")
            # the DIN zones from the room the wall stands in (floor, ceiling, corners) and the wall file's doors,
            # windows and sockets; the map's frame is room wall 0's (stage_mesh)
            wall_map.room = wall_room_in_room(site.walls[0].T_room_from_wall, site.room.corners, site.room.height_m,
                                              0, self.wall.openings, self.wall.sockets,
                                              "the site's room, the wall file's openings and sockets")
            self._robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), seed=self.options.seed)
            self._session = ProjectionSession(rig, wall_map, self._robot)
            self._session.aim_at(self.aim_point())
        return self._session

    def release(self) -> None:
        for part in (self._session, self._robot, self._site):
            if part is not None:
                with contextlib.suppress(Exception):  # releasing GL/serial objects after a failure
                    (part.close if hasattr(part, "close") else part.release)()
        self._session = self._robot = self._site = None


# -- stages ---------------------------------------------------------------------------------------------------
def stage_scan(ctx: DemoContext) -> None:
    """Adaptive scan of the wall through the serial device simulators (--quick: in-process), with progress."""
    from arproj.run.scan import ScanSettings, new_scan_log, scan_simulated
    from scanner.figures import plot_log
    from scanner.run import open_for_resume

    log_path = ctx.out / "scan.db"
    if ctx.options.resume and log_path.exists():  # an interrupted scan continues where it stopped
        scan_log, _ = open_for_resume(log_path, ctx.wall_path)
        settings = ScanSettings.from_log(scan_log.meta, log_path)
    else:
        settings = ScanSettings(plan="adaptive", seed=ctx.options.seed)
        scan_log = new_scan_log(log_path, ctx.wall, str(ctx.wall_path), settings, overwrite=True)
    settings.serial = not ctx.options.quick
    try:
        with progress_bar() as bar:
            task = bar.add_task("scanning", total=1.0)

            def progress(t: float, total: float, passes: int) -> None:
                bar.update(task, completed=t, total=total,
                           description=f"scan: {passes} passes, {t / 60:.1f}/~{total / 60:.1f} min simulated")

            result = scan_simulated(ctx.wall, settings, scan_log, progress).result
    finally:
        scan_log.close()
    backend_name = ("GRBL drives + wall scanner simulators over serial (socket://)" if settings.serial
                    else "in-process site (--quick)")
    plot_log(log_path, ctx.out / "scan_readings.png")
    ctx.picture("scan_readings.png", "Raw inductive and AC readings where the scanner took them (adaptive plan: "
                "a coarse grid, then passes that confirm and trace what it found); the wall file's truth dashed.",
                "scan")
    ctx.figures["scan"] = {"frames": result.n_frames, "passes": result.n_passes,
                           "samples": len(result.samples.get("time_s", [])),
                           "simulated scan time min": result.scan_time_s / 60, "backend": backend_name,
                           "wall": f"{ctx.wall.name} ({ctx.wall.width_m} × {ctx.wall.height_m} m, "
                                   f"{len(ctx.wall.objects)} objects)"}


def stage_map(ctx: DemoContext) -> None:
    """Map from the scan log (stitched frames), every export, and the map's accuracy against the wall file."""
    from geometry.polyline import polyline_length
    from mapping.evaluate import evaluate, false_safe, fastener_recall
    from mapping.exports import export_all
    from mapping.pipeline import sample_positions

    data, result = ctx.map_data()
    export_all(data, result, ctx.out / "map")
    ev = evaluate(result.objects, ctx.wall)
    mean_mm, p95_mm = ev.position_mm()
    safe = false_safe(result.mapped_objects(), result.coverage, ctx.wall)
    worst, worst_share = safe.worst()
    fasteners_found, fasteners = fastener_recall(result.objects, ctx.wall)
    figures: dict[str, Any] = {"objects found": len(result.objects), "targets in the wall": ev.n_targets,
                               "targets found": ev.n_found, "recall": ev.recall, "precision": ev.precision,
                               "position error mean mm": mean_mm, "position error p95 mm": p95_mm,
                               "class accuracy": ev.class_accuracy(), "missed": ", ".join(ev.missed) or "none",
                               "fasteners found": f"{fasteners_found} of {fasteners}",
                               "false-safe length %": 100 * safe.share,
                               "hazard length unknown %": 100 * safe.unknown_share,
                               "worst false-safe object": f"{worst} ({100 * worst_share:.1f} %)" if worst_share
                               else "none",
                               "wall looked at by both safety channels %": 100 * result.coverage.covered_share()}
    if result.truth_xy is not None and len(result.truth_xy) == len(result.sample_xy):
        logged = sample_positions(data)
        truth = result.truth_xy
        figures["sample position error as logged mm"] = float(1000 * np.linalg.norm(logged - truth, axis=1).mean())
        figures["sample position error after stitching mm"] = float(
            1000 * np.linalg.norm(result.sample_xy - truth, axis=1).mean())
    inferred = [polyline_length(p) for o in result.mapped_objects() if o.shape == "line" for p in o.parts(False)]
    figures["inferred stretches"] = len(inferred)
    figures["inferred length m"] = float(sum(inferred))
    figures["notes"] = "; ".join(result.notes + result.warnings)
    ctx.figures["map"] = figures
    map_against_truth(ctx, result.objects)
    ctx.picture("map/map.png", "The in-wall map: classified objects with legend and scale bar (wall coordinates, "
                "origin at the lower-left corner seen from the room).", "map")
    ctx.picture("map/signals.png", "Raw signals along one line across the wall, as the paper's figures 5 and 6: "
                "inductive and AC readings against the position, with the crossings of the mapped objects.", "map")


def map_against_truth(ctx: DemoContext, objects: list[Any]) -> None:
    """Every wall object scored against the map (fasteners, studs and cavities too; a wrong class named as
    such), into ctx.figures["map scores"], and the map-against-truth figure."""
    from arproj.report.figures import MAP_VS_TRUTH_TEXT, map_vs_truth_figure
    from mapping.evaluate import object_scores, unmatched_objects

    scores = object_scores(objects, ctx.wall)
    unmatched = unmatched_objects(objects, ctx.wall)
    ctx.figures["map scores"] = {"objects": [asdict(s) for s in scores],
                                 "on nothing": [o.cls for o in unmatched]}
    map_vs_truth_figure(objects, ctx.wall, scores, unmatched, ctx.out / "map_vs_truth.png")
    ctx.picture("map_vs_truth.png", "The map against the truth. " + MAP_VS_TRUTH_TEXT, "map")


def stage_mesh(ctx: DemoContext) -> None:
    """Range images of the wall → merged surface mesh in the wall frame → textured wall.glb (and a view of it)."""
    from arproj.cli.map import write_room_map
    from arproj.session.wallmap import load_wall_map
    from mapping.exports.glb import ROOM_FILE_NAME, write_wall_glb
    from mapping.surface import merged_range_mesh, other_walls_in_mesh, split_wall_faces, wall_mesh_from_range_images
    from render import MeshRenderer

    _, result = ctx.map_data()
    site = ctx.site()
    T_room_from_wall = site.walls[0].T_room_from_wall
    views, arrays = [], {}
    for k, (vx, vy) in enumerate(_range_view_centres(ctx.wall.width_m, ctx.wall.height_m)):
        eye, target = transform_points(T_room_from_wall, [[vx, vy, RANGE_VIEW_DISTANCE_M], [vx, vy, 0.0]])
        T_room_from_cam = look_at(eye, target, up=[0.0, 0.0, 1.0])
        image = site.range_image(T_room_from_cam)
        depth, intr = _block_median(np.asarray(image.depth, dtype=np.float64), image.intr, RANGE_BLOCK_PX)
        views.append((depth, intr, T_room_from_cam))
        arrays |= {f"depth_{k}": depth, f"K_{k}": intr.K, f"T_world_from_camera_{k}": T_room_from_cam}
    for y in (0.3 * ctx.wall.height_m, 0.7 * ctx.wall.height_m):  # into the corner: the side wall beside it
        k = len(views)
        eye, target = transform_points(T_room_from_wall, [[CORNER_VIEW_M[0], y, CORNER_VIEW_M[1]], [0.0, y, 0.2]])
        T_room_from_cam = look_at(eye, target, up=[0.0, 0.0, 1.0])
        image = site.range_image(T_room_from_cam)
        depth, intr = _block_median(np.asarray(image.depth, dtype=np.float64), image.intr, RANGE_BLOCK_PX)
        views.append((depth, intr, T_room_from_cam))
        arrays |= {f"depth_{k}": depth, f"K_{k}": intr.K, f"T_world_from_camera_{k}": T_room_from_cam}
    np.savez_compressed(ctx.out / "map" / "range_images.npz", T_world_from_wall=T_room_from_wall, **arrays)
    with warnings.catch_warnings():  # all-NaN pixel blocks (no return) are expected at the views' edges
        warnings.simplefilter("ignore", RuntimeWarning)
        merged = merged_range_mesh(views)
        mesh = wall_mesh_from_range_images(views, result.bounds, T_room_from_wall, merged=merged)
    # The crop to the mapped area is in x, y only: the floor in front of the wall's foot comes along. wall.glb
    # keeps it as a dark, untextured surface (no map: unknown); only the wall's faces carry the map.
    wall_faces, other = split_wall_faces(mesh)
    write_wall_glb(result, ctx.out / "map" / "wall.glb", mesh)
    off_plane = np.abs(wall_faces.vertices[:, 2])  # the true wall is the plane z = 0 of the wall frame
    ctx.figures["mesh"] = {"range views": len(views), "vertices": len(mesh.vertices), "faces": len(mesh.faces),
                           "faces textured (on the wall)": len(wall_faces.faces),
                           "faces dark (other surfaces: floor)": 0 if other is None else len(other.faces),
                           "mapped area covered %": _coverage_percent(wall_faces.vertices, result.bounds),
                           "surface median off the true wall mm": float(1000 * np.median(off_plane)),
                           "surface p95 off the true wall mm": float(1000 * np.percentile(off_plane, 95)),
                           "surface RMS off the true wall mm": float(1000 * np.sqrt(np.mean(off_plane ** 2))),
                           "surface max off the true wall mm": float(1000 * off_plane.max())}
    # room.glb when the range images see another wall (the corner views): what the room stage projects
    others = other_walls_in_mesh(merged, T_room_from_wall, views[0][2][:3, 3])
    (ctx.out / "map" / ROOM_FILE_NAME).unlink(missing_ok=True)  # an earlier run's
    if others:
        from arproj.session.room import load_room_map

        room = load_room_map(write_room_map(ctx.out / "map" / ROOM_FILE_NAME, result, merged, T_room_from_wall))
        ctx.figures["mesh"] |= {"room.glb: other walls seen": len(others),
                                "room.glb: faces textured (the mapped wall)": len(room.walls[0].wall_map.mesh.faces),
                                "room.glb: faces dark (side wall, floor: no map)":
                                    0 if room.other is None else len(room.other.faces)}
    # A look at the textured mesh from the room, 40° to the side.
    import trimesh

    loaded = load_wall_map(ctx.out / "map" / "wall.glb")
    textured = trimesh.Scene([loaded.mesh] + ([loaded.other] if loaded.other is not None else []))
    from geometry.intrinsics import Intrinsics

    intr = Intrinsics.from_fov(960, 600, 60.0)
    cx, cy = ctx.map_centre()
    size = max(ctx.wall.width_m, ctx.wall.height_m)
    eye = [cx + 0.6 * size, cy + 0.2 * size, 1.2 * size + 0.5]  # from the side, the whole map in view
    T_wall_from_cam = look_at(eye, [cx, cy, 0.0], up=[0.0, 1.0, 0.0])
    with MeshRenderer() as renderer:
        renderer.set_mesh(textured)
        view = renderer.render(intr, T_wall_from_cam).color
    cv2.imwrite(str(ctx.out / "mesh_view.png"), cv2.cvtColor(view, cv2.COLOR_RGB2BGR))
    ctx.picture("mesh_view.png", f"The textured mesh (map/wall.glb): the wall surface measured by {len(views)} range "
                "images, the in-wall map as its texture (dark where the scanner did not pass), rendered from the "
                "room with arproj's mesh renderer.", "mesh")


def _block_median(depth: np.ndarray, intr: Any, block: int) -> tuple[np.ndarray, Any]:
    """A range image reduced to one pixel per block × block (the median of its valid depths; NaN if none):
    the noise drops by about the block size, lone outliers at depth edges vanish, and the mesh stays small.

    depth: (h, w) metres, NaN where missing. Returns ((h // block, w // block) depth, matching intrinsics).
    """
    from geometry.intrinsics import Intrinsics

    h, w = (depth.shape[0] // block) * block, (depth.shape[1] // block) * block
    blocks = depth[:h, :w].reshape(h // block, block, w // block, block).transpose(0, 2, 1, 3)
    with warnings.catch_warnings():  # all-NaN blocks are expected (no return there): they stay NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        reduced = np.nanmedian(blocks.reshape(h // block, w // block, -1), axis=2)
    # pixel centres: reduced pixel j covers original pixels j·block … j·block + block - 1
    small = Intrinsics(fx=intr.fx / block, fy=intr.fy / block, cx=(intr.cx + 0.5) / block - 0.5,
                       cy=(intr.cy + 0.5) / block - 0.5, width=w // block, height=h // block, dist=intr.dist)
    return reduced, small


def _coverage_percent(vertices: np.ndarray, bounds: tuple[float, float, float, float]) -> float:
    """Share (%) of the COVERAGE_CELL_M cells over bounds (x0, y0, x1, y1) that hold a vertex (n, 3)."""
    x0, y0, x1, y1 = bounds
    nx, ny = max(1, round((x1 - x0) / COVERAGE_CELL_M)), max(1, round((y1 - y0) / COVERAGE_CELL_M))
    ix = np.floor((vertices[:, 0] - x0) / (x1 - x0) * nx).astype(int)
    iy = np.floor((vertices[:, 1] - y0) / (y1 - y0) * ny).astype(int)
    ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    return 100.0 * len(np.unique(iy[ok] * nx + ix[ok])) / (nx * ny)


def _range_view_centres(width_m: float, height_m: float) -> list[tuple[float, float]]:
    """Wall points (x, y) the range camera looks at: a grid whose footprints overlap by RANGE_VIEW_OVERLAP."""
    fov_w, fov_h = RANGE_FOOTPRINT_PER_M[0] * RANGE_VIEW_DISTANCE_M, RANGE_FOOTPRINT_PER_M[1] * RANGE_VIEW_DISTANCE_M
    nx = max(1, int(np.ceil(width_m / ((1 - RANGE_VIEW_OVERLAP) * fov_w))))
    ny = max(1, int(np.ceil(height_m / ((1 - RANGE_VIEW_OVERLAP) * fov_h))))
    xs = (np.arange(nx) + 0.5) * width_m / nx
    ys = (np.arange(ny) + 0.5) * height_m / ny
    return [(float(x), float(y)) for y in ys for x in xs]


def stage_calibrate(ctx: DemoContext) -> None:
    """The calibration wizard's simulated procedure (resumable itself), and its quality figures."""
    from arproj.report.figures import calibration_figure
    from arproj.wizard import run_wizard

    if ctx.options.rig is not None:
        _use_given_rig(ctx)
        return
    state = run_wizard(ctx.out / "rig", sim=True, seed=ctx.options.seed, restart=not ctx.options.resume,
                       stereo_poses=QUICK_STEREO_POSES if ctx.options.quick else None)
    if state.get("next") is not None:
        raise RuntimeError(f"the calibration wizard stopped before step {state['next']}")
    steps = state["steps"]
    q = {name: steps[name].get("quality", {}) for name in steps}
    figures: dict[str, Any] = {
        "stereo reprojection RMS px": q["stereo"].get("reprojection_rms_px"),
        "stereo epipolar error px": q["stereo"].get("epipolar_error_px_per_image"),
        "stereo baseline mm": 1000 * q["stereo"]["baseline_m"] if "baseline_m" in q["stereo"] else None,
        "projector RMS px": q["projector"].get("projector_rms_px"),
        "head model residual deg": q["head"].get("rotation_rms_deg"),
        "head model residual mm": q["head"].get("position_rms_mm"),
        "validation 3-D error RMS mm": q["validation"].get("rms_mm"),
        "validation 3-D error max mm": q["validation"].get("max_mm"),
    }
    for name in steps:
        for key, value in _flat(steps[name].get("truth_errors", {})).items():
            figures[f"vs truth: {name} {key}"] = value
    ctx.figures["calibrate"] = {k: v for k, v in figures.items() if v is not None}
    calibration_figure(state, ctx.out / "calibration.png")
    ctx.picture("calibration.png", "Calibration quality: the wizard's residuals per step and its validation at "
                "head angles not used for fitting (3-D error of the predicted projected grid).", "calibrate")


def _use_given_rig(ctx: DemoContext) -> None:
    """--rig DIR: that rig (copied to OUT/rig) instead of a calibration in this run; its recorded quality."""
    from geometry.rig import Rig

    rig = Rig.load(ctx.options.rig)
    rig.save(ctx.out / "rig")
    figures: dict[str, Any] = {"rig": f"{ctx.options.rig} (given with --rig; not calibrated in this run)"}
    if isinstance(rig.quality, dict):
        for key, value in _flat(rig.quality).items():
            figures[key] = value
        if isinstance(rig.quality.get("source"), str):
            figures["rig source"] = rig.quality["source"]
    ctx.figures["calibrate"] = figures


def stage_wall_pose(ctx: DemoContext) -> None:
    """Estimate the wall plane and the projector's pose from the projected pattern; compare with the site."""
    from arproj.session.scenarios import truth_of

    ctx.figures["wall pose"] = {"rig used": CALIBRATED_RIG if ctx.options.rig is None else f"{ctx.options.rig} (--rig)"}
    session = ctx.session()
    reg = session.estimate()
    calibrated_failure = None
    if reg is None:  # say so, then show the rest with the robot's design values (labelled everywhere)
        calibrated_failure = session.pose_failure
        err_console.print(f"[yellow]wall pose with the calibrated rig failed:[/] {calibrated_failure}; going on "
                          "with the robot's design values (uncalibrated rig)", highlight=False)
        ctx.release()
        ctx.figures["wall pose"] = {"rig used": DESIGN_RIG}
        session = ctx.session()
        reg = session.estimate()
        if reg is None:
            raise RuntimeError(f"the wall pose could not be estimated with the calibrated rig "
                               f"({calibrated_failure}) nor with the design values ({session.pose_failure})")
    truth = truth_of(ctx.site(), 0)
    T_robot_from_wall = invert(truth.T_wall_from_robot)
    normal = T_robot_from_wall[:3, 2]
    distance = -float(normal @ T_robot_from_wall[:3, 3])
    T_true = truth.T_wall_from_projector
    ctx.figures["wall pose"] |= {"calibrated rig failed": calibrated_failure} if calibrated_failure else {}
    ctx.figures["wall pose"] |= {
        "wall normal error deg": reg.plane.normal_error_deg(normal),
        "wall distance error mm": 1000 * abs(reg.plane.distance - distance),
        "projector position error mm": 1000 * float(np.linalg.norm(reg.T_wall_from_projector[:3, 3] - T_true[:3, 3])),
        "projector rotation error deg": rotation_angle_deg(reg.T_wall_from_projector, T_true),
        "pattern corners used": reg.plane.corners,
        "expected registration σ mm": 1000 * reg.sigma_m,
        "distance to the wall m": reg.distance_m, "incidence deg": reg.incidence_deg,
        "robot position in the wall frame m (truth)": [round(float(v), 3) for v in truth.T_wall_from_robot[:3, 3]],
        "in-plane position of the wall frame from": reg.prior_source}
    pattern = session.last_pattern_capture
    if pattern is not None:
        left = pattern[1] if pattern[1].ndim == 2 else cv2.cvtColor(pattern[1], cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(ctx.out / "pattern_left.png"), left)
        ctx.picture("pattern_left.png", "The pattern the beamer projects for the wall pose, as the left camera "
                    "sees it.", "wall pose")


def stage_prewarp(ctx: DemoContext) -> None:
    """The session's frame: the map pre-warped for the beamer (closed loop, safety gate); its true error."""
    from arproj.session.evaluate import map_features, true_landing_errors

    session = ctx.session()
    decision = session.update()
    frame = session.last_frame
    cv2.imwrite(str(ctx.out / "prewarped_frame.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    figures: dict[str, Any] = {"gate": "map shown" if decision.show_map else "WARNING: " + "; ".join(decision.reasons)}
    if np.isfinite(decision.bound_m):
        figures["registration bound 95 % mm"] = 1000 * decision.bound_m
    reg = session.registration
    if reg is not None:
        if reg.loop is not None and len(reg.loop.errors_xy):
            measured = np.linalg.norm(reg.loop.errors_xy - reg.correction_xy, axis=1)
            figures["closed loop: marks seen"] = int(reg.loop.seen.sum())
            figures["closed loop: measured error mean mm"] = float(1000 * measured.mean())
        features = map_features(session.wall_map, reg.T_wall_from_projector, session.projector_intr)
        if len(features):
            errors, _ = true_landing_errors(session, ctx.site(), features, 0)
            if len(errors):
                figures["registration error features"] = len(errors)
                figures["registration error mean mm"] = float(1000 * errors.mean())
                figures["registration error p95 mm"] = float(1000 * np.percentile(errors, 95))
                figures["registration error max mm"] = float(1000 * errors.max())
        figures["projector pixel footprint mm"] = 1000 * reg.footprint_m
    raster = session.map_projector.map_raster  # the map's (the truth check drew marks after it)
    if decision.show_map and raster is not None:
        figures["DIN zones drawn where not scanned m²"] = raster.zone_texels / raster.px_per_m ** 2
        figures["DIN zone labels ('" + DIN_ZONE_WORDS + "')"] = raster.zone_labels
    ctx.figures["pre-warp"] = figures
    ctx.picture("prewarped_frame.png", f"The frame the beamer shows ({frame.shape[1]}×{frame.shape[0]}): the map "
                "pre-warped for the oblique wall and the lens, with legend and registration status; hatched and "
                f"labelled '{DIN_ZONE_WORDS}': the DIN 18015-3 installation zones of the room (floor, ceiling, "
                "corners, doors, windows, sockets) where the wall was not scanned — unknown, never safe.", "pre-warp")


def stage_photograph(ctx: DemoContext) -> None:
    """Photograph the wall with the pre-warped frame projected on it (paper fig. 16), and with the truth drawn."""
    from arproj.report.figures import TRUTH_ON_PHOTO_TEXT, draw_truth_on_photo

    session = ctx.session()
    frame = cv2.cvtColor(cv2.imread(str(ctx.out / "prewarped_frame.png")), cv2.COLOR_BGR2RGB)
    ctx._robot.sync_head()
    site = ctx.site()
    photo = site.photograph("camera_left", projector_image=frame, exposure="auto")  # metered, as a photographer
    image = photo.image if photo.image.ndim == 3 else cv2.cvtColor(photo.image, cv2.COLOR_GRAY2RGB)
    cv2.imwrite(str(ctx.out / "photo_on_wall.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    overlay, drawn = draw_truth_on_photo(image, ctx.wall, site.walls[0].T_room_from_wall, photo.T_room_from_camera,
                                         photo.intr, TRUTH_STEP_M)
    cv2.imwrite(str(ctx.out / "photo_with_truth.png"), cv2.cvtColor(overlay, cv2.COLOR_RGB2BGR))
    T_wall_from_camera = invert(site.walls[0].T_room_from_wall) @ photo.T_room_from_camera
    (ctx.out / "photo_camera.json").write_text(json.dumps({  # to draw anything in wall coordinates on the photo
        "camera": "camera_left", "K": photo.intr.K.tolist(), "dist": list(photo.intr.dist),
        "width": photo.intr.width, "height": photo.intr.height, "T_wall_from_camera": T_wall_from_camera.tolist()},
        indent=2))
    lit = photo.truth.wall_index == 0
    ctx.figures["photograph"] = {"camera": "camera_left", "exposure ms": 1000 * photo.exposure_s,
                                 "truth objects in view": drawn, "wall in the photo %": 100 * float(lit.mean()),
                                 "head (pan, tilt) deg": [round(a, 3) for a in session.head_deg()]}
    ctx.picture("photo_on_wall.png", "The wall photographed by the robot's left camera (a colour camera: Bayer "
                "sensor, demosaiced) with the map projected on it (as the paper's figure 16).", "photograph")
    ctx.picture("photo_with_truth.png", f"The same photograph with the wall file's truth drawn in "
                f"{TRUTH_ON_PHOTO_TEXT} (exact camera pose of the simulation): where the projected lines should be.",
                "photograph")


def stage_room(ctx: DemoContext) -> None:
    """The room session on map/room.glb: the head turned so the beam crosses the room corner beside the mapped
    wall; the mapped wall registered, checked and shown, the side wall (no map: unknown) dark. Against the
    site's truth: where the mapped wall's marks land, and whether anything lit falls on the side wall."""
    from arproj.session.evaluate import room_landing_errors
    from arproj.session.room import RoomSession, load_room_map, wall_points_in_view

    glb = ctx.out / "map" / "room.glb"
    if not glb.is_file():
        raise RuntimeError("map/room.glb was not written: the mesh stage's range images saw no other wall")
    room = load_room_map(glb)
    session = ctx.session()  # the demo's robot and rig
    site = ctx.site()
    with RoomSession(session.rig, room.walls, ctx._robot, other=room.other) as rs:
        rs.aim_at(0, (CORNER_AIM_X_M, ctx.aim_point()[1]))
        verdicts = rs.update()
        frame = rs.last_frame
        assert frame is not None
        cv2.imwrite(str(ctx.out / "room_frame.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        ctx._robot.sync_head()
        landing = np.asarray(site.projector_landing().wall_index)
        lit = frame.max(axis=2) > 0
        # a projector pixel by the wall's edge (the corner line, the floor) straddles it: 2 px either side
        near_edge = cv2.dilate((landing == 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        figures: dict[str, Any] = {
            "registered on wall": rs.walls[rs.anchor].index,
            "beam on the mapped wall %": 100 * float((landing == 0).mean()),
            "beam on other surfaces %": 100 * float((landing != 0).mean()),
            "lit pixels landing off the mapped wall": int((lit & (landing != 0)).sum()),
            "… of them more than 2 px from its edge": int((lit & ~near_edge).sum()),
            "frame says": " / ".join(rs.last_words)}
        v = verdicts.get(0)
        figures["mapped wall"] = "not in view" if v is None else "shown" if v.shown else \
            "dark: " + "; ".join(v.decision.reasons)
        if v is not None and v.shown and rs.T_room_from_projector is not None:
            marks = wall_points_in_view(rs.walls, 0, rs.T_room_from_projector, rs.projector_intr, grid=(8, 5),
                                        border=0.05)
            errors, elsewhere = room_landing_errors(rs, site, 0, marks)
            if len(errors):
                figures |= {"registration error marks": len(errors), "marks landing elsewhere": elsewhere,
                            "registration error mean mm": float(1000 * errors.mean()),
                            "registration error max mm": float(1000 * errors.max())}
        ctx.figures["room"] = figures
    session.registration = None  # the head moved: the demo's own session measures again if used after this
    ctx.picture("room_frame.png", "The room session's frame (map/room.glb) with the beam across the room corner: the "
                "mapped wall drawn with its map; the side wall beside it and the floor, measured by the range "
                "camera but not scanned, left dark — unknown, never safe.", "room")


STAGES: list[tuple[str, Callable[[DemoContext], None], tuple[str, ...]]] = [
    ("scan", stage_scan, ()),
    ("map", stage_map, ("scan",)),
    ("mesh", stage_mesh, ("map",)),
    ("calibrate", stage_calibrate, ()),
    ("wall pose", stage_wall_pose, ("map", "calibrate")),
    ("pre-warp", stage_prewarp, ("wall pose",)),
    ("photograph", stage_photograph, ("pre-warp",)),
    ("room", stage_room, ("mesh", "wall pose")),
]


# -- running --------------------------------------------------------------------------------------------------
def _check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as err:
        raise InputError(f"cannot write to the output folder {out}: {err.strerror}",
                         "pass --out with a folder you can write to") from None


def _load_state(ctx: DemoContext) -> set[str]:
    path = ctx.out / STATE_FILE
    if not path.exists():
        return set()
    from geometry.inputs import parse_json, read_text

    # written by json.dumps, which writes NaN for a figure that has none: those constants are ours
    hint = "delete it, or run without --resume"
    state = parse_json(read_text(path, "demo state", 64 << 20, hint), str(path), hint, constants=True)
    if not isinstance(state, dict) or state.get("version") != STATE_VERSION:
        raise InputError(f"{path}: written by another version of the demo", "run without --resume to start over")
    if state.get("wall_fingerprint") != ctx.wall.fingerprint() or state.get("quick") != ctx.options.quick \
            or state.get("seed") != ctx.options.seed:
        raise InputError(f"{ctx.out} holds a demo of {state.get('wall_path')} (quick {state.get('quick')}, seed "
                         f"{state.get('seed')}), not of {ctx.wall_path} with these options",
                         "use the same --wall/--quick/--seed, another --out, or run without --resume")
    ctx.figures.update(state.get("figures", {}))
    ctx.pictures.extend(state.get("pictures", []))
    for name, rec in state.get("stages", {}).items():
        ctx.stages[name] = StageRecord(name, rec.get("seconds"), rec.get("status", "pending"), rec.get("reason", ""))
    return {n for n, r in ctx.stages.items() if r.status in ("done", "skipped")}


def _save_state(ctx: DemoContext) -> None:
    state = {"version": STATE_VERSION, "wall_path": str(ctx.wall_path), "wall_fingerprint": ctx.wall.fingerprint(),
             "quick": ctx.options.quick, "seed": ctx.options.seed, "figures": ctx.figures, "pictures": ctx.pictures,
             "stages": {n: {"seconds": r.seconds, "status": r.status, "reason": r.reason}
                        for n, r in ctx.stages.items()}}
    tmp = ctx.out / (STATE_FILE + ".tmp")
    tmp.write_text(json.dumps(state, indent=2, default=plain))
    tmp.replace(ctx.out / STATE_FILE)  # atomic: a kill mid-write keeps the previous state


def run_demo(options: DemoOptions) -> DemoContext:
    """Run (or resume) every stage; returns the context with figures, pictures and stage records.

    InputError for bad input (wall file, output folder, a state of another run). KeyboardInterrupt propagates
    after the state of the finished stages has been saved.
    """
    from arproj.run.scan import resolve_wall

    wall, wall_path = resolve_wall(options.wall)
    wall_path = wall_path.resolve()
    if options.rig is not None:
        from geometry.rig import Rig

        Rig.load(options.rig)  # a bad rig folder is an input error now, not a failed stage later
    _check_writable(options.out)
    from render.gl import create_context

    create_context().release()  # the site's cameras and the projection need GL: say so before the scan, not after
    ctx = DemoContext(options, wall, wall_path)
    finished = _load_state(ctx) if options.resume else set()
    if not options.resume:
        ctx.stages.clear()
    started_run = time.perf_counter()
    try:
        for number, (name, stage, needs) in enumerate(STAGES, start=1):
            record = ctx.stages.setdefault(name, StageRecord(name))
            if name in finished:
                record.status = "skipped"
                err_console.print(f"[dim]{name}: done in an earlier run (--resume), skipped[/]")
                continue
            missing = [n for n in needs if ctx.stages.get(n, StageRecord(n)).status not in ("done", "skipped")]
            if missing:
                record.status, record.seconds = "not run", None
                record.reason = f"needs the {' and '.join(missing)} stage, which did not finish"
                err_console.print(f"[yellow]{name}: not run[/] ({record.reason})", highlight=False)
                _save_state(ctx)
                continue
            err_console.print(f"[bold]── {number}/{len(STAGES)} {name}[/]", highlight=False)
            start = time.perf_counter()
            try:
                with _stdout_to_stderr(), working(f"{number}/{len(STAGES)} {name}"):  # bars inside it nest
                    stage(ctx)
            except InputError:
                raise
            except Exception as err:  # a part not usable yet: report it, run what does not depend on it
                record.status, record.seconds = "failed", time.perf_counter() - start
                record.reason = f"{type(err).__name__}: {err}"
                (ctx.out / f"error-{name.replace(' ', '-')}.txt").write_text(traceback.format_exc())
                err_console.print(f"[red]{name} failed:[/] {record.reason}", highlight=False)
                _save_state(ctx)
                continue
            record.status, record.seconds, record.reason = "done", time.perf_counter() - start, ""
            (ctx.out / f"error-{name.replace(' ', '-')}.txt").unlink(missing_ok=True)  # from an earlier run
            _save_state(ctx)
            err_console.print(f"   done in {record.seconds:.1f} s", highlight=False)
    finally:
        ctx.release()
    ctx.figures.setdefault("run", {})["this run's wall-clock time s"] = time.perf_counter() - started_run
    _save_state(ctx)
    from arproj.report import write_report

    write_report(ctx)
    return ctx


@contextlib.contextmanager
def _stdout_to_stderr() -> Iterator[None]:
    """The parts' own progress messages go to stderr, so stdout carries only the demo's summary."""
    with contextlib.redirect_stdout(sys.stderr):
        yield


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dict → {"a b": number} with only numbers kept (truth error figures of the wizard)."""
    out: dict[str, Any] = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out |= _flat(v, f"{prefix} {k}".strip())
    elif isinstance(d, (int, float)) and not isinstance(d, bool):
        out[prefix] = float(d)
    return out


HEADLINES = [  # (stage, figure, label, format)
    ("map", "recall", "map recall", "{:.0%}"),
    ("map", "position error mean mm", "map position error mean", "{:.2f} mm"),
    ("map", "sample position error after stitching mm", "stitched sample positions (mean)", "{:.2f} mm"),
    ("mesh", "surface median off the true wall mm", "mesh off the true wall (median)", "{:.2f} mm"),
    ("calibrate", "validation 3-D error RMS mm", "calibration validation (RMS)", "{:.3f} mm"),
    ("wall pose", "wall normal error deg", "wall normal error", "{:.3f}°"),
    ("wall pose", "wall distance error mm", "wall distance error", "{:.2f} mm"),
    ("pre-warp", "registration error mean mm", "registration error on the wall (mean)", "{:.2f} mm"),
    ("pre-warp", "registration error p95 mm", "registration error on the wall (p95)", "{:.2f} mm"),
]


def headline_figures(ctx: DemoContext) -> list[tuple[str, str]]:
    rows = []
    for stage, key, label, fmt in HEADLINES:
        value = ctx.figures.get(stage, {}).get(key)
        if isinstance(value, (int, float)):
            rows.append((label, fmt.format(value)))
    return rows


def print_summary(ctx: DemoContext) -> None:
    console.print(f"\n[bold green]Report:[/] {(ctx.out / 'report.html').resolve()}", highlight=False)
    for label, value in headline_figures(ctx):
        console.print(f"  {label}: {value}", highlight=False)
    total = sum(r.seconds or 0.0 for r in ctx.stages.values())
    console.print(f"  stage time (all runs): {total:.0f} s", highlight=False)
    for record in ctx.stages.values():
        if record.status in ("failed", "not run"):
            console.print(f"  [red]{record.name}: {record.status}[/] — {record.reason}", highlight=False)
