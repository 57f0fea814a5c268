"""The simulated 2-D lasers and their fix: against the simulated truth, σ consistent with the errors."""

import math

import numpy as np
import pytest

from geometry.errors import InputError
from scanner.laser import LaserConfig, measure_fix, simulate_fix, simulate_scan_2d

Z_MAX = 4.5  # largest normalised error allowed over the trials (σ must describe the real errors)


def test_fix_matches_the_true_pose_within_its_sigma():
    z = []
    for k in range(15):
        rng = np.random.default_rng([k, 103])
        true = (0.35 * k % 2.8, 0.01 * math.sin(k), 0.003 * math.cos(k))
        fix, (standoff, yaw) = simulate_fix(true, 2.8, rng)
        # 3 mm range noise averaged over at most the 1440 rays of a turn: σ cannot be far below 3 mm / √1440 = 8e-5 m;
        # above 1 mm (a third of one ray's noise) nothing would be averaged. Yaw: a tenth of the robot's 0.5° σ.
        assert 5e-5 < fix["laser_x_sigma_m"] < 0.001 and 2e-5 < fix["laser_y_sigma_m"] < 0.001
        assert fix["laser_phi_sigma_rad"] < math.radians(0.05)
        z.append([(fix["laser_x_m"] - true[0]) / fix["laser_x_sigma_m"],
                  (fix["laser_y_m"] - true[1]) / fix["laser_y_sigma_m"],
                  (fix["laser_phi_rad"] - true[2]) / fix["laser_phi_sigma_rad"],
                  (fix["laser_dist_m"] - standoff) / fix["laser_dist_sigma_m"],
                  (fix["laser_yaw_rad"] - yaw) / fix["laser_yaw_sigma_rad"]])
    z = np.abs(np.array(z))
    assert z.max() < Z_MAX
    # If σ describes the errors, mean z² over these 75 values is 1 ± sqrt(2/75) = 0.16 (χ²): 4 such sd either side.
    spread = 4 * math.sqrt(2 / z.size)
    assert math.sqrt(1 - spread) < float(np.sqrt(np.mean(z**2))) < math.sqrt(1 + spread)


def test_scan_has_noise_and_outliers_and_is_deterministic():
    cfg = LaserConfig()
    a1, r1 = simulate_scan_2d(1.0, 0.5, 0.0, 2.5, cfg.room_depth_m, cfg, np.random.default_rng(1))
    _, r2 = simulate_scan_2d(1.0, 0.5, 0.0, 2.5, cfg.room_depth_m, cfg, np.random.default_rng(1))
    np.testing.assert_array_equal(r1, r2)
    assert abs(a1[1] - a1[0] - cfg.angular_step_rad) < 1e-12  # float64 round-off near π is ~4e-16 rad
    errors = []
    for seed in range(20):
        angles, ranges = simulate_scan_2d(1.0, 0.5, 0.0, 2.5, cfg.room_depth_m, cfg, np.random.default_rng(seed))
        behind = np.abs(angles + math.pi / 2) < math.radians(20)  # rays to the wall straight behind: 0.5/cos
        errors.append(ranges[behind] - 0.5 / np.cos(angles[behind] + math.pi / 2))
    err = np.concatenate(errors)
    inlier = np.abs(err) < 10 * cfg.range_sigma_m  # range noise never reaches 10 σ; clutter returns do
    # The median absolute deviation of Gaussian noise is 0.674 σ; over ~3,000 rays it is known to a few %.
    assert float(np.median(np.abs(err[inlier]))) == pytest.approx(0.674 * cfg.range_sigma_m, rel=0.1)
    # Clutter returns lie uniformly between 5 % and 100 % of the true range (~0.5 m): more than 3 cm short of
    # it for (0.94 - 0.05) / 0.95 of them. Their count is binomial; allow 4 of its standard deviations.
    p = cfg.outlier_fraction * (1 - 0.03 / 0.5 - 0.05) / 0.95
    expected, sd = p * err.size, math.sqrt(err.size * p * (1 - p))
    assert abs(int(np.sum(np.abs(err) > 0.03)) - expected) < 4 * sd


def test_fix_without_a_visible_side_wall_raises():
    cfg = LaserConfig(max_range_m=0.6)
    angles, ranges = simulate_scan_2d(1.5, 0.5, 0.0, 2.5, cfg.room_depth_m, cfg, np.random.default_rng(2))
    with pytest.raises(InputError, match="side wall"):
        measure_fix(angles, ranges, cfg.side_margin_m)
