"""The robot's inclinometer in the session, against the simulated site's truth: it reads the tilt the robot
really stands with on the site's floor, and its reading replaces the wall-pose fusion's floor prior, which
shrinks the pose's roll and pitch σ to the inclinometer's and lets the map be drawn where the prior cut it."""

import numpy as np
import pytest

from arproj.session.evaluate import map_features, true_landing_errors
from arproj.session.output import MemoryOutput
from arproj.session.registration import inside_polygon
from arproj.session.robot_io import DeviceInclinometer, SimulatedRobot, nominal_rig, true_tilt_deg
from arproj.session.session import ProjectionSession
from arproj.session.tolerances import REGISTRATION_TOLERANCE_M
from arproj.session.wallmap import wall_map_from_wall_file
from devices.sim.inclinometer import SIGMA_DEG
from scanner.wall import shipped_walls

pytestmark = pytest.mark.gl


def test_the_simulated_robots_inclinometer_reads_the_sites_tilt(gl_context) -> None:
    from arproj.sim.site import Site

    with Site.build(seed=4, ctx=gl_context, robot={"distance_m": 2.0, "incidence_deg": 30.0}) as site:
        truth = np.array(true_tilt_deg(site))
        assert np.all(np.abs(truth) > 1e-4)  # the floor is tilted (σ 0.1° each)
        robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), seed=4)
        try:
            assert robot.inclinometer is not None
            readings = [robot.inclinometer.reading() for _ in range(20)]
            full = robot.full_pose_inputs()
            assert full is not None and full.tilt is not None
        finally:
            robot.close()
        errors = np.array([[r.roll_deg, r.pitch_deg] for r in readings]) - truth
        assert all(r.sigma_roll_deg == r.sigma_pitch_deg == SIGMA_DEG for r in readings)
        assert np.all(np.abs(errors) < 5 * SIGMA_DEG)
        # the robot moved: the inclinometer follows the site's robot, not the placement it started at
        site.place_robot(2.0, 0.0)
        moved = np.array(true_tilt_deg(site))
        robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), seed=4, inclinometer=False)
        try:
            assert robot.inclinometer is None and robot.full_pose_inputs().tilt is None  # the floor prior
        finally:
            robot.close()
        assert np.any(np.abs(moved - truth) > 1e-4)


def test_the_served_sites_inclinometer_is_read_over_its_url() -> None:
    from arproj.sim.live import serve_live_site

    with serve_live_site(seed=1, small=True) as live:
        truth = np.array(live.true_tilt_deg())
        device = DeviceInclinometer(live.urls.inclinometer)
        try:
            reading = device.reading()
            assert device.model == "INCLINOMETER SIM 1.0"
            assert device.device.true_tilt() == tuple(truth)
        finally:
            device.close()
    assert np.all(np.abs(np.array([reading.roll_deg, reading.pitch_deg]) - truth) < 5 * SIGMA_DEG)


def _session(gl_context, inclinometer: bool):
    """The session at 2 m, 30° on a tilted floor (seed 0: roll -0.04°, pitch 0.001°), registered once."""
    from arproj.sim.site import Site

    site = Site.build(seed=0, ctx=gl_context, robot={"distance_m": 2.0, "incidence_deg": 30.0})
    robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), seed=0, head_speed_deg_s=1000.0,
                                   inclinometer=inclinometer)
    wall_map = wall_map_from_wall_file(shipped_walls()["demo_brick_wall"])
    session = ProjectionSession(nominal_rig(site), wall_map, robot, ctx=gl_context)
    session.aim_at([1.3, 1.1])
    return site, robot, session, session.update()


def test_the_inclinometer_replaces_the_floor_prior_and_the_map_grows(gl_context) -> None:
    shares, sigmas = {}, {}
    for inclinometer in (False, True):
        site, robot, session, decision = _session(gl_context, inclinometer)
        try:
            reg = session.registration
            assert decision.show_map and reg is not None and reg.pose_covariance is not None, decision.reasons
            assert ("inclinometer" in reg.prior_source) == inclinometer, reg.prior_source
            sigmas[inclinometer] = np.degrees(np.sqrt(np.diag(reg.pose_covariance)[:2]))
            shares[inclinometer] = 1.0 if reg.trusted is None else reg.trusted.share
            # where the map is drawn it is right: within the tolerance on the true wall
            features = map_features(session.wall_map, reg.T_wall_from_projector, session.projector_intr)
            if reg.trusted is not None and reg.trusted.polygon is not None:
                features = features[inside_polygon(features, reg.trusted.polygon)]
            errors, _ = true_landing_errors(session, site, features, 0)
            assert len(errors) > 10 and errors.max() < REGISTRATION_TOLERANCE_M
        finally:
            session.close()
            robot.close()
            site.release()
    # the prior's 0.1° (the plane pins part of it) against the inclinometer's 0.01°
    assert np.all(sigmas[True] <= SIGMA_DEG * 1.001) and np.all(sigmas[False] > 3 * sigmas[True])
    # the prior cut the map to less than half (the pose term: the roll about the wall's normal); measured, all
    assert shares[False] < 0.6 and shares[True] > 0.95, shares


def test_an_inclinometer_no_fusion_would_read_is_refused(tmp_path) -> None:
    from arproj.run.project import SessionOptions, run_session
    from geometry import Intrinsics
    from geometry.errors import InputError
    from geometry.rig import Rig

    cam = Intrinsics.from_fov(1280, 800, 60.0)
    Rig(intrinsics={"camera_left": cam, "camera_right": cam, "projector": cam}).save(tmp_path / "rig")
    (tmp_path / "prior.yaml").write_text("T_wall_from_robot: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]")
    truth = shipped_walls()["small_test_wall"]
    with pytest.raises(InputError, match="--inclinometer is read by the full wall-pose fusion"):
        run_session(SessionOptions(truth=truth, rig_dir=tmp_path / "rig", wall_prior=tmp_path / "prior.yaml",
                                   inclinometer_url="socket://127.0.0.1:9"), say=lambda _: None)
    with pytest.raises(InputError, match="contradict"):
        run_session(SessionOptions(truth=truth, sim=True, inclinometer_url="socket://127.0.0.1:9",
                                   inclinometer=False), say=lambda _: None)
