"""The map's export formats: one module each, found by the package, written in order; a new module is a new
format."""

import sys
import types
from pathlib import Path

import numpy as np
import yaml

from geometry.polyline import densify
from mapping import drill, exports
from mapping.evaluate import is_hazard
from mapping.exports import map_server
from tests.support.hazard_wall import hazard_wall, hazard_wall_dense_map


def test_every_format_module_is_found_in_writing_order() -> None:
    names = [m.FILE_NAME for m in exports.formats()]
    # the projection session's mesh first; the files `arproj map` has always written, each once
    assert names == ["wall.glb", "objects.json", "coverage.npz", "map.png", "signals.png", "objects.dxf",
                     "map_server.yaml"]
    assert "map_server.pgm" in exports.file_names()  # a format's second file is the folder's too


def test_a_new_module_is_a_new_format(tmp_path, monkeypatch) -> None:
    """A module dropped into the package (here a made-up CSV of object classes) is written with the rest."""
    package_dir = tmp_path / "extra"
    package_dir.mkdir()
    (package_dir / "classes_csv.py").write_text(
        "from pathlib import Path\n"
        "FILE_NAME = 'classes.csv'\n"
        "ORDER = 90\n"
        "def write(job) -> Path:\n"
        "    path = job.out_dir / FILE_NAME\n"
        "    path.write_text('\\n'.join(o.cls for o in job.objects))\n"
        "    return path\n")
    monkeypatch.setattr(exports, "__path__", [*exports.__path__, str(package_dir)])
    monkeypatch.delitem(sys.modules, "mapping.exports.classes_csv", raising=False)
    found = exports.formats()
    assert [m.FILE_NAME for m in found][-1] == "classes.csv"
    job = types.SimpleNamespace(out_dir=tmp_path, objects=[types.SimpleNamespace(cls="power_line")])
    assert found[-1].write(job).read_text() == "power_line"


def _read_map_server(yaml_path: Path) -> tuple[dict, np.ndarray]:
    """(meta, occupancy) as ROS map_server reads a trinary map: occ = (255 − value)/255 (negate 0), above
    occupied_thresh 100, below free_thresh 0, else −1; the image's last row is the grid's first."""
    meta = yaml.safe_load(yaml_path.read_text())
    raw = (yaml_path.parent / meta["image"]).read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:  # magic, width, height, maxval, skipping comments
        while raw[pos:pos + 1].isspace():
            pos += 1
        if raw[pos:pos + 1] == b"#":
            pos = raw.index(b"\n", pos) + 1
            continue
        end = pos
        while not raw[end:end + 1].isspace():
            end += 1
        fields.append(raw[pos:end])
        pos = end
    assert fields[0] == b"P5" and fields[3] == b"255"
    width, height = int(fields[1]), int(fields[2])
    pixels = np.frombuffer(raw[pos + 1:], np.uint8)
    assert pixels.size == width * height
    occ = (255 - pixels.reshape(height, width)[::-1].astype(float)) / 255
    grid = np.full(occ.shape, -1, np.int8)
    grid[occ > meta["occupied_thresh"]] = 100
    grid[occ < meta["free_thresh"]] = 0
    return meta, grid


def test_the_map_server_grid_reads_back_as_the_drill_verdicts_and_no_hazard_lies_on_free(tmp_path) -> None:
    result, objects = hazard_wall_dense_map()
    job = exports.ExportJob(data=None, result=result, out_dir=tmp_path, objects=objects)  # type: ignore[arg-type]
    meta, grid = _read_map_server(map_server.write(job))
    info = result.coverage.info
    assert meta["mode"] == "trinary" and meta["negate"] == 0 and meta["resolution"] == info.resolution
    assert meta["origin"] == [info.origin_x, info.origin_y, 0.0]
    verdicts = drill.verdict_raster(objects, result.coverage, result.bounds)
    codes = drill.VERDICT_CODES
    expected = np.select([verdicts == codes[drill.SAFE], verdicts == codes[drill.KEEP_AWAY]], [0, 100], -1)
    np.testing.assert_array_equal(grid, expected)
    assert (grid == 0).any() and (grid == 100).any() and (grid == -1).any()
    # free only where both safety channels looked
    assert not (grid == 0)[~result.coverage.covered_by_all()].any()
    # against the truth: no point of a true hazard falls on a free cell
    for obj in hazard_wall().objects:
        if not is_hazard(obj):
            continue
        probes = densify(np.asarray(obj.geometry_m, dtype=np.float64), 0.002)
        cols = np.floor((probes[:, 0] - info.origin_x) / info.resolution).astype(int)
        rows = np.floor((probes[:, 1] - info.origin_y) / info.resolution).astype(int)
        ok = (cols >= 0) & (cols < info.width) & (rows >= 0) & (rows < info.height)
        assert not (grid[rows[ok], cols[ok]] == 0).any(), obj.id
