"""Full-height walls: stacked bands (the lift raises the drive frame), planned, timed, stitched and mapped.

The test wall is 2.6 m high (rooms are 2.5–2.75 m; the drives reach 2.1 m): a live cable runs horizontally in
the top installation zone at 2.3 m, a copper pipe rises from 1.2 m to the wall top across the seam between
the bands (2.05–2.1 m), and a live cable drops to a socket in the lower band only. 0.7 m wide: two robot
positions, two bands each.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from geometry.errors import InputError
from geometry.polyline import densify, distances_to_polyline
from mapping import tolerances as tol
from mapping.evaluate import MATCH_M, evaluate, false_safe
from mapping.pipeline import build_map
from mapping.scandata import ScanData
from mapping.stitching import LASER_SIGMA_FLOOR
from scanner.log import ScanLog
from scanner.plan import DensePlanner, DriveConfig, band_ranges, frame_targets, make_planner
from scanner.run import (
    DirectBackend,
    ScanCrashError,
    _estimate_total,
    open_for_resume,
    run_scan,
    scan_meta,
    simulated_site,
)
from scanner.sensor_model import SensorConfig
from scanner.wall import Wall, WallObject, save_wall

HEIGHT_M = 2.6
CABLE_Y_M = 2.3  # 30 cm below a 2.6 m ceiling line: the top installation zone (15–45 cm below the ceiling)
PIPE_X_M = 0.2


def full_height_wall(height_m: float = HEIGHT_M) -> Wall:
    """The test wall, or its objects cut to a lower wall of height_m (the same wall, 2.0 m high)."""
    pipe_top = min(HEIGHT_M, height_m)
    objects = [WallObject("pipe", "pipe-seam", 0.025, np.array([[PIPE_X_M, 1.2], [PIPE_X_M, pipe_top]]),
                          material="copper", diameter_m=0.015, water_filled=True),
               WallObject("cable", "cable-socket", 0.02, np.array([[0.5, 0.3], [0.5, 1.6]]), live=True,
                          diameter_m=0.008, material="copper")]
    if height_m > CABLE_Y_M:
        objects.append(WallObject("cable", "cable-top", 0.02, np.array([[0.0, CABLE_Y_M], [0.7, CABLE_Y_M]]),
                                  live=True, diameter_m=0.008, material="copper"))
    return Wall(width_m=0.7, height_m=height_m, material="brick", name=f"full-height wall {height_m} m",
                objects=objects, source="full_height_wall()")


def _scan(wall: Wall, plan: str, seed: int, drives: DriveConfig | None = None):
    sensor, drives = SensorConfig(), drives or DriveConfig()
    world, robot = simulated_site(wall, sensor, drives, seed)
    result = run_scan(wall, DirectBackend(world), robot, plan_kind=plan, sensor=sensor, drives=drives)
    meta = scan_meta(wall, wall.source, make_planner(plan, wall, drives).describe(), sensor, drives, seed, True)
    return result, ScanData.from_scan(f"{plan} scan", result.samples, result.frames, meta)


@pytest.fixture(scope="module", params=[("dense", 3), ("adaptive", 11)], ids=["dense", "adaptive"])
def mapped(request):
    plan, seed = request.param
    wall = full_height_wall()
    result, data = _scan(wall, plan, seed)
    return plan, wall, result, data, build_map(data)


def test_a_tall_wall_is_stacked_bands_and_a_wall_within_reach_is_one_band_as_before():
    drives = DriveConfig()
    assert band_ranges(full_height_wall(2.0), drives) == [(0.0, 0.0, 2.0)]  # y_m, v_lo, v_hi: as before bands
    bands = band_ranges(full_height_wall(), drives)
    assert bands == [(0.0, 0.0, 2.1), (0.5, 1.55, 2.1)]  # the lift raises the frame no more than needed
    (y0, _, top0), (y1, lo1, top1) = bands
    assert y0 + top0 - (y1 + lo1) == pytest.approx(drives.band_overlap_m)  # bands overlap like frames
    assert y1 + top1 == pytest.approx(HEIGHT_M)
    frames = frame_targets(full_height_wall(), drives)
    # band after band at one robot position, the next position from the band the lift is at
    assert [(f.column, f.band) for f in frames] == [(0, 0), (0, 1), (1, 1), (1, 0)]
    assert [f.frame_id for f in frames] == [0, 1, 2, 3]
    assert all(0.0 <= f.v_lo < f.v_hi <= drives.travel_v_m for f in frames)


def test_a_wall_beyond_the_lifts_reach_is_refused_with_the_reach():
    drives = DriveConfig()
    reach = drives.travel_v_m + drives.lift_travel_m
    assert len(band_ranges(full_height_wall(reach), drives)) == 2  # the lift's full travel still fits
    with pytest.raises(InputError, match=r"tall.yaml: height_m = 3 exceeds what the drives reach with the lift "
                                         r"\(travel_v_m \+ lift_travel_m = 2.1 \+ 0.8 = 2.9 m\)") as err:
        frame_targets(Wall(width_m=1.0, height_m=3.0, source="tall.yaml"), drives)
    assert "longer lift" in err.value.hint
    with pytest.raises(InputError, match=r"band_overlap_m = 2.2: must lie in 0 ≤ overlap < travel_v_m"):
        frame_targets(full_height_wall(), DriveConfig(band_overlap_m=2.2))


def test_the_time_model_counts_every_robot_move_lift_move_and_alignment():
    wall = full_height_wall()

    def dense_time(**changes: float) -> float:
        drives = DriveConfig(**changes)
        planner = DensePlanner(wall, drives)
        return _estimate_total(planner, planner.frames(), drives)  # exact for dense (tests/scanner/test_plan.py)

    d = DriveConfig()
    base = dense_time()
    # 2 positions × 2 bands: 2 platform moves, 2 lift moves (up at the first position, down at the second),
    # an alignment after each of the 4
    assert base - dense_time(lift_move_s=0.0) == pytest.approx(2 * d.lift_move_s)
    assert base - dense_time(robot_align_s=0.0) == pytest.approx(4 * d.robot_align_s)
    assert base - dense_time(robot_move_s=0.0) == pytest.approx(2 * d.robot_move_s)
    lower = full_height_wall(2.0)
    result, _ = _scan(wall, "adaptive", 11)
    low_result, _ = _scan(lower, "adaptive", 11)
    assert result.scan_time_s > low_result.scan_time_s + 2 * (d.lift_move_s + d.robot_align_s)
    dense_low = DensePlanner(lower, d)
    assert base > _estimate_total(dense_low, dense_low.frames(), d) + 2 * (d.lift_move_s + d.robot_align_s)


def test_the_cable_in_the_top_zone_and_the_pipe_across_the_seam_are_mapped(mapped):
    plan, wall, _, data, m = mapped
    ev = evaluate(m.objects, wall)
    assert ev.missed == [] and ev.recall == 1.0, (plan, ev.missed)
    # the pipe crossing the band seam is one object, not two pieces meeting at the seam
    pipe = wall.by_id("pipe-seam").points_m
    probe = densify(pipe, 0.005)
    lines = [o for o in m.objects if o.kind == "line"]
    cover = [float((distances_to_polyline(probe, o.points_m) < MATCH_M).mean()) for o in lines]
    best = lines[int(np.argmax(cover))]
    assert max(cover) > 0.9, (plan, cover)
    # its position error: the map's own position σ and the upper band's pose after stitching (the laser's x
    # and roll σ, the roll acting over the drives' whole v travel), 2σ for the worst 5 %
    upper = data.frames["cmd_y_m"] > 0
    sigma_x = max(float(np.max(data.frames["laser_x_sigma_m"][upper])), LASER_SIGMA_FLOOR[0])
    sigma_phi = max(float(np.max(data.frames["laser_phi_sigma_rad"][upper])), LASER_SIGMA_FLOOR[2])
    sigma = math.hypot(tol.POSITION_SIGMA_M, math.hypot(sigma_x, DriveConfig().travel_v_m * sigma_phi))
    on_pipe = densify(best.points_m, 0.002)
    on_pipe = on_pipe[(on_pipe[:, 1] > 1.2) & (on_pipe[:, 1] < HEIGHT_M)]
    error = distances_to_polyline(on_pipe, pipe)
    assert float(np.percentile(error, 95)) < 2.0 * sigma, (plan, float(np.percentile(error, 95)), sigma)
    at_seam = error[(on_pipe[:, 1] > 2.0) & (on_pipe[:, 1] < 2.15)]
    assert at_seam.size and float(at_seam.max()) < 2.0 * sigma  # no step where the bands meet
    fs = false_safe(m.mapped_objects(), m.coverage, wall)
    assert fs.share == 0.0, fs.safe_m  # nothing true is called safe, in either band


def test_the_upper_bands_stitched_poses_match_the_truth_within_the_lasers_sigma(mapped):
    plan, _, result, data, m = mapped
    f = data.frames
    upper = f["cmd_y_m"] > 0
    assert upper.sum() == 2 and np.allclose(f["cmd_y_m"][upper], 0.5)
    true = np.column_stack([f["true_x_m"], f["true_y_m"], f["true_phi_rad"]])
    error = np.abs(m.poses - true)[upper]
    sigma_y = np.maximum(f["laser_y_sigma_m"][upper], LASER_SIGMA_FLOOR[1])
    sigma_phi = np.maximum(f["laser_phi_sigma_rad"][upper], LASER_SIGMA_FLOOR[2])
    assert np.all(error[:, 1] < 3.0 * sigma_y), (plan, error[:, 1], sigma_y)
    assert np.all(error[:, 2] < 3.0 * sigma_phi), (plan, error[:, 2], sigma_phi)
    assert np.all(error[:, :2] < 0.002)  # a few mm at most, where the robot stopped 1 cm off (robot_sigma_m)
    # the upper band's truth: raised by the lift, scanned to the wall's top
    assert np.all(np.abs(true[upper, 1] - 0.5) < 5 * DriveConfig().robot_sigma_m)
    top = result.samples["true_y_m"][np.isin(result.samples["frame_id"], f["frame_id"][upper])]
    assert HEIGHT_M - 0.03 < float(top.max()) < HEIGHT_M + 0.03


def test_a_crash_in_the_upper_band_resumes_to_the_uninterrupted_samples(tmp_path):
    wall = full_height_wall()
    reference, _ = _scan(wall, "adaptive", 5)
    sensor, drives = SensorConfig(), DriveConfig()
    path = tmp_path / "scan.db"
    ScanLog.create(path, scan_meta(wall, wall.source, make_planner("adaptive", wall, drives).describe(), sensor,
                                   drives, 5, simulated=True)).close()
    passes = reference.samples["pass_id"][reference.samples["frame_id"] == 1]
    crash_at = int(passes[len(passes) // 2])  # mid-way through the first upper band

    def hook(pass_id: int) -> None:
        if pass_id == crash_at:
            raise ScanCrashError(f"power lost before pass {pass_id}")

    for crash_hook in (hook, None):
        log, logged_wall = open_for_resume(path)
        world, robot = simulated_site(logged_wall, sensor, drives, 5)
        try:
            run_scan(logged_wall, DirectBackend(world), robot, plan_kind="adaptive", plan_options=log.meta["plan"],
                     sensor=sensor, drives=drives, log=log, crash_hook=crash_hook)
        except ScanCrashError:
            pass
        finally:
            log.close()
    with ScanLog.open(path) as log:
        stored, frames = log.samples(), log.frames()
        assert log.meta["scan_time_s"] == pytest.approx(reference.scan_time_s)
    for key, values in reference.samples.items():
        np.testing.assert_array_equal(stored[key], values, err_msg=key)
    np.testing.assert_allclose(frames["cmd_y_m"], [0.0, 0.5, 0.5, 0.0])


def test_scan_and_map_commands_run_a_full_height_wall(tmp_path):
    """`arproj scan --sim` (serial device simulators) and `arproj map --wall`, as a person runs them."""
    wall_file = tmp_path / "tall.yaml"
    save_wall(full_height_wall(), wall_file)
    env = {**os.environ, "COLUMNS": "200"}
    cli = [sys.executable, "-c", "from arproj.cli import main; main()"]
    scan = subprocess.run([*cli, "scan", "--sim", "--wall", str(wall_file), "--log", str(tmp_path / "scan.db"),
                           "--plan", "adaptive", "--seed", "2"], env=env, capture_output=True, text=True,
                          timeout=120)
    assert scan.returncode == 0, scan.stderr
    assert "4 frames" in scan.stdout
    mapped = subprocess.run([*cli, "map", str(tmp_path / "scan.db"), "--out", str(tmp_path / "map"), "--wall",
                             str(wall_file)], env=env, capture_output=True, text=True, timeout=120)
    assert mapped.returncode == 0, mapped.stderr
    assert "recall 100.0% (3/3)" in mapped.stdout, mapped.stdout
