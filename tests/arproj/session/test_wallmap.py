"""Loading the mapping's exports (wall.glb + objects.json + coverage.npz) and the bad-input messages."""

import json

import numpy as np
import pytest
import trimesh
from PIL import Image

from arproj.session import overlays
from arproj.session.wallmap import load_wall_map, plane_mesh, wall_map_from_wall_file
from geometry.errors import InputError
from mapping.evidence import Coverage
from mapping.grid import GridInfo
from scanner.wall import shipped_walls


def _write_glb(path, width=2.0, height=1.5, scanned_right_half=True):
    """A wall mesh textured in wall coordinates (uv = x/W, y/H) whose left half is unscanned (alpha 0)."""
    mesh = plane_mesh(0.0, 0.0, width, height)
    texture = np.zeros((60, 80, 4), np.uint8)
    texture[..., :3] = 120
    texture[:, 40:, 3] = 255
    if not scanned_right_half:
        texture[..., 3] = 255
    uv = mesh.vertices[:, :2] / [width, height]
    material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(texture, "RGBA"))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    mesh.export(path)
    coverage = Coverage.complete(GridInfo.covering(0.0, 0.0, width, height, 0.004))
    xs, _ = coverage.info.cell_centres()
    for layer in coverage.covered.values():
        layer[:, xs < (width / 2 if scanned_right_half else 0.0)] = False
    coverage.save(path.with_name("coverage.npz"))


def test_glb_objects_and_coverage_load_and_judge_points(tmp_path):
    _write_glb(tmp_path / "wall.glb")
    (tmp_path / "objects.json").write_text(json.dumps({"objects": [
        {"class": "power_line", "points_m": [[1.5, 0.0], [1.5, 1.5]], "width_m": 0.01, "confidence": 0.5},
        {"class": "cavity", "points_m": [[1.6, 0.2], [1.9, 0.2], [1.9, 0.6], [1.6, 0.6]], "width_m": 0.0,
         "confidence": 0.9, "position_sigma_m": 0.004}]}))
    wm = load_wall_map(tmp_path / "wall.glb")
    assert wm.extent == pytest.approx((0.0, 0.0, 2.0, 1.5))
    assert wm.uv_from_xy == pytest.approx(np.array([[0.5, 0, 0], [0, 1 / 1.5, 0]]), abs=1e-6)
    assert [o.cls for o in wm.objects] == ["power_line", "cavity"]
    assert wm.objects[0].sigma_m == pytest.approx(0.006)  # 3 mm default / confidence 0.5
    assert wm.objects[1].sigma_m == pytest.approx(0.004) and wm.objects[1].is_outline
    assert overlays.check_drill_point(wm, np.array([1.2, 0.7]), 0.001).verdict == overlays.VERDICT_SAFE
    assert overlays.check_drill_point(wm, np.array([1.5, 0.7]), 0.001).verdict == overlays.VERDICT_KEEP_AWAY
    unscanned = overlays.check_drill_point(wm, np.array([0.5, 0.7]), 0.001)
    assert unscanned.verdict == overlays.VERDICT_UNKNOWN and "not scanned" in unscanned.reason
    outside = overlays.check_drill_point(wm, np.array([7.0, 7.0]), 0.001)  # `arproj project --drill 7,7`
    assert outside.verdict == overlays.VERDICT_UNKNOWN and outside.reason == "outside the wall"


def test_a_map_folder_without_its_coverage_layer_is_refused(tmp_path):
    _write_glb(tmp_path / "wall.glb")
    (tmp_path / "coverage.npz").unlink()
    with pytest.raises(InputError, match=r"coverage.*arproj map"):
        load_wall_map(tmp_path / "wall.glb")


def test_missing_and_malformed_glb_give_messages(tmp_path):
    with pytest.raises(InputError, match="no such map file"):
        load_wall_map(tmp_path / "nope.glb")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00garbage that is not a GLB")
    with pytest.raises(InputError, match="not a readable GLB"):
        load_wall_map(bad)


@pytest.mark.parametrize("doc, message", [
    ("{", "not valid JSON"),
    ('{"things": []}', 'expected {"objects"'),
    ('{"objects": [{"class": "dragon", "points_m": [[0, 0]], "width_m": 0.01}]}', "class 'dragon' is unknown"),
    ('{"objects": [{"class": "metal_pipe", "width_m": 0.01}]}', r"points_m = None: must be a list"),
    ('{"objects": [{"class": "metal_pipe", "points_m": [[0, "x"]], "width_m": 0.01}]}',
     r"points_m = \[\[0, 'x'\]\]: must be"),
    ('{"objects": [{"class": "metal_pipe", "points_m": [[0, 0]], "width_m": -1}]}',
     "width_m = -1: must be between 0 and 10"),
    ('{"objects": [{"class": "metal_pipe", "points_m": [[0, 0], [1, 0]], "width_m": 0.01, "measured": [1]}]}',
     "measured must be a list of 1 true/false"),
])
def test_bad_objects_json_names_the_problem(tmp_path, doc, message):
    _write_glb(tmp_path / "wall.glb")
    (tmp_path / "objects.json").write_text(doc)
    with pytest.raises(InputError, match=message):
        load_wall_map(tmp_path / "wall.glb")


def test_truth_map_from_a_wall_file_uses_the_mapping_classes():
    wm = wall_map_from_wall_file(shipped_walls()["paper_test_plate"])
    assert overlays.check_drill_point(wm, np.array([7.0, 7.0]), 0.001).reason == "outside the wall"
    kinds = {o.cls for o in wm.objects}
    assert "power_line" in kinds and "metal_pipe" in kinds
    assert all(o.width_m > 0 for o in wm.objects if o.cls in ("power_line", "metal_pipe"))


def test_truth_map_names_what_the_channels_can_tell():
    wm = wall_map_from_wall_file(shipped_walls()["drywall_studs"])
    by_shape = {(o.cls, o.shape) for o in wm.objects}
    # the plastic water pipe and the wooden beam both only raise the capacitive level: non-metal, a line and an
    # outline; the steel studs are metal, not pipes
    assert ("non_metal", "line") in by_shape and ("non_metal", "outline") in by_shape
    assert ("metal", "outline") in by_shape
    assert not {"wood", "plastic_pipe"} & {o.cls for o in wm.objects}


def test_a_range_image_map_textures_the_wall_and_leaves_the_floor_dark(tmp_path):
    """Simulated site (seed 0), the floor strip kept by the x-y crop of `map --range-images`: wall.glb carries
    the map on the wall's faces only, the floor comes back as the untextured other surface, and the projector's
    frame shows nothing (black) on the floor while it draws the map on the wall."""
    from arproj.session.projection import MapProjector
    from geometry.intrinsics import Intrinsics
    from geometry.poses import look_at
    from mapping.exports.glb import write_wall_glb
    from tests.support.hazard_wall import hazard_wall_dense_map
    from tests.support.wall_foot_range import truth_floor_faces, wall_foot_mesh

    result, _ = hazard_wall_dense_map()
    mesh, T_room_from_wall = wall_foot_mesh()
    floor_faces = int(truth_floor_faces(mesh, T_room_from_wall).sum())
    write_wall_glb(result, tmp_path / "wall.glb", mesh)
    result.coverage.save(tmp_path / "coverage.npz")
    wm = load_wall_map(tmp_path / "wall.glb")
    assert wm.texture is not None and wm.other is not None
    assert np.abs(wm.mesh.vertices[:, 2]).max() < 0.05  # every textured face lies on the wall
    assert len(wm.other.faces) >= floor_faces > 100  # the floor is there, with no map
    assert len(wm.mesh.faces) + len(wm.other.faces) == len(mesh.faces)
    assert wm.extent[1] >= -0.05 and wm.extent[3] <= result.bounds[3] + 0.05

    intr = Intrinsics.from_fov(320, 240, 50.0)
    x0, y0, x1, y1 = result.bounds
    cx = (x0 + x1) / 2
    T_wall_from_projector = look_at([cx, 0.9, 1.2], [cx, 0.15, 0.0], up=[0.0, 1.0, 0.0])
    with MapProjector(wm, intr) as projector:
        frame = projector.render(T_wall_from_projector)
    # truth floor points (wall frame y = 0, 10..30 cm out from the wall) and wall points in the map
    xs = np.linspace(x0 + 0.05, x1 - 0.05, 5)
    floor = np.array([[x, 0.0, z] for x in xs for z in (0.10, 0.2, 0.3)])
    wall = np.array([[x, y, 0.0] for x in xs for y in np.linspace(y0 + 0.05, y1 - 0.05, 5)])
    from geometry.poses import invert, transform_points

    def pixels(points: np.ndarray) -> np.ndarray:
        px = np.round(intr.project(transform_points(invert(T_wall_from_projector), points))).astype(int)
        assert ((px >= 0) & (px < [intr.width, intr.height])).all()  # in view
        return frame[px[:, 1], px[:, 0]]

    assert (pixels(floor) == 0).all()  # black: nothing is projected where nothing is known
    assert (pixels(wall).max(axis=1) > 0).mean() > 0.5  # the map is drawn on the wall
