"""`arproj import-scan TABLE --out scan.db`: a recorded scan from another device (a generic table or a DIY
scanner's gridded record) as a scan log that `arproj map` reads."""

from __future__ import annotations

from pathlib import Path

import typer

from arproj.console import console


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("import-scan")
    def import_scan(
        table: Path = typer.Argument(..., help="The recorded scan: a CSV table with a header (x_m,y_m and any of "
                                     "inductive,capacitive,ac; optionally time_s,pass) or a gridded record (the "
                                     "tare alone on the first line, then X,Y,reading: cell indices and the mean "
                                     "coil delay in µs)."),
        out: Path = typer.Option(..., "--out", help="Scan log (SQLite) to write."),
        fmt: str | None = typer.Option(None, "--format", help="generic | gridded (default: detected from the "
                                       "first line)."),
        cell_m: float = typer.Option(0.03, "--cell-m", help="Cell size of a gridded record, metres."),
        us_per_unit: float = typer.Option(1.0, "--us-per-unit", help="Gridded record: coil delay (µs) per unit "
                                          "of the inductive response (only the display's saturation depends on "
                                          "it: the map's thresholds come from the record's own noise)."),
        wall: str | None = typer.Option(None, "--wall", help="The wall the record lies on (file or shipped name): "
                                        "its size and fingerprint go into the log; default: the rectangle from "
                                        "the corner to the samples' far edge."),
        overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing log at --out."),
    ) -> None:
        """Bring a recorded scan in as a scan log: every sample with its position and readings, the format,
        cell size and channels in the log's meta. Map it with `arproj map LOG --out DIR`."""
        from geometry.errors import InputError

        if wall is not None:  # a wrong --wall: refused before the slow imports below
            from scanner.wall import wall_file

            wall_file(wall)
        from scanner.recorded import FORMATS, import_table

        if fmt is not None and fmt not in FORMATS:
            raise InputError(f"--format {fmt}: unknown format", f"use one of {', '.join(FORMATS)}")
        if not us_per_unit > 0:
            raise InputError(f"--us-per-unit {us_per_unit}: must be a positive number of µs")
        the_wall, wall_path = None, None
        if wall is not None:
            from arproj.run.scan import resolve_wall

            the_wall, found = resolve_wall(wall)
            wall_path = str(found)
        summary = import_table(table, out, fmt, cell_m=cell_m, us_per_unit=us_per_unit, wall=the_wall,
                               wall_path=wall_path, overwrite=overwrite)
        cells = f", {summary.cell_m * 1000:g} mm cells" if summary.cell_m is not None else ""
        console.print(f"{table}: {summary.format} table, {summary.samples:,} samples in {summary.passes} passes"
                      f"{cells}; channels {', '.join(summary.channels)}; wall {summary.wall_size_m[0]:g} x "
                      f"{summary.wall_size_m[1]:g} m", highlight=False)
        console.print(f"wrote {summary.log} (map it: arproj map {summary.log} --out DIR)", highlight=False)
