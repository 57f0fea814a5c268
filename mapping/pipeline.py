"""Scan log → stitched frame poses → occupancy/signal grid → classified objects (what `arproj map` runs).

Reads the SQLite scan log written by scanner.log (format arproj-scanlog/2 or /1). Bad parts of a log are skipped
with a warning and the map is built from what is sound: passes that cannot be read (a truncated file), samples
without a position, NaN readings (that sensor only); cells no sample reached stay *unknown*.
"""

from __future__ import annotations

import itertools
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError
from mapping import tolerances as tol
from mapping.depth import AcModel, estimate_depths
from mapping.evidence import Coverage, coverage_radii, mapped_objects, sample_noise
from mapping.fusion import METAL_CLASSES, UNKNOWN, Fuser, FusionParams, InductiveModel
from mapping.grid import SENSORS, GridInfo, SensorModel, WallGrid, cell_points, cell_resolution
from mapping.map_object import MapObject
from mapping.mapfile import MappedObject
from mapping.objects import extract_lines, extract_points, extract_regions, near_lines, points_on_lines
from mapping.scandata import ScanData
from mapping.stitching import FrameGraph, laser_constraints
from scanner.channels import AC, CAPACITIVE, INDUCTIVE, claimable
from scanner.log import DamagedLogError, ScanLog
from scanner.sensor_model import ADDITIVE_SATURATED, additive_units

STITCH_ROUNDS = 2  # feature pairing + alignment rounds (the second re-pairs and re-linearises)
# A gridded record's map cell is covered when a cell-centre point lies this share of a map cell from its
# centre: that cell alone (its neighbours' centres lie a whole cell away)
CELL_CENTRE_RADIUS = 0.25
SPARSE_COVERAGE = 0.6  # below this fraction of the wall's cells observed, lines come from the passes' peaks
CAP_TWO_SIDED = CAPACITIVE.two_sided  # cavities lower the capacitive map: two-sided background


def load_scan(path: str | Path) -> ScanData:
    """Read a scan log; unreadable passes are skipped with a warning (a truncated or damaged file)."""
    path = Path(path)
    warnings: list[str] = []
    try:
        log = ScanLog.open(path)
    except DamagedLogError as err:
        warnings.append(f"{err}; reading the passes that are sound")
        log = ScanLog.open(path, salvage=True)
    with log:
        try:
            frames = log.frames()
        except (sqlite3.DatabaseError, DamagedLogError, ValueError) as err:
            warnings.append(f"{path}: frames table unreadable ({err}); using sample positions as logged")
            frames = {}
        try:
            samples = log.samples()
        except (sqlite3.DatabaseError, DamagedLogError) as err:  # the reader names damaged pages DamagedLogError
            warnings.append(f"{path}: damaged samples table ({err}); reading pass by pass")
            samples = _samples_pass_by_pass(log, warnings)
        meta = dict(log.meta)
    data = ScanData(str(path), samples, frames, meta, warnings)
    if data.n_samples == 0:
        raise InputError(f"{path}: the scan log has no samples",
                         "the scan stopped before its first pass; resume it with `arproj scan --resume LOG`")
    if meta.get("status") != "complete":
        warnings.append(f"{path}: the scan is not complete (status {meta.get('status')!r}); the map covers "
                        "what was scanned, the rest is marked unknown")
    return data


def _samples_pass_by_pass(log: ScanLog, warnings: list[str]) -> dict[str, NDArray]:
    try:
        pass_ids = [int(p) for p in log.passes()["pass_id"]]
    except (sqlite3.DatabaseError, DamagedLogError) as err:
        raise InputError(f"{log.path}: the scan log is damaged beyond reading ({err})") from None
    parts, bad = [], 0
    for pid in pass_ids:
        try:
            parts.append(log.samples([pid]))
        except (sqlite3.DatabaseError, DamagedLogError):
            bad += 1
    if bad:
        warnings.append(f"{log.path}: {bad} of {len(pass_ids)} passes unreadable and skipped")
    if not parts:
        return {}
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


@dataclass
class MapResult:
    grid: WallGrid
    objects: list[MapObject]
    bounds: tuple[float, float, float, float]  # x_min, y_min, x_max, y_max of the wall, metres
    poses: NDArray[np.float64] | None  # (n_frames, 3) stitched frame poses, or None
    frame_ids: NDArray[np.int64] | None
    warnings: list[str]
    sample_xy: NDArray[np.float64]  # (n, 2) positions the map used, metres
    truth_xy: NDArray[np.float64] | None = None  # (n, 2) simulation truth, if logged
    notes: list[str] = field(default_factory=list)  # what was done (not problems)
    coverage: Coverage | None = None  # what each channel's footprint covered and where it responded

    def mapped_objects(self) -> list[MappedObject]:
        """The objects as objects.json holds them: measured and inferred stretches, depth, position σ."""
        return mapped_objects(self.objects, self.coverage, tol.POSITION_SIGMA_M)


@dataclass(frozen=True)
class ExtractionParams:
    """Thresholds of extract_objects (heights in robust σ over the background, lengths in metres)."""

    line_min_strength: float = 6.0  # ridge height of an inductive or AC line
    point_min_strength: float = 8.0  # peak height of a fastener (inductive, additive units)
    ac_line_sigma_m: float = 0.004  # smoothing of the AC line detector: crests are sharp, and best located so
    # Around each metal line this much is explained (its footprint and capacitive echo): max(floor, factor · width)
    line_clearance_m: float = 0.04
    line_clearance_widths: float = 1.5
    point_clearance_m: float = 0.04  # ... around each fastener and box
    # Metal areas (plates, steel studs) on the inductive map, beside the lines and points
    metal_region_min_strength: float = 10.0
    metal_region_min_width_m: float = 0.04
    metal_region_min_area_m2: float = 0.003
    metal_region_clearance_m: float = 0.02  # the capacitive map is explained this far around a metal area
    # Studs (raised) and cavities (lowered) on the capacitive map
    capacitive_region_min_strength: float = 8.0
    capacitive_region_min_area_m2: float = 0.006
    non_metal_clearance_m: float = 0.04  # a non-metal line explains max(this, its width) around it
    non_metal_line_min_strength: float = 8.0  # capacitive ridge height for a non-metal line, as for its regions
    non_metal_line_max_width_m: float = 0.12  # wider ridges are areas: a line's capacitive footprint at 5 cm < 10 cm
    echo_radius_m: float = 0.02  # a capacitive ridge this close along a metal line is that line's capacitive echo
    crest_radius_m: float = 0.015  # an inductive line this close along an AC crest is the same cable
    duplicate_share: float = 0.7  # ... when more than this share of a segment lies that close (sampled every
    duplicate_step_m: float = 0.01  # ... this far along it)
    stud_fasteners: int = 2  # this many fasteners on a non-metal ridge's centre line: a stud the board is fixed to
    stud_max_bend_widths: float = 0.25  # a stud is straight: its chord departs less than this share of its width
    stud_on_line_widths: float = 0.25  # fasteners within max(this share of the width, stud_on_line_m) of its centre
    stud_on_line_m: float = 0.01


@dataclass(frozen=True)
class MapSettings:
    resolution_m: float = tol.DEFAULT_RESOLUTION_M
    stitch: bool = True
    extraction: ExtractionParams = field(default_factory=ExtractionParams)
    fusion: FusionParams = field(default_factory=FusionParams)


def sample_positions(data: ScanData, poses: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Wall positions (n, 2) of the samples: as logged, or re-derived from drive positions and frame poses."""
    s = data.samples
    xy = np.column_stack([s["x_m"], s["y_m"]])
    if poses is None or not data.frames:
        return xy
    ids = data.frames["frame_id"]
    lookup = {int(f): k for k, f in enumerate(ids)}
    k = np.array([lookup.get(int(f), -1) for f in s["frame_id"]])
    ok = k >= 0
    out = xy.copy()
    uv = np.column_stack([s["drive_u_m"], s["drive_v_m"]])
    pose = poses[k[ok]]
    c, sn = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    out[ok, 0] = pose[:, 0] + c * uv[ok, 0] - sn * uv[ok, 1]
    out[ok, 1] = pose[:, 1] + sn * uv[ok, 0] + c * uv[ok, 1]
    return out


def hysteresis_corrected(xy: NDArray[np.float64], data: ScanData, shift_m: float) -> NDArray[np.float64]:
    """Inductive sample positions moved back against the direction of motion by the sensor's lag."""
    if shift_m == 0.0:
        return xy
    s = data.samples
    out = xy.copy()
    d = s["direction"].astype(np.float64)
    along_x = s["axis"] == 0
    out[along_x, 0] -= d[along_x] * shift_m
    out[~along_x, 1] -= d[~along_x] * shift_m
    return out


def wall_bounds(data: ScanData, xy: NDArray[np.float64]) -> tuple[float, float, float, float]:
    w, h = data.meta.get("wall_width_m"), data.meta.get("wall_height_m")
    if isinstance(w, (int, float)) and isinstance(h, (int, float)) and w > 0 and h > 0:
        return (0.0, 0.0, float(w), float(h))
    ok = np.all(np.isfinite(xy), axis=1)
    lo, hi = xy[ok].min(axis=0), xy[ok].max(axis=0)
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def stitch_frames(data: ScanData) -> tuple[NDArray[np.float64] | None, list[str], list[str]]:
    """(poses, notes, warnings): frame poses aligned from their localization priors, the 2-D laser's x fixes
    (if logged) and, where frames overlap, shared in-wall features, None if the log has no frames; what they
    were stitched with; what could not be. See mapping.stitching."""
    from mapping.frame_features import feature_constraints, frames_features

    f = data.frames
    if not f or f["frame_id"].size == 0:
        return None, [], ["log has no frames; using logged sample positions"]
    est = np.column_stack([f["est_x_m"], f["est_y_m"], f["est_phi_rad"]])
    cov = f["cov"].copy()
    notes: list[str] = []
    warnings: list[str] = []
    bad = ~(np.all(np.isfinite(est), axis=1) & np.all(np.isfinite(cov.reshape(-1, 9)), axis=1))
    if bad.any():
        warnings.append(f"{int(bad.sum())} frame(s) without a sound localization; their samples keep the logged "
                     "positions")
        est[bad] = 0.0
        cov[bad] = np.diag([1e2, 1e2, 1e2])  # effectively free; constrained only by features if any
    eig = np.linalg.eigvalsh(cov)
    cov[eig.min(axis=1) <= 0] += np.diag([1e-8, 1e-8, 1e-10])
    features = frames_features(data)
    poses, n_feat, n_laser, dropped = est.copy(), 0, 0, 0
    for round_ in range(STITCH_ROUNDS):
        # Round 1 pairs features by the localization (and laser); later rounds re-pair them by the aligned
        # poses and re-linearise the rotations about those (Gauss–Newton)
        graph = FrameGraph(poses.copy())
        graph.add_priors(est, cov)
        n_laser = laser_constraints(graph, f)
        first_feature = graph.n_blocks
        sigma = None if round_ == 0 else np.tile([0.003, 0.003, 0.002], (len(est), 1))
        n_feat = feature_constraints(data, graph, poses, features, sigma)
        if n_feat == 0 and n_laser == 0:
            break
        poses, dropped = graph.solve_robust(feature_blocks_from=first_feature)
        if n_feat == 0:
            break  # laser only: linear, one solve is exact
    poses[bad] = np.nan
    if n_feat or n_laser:
        parts = ([f"{n_laser} laser fix(es)"] if n_laser else []) + \
            ([f"{n_feat - dropped} shared in-wall feature(s)"] if n_feat else [])
        notes.append(f"stitched {len(est)} frames with {' and '.join(parts)}"
                     + (f" ({dropped} inconsistent pairing(s) dropped)" if dropped else ""))
    return poses, notes, warnings


def build_map(data: ScanData, settings: MapSettings | None = None) -> MapResult:
    """The whole mapping chain on one scan."""
    settings = settings or MapSettings()
    warnings = list(data.warnings)
    poses, frame_ids, notes = None, None, []
    if settings.stitch and data.frames:
        poses, stitch_notes, stitch_warnings = stitch_frames(data)
        warnings += stitch_warnings
        notes += stitch_notes
        frame_ids = data.frames["frame_id"]
    xy = sample_positions(data, poses)
    if poses is not None:
        logged = np.column_stack([data.samples["x_m"], data.samples["y_m"]])
        missing = ~np.all(np.isfinite(xy), axis=1)
        xy[missing] = logged[missing]
    unplaced = ~np.all(np.isfinite(xy), axis=1)
    if unplaced.all():
        raise InputError(f"{data.source}: no sample has a position on the wall", "check the log's x_m/y_m")
    if unplaced.any():
        warnings.append(f"{int(unplaced.sum())} sample(s) without a position skipped")
    bounds = wall_bounds(data, xy)
    margin = 0.0
    # A gridded record's sample covers its cell: the map's cells divide the record's, edges on edges
    cell = data.cell_m
    resolution = settings.resolution_m if cell is None else cell_resolution(cell, settings.resolution_m)
    info = GridInfo.covering(bounds[0] - margin, bounds[1] - margin, bounds[2] + margin, bounds[3] + margin,
                             resolution)
    if cell is not None:
        notes.append(f"gridded record: each reading covers its {cell * 1000:g} mm cell (map cells "
                     f"{resolution * 1000:.3g} mm); cells not in the record stay unknown")
    absent = [s for s in SENSORS if s not in data.channels]
    if absent:
        notes.append(f"the record has no {', '.join(absent)} channel: classes only those tell are not claimed")
    readings = {s: data.samples[s] for s in SENSORS if s in data.samples and s in data.channels}
    models: dict[str, SensorModel] = {}
    for s, v in readings.items():
        nan = int((~np.isfinite(v)).sum())
        if nan:
            warnings.append(f"{nan} NaN {s} reading(s) skipped")
        if np.isfinite(v).any():
            models[s] = SensorModel.from_readings(s, v)
    if not models:
        raise InputError(f"{data.source}: every reading is NaN; nothing to map")
    grid = WallGrid(info, models)
    shift = float((data.meta.get("sensor") or {}).get("hysteresis_m", 0.0) or 0.0)
    looked: dict[str, NDArray[np.float64]] = {}
    radii = coverage_radii(data.meta.get("sensor"))
    for s in models:
        pos = hysteresis_corrected(xy, data, shift) if s == INDUCTIVE.name else xy
        values = readings[s]
        if cell is not None:  # the reading stands at every map cell centre of its cell, and covers just those
            pos, values = cell_points(pos, values, cell, resolution)
            radii[s] = CELL_CENTRE_RADIUS * resolution
        grid.add_samples(pos, {s: values})
        looked[s] = pos[np.isfinite(values) & np.all(np.isfinite(pos), axis=1)]
    coverage = float(np.mean(grid.known(next(iter(models)))))
    sparse = cell is None and coverage < SPARSE_COVERAGE  # a record's cells are a grid, not passes
    objects = extract_objects(grid, settings, data.meta.get("sensor"), data if sparse else None, xy, shift)
    if sparse:
        notes.append(f"sparse scan ({coverage:.0%} of the wall covered): lines linked from the passes' peaks")
    sensor_meta = data.meta.get("sensor")
    estimate_depths(objects, grid, data.samples, xy, InductiveModel.from_meta(sensor_meta), shift,
                    AcModel.from_meta(sensor_meta))
    pass_ids = data.samples.get("pass_id", np.zeros(data.n_samples, np.int64))
    noise = {s: sample_noise(readings[s], pass_ids, s) for s in models}
    evidence = Coverage.from_grid(grid, looked, objects, radii, bounds, noise)
    truth = None
    if "true_x_m" in data.samples and np.isfinite(data.samples["true_x_m"]).any():
        truth = np.column_stack([data.samples["true_x_m"], data.samples["true_y_m"]])
    return MapResult(grid, objects, bounds, poses, frame_ids, warnings, xy, truth, notes, evidence)


def extract_objects(grid: WallGrid, settings: MapSettings | None = None, sensor_meta: dict | None = None,
                    sparse_data: ScanData | None = None, xy: NDArray[np.float64] | None = None,
                    lag_m: float = 0.0) -> list[MapObject]:
    """Lines from the inductive and AC maps (merged where they coincide) — or, for a sparse scan
    (sparse_data given), from the passes' peaks — then fasteners, non-metal lines (raised capacitive ridges no
    metal explains: water-filled plastic pipes), studs and cavities, all classified.

    A class says only what its channels can tell: what the inductive or AC map found is metal (if fusion
    cannot tell which, "metal"); what only the capacitive map shows is "non_metal" or "cavity", never a pipe
    or metal; a capacitive object fusion cannot name is left to the evidence layer (an unexplained response).
    A non-metal ridge is a line unless fasteners sit on its centre line (a stud: its outline is drawn), so a
    water pipe is one line, never pieces of area."""
    from mapping.sparse import capacitive_from_passes, lines_from_passes

    settings = settings or MapSettings()
    ex = settings.extraction
    model = InductiveModel.from_meta(sensor_meta)
    fuser = Fuser(grid, settings.fusion, model)
    lines: list[MapObject] = []
    if sparse_data is not None and xy is not None:
        lines = lines_from_passes(sparse_data.samples, xy, lag_m, model, settings.fusion)
    elif AC.name in grid.models:
        # Live cables: sharp AC crests (their best-located view). Broad AC ridges are metal coupled to a
        # cable; the inductive map shows that metal better.
        for obj in extract_lines(grid.signal(AC.name), grid.info, sigma_m=ex.ac_line_sigma_m,
                                 min_strength=ex.line_min_strength):
            fuser.classify(obj)
            if obj.cls == "power_line" and obj.features.get("ac_sharpness", 0.0) >= settings.fusion.ac_sharpness:
                lines.append(obj)
    if INDUCTIVE.name in grid.models and sparse_data is None:
        found = extract_lines(grid.signal(INDUCTIVE.name), grid.info, min_strength=ex.line_min_strength)
        crests = list(lines)
        for obj in found:
            lines += _without_duplicate_parts(obj, crests, ex.crest_radius_m, ex)
    points: list[MapObject] = []
    boxes: list[MapObject] = []  # peaks where lines end or meet: the box or junction they meet at
    if INDUCTIVE.name in grid.models:
        # in units where a screw on a pipe adds to the pipe (a saturated display would flatten it away)
        points = extract_points(additive_units(INDUCTIVE.name, grid.signal(INDUCTIVE.name)), grid.info,
                                min_strength=ex.point_min_strength, saturated=ADDITIVE_SATURATED,
                                boxes=True)
        points, boxes = points_on_lines(points, lines)
    non_metal: list[MapObject] = []
    if CAPACITIVE.name in grid.models and INDUCTIVE.name in grid.models and sparse_data is None:
        non_metal = _non_metal_lines(grid, fuser, lines, points, ex)
    regions: list[MapObject] = []
    near_metal_lines = np.zeros(grid.info.shape, bool)
    for ln in lines:
        near_metal_lines |= near_lines([ln], grid.info, max(ex.line_clearance_m, ex.line_clearance_widths * ln.width_m))
    explained = near_metal_lines.copy()
    if points or boxes:
        explained |= near_lines([MapObject("line", np.repeat(p.points_m, 2, axis=0), 0.0) for p in points + boxes],
                                grid.info, ex.point_clearance_m)
    metal_regions: list[MapObject] = []
    if INDUCTIVE.name in grid.models:  # metal areas: plates, steel studs
        metal_regions = extract_regions(grid.signal(INDUCTIVE.name), grid.info, +1.0,
                                        min_strength=ex.metal_region_min_strength,
                                        min_width_m=ex.metal_region_min_width_m,
                                        min_area_m2=ex.metal_region_min_area_m2, exclude=explained)
    if CAPACITIVE.name in grid.models:  # studs (raised) and cavities (lowered)
        cap = grid.signal(CAPACITIVE.name)
        # Fasteners do not show capacitively (too small): only lines explain the capacitive map — metal ones
        # (their capacitive echo) and the non-metal ones found above
        by_lines = near_metal_lines.copy()
        for ln in non_metal:
            by_lines |= near_lines([ln], grid.info, max(ex.non_metal_clearance_m, ln.width_m))
        metal = (near_lines(metal_regions, grid.info, ex.metal_region_clearance_m) if metal_regions
                 else np.zeros(grid.info.shape, bool))
        regions += extract_regions(cap, grid.info, +1.0, min_strength=ex.capacitive_region_min_strength,
                                   min_area_m2=ex.capacitive_region_min_area_m2, exclude=by_lines | metal,
                                   two_sided=CAP_TWO_SIDED)
        regions += extract_regions(cap, grid.info, -1.0, min_strength=ex.capacitive_region_min_strength,
                                   min_area_m2=ex.capacitive_region_min_area_m2, exclude=near_metal_lines,
                                   two_sided=CAP_TWO_SIDED)
    if sparse_data is not None:
        # the grid is too patchy for areas; the passes' lines are classified already, and the capacitive
        # objects come from the passes too (a straight non-metal run with fasteners on it is a stud)
        metal_found = lines + [_metal_named(fuser.classify(o)) for o in points] + [_box(fuser, o) for o in boxes]
        cap_radius = coverage_radii(sensor_meta)[CAPACITIVE.name]
        ridges, cavities = (capacitive_from_passes(sparse_data.samples, xy, cap_radius, settings.fusion)
                            if xy is not None else ([], []))
        fasteners = np.array([p.points_m[0] for p in points]).reshape(-1, 2)
        capacitive = [_as_outline(MapObject("line", r.points_m[[0, -1]], r.width_m, r.strength, r.cls,
                                            r.confidence, r.features)) if _is_stud(r, fasteners, ex) else r
                      for r in ridges] + cavities
    else:
        metal_found = [_metal_named(fuser.classify(o)) for o in lines + points + metal_regions]
        metal_found += [_box(fuser, o) for o in boxes]
        capacitive = [o for o in (fuser.classify(r) for r in regions) if o.cls != UNKNOWN]
    # A class is a claim the record's channels support: without the channel a class needs, metal is "metal"
    # and a capacitive finding is left to the evidence layer (an unexplained response)
    metal_found = [_within_channels(o, grid.sensors) for o in metal_found]
    # a straight ridge of sheet metal (fusion's "metal", not a ridge merely named metal by its channel)
    metal_found = [_as_outline(o) if o.kind == "line" and o.cls == "metal" and len(o.points_m) == 2
                   and not o.features.get(NAMED_BY_CHANNEL) else o for o in metal_found]
    return metal_found + [o for o in non_metal + capacitive if claimable(o.cls, grid.sensors)]


NAMED_BY_CHANNEL = "metal_by_channel"  # feature flag: the class is the finding channel's, fusion could not tell


def _non_metal_lines(grid: WallGrid, fuser: Fuser, metal_lines: list[MapObject],
                     points: list[MapObject], ex: ExtractionParams) -> list[MapObject]:
    """Raised capacitive ridges that no metal line explains and where the inductive channel finds no metal,
    classified (non_metal): water-filled plastic pipes, or studs whose fasteners are not in view (the
    capacitive channel cannot tell the two apart; only the shape differs). A straight ridge with fasteners
    on its centre line is a stud: it is left to the outlines (extract_regions)."""
    found = extract_lines(grid.signal(CAPACITIVE.name), grid.info, min_strength=ex.non_metal_line_min_strength,
                          two_sided=CAP_TWO_SIDED)
    fasteners = np.array([p.points_m[0] for p in points]).reshape(-1, 2)
    out = []
    for ridge in found:
        if ridge.width_m > ex.non_metal_line_max_width_m:
            continue
        for piece in _without_duplicate_parts(ridge, metal_lines, ex.echo_radius_m, ex):
            fuser.classify(piece)
            if piece.cls != "non_metal":
                continue  # metal's capacitive echo (the inductive map names it), or too weak to name
            if _is_stud(piece, fasteners, ex):
                continue
            out.append(piece)
    return out


def _is_stud(line: MapObject, fasteners: NDArray[np.float64], ex: ExtractionParams) -> bool:
    """A straight non-metal ridge with ex.stud_fasteners or more fasteners on its centre line (within a
    quarter of its width): the boards' screws or nails, driven into a stud."""
    from geometry.polyline import distances_to_polyline

    p = line.points_m
    chord = p[-1] - p[0]
    length = float(np.linalg.norm(chord))
    if len(fasteners) < ex.stud_fasteners or length < 1e-9:
        return False
    rel = p - p[0]
    bend = float(np.max(np.abs(chord[0] * rel[:, 1] - chord[1] * rel[:, 0])) / length)
    if bend > ex.stud_max_bend_widths * line.width_m:
        return False  # bent: a pipe, never a stud
    reach = max(ex.stud_on_line_widths * line.width_m, ex.stud_on_line_m)
    on_line = distances_to_polyline(fasteners, p[[0, -1]]) <= reach
    return int(on_line.sum()) >= ex.stud_fasteners


def _metal_named(obj: MapObject) -> MapObject:
    """An object the inductive or AC map found is metal (that is all those channels see): where fusion could
    not name its class ("unknown", or non-metal on a weak inductive ridge), it is "metal" ("fastener" for a
    point) with the probability fusion gave the metal classes together."""
    if obj.cls in METAL_CLASSES:
        return obj
    cls = "fastener" if obj.kind == "point" else "metal"
    obj.cls, obj.confidence = cls, _metal_probability(obj)
    obj.features[NAMED_BY_CHANNEL] = 1.0
    return obj


def _within_channels(obj: MapObject, channels: list[str]) -> MapObject:
    """A metal object whose class needs a channel the record lacks (scanner.channels `needed_for`: a power
    line needs the AC crest, telling a pipe from a cable too) as "metal", which its finding channel tells. A
    line's kind of metal (cable, pipe or a sheet's straight ridge) is one decision, by the AC crest and the
    inductive strength: where a pipe cannot be told, neither can sheet metal, and the line stays a line."""
    if claimable(obj.cls, channels) and not (obj.kind == "line" and not claimable("metal_pipe", channels)):
        return obj
    obj.cls, obj.confidence = "metal", _metal_probability(obj) or obj.confidence
    obj.features[NAMED_BY_CHANNEL] = 1.0
    return obj


def _metal_probability(obj: MapObject) -> float:
    """What fusion gave the metal classes together: how sure the inductive channel is of metal here."""
    return float(sum(obj.features.get(f"p_{c}", 0.0) for c in METAL_CLASSES))


def _box(fuser: Fuser, obj: MapObject) -> MapObject:
    """A point peak where lines end or meet: metal (a socket or junction box, the crossing's own peak), never
    a fastener — its class says only that the inductive channel sees metal there."""
    fuser.classify(obj)
    obj.cls, obj.confidence = "metal", _metal_probability(obj) or 1.0
    obj.features[NAMED_BY_CHANNEL] = 1.0
    obj.features["at_line_end"] = 1.0
    return obj


def _as_outline(obj: MapObject) -> MapObject:
    """A straight ridge of sheet metal (a steel stud, a plate) as the rectangle it covers."""
    a, b = obj.points_m
    d = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
    n = np.array([-d[1], d[0]]) * 0.5 * obj.width_m
    ring = np.array([a + n, b + n, b - n, a - n, a + n])
    return MapObject("outline", ring, obj.width_m, obj.strength, obj.cls, obj.confidence, obj.features)


def _without_duplicate_parts(obj: MapObject, kept: list[MapObject], radius_m: float,
                             ex: ExtractionParams) -> list[MapObject]:
    """obj minus the segments that lie along lines already kept (a cable seen by both the AC and the
    inductive sensor); what remains, split where segments were removed. A segment is a duplicate when
    ex.duplicate_share of it lies within radius_m of a kept line."""
    from geometry.polyline import distances_to_polyline, midpoint_samples

    if not kept:
        return [obj]
    p = obj.points_m
    dup = []
    for a, b in itertools.pairwise(p):
        pts, _ = midpoint_samples(np.array([a, b]), ex.duplicate_step_m)
        d = np.min([distances_to_polyline(pts, k.points_m) for k in kept], axis=0)
        dup.append(bool((d < radius_m).mean() > ex.duplicate_share))
    if not any(dup):
        return [obj]
    out, run = [], [p[0]]
    for k, is_dup in enumerate(dup):
        if is_dup:
            if len(run) >= 2:
                out.append(np.array(run))
            run = [p[k + 1]]
        else:
            run.append(p[k + 1])
    if len(run) >= 2:
        out.append(np.array(run))
    pieces = []
    for poly in out:
        if np.linalg.norm(np.diff(poly, axis=0), axis=1).sum() >= tol.LINE_MIN_LENGTH_M:
            pieces.append(MapObject("line", poly, obj.width_m, obj.strength, features=dict(obj.features)))
    return pieces


