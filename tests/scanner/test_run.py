"""Scans recorded in the log: kill at random points, resume, and get exactly the uninterrupted samples."""

import os
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pytest

from geometry.errors import InputError
from scanner.log import ScanLog
from scanner.plan import DriveConfig
from scanner.run import DirectBackend, ScanCrashError, open_for_resume, run_scan, scan_meta, simulated_site
from scanner.sensor_model import SensorConfig
from scanner.wall import load_wall, shipped_walls

SMALL = shipped_walls()["small_test_wall"]


def _uninterrupted(wall, plan, seed):
    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(wall, sensor, drives, seed)
    return run_scan(wall, DirectBackend(world), robot, plan_kind=plan, sensor=sensor, drives=drives)


def _new_log(path, wall, plan, seed):
    from scanner.plan import make_planner

    sensor, drives = SensorConfig(), DriveConfig()
    described = make_planner(plan, wall, drives).describe()
    return ScanLog.create(path, scan_meta(wall, str(SMALL), described, sensor, drives, seed, simulated=True))


def _resume_until(path, wall, plan, seed, crash_at):
    sensor, drives = SensorConfig(), DriveConfig()
    log, _ = open_for_resume(path)
    world, robot = simulated_site(wall, sensor, drives, seed)

    def hook(pass_id):
        if pass_id == crash_at:
            raise ScanCrashError(f"power lost before pass {pass_id} was committed")

    try:
        return run_scan(wall, DirectBackend(world), robot, plan_kind=plan, plan_options=log.meta["plan"],
                        sensor=sensor, drives=drives, log=log, crash_hook=hook)
    finally:
        log.close()


@pytest.mark.parametrize(("plan", "crashes"), [("dense", 20), ("adaptive", 6)])
def test_crashes_at_random_points_then_resume_give_the_uninterrupted_samples(tmp_path, plan, crashes):
    wall = load_wall(SMALL)
    reference = _uninterrupted(wall, plan, seed=4)
    rng = np.random.default_rng(7)
    points = np.sort(rng.choice(np.arange(reference.n_passes), size=min(crashes, reference.n_passes),
                                replace=False))
    path = tmp_path / "scan.db"
    _new_log(path, wall, plan, seed=4).close()
    for crash_at in points:
        with pytest.raises(ScanCrashError):
            _resume_until(path, wall, plan, 4, int(crash_at))
        with ScanLog.open(path) as log:
            assert log.pass_count() == crash_at  # everything before the crash is kept, nothing after
    _resume_until(path, wall, plan, 4, crash_at=-1)
    with ScanLog.open(path) as log:
        stored = log.samples()
        assert log.meta["status"] == "complete"
    assert len(stored["seq"]) == len(reference.samples["seq"])
    np.testing.assert_array_equal(stored["seq"], np.arange(len(stored["seq"])))  # unique, no duplicates
    for key, values in reference.samples.items():
        np.testing.assert_array_equal(stored[key], values, err_msg=key)


def _pass_count(path):
    try:
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=1.0) as db:
            return db.execute("SELECT COUNT(*) FROM passes").fetchone()[0]
    except sqlite3.Error:
        return 0


def _cli(*args):
    return [sys.executable, "-c", "from arproj.cli import main; main()", *args]


def test_kill_9_of_the_cli_and_resume(tmp_path):
    wall = load_wall(SMALL)
    reference = _uninterrupted(wall, "dense", seed=3)
    path = tmp_path / "scan.db"
    env = {**os.environ, "COLUMNS": "120"}
    for kill_after in (4, 17):  # two SIGKILLs at different points of the serial-device scan
        args = ["scan", "--resume", str(path)] if path.exists() else \
            ["scan", "--sim", "--wall", str(SMALL), "--log", str(path), "--plan", "dense", "--seed", "3"]
        proc = subprocess.Popen(_cli(*args), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        while _pass_count(path) < kill_after and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert _pass_count(path) < reference.n_passes, "the scan finished before it could be killed"
    done = subprocess.run(_cli("scan", "--resume", str(path)), env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    with ScanLog.open(path) as log:
        stored = log.samples()
    for key, values in reference.samples.items():
        np.testing.assert_array_equal(stored[key], values, err_msg=key)


def test_resume_with_another_wall_or_plan_is_refused(tmp_path):
    wall = load_wall(SMALL)
    path = tmp_path / "scan.db"
    _new_log(path, wall, "dense", seed=1).close()
    with pytest.raises(InputError, match="another wall"):
        open_for_resume(path, shipped_walls()["paper_test_plate"])
    log, _ = open_for_resume(path, SMALL)
    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(wall, sensor, drives, 1)
    run_scan(wall, DirectBackend(world), robot, plan_kind="dense", sensor=sensor, drives=drives, log=log)
    log.close()
    log, _ = open_for_resume(path)
    world, robot = simulated_site(wall, sensor, drives, 1)
    with pytest.raises(InputError, match="different plan"):
        run_scan(wall, DirectBackend(world), robot, plan_kind="adaptive", sensor=sensor, drives=drives, log=log)


def test_cli_errors_are_one_line(tmp_path):
    bad = tmp_path / "wall.yaml"
    bad.write_text("format: arproj-wall/1\nwidth_m: 2\nheight_m: 3.5\nmaterial: brick\n")
    done = subprocess.run(_cli("scan", "--sim", "--wall", str(bad), "--log", str(tmp_path / "x.db")),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "height_m = 3.5 exceeds what the drives reach with the lift" in done.stderr
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "x.db").exists()


def test_frames_in_the_log_carry_the_laser_fix(tmp_path):
    from scanner.laser import LASER_KEYS

    log = _new_log(tmp_path / "scan.db", load_wall(SMALL), "dense", 3)
    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(load_wall(SMALL), sensor, drives, 3)
    run_scan(load_wall(SMALL), DirectBackend(world), robot, sensor=sensor, drives=drives, log=log)
    log.close()
    with ScanLog.open(tmp_path / "scan.db") as back:
        f = back.frames()
    assert all(np.isfinite(f[k]).all() for k in LASER_KEYS)
    for axis, key in ((0, "laser_x_m"), (1, "laser_y_m"), (2, "laser_phi_rad")):
        truth = f[("true_x_m", "true_y_m", "true_phi_rad")[axis]]
        sigma = f[key.replace("_m", "_sigma_m") if axis < 2 else "laser_phi_sigma_rad"]
        assert np.all(np.abs(f[key] - truth) < 5 * sigma)  # 5 σ: p ≈ 6e-7 per value if σ is honest


def test_an_adaptive_log_from_an_earlier_planner_is_refused_on_resume_with_a_clear_line(tmp_path):
    # the planner's passes changed (fasteners, seams, priors): resuming would lay passes the log does not hold
    from scanner.plan import ADAPTIVE_PLANNER_VERSION

    wall = load_wall(shipped_walls()["small_test_wall"])
    path = tmp_path / "old.db"
    ScanLog.create(path, scan_meta(wall, "small", {"kind": "adaptive"}, SensorConfig(), DriveConfig(), 1,
                                   simulated=True)).close()
    with pytest.raises(InputError, match=f"planner version 1; this arproj plans version {ADAPTIVE_PLANNER_VERSION}"):
        open_for_resume(path)
    ScanLog.open(path, writable=True).close()  # refused, not locked or changed


def test_the_adaptive_row_spacing_is_an_option_recorded_in_the_log_and_checked(tmp_path):
    path = tmp_path / "rows.db"
    done = subprocess.run(_cli("scan", "--sim", "--fast", "--wall", str(SMALL), "--log", str(path),
                               "--row-spacing", "0.1"), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    with ScanLog.open(path) as log:
        assert log.meta["plan"]["coarse_row_spacing_m"] == 0.1
        rows = {round(float(v), 6) for v, a, s in zip(log.passes()["start_v_m"], log.passes()["axis"],
                                                       log.passes()["stage"], strict=True)
                if a == "x" and s == "coarse"}
    assert {0.0, 0.1, 0.2} <= rows
    bad = subprocess.run(_cli("scan", "--sim", "--wall", str(SMALL), "--log", str(tmp_path / "x.db"),
                              "--row-spacing", "25"), capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--row-spacing = 25 m" in bad.stderr and "Traceback" not in bad.stderr
    assert not (tmp_path / "x.db").exists()


def test_a_watcher_gets_the_plans_own_peaks_searched_once_and_the_plan_is_unchanged(monkeypatch):
    """Every pass of a stage the adaptive plan searches reaches the watcher with the plan's per-channel peaks
    (what detect_peaks finds on its samples, less the inductive lag), each pass searched once; no other pass
    carries any; and asking for them changes no pass of the plan."""
    import scanner.plan as plan_module
    from scanner.channels import INDUCTIVE, LINE_PEAKS
    from scanner.peaks import PeakConfig, detect_peaks

    wall = load_wall(shipped_walls()["paper_test_plate"])
    plain = _uninterrupted(wall, "adaptive", 3)
    searches = []

    def counted(*args, **kwargs):
        if "keep_cut" in kwargs:  # the crossings' search (the plan's other searches cut no peak)
            searches.append(id(args[1]))
        return detect_peaks(*args, **kwargs)

    monkeypatch.setattr(plan_module, "detect_peaks", counted)
    seen = []

    class Watcher:
        def frame(self, row, report):
            pass

        def scanned(self, row, samples):
            seen.append((row, samples))

    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(wall, sensor, drives, 3)
    watched = run_scan(wall, DirectBackend(world), robot, plan_kind="adaptive", sensor=sensor, drives=drives,
                       watch=Watcher())
    assert watched.samples.keys() == plain.samples.keys()
    for key, values in plain.samples.items():
        np.testing.assert_array_equal(watched.samples[key], values, err_msg=key)
    with_peaks = [(row, s) for row, s in seen if "peaks" in row]
    assert all((row["stage"] in plan_module.SEARCHED_STAGES) == ("peaks" in row) for row, _ in seen)
    assert {row["stage"] for row, _ in with_peaks} == {"coarse", "confirm", "trace"}
    assert {row["stage"] for row, _ in seen} - set(plan_module.SEARCHED_STAGES) == {"follow", "point"}  # both kinds
    assert len(searches) == len(LINE_PEAKS) * len(with_peaks)  # once each, though the studs look at rows again
    found = 0
    for row, samples in with_peaks:
        coord = samples["drive_u_m" if row["axis"] == "x" else "drive_v_m"]
        for channel in (c.name for c in LINE_PEAKS):
            lag = sensor.hysteresis_m * row["direction"] if channel == INDUCTIVE.name else 0.0
            # a peak cut by a seam's end is kept at some ends of some frames (the plan's seams): between the two
            inner, outer = ({round(p.position - lag, 9) for p in detect_peaks(coord, samples[channel], PeakConfig(),
                                                                              keep_cut=cut)}
                            for cut in ((False, False), (True, True)))
            got = {round(p, 9) for p in row["peaks"][channel]}
            assert inner <= got <= outer, (row, channel)
            found += len(got)
    assert found > 20
