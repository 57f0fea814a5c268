"""A one-frame wall with every kind of hazard (a live and a dead cable, a copper pipe, a water-filled plastic
pipe that only the capacitive channel sees, a screw), scanned densely and mapped once per test process: the drill
check's and the drill-verdict exports' tests read it."""

from __future__ import annotations

import functools

from mapping.mapfile import MappedObject
from mapping.pipeline import MapResult, MapSettings, build_map
from mapping.simscan import simulate_scan
from scanner.wall import Wall, wall_from_dict

WALL = {
    "format": "arproj-wall/1", "name": "drill test wall", "width_m": 0.35, "height_m": 0.40, "material": "brick",
    "objects": [
        {"kind": "cable", "id": "live", "points_m": [[0.08, 0.0], [0.08, 0.40]], "depth_m": 0.02, "live": True},
        {"kind": "cable", "id": "dead", "points_m": [[0.0, 0.30], [0.35, 0.30]], "depth_m": 0.02, "live": False},
        {"kind": "pipe", "id": "copper", "points_m": [[0.0, 0.12], [0.35, 0.12]], "depth_m": 0.03,
         "material": "copper", "diameter_m": 0.015},
        {"kind": "pipe", "id": "water", "points_m": [[0.24, 0.0], [0.24, 0.40]], "depth_m": 0.025,
         "material": "plastic", "diameter_m": 0.02, "water_filled": True},
        {"kind": "screw", "id": "screw", "points_m": [[0.16, 0.21]], "depth_m": 0.005},
    ]}
CLEAR_SPOT = (0.16, 0.05)  # 8 cm from the live cable, the water pipe and the copper pipe: nothing there


@functools.cache
def hazard_wall() -> Wall:
    return wall_from_dict(WALL, "drill test wall")


@functools.cache
def hazard_wall_dense_map() -> tuple[MapResult, list[MappedObject]]:
    """The wall scanned with no robot placement error (the 1 cm raster covers it from its lower edge up), mapped."""
    data = simulate_scan(hazard_wall(), seed=4, robot_sigma=(0.0, 0.0, 0.0), loc_sigma=(1e-4, 1e-4, 1e-5))
    result = build_map(data, MapSettings(stitch=False))
    return result, result.mapped_objects()
