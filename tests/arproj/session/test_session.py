"""The whole session on the simulated site: aim, estimate, verify, show — checked against the site's truth;
then the faults the safety gate exists for (head slip, robot nudged, head gone)."""

import numpy as np
import pytest

from arproj.session.evaluate import true_landing_errors
from arproj.session.output import MemoryOutput
from arproj.session.robot_io import DeviceInclinometer, SimulatedRobot, nominal_rig, true_tilt_deg
from arproj.session.session import ProjectionSession
from arproj.session.wallmap import wall_map_from_wall_file
from devices.pelco_d import PanTiltHead
from devices.sim import HeadSimulator, InclinometerSim
from geometry.poses import make_pose, rotation_about
from scanner.wall import shipped_walls

pytestmark = pytest.mark.gl


def _start(gl_context, head_zero_error_deg=(0.0, 0.0), inclinometer=True):
    """A fresh site and a session on it, aimed and updated once; the rig's head model may be off by
    head_zero_error_deg (pan, tilt zero offsets); inclinometer False: the robot has none (the floor prior)."""
    from arproj.sim.site import Site
    from geometry.head import HeadModel
    from geometry.rig import Rig

    site = Site.build(seed=3, ctx=gl_context, robot={"distance_m": 2.2, "incidence_deg": 20.0})
    head_sim = HeadSimulator(speed_deg_s=600.0, initial_deg=tuple(site.head_angles_cmd_deg[:2]))
    head = PanTiltHead(head_sim.url, timeout_s=0.1)
    out = MemoryOutput()
    # the robot stands tilted on the site's floor (0.05°, -0.12°): its inclinometer measures that, as
    # SimulatedRobot.on_site's does (with the floor prior alone the map is cut to a third here, 4-6 mm off)
    inclinometer_sim = InclinometerSim(lambda: true_tilt_deg(site), seed=3) if inclinometer else None
    robot = SimulatedRobot(site, 0, head_sim, head, out, inclinometer_sim=inclinometer_sim,
                           inclinometer=None if inclinometer_sim is None else DeviceInclinometer(inclinometer_sim.url))
    wall_map = wall_map_from_wall_file(shipped_walls()["demo_brick_wall"])
    rig = nominal_rig(site)
    if any(head_zero_error_deg):
        h = rig.head
        offsets = h.zero_offsets_deg + np.array([*head_zero_error_deg, 0.0])
        rig = Rig(rig.intrinsics, rig.poses, HeadModel(h.axes, h.points, h.T_robot_from_projector_zero, offsets),
                  rig.quality)
    session = ProjectionSession(rig, wall_map, robot, ctx=gl_context)
    session.aim_at([1.3, 1.1])
    session.set_drill_point([1.5, 1.2])
    return site, head_sim, session, out, session.update()


@pytest.fixture
def running(gl_context):
    """A fresh site and session for each test: the tests nudge the robot and slip the head, so none may see
    another's changes (about 3.5 s each)."""
    site, head_sim, session, out, decision = _start(gl_context)
    yield site, head_sim, session, out, decision
    session.close()
    session.robot.close()


def _marks(session):
    from arproj.session.registration import choose_marks

    return choose_marks(session.registration.T_wall_from_projector, session.projector_intr,
                        session.wall_map.extent, grid=(5, 4))


def test_registered_map_lands_within_two_millimetres(running):
    site, _, session, out, decision = running
    assert decision.show_map, decision.reasons
    errors, _ = true_landing_errors(session, site, _marks(session), 0)
    assert len(errors) >= 15
    assert errors.mean() < 0.002 and np.percentile(errors, 95) < 0.004
    # the closed loop's camera measurement agrees with the truth
    loop = session.registration.loop
    measured = np.linalg.norm(loop.errors_xy - session.registration.correction_xy, axis=1)
    assert abs(np.mean(measured) - errors.mean()) < 0.0015
    frame = out.last
    assert frame.shape == (800, 1280, 3) and frame[:, :, 0].max() == 255  # the map with its legend
    assert "safe" in session.drill_check([1.5, 1.2]).message


def test_head_model_off_is_measured_from_the_pattern(gl_context):
    # a rig whose head model puts the projector 1-2° off: the estimator declines with projector_pose_off, and
    # the session measures the projector's pose from the pattern instead, still landing the map
    site, _, session, _, decision = _start(gl_context, head_zero_error_deg=(1.5, -1.0))
    try:
        assert decision.show_map, decision.reasons
        assert any(line.startswith("head model disagrees with the pattern") for line in session.log)
        errors, _ = true_landing_errors(session, site, _marks(session), 0)
        assert len(errors) >= 15
        assert errors.mean() < 0.002 and np.percentile(errors, 95) < 0.004
    finally:
        session.close()
        session.robot.close()


def test_head_slip_is_caught_and_healed_by_re_estimating(running):
    site, head_sim, session, _, _ = running
    head_sim.faults.slip_deg = (0.35, -0.1)  # the mount slipped; the encoder still reports the command
    try:
        ev_before = session.evidence()
        assert ev_before.head_command_error_deg == 0.0  # invisible to the head's own report
        session.robot.sync_head()
        errors, _ = true_landing_errors(session, site, _marks(session), 0)
        assert errors.mean() > 0.010  # the shown map would now be a centimetre off
        decision = session.update()
        assert "projection landed off: re-estimating the wall pose" in session.log
        assert decision.show_map, decision.reasons
        errors, _ = true_landing_errors(session, site, _marks(session), 0)
        assert errors.mean() < 0.002
    finally:
        head_sim.faults.slip_deg = (0.0, 0.0)


def test_robot_nudge_is_seen_by_the_laser(running):
    site, _, session, _, _ = running
    nudge = make_pose(rotation_about([0, 0, 1], np.radians(0.3)), [0.012, -0.008, 0.0])
    site.move_robot(site.T_room_from_robot @ nudge)
    ev = session.evidence()
    assert ev.robot_motion_m > 0.01
    from arproj.session import gate

    assert not gate.decide(ev).show_map  # until re-estimated, the old map would be wrong
    decision = session.update()
    assert "head or robot moved: re-estimating the wall pose" in session.log
    assert decision.show_map, decision.reasons
    errors, _ = true_landing_errors(session, site, _marks(session), 0)
    assert errors.mean() < 0.002


def test_dead_head_shows_the_warning_and_the_session_stays_up(running):
    _, head_sim, session, _, _ = running
    head_sim.faults.dead = True
    session.robot.head.timeout_s = 0.02
    try:
        decision = session.decide()
        assert not decision.show_map
        assert any("head not answering" in r for r in decision.reasons)
        frame = session.render_frame(decision)
        assert frame[4, 640, 0] == 255 and frame[4, 640, 2] == 40  # the red warning border
    finally:
        head_sim.faults.dead = False
        session.robot.head.timeout_s = 0.1


def test_marks_no_camera_can_photograph_leave_the_map_unchecked_and_refused(running, monkeypatch):
    # marks outside both cameras' frames are not projected; when that leaves too few, the map they would have
    # checked counts as unseen (pattern lost), never as a map with nothing to check
    from arproj.session import gate, registration
    from arproj.session import tolerances as tol

    _, _, session, _, decision = running
    assert decision.show_map, decision.reasons
    monkeypatch.setattr(registration, "project_in_view",
                        lambda intr, p, margin=0.0: (np.full((len(p), 2), np.nan), np.zeros(len(p), bool)))
    loop = session.verify()
    assert loop is not None and len(loop.marks_xy) >= tol.CLOSED_LOOP_MIN_FEATURES and not loop.seen.any()
    refused = gate.decide(session.evidence(), tol.REGISTRATION_TOLERANCE_M)
    assert not refused.show_map and any(r.startswith("pattern lost: 0 of") for r in refused.reasons)


@pytest.mark.parametrize("inclinometer", [False, True])
def test_the_bound_covers_the_true_error_and_names_what_cuts_the_map(gl_context, inclinometer):
    """On the site's tilted floor (0.05°, -0.12°), with the floor prior alone and with the inclinometer."""
    from arproj.session import registration, scenarios
    from arproj.session import tolerances as tol

    site, _, session, _, decision = _start(gl_context, inclinometer=inclinometer)
    try:
        reg = session.registration
        trusted = reg.trusted
        assert decision.show_map and trusted is not None and trusted.points_xy is not None
        # every drawn sample's true error (the pose before the loop's correction) inside its own 95 % bound
        T_uncorrected = make_pose(None, [-reg.correction_xy[0], -reg.correction_xy[1], 0.0]) \
            @ reg.T_wall_from_projector
        belief = scenarios.Belief(session.rig, reg.T_wall_from_robot, T_uncorrected, reg.sigma_m, reg.distance_m)
        errors = scenarios.true_errors(belief, scenarios.truth_of(site, 0), trusted.points_xy)
        assert np.all(errors <= tol.Z95 * trusted.point_sigma_m)
        if inclinometer:  # the tilts measured: nothing cuts the map at 2.2 m
            assert trusted.share == 1.0 and not reg.cut_by
            return
        # the robot's roll is known from the floor alone (no wall edge in view at 2.2 m): the fused pose cuts the
        # map there, and knowing its tilts (an inclinometer) would shrink the bound
        assert trusted.share < 1.0 and reg.cut_by.startswith("the pose term")
        assert f"the pose's {registration.POSE_DOFS[2]} known" in reg.cut_by and "inclinometer" in reg.cut_by
    finally:
        session.close()
        session.robot.close()
