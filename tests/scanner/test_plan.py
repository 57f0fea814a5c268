"""Planning: time model, frames and reach, dense raster, adaptive plan against the truth."""

import math

import numpy as np
import pytest

from geometry.errors import InputError
from scanner.plan import (
    DensePlanner,
    DriveConfig,
    PassSpec,
    check_pass_in_reach,
    frame_pose_apply,
    frame_pose_inverse,
    frame_targets,
    move_position,
    move_time,
    sample_times,
)
from scanner.run import DirectBackend, _estimate_total, run_scan, simulated_site
from scanner.sensor_model import SensorConfig
from scanner.wall import Wall, load_wall, random_wall, shipped_walls


def test_trapezoid_and_triangle_profiles():
    assert move_time(0.35, 0.05, 0.5) == pytest.approx(0.35 / 0.05 + 0.05 / 0.5)
    assert move_time(0.001, 0.05, 0.5) == pytest.approx(2 * math.sqrt(0.001 / 0.5))  # never reaches speed
    for length in (0.001, 0.35, 2.0):
        total = move_time(length, 0.05, 0.5)
        t = np.linspace(0, total, 1001)
        s = move_position(t, length, 0.05, 0.5)
        # Float64 round-off only: positions up to 2 m (ulp 4e-16), speeds from differences of 1001 samples
        assert s[0] == 0 and s[-1] == pytest.approx(length, abs=1e-12)
        assert np.all(np.diff(s) >= -1e-15)
        assert np.max(np.diff(s) / np.diff(t)) <= 0.05 + 1e-9  # the speed limit holds
    times = sample_times(7.1, 200.0)
    assert len(times) == 1421 and times[1] == 0.005


def test_frame_poses_round_trip():
    pose = (1.05, 0.01, 0.002)
    uv = np.array([[0.0, 0.0], [0.4, 2.1], [0.2, 1.0]])
    np.testing.assert_allclose(frame_pose_inverse(pose, frame_pose_apply(pose, uv)), uv, atol=1e-12)
    np.testing.assert_allclose(frame_pose_apply(pose, uv[:1]), [[1.05, 0.01]])


def test_frames_cover_the_wall_and_plans_outside_the_reach_are_refused():
    drives = DriveConfig()
    frames = frame_targets(Wall(width_m=2.5, height_m=2.0), drives)
    assert len(frames) == 8 and frames[1].x_m == pytest.approx(0.35)
    assert all(f.u_hi <= drives.travel_u_m for f in frames)
    assert frames[-1].x_m + frames[-1].u_hi == pytest.approx(2.5)
    with pytest.raises(InputError, match=r"tall.yaml: height_m = 3 exceeds what the drives reach with the lift"):
        frame_targets(Wall(width_m=1.0, height_m=3.0, source="tall.yaml"), drives)  # 2.6 m: bands (test_bands.py)
    with pytest.raises(InputError, match=r"u=0.4500 m.*outside the drives' reach"):
        check_pass_in_reach(PassSpec(0, "raster", "x", (0.0, 0.1), (0.45, 0.1)), drives)
    with pytest.raises(InputError, match=r"scan_speed_m_s = 0.1 exceeds the scanner's speed limit"):
        wall = load_wall(shipped_walls()["small_test_wall"])
        world, robot = simulated_site(wall, SensorConfig(), drives, 0)
        run_scan(wall, DirectBackend(world), robot, drives=DriveConfig(scan_speed_m_s=0.1))


def test_dense_raster_is_the_papers_way_and_the_time_model_adds_up():
    wall = load_wall(shipped_walls()["small_test_wall"])
    drives, sensor = DriveConfig(), SensorConfig()
    planner = DensePlanner(wall, drives)
    (passes,) = list(planner.frame_stages(planner.frames()[0]))
    assert len(passes) == 31 and {p.axis for p in passes} == {"x"}
    assert [p.direction for p in passes[:3]] == [1, -1, 1]  # serpentine
    assert np.allclose(np.diff([p.start_uv[1] for p in passes]), 0.01)
    world, robot = simulated_site(wall, sensor, drives, 0)
    result = run_scan(wall, DirectBackend(world), robot, plan_kind="dense", sensor=sensor, drives=drives)
    line = move_time(0.35, drives.scan_speed_m_s, drives.accel_m_s2)
    step = move_time(0.01, drives.rapid_speed_m_s, drives.accel_m_s2)
    expected = drives.robot_move_s + drives.robot_align_s + 31 * line + 30 * step
    assert result.scan_time_s == pytest.approx(expected)
    assert _estimate_total(planner, planner.frames(), drives) == pytest.approx(expected)
    # every sample is within the wall strip its pass covers, at the scanner's sample rate
    assert len(result.samples["time_s"]) == 31 * len(sample_times(line, sensor.rate_hz))


def test_adaptive_plan_takes_under_a_fifth_of_the_dense_time():
    wall = random_wall(7)
    drives, sensor = DriveConfig(), SensorConfig()
    dense = DensePlanner(wall, drives)
    dense_time = _estimate_total(dense, dense.frames(), drives)
    world, robot = simulated_site(wall, sensor, drives, 7)
    result = run_scan(wall, DirectBackend(world), robot, plan_kind="adaptive", sensor=sensor, drives=drives)
    assert result.scan_time_s < 0.2 * dense_time  # the bench's TARGET_TIME_RATIO_RANDOM
    # what the map makes of it (recall, false-safe length): tests/mapping/test_adaptive_scan.py


def test_adaptive_options_round_trip_through_the_logs_meta():
    from scanner.plan import AdaptiveConfig, make_planner

    wall = random_wall(3)
    cfg = AdaptiveConfig(max_step_m=0.2, follow_rounds=1)
    planner = make_planner("adaptive", wall, DriveConfig(), options={k: v for k, v in cfg.to_dict().items()})
    again = make_planner("adaptive", wall, DriveConfig(), options=planner.describe())
    assert again.config == planner.config == cfg  # a resumed scan replays the same plan
