"""Depths of mapped objects (mapping.depth) against the simulated truth.

Two walls with pipes and cables at 15, 25, 35 and 50 mm, vertical, horizontal and diagonal, crossing each
other and beside a parallel neighbour, plus screws, are scanned densely (mapping.simscan, fixed seed), the
pipes wall also adaptively by the scanner's own executor (scanner.run, in-process); the map comes from
mapping.pipeline.build_map, each object with a depth is matched to the true object it lies on, and its error
is compared with the bound and with its own reported σ.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from mapping.depth import AcModel, Footprint, estimate_depths, inductive_footprint
from mapping.evaluate import depth_errors, truth_under
from mapping.fusion import InductiveModel
from mapping.map_object import MapObject
from mapping.pipeline import MapResult, build_map, load_scan
from mapping.scandata import ScanData
from mapping.simscan import simulate_scan
from scanner.wall import Wall, WallObject, wall_from_dict

MEAN_ERROR_M = 0.005  # what a handheld scanner's depth readout promises (±5 mm): the task's bound
Z_MAX = 3.0  # the σ describes the errors: a Gaussian error beyond 3σ happens 3 times in 1000
SIGMA_MAX_M = 0.01  # a 1σ of a centimetre or more tells nothing about how deep to drill
MATCH_M = 0.015  # an object belongs to the true one within this (mapping.evaluate.MATCH_M)
SAMPLE_STEP_M = 0.002  # along a pass: ≥ 20 samples across the narrowest (AC, σ 6 mm) peak's ±3σ


def _pipe(oid: str, points: list[list[float]], depth: float, material: str = "copper") -> dict:
    return {"kind": "pipe", "id": oid, "points_m": points, "depth_m": depth, "material": material,
            "diameter_m": 0.015}


def _cable(oid: str, points: list[list[float]], depth: float) -> dict:
    return {"kind": "cable", "id": oid, "points_m": points, "depth_m": depth}


def _wall(name: str, objects: list[dict]) -> Wall:
    # 1.05 m: three 35 cm frames; objects keep clear of the frame seams at x = 0.35 and 0.70 (no single pass
    # reaches across one, so an object on a seam has no crossing: it is left without a depth)
    return wall_from_dict({"format": "arproj-wall/1", "name": name, "width_m": 1.05, "height_m": 0.7,
                           "material": "drywall", "objects": objects})


PIPES = _wall("depth: pipes", [
    _pipe("pipe-v15", [[0.12, 0.0], [0.12, 0.7]], 0.015),
    _pipe("pipe-d35", [[0.30, 0.05], [0.70, 0.45]], 0.035),
    _pipe("pipe-h50", [[0.05, 0.60], [1.0, 0.60]], 0.05),  # crosses both vertical pipes
    _pipe("pipe-v25", [[0.90, 0.0], [0.90, 0.7]], 0.025, "steel"),
    {"kind": "screw", "id": "screw-10", "points_m": [[0.22, 0.35]], "depth_m": 0.01},
    {"kind": "screw", "id": "screw-20", "points_m": [[0.60, 0.15]], "depth_m": 0.02},
])
CABLES = _wall("depth: cables", [
    _cable("cable-v25", [[0.10, 0.0], [0.10, 0.7]], 0.025),
    _cable("cable-h15", [[0.05, 0.55], [1.0, 0.55]], 0.015),  # over both vertical cables and the pipe
    _cable("cable-d50", [[0.30, 0.05], [0.70, 0.45]], 0.05),
    _cable("cable-v35", [[0.90, 0.0], [0.90, 0.7]], 0.035),
    _pipe("pipe-v25", [[0.82, 0.0], [0.82, 0.7]], 0.025),  # 8 cm beside the cable, coupled to it (AC)
    {"kind": "screw", "id": "screw-05", "points_m": [[0.22, 0.30]], "depth_m": 0.005},
])


def _estimate(data: ScanData, result: MapResult, samples: dict | None = None) -> None:
    sensor = data.meta["sensor"]
    estimate_depths(result.objects, result.grid, data.samples if samples is None else samples, result.sample_xy,
                    InductiveModel.from_meta(sensor), float(sensor["hysteresis_m"]), AcModel.from_meta(sensor))


def _truth_of(obj: MapObject, wall: Wall) -> WallObject | None:
    return truth_under(obj, wall, MATCH_M)


def _errors(result: MapResult, wall: Wall) -> list[tuple[str, float, float]]:
    errors = depth_errors(result.objects, wall)
    assert all(np.isfinite(s) for _, _, s in errors)  # a depth always comes with its σ
    return errors


def _check(errors: list[tuple[str, float, float]]) -> None:
    err = np.array([e for _, e, _ in errors])
    sigma = np.array([s for _, _, s in errors])
    report = ", ".join(f"{i} {e * 1000:+.1f}±{s * 1000:.1f} mm" for i, e, s in errors)
    assert np.mean(np.abs(err)) <= MEAN_ERROR_M, report
    assert np.all(np.abs(err) <= Z_MAX * sigma), report
    assert np.all(sigma < SIGMA_MAX_M), report


@pytest.fixture(scope="module", params=[PIPES, CABLES], ids=["pipes", "cables"])
def dense(request):
    wall = request.param
    data = simulate_scan(wall, seed=7, sample_step_m=SAMPLE_STEP_M)
    result = build_map(data)
    plain = copy.deepcopy(result)  # for the grid fallback: build_map's depths cleared, to be filled again
    for obj in plain.objects:
        obj.depth_m = obj.depth_sigma_m = None
    _estimate(data, result)
    return wall, data, result, plain


def test_dense_scan_depths_match_the_truth(dense):
    wall, _, result, _ = dense
    errors = _errors(result, wall)
    # every pipe, cable and screw the raster crosses gets a depth
    assert {t.id for t in wall.objects} == {i for i, _, _ in errors}
    _check(errors)
    # live cables are measured on the AC channel (sharper, quieter), pipes on the inductive one
    for obj in result.objects:
        truth = _truth_of(obj, wall) if obj.depth_m is not None else None
        if truth is not None and truth.kind in ("pipe", "cable"):
            assert obj.features["depth_channel_ac"] == (1.0 if truth.kind == "cable" else 0.0)


def test_grid_fallback_when_samples_have_no_passes(dense):
    # Without pass ids the samples cannot be split into passes: the lines' depths come from cross profiles of
    # the grid (its splat kernel undone); points need passes and stay without a depth.
    wall, data, _, plain = dense
    samples = {k: v for k, v in data.samples.items() if k != "pass_id"}
    _estimate(data, plain, samples)
    errors = _errors(plain, wall)
    assert errors
    assert all(o.depth_m is None for o in plain.objects if o.kind == "point")
    _check(errors)


def test_adaptive_scan_depths_from_its_passes(tmp_path):
    """The scanner's own adaptive scan: coarse passes 25 cm apart, short confirm and trace passes. (The 45°
    pipe's x and y trace crossings made two lines, one 1.7 cm off, until the plan laid point passes across
    the bumps along its following passes; since then the pipe is one line with a depth.)"""
    from scanner.log import ScanLog
    from scanner.plan import DriveConfig
    from scanner.run import DirectBackend, run_scan, scan_meta, simulated_site
    from scanner.sensor_model import SensorConfig

    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(PIPES, sensor, drives, 0)
    log = ScanLog.create(tmp_path / "adaptive.sqlite",
                         scan_meta(PIPES, "<test>", {"kind": "adaptive"}, sensor, drives, 0, True))
    run_scan(PIPES, DirectBackend(world), robot, plan_kind="adaptive", log=log)
    log.set_meta("status", "complete")
    log.close()
    data = load_scan(tmp_path / "adaptive.sqlite")
    result = build_map(data)
    assert any("sparse scan" in n for n in result.notes)
    _estimate(data, result)
    errors = _errors(result, PIPES)
    # the four pipes are each crossed by ≥ 3 passes clear of their ends (screws are not mapped by this plan)
    assert {i for i, _, _ in errors} >= {"pipe-v15", "pipe-d35", "pipe-h50", "pipe-v25"}
    _check(errors)


def test_unmeasurable_objects_keep_no_depth():
    # A pipe 2 mm under the surface saturates the inductive sensor over its whole core; a line where no pass
    # ran has no crossings; an outline is not a footprint-shaped profile. None of them gets a depth.
    wall = wall_from_dict({"format": "arproj-wall/1", "name": "saturated", "width_m": 0.35, "height_m": 0.3,
                           "material": "drywall",
                           "objects": [{"kind": "pipe", "id": "p", "points_m": [[0.17, 0.0], [0.17, 0.3]],
                                        "depth_m": 0.002, "material": "steel", "diameter_m": 0.05}]})
    data = simulate_scan(wall, seed=1, sample_step_m=SAMPLE_STEP_M, line_spacing_m=0.02)
    result = build_map(data)
    assert float(np.mean(data.samples["inductive"] >= 0.999)) > 0.05  # the premise: a saturated core
    on_pipe = MapObject("line", np.array([[0.17, 0.02], [0.17, 0.28]]), 0.03, cls="metal_pipe")
    elsewhere = MapObject("line", np.array([[0.5, 0.02], [0.5, 0.28]]), 0.03, cls="metal_pipe")
    ring = np.array([[0.1, 0.1], [0.2, 0.1], [0.2, 0.2], [0.1, 0.2], [0.1, 0.1]])
    outline = MapObject("outline", ring, 0.1, cls="metal")
    result.objects = [on_pipe, elsewhere, outline]
    _estimate(data, result)
    assert all(o.depth_m is None and o.depth_sigma_m is None for o in result.objects)


@pytest.mark.parametrize("depth", [0.0, 0.005, 0.02, 0.06])
def test_footprint_relations_invert(depth):
    # the widths the forward model (scanner.sensor_model) gives lines and points, turned back into depths
    fp = inductive_footprint(InductiveModel())
    su, sv = math.hypot(0.011, 0.55 * depth), math.hypot(0.016, 0.55 * depth)
    for angle in np.radians([0.0, 30.0, 45.0, 90.0]):
        e = np.array([math.cos(angle), math.sin(angle)])
        n = np.array([-e[1], e[0]])
        var = n[0] ** 2 * su**2 + n[1] ** 2 * sv**2  # a line integral's cross profile: nᵀΣn
        assert fp.var_across(n, depth) == pytest.approx(var, rel=1e-12)
        assert fp.depth(var - fp.var_across(n, 0.0)) == pytest.approx(depth, abs=1e-9)
        # fusion's width-to-depth agrees (FWHM = 2.3548 σ)
        assert InductiveModel().depth_from_width(2.3548 * math.sqrt(var), e) == pytest.approx(depth, abs=2e-5)
        slice_var = 1.0 / (e[0] ** 2 / su**2 + e[1] ** 2 / sv**2)  # a point's profile along a pass: 1/(aᵀΣ⁻¹a)
        assert fp.var_slice(e, depth) == pytest.approx(slice_var, rel=1e-12)
        assert fp.depth(fp.excess_slice(slice_var, e)) == pytest.approx(depth, abs=1e-9)
    ac = Footprint(0.004, 0.004, 0.3)
    assert ac.depth(ac.var_across(np.array([1.0, 0.0]), depth) - 0.004**2) == pytest.approx(depth, abs=1e-9)
