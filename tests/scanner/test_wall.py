"""Wall description files: round trips, shipped walls, strict validation, random walls."""

import json

import numpy as np
import pytest

from geometry.errors import InputError
from geometry.polyline import distances_to_polyline
from scanner.wall import load_wall, random_wall, save_wall, shipped_walls


def test_shipped_walls_load_and_include_the_paper_plate():
    walls = shipped_walls()
    assert {"paper_test_plate", "small_test_wall", "drywall_studs", "demo_brick_wall"} <= set(walls)
    plate = load_wall(walls["paper_test_plate"])
    assert plate.width_m == 1.8 and plate.material == "wood"
    pipe45 = plate.by_id("pipe-45deg")
    direction = np.diff(pipe45.points_m, axis=0)[0]
    assert np.degrees(np.arctan2(direction[1], direction[0])) == pytest.approx(45.0)
    assert plate.by_id("extension-cord").live is True


def test_yaml_and_json_round_trip_keep_the_fingerprint(tmp_path):
    wall = random_wall(3)
    save_wall(wall, tmp_path / "w.yaml")
    save_wall(wall, tmp_path / "w.json")
    a, b = load_wall(tmp_path / "w.yaml"), load_wall(tmp_path / "w.json")
    assert a.fingerprint() == b.fingerprint() == wall.fingerprint()
    assert len(a.objects) == len(wall.objects)
    for o1, o2 in zip(a.objects, wall.objects, strict=True):
        np.testing.assert_allclose(o1.geometry_m, o2.geometry_m, atol=1e-6)  # wall files store 1 µm (6 decimals)
    assert random_wall(4).fingerprint() != wall.fingerprint()


def _write(tmp_path, content):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    return path


BASE = {"format": "arproj-wall/1", "width_m": 1.0, "height_m": 1.0, "material": "brick", "objects": []}


@pytest.mark.parametrize(("change", "expected"), [
    ({"width_m": -1}, "width_m = -1"),
    ({"material": "cheese"}, "material = 'cheese'"),
    ({"format": "v0"}, "format = 'v0'"),
    ({"colour": "red"}, "colour"),
    ({"objects": [{"kind": "pipe", "id": "p", "points_m": [[0, 0], [1, 1]], "depth_m": 0.02,
                   "diameter_m": 0.01}]}, "objects[0] (id p).material"),
    ({"objects": [{"kind": "pipe", "id": "p", "points_m": [[0, 0], [2, 1]], "depth_m": 0.02,
                   "diameter_m": 0.01, "material": "copper"}]}, "outside the wall"),
    ({"objects": [{"kind": "cable", "id": "c", "points_m": [[0, 0], [1, 1]], "depth_m": "deep"}]},
     "objects[0] (id c).depth_m = 'deep'"),
    ({"objects": [{"kind": "screw", "id": "s", "points_m": [[0.1, 0.1], [0.2, 0.2]], "depth_m": 0.01}]},
     "exactly 1 point"),
    ({"objects": [{"kind": "plate", "id": "x", "points_m": [[0.1, 0.1]], "depth_m": 0.01}]}, "outline_m"),
    ({"objects": [{"kind": "wormhole", "id": "w", "depth_m": 0.01}]}, "objects[0].kind = 'wormhole'"),
    ({"objects": [{"kind": "cable", "id": "c", "points_m": [[0, 0], [1, 1]], "depth_m": 0.01, "live": "yes"}]},
     "live = 'yes'"),
    ({"objects": [{"kind": "cable", "id": "c", "points_m": [[0, 0], [1, 1]], "depth_m": 0.01},
                  {"kind": "cable", "id": "c", "points_m": [[0, 0], [1, 0]], "depth_m": 0.01}]}, "used twice"),
])
def test_malformed_walls_name_file_field_and_value(tmp_path, change, expected):
    path = _write(tmp_path, {**BASE, **change})
    with pytest.raises(InputError) as err:
        load_wall(path)
    assert str(path) in str(err.value)
    assert expected in str(err.value)


def test_unparsable_and_missing_files(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("width_m: [1,\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_wall(bad)
    with pytest.raises(InputError, match="no such wall file"):
        load_wall(tmp_path / "nope.yaml")


def test_random_walls_are_plausible_and_reproducible():
    for seed in range(25):
        wall = random_wall(seed)
        assert wall.fingerprint() == random_wall(seed).fingerprint()
        targets = wall.targets()
        assert len(targets) >= 5
        # distinct objects: no two pipe/cable runs stay within 8 cm of each other over a long stretch
        for i, a in enumerate(targets):
            for b in targets[i + 1:]:
                from geometry.polyline import densify
                close = distances_to_polyline(densify(a.points_m, 0.02), b.points_m) < 0.08
                assert close.sum() * 0.02 <= 0.2 + 1e-9, (seed, a.id, b.id)
