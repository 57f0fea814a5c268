"""`arproj map --range-images` writes room.glb when the range images see another wall beside the mapped one (a
room corner), and only then: the mapped wall's faces carry its map, the other wall's and the floor's are dark
(simulated site, truth known)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from arproj.cli import app
from arproj.sim.site import Site, shared_context
from geometry.intrinsics import Intrinsics
from geometry.poses import look_at, transform_points
from mapping.simscan import simulate_scan, write_log
from scanner.wall import load_wall, shipped_walls

WALL = "small_test_wall"


def _range_views(path: Path, looks: list[tuple[list[float], list[float]]]) -> tuple[Path, Site]:
    """Range images of the simulated site (seed 0) from eyes at targets given in wall 0's frame, saved as
    `arproj map --range-images` reads them (T_world_from_wall: wall 0's frame in the room)."""
    site = Site.build(seed=0, ctx=shared_context())
    T_room_from_wall = site.walls[0].T_room_from_wall
    arrays: dict[str, np.ndarray] = {"T_world_from_wall": T_room_from_wall}
    intr = Intrinsics.from_fov(120, 90, 60.0)
    for k, (eye_w, target_w) in enumerate(looks):
        eye, target = transform_points(T_room_from_wall, [eye_w, target_w])
        T_room_from_cam = look_at(eye, target, up=[0.0, 0.0, 1.0])
        image = site.range_image(T_room_from_cam, intr)
        arrays |= {f"depth_{k}": np.asarray(image.depth, dtype=np.float64), f"K_{k}": image.intr.K,
                   f"T_world_from_camera_{k}": T_room_from_cam}
    np.savez(path, **arrays)
    return path, site


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("room_map")
    return write_log(simulate_scan(load_wall(shipped_walls()[WALL]), seed=2), root / "scan.sqlite")


def test_range_images_into_the_corner_give_room_glb_the_other_wall_dark(log: Path, tmp_path: Path) -> None:
    from arproj.session.room import load_room_map

    wall = load_wall(shipped_walls()[WALL])
    cx, cy = wall.width_m / 2, wall.height_m / 2
    # one view on the mapped wall, one into the room corner at its x = 0 (the side wall beside it)
    npz, site = _range_views(tmp_path / "views.npz", [([cx, cy, 1.4], [cx, cy, 0.0]),
                                                      ([0.9, cy, 1.0], [0.0, cy, 0.2])])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            done = CliRunner().invoke(app, ["map", str(log), "--out", str(tmp_path / "m"), "--range-images",
                                            str(npz)])
        assert done.exit_code == 0, done.output
        assert (tmp_path / "m" / "wall.glb").is_file() and "room.glb" in done.output
        room = load_room_map(tmp_path / "m" / "room.glb")
        T_room_from_wall = site.walls[0].T_room_from_wall
        assert len(room.walls) == 1 and np.allclose(room.walls[0].T_room_from_wall, T_room_from_wall)
        mapped = room.walls[0].wall_map
        assert np.abs(np.asarray(mapped.mesh.vertices)[:, 2]).max() < 0.05  # its faces on its own plane
        assert room.other is not None
        # the side wall's measured faces are among the dark ones: room points on the side wall's plane
        corner = transform_points(T_room_from_wall, [[0.0, cy, 0.0]])[0]  # on the corner line at wall 0's x = 0
        side = next(w for w in site.walls[1:]
                    if abs(float(w.T_room_from_wall[:3, 2] @ (corner - w.T_room_from_wall[:3, 3]))) < 1e-6)
        local = transform_points(np.linalg.inv(side.T_room_from_wall), np.asarray(room.other.vertices))
        assert (np.abs(local[:, 2]) < 0.02).sum() > 100
        # beyond the map's bounds the mapped wall's tile is transparent: not scanned, unknown
        tex = mapped.texture
        assert tex is not None and tex[..., 3].min() == 0
    finally:
        site.release()

    # the same wall seen alone: no other wall, no room.glb
    npz, site = _range_views(tmp_path / "alone.npz", [([cx, cy, 1.4], [cx, cy, 0.0])])
    site.release()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        done = CliRunner().invoke(app, ["map", str(log), "--out", str(tmp_path / "alone"), "--range-images",
                                        str(npz)])
    assert done.exit_code == 0, done.output
    assert (tmp_path / "alone" / "wall.glb").is_file() and not (tmp_path / "alone" / "room.glb").exists()
