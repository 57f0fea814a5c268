"""Honest classes on simulated dense scans: a class says only what the channels can tell.

The capacitive channel alone cannot tell a wooden stud from a water-filled plastic pipe: both are "non_metal";
a pipe is never called wood, metal or a pipe of metal when no metal is there, and what the inductive channel
sees is never called non-metal. Walls: one built for this (every class side by side, a water pipe crossing a
cable and a copper pipe) and hard-case walls with water-filled plastic pipes (scanner.hard_walls), scanned
densely (mapping.simscan) and mapped as `arproj map` does (mapping.pipeline.build_map).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from geometry.errors import InputError
from geometry.polyline import densify, distances_to_polyline
from mapping.evaluate import MIN_COVERAGE, false_safe, truth_class
from mapping.fusion import METAL_CLASSES
from mapping.map_object import MapObject
from mapping.mapfile import parse_object
from mapping.pipeline import MapResult, build_map
from mapping.simscan import simulate_scan
from scanner.hard_walls import hard_case_wall
from scanner.sensor_model import points_in_polygon
from scanner.wall import FORMAT, Wall, WallObject, wall_from_dict

ON_M = 0.02  # a mapped object within 2 cm of a true centre line lies on it (10 σ of the 2 mm position σ)
STEP_M = 0.005  # true centre lines and mapped geometry are probed every 5 mm
HEIGHT_M = 1.2
# hard-case walls with a water-filled plastic pipe: vertical beside steel studs (drywall), an L (brick),
# vertical beside wooden studs with screws (drywall), 5 cm deep beside shallow copper pipes (aerated concrete)
HARD_WALLS = (3, 9, 11, 23)


def _rect(x0: float, x1: float) -> list[list[float]]:
    return [[x0, 0.0], [x1, 0.0], [x1, HEIGHT_M], [x0, HEIGHT_M]]


def _classes_wall() -> Wall:
    """Every class side by side on drywall, 15-30 cm apart, and a water pipe across the cable and the copper
    pipe (the crossings must not make it metal)."""
    objects: list[dict] = [
        {"kind": "cable", "id": "live-cable", "points_m": [[0.15, 0.0], [0.15, HEIGHT_M]], "depth_m": 0.02},
        {"kind": "pipe", "id": "copper-pipe", "points_m": [[0.45, 0.0], [0.45, HEIGHT_M]], "depth_m": 0.025,
         "material": "copper", "diameter_m": 0.015},
        {"kind": "stud", "id": "wood-stud", "outline_m": _rect(0.70, 0.755), "depth_m": 0.0125, "material": "wood"},
        {"kind": "pipe", "id": "water-pipe", "points_m": [[1.0, 0.0], [1.0, HEIGHT_M]], "depth_m": 0.025,
         "material": "plastic", "diameter_m": 0.02, "water_filled": True},
        {"kind": "stud", "id": "steel-stud", "outline_m": _rect(1.25, 1.30), "depth_m": 0.0125, "material": "steel"},
        {"kind": "pipe", "id": "water-pipe-across", "points_m": [[0.05, 1.0], [0.6, 1.0]], "depth_m": 0.03,
         "material": "plastic", "diameter_m": 0.02, "water_filled": True},
    ]
    # the boards' screws on the studs' centre lines
    objects += [{"kind": "screw", "id": f"wood-screw-{k}", "points_m": [[0.7275, y]], "depth_m": 0.004}
                for k, y in enumerate((0.15, 0.5, 0.85))]
    objects += [{"kind": "screw", "id": f"steel-screw-{k}", "points_m": [[1.275, y]], "depth_m": 0.004}
                for k, y in enumerate((0.3, 0.7))]
    return wall_from_dict({"format": FORMAT, "name": "classes", "width_m": 1.6, "height_m": HEIGHT_M,
                           "material": "drywall", "objects": objects})


@dataclass(frozen=True)
class Mapped:
    wall: Wall
    result: MapResult

    def of(self, predicate) -> list[WallObject]:
        return [o for o in self.wall.objects if predicate(o)]


@functools.cache
def _mapped(which: str | int) -> Mapped:
    """The wall ("classes" or a hard-case index), its dense scan and its map, built once per test session."""
    wall = _classes_wall() if which == "classes" else hard_case_wall(int(which))
    seed = 11 if which == "classes" else int(which)
    return Mapped(wall, build_map(simulate_scan(wall, seed=seed, sample_step_m=0.002)))


@pytest.fixture(params=("classes", *HARD_WALLS), ids=["classes-wall", *(f"hard-{i:02d}" for i in HARD_WALLS)])
def mapped(request) -> Mapped:
    return _mapped(request.param)


@pytest.fixture
def classes_wall() -> Mapped:
    return _mapped("classes")


@pytest.fixture
def hard_11() -> Mapped:
    return _mapped(11)


def _water_pipe(o: WallObject) -> bool:
    return o.kind == "pipe" and not o.is_metal and bool(o.water_filled)


def _centre_line(stud: WallObject) -> NDArray[np.float64]:
    """Probe points along a full-height stud's centre line, 5 % short of either end."""
    ring = np.asarray(stud.outline_m, dtype=np.float64)
    x = float(ring[:, 0].mean())
    y0, y1 = float(ring[:, 1].min()), float(ring[:, 1].max())
    margin = 0.05 * (y1 - y0)
    return densify(np.array([[x, y0 + margin], [x, y1 - margin]]), STEP_M)


def _share_along(probe: NDArray[np.float64], objects: list[MapObject]) -> float:
    """Share of probe points within ON_M of a line's centre line or inside an outline of objects."""
    hit = np.zeros(len(probe), bool)
    for o in objects:
        if o.kind == "outline":
            hit |= points_in_polygon(probe, o.points_m)
        elif len(o.points_m) > 1:
            hit |= distances_to_polyline(probe, o.points_m) <= ON_M
    return float(hit.mean())


def _lies_on(obj: MapObject, truth: NDArray[np.float64]) -> bool:
    """Whether a mapped object lies on a true centre line: an outline holding part of it, a line or point most
    of whose geometry lies within ON_M of it."""
    probe = densify(truth, STEP_M)
    if obj.kind == "outline":
        return bool(points_in_polygon(probe, obj.points_m).mean() > 0.1)
    pts = densify(obj.points_m, STEP_M) if len(obj.points_m) > 1 else obj.points_m
    return bool((distances_to_polyline(pts, truth) <= ON_M).mean() > 0.5)


# ---- the capacitive-only object: a water-filled plastic pipe ------------------------------------------------

def test_a_water_filled_plastic_pipe_is_one_non_metal_line(mapped):
    pipes = mapped.of(_water_pipe)
    assert pipes
    lines = [o for o in mapped.result.objects if o.kind == "line" and o.cls == "non_metal"]
    for pipe in pipes:
        truth = np.asarray(pipe.points_m, dtype=np.float64)
        # found as evaluate() finds a pipe: 70 % of its centre line within reach of mapped lines of its class
        along = _share_along(densify(truth, STEP_M), lines)
        assert along >= MIN_COVERAGE, (pipe.id, along)
        on = [o for o in mapped.result.objects if _lies_on(o, truth)]
        # no channel that sees metal responds there: nothing on it is metal, and it is a line, not areas
        assert not [o.cls for o in on if o.cls in METAL_CLASSES], pipe.id
        assert all(o.kind == "line" and o.cls == "non_metal" for o in on), [(o.kind, o.cls) for o in on]
        assert truth_class(pipe) == "non_metal"


def test_what_the_inductive_channel_sees_is_never_non_metal(mapped):
    metal = mapped.of(lambda o: o.kind == "cable" or (o.kind == "pipe" and o.is_metal))
    for obj in mapped.result.objects:
        if obj.kind != "line":
            continue
        for truth in metal:
            if _lies_on(obj, np.asarray(truth.points_m, dtype=np.float64)):
                assert obj.cls in METAL_CLASSES, (truth.id, obj.cls, obj.features)


def test_non_metal_objects_lie_on_wood_or_water(mapped):
    """No non-metal object where there is no wood and no water (a metal pipe's capacitive echo, say)."""
    wood_or_water = mapped.of(lambda o: truth_class(o) == "non_metal")
    for obj in (o for o in mapped.result.objects if o.cls == "non_metal"):
        probe = densify(obj.points_m, STEP_M)
        on_wood_or_water = False
        for truth in wood_or_water:
            geometry = np.asarray(truth.geometry_m, dtype=np.float64)
            if truth.kind == "pipe":
                on_wood_or_water |= bool((distances_to_polyline(probe, geometry) <= ON_M).mean() > 0.5)
            else:  # the outline of a stud's half-maximum signal: up to a footprint σ (2.3 cm) beyond its edge
                ring = np.vstack([geometry, geometry[:1]])
                near = points_in_polygon(probe, geometry) | (distances_to_polyline(probe, ring) <= 0.025)
                on_wood_or_water |= bool(near.mean() > 0.9)
        assert on_wood_or_water, (obj.kind, np.round(obj.points_m, 3).tolist())


def test_the_drill_check_calls_no_hazard_safe(mapped):
    result = mapped.result
    safe = false_safe(result.mapped_objects(), result.coverage, mapped.wall)
    assert set(safe.probed_m) >= {o.id for o in mapped.of(_water_pipe)}
    assert safe.share == 0.0, safe.worst()


# ---- studs --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("wall_fixture", ["classes_wall", "hard_11"])
def test_a_wooden_stud_is_one_non_metal_outline(request, wall_fixture):
    m = request.getfixturevalue(wall_fixture)
    studs = m.of(lambda o: o.kind == "stud" and o.material == "wood")
    assert studs
    for stud in studs:
        probe = _centre_line(stud)
        outlines = [o for o in m.result.objects if o.kind == "outline" and o.cls == "non_metal"]
        # one outline along it, not pieces cut out around its screws (they do not show capacitively)
        holding = [o for o in outlines if points_in_polygon(probe, o.points_m).mean() > 0.1]
        assert len(holding) == 1, (stud.id, len(holding))
        assert _share_along(probe, holding) >= 0.9, stud.id
        metal = [o for o in m.result.objects if o.cls in ("metal", "metal_pipe", "power_line") and o.kind != "point"]
        assert _share_along(probe, metal) == 0.0, stud.id  # its screws are fasteners (points), the stud is no metal


def test_a_steel_stud_is_metal_not_a_pipe(classes_wall):
    stud = classes_wall.wall.by_id("steel-stud")
    probe = _centre_line(stud)
    over = [o for o in classes_wall.result.objects if o.kind != "point" and _share_along(probe, [o]) > 0.1]
    assert over and all(o.cls == "metal" for o in over), [(o.kind, o.cls) for o in over]
    assert _share_along(probe, over) >= 0.9
    assert truth_class(stud) == "metal"


@pytest.mark.parametrize(("object_id", "cls"), [("copper-pipe", "metal_pipe"), ("live-cable", "power_line")])
def test_metal_lines_keep_their_classes(classes_wall, object_id, cls):
    truth = classes_wall.wall.by_id(object_id)
    lines = [o for o in classes_wall.result.objects if o.kind == "line" and o.cls == cls]
    assert _share_along(densify(truth.points_m, STEP_M), lines) >= MIN_COVERAGE
    assert truth_class(truth) == cls


# ---- names: the truth's and old files' -------------------------------------------------------------------------

def test_truth_classes_say_what_the_channels_can_tell():
    def pipe(material: str, water: bool) -> WallObject:
        return WallObject("pipe", "p", 0.02, points_m=np.array([[0.0, 0.0], [0.0, 1.0]]), material=material,
                          diameter_m=0.02, water_filled=water)

    assert truth_class(pipe("plastic", True)) == "non_metal"
    assert truth_class(pipe("plastic", False)) == "plastic_pipe"  # no channel sees it: no mapped class
    assert truth_class(pipe("copper", True)) == "metal_pipe"
    ring = np.array([[0.0, 0.0], [0.05, 0.0], [0.05, 1.0], [0.0, 1.0]])
    assert truth_class(WallObject("stud", "s", 0.0125, outline_m=ring, material="wood")) == "non_metal"
    assert truth_class(WallObject("stud", "s", 0.0125, outline_m=ring, material="steel")) == "metal"


def test_old_wood_objects_read_as_non_metal_outlines():
    ring = [[0.6, 0.0], [0.65, 0.0], [0.65, 2.0], [0.6, 2.0]]
    for item in ({"class": "wood", "points_m": ring, "width_m": 0.05},  # format 1: no kind
                 {"class": "wood", "kind": "outline", "points_m": ring, "width_m": 0.05}):
        obj = parse_object(item, "objects.json: objects[0]")
        assert obj.cls == "non_metal" and obj.is_outline
    # a non-metal line (a water pipe) without a stated kind stays a line unless its points close a ring
    bent = parse_object({"class": "non_metal", "points_m": [[0.0, 0.0], [0.5, 0.0], [0.5, 1.0]], "width_m": 0.06},
                        "objects[1]")
    assert bent.shape == "line"
    closed = parse_object({"class": "non_metal", "points_m": [*ring, ring[0]], "width_m": 0.05}, "objects[2]")
    assert closed.is_outline
    with pytest.raises(InputError, match="class 'timber' is unknown"):
        parse_object({"class": "timber", "points_m": ring, "width_m": 0.05}, "objects[3]")
