"""Imported records mapped against the simulated site's truth: a gridded record's coverage is exactly its
measured cells, its objects lie where the wall file has them, and its classes are what its channels tell; a
generic table round trip keeps every sample."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from arproj.cli import app
from mapping.evaluate import evaluate, is_target
from mapping.grid import cell_points, cell_resolution
from mapping.pipeline import build_map, load_scan
from mapping.simscan import simulate_scan
from scanner.channels import AC, CAPACITIVE, CHANNELS, INDUCTIVE, NAMES, claimable
from scanner.recorded import gridded, import_table
from scanner.sim.recorded import DEFAULT_TARE_US, gridded_readings, wall_cells
from scanner.wall import load_wall, shipped_walls

CELL_M = 0.03


@pytest.fixture(scope="module")
def plate():
    return load_wall(shipped_walls()["paper_test_plate"])


@pytest.fixture(scope="module")
def gridded_map(plate, tmp_path_factory):
    """paper_test_plate recorded on 3 cm cells (seed 4), with the cells of a patch over the top of the
    vertical pipe and of a strip at the right edge left out (not measured)."""
    cells = wall_cells(plate, CELL_M)
    hole = (cells[:, 0] >= 44) & (cells[:, 0] <= 48) & (cells[:, 1] >= 17)
    strip = cells[:, 0] >= 57
    measured = cells[~(hole | strip)]
    folder = tmp_path_factory.mktemp("gridded")
    gridded.write(folder / "plate.txt", DEFAULT_TARE_US, measured, gridded_readings(plate, measured, CELL_M, seed=4))
    import_table(folder / "plate.txt", folder / "scan.db", wall=plate)
    data = load_scan(folder / "scan.db")
    return measured, folder, data, build_map(data)


def test_coverage_is_exactly_the_measured_cells(gridded_map, plate) -> None:
    measured, _, _, result = gridded_map
    info = result.coverage.info
    assert info.resolution == pytest.approx(cell_resolution(CELL_M, 0.004)) == pytest.approx(0.00375)
    xs, ys = info.cell_centres()
    gx, gy = np.meshgrid(xs, ys)
    cell_of_map_cell = np.stack([np.floor(gx / CELL_M), np.floor(gy / CELL_M)], axis=-1).astype(np.int64)
    truth = np.zeros(info.shape, bool)
    keys = {tuple(c) for c in measured.tolist()}
    for r in range(info.height):
        for c in range(info.width):
            truth[r, c] = tuple(cell_of_map_cell[r, c]) in keys
    assert result.coverage.channels == [INDUCTIVE.name]  # no other channel looked at anything
    covered = result.coverage.covered[INDUCTIVE.name]
    np.testing.assert_array_equal(covered, truth)
    assert covered.sum() == len(measured) * 8 * 8  # every measured cell, as 8 x 8 map cells, and nothing else
    assert not result.coverage.covered_by_all().any()  # without the capacitive channel no point is free


def test_objects_lie_where_the_wall_has_them(gridded_map, plate) -> None:
    *_, result = gridded_map
    ev = evaluate(result.objects, plate)
    assert ev.n_targets == sum(is_target(o) for o in plate.objects) == 3
    assert ev.recall == 1.0 and ev.precision > 0.9
    mean, p95 = ev.position_mm()
    assert mean < 5.0 and p95 < 10.0  # cells of 30 mm, the reading interpolated between their centres
    plate_box = next(o for o in plate.objects if o.kind == "plate").outline_m
    lo, hi = plate_box.min(axis=0) - 0.01, plate_box.max(axis=0) + 0.01
    lines = [o for o in result.objects if o.kind == "line"]
    assert len(lines) >= 3
    # the mounting plate is found as metal on it; nothing is found in the cells left out
    on_plate = [o for o in result.objects if np.all((o.points_m >= lo) & (o.points_m <= hi))]
    assert on_plate and all(o.cls == "metal" for o in on_plate)
    for o in result.objects:
        assert np.all(o.points_m[:, 0] <= 57 * CELL_M + 0.01)  # not in the strip left out
    vertical = next(o for o in lines if abs(o.points_m[0, 0] - 1.4) < 0.01)
    assert vertical.points_m[:, 1].max() <= 17 * CELL_M + 0.01  # ends where the patch left out begins


def test_classes_are_what_the_channels_tell(gridded_map) -> None:
    *_, data, result = gridded_map
    assert data.channels == (INDUCTIVE.name,) and data.cell_m == CELL_M
    classes = {o.cls for o in result.objects}
    assert classes <= {c for c in ("power_line", "metal_pipe", "metal", "fastener", "non_metal", "cavity")
                       if claimable(c, [INDUCTIVE.name])} == {"metal", "fastener"}
    assert "metal" in classes  # the cable and both pipes are metal lines, no more
    assert any("no capacitive, ac channel" in n for n in result.notes)
    assert not any("NaN" in w for w in result.warnings)  # absent channels are not missing readings


def test_claims_need_their_channels() -> None:
    everything = [c.name for c in CHANNELS]
    for cls in ("power_line", "metal_pipe", "metal", "fastener", "non_metal", "cavity"):
        assert claimable(cls, everything)
    assert not claimable("power_line", [INDUCTIVE.name, CAPACITIVE.name])
    assert not claimable("metal_pipe", [INDUCTIVE.name])
    assert claimable("power_line", [AC.name])
    assert not claimable("non_metal", [CAPACITIVE.name])  # metal raises the capacitive level too
    assert claimable("cavity", [CAPACITIVE.name])


def test_cell_points_fill_their_cells_and_interpolate_between_centres() -> None:
    xy = (np.array([[0, 0], [1, 0], [3, 0]]) + 0.5) * CELL_M
    points, values = cell_points(xy, [0.0, 1.0, np.nan], CELL_M, 0.0075)
    assert len(points) == 3 * 16
    np.testing.assert_array_equal(np.floor(points / CELL_M).astype(int)[::16], [[0, 0], [1, 0], [3, 0]])
    mine = values[:16].reshape(4, 4)  # cell 0's points: rows along y, columns along x
    # towards the measured neighbour the reading rises; at the far side (no neighbour) it is the cell's own
    np.testing.assert_allclose(mine[0], [0.0, 0.0, 0.125, 0.375])
    assert np.isnan(values[32:]).all()  # a NaN reading covers nothing


def test_a_generic_table_round_trip(tmp_path: Path) -> None:
    wall = load_wall(shipped_walls()["small_test_wall"])
    scan = simulate_scan(wall, seed=2, line_spacing_m=0.01, sample_step_m=0.002)
    s = scan.samples
    columns = ["x_m", "y_m", *NAMES, "time_s", "pass"]
    table = np.column_stack([s["x_m"], s["y_m"], *(s[c] for c in NAMES), s["time_s"], s["pass_id"]])
    path = tmp_path / "scan.csv"
    np.savetxt(path, table, delimiter=",", header=",".join(columns), comments="", fmt="%.17g")
    runner = CliRunner()
    done = runner.invoke(app, ["import-scan", str(path), "--out", str(tmp_path / "scan.db"), "--wall",
                               "small_test_wall"])
    assert done.exit_code == 0, done.output
    data = load_scan(tmp_path / "scan.db")
    assert data.channels == NAMES and data.cell_m is None and data.meta["source"]["format"] == "generic"
    for column, key in (("x_m", "x_m"), ("y_m", "y_m"), ("time_s", "time_s"), ("pass_id", "pass_id"),
                        *((c, c) for c in NAMES)):
        np.testing.assert_array_equal(data.samples[key], s[column], err_msg=key)
    mapped = runner.invoke(app, ["map", str(tmp_path / "scan.db"), "--out", str(tmp_path / "map"), "--wall",
                                 str(shipped_walls()["small_test_wall"])])
    assert mapped.exit_code == 0, mapped.output
    result = build_map(data)
    ev = evaluate(result.objects, wall)
    assert ev.recall == 1.0
    assert "power_line" in {o.cls for o in result.objects}  # with the AC channel a live cable is named
    assert (tmp_path / "map" / "coverage.npz").is_file()
