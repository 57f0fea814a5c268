"""Scanning through the serial devices and their simulators: fault injection, recovery, clear errors, never a
hang."""

import contextlib
import time
from collections import Counter

import numpy as np
import pytest

from devices.errors import DeviceError, DeviceResetError
from devices.grbl import GrblDrives, GrblError
from devices.link import LineFramer, SerialLink
from devices.sim import DeviceServer, FaultConfig
from devices.wallscanner import CrcLineFramer, ScannerError, WallScanner
from geometry.errors import InputError
from scanner.hardware import DeviceBackend, simulated_devices
from scanner.plan import DriveConfig, PassSpec
from scanner.run import DirectBackend, run_scan, simulated_site
from scanner.sensor_model import SensorConfig
from scanner.sim.devices import GrblSim, WallScannerSim
from scanner.sim.world import SimWorld
from scanner.wall import load_wall, shipped_walls


@pytest.fixture(scope="module")
def small_wall():
    return load_wall(shipped_walls()["small_test_wall"])


def test_a_thousand_seeded_faults_lose_no_sample(small_wall):
    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(small_wall, sensor, drives, 11)
    reference = run_scan(small_wall, DirectBackend(world), robot, plan_kind="dense", sensor=sensor, drives=drives)
    world, robot = simulated_site(small_wall, sensor, drives, 11)
    # every kind, the hostile ones too (tests/devices/test_soak.py), but few of the slow ones: a reconnect costs
    # pyserial's 0.3 s close, a device that keeps talking the request's whole bound (about 1 s); the cheap kinds
    # (a timeout of 0.03 s at most) make up the thousand
    faults = FaultConfig(rate=0.016, seed=5, down_s=0.02, weights={
        "garbage": 0.3, "junk": 0.25, "truncate": 0.25, "drop": 0.1, "disconnect": 0.3,
        "vanish": 0.3, "stream": 0.0025, "flood": 0.0025})
    with simulated_devices(world, robot, faults, timeout_s=0.03, max_pass_attempts=30) as devices:
        result = run_scan(small_wall, devices.backend, devices.robot, plan_kind="dense", sensor=sensor,
                          drives=drives)
        servers = devices.servers.servers
        injected = servers["drives"].faults.counts + servers["scanner"].faults.counts
        reconnects = servers["drives"].connections + servers["scanner"].connections - 2
    assert sum(injected.values()) >= 1000, injected
    assert all(injected[k] > 0 for k in ("garbage", "junk", "truncate", "drop", "disconnect", "vanish", "stream",
                                         "flood")), injected
    assert reconnects >= 3 and devices.backend.pass_restarts >= 3
    for key, values in reference.samples.items():
        np.testing.assert_array_equal(result.samples[key], values, err_msg=key)


def test_serial_path_equals_in_process_path_for_an_adaptive_scan(small_wall):
    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(small_wall, sensor, drives, 2)
    reference = run_scan(small_wall, DirectBackend(world), robot, plan_kind="adaptive", sensor=sensor,
                         drives=drives)
    world, robot = simulated_site(small_wall, sensor, drives, 2)
    with simulated_devices(world, robot) as devices:
        result = run_scan(small_wall, devices.backend, devices.robot, plan_kind="adaptive", sensor=sensor,
                          drives=drives)
    assert result.n_passes == reference.n_passes > 5
    for key, values in reference.samples.items():
        np.testing.assert_array_equal(result.samples[key], values, err_msg=key)
    # the frames too: the base's pose and covariance, the truth, and the laser's fix from its scans over the wire
    assert [row.keys() for row in result.frames] == [row.keys() for row in reference.frames]
    for row, ref in zip(result.frames, reference.frames, strict=True):
        for key, value in ref.items():
            np.testing.assert_array_equal(row[key], value, err_msg=key)
    assert "laser_x_m" in reference.frames[0]


def test_a_device_that_never_comes_back_is_reported_quickly(small_wall):
    sensor, drives = SensorConfig(), DriveConfig()
    world, _ = simulated_site(small_wall, sensor, drives, 0)
    server = DeviceServer(GrblSim(world))
    server.start()
    link = SerialLink(server.url, LineFramer(), "drives", timeout_s=0.05, reconnect_attempts=3,
                      reconnect_delay_s=0.01)
    link.open()
    grbl = GrblDrives(link)
    grbl.home()
    server.stop()  # unplugged for good
    start = time.monotonic()
    with pytest.raises(DeviceError, match=r"drives at socket://127.0.0.1:.* did not come back"):
        for _ in range(5):
            with contextlib.suppress(DeviceResetError):  # after a reconnect the backend would redo its step
                grbl.status()
    # 3 reconnects x (0.05 s timeout + 0.01 s delay) is well under a second; 5 s allows a loaded 2-core CI box
    assert time.monotonic() - start < 5.0


def test_grbl_refuses_moves_outside_the_travel(small_wall):
    sensor, drives = SensorConfig(), DriveConfig()
    world, _ = simulated_site(small_wall, sensor, drives, 0)
    with DeviceServer(GrblSim(world)) as server, SerialLink(server.url, LineFramer(), "drives", timeout_s=0.5) as link:
        grbl = GrblDrives(link)
        grbl.home()
        grbl.move_to(0.1, 0.2)
        grbl.wait_until_at(0.1, 0.2)
        assert grbl.status() == ("Idle", 0.1, 0.2)
        with pytest.raises(GrblError, match=r"ALARM:2.*soft limit"):
            grbl.move_to(0.1, drives.travel_v_m + 0.5)


class _BrokenScannerWorld(SimWorld):
    """A scanner whose inductive channel reports 4095 counts (a saturated 12-bit ADC)."""

    def sample_timeline(self, times_us, tag):
        counts = super().sample_timeline(times_us, tag)
        counts[len(counts) // 2, 0] = 4095
        return counts


def test_out_of_range_scanner_values_are_reported_with_the_value(small_wall):
    sensor, drives = SensorConfig(), DriveConfig()
    world = _BrokenScannerWorld(small_wall, sensor, drives, 0)
    with DeviceServer(GrblSim(world)) as g, DeviceServer(WallScannerSim(world)) as s:
        backend = DeviceBackend(g.url, s.url, drives, sensor, timeout_s=0.5)
        backend.start()
        with pytest.raises(ScannerError, match="inductive = 4095 counts"):
            backend.measure_pass(0, PassSpec(0, "raster", "x", (0.0, 0.1), (0.3, 0.1)))
        backend.close()
    assert issubclass(ScannerError, InputError)


def test_scanner_requests_have_ids_and_reject_bad_commands(small_wall):
    world = SimWorld(small_wall, SensorConfig(), DriveConfig(), 0)
    with DeviceServer(WallScannerSim(world)) as server, \
            SerialLink(server.url, CrcLineFramer(), "scanner", timeout_s=0.5) as link:
        scanner = WallScanner(link)
        assert scanner.identify().startswith("WALLSCAN")
        with pytest.raises(ScannerError, match="ERR 1"):
            scanner.request("SELFDESTRUCT")
        with pytest.raises(ScannerError, match="ERR 4"):
            scanner.arm(0.0, 1)


def test_a_recorded_scan_session_replays_byte_for_byte(small_wall, tmp_path):
    """Record every byte of a faulty scan (record:// around each device's URL, spy://'s format), then scan again
    against the recordings alone: the host must send the recorded bytes (replay:// checks each one) and gets
    the same samples and frames; every recorded byte is played, every recorded reconnect made."""
    from devices.recording import finish_replay
    from scanner.hardware import DeviceRobot
    from scanner.sim.devices import SiteServers

    sensor, drives = SensorConfig(), DriveConfig()
    # no "drop": a lost answer is waited for by the deadline, the one thing a replay could time differently
    faults = FaultConfig(rate=0.04, seed=3, down_s=0.02, weights={"garbage": 0.3, "junk": 0.3, "truncate": 0.2,
                                                                   "corrupt": 0.1, "disconnect": 0.3})
    files = {name: tmp_path / f"{name}.spy" for name in ("drives", "scanner", "laser", "base")}

    def scan(urls):
        backend = DeviceBackend(urls["drives"], urls["scanner"], drives, sensor, timeout_s=0.3, realtime=False)
        robot = DeviceRobot(urls["laser"], urls["base"], timeout_s=0.3)
        try:
            backend.start()
            robot.start()
            return run_scan(small_wall, backend, robot, plan_kind="adaptive", sensor=sensor, drives=drives)
        finally:
            backend.close()
            robot.close()

    world, robot = simulated_site(small_wall, sensor, drives, 6)
    with SiteServers(world, robot, faults) as servers:
        recorded = scan({name: f"record://{url}?file={files[name]}" for name, url in servers.urls.items()})
        injected = sum((server.faults.counts for server in servers.servers.values()), Counter())
        reconnects = sum(server.connections - 1 for server in servers.servers.values())
    assert injected["disconnect"] > 0 and injected["garbage"] > 0 and injected["truncate"] > 0
    assert reconnects >= injected["disconnect"]
    replayed = scan({name: f"replay://{path}" for name, path in files.items()})
    for key, values in recorded.samples.items():
        np.testing.assert_array_equal(replayed.samples[key], values, err_msg=key)
    for row, ref in zip(replayed.frames, recorded.frames, strict=True):
        for key, value in ref.items():
            np.testing.assert_array_equal(row[key], value, err_msg=key)
    for path in files.values():
        session = finish_replay(path)
        assert session.left() == 0 and session.opened == len(session.connections), path.name


def test_an_operator_places_the_robot_and_the_laser_fixes_where(small_wall):
    """No robot base: the operator is asked to place the robot for every frame (here a test operator who drives
    the simulated base, so the simulated site knows where the robot truly stands) and the frame's pose is the
    laser's fix with its covariance; the wall is measured as where the base places it."""
    from devices.robotbase import RobotBase
    from scanner.hardware import DeviceRobot
    from scanner.sim.devices import SiteServers

    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(small_wall, sensor, drives, 8)
    reference = run_scan(small_wall, DirectBackend(world), robot, plan_kind="dense", sensor=sensor, drives=drives)
    world, robot = simulated_site(small_wall, sensor, drives, 8)
    placed = []
    with SiteServers(world, robot) as servers, \
            SerialLink(servers.urls["base"], CrcLineFramer(), "robot base", timeout_s=0.5) as base_link:
        hands = RobotBase(base_link)

        def operator(frame):
            placed.append(frame.frame_id)
            hands.go_to((frame.x_m, frame.y_m, 0.0), frame.frame_id)

        backend = DeviceBackend(servers.urls["drives"], servers.urls["scanner"], drives, sensor, realtime=False)
        on_site = DeviceRobot(servers.urls["laser"], None, operator=operator)
        backend.start()
        on_site.start()
        result = run_scan(small_wall, backend, on_site, plan_kind="dense", sensor=sensor, drives=drives)
        backend.close()
        on_site.close()
    assert placed == list(range(result.n_frames))
    for key in ("inductive", "capacitive", "ac", "drive_u_m", "drive_v_m", "time_s"):
        np.testing.assert_array_equal(result.samples[key], reference.samples[key], err_msg=key)
    truth = reference.frames
    for row, ref in zip(result.frames, truth, strict=True):
        assert np.isnan(row.get("true_x_m", np.nan))  # nobody on hardware knows the truth
        for axis, (est, sigma) in enumerate((("laser_x_m", "laser_x_sigma_m"), ("laser_y_m", "laser_y_sigma_m"),
                                             ("laser_phi_rad", "laser_phi_sigma_rad"))):
            assert row[("est_x_m", "est_y_m", "est_phi_rad")[axis]] == row[est]
            assert row["cov"][axis, axis] == pytest.approx(row[sigma] ** 2)
            true = ref[("true_x_m", "true_y_m", "true_phi_rad")[axis]]
            assert abs(row[est] - true) < 4.5 * row[sigma], est


def test_the_laser_sends_its_scan_whole_through_faults_and_refuses_an_unknown_head(small_wall):
    from devices.laser2d import Laser2D, LaserError
    from scanner.laser import LaserConfig, simulated_head_scan
    from scanner.sim.devices import LaserSim

    world = SimWorld(small_wall, SensorConfig(), DriveConfig(), 4)
    world.place_robot((0.1, 0.02, 0.004), (0.52, 0.01))
    cfg = LaserConfig()
    faults = FaultConfig(rate=0.2, seed=2, weights={"garbage": 0.4, "junk": 0.2, "truncate": 0.2, "corrupt": 0.2})
    with DeviceServer(LaserSim(world, cfg), faults) as server, \
            SerialLink(server.url, CrcLineFramer(), "laser", timeout_s=0.05) as link:
        laser = Laser2D(link)
        assert laser.heads() == ["H", "V"]
        for head in ("H", "V"):
            angles, ranges = laser.scan(head, tag=9)
            want_angles, want = simulated_head_scan(head, world.true_pose, world.alignment, small_wall.width_m,
                                                    cfg, 4, 9)
            np.testing.assert_array_equal(angles, want_angles)
            np.testing.assert_array_equal(ranges, want)  # NaN (no return) where the simulator had none
        assert sum(server.faults.counts.values()) > 10 and laser.faults_recovered > 0
        with pytest.raises(LaserError, match="ERR 4"):
            laser.scan("X")
