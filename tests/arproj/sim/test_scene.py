"""Scene configuration: defaults, overrides, and clear errors for bad input."""

from __future__ import annotations

from pathlib import Path

import pytest

from arproj.sim import Site, load_scene
from geometry.errors import InputError


def test_defaults_are_the_documented_typical_site() -> None:
    scene = load_scene()
    assert scene["projector"]["width"] == 1280 and scene["projector"]["height"] == 800
    assert scene["cameras"]["width"] == 1280 and scene["cameras"]["baseline_m"] == pytest.approx(0.2)
    assert len(scene["room"]["corners_m"]) == 4


def test_file_and_overrides_merge(tmp_path: Path) -> None:
    path = tmp_path / "scene.yaml"
    path.write_text("robot:\n  distance_m: 3.0\nprojector:\n  lumens: 1500\n")
    scene = load_scene(path, robot={"incidence_deg": 20})
    assert scene["robot"]["distance_m"] == 3.0
    assert scene["robot"]["incidence_deg"] == 20.0
    assert scene["projector"]["lumens"] == 1500.0
    assert scene["projector"]["throw_ratio"] == 1.3          # untouched default


@pytest.mark.parametrize(("scene", "words"), [
    ({"robot": {"distnce_m": 2.0}}, ["robot.distnce_m", "2.0"]),
    ({"room": {"height_m": -2.6}}, ["room.height_m", "-2.6"]),
    ({"projector": {"width": 0}}, ["projector.width", "0"]),
    ({"cameras": {"hfov_deg": "wide"}}, ["cameras.hfov_deg", "wide"]),
    ({"room": {"wall_texture": "marble"}}, ["room.wall_texture", "marble"]),
    ({"room": {"walls": {7: {"albedo": 0.5}}}}, ["room.walls", "7"]),
    ({"cameras": {"right": {"baseline_m": 0.3}}}, ["cameras.right.baseline_m"]),
    ({"cameras": {"right": {"read_noise_e": -0.5}}}, ["cameras.right.read_noise_e", "-0.5"]),
    ({"cameras": {"prnu": 1.5}}, ["cameras.prnu", "1.5"]),
    ({"cameras": {"msaa_samples": 3}}, ["cameras.msaa_samples", "3"]),
    ({"cameras": {"dist": [0.1, 0.2, 0.3]}}, ["cameras.dist", "3"]),
])
def test_bad_values_name_key_and_value(scene: dict, words: list[str]) -> None:
    with pytest.raises(InputError) as err:
        load_scene(scene)
    for word in words:
        assert word in str(err.value)


def test_missing_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such scene file"):
        load_scene(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot: [unclosed\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_scene(bad)


def test_impossible_geometry_is_refused() -> None:
    # A camera mounted 3 m ahead of the robot ends up in (or beyond) the wall it faces.
    with pytest.raises(InputError, match=r"camera_left .* inside or beyond a wall"):
        Site.build({"cameras": {"position_m": [3.0, 0.1, 1.0]}})
    # Turned round to face the room: the projector's axis leaves the wall it is meant to light.
    with pytest.raises(InputError, match="projector faces away"):
        Site.build({"robot": {"head_deg": [0.0, 59.0, 0.0]}})
    # Too far from the wall for this room: the robot would stand outside.
    with pytest.raises(InputError, match="distance_m = 6"):
        Site.build({"robot": {"distance_m": 6.0}})
