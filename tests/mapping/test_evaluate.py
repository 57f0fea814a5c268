"""Scoring a map against the wall's truth: recall counted on measured stretches only, pipes labelled wood."""

from __future__ import annotations

import numpy as np
import pytest

from mapping.evaluate import evaluate, evaluate_measured, pipes_labelled_wood
from mapping.map_object import MapObject
from mapping.mapfile import MappedObject
from scanner.wall import Wall, wall_from_dict

CABLE = [[0.3, 0.0], [0.3, 1.0]]
PIPE = [[0.5, 0.5], [0.9, 0.5]]
WATER = [[0.8, 0.0], [0.8, 0.4]]


@pytest.fixture(scope="module")
def wall() -> Wall:
    return wall_from_dict({"format": "arproj-wall/1", "name": "tiny", "width_m": 1.0, "height_m": 1.0,
                           "material": "drywall", "objects": [
                               {"kind": "cable", "id": "cable", "points_m": CABLE, "depth_m": 0.02},
                               {"kind": "pipe", "id": "pipe", "points_m": PIPE, "depth_m": 0.02,
                                "material": "copper", "diameter_m": 0.015},
                               {"kind": "pipe", "id": "water", "points_m": WATER, "depth_m": 0.02,
                                "material": "plastic", "diameter_m": 0.02, "water_filled": True}]}, "test")


def _line(points: list[list[float]], n: int = 11) -> np.ndarray:
    """n points evenly along a straight line (n - 1 segments), offset 3 mm: a map never lies on the truth."""
    a, b = np.asarray(points, dtype=np.float64)
    return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a) + 0.003


def _mapped(cable_measured: np.ndarray | None) -> list[MappedObject]:
    return [MappedObject("power_line", _line(CABLE), 0.008, measured=cable_measured),
            MappedObject("metal_pipe", _line(PIPE), 0.015)]


def _plain(objects: list[MappedObject]) -> list[MapObject]:
    return [MapObject("line", o.points_m, o.width_m, cls=o.cls) for o in objects]


def test_measured_recall_equals_plain_recall_when_nothing_is_inferred(wall):
    mapped = _mapped(None)
    measured, plain = evaluate_measured(mapped, wall), evaluate(_plain(mapped), wall)
    assert (measured.n_found, measured.n_targets) == (plain.n_found, plain.n_targets) == (2, 2)
    assert measured.class_pairs == plain.class_pairs


def test_a_target_joined_across_unmeasured_ground_is_not_found_as_measured(wall):
    flags = np.ones(10, bool)
    flags[3:7] = False  # 40 % of the cable inferred: 60 % measured, under the 70 % a target needs
    mapped = _mapped(flags)
    measured, plain = evaluate_measured(mapped, wall), evaluate(_plain(mapped), wall)
    assert plain.n_found == 2
    assert measured.n_found == 1 and measured.missed == ["cable"]
    assert measured.recall < plain.recall
    flags = np.ones(10, bool)
    flags[[0, 9]] = False  # 20 % inferred: still found
    assert evaluate_measured(_mapped(flags), wall).n_found == 2


def test_pipes_labelled_wood(wall):
    honest = [MapObject("line", _line(CABLE), 0.008, cls="power_line"),
              MapObject("line", _line(PIPE), 0.015, cls="metal_pipe"),
              MapObject("line", _line(WATER), 0.02, cls="non_metal")]  # what the capacitive channel can tell
    # a wooden stud's outline the cable crosses covers 5 cm of it: the cable is still a power line
    stud = MapObject("outline", np.array([[0.0, 0.2], [1.0, 0.2], [1.0, 0.25], [0.0, 0.25]]), 0.05, cls="non_metal")
    assert pipes_labelled_wood([*honest, stud], wall) == []
    cable_as_non_metal = MapObject("line", _line(CABLE), 0.008, cls="non_metal")
    assert pipes_labelled_wood([cable_as_non_metal, *honest[1:]], wall) == ["cable"]
    water_as_stud = MapObject("outline", np.array([[0.78, 0.0], [0.82, 0.0], [0.82, 0.4], [0.78, 0.4]]), 0.04,
                              cls="non_metal")
    assert pipes_labelled_wood([*honest[:2], water_as_stud], wall) == ["water"]


def test_every_object_is_scored_and_a_screw_mapped_as_a_power_line_is_a_wrong_class() -> None:
    """object_scores lists every class of the wall: fasteners, studs, a dry plastic pipe (invisible), and calls
    a find of another class a wrong class, not a find."""
    from mapping.evaluate import class_summary, object_scores, unmatched_objects

    wall = wall_from_dict({"format": "arproj-wall/1", "name": "all", "width_m": 1.0, "height_m": 1.0,
                           "material": "drywall", "objects": [
                               {"kind": "cable", "id": "cable", "points_m": CABLE, "depth_m": 0.02},
                               {"kind": "screw", "id": "screw", "points_m": [[0.7, 0.8]], "depth_m": 0.01},
                               {"kind": "nail", "id": "nail", "points_m": [[0.1, 0.1]], "depth_m": 0.01},
                               {"kind": "stud", "id": "stud", "outline_m": [[0.45, 0.0], [0.5, 0.0], [0.5, 1.0],
                                                                           [0.45, 1.0]], "material": "wood",
                                "depth_m": 0.01},
                               {"kind": "pipe", "id": "dry", "points_m": [[0.0, 0.3], [1.0, 0.3]],
                                "depth_m": 0.02, "material": "plastic", "diameter_m": 0.02,
                                "water_filled": False}]}, "test")
    objects = [MapObject("line", _line(CABLE), 0.008, cls="power_line"),
               MapObject("line", np.array([[0.68, 0.8], [0.72, 0.8]]), 0.008, cls="power_line"),
               MapObject("line", np.array([[0.475, 0.05], [0.475, 0.95]]), 0.05, cls="non_metal"),
               MapObject("point", np.array([[0.9, 0.9]]), 0.004, cls="fastener")]
    scores = {s.id: s for s in object_scores(objects, wall)}
    assert (scores["cable"].verdict, scores["cable"].mapped_class) == ("found", "power_line")
    assert (scores["screw"].verdict, scores["screw"].mapped_class) == ("wrong class", "power_line")
    assert scores["nail"].verdict == "missed" and scores["stud"].verdict == "found"
    assert scores["dry"].verdict == "invisible"
    summary = class_summary(list(scores.values()))
    assert summary["fastener"] == {"objects": 2, "found": 0, "wrong class": 1, "missed": 1, "invisible": 0}
    assert [o.cls for o in unmatched_objects(objects, wall)] == ["fastener"]  # the one at (0.9, 0.9)
