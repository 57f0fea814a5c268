"""Recorded scans in (scanner/recorded): the generic table and the DIY gridded record read, checked and written
as scan logs; bad tables refused with the file, line and value."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from arproj.cli import app
from geometry.errors import InputError
from scanner.channels import CAPACITIVE, INDUCTIVE, NAMES
from scanner.log import ScanLog
from scanner.recorded import detect_format, generic, gridded, import_table, read_table
from scanner.sim.recorded import DEFAULT_TARE_US, gridded_readings, wall_cells
from scanner.wall import load_wall, shipped_walls


@pytest.fixture(scope="module")
def plate():
    return load_wall(shipped_walls()["paper_test_plate"])


def test_the_format_is_detected_from_the_first_line(tmp_path: Path) -> None:
    assert detect_format("t", "# made by hand\n\n251.5\n0,0,251.0\n") == gridded.NAME
    assert detect_format("t", f"x_m,y_m,{INDUCTIVE.name}\n0.1,0.2,0.3\n") == generic.NAME
    with pytest.raises(InputError, match=r"t, line 1: cannot tell the table's format .* --format generic\|gridded"):
        detect_format("t", "a;b;c\n")


def test_a_gridded_record_is_its_cells(tmp_path: Path) -> None:
    path = tmp_path / "rec.txt"
    path.write_text("250\n2,1,253\n0,0,250\n1,0,247\n", encoding="ascii")
    r = read_table(path, cell_m=0.05)
    assert r.format == gridded.NAME and r.cell_m == 0.05 and r.channels == [INDUCTIVE.name]
    # row by row from the bottom, each sample at its cell's centre
    np.testing.assert_allclose(r.xy, [[0.025, 0.025], [0.075, 0.025], [0.125, 0.075]])
    np.testing.assert_array_equal(r.line, [3, 4, 2])
    np.testing.assert_array_equal(r.pass_id, [0, 0, 1])
    # ferrous (above the tare) and non-ferrous (below) metal alike raise the inductive response
    np.testing.assert_allclose(r.readings[INDUCTIVE.name], 1.0 - np.exp(-np.array([0.0, 3.0, 3.0])))
    assert r.meta == {"tare_us": 250.0, "us_per_unit": 1.0, "ferrous_cells": 1, "non_ferrous_cells": 1}
    assert r.extent_m == pytest.approx((0.15, 0.1))


@pytest.mark.parametrize(("text", "message"), [
    ("250,1\n0,0,1\n", r"line 1: the first line '250,1' should hold the tare alone"),
    ("tare\n0,0,1\n", r"line 1: tare = 'tare' is not a number"),
    ("250\n", r"line 1: the record holds a tare but no cells"),
    ("250\n0,0,251\n\n0,0.5,251\n", r"line 4: Y = '0.5' is not an integer cell index"),
    ("250\n0,-1,251\n", r"line 2: Y = -1 is below 0"),
    ("250\n0,0,251\n3,4\n", r"line 3: '3,4' has 2 values, expected X,Y,reading"),
    ("250\n0,0,nan\n", r"line 2: reading = 'nan' is not a finite number"),
    ("250\n1,1,251\n0,0,250\n1,1,252\n", r"line 4: cell \(1, 1\) was already given on line 2"),
])
def test_a_bad_gridded_record_names_the_line_and_value(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "rec.txt"
    path.write_text(text, encoding="ascii")
    with pytest.raises(InputError, match=f"{path}, {message}"):
        read_table(path, fmt=gridded.NAME)


@pytest.mark.parametrize(("text", "message"), [
    (f"x_m,y_m,{INDUCTIVE.name},colour\n", r"line 1: unknown column 'colour'"),
    ("x_m,y_m,time_s\n0,0,1\n", r"line 1: no reading column"),
    (f"x_m,{INDUCTIVE.name}\n0,0.1\n", r"cannot tell the table's format"),
    (f"x_m,y_m,{INDUCTIVE.name}\n", r"line 1: the table has a header but no samples"),
    (f"x_m,y_m,{INDUCTIVE.name}\n0.1,0.2,0.3\n0.1,0.2\n", r"line 3: 2 values for 3 columns"),
    (f"x_m,y_m,{INDUCTIVE.name}\n0.1,0.2,1.2\n", r"line 2: inductive = 1.2 is outside 0..1"),
    (f"x_m,y_m,{INDUCTIVE.name}\n0.1,inf,0.3\n", r"line 2: y_m = 'inf' is not a finite number"),
    (f"x_m,y_m,{INDUCTIVE.name}\n0.1,,0.3\n", r"line 2: y_m is empty"),
    (f"x_m,y_m,{INDUCTIVE.name},pass\n0.1,0.2,0.3,1.5\n", r"line 2: pass = 1.5 is not an integer"),
])
def test_a_bad_generic_table_names_the_line_and_value(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "scan.csv"
    path.write_text(text, encoding="ascii")
    with pytest.raises(InputError, match=message):
        read_table(path)


def test_a_generic_table_without_passes_is_split_at_its_raster_jumps(tmp_path: Path) -> None:
    x = np.tile(np.arange(0.0, 0.1, 0.002), 3)
    y = np.repeat([0.1, 0.12, 0.14], len(x) // 3)
    path = tmp_path / "scan.csv"
    path.write_text(f"y_m,x_m,{CAPACITIVE.name}\n" + "".join(f"{b},{a},0.4\n" for a, b in zip(x, y, strict=True)),
                    encoding="ascii")
    r = read_table(path)
    assert r.format == generic.NAME and r.channels == [CAPACITIVE.name] and r.time_s is None
    np.testing.assert_array_equal(np.bincount(r.pass_id), [50, 50, 50])
    np.testing.assert_allclose(r.xy[:, 0], x)


def test_an_imported_record_is_a_scan_log_with_its_source(tmp_path: Path, plate) -> None:
    cells = wall_cells(plate, 0.03)[::7]
    gridded.write(tmp_path / "rec.txt", DEFAULT_TARE_US, cells, gridded_readings(plate, cells, 0.03, seed=1))
    summary = import_table(tmp_path / "rec.txt", tmp_path / "scan.db", wall=plate, wall_path="plate.yaml")
    assert summary.samples == len(cells) and summary.channels == (INDUCTIVE.name,)
    with ScanLog.open(tmp_path / "scan.db") as log:
        meta, samples = log.meta, log.samples()
        assert len(log.frames()["frame_id"]) == 1 and log.pass_count() == summary.passes
    assert meta["status"] == "complete" and meta["wall_fingerprint"] == plate.fingerprint()
    assert (meta["wall_width_m"], meta["wall_height_m"]) == (plate.width_m, plate.height_m)
    assert meta["cell_m"] == 0.03 and meta["channels"] == [INDUCTIVE.name]
    assert meta["source"]["format"] == gridded.NAME and meta["source"]["rows"] == len(cells)
    assert meta["source"]["tare_us"] == DEFAULT_TARE_US
    order = np.lexsort((cells[:, 0], cells[:, 1]))
    np.testing.assert_allclose(np.column_stack([samples["x_m"], samples["y_m"]]), (cells[order] + 0.5) * 0.03)
    assert np.isfinite(samples[INDUCTIVE.name]).all()
    assert all(np.isnan(samples[c]).all() for c in NAMES if c != INDUCTIVE.name)
    # a cell beyond the wall it is said to lie on is refused, naming its line
    (tmp_path / "far.txt").write_text("250\n0,0,250\n60,3,251\n", encoding="ascii")
    with pytest.raises(InputError, match=r"far.txt, line 3: the cell centred at \(1.815, 0.105\) m lies beyond "
                                         r"the wall plate.yaml \(1.8 x 0.6 m\)"):
        import_table(tmp_path / "far.txt", tmp_path / "far.db", wall=plate, wall_path="plate.yaml")


def test_import_scan_command(tmp_path: Path) -> None:
    (tmp_path / "rec.txt").write_text("250\n0,0,250\n1,0,255\n1,1,250\n", encoding="ascii")
    runner = CliRunner()
    ok = runner.invoke(app, ["import-scan", str(tmp_path / "rec.txt"), "--out", str(tmp_path / "scan.db"),
                             "--cell-m", "0.05"])
    assert ok.exit_code == 0, ok.output
    said = " ".join(ok.output.split())  # the console wraps long lines
    assert "gridded table, 3 samples in 2 passes, 50 mm cells; channels inductive; wall 0.1 x 0.1 m" in said
    again = runner.invoke(app, ["import-scan", str(tmp_path / "rec.txt"), "--out", str(tmp_path / "scan.db")])
    assert again.exit_code == 1 and isinstance(again.exception, InputError)
    assert "already exists" in str(again.exception) and "--overwrite" in str(again.exception)
