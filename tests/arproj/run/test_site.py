"""The site file: a simulated scan writes where the wall is in the room (checked against the scanning
simulator's truth); a separate process that reads only the file finds the wall again with the projection
robot's laser and registers as the session does in one process with the site's true room; bad site files are
refused with one line; `arproj project --sim --head URL` drives a head served by `arproj devices serve`; and on
the hardware path a wall scanned on served devices is found again by a separate `arproj project --laser URL …`
process on the served projection robot, with the registration of `arproj project --sim` on the same site."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from arproj.run.project import SessionOptions, simulated_site_for
from arproj.run.scan import ScanSettings, resolve_wall, scan_simulated, write_site
from arproj.session.output import MemoryOutput
from arproj.session.robot_io import SimulatedRobot, nominal_rig
from arproj.session.session import ProjectionSession
from arproj.session.wallmap import wall_map_from_wall_file
from arproj.site_file import read_site, read_site_wall, simulated_room, site_wall_from_scan
from geometry.poses import invert, rotation_angle_deg
from scanner.laser import LaserConfig
from tests.support.processes import ctrl_c_default

WALL, KEY, SEED = "paper_test_plate", "plate", 4
DISTANCE_M = 2.0
ENV = {**os.environ, "COLUMNS": "200"}


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from arproj.cli import main; main()", *args]


@pytest.fixture(scope="module")
def scanned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """A simulated scan of the plate (in-process site, no log needed for the site file) and its site file,
    with the entry as the scan made it in memory."""
    folder = tmp_path_factory.mktemp("site")
    wall = resolve_wall(WALL)[0]
    result = scan_simulated(wall, ScanSettings(plan="adaptive", seed=SEED, serial=False)).result
    site_path = folder / "site.yaml"
    assert write_site(site_path, KEY, wall, result, folder / "scan.db") is False
    in_memory = site_wall_from_scan(KEY, wall, result.rooms, result.frames, LaserConfig(), folder / "map",
                                    folder / "scan.db")
    return site_path, in_memory


def test_scan_writes_where_the_wall_is_in_the_room(scanned: tuple[Path, object]) -> None:
    site_path, _ = scanned
    wall = read_site(site_path)[KEY]
    corners, height, T_true = simulated_room(wall.width_m, wall.height_m)
    for name, truth in (("width", corners[0, 0]), ("depth", corners[2, 1]), ("height", height)):
        size = wall.measured[name]
        assert size.frames == 6 and size.sigma_m is not None and 0 < size.sigma_m < 0.001
        assert abs(size.value_m - truth) < 5 * size.sigma_m, name  # each frame's look, by inverse variance
    # the wall frame lies on room wall 0, side_margin from its left side wall and floor_margin above the floor
    np.testing.assert_allclose(wall.T_room_from_wall[:3, :3], T_true[:3, :3], atol=1e-12)
    assert abs(wall.T_room_from_wall[0, 3] - T_true[0, 3]) < 5 * wall.measured["width"].sigma_m
    np.testing.assert_allclose(wall.T_room_from_wall[1:3, 3], T_true[1:3, 3], atol=1e-12)
    assert 0 < wall.sigma_along_m < 0.001 and 0 < wall.sigma_height_m < 0.001
    doc = yaml.safe_load(site_path.read_text())
    assert doc["format"] == "arproj-site/1" and doc["walls"][KEY]["map"] == "map"
    assert doc["walls"][KEY]["scan_log"] == "scan.db"


def _session_registration(robot: SimulatedRobot, site: object) -> dict:
    """One cycle of the session on the robot; the registration and its truth (the map's frame on the site)."""
    rig = nominal_rig(site)
    wall = resolve_wall(WALL)[0]
    with ProjectionSession(rig, wall_map_from_wall_file(wall.source), robot) as session:
        session.aim_at((wall.width_m / 2, wall.height_m / 2))
        decision = session.update()
        reg = session.registration
        assert decision.show_map and reg is not None, decision.reasons
        T_true = invert(robot.T_room_from_map) @ site.T_room_from_robot
        return {"T_wall_from_robot": reg.T_wall_from_robot, "truth": T_true, "sigma_m": reg.sigma_m,
                "source": reg.prior_source}


def test_reopened_site_registers_as_in_one_process(scanned: tuple[Path, object]) -> None:
    site_path, in_memory = scanned
    options = SessionOptions(sim=True, seed=SEED, distance=DISTANCE_M)
    results = {}
    for how in ("one process, true room", "the scan's entry in memory"):
        site, T_room_from_map = simulated_site_for(in_memory, options, None)
        with site:
            robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), seed=SEED, T_room_from_map=T_room_from_map,
                                           site_wall=None if how.startswith("one") else in_memory)
            try:
                results[how] = _session_registration(robot, site)
            finally:
                robot.close()
    # a new process that knows only the site file (and the wall file, for what to draw)
    done = subprocess.run(_cli("project", "--sim", "--site", str(site_path), "--wall", KEY, "--truth",
                               str(resolve_wall(WALL)[1]), "--seed", str(SEED), "--distance", str(DISTANCE_M),
                               "--json"), env=ENV, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    reopened = json.loads(done.stdout)["registration"]
    assert "laser fix in the site's room" in reopened["source"]
    one, memory = results["one process, true room"], results["the scan's entry in memory"]
    assert "localization" in one["source"] and "laser fix in the site's room" in memory["source"]
    T_reopened = np.asarray(reopened["T_wall_from_robot"])
    # the file holds the entry exactly: the reopened session is the in-memory one
    np.testing.assert_allclose(T_reopened, memory["T_wall_from_robot"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(reopened["truth"]["T_wall_from_robot"]), one["truth"], atol=1e-12)
    # against the one-process session: both fuse the plane with laser returns (σ 1 cm each) against the room,
    # the reopened one the room the scanning laser measured (σ well under 1 mm, the file's); their registration
    # σ on the wall (from those covariances) bounds the difference: 4σ of two independent estimates
    tolerance = 4.0 * np.hypot(one["sigma_m"], reopened["sigma_mm"] / 1000)
    difference = np.linalg.norm(T_reopened[:2, 3] - one["T_wall_from_robot"][:2, 3])
    assert difference < tolerance, (difference, tolerance)
    assert rotation_angle_deg(T_reopened[:3, :3], one["T_wall_from_robot"][:3, :3]) < 0.2
    for T, sigma in ((T_reopened, reopened["sigma_mm"] / 1000), (one["T_wall_from_robot"], one["sigma_m"])):
        assert np.linalg.norm(T[:2, 3] - one["truth"][:2, 3]) < 4.0 * sigma  # each against the truth
    assert reopened["truth"]["aim_error_mm"] < 4.0 * reopened["sigma_mm"]


def _serve(urls_file: Path, *args: str) -> tuple[subprocess.Popen[str], dict[str, str]]:
    """`arproj devices serve` in a process of its own, and its URLs once it has written them."""
    serve = subprocess.Popen(_cli("devices", "serve", "--urls", str(urls_file), *args), env=ENV,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=ctrl_c_default)
    deadline = time.monotonic() + 60
    while not urls_file.exists() and serve.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    if not urls_file.exists():
        serve.kill()
        raise AssertionError(serve.communicate(timeout=5))
    return serve, yaml.safe_load(urls_file.read_text())["urls"]


def _stop(serve: subprocess.Popen[str]) -> None:
    """Ctrl-C: the server stops cleanly (exit status 130)."""
    if serve.poll() is None:
        serve.send_signal(signal.SIGINT)
    try:
        _, err = serve.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        serve.kill()
        serve.wait()
        raise
    assert serve.returncode == 130, err


def test_site_scanned_on_devices_reopens_on_the_hardware_path(tmp_path: Path) -> None:
    """Scan on served devices writes the site file; a separate `arproj project` on the hardware path (screen,
    cameras, head, laser and inclinometer at the URLs a separate `arproj devices serve --projection` prints; the
    rig file) finds the wall again with the laser and registers as `arproj project --sim` does in one process."""
    serve, urls = _serve(tmp_path / "urls.yaml", "--wall", WALL, "--seed", str(SEED), "--projection",
                         "--distance", str(DISTANCE_M))
    try:
        site_path, truth_file = tmp_path / "site.yaml", str(resolve_wall(WALL)[1])
        scan = subprocess.run(_cli("scan", "--wall", WALL, "--log", str(tmp_path / "scan.db"), "--plan", "adaptive",
                                   *(a for k in ("drives", "scanner", "laser", "base") for a in (f"--{k}", urls[k])),
                                   "--virtual-clock", "--site", str(site_path), "--site-key", KEY),
                              env=ENV, capture_output=True, text=True, timeout=600)
        assert scan.returncode == 0, scan.stderr
        site_wall = read_site_wall(site_path, KEY)
        # the rig: the projection robot's design values (what the served site is built from, seed and layout)
        site, _ = simulated_site_for(site_wall, SessionOptions(sim=True, seed=SEED, distance=DISTANCE_M), None)
        with site:
            nominal_rig(site).save(tmp_path / "rig")
        common = ("--site", str(site_path), "--wall", KEY, "--truth", truth_file, "--rig", str(tmp_path / "rig"),
                  "--json")
        served = subprocess.run(_cli("project", *common, "--screen", urls["screen"], "--left", urls["camera_left"],
                                     "--right", urls["camera_right"], "--head", urls["head"],
                                     "--laser", urls["projection_laser"], "--inclinometer", urls["inclinometer"]),
                                env=ENV, capture_output=True, text=True, timeout=600)
        assert served.returncode == 0, served.stderr
    finally:
        _stop(serve)
    one = subprocess.run(_cli("project", "--sim", "--seed", str(SEED), "--distance", str(DISTANCE_M), *common),
                         env=ENV, capture_output=True, text=True, timeout=600)
    assert one.returncode == 0, one.stderr
    hardware, in_one = json.loads(served.stdout), json.loads(one.stdout)
    reg, ref = hardware["registration"], in_one["registration"]
    for r in (reg, ref):
        assert "laser fix in the site's room (left and right side wall)" in r["source"], r["source"]
        assert "inclinometer" in r["source"], r["source"]  # the served one, and --sim's own
    # the pattern was seen through the served cameras: the closed loop found its marks
    assert hardware["cycles"][0]["closed_loop_mm"]["seen"] >= 8, hardware["cycles"]
    # Two estimates of the same robot pose from independent noise (the laser's returns, the camera pictures,
    # which the served path also JPEG-compresses and the laser rounds to mm): their registration σ on the
    # wall bounds the difference, 4σ of two independent estimates; each against the simulated truth the same
    sigma_reg, sigma_ref = reg["sigma_mm"] / 1000, ref["sigma_mm"] / 1000
    tolerance = 4.0 * np.hypot(sigma_reg, sigma_ref)
    for name in ("T_wall_from_robot", "T_wall_from_projector"):
        T_hw, T_one = np.asarray(reg[name]), np.asarray(ref[name])
        assert np.linalg.norm(T_hw[:3, 3] - T_one[:3, 3]) < tolerance, (name, T_hw[:3, 3] - T_one[:3, 3])
        assert rotation_angle_deg(T_hw[:3, :3], T_one[:3, :3]) < 0.2, name
    truth = np.asarray(ref["truth"]["T_wall_from_robot"])
    assert np.linalg.norm(np.asarray(reg["T_wall_from_robot"])[:3, 3] - truth[:3, 3]) < 4.0 * sigma_reg
    aim_difference = np.linalg.norm(np.subtract(reg["aim_xy_m"], ref["aim_xy_m"]))
    assert aim_difference < tolerance, aim_difference


def test_hardware_site_sessions_refuse_what_they_cannot_do(scanned: tuple[Path, object], tmp_path: Path) -> None:
    """Without the laser, with a rig that does not place it, or --laser with --sim: one line, exit status 2,
    before any device is opened."""
    site_path, in_memory = scanned
    site, _ = simulated_site_for(in_memory, SessionOptions(sim=True, seed=SEED), None)
    with site:
        rig = nominal_rig(site)
    rig.save(tmp_path / "rig")
    del rig.poses["T_robot_from_laser"]
    rig.save(tmp_path / "rig_without_laser")
    common = ("project", "--site", str(site_path), "--wall", KEY, "--truth", str(resolve_wall(WALL)[1]))
    for args, named in (
            (("--rig", str(tmp_path / "rig")), "needs the projection robot's 2-D laser"),
            (("--rig", str(tmp_path / "rig_without_laser"), "--laser", "socket://127.0.0.1:9"),
             "(poses: T_robot_from_laser)"),
            (("--sim", "--laser", "socket://127.0.0.1:9"), "with --sim the simulated site's laser is read"),
            (("--rig", str(tmp_path / "rig"), "--screen", "beamer"), "--screen 'beamer' is neither")):
        done = subprocess.run(_cli(*common, *args), env=ENV, capture_output=True, text=True, timeout=300)
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and named in lines[0], lines


def _project(site: Path, key: str = KEY) -> subprocess.CompletedProcess[str]:
    return subprocess.run(_cli("project", "--sim", "--site", str(site), "--wall", key, "--truth",
                               str(resolve_wall(WALL)[1])), env=ENV, capture_output=True, text=True, timeout=300)


def _edit(doc: dict, path: str, value: object) -> dict:
    node = doc["walls"][KEY]
    *parents, last = path.split(".")
    for part in parents:
        node = node[part]
    node[last] = value
    return doc


@pytest.mark.parametrize(("change", "named"), [
    (lambda d: "format: arproj-site/1\nwalls: [\n", "not valid YAML at line"),
    (lambda d: yaml.safe_dump({"format": "arproj-devices/1", "urls": {}}), "format = 'arproj-devices/1'"),
    (lambda d: yaml.safe_dump(_edit(d, "T_room_from_wall", [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                            [0, 0, 0, 1]])), "walls.plate.T_room_from_wall"),
    (lambda d: yaml.safe_dump(_edit(d, "room.wall_index", 7)), "walls.plate.room.wall_index = 7"),
    (lambda d: yaml.safe_dump(_edit(d, "room.corners_m", d["walls"][KEY]["room"]["corners_m"][::-1])),
     "walls.plate.room.corners_m"),
    (lambda d: yaml.safe_dump(_edit(d, "wall.width_m", "wide")), "walls.plate.wall.width_m = 'wide'"),
    (lambda d: yaml.safe_dump(_edit(d, "wall.width_m", 30.0)), "does not fit on room wall 0"),
    (lambda d: yaml.safe_dump({**d, "walls": {KEY: {k: v for k, v in d["walls"][KEY].items() if k != "laser"}}}),
     "walls.plate.laser is missing"),
])
def test_bad_site_files_are_refused_with_one_line(scanned: tuple[Path, object], tmp_path: Path, change: object,
                                                  named: str) -> None:
    site_path, _ = scanned
    bad = tmp_path / "bad.yaml"
    bad.write_text(change(yaml.safe_load(site_path.read_text())))  # type: ignore[operator]
    done = _project(bad)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(bad) in lines[0] and named in lines[0], lines


def test_unknown_wall_and_other_files_refused(scanned: tuple[Path, object], tmp_path: Path) -> None:
    site_path, _ = scanned
    with pytest.raises(Exception, match=r"no wall 'door' in the site file \(walls: plate\)"):
        read_site_wall(site_path, "door")
    # a scan never writes its site entry over another kind of file: refused before it starts, file kept
    other = tmp_path / "notes.yaml"
    other.write_text("shopping: [milk]\n")
    done = subprocess.run(_cli("scan", "--sim", "--fast", "--wall", "small_test_wall", "--log",
                               str(tmp_path / "scan.db"), "--site", str(other)),
                          env=ENV, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "not a site file" in done.stderr and not (tmp_path / "scan.db").exists()
    assert other.read_text() == "shopping: [milk]\n"


def test_project_on_a_head_served_by_devices_serve(tmp_path: Path) -> None:
    serve, urls = _serve(tmp_path / "urls.yaml", "--wall", "small_test_wall")
    try:
        done = subprocess.run(_cli("project", "--sim", "--head", urls["head"], "--truth",
                                   str(resolve_wall("demo_brick_wall")[1]), "--json"),
                              env=ENV, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        result = json.loads(done.stdout)
        assert result["cycles"][0]["show_map"], result["cycles"]
        truth = result["registration"]["truth"]
        assert truth["aim_error_mm"] < 4.0 * result["registration"]["sigma_mm"], truth
    finally:
        _stop(serve)


def test_site_file_keeps_openings_and_sockets_and_the_map_gets_its_room(scanned: tuple[Path, object],
                                                                        tmp_path: Path) -> None:
    """The DIN zones' inputs: doors, windows and sockets read back from the site file, the floor, ceiling and
    corners from its room in the map's wall frame (the simulated scanning site's truth)."""
    from arproj.session.wallmap import wall_room_in_room
    from geometry.errors import InputError

    site_path, _ = scanned
    doc = yaml.safe_load(site_path.read_text())
    door = {"kind": "door", "outline_m": [[0.1, 0.0], [0.3, 0.0], [0.3, 0.25], [0.1, 0.25]]}
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(_edit(_edit(doc, "openings", [door]), "sockets", [[0.05, 0.1]])))
    wall = read_site(path)[KEY]
    assert [o.kind for o in wall.openings] == ["door"] and wall.sockets.tolist() == [[0.05, 0.1]]
    assert read_site(site_path)[KEY].openings == [] and read_site(site_path)[KEY].sockets.shape == (0, 2)
    room = wall_room_in_room(wall.T_room_from_wall, wall.corners_m, wall.room_height_m, wall.wall_index,
                             wall.openings, wall.sockets)
    assert room.floor_y_m == pytest.approx(-wall.floor_margin_m, abs=1e-9)
    assert room.ceiling_y_m == pytest.approx(wall.room_height_m - wall.floor_margin_m, abs=1e-9)
    assert room.corner_x_m == (pytest.approx(-wall.side_margin_m, abs=1e-9),
                               pytest.approx(wall.room_width_m - wall.side_margin_m, abs=1e-9))
    assert room.openings == [("door", 0.1, 0.0, 0.3, 0.25)]
    path.write_text(yaml.safe_dump(_edit(doc, "sockets", [[9.0, 0.1]])))
    with pytest.raises(InputError, match=r"walls.plate: sockets\[0\]"):
        read_site(path)
