"""`arproj scan --record/--view`, `arproj map --record`, `arproj export mcap`: the ROS 2 bag read back with rosbags
(its own CDR reader and rosbag2 metadata reader, independent of the writer), the Rerun recording read back with
rerun's RrdReader, against the scan log, the map and the simulated truth."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from shapely.geometry import LineString, Point
from typer.testing import CliRunner

from arproj.cli import app
from arproj.run.scan import ScanSettings, new_scan_log, scan_simulated
from arproj.run.view import ENTITIES
from arproj.run.watch import open_watchers
from mapping import drill, mapfile
from mapping.evidence import FILE_NAME, Coverage
from mapping.pipeline import MapSettings, build_map, load_scan
from mapping.ros.record import record_map
from mapping.simscan import simulate_scan, write_log
from scanner.wall import load_wall, shipped_walls

SCAN_TOPICS = {"/tf_static": "tf2_msgs/msg/TFMessage", "/tf": "tf2_msgs/msg/TFMessage",
               "/scanner/pass": "arproj_msgs/msg/ScannerPass", "/laser": "sensor_msgs/msg/LaserScan",
               "/laser/vertical": "sensor_msgs/msg/LaserScan"}
MAP_TOPICS = {"/map": "nav_msgs/msg/OccupancyGrid", "/objects": "visualization_msgs/msg/MarkerArray",
              **{f"/map/{c}": "nav_msgs/msg/OccupancyGrid" for c in ("inductive", "capacitive", "ac")}}


@pytest.fixture(scope="module")
def scanned(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """small_test_wall (a live cable at x = 0.12, a copper pipe at y = 0.18, a screw at (0.27, 0.07)) scanned on
    the in-process site with the adaptive plan, recorded (--record) and viewed (--view FILE.rrd) as `arproj scan`
    does it."""
    root = tmp_path_factory.mktemp("ros_scan")
    (root / "scan").mkdir()
    wall = load_wall(shipped_walls()["small_test_wall"])
    settings = ScanSettings(plan="adaptive", serial=False)
    log = new_scan_log(root / "scan.db", wall, "small_test_wall", settings)
    with log, open_watchers(log.meta, root / "scan" / "scan.mcap", str(root / "scan.rrd")) as watch:
        scan_simulated(wall, settings, log, watch=watch)
    return root


@pytest.fixture(scope="module")
def mapped(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same wall's dense scan without placement error (test_drill's), mapped; its bag as `arproj map
    --record` writes it, and the map folder's objects.json and coverage.npz that `arproj export mcap` reads."""
    root = tmp_path_factory.mktemp("ros_map")
    wall = load_wall(shipped_walls()["small_test_wall"])
    log = write_log(simulate_scan(wall, seed=2, robot_sigma=(0.0, 0.0, 0.0), loc_sigma=(1e-4, 1e-4, 1e-5)),
                    root / "scan.db")
    data = load_scan(log)
    result = build_map(data, MapSettings())
    assert result.coverage is not None
    (root / "map").mkdir()
    (root / "map_bag").mkdir()
    objects = result.mapped_objects()
    mapfile.write_objects(root / "map" / mapfile.FILE_NAME, objects)
    result.coverage.save(root / "map" / FILE_NAME)
    record_map(root / "map_bag" / "m.mcap", data, objects, result.coverage)
    return root


def _read(folder: Path) -> dict[str, list[tuple[int, object]]]:
    """{topic: [(log time ns, message)]}, every message deserialised, and the types the connections name."""
    out: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([folder]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for connection, t, raw in reader.messages():
            out.setdefault(connection.topic, []).append((t, reader.deserialize(raw, connection.msgtype)))
    out["types"] = [(0, types)]
    return out


def test_every_topic_and_message_of_the_scan_bag_deserialises(scanned: Path) -> None:
    bag = _read(scanned / "scan")
    assert bag.pop("types")[0][1] == SCAN_TOPICS
    meta = yaml.safe_load((scanned / "scan" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "mcap" and meta["relative_file_paths"] == ["scan.mcap"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts == {topic: len(messages) for topic, messages in bag.items()}
    data = load_scan(scanned / "scan.db")
    passes = [m for _, m in bag["/scanner/pass"]]
    assert len(passes) == len(np.unique(data.samples["pass_id"]))
    for msg in passes:  # every sample of every pass, as the log holds it
        rows = data.samples["pass_id"] == msg.pass_id
        np.testing.assert_array_equal(msg.inductive, data.samples["inductive"][rows])
        np.testing.assert_array_equal(msg.x_m, data.samples["x_m"][rows])
        assert msg.header.frame_id == "wall" and msg.frame_id == int(data.samples["frame_id"][rows][0])


def test_tf_is_one_tree_and_the_poses_match_the_log_and_the_truth(scanned: Path) -> None:
    bag = _read(scanned / "scan")
    data = load_scan(scanned / "scan.db")
    parents: dict[str, str] = {}
    for _, msg in bag["/tf_static"] + bag["/tf"]:
        for tr in msg.transforms:
            assert parents.setdefault(tr.child_frame_id, tr.header.frame_id) == tr.header.frame_id  # one parent
    assert parents == {"wall": "room", "robot": "room", "laser": "robot", "laser_vertical": "robot",
                       "scanner": "robot"}
    robots = [tr for _, m in bag["/tf"] for tr in m.transforms if tr.child_frame_id == "robot"]
    f = data.frames
    assert len(robots) == len(f["frame_id"])
    for tr, x, y, phi, tx, ty in zip(robots, f["est_x_m"], f["est_y_m"], f["est_phi_rad"], f["true_x_m"],
                                     f["true_y_m"], strict=True):
        t, q = tr.transform.translation, tr.transform.rotation
        assert (t.x, t.y, t.z) == pytest.approx((x, y, 0.0), abs=1e-12)
        assert 2 * math.atan2(q.z, q.w) == pytest.approx(phi, abs=1e-9) and q.x == q.y == 0.0
        assert math.hypot(t.x - tx, t.y - ty) < 0.01  # the localised pose, within 10 mm of the truth
    scanner = [tr.transform.translation for _, m in bag["/tf"] for tr in m.transforms
               if tr.child_frame_id == "scanner"]
    u, v = data.samples["drive_u_m"], data.samples["drive_v_m"]
    for t in scanner:  # each is a sample's drive position
        assert np.min(np.hypot(u - t.x, v - t.y)) < 1e-12
    horizontal = bag["/laser"][0][1]  # the wall lies behind the horizontal laser, a standoff away (0.5 ± 0.03 m)
    angles = horizontal.angle_min + horizontal.angle_increment * np.arange(len(horizontal.ranges))
    assert horizontal.ranges[np.argmin(np.abs(angles + math.pi / 2))] == pytest.approx(0.5, abs=0.04)


def test_grids_are_the_drill_verdicts_and_unknown_is_never_free(mapped: Path) -> None:
    coverage = Coverage.load(mapped / "map" / FILE_NAME)
    objects = mapfile.read_objects(mapped / "map" / mapfile.FILE_NAME)
    want = drill.verdict_raster(objects, coverage, coverage.wall_bounds)
    for folder in (mapped / "map_bag",):
        bag = _read(folder)
        assert MAP_TOPICS.items() <= bag.pop("types")[0][1].items()
        grids = {topic: msgs[-1][1] for topic, msgs in bag.items() if topic.startswith("/map")}
        info = coverage.info
        for grid in grids.values():
            assert (grid.info.width, grid.info.height) == (info.width, info.height)
            assert grid.info.resolution == pytest.approx(info.resolution)
            assert grid.header.frame_id == "wall"
        main = np.asarray(grids["/map"].data).reshape(info.height, info.width)
        expect = np.select([want == drill.VERDICT_CODES[drill.SAFE], want == drill.VERDICT_CODES[drill.KEEP_AWAY]],
                           [0, 100], -1)
        np.testing.assert_array_equal(main, expect)
        assert (main == 0).any() and (main == 100).any() and (main == -1).any()
        for channel in coverage.channels:
            g = np.asarray(grids[f"/map/{channel}"].data).reshape(info.height, info.width)
            assert not np.any((g == 0) & (main != 0))  # free only where /map is free …
            assert not np.any((g == 0) & ~coverage.covered[channel])  # … and this channel looked
        assert np.all(np.asarray(grids["/map/ac"].data).reshape(info.shape)[~coverage.covered["ac"]] == -1)


def test_objects_are_the_map_and_the_map_finds_the_truth(mapped: Path) -> None:
    objects = mapfile.read_objects(mapped / "map" / mapfile.FILE_NAME)
    markers = _read(mapped / "map_bag")["/objects"][-1][1].markers
    labels = [m for m in markers if m.ns == "label"]
    assert len(labels) == len(objects)
    for obj, text in zip(objects, labels, strict=True):
        assert obj.cls.replace("_", " ") in text.text
        assert ("depth unknown" if obj.depth_m is None else f"depth {1000 * obj.depth_m:.0f} mm") in text.text
    strips = [m for m in markers if m.type == 4]
    drawn = np.array([(p.x, p.y) for m in strips for p in m.points])
    for obj in objects:  # every vertex of every line is drawn where the map has it (objects.json keeps 10 µm)
        if obj.shape != "point":
            gaps = np.hypot(*(drawn[:, None, :] - obj.points_m[None]).transpose(2, 0, 1))
            assert gaps.min(axis=0).max() < 1e-5
    truth = load_wall(shipped_walls()["small_test_wall"])
    assert {"measured", "label"} <= {m.ns for m in markers}
    lines = [o for o in truth.objects if o.points_m is not None and len(o.points_m) >= 2]
    assert len(lines) == 2  # the cable and the pipe: each drawn along its true course, within 10 mm
    for obj in lines:
        course = LineString(obj.points_m)
        assert any(len(m.points) >= 2 and max(course.distance(Point(p.x, p.y)) for p in m.points) < 0.01
                   for m in strips)


def test_export_mcap_writes_the_same_bag_from_the_map_folder(mapped: Path) -> None:
    done = CliRunner().invoke(app, ["export", "mcap", str(mapped / "scan.db"), str(mapped / "map")])
    assert done.exit_code == 0, done.output
    exported, recorded = _read(mapped / "ros2"), _read(mapped / "map_bag")
    assert exported["types"] == recorded["types"]
    for topic in MAP_TOPICS:
        a, b = exported[topic][-1][1], recorded[topic][-1][1]
        if topic == "/objects":
            assert [m.text for m in a.markers] == [m.text for m in b.markers]
        else:
            np.testing.assert_array_equal(a.data, b.data)
    assert len(exported["/scanner/pass"]) == len(recorded["/scanner/pass"])


def test_the_rerun_recording_holds_every_entity(scanned: Path) -> None:
    from rerun.chunk import RrdReader

    paths = set(RrdReader(scanned / "scan.rrd").store().schema().entity_paths())
    for entity in ENTITIES:  # wall/samples holds one child per batch sent
        assert f"/{entity}" in paths or any(p.startswith(f"/{entity}/") for p in paths), entity


@pytest.mark.parametrize("args, message", [
    (["--record", "x.bag"], "a recording is an .mcap file"),
    (["--record", "nowhere/x.mcap"], "no folder nowhere"),
    (["--view", "x.png"], "give `live` (a viewer) or a FILE.rrd"),
])
def test_a_bad_target_is_one_line_before_the_scan(args: list[str], message: str, tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    import sys

    from arproj.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["arproj", "scan", "--sim", "--fast", "--wall", "small_test_wall", "--log",
                                      "s.db", "--no-site", *args])
    with pytest.raises(SystemExit) as exit_:
        main()
    assert exit_.value.code == 2 and message in capsys.readouterr().err.replace("\n", " ")
    assert not (tmp_path / "s.db").exists()
