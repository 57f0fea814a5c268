"""Priors (DIN 18015-3 installation zones, known sockets): they order the adaptive plan's passes, never replace one."""

from collections import Counter

import numpy as np
import pytest

from geometry.errors import InputError
from scanner.log import ScanLog
from scanner.plan import AdaptivePlanner, DriveConfig, PassSpec, frame_pose_apply, make_planner
from scanner.priors import CROSS_SCORE, wall_priors
from scanner.run import DirectBackend, ScanCrashError, open_for_resume, run_scan, scan_meta, simulated_site
from scanner.sensor_model import SensorConfig
from scanner.wall import Wall, load_wall, shipped_walls, wall_from_dict


def _wall(width_m: float, height_m: float, objects: list, **known) -> Wall:
    return wall_from_dict({"format": "arproj-wall/1", "name": "priors", "width_m": width_m, "height_m": height_m,
                           "material": "brick", "objects": objects, **known}, "test")


@pytest.fixture
def recorded(monkeypatch) -> list[PassSpec]:
    """Every pass the in-process backend measures, in order."""
    passes: list[PassSpec] = []
    measure = DirectBackend.measure_pass

    def record(self, pass_id, spec):
        passes.append(spec)
        return measure(self, pass_id, spec)

    monkeypatch.setattr(DirectBackend, "measure_pass", record)
    return passes


def _scan(wall: Wall, priors: bool, seed: int):
    sensor, drives = SensorConfig(), DriveConfig()
    world, robot = simulated_site(wall, sensor, drives, seed)
    return run_scan(wall, DirectBackend(world), robot, plan_kind="adaptive", plan_options={"priors": priors},
                    sensor=sensor, drives=drives)


def test_zones_of_a_wall_from_the_site_survey_follow_the_standard():
    # the site survey: floor 0.3 m below y = 0, ceiling 2.7 m above the floor (a 2.0 m wall fits under it)
    priors = wall_priors(_wall(2.5, 2.0, []))
    bands = {z.name: (z.course, round(z.lo_m, 6), round(z.hi_m, 6)) for z in priors.zones}
    assert bands == {"top": ("x", 1.95, 2.25), "middle": ("x", 0.70, 1.00), "bottom": ("x", -0.15, 0.15),
                     "left corner": ("y", 0.10, 0.30), "right corner": ("y", 2.20, 2.40)}
    assert "site survey" in priors.origin


def test_zones_from_the_wall_files_room_and_openings():
    wall = _wall(3.0, 2.0, [], room={"floor_y_m": -0.1, "ceiling_y_m": 2.3},
                 openings=[{"kind": "door", "outline_m": [[0.8, 0.0], [1.7, 0.0], [1.7, 2.0], [0.8, 2.0]]}])
    bands = {z.name: (round(z.lo_m, 6), round(z.hi_m, 6)) for z in wall_priors(wall).zones}
    assert bands["top"] == (1.85, 2.15) and bands["bottom"] == (0.05, 0.35) and bands["middle"] == (0.9, 1.2)
    assert bands["left of door 1"] == (0.5, 0.7) and bands["right of door 1"] == (1.8, 2.0)
    # a low wall: the ceiling's zone lies above it and is left out
    assert "top" not in {z.name for z in wall_priors(_wall(1.0, 1.0, [])).zones}


def test_scores_of_passes_and_points():
    priors = wall_priors(_wall(2.5, 2.0, [], sockets=[[1.2, 0.4]]))
    along = priors.pass_score(np.array([0.4, 0.85]), np.array([0.8, 0.85]))  # in the middle zone, along it
    across = priors.pass_score(np.array([0.6, 0.0]), np.array([0.6, 2.0]))  # crosses the horizontal zones
    outside = priors.pass_score(np.array([0.4, 0.5]), np.array([0.8, 0.5]))
    assert along == 1.0 and across == CROSS_SCORE and outside == 0.0
    assert priors.pass_score(np.array([1.0, 0.45]), np.array([1.4, 0.45])) == 1.0  # passes the socket
    # a find on a vertical pass (course along x) in a horizontal zone; one on a horizontal pass is not
    assert priors.point_hit(np.array([0.6, 0.85]), "x") == "middle"
    assert priors.point_hit(np.array([0.6, 0.85]), "y") is None
    assert priors.point_hit(np.array([1.25, 0.42]), "y") == "socket 1"


def test_priors_reorder_the_same_coarse_passes_and_do_not_lower_recall_or_raise_the_time():
    from arproj.run.scan import scan_and_map
    from mapping.evaluate import evaluate
    from scanner.hard_walls import hard_case_wall

    wall = hard_case_wall(0)
    drives = DriveConfig()

    def coarse_lines(priors: bool) -> tuple[Counter, list[list[PassSpec]]]:
        planner = make_planner("adaptive", wall, drives, options={"priors": priors})
        stages = [next(planner.frame_stages(frame)) for frame in planner.frames()]
        # a line scanned either way round is the same measurement (the inductive lag is undone per direction)
        return Counter((p.frame_id, p.axis, *sorted([p.start_uv, p.end_uv])) for s in stages for p in s), stages

    lines_on, stages_on = coarse_lines(True)
    lines_off, stages_off = coarse_lines(False)
    assert lines_on == lines_off
    assert [p.stage for s in stages_on for p in s] == ["coarse"] * sum(lines_off.values())
    assert stages_on != stages_off  # the order did change
    results = {priors: scan_and_map(wall, "adaptive", 0, {"priors": priors}) for priors in (False, True)}
    recall = {priors: evaluate(result.objects, wall).recall for priors, (_, result) in results.items()}
    assert recall[True] >= recall[False] > 0.5, recall
    time = {priors: scan.scan_time_s for priors, (scan, _) in results.items()}
    assert time[True] <= 1.05 * time[False], time  # ordering changes the rapids only


def test_a_cable_in_a_zone_is_traced_first(recorded):
    # frame 1 (wall x 0.35..0.75) holds no vertical zone: a vertical pipe near where the coarse passes end
    # and a live cable in the middle zone (1.00-1.30 m above the floor, y 0.70..1.00)
    wall = _wall(1.05, 2.0, [
        {"kind": "cable", "id": "zone-cable", "points_m": [[0.40, 0.85], [0.70, 0.85]], "depth_m": 0.02},
        {"kind": "pipe", "id": "pipe", "points_m": [[0.55, 0.0], [0.55, 0.55]], "depth_m": 0.02,
         "material": "copper", "diameter_m": 0.015}])
    first = {}
    for priors in (False, True):
        recorded.clear()
        scan = _scan(wall, priors, seed=2)
        confirm = next(p for p in recorded if p.frame_id == 1 and p.stage == "confirm")
        first[priors] = (confirm, next(r for r in scan.plan_report if r["frame_id"] == 1))
    confirm, row = first[True]
    v = sorted([confirm.start_uv[1], confirm.end_uv[1]])
    assert v[0] <= 0.85 <= v[1] and row["channel"] == "ac" and row["first_in"] == "middle"
    confirm, row = first[False]  # without priors the nearest find (the pipe's, on the bottom row) went first
    assert max(confirm.start_uv[1], confirm.end_uv[1]) < 0.7 and row["channel"] == "inductive"


def test_a_known_socket_between_coarse_rows_is_searched_first_and_mapped(recorded):
    from arproj.run.scan import scan_and_map
    from mapping.evaluate import area_recall, evaluate

    # a socket box between the rows at 0.25 and 0.5 m and between the columns: no coarse pass passes over it
    centre, half = np.array([0.175, 0.375]), 0.0325
    box = [(centre + half * np.array(c)).tolist() for c in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    wall = _wall(0.35, 1.0, [
        {"kind": "plate", "id": "socket", "outline_m": box, "depth_m": 0.02, "material": "steel",
         "thickness_m": 0.001},
        {"kind": "cable", "id": "feed", "points_m": [[0.175, 0.4075], [0.175, 1.0]], "depth_m": 0.02}],
        sockets=[centre.tolist()])
    scan, result = scan_and_map(wall, "adaptive", 1, {"priors": True})
    stages = [p.stage for p in recorded]
    n_coarse = stages.count("coarse")
    assert stages[n_coarse:n_coarse + 5] == ["socket"] * 5  # looked at before anything is traced
    f = scan.frames[0]
    pose = (f["est_x_m"], f["est_y_m"], f["est_phi_rad"])  # the square is laid where the robot localised itself
    for p in recorded[n_coarse:n_coarse + 5]:
        middle = frame_pose_apply(pose, np.add(p.start_uv, p.end_uv) / 2)[0]
        assert np.linalg.norm(middle - centre) <= 0.071  # a square around it
    assert scan.plan_report[0]["first_in"] == "socket 1"
    assert area_recall(result.objects, wall)[0] == 1  # the box: a metal object at its middle
    assert evaluate(result.objects, wall).n_found == 1  # and its cable
    assert any("socket 1: searched 1" in line for line in scan.plan_priors)
    recorded.clear()
    scan_and_map(wall, "adaptive", 1, {"priors": False})
    assert "socket" not in {p.stage for p in recorded}


def test_a_log_made_without_priors_resumes_without_them(tmp_path):
    wall = load_wall(shipped_walls()["small_test_wall"])
    sensor, drives = SensorConfig(), DriveConfig()
    plan = make_planner("adaptive", wall, drives, options={"priors": False}).describe()
    assert plan["priors"] is False
    path = tmp_path / "scan.db"
    ScanLog.create(path, scan_meta(wall, "small", plan, sensor, drives, 4, simulated=True)).close()

    def resume(options: dict, crash_at: int = -1):
        log, _ = open_for_resume(path)
        world, robot = simulated_site(wall, sensor, drives, 4)

        def hook(pass_id: int) -> None:
            if pass_id == crash_at:
                raise ScanCrashError("power lost")

        try:
            return run_scan(wall, DirectBackend(world), robot, plan_kind="adaptive", plan_options=options,
                            sensor=sensor, drives=drives, log=log, crash_hook=hook)
        finally:
            log.close()

    with pytest.raises(ScanCrashError):
        resume(plan, crash_at=6)
    with pytest.raises(InputError, match="differs from the plan"):  # the priors' order is another plan
        resume({**plan, "priors": True})
    with ScanLog.open(path) as log:
        meta_plan = log.meta["plan"]
    done = resume(meta_plan)
    reference = _scan(wall, False, seed=4)
    np.testing.assert_array_equal(done.samples["inductive"], reference.samples["inductive"])


def test_planner_without_priors_keeps_none():
    planner = AdaptivePlanner(_wall(0.35, 0.5, []), DriveConfig())
    assert planner.priors is not None and planner.describe()["priors"] is True
    off = make_planner("adaptive", _wall(0.35, 0.5, []), DriveConfig(), options={"priors": False})
    assert off.priors is None and off.priors_lines()[0].startswith("priors off")


@pytest.mark.parametrize(("known", "where"), [
    ({"sockets": [[0.2]]}, "sockets[0]"),
    ({"sockets": [[0.2, 3.0]]}, "sockets[0]"),
    ({"sockets": {"x": 1}}, "sockets"),
    ({"openings": [{"kind": "hatch", "outline_m": [[0, 0], [0.2, 0], [0.2, 0.2]]}]}, "openings[0].kind"),
    ({"openings": [{"kind": "window", "outline_m": [[0, 0], [0.2, 0]]}]}, "openings[0].outline_m"),
    ({"openings": [{"kind": "door", "outline_m": [[0, 0], [0.2, 0], [0.2, 0.2]], "height": 2}]},
     "openings[0].height"),
    ({"room": {"floor_y_m": 0.2, "ceiling_y_m": 2.5}}, "room.floor_y_m"),
    ({"room": {"ceiling_y_m": 2.5}}, "room"),
])
def test_a_wall_file_with_a_bad_prior_names_the_file_and_the_key(tmp_path, known, where):
    import yaml

    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"format": "arproj-wall/1", "width_m": 1.0, "height_m": 1.0, "objects": [],
                                    **known}))
    with pytest.raises(InputError) as err:
        load_wall(path)
    assert str(path) in str(err.value) and f"{where} = " in str(err.value)


def test_declared_priors_round_trip_and_old_walls_keep_their_fingerprint():
    plain = {"format": "arproj-wall/1", "name": "priors", "width_m": 1.0, "height_m": 1.0, "material": "brick",
             "objects": []}
    assert _wall(1.0, 1.0, []).to_dict() == plain  # nothing added: logs of old walls still match
    known = _wall(1.0, 1.0, [], sockets=[[0.3, 0.3]], room={"floor_y_m": -0.3, "ceiling_y_m": 2.4},
                  openings=[{"kind": "window", "outline_m": [[0.5, 0.5], [0.9, 0.5], [0.9, 0.9], [0.5, 0.9]]}])
    again = wall_from_dict(known.to_dict(), "again")
    assert again.fingerprint() == known.fingerprint() != _wall(1.0, 1.0, []).fingerprint()
    np.testing.assert_allclose(again.sockets, [[0.3, 0.3]])
