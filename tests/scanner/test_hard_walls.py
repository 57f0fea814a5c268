"""Hard-case walls: enough of them, reproducible, valid files, and every case found in the geometry itself."""

import functools
import itertools
import math

import numpy as np
import pytest

from geometry.polyline import densify, distances_to_polyline
from scanner.hard_walls import (
    COARSE_ROW_SPACING_M,
    DEEP_PIPE_DEPTH_M,
    HARD_CASES,
    MIN_GAP_M,
    N_HARD_CASE_WALLS,
    hard_case_wall,
    hard_case_walls,
)
from scanner.sensor_model import SensorModel, points_in_polygon
from scanner.wall import Wall, WallObject, load_wall, save_wall

SEEDS = (0, 1, 2)


@functools.cache
def _walls(seed: int) -> tuple[Wall, ...]:
    return tuple(hard_case_walls(seed))


def _named_cases(wall: Wall) -> list[str]:
    label, _, cases = wall.name.partition(" ")
    assert label.startswith("hard-")
    return cases.split(" + ")


def _of_kind(wall: Wall, *kinds: str) -> list[WallObject]:
    return [o for o in wall.objects if o.kind in kinds]


def _closed(outline: np.ndarray) -> np.ndarray:
    return np.vstack([outline, outline[:1]])


def _distance_to_area(points: np.ndarray, area: WallObject) -> np.ndarray:
    """0 inside the outline, else the distance to it. points : (n, 2) -> (n,) metres."""
    d = distances_to_polyline(points, _closed(area.outline_m))
    return np.where(points_in_polygon(points, area.outline_m), 0.0, d)


def _samples(obj: WallObject) -> np.ndarray:
    if obj.outline_m is not None:
        return densify(_closed(obj.outline_m), 0.005)
    return densify(obj.points_m, 0.005) if len(obj.points_m) > 1 else obj.points_m


def _gap(a: WallObject, b: WallObject) -> float:
    """Smallest distance between two objects (0 where one overlaps an area); inf when clearly apart."""
    ga, gb = a.geometry_m, b.geometry_m
    if np.any(ga.min(axis=0) - gb.max(axis=0) > MIN_GAP_M) or np.any(gb.min(axis=0) - ga.max(axis=0) > MIN_GAP_M):
        return math.inf

    def one_way(p: WallObject, q: WallObject) -> float:
        s = _samples(p)
        return float((_distance_to_area(s, q) if q.outline_m is not None else distances_to_polyline(s, q.points_m))
                     .min())
    return min(one_way(a, b), one_way(b, a))


def _turns_deg(points: np.ndarray) -> list[float]:
    """Signed direction change at each interior vertex of a polyline, degrees (left turns positive)."""
    d = np.diff(points, axis=0)
    heading = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    return [float((b - a + 180.0) % 360.0 - 180.0) for a, b in itertools.pairwise(heading)]


# ---------------------------------------------------------------------------------------------- case checks
def _has_bend(wall: Wall) -> bool:
    return any(abs(abs(t) - 90.0) < 1.0 or abs(abs(t) - 45.0) < 1.0
               for o in wall.targets() for t in _turns_deg(o.points_m))


def _detour_between_rows(line: np.ndarray, wall_height: float) -> bool:
    """The polyline leaves its end-to-end line by >= 8 cm, over a 20-40 cm path, strictly between two rows
    k·25 cm and (k+1)·25 cm, and is back on course where both rows cross it."""
    a, b = line[0], line[-1]
    along = (b - a) / np.linalg.norm(b - a)
    normal = np.array([-along[1], along[0]])
    samples = densify(line, 0.002)
    offset = np.abs((samples - a) @ normal)
    aside = offset > 0.005
    if offset.max() < 0.08:
        return False
    path_aside = float(np.linalg.norm(np.diff(samples, axis=0), axis=1)[aside[1:] & aside[:-1]].sum())
    y_aside = samples[aside, 1]
    for k in range(round(wall_height / COARSE_ROW_SPACING_M)):
        low, high = k * COARSE_ROW_SPACING_M, (k + 1) * COARSE_ROW_SPACING_M
        if low < y_aside.min() and y_aside.max() < high and 0.2 <= path_aside <= 0.4:
            at_rows = [offset[np.abs(samples[:, 1] - row) < 0.002] for row in (low, high)]
            return all(len(o) > 0 and o.max() < 0.005 for o in at_rows)
    return False


def _has_detour(wall: Wall) -> bool:
    return any(_detour_between_rows(o.points_m, wall.height_m) for o in wall.targets())


def _cable_ends_near(wall: Wall, box: WallObject) -> int:
    ends = np.array([p for c in _of_kind(wall, "cable") for p in (c.points_m[0], c.points_m[-1])])
    return int((_distance_to_area(ends, box) <= 0.02).sum())


def _is_box(obj: WallObject) -> bool:
    sides = obj.outline_m.max(axis=0) - obj.outline_m.min(axis=0)
    return (obj.kind == "plate" and obj.material == "steel" and obj.thickness_m <= 0.002
            and bool(np.all((sides >= 0.059) & (sides <= 0.071))))


def _has_junction_and_dead_end(wall: Wall) -> bool:
    ends = [_cable_ends_near(wall, box) for box in _of_kind(wall, "plate") if _is_box(box)]
    return max(ends, default=0) >= 3 and 1 in ends


def _segments_cross(p: np.ndarray, q: np.ndarray, r: np.ndarray, s: np.ndarray) -> bool:
    def side(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
        return float(np.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])))
    return side(p, q, r) * side(p, q, s) < 0 and side(r, s, p) * side(r, s, q) < 0


def _has_crossing(wall: Wall) -> bool:
    return any(_segments_cross(p0, p1, c0, c1)
               for pipe in _of_kind(wall, "pipe") for p0, p1 in itertools.pairwise(pipe.points_m)
               for cable in _of_kind(wall, "cable") for c0, c1 in itertools.pairwise(cable.points_m))


def _has_parallel_cables(wall: Wall) -> bool:
    cables = _of_kind(wall, "cable")
    step = 0.005
    for i, a in enumerate(cables):
        samples = densify(a.points_m, step)
        for b in cables[i + 1:]:
            d = distances_to_polyline(samples, b.points_m)
            if np.sum(np.abs(d - 0.05) <= 0.005) * step >= 0.30:
                return True
    return False


def _has_deep_pipe(wall: Wall) -> bool:
    depths = [o.depth_m for o in _of_kind(wall, "pipe")]
    return any(d == pytest.approx(DEEP_PIPE_DEPTH_M) for d in depths) and any(0.015 <= d <= 0.03 for d in depths)


def _has_filled_plastic_pipe(wall: Wall) -> bool:
    return any(o.material == "plastic" and o.water_filled for o in _of_kind(wall, "pipe"))


def _stud_with_fasteners(wall: Wall, material: str) -> bool:
    for stud in _of_kind(wall, "stud"):
        (x0, y0), (x1, y1) = stud.outline_m.min(axis=0), stud.outline_m.max(axis=0)
        if stud.material != material or not 0.04 <= x1 - x0 <= 0.06 or y0 > 0 or y1 < wall.height_m:
            continue
        points = np.array([f.points_m[0] for f in _of_kind(wall, "screw", "nail")]).reshape(-1, 2)
        held = points[points_in_polygon(points, stud.outline_m)]
        pitch = np.diff(np.sort(held[:, 1]))
        if (len(held) >= 3 and np.all(np.abs(held[:, 0] - (x0 + x1) / 2) < 0.001)
                and np.all((pitch >= 0.3 - 1e-6) & (pitch <= 0.4 + 1e-6))):
            return True
    return False


def _loose_fasteners(wall: Wall) -> list[WallObject]:
    studs = _of_kind(wall, "stud", "beam")
    return [f for f in _of_kind(wall, "screw", "nail")
            if all(_gap(f, o) >= MIN_GAP_M - 1e-3 for o in wall.objects if o is not f and o not in studs)
            and not any(points_in_polygon(f.points_m, s.outline_m)[0] for s in studs)]


def _has_cavity_behind_drywall(wall: Wall) -> bool:
    return wall.material == "drywall" and bool(_of_kind(wall, "cavity"))


def _has_live_and_dead(wall: Wall) -> bool:
    return {c.live for c in _of_kind(wall, "cable")} == {True, False}


CHECKS = {
    "bends and elbows": _has_bend,
    "detour between coarse rows": _has_detour,
    "junction and dead ends at socket boxes": _has_junction_and_dead_end,
    "X crossing of a pipe and a cable": _has_crossing,
    "parallel cables 5 cm apart": _has_parallel_cables,
    "pipe 5 cm deep": _has_deep_pipe,
    "filled plastic pipe": _has_filled_plastic_pipe,
    "wood stud with fasteners": lambda wall: _stud_with_fasteners(wall, "wood"),
    "steel stud with fasteners": lambda wall: _stud_with_fasteners(wall, "steel"),
    "loose screws and nails": lambda wall: len(_loose_fasteners(wall)) >= 3,
    "cavity behind drywall": _has_cavity_behind_drywall,
    "live and dead cables": _has_live_and_dead,
}


# ---------------------------------------------------------------------------------------------- tests
def test_cases_have_checks_and_every_case_is_in_some_wall():
    assert set(CHECKS) == set(HARD_CASES) and len(HARD_CASES) == len(set(HARD_CASES))
    named = {case for wall in _walls(0) for case in _named_cases(wall)}
    assert named == set(HARD_CASES)


def test_enough_walls_of_the_usual_size_and_varied_materials():
    walls = _walls(0)
    assert len(walls) == N_HARD_CASE_WALLS >= 20
    assert all((w.width_m, w.height_m) == (2.5, 2.0) for w in walls)
    assert {w.material for w in walls} == {"drywall", "brick", "concrete", "aerated_concrete"}
    assert all(w.material == "drywall" for w in walls if _of_kind(w, "stud", "cavity"))
    assert [w.name[:7] for w in walls] == [f"hard-{i:02d}" for i in range(len(walls))]
    assert all(2 <= len(_named_cases(w)) <= 4 for w in walls)


@pytest.mark.parametrize("seed", SEEDS)
def test_each_wall_holds_the_cases_its_name_claims(seed):
    for wall in _walls(seed):
        for case in _named_cases(wall):
            assert CHECKS[case](wall), f"seed {seed}: {wall.name!r} does not hold {case!r}"


def test_the_shapes_of_bends_and_fasteners_across_walls():
    lines = [o.points_m for w in _walls(0) for o in w.targets()]
    turns = [_turns_deg(p) for p in lines]
    right_angle = [[abs(abs(t) - 90.0) < 1.0 for t in ts] for ts in turns]
    assert any(len(ts) == 1 and ok == [True] for ts, ok in zip(turns, right_angle, strict=True))  # an L
    assert any(len(ts) == 2 and all(ok) and ts[0] * ts[1] < 0
               for ts, ok in zip(turns, right_angle, strict=True))  # a Z
    assert any(abs(abs(t) - 45.0) < 1.0 for ts in turns for t in ts)
    loose = [f.kind for w in _walls(0) for f in _loose_fasteners(w)]
    assert {"screw", "nail"} <= set(loose)


def test_plastic_pipe_is_seen_only_by_the_capacitive_channel():
    wall = next(w for w in _walls(0) if _has_filled_plastic_pipe(w))
    pipe = next(o for o in _of_kind(wall, "pipe") if o.material == "plastic")
    without = Wall(wall.width_m, wall.height_m, wall.material, objects=[o for o in wall.objects if o is not pipe])
    over = densify(pipe.points_m, 0.05)
    delta = SensorModel(wall).raw(over) - SensorModel(without).raw(over)
    assert np.abs(delta[:, [0, 2]]).max() < 1e-12  # inductive and AC: nothing there
    assert delta[:, 1].min() > 0.05  # water raises the capacitive reading


@pytest.mark.parametrize("seed", SEEDS)
def test_objects_of_different_groups_keep_apart(seed):
    for wall in _walls(seed):
        ids = [o.id for o in wall.objects]
        assert len(set(ids)) == len(ids)
        objects = wall.objects
        for i, a in enumerate(objects):
            for b in objects[i + 1:]:
                if a.id.split("-")[0] != b.id.split("-")[0]:
                    assert _gap(a, b) >= MIN_GAP_M - 1e-3, f"{wall.name}: {a.id} and {b.id}"


def test_deterministic_for_a_seed_and_different_for_another():
    first = [w.fingerprint() for w in _walls(0)]
    assert [w.fingerprint() for w in hard_case_walls(0)] == first
    assert hard_case_wall(5, seed=0).fingerprint() == first[5]
    other = _walls(1)
    assert all(a != b.fingerprint() for a, b in zip(first, other, strict=True))
    assert [w.name for w in other] == [w.name for w in _walls(0)]  # the cases belong to the index


def test_index_out_of_range_is_refused():
    with pytest.raises(IndexError):
        hard_case_wall(N_HARD_CASE_WALLS)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_every_wall_round_trips_through_a_file(tmp_path, suffix):
    for wall in _walls(0):
        path = tmp_path / f"{wall.name[:7]}{suffix}"
        save_wall(wall, path)
        loaded = load_wall(path)
        assert loaded.fingerprint() == wall.fingerprint() and loaded.name == wall.name


def test_sensor_model_gives_finite_readings_on_every_wall():
    gx, gy = np.meshgrid(np.linspace(0.02, 2.48, 20), np.linspace(0.02, 1.98, 15))
    points = np.column_stack([gx.ravel(), gy.ravel()])
    for wall in _walls(0):
        readings = SensorModel(wall).display(points, rng=np.random.default_rng(0))
        assert readings.shape == (300, 3) and np.all(np.isfinite(readings))
        assert np.all((readings >= 0.0) & (readings <= 1.0))
