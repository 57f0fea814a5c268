"""`arproj project`: the projection session at the drilling site.

    arproj project --map OUT/wall.glb --rig RIG_DIR --sim [--aim 1.2,1.1] [--drill 1.25,1.0] [--output DIR]
    arproj project --truth scanner/walls/demo_brick_wall.yaml --sim --follow '1.0,1.0;1.3,1.1;1.8,1.2'
    arproj project --map wall.glb --rig RIG --head /dev/ttyUSB0 --left 0 --right 1 --wall-prior prior.yaml \
        --window --screen 1
    arproj project --sim --site site.yaml --wall small_test_wall [--head URL]   # found again from the site file
    arproj project --sim --room OUT/map/room.glb --follow '0:1.5,1.2;0:0.3,1.2'  # several walls of one room
    arproj project --site site.yaml --wall K --rig RIG --head URL --laser URL --left CAM --right CAM \
        --screen tcp://HOST:PORT [--inclinometer URL]  # hardware: found again by the robot's 2-D laser
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import typer

from arproj.console import console, err_console, working
from geometry.errors import InputError


def _point(text: str, option: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{option} {text!r} is not X,Y in metres", "e.g. --aim 1.2,1.1") from None
    return x, y


def _points(text: str, option: str) -> list[tuple[float, float]]:
    return [_point(p, option) for p in text.split(";") if p.strip()]


def _stdin_lines() -> Iterator[str]:
    import sys

    yield from sys.stdin


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command()
    def project(
        map_path: Path = typer.Option(None, "--map", help="wall.glb from `arproj map` (objects.json beside it)."),
        room: Path = typer.Option(None, "--room", help="room.glb (`arproj map --range-images` of a room corner, "
                                  "`arproj demo`): the walls of one room, each with its own map; the session "
                                  "registers on the wall the beam falls on most and judges each wall in view. "
                                  "--aim/--follow points are then K:X,Y (on room wall K; X,Y: the first)."),
        objects: Path = typer.Option(None, "--objects", help="objects.json, if not beside the GLB."),
        truth: Path = typer.Option(None, "--truth", help="Project a wall file's truth instead of a map "
                                   "(scanner wall YAML or a shipped wall's name; for trying the session before "
                                   "mapping)."),
        rig_dir: Path = typer.Option(None, "--rig", help="Rig folder from `arproj calibrate` (rig.yaml)."),
        sim: bool = typer.Option(False, "--sim", help="Run on the simulated site (head simulator over "
                                 "socket://, simulated cameras); no hardware."),
        seed: int = typer.Option(0, "--seed", help="Seed of the simulated site."),
        wall_key: str = typer.Option("0", "--wall", help="Which wall the map belongs to: with --site its key in "
                                     "the site file, else the index of the simulated room's wall."),
        distance: float = typer.Option(2.5, "--distance", help="--sim: robot's distance to the wall, metres."),
        incidence: float = typer.Option(0.0, "--incidence", help="--sim: robot's angle to the wall, degrees."),
        aim: str = typer.Option(None, "--aim", help="Wall point X,Y (metres) to centre the image on."),
        drill: str = typer.Option(None, "--drill", help="Drill point X,Y (metres): distance and verdict."),
        follow: str = typer.Option(None, "--follow", help="Follow a drill target along 'X,Y;X,Y;…'."),
        cycles: int = typer.Option(1, "--cycles", help="Update cycles (re-estimate on motion, verify, show); "
                                   "0: until Ctrl-C."),
        output: Path = typer.Option(None, "--output", help="Also write every beamer frame to DIR as PNG."),
        window: bool = typer.Option(False, "--window", help="Show frames in a borderless fullscreen window."),
        screen: str = typer.Option("0", "--screen", help="Display screen of the beamer for --window, or a "
                                   "screen server tcp://HOST:PORT that shows the frames sent to it (e.g. the "
                                   "one `arproj devices serve --projection` serves)."),
        head_url: str = typer.Option(None, "--head", help="Pan/tilt head: serial port or socket:// URL."),
        laser_url: str = typer.Option(None, "--laser", help="Hardware: the projection robot's 2-D laser (serial "
                                      "port or socket:// URL, the laser protocol `arproj scan --laser` speaks); "
                                      "with --site it finds the wall again. Its place on the robot is the rig's "
                                      "T_robot_from_laser."),
        inclinometer_url: str = typer.Option(None, "--inclinometer", help="The robot's inclinometer (serial port "
                                             "or socket:// URL, devices/inclinometer.py; e.g. the one `arproj "
                                             "devices serve --projection` serves): its roll and pitch replace the "
                                             "wall-pose fusion's floor prior (0.1°, 'it stands on a level floor'), "
                                             "which is most of the bound that cuts the map at 2-4 m. Used where "
                                             "the full pose is fused: --sim, or --site with --laser. --sim "
                                             "without it reads a simulated one on the site."),
        no_inclinometer: bool = typer.Option(False, "--no-inclinometer", help="--sim: no inclinometer, the "
                                             "floor prior alone (what a robot without one can show)."),
        left: str = typer.Option("0", "--left", help="Left camera: index, file or URL (hardware)."),
        right: str = typer.Option("1", "--right", help="Right camera: index, file or URL (hardware)."),
        wall_prior: Path = typer.Option(None, "--wall-prior", help="Hardware: YAML with T_wall_from_robot "
                                        "(in-plane position of the wall frame)."),
        site: Path = typer.Option(None, "--site", help="Site file from `arproj scan` (site.yaml): find wall "
                                  "--wall KEY again by the 2-D laser (--laser URL; with --sim the simulated "
                                  "site's) in the room the scan saw; its map folder unless --map/--truth."),
        head_fault: str = typer.Option(None, "--head-fault", help="--sim: inject a head fault: dead, "
                                       "slip:PAN,TILT (degrees) or flaky."),
        interactive: bool = typer.Option(False, "--interactive", help="After the first cycle, read commands "
                                         "from the terminal: aim X,Y | drill X,Y | check X,Y | update | "
                                         "estimate | status | quit."),
        record: Path = typer.Option(None, "--record", help="Also write every cycle as ROS 2 messages into this "
                                    ".mcap (tf, CameraInfo, the frame and the captures as PNG, the gate state); "
                                    "metadata.yaml beside it."),
        view: str = typer.Option(None, "--view", help="Show the session in a Rerun viewer (frames, check marks, "
                                 "camera captures, gate state): `--view live` spawns the viewer, `--view "
                                 "FILE.rrd` saves the recording instead."),
        as_json: bool = typer.Option(False, "--json", help="Print the session's results as JSON."),
    ) -> None:
        """Project the in-wall map onto the wall, pre-warped for the beamer, with a safety gate."""
        from arproj.run.project import SessionOptions, run_session
        from arproj.run.watch import check_targets

        check_targets(record, view)  # a bad --record or --view refused before any work

        if truth is not None:  # a shipped name or a file, checked before the session starts
            from scanner.wall import load_wall, wall_file

            truth = wall_file(truth, "--truth")
            load_wall(truth)
        wall_index = 0
        if site is None:
            try:
                wall_index = int(wall_key)
            except ValueError:
                raise InputError(f"--wall {wall_key!r}: without --site the wall is the simulated room's index",
                                 "e.g. --wall 0, or pass --site site.yaml --wall KEY") from None
        room_aims = []
        if room is not None:  # points on any wall of the room: K:X,Y
            from arproj.run.room import parse_room_point

            room_aims = [parse_room_point(p, "--follow") for p in follow.split(";") if p.strip()] if follow \
                else [parse_room_point(aim, "--aim")] if aim else []
            aim = follow = None
        options = SessionOptions(
            map_path=map_path, objects=objects, truth=truth, rig_dir=rig_dir, sim=sim, seed=seed,
            wall_index=wall_index, distance=distance, incidence=incidence,
            aim=_point(aim, "--aim") if aim else None, drill=_point(drill, "--drill") if drill else None,
            follow=_points(follow, "--follow") if follow else [], cycles=cycles, output=output, window=window,
            screen=screen, head_url=head_url, laser_url=laser_url, left=left, right=right, wall_prior=wall_prior,
            head_fault=head_fault, commands=_stdin_lines() if interactive else None, site=site,
            inclinometer_url=inclinometer_url, inclinometer=not no_inclinometer,
            site_key=wall_key if site is not None else None, record=record,
            view=view, room=room, room_aims=room_aims)
        if interactive:  # the terminal is the user's after the first cycle: no spinner under their typing
            err_console.print("projection session: starting the robot, finding the wall …", highlight=False)
            result = run_session(options, say=lambda text: err_console.print(text, highlight=False))
        else:
            with working("projection session: starting the robot, finding the wall, rendering") as step:
                def say(text: str) -> None:
                    err_console.print(text, highlight=False)
                    if text.startswith("cycle "):  # a cycle is done: the next one runs
                        step("projection session: next cycle (checking the pose, rendering)")

                result = run_session(options, say=say)
        if as_json:
            print(json.dumps(result, indent=2))
        else:
            for cycle in result["cycles"]:
                status = "MAP SHOWN" if cycle["show_map"] else "WARNING SHOWN: " + "; ".join(cycle["reasons"])
                console.print(f"cycle {cycle['cycle']}: {status}", highlight=False)
                if cycle.get("drill"):
                    console.print(f"  drill point {cycle['drill']['xy']}: {cycle['drill']['message']}",
                                  highlight=False)
                if cycle.get("closed_loop_mm"):
                    c = cycle["closed_loop_mm"]
                    console.print(f"  closed loop: {c['seen']} marks, error mean {c['mean']:.2f} mm, p95 "
                                  f"{c['p95']:.2f} mm (offset corrected {c['corrected']})", highlight=False)
            if result.get("frames"):
                console.print(f"frames written to {result['frames']}", highlight=False)
