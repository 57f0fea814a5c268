"""`arproj project --sim --room room.glb`: the room session from the command line hands over from wall 0 to the
wall across the corner as the --follow points move onto it, each wall judged and shown; a room.glb of another
room, an unknown wall or a second map are refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from arproj.cli import app
from arproj.session.wallmap import plane_mesh
from arproj.sim.site import Site, shared_context
from geometry.poses import make_pose, transform_points
from mapping.exports.glb import AtlasWall, write_room_glb

SIDE = 3  # the simulated room's wall meeting wall 0 at wall 0's x = 0 (at its own far end)


def _room_glb(path: Path, shift_m: float = 0.0) -> Path:
    """room.glb of the simulated room's walls 0 and SIDE (flat, each its own colour), wall 0 moved shift_m out
    of its plane (a room.glb of another room)."""
    with Site.build(seed=0, ctx=shared_context()) as site:
        parts, walls = [], []
        for k, i in enumerate((0, SIDE)):
            w = site.walls[i]
            T = w.T_room_from_wall @ make_pose(None, [0.0, 0.0, shift_m if i == 0 else 0.0])
            plane = plane_mesh(0.0, 0.0, w.width_m, w.height_m).subdivide().subdivide()
            parts.append(trimesh.Trimesh(transform_points(T, plane.vertices), plane.faces))
            texture = np.zeros((40, int(40 * w.width_m / w.height_m), 4), np.uint8)
            texture[..., k], texture[..., 3] = 200, 255
            walls.append(AtlasWall(i, T, texture, (0.0, 0.0, w.width_m, w.height_m), (w.width_m, w.height_m)))
    return write_room_glb(path, trimesh.util.concatenate(parts), walls)


@pytest.fixture(scope="module")
def room_glb(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _room_glb(tmp_path_factory.mktemp("room") / "room.glb")


def test_project_room_hands_over_across_the_corner(room_glb: Path) -> None:
    done = CliRunner().invoke(app, ["project", "--sim", "--room", str(room_glb), "--distance", "2", "--incidence",
                                    "30", "--follow", f"0:1.0,1.2;{SIDE}:3.0,1.2", "--json"])
    assert done.exit_code == 0, done.output
    result = json.loads(done.output[done.output.index("{"):])
    first, second = result["cycles"]
    assert first["registered_on"] == 0 and second["registered_on"] == SIDE
    for cycle in (first, second):
        assert set(cycle["walls"]) == {"0", str(SIDE)} and cycle["show_map"]
        # the wall registered on is shown; the other is judged by its own bound (from the pose's full
        # covariance, which at 2 m / 30° may just exceed the tolerance far round the corner) and never shown
        # beyond it
        assert cycle["walls"][str(cycle["registered_on"])]["shown"], cycle
        assert all(not w["shown"] or w["bound_mm"] < 10 for w in cycle["walls"].values()), cycle
        assert all(w["shown"] or w["reasons"] for w in cycle["walls"].values()), cycle
    assert any(line.startswith(f"handover: registering on wall {SIDE}") for line in result["log"])


@pytest.mark.parametrize("extra, says", [
    (["--map", "wall.glb"], "not with --map"),
    (["--follow", "9:1.0,1.0"], "room.glb has no wall 9"),
    (["--aim", "1.0;1.0"], "is not K:X,Y"),
])
def test_project_room_refuses_bad_input_in_one_line(room_glb: Path, extra: list[str], says: str) -> None:
    from geometry.errors import InputError

    done = CliRunner().invoke(app, ["project", "--sim", "--room", str(room_glb), *extra])
    assert isinstance(done.exception, InputError) and says in str(done.exception), done.output


def test_project_room_refuses_a_room_glb_of_another_room(tmp_path: Path) -> None:
    from geometry.errors import InputError

    done = CliRunner().invoke(app, ["project", "--sim", "--room", str(_room_glb(tmp_path / "r.glb", 0.2))])
    assert isinstance(done.exception, InputError) and "made in another room" in str(done.exception), done.output
