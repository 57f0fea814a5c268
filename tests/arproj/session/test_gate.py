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
    far = make_pose(None, [0.0, 0.0, -2.0])  # a plane 2 m before the wall: the laser sees the wall through it
    assert registration.laser_plane_offset_m(far, laser, 1.5) == pytest.approx(2.0, abs=0.01)
    # no return along the projected part of the wall at all: no laser check
    assert np.isnan(registration.laser_plane_offset_m(np.eye(4), laser + np.array([10.0, 0.0, 0.0]), 1.5))


def test_the_laser_judges_the_cameras_plane_within_its_own_uncertainty_and_sees_through_a_person():
    from arproj.session import registration
    from geometry.poses import make_pose, rotation_about

    rng = np.random.default_rng(5)
    x = np.linspace(-1.4, 1.4, 200)
    laser = np.column_stack([x + 1.5, np.zeros_like(x), rng.normal(0, 0.005, len(x))])
    # a plane tilted 0.6° about the vertical: 16 mm off the laser at the window's centre, 30 mm at its end
    tilted = make_pose(rotation_about([0, 1, 0], np.radians(0.6)), [0.0, 0.0, 0.0])
    off = registration.laser_plane_offset_m(tilted, laser, 1.5)
    assert off > gate.LASER_PLANE_TOLERANCE_M
    # a plane measured that loosely (1σ of 0.5° in its normal) may be that far off: no disagreement beyond it
    loose = np.diag([np.radians(0.5) ** 2, 1e-12, np.radians(0.5) ** 2, 0.002 ** 2])
    assert registration.laser_plane_offset_m(tilted, laser, 1.5, loose) < gate.LASER_PLANE_TOLERANCE_M
    # one measured well (0.02°, 0.5 mm) may not
    tight = np.diag([np.radians(0.02) ** 2, 1e-12, np.radians(0.02) ** 2, 0.0005 ** 2])
    assert registration.laser_plane_offset_m(tilted, laser, 1.5, tight) > gate.LASER_PLANE_TOLERANCE_M
    # the cameras measured a person 1 m before the wall: a few returns on them, most from the wall behind
    person = np.column_stack([np.linspace(1.3, 1.7, 30), np.zeros(30), np.full(30, 1.0)])
    seen = np.concatenate([laser[np.abs(laser[:, 0] - 1.5) > 0.25], person])
    on_person = make_pose(None, [0.0, 0.0, -1.0])  # wall frame with z = 0 on the person
    assert registration.laser_plane_offset_m(on_person, seen, 1.5) == pytest.approx(1.0, abs=0.02)


def test_the_loop_judges_the_drawn_area_where_no_mark_could_go():
    from arproj.session import registration

    # marks over the near half of what is drawn; the error grows along the wall (a turn seen at an angle)
    marks = np.array([[x, y] for x in np.linspace(0.0, 1.0, 6) for y in np.linspace(0.0, 0.6, 4)])
    def field(p):
        return np.column_stack([0.008 * p[:, 0], 0.002 * p[:, 0]]) - [0.004, 0.001]

    drawn = np.array([[x, y] for x in np.linspace(0.0, 2.0, 11) for y in np.linspace(0.0, 0.6, 4)])
    worst_mark = np.linalg.norm(field(marks), axis=1).max()
    worst = registration.field_worst_m(marks, field(marks), drawn)
    assert worst == pytest.approx(np.linalg.norm(field(drawn), axis=1).max(), rel=1e-6)
    assert worst_mark < 0.005 < 0.010 < worst
    ev = _good(closed_loop_errors_m=np.linalg.norm(field(marks), axis=1), closed_loop_field_max_m=worst)
    decision = gate.decide(ev)
    assert not decision.show_map and any("lands up to 12 mm off" in r for r in decision.reasons)
    assert np.isnan(registration.field_worst_m(marks[:3], field(marks[:3]), drawn))  # too few marks to fit


def test_a_rig_in_doubt_is_said_as_such():
    decision = gate.decide(gate.RegistrationEvidence(rig_failure="the projector sits 1° off"))
    assert not decision.show_map and decision.reasons == ["rig in doubt: the projector sits 1° off"]
    assert decision.craftsman == [gate.SAY_RIG]
