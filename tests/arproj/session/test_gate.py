"""The safety gate's decisions and laser scan matching against exact geometry (the triangulation of its check
marks: tests/geometry/test_triangulation.py)."""

import numpy as np
import pytest

from arproj.session import gate
from arproj.session import tolerances as tol


def _good(**changes):
    ev = gate.RegistrationEvidence(pose_sigma_m=0.0008, closed_loop_errors_m=np.full(30, 0.001),
                                   closed_loop_expected=35, stereo_residual_px=0.05)
    for k, v in changes.items():
        setattr(ev, k, v)
    return ev


def test_good_registration_opens_the_gate():
    d = gate.decide(_good())
    assert d.show_map and d.reasons == []
    assert d.bound_m == pytest.approx(tol.Z95 * 0.0008 + 0.001)


@pytest.mark.parametrize("changes, reason", [
    ({"pose_failure": "only 5 corners"}, "wall pose unknown"),
    ({"pose_sigma_m": None}, "not estimated"),
    ({"head_command_error_deg": 0.2}, "head not where commanded"),
    ({"head_failure": "did not answer"}, "head not answering"),
    ({"robot_motion_m": 0.02}, "robot moved 20 mm"),
    ({"closed_loop_errors_m": np.full(4, 0.001)}, "pattern lost: 4 of 35"),
    ({"closed_loop_errors_m": np.full(30, 0.015)}, "projection lands up to 15 mm off"),
    ({"laser_plane_offset_m": 0.02}, "laser and cameras disagree about the wall by 20 mm"),
    ({"stereo_residual_px": 4.0}, "cameras disagree with the rig"),
    ({"pose_sigma_m": 0.008}, "registration uncertain"),
])
def test_each_failure_closes_the_gate_and_says_why(changes, reason):
    d = gate.decide(_good(**changes))
    assert not d.show_map
    assert any(reason in r for r in d.reasons), d.reasons
    # The craftsman gets one plain sentence per kind of failure, never a device address or a pixel residual.
    assert d.craftsman and all("://" not in line and " px" not in line for line in d.craftsman)


def test_a_head_failure_names_its_port_to_the_operator_only():
    d = gate.decide(_good(head_failure="socket://127.0.0.1:4711: no answer to a status query — check the cable"))
    assert any("socket://127.0.0.1:4711" in r for r in d.reasons)
    assert d.craftsman == [gate.SAY_HEAD_SILENT]


def _scan(position, yaw, rng, noise=0.01):
    """A 270° scan of a 5 x 4 m room from position, heading yaw (robot frame points)."""
    angles = np.radians(np.arange(-135.0, 135.0, 0.25))
    out = []
    for a in angles:
        d = np.array([np.cos(a + yaw), np.sin(a + yaw)])
        hits = [(val - position[axis]) / d[axis] for axis, val in ((0, 0.0), (0, 5.0), (1, 0.0), (1, 4.0))
                if abs(d[axis]) > 1e-9 and (val - position[axis]) / d[axis] > 0]
        r = min(hits) + rng.normal(0, noise)
        out.append([r * np.cos(a), r * np.sin(a)])
    return np.array(out)


@pytest.mark.parametrize("move", [(0.0, 0.0, 0.0), (0.006, 0.0, 0.0), (0.0, -0.01, 0.0), (0.004, 0.003, 0.4)])
def test_scan_matching_measures_the_robots_motion(move):
    rng = np.random.default_rng(5)
    start = np.array([2.0, 1.5])
    ref = _scan(start, 0.0, rng)
    cur = _scan(start + move[:2], np.radians(move[2]), rng)
    m = gate.scan_motion(ref, cur)
    # 4 σ of what the scans' 1 cm range noise leaves (σ over 60 seeds: 0.9 mm along x, which only the wall
    # ahead constrains, 0.6 mm along y, 0.02° in heading)
    assert m.dx == pytest.approx(move[0], abs=0.004)
    assert m.dy == pytest.approx(move[1], abs=0.0025)
    assert np.degrees(m.dtheta_rad) == pytest.approx(move[2], abs=0.09)


def test_robot_motion_is_judged_against_the_scan_matchs_own_noise():
    start = np.array([2.0, 1.5])
    false_moves = 0
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        ref = _scan(start, 0.0, rng)
        still = gate.scan_motion(ref, _scan(start, 0.0, rng))
        # its covariance describes its error: σ of x (the wall ahead only) ~0.9 mm, y ~0.6 mm (60 seeds)
        assert 0.0003 < np.sqrt(still.cov[0, 0]) < 0.003 and 0.0002 < np.sqrt(still.cov[1, 1]) < 0.002
        false_moves += still.significant
        moved = gate.scan_motion(ref, _scan(start + np.array([0.0, 0.006]), 0.0, rng))
        assert moved.significant  # 6 mm: ten σ
    assert false_moves <= 1  # χ² at 99.9 %: none expected in 20
    # the one test decide() and the session's re-estimate share: beyond the noise and mattering at the wall
    assert gate.robot_moved(gate.RegistrationEvidence(robot_motion_m=0.004, robot_motion_significant=True))
    assert not gate.robot_moved(gate.RegistrationEvidence(robot_motion_m=0.004, robot_motion_significant=False))
    assert not gate.robot_moved(gate.RegistrationEvidence(robot_motion_m=0.002, robot_motion_significant=True))
    noise = _good(robot_motion_m=0.0035, robot_motion_significant=False)
    assert not any("robot moved" in r for r in gate.decide(noise).reasons)
    assert not gate.decide(_good(robot_motion_m=0.0035)).show_map  # unknown significance: moved
    assert gate.ScanMotion(np.nan, np.nan, np.nan, np.nan, 0).significant  # no match: nothing says it stayed


def test_the_shown_region_shrinks_with_what_the_loop_measures_and_never_grows():
    from arproj.session import registration

    grid = np.array([[x, y] for x in np.linspace(0.0, 3.0, 31) for y in np.linspace(0.0, 1.0, 6)])
    sigma = 0.0015 + 0.0012 * grid[:, 0]  # 1σ growing along the wall: Z95·σ from 2.9 mm to 10 mm
    drawn = registration.trusted_region(grid, sigma, 0.010)
    assert drawn.checked_polygon is not None and 0.5 < drawn.share < 1.0  # where Z95·σ + reserve ≤ 10 mm
    same, s_same = registration.checked_region(drawn, tol.CLOSED_LOOP_RESERVE_M / 2, 0.010)
    assert same.share == drawn.share and s_same == pytest.approx(drawn.sigma_m)
    worse, s_worse = registration.checked_region(drawn, 0.004, 0.010)
    assert worse.share < drawn.share and tol.Z95 * s_worse + 0.004 <= 0.010  # the gate's bound holds inside
    assert np.array_equal(worse.checked_polygon, drawn.checked_polygon)  # the marks stay where they were put
    gone, s_gone = registration.checked_region(drawn, 0.0095, 0.010)
    assert not gone.usable and s_gone == pytest.approx(sigma.max())  # too little left: the gate refuses
    assert not gate.decide(_good(pose_sigma_m=s_gone, closed_loop_errors_m=np.full(30, 0.0095))).show_map


def test_a_plane_measured_before_the_wall_is_a_laser_disagreement_not_a_missing_check():
    from arproj.session import registration
    from geometry.poses import make_pose

    # the laser's returns from a wall at z = 0 (wall frame = robot frame here), 1 cm noise
    rng = np.random.default_rng(3)
    x = np.linspace(-1.4, 1.4, 200)
    laser = np.column_stack([x + 1.5, np.zeros_like(x), rng.normal(0, 0.01, len(x))])
    assert registration.laser_plane_offset_m(np.eye(4), laser, 1.5) < 0.006
    # the cameras took a board 14 cm before the wall for the wall: no return lies near that plane
    board = make_pose(None, [0.0, 0.0, -0.14])
    offset = registration.laser_plane_offset_m(board, laser, 1.5)
    assert offset == pytest.approx(0.14, abs=0.01)
    assert not gate.decide(_good(laser_plane_offset_m=offset)).show_map
    far = make_pose(None, [0.0, 0.0, -2.0])  # nothing within reach of the plane at all: no laser check
    assert np.isnan(registration.laser_plane_offset_m(far, laser, 1.5))
