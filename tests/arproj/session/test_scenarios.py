"""Rendered degraded scenes against the simulated truth (fixed seeds): the session's own update on a site the
cameras really see changed. A fine scene is shown; a scene that spoils the registration is refused or healed
(re-estimated and then right); none shows a map off by more than the tolerance."""

import numpy as np
import pytest

from arproj.session import scenarios
from arproj.session import tolerances as tol
from arproj.session.output import MemoryOutput
from arproj.session.robot_io import SimulatedRobot, nominal_rig
from arproj.session.session import ProjectionSession
from arproj.session.wallmap import wall_map_from_wall_file
from scanner.wall import shipped_walls

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def station(gl_context):
    """One registered placement (2.2 m, 20°, demo wall), shared: every scene restores it and undoes its change."""
    from arproj.sim.site import Site

    site = Site.build(seed=3, ctx=gl_context, robot={"distance_m": 2.2, "incidence_deg": 20.0})
    robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), "measured", seed=3, head_speed_deg_s=1000.0)
    session = ProjectionSession(nominal_rig(site), wall_map_from_wall_file(shipped_walls()["demo_brick_wall"]),
                                robot, ctx=gl_context)
    assert session.update().show_map
    st = scenarios.Station(site, session, robot, gl_context)
    yield st
    st.close()


def _never_unsafe(o: scenarios.Outcome) -> None:
    assert not o.unsafe, (o.kind, o.magnitude, o.true_max_m, o.reasons)


def test_a_fine_scene_is_shown_and_right(station):
    # room light as it was, after the estimate: nothing changed but the photographs' noise
    o = scenarios.run_scene(station, scenarios.sunlight(station, station.ambient_lux, before=False))
    assert o.show_map and o.verified and o.reasons == []
    assert o.true_max_m < 0.004 and o.loop_max_m < tol.CLOSED_LOOP_RESERVE_M
    # the map is drawn where the pose's 95 % error (its full covariance at each point: the floor's tilt prior
    # turns the far corners) plus the reserve holds — a good part of the image at 2.2 m, never the truth outside
    assert o.true_max_m <= o.bound_m <= tol.REGISTRATION_TOLERANCE_M and o.shown_share > 0.3


def test_a_moved_robot_is_seen_and_registered_again(station):
    o = scenarios.run_scene(station, scenarios.robot_moved(station, (0.025, -0.01), 0.6))
    _never_unsafe(o)
    assert "head or robot moved: re-estimating the wall pose" in station.session.log
    # registered again, and right; shown where its bound allows (from the new spot it may allow too little)
    assert o.judged and o.true_max_m < 0.004 and (o.show_map or o.reasons[0].startswith("registration uncertain"))


def test_a_slipped_head_is_caught_by_the_closed_loop(station):
    o = scenarios.run_scene(station, scenarios.head_slipped(station, (0.45, -0.3)))
    _never_unsafe(o)
    assert "projection landed off: re-estimating the wall pose" in station.session.log
    assert o.show_map and o.true_max_m < 0.004
    assert station.robot.head_sim.faults.slip_deg == (0.0, 0.0)  # put back


def test_a_pattern_mostly_hidden_is_refused(station):
    x0 = float(station.area_xy[:, 0].min())
    o = scenarios.run_scene(station, scenarios.pattern_occluded(station, 0.9, x0 - 0.05, 0.05, True,
                                                                np.random.default_rng(1)))
    assert not o.show_map and not o.verified
    assert not station.site.targets  # the board was taken away again


def test_glaring_sunlight_is_refused(station):
    o = scenarios.run_scene(station, scenarios.sunlight(station, 20_000.0, before=True))
    assert not o.show_map and any("wall pose unknown" in r for r in o.reasons)
    assert station.site.room.ambient_lux == station.ambient_lux


def test_a_wrong_camera_mount_in_the_rig_file_is_refused(station):
    o = scenarios.run_scene(station, scenarios.wrong_rig_file(station, 3, np.random.default_rng(4)))
    assert not o.show_map and o.reasons
    # refused either where its wall pose disagrees with the robot's prior (a fresh station: this test alone on
    # an xdist worker) or by the gate after the estimate (the station registered again by earlier scenes) —
    # where it was judged, it would have been far off
    if o.judged:
        assert o.true_max_m > tol.REGISTRATION_TOLERANCE_M


def test_a_person_in_the_beam_never_shows_a_wrong_map(station):
    centre = float(station.area_xy[:, 0].mean())
    rng = np.random.default_rng(2)
    for before in (True, False):
        o = scenarios.run_scene(station, scenarios.person_in_beam(station, centre, 0.6, before, rng))
        _never_unsafe(o)
        assert o.show_map or o.reasons


def test_drawn_scenes_are_seeded(station):
    a = scenarios.draw_scene(station, "pattern occluded", np.random.default_rng(7))
    b = scenarios.draw_scene(station, "pattern occluded", np.random.default_rng(7))
    assert a.what == b.what and a.before == b.before
    assert set(scenarios.scene_seeds(scenarios.TUNING_SEED_START, 300)).isdisjoint(
        scenarios.scene_seeds(scenarios.JUDGED_SEED_START, 1000))


def test_a_wrong_camera_mount_the_head_cannot_explain_is_a_rig_in_doubt(station):
    # the mount of this rig file puts the projector 23 mm and 0.8° off its head model: measured from the pattern
    # (the head-model fallback) it would be consistent with the cameras, the closed loop blind to it and the map
    # centimetres off; no turn of the head explains it, so the registration is refused and the craftsman told
    o = scenarios.run_scene(station, scenarios.wrong_rig_file(station, 3, np.random.default_rng(4)))
    assert not o.show_map
    assert o.reasons and o.reasons[0].startswith("rig in doubt: the projector sits")
    if o.judged:  # its wall pose fitted the robot's prior (earlier scenes moved it): it would have been far off
        assert o.true_max_m > tol.REGISTRATION_TOLERANCE_M

