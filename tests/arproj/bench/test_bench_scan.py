"""bench scan's scores on one small hard-case wall: recall as measured stretches beside plain recall, and the
headline figures issues 15 and 16 ask for."""

from __future__ import annotations

import json

import pytest

from arproj.bench import BenchTable
from arproj.bench.scan import COLUMNS, PLANS, PlanStats, _headline, _row, _score
from arproj.run.scan import scan_and_map
from mapping.evaluate import evaluate, evaluate_measured
from scanner.wall import Wall, wall_from_dict

NEW_HEADLINES = ("recall of pipes and cables as measured stretches (adaptive)", "recall of fasteners (adaptive)",
                 "recall of studs, plates (socket boxes), cavities (adaptive)", "depth error mean (adaptive)",
                 "pipes and cables labelled wood (adaptive)")


@pytest.fixture(scope="module")
def small_wall() -> Wall:
    # hard cases on 1 m × 1 m: a pipe bending by 90° between coarse rows, a cable with a 45° offset crossing
    # it, a cable ending at a socket box, a wooden stud with screws (drywall)
    return wall_from_dict({"format": "arproj-wall/1", "name": "small hard cases", "width_m": 1.0, "height_m": 1.0,
                           "material": "drywall", "objects": [
                               {"kind": "pipe", "id": "L", "points_m": [[0.12, 1.0], [0.12, 0.37], [0.6, 0.37]],
                                "depth_m": 0.02, "material": "copper", "diameter_m": 0.015},
                               {"kind": "cable", "id": "offset", "depth_m": 0.015, "live": True,
                                "points_m": [[0.5, 0.0], [0.5, 0.55], [0.6, 0.65], [0.6, 1.0]]},
                               {"kind": "cable", "id": "to-box", "depth_m": 0.02, "live": True,
                                "points_m": [[0.3, 1.0], [0.3, 0.78]]},
                               {"kind": "plate", "id": "box", "depth_m": 0.02, "material": "steel",
                                "thickness_m": 0.001,
                                "outline_m": [[0.27, 0.72], [0.33, 0.72], [0.33, 0.78], [0.27, 0.78]]},
                               {"kind": "stud", "id": "stud", "depth_m": 0.0125, "material": "wood",
                                "outline_m": [[0.8, 0.0], [0.85, 0.0], [0.85, 1.0], [0.8, 1.0]]},
                               {"kind": "screw", "id": "screw-1", "points_m": [[0.825, 0.3]], "depth_m": 0.004},
                               {"kind": "screw", "id": "screw-2", "points_m": [[0.825, 0.65]], "depth_m": 0.004}]},
                          "test")


@pytest.fixture(scope="module")
def scored(small_wall: Wall):
    scan, result = scan_and_map(small_wall, "adaptive", 3)
    stats = PlanStats()
    _score(stats, small_wall, scan, result)
    return result, stats


def test_recall_as_measured_stretches_is_at_most_plain_and_the_same_without_inferred_stretches(scored, small_wall):
    result, stats = scored
    assert (stats.targets, stats.fasteners, stats.areas) == (3, 2, 2)
    assert stats.measured_found <= stats.found
    # the same matching: with every stretch taken as measured it finds exactly what evaluate() finds
    mapped = result.mapped_objects()
    for obj in mapped:
        obj.measured = None
    plain, as_measured = evaluate(result.objects, small_wall), evaluate_measured(mapped, small_wall)
    assert (as_measured.n_found, as_measured.missed) == (plain.n_found, plain.missed)


def test_the_headline_and_the_table_carry_the_new_figures(scored):
    _, stats = scored
    table = BenchTable("scan", "test", COLUMNS, [_row("small: adaptive", stats)],
                       headline=_headline({(name, plan): stats for name in ("hard-case", "random") for plan in PLANS}))
    assert len(table.rows[0]) == len(COLUMNS)
    headline = json.loads(table.to_json())["headline"]
    for key in NEW_HEADLINES:
        assert {"arproj", "peer", "peer_name", "unit", "target", "met"} <= set(headline[key]), key
    assert headline[NEW_HEADLINES[0]]["arproj"] == round(stats.measured_recall, 3)
    assert headline[NEW_HEADLINES[1]]["arproj"] == round(stats.fastener_recall, 3)
    assert headline[NEW_HEADLINES[2]]["arproj"] == round(stats.area_recall, 3)
    assert headline[NEW_HEADLINES[3]]["arproj"] == round(stats.depth_mm, 2)
    assert headline[NEW_HEADLINES[4]]["arproj"] == len(stats.as_wood)
    assert "false-safe length (adaptive)" in headline and "scan time, random walls (adaptive / dense)" in headline
