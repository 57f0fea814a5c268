"""The Pelco-D head driver against the head simulator over socket:// (the same code path as real hardware)."""

import pytest

from devices.errors import DeviceError, DeviceTimeoutError
from devices.pelco_d import PanTiltHead
from devices.sim import HeadFaults, HeadSimulator

# Half the Pelco-D 0.01° step, plus float round-off: the simulator settles on the commanded step.
STEP_DEG = 0.006


def test_move_and_query_reach_the_commanded_angles():
    with HeadSimulator(speed_deg_s=400.0) as sim, PanTiltHead(sim.url, timeout_s=0.1) as head:
        reported = head.move_to(12.34, -7.5)
        assert reported == pytest.approx((12.34, -7.5), abs=STEP_DEG)
        assert sim.reported_deg() == pytest.approx((12.34, -7.5), abs=STEP_DEG)
        assert head.retries_used == 0


def test_faults_are_retried_and_the_move_still_completes():
    faults = HeadFaults(drop_reply_rate=0.15, corrupt_reply_rate=0.15, garbage_rate=0.3, ignore_command_rate=0.2)
    with HeadSimulator(speed_deg_s=400.0, faults=faults, seed=7) as sim, \
            PanTiltHead(sim.url, timeout_s=0.05, retries=6) as head:
        for pan, tilt in [(5.0, 2.0), (-20.0, 10.0), (0.5, -3.25)]:
            assert head.move_to(pan, tilt) == pytest.approx((pan, tilt), abs=STEP_DEG)
        assert sim.faults_injected > 0
        assert head.retries_used > 0


def test_slip_is_invisible_to_the_encoder():
    faults = HeadFaults(slip_deg=(0.4, -0.2))
    with HeadSimulator(speed_deg_s=400.0, faults=faults) as sim, PanTiltHead(sim.url, timeout_s=0.1) as head:
        assert head.move_to(10.0, 5.0) == pytest.approx((10.0, 5.0), abs=STEP_DEG)
        assert sim.true_deg() == pytest.approx((10.4, 4.8), abs=STEP_DEG)


def test_a_dead_head_gives_a_clear_timeout():
    with HeadSimulator(faults=HeadFaults(dead=True)) as sim, \
            PanTiltHead(sim.url, timeout_s=0.03, retries=1) as head, \
            pytest.raises(DeviceTimeoutError, match="did not answer the pan query after 2 tries"):
        head.position()


def test_an_unreachable_url_names_the_url():
    with pytest.raises(DeviceError, match=r"socket://127\.0\.0\.1:9"):
        PanTiltHead("socket://127.0.0.1:9", timeout_s=0.05)


def test_a_stalled_head_is_reported_not_assumed_in_place():
    faults = HeadFaults(ignore_command_rate=1.0)
    with HeadSimulator(faults=faults) as sim, \
            PanTiltHead(sim.url, timeout_s=0.05, settle_timeout_s=0.6) as head, \
            pytest.raises(DeviceError, match=r"did not reach pan 3\.00°"):
        head.move_to(3.0, 1.0)


def test_a_head_that_vanishes_and_comes_back_is_reconnected():
    with HeadSimulator(speed_deg_s=400.0) as sim, PanTiltHead(sim.url, timeout_s=0.05) as head:
        head.move_to(4.0, 2.0)
        sim.drop_connections()
        assert head.position() == pytest.approx((4.0, 2.0), abs=STEP_DEG)
        assert head.reconnects == 1
