"""`arproj export FORMAT …`: a scan and its map in another ecosystem's format (`export mcap`: ROS 2)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    export_app = typer.Typer(help="Write a scan and its map in another ecosystem's format.", no_args_is_help=True)
    app.add_typer(export_app, name="export")

    @export_app.command("mcap")
    def export_mcap(
        log: Path = typer.Argument(..., help="Scan log (SQLite) written by `arproj scan --log LOG`."),
        map_dir: Path = typer.Argument(..., help="Map folder `arproj map LOG --out DIR` wrote from that log "
                                       "(objects.json, coverage.npz)."),
        out: Path | None = typer.Option(None, "--out", help="The .mcap file to write (default: ros2/scan.mcap "
                                        "beside the map folder); metadata.yaml goes beside it."),
    ) -> None:
        """Write the scan and its map as ROS 2 messages (CDR) in MCAP, a rosbag2 folder that `ros2 bag info`,
        `ros2 bag play`, RViz and Foxglove open: /tf_static, /tf (room → robot → scanner), /scanner/pass,
        /map (drill verdicts: free only where arproj looked and found nothing), /map/<channel>, /objects."""
        from arproj.console import console, working
        from geometry.errors import InputError

        if not map_dir.is_dir():
            raise InputError(f"{map_dir}: no such map folder", "give the folder passed to `arproj map --out`")
        with working("reading the map folder") as step:
            from mapping import mapfile
            from mapping.evidence import FILE_NAME, Coverage
            from mapping.pipeline import load_scan
            from mapping.ros.bag import check_path
            from mapping.ros.record import record_map

            path = out if out is not None else map_dir.resolve().parent / "ros2" / "scan.mcap"
            if out is None:
                path.parent.mkdir(exist_ok=True)
            check_path(path)
            coverage = Coverage.load(map_dir / FILE_NAME)
            objects = mapfile.read_objects(map_dir / mapfile.FILE_NAME)
            mapfile.check_objects_within(objects, coverage.wall_bounds, map_dir / mapfile.FILE_NAME)
            step(f"reading {log}")
            data = load_scan(log)
            step(f"writing {path}")
            written = record_map(path, data, objects, coverage)
        console.print(f"wrote {written} and {written.parent / 'metadata.yaml'} (a rosbag2: `ros2 bag info "
                      f"{written.parent}`)", highlight=False)
