"""`arproj drill MAP_DIR`: verdicts from a map folder `arproj map` wrote, and one clear line for bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from arproj.cli import app
from mapping.simscan import simulate_scan, write_log
from scanner.wall import load_wall, shipped_walls


@pytest.fixture(scope="module")
def map_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """small_test_wall (0.35 × 0.3 m: a live cable at x = 0.12, a copper pipe at y = 0.18, a screw at
    (0.27, 0.07)), a dense scan without placement error, mapped by the CLI."""
    root = tmp_path_factory.mktemp("drill")
    wall = load_wall(shipped_walls()["small_test_wall"])
    log = write_log(simulate_scan(wall, seed=2, robot_sigma=(0.0, 0.0, 0.0), loc_sigma=(1e-4, 1e-4, 1e-5)),
                    root / "scan.sqlite")
    done = CliRunner().invoke(app, ["map", str(log), "--out", str(root / "map")])
    assert done.exit_code == 0, done.output
    return root / "map"


def test_json_verdicts_on_a_cable_a_clear_spot_and_outside(map_dir: Path) -> None:
    done = CliRunner().invoke(app, ["drill", str(map_dir), "--at", "0.12,0.10", "--at", "0.05,0.05",
                                    "--at", "0.50,0.20", "--json"])
    assert done.exit_code == 0, done.output
    points = json.loads(done.output)["points"]
    assert [p["verdict"] for p in points] == ["keep_away", "safe", "unknown"]
    assert points[0]["nearest"]["class"] == "power_line" and points[0]["nearest"]["distance_m"] == 0.0
    assert points[2]["reason"] == "outside the wall"
    assert set(points[1]) == {"x_m", "y_m", "verdict", "reason", "nearest"}


def test_points_file_and_plain_output(map_dir: Path, tmp_path: Path) -> None:
    csv = tmp_path / "holes.csv"
    csv.write_text("x_m,y_m\n0.12,0.25\n0.30,0.25\n")
    done = CliRunner().invoke(app, ["drill", str(map_dir), "--points", str(csv)])
    assert done.exit_code == 0, done.output
    lines = [ln for ln in done.output.splitlines() if ln.strip()]
    assert len(lines) == 2
    assert "keep away" in lines[0] and "power line" in lines[0]


@pytest.mark.parametrize("args, message", [
    (["--at", "1.2"], "not a point X,Y"),
    (["--at", "a,b"], "not a point X,Y"),
    (["--at", "nan,0.1"], "not a point on a wall"),
    ([], "no point to check"),
    (["--at", "0.1,0.1", "--radius", "-3"], "drill radius"),
])
def test_bad_points_are_one_line_with_status_2(map_dir: Path, args: list[str], message: str) -> None:
    import sys

    from arproj.cli import main

    argv = sys.argv
    sys.argv = ["arproj", "drill", str(map_dir), *args]
    try:
        with pytest.raises(SystemExit) as exit_:
            main()
    finally:
        sys.argv = argv
    assert exit_.value.code == 2


def test_a_map_folder_from_before_coverage_is_refused_not_guessed(map_dir: Path, tmp_path: Path) -> None:
    import shutil

    old = tmp_path / "old_map"
    shutil.copytree(map_dir, old)
    (old / "coverage.npz").unlink()
    done = CliRunner().invoke(app, ["drill", str(old), "--at", "0.05,0.05"])
    assert done.exit_code != 0
    assert "coverage" in str(done.exception) and "arproj map" in str(done.exception)
