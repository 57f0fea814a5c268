"""`arproj map LOG --out DIR`: build the in-wall map from a scan log and write its exports.

With range images that see more than the mapped wall (a room corner: another wall beside it), DIR also gets
room.glb (mapping.exports.glb.write_room_glb): the measured room mesh in the range images' frame, the mapped
wall's faces textured by its map, the other wall's, the floor's and the rest dark — unknown, never safe.
`arproj project --room DIR/room.glb` projects it; wall.glb stays the one-wall map.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from arproj.console import console, err_console, progress_bar

if TYPE_CHECKING:
    import numpy as np
    import trimesh
    from numpy.typing import NDArray

    from mapping.pipeline import MapResult

RANGE_IMAGES_FILE = "range_images.npz"  # the demo keeps the range images it meshed in the map folder


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("map")
    def map_command(
        log: Path = typer.Argument(..., help="Scan log (SQLite) written by `arproj scan --log LOG`."),
        out: Path = typer.Option(Path("map"), "--out", help="Folder for wall.glb, objects.json, coverage.npz, "
                                 "map.png, signals.png, objects.dxf and map_server.yaml/.pgm (ROS)."),
        resolution_mm: float = typer.Option(4.0, "--resolution", help="Map cell size in millimetres."),
        no_stitch: bool = typer.Option(False, "--no-stitch", help="Use the logged sample positions as they "
                                       "are (skip frame alignment)."),
        signal_y: float | None = typer.Option(None, "--signal-y", help="Height (m) of the line whose raw "
                                              "readings signals.png shows (default: mid-wall)."),
        range_images: Path | None = typer.Option(None, "--range-images", help="Range images (.npz: depth_k, "
                                                 "K_k, T_world_from_camera_k, optional T_world_from_wall) "
                                                 "whose merged surface becomes wall.glb's mesh; when they "
                                                 "see another wall too (and give T_world_from_wall), also "
                                                 "room.glb: the room's mesh, the other walls dark."),
        wall: Path | None = typer.Option(None, "--wall", help="Wall file with the truth (simulation), or a "
                                         "shipped wall's name: print recall, precision and position error "
                                         "against it."),
        record: Path | None = typer.Option(None, "--record", help="Also write the scan and this map as ROS 2 "
                                           "messages into this .mcap file (tf, passes, /map and one grid per "
                                           "channel, /objects), a rosbag2 metadata.yaml beside it."),
    ) -> None:
        """Build the in-wall map from a scan log: occupancy grids, stitched frames, classified objects, and
        the exports the projection session and CAD read."""
        from arproj.outputs import OutputFolder
        from geometry.errors import InputError
        from mapping import exports
        from mapping.pipeline import MapSettings, build_map, load_scan

        if not resolution_mm > 0:
            raise InputError(f"--resolution {resolution_mm}: the cell size must be a positive number of mm")
        truth = None
        if wall is not None:  # first: a wrong --wall is refused before any work
            from scanner.wall import load_wall, wall_file

            truth = load_wall(wall_file(wall))
        # every input is read and checked before anything is written: a refusal leaves an earlier map as it was
        from mapping.exports.glb import ROOM_FILE_NAME

        folder = OutputFolder(out, exports.file_names() | {RANGE_IMAGES_FILE, ROOM_FILE_NAME}, "map folder",
                              keep={RANGE_IMAGES_FILE})
        folder.check()
        if record is not None:
            from mapping.ros.bag import check_path

            check_path(record)
        surface = None  # (range views, T_world_from_wall)
        if range_images is not None:
            from mapping.surface import load_range_images

            surface = load_range_images(str(range_images))
        with progress_bar() as bar:
            # reading, mapping, the mesh if asked, then one step per export
            task = bar.add_task("mapping", total=2 + (surface is not None) + len(exports.formats()))
            bar.update(task, description="reading the log")
            data = load_scan(log)
            bar.advance(task)
            bar.update(task, description=f"mapping {data.n_samples:,} samples")
            result = build_map(data, MapSettings(resolution_m=resolution_mm / 1000.0, stitch=not no_stitch))
            bar.advance(task)
            mesh = room_mesh = None
            if surface is not None:
                from mapping.surface import merged_range_mesh, other_walls_in_mesh, wall_mesh_from_range_images

                bar.update(task, description="meshing the range images")
                merged = merged_range_mesh(surface[0])
                mesh = wall_mesh_from_range_images(surface[0], result.bounds, surface[1], merged=merged)
                if surface[1] is not None and other_walls_in_mesh(merged, surface[1], surface[0][0][2][:3, 3]):
                    room_mesh = merged  # the range images see another wall: a room, in their frame
                bar.advance(task)
            written = []
            with folder as tmp:  # the whole folder, then swapped in place: a kill leaves the old or the new map
                steps = exports.export_steps(data, result, tmp, mesh, title=f"In-wall map of {log.name}",
                                            signal_y=signal_y)
                for name, step in steps:
                    bar.update(task, description=f"writing {name}")
                    written.append(out / step().name)
                    bar.advance(task)
                if room_mesh is not None:
                    assert surface is not None and surface[1] is not None
                    write_room_map(tmp / ROOM_FILE_NAME, result, room_mesh, surface[1])
                    written.append(out / ROOM_FILE_NAME)
        if record is not None:
            from mapping.ros.record import record_map

            assert result.coverage is not None  # build_map always makes it
            written.append(record_map(record, data, result.mapped_objects(), result.coverage))
        for note in result.notes:
            console.print(note, highlight=False)
        for w in result.warnings:
            err_console.print(f"[yellow]warning:[/] {w}", highlight=False)
        counts: dict[str, int] = {}
        for o in result.objects:
            counts[o.cls] = counts.get(o.cls, 0) + 1
        summary = ", ".join(f"{n} {c.replace('_', ' ')}" for c, n in sorted(counts.items())) or "nothing"
        console.print(f"found {summary}", highlight=False)
        for path in written:
            console.print(f"wrote {path}", highlight=False)
        if truth is not None:
            from mapping.evaluate import evaluate

            ev = evaluate(result.objects, truth)
            mean, p95 = ev.position_mm()
            console.print(f"against {wall}: recall {ev.recall:.1%} ({ev.n_found}/{ev.n_targets}), precision "
                          f"{ev.precision:.1%}, position error mean {mean:.2f} mm, p95 {p95:.2f} mm, "
                          f"class accuracy {ev.class_accuracy():.1%}", highlight=False)


def write_room_map(path: Path, result: MapResult, room_mesh: trimesh.Trimesh,
                   T_room_from_wall: NDArray[np.float64]) -> Path:
    """room.glb of one mapped wall in a measured room: the wall (room wall 0, its frame T_room_from_wall in the
    mesh's frame, as wide and high as its measured faces reach) textured by the map, every other surface dark."""
    from mapping.exports.glb import AtlasWall, wall_texture, write_room_glb
    from mapping.surface import wall_size_in_mesh

    size = wall_size_in_mesh(room_mesh, T_room_from_wall, result.bounds)
    wall = AtlasWall(0, T_room_from_wall, wall_texture(result), result.bounds, size)
    return write_room_glb(path, room_mesh, [wall])
