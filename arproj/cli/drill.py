"""`arproj drill MAP_DIR --at X,Y`: may one drill here? One verdict per point, from the map's evidence."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import typer

from arproj.console import console

MAX_POINTS = 100_000  # a points file longer than this is no list of drill holes


def _parse_point(text: str, where: str) -> tuple[float, float]:
    from geometry.errors import InputError

    parts = [p.strip() for p in text.replace(";", ",").split(",")]
    try:
        if len(parts) != 2:
            raise ValueError
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        raise InputError(f"{where}: {text!r} is not a point X,Y (wall metres, e.g. 1.20,0.85)") from None
    if not (abs(x) < 1e4 and abs(y) < 1e4):  # also refuses nan and inf
        raise InputError(f"{where}: {text!r} is not a point on a wall (metres, finite)")
    return x, y


def read_points_csv(path: Path) -> list[tuple[float, float]]:
    """Points from a CSV file: two columns x, y in wall metres, an optional header line (x_m,y_m)."""
    from geometry.errors import InputError

    try:
        text = path.read_text()
    except (FileNotFoundError, IsADirectoryError):
        raise InputError(f"{path}: no such points file", "give a CSV of x,y wall metres, one point per line") \
            from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file", "give a CSV of x,y wall metres, one point per line") from None
    points = []
    for number, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        if number == 1 and not row[0].strip().lstrip("+-").replace(".", "", 1).isdigit():
            continue  # a header
        points.append(_parse_point(",".join(row[:2]) if len(row) >= 2 else row[0], f"{path}:{number}"))
        if len(points) > MAX_POINTS:
            raise InputError(f"{path}: more than {MAX_POINTS:,} points", "split the file")
    if not points:
        raise InputError(f"{path}: no points in the file", "one point per line: x,y in wall metres")
    return points


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("drill")
    def drill_command(
        map_dir: Path = typer.Argument(..., help="Map folder written by `arproj map … --out DIR` (objects.json "
                                       "and coverage.npz)."),
        at: list[str] = typer.Option([], "--at", help="A point X,Y in wall metres (from the lower-left corner, "
                                     "x right, y up); repeat for more."),
        points: Path | None = typer.Option(None, "--points", help="CSV file of points: x,y per line (wall "
                                           "metres), an optional header."),
        radius_mm: float = typer.Option(4.0, "--radius", help="Drill radius in millimetres (an 8 mm bit: 4)."),
        as_json: bool = typer.Option(False, "--json", help="Print the verdicts as JSON."),
    ) -> None:
        """Say for each point whether drilling there is **safe**, to **keep away**, or **unknown**, and why.

        *safe* only where the inductive and capacitive sensors (between them every pipe, cable, stud and
        fastener that matters) covered the whole hole plus its margin and found nothing; *keep away* where a
        mapped object's safety band reaches the hole (its class, distance and depth are named); *unknown*
        everywhere else, with the reason: not scanned, inferred only (an object joined across ground no sensor
        covered), a response no mapped object explains, a channel missing, or outside the wall.

        Example: `arproj drill map/ --at 1.20,0.85 --at 0.40,1.10`
        """
        from geometry.errors import InputError
        from mapping import drill, mapfile
        from mapping.evidence import FILE_NAME, Coverage

        if not map_dir.is_dir():
            raise InputError(f"{map_dir}: no such map folder", "give the folder passed to `arproj map --out`")
        if not (0.0 < radius_mm <= 100.0):
            raise InputError(f"--radius {radius_mm}: a drill radius is between 0 and 100 mm")
        queries = [_parse_point(text, "--at") for text in at]
        if points is not None:
            queries += read_points_csv(points)
        if not queries:
            raise InputError("no point to check", "give --at X,Y (wall metres) or --points FILE.csv")
        coverage = Coverage.load(map_dir / FILE_NAME)
        objects = mapfile.read_objects(map_dir / mapfile.FILE_NAME)
        mapfile.check_objects_within(objects, coverage.wall_bounds, map_dir / mapfile.FILE_NAME)
        verdicts = drill.check_points(queries, objects, coverage, coverage.wall_bounds,
                                      drill_radius_m=radius_mm / 1000.0)
        if as_json:
            print(json.dumps({"map": str(map_dir), "drill_radius_m": radius_mm / 1000.0,
                              "points": [v.to_json() for v in verdicts]}, indent=1))
            return
        colour = {drill.SAFE: "green", drill.KEEP_AWAY: "red", drill.UNKNOWN: "yellow"}
        for v in verdicts:
            word = v.verdict.replace("_", " ")
            console.print(f"({v.x_m:.3f}, {v.y_m:.3f}) m: [bold {colour[v.verdict]}]{word}[/] — {v.reason}",
                          highlight=False)
