"""`arproj devices serve`: the simulated devices as a separate process, on loopback socket:// URLs."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from types import FrameType

import typer

from geometry.errors import InputError


def _interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    devices_app = typer.Typer(help="Virtual hardware: the device simulators as a separate process.",
                              no_args_is_help=True)
    app.add_typer(devices_app, name="devices")

    @devices_app.command("serve")
    def serve(
        wall: str = typer.Option(..., "--wall", help="Wall file (YAML/JSON) or shipped wall name: the simulated "
                                 "site the scanning robot's devices measure."),
        faults: float = typer.Option(0.0, "--faults", help="Probability of a fault per line or frame a device "
                                     "sends (garbage, truncation, drops, disconnects)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the simulation (robot errors, sensor and laser noise, "
                                 "faults): the same as `arproj scan --sim --seed N` gives the same samples."),
        urls: Path = typer.Option(None, "--urls", help="Also write the URLs to this YAML file "
                                  "(format arproj-devices/1: urls: {drives, scanner, base, laser, head}, with "
                                  "--projection also screen, camera_left, camera_right, projection_laser, "
                                  "inclinometer)."),
        projection: bool = typer.Option(False, "--projection", help="Also serve the projection robot on the "
                                        "simulated site around the wall (the site `arproj project --sim --site` "
                                        "builds): the beamer's screen, both cameras, the head, its 2-D laser and "
                                        "its inclinometer."),
        distance: float = typer.Option(2.5, "--distance", help="--projection: the projection robot's distance "
                                       "to the wall, metres (as `arproj project --distance`)."),
    ) -> None:
        """Serve the simulators of the drives, the wall scanner, the robot base, the 2-D laser and the pan/tilt
        head on 127.0.0.1 and print their URLs; runs until Ctrl-C (or SIGTERM): exit status 130."""
        from scanner.wall import wall_file

        if not 0.0 <= faults <= 0.5:
            raise InputError(f"--faults = {faults}: must be a probability between 0 and 0.5")
        if distance <= 0:
            raise InputError(f"--distance = {distance}: must be a positive distance in metres")
        wall_file(wall)  # a wrong --wall: refused before the slow imports below
        from arproj.console import console
        from arproj.run.devices import ServeRequest, device_urls, serve_devices, write_urls
        from arproj.run.scan import resolve_wall

        the_wall, path = resolve_wall(wall)
        request = ServeRequest(the_wall, str(path), seed, faults, projection, distance)
        with serve_devices(request) as served:
            found = device_urls(served)
            console.print(f"serving the simulated site of {the_wall.name} (seed {seed}, faults {faults:g}):",
                          highlight=False)
            for name, devices in served.items():
                for device, url in devices.items():
                    console.print(f"  {device:<16} {url}   ({name})", highlight=False)
            if urls is not None:
                write_urls(urls, request, served)
                console.print(f"URLs written to {urls}", highlight=False)
            console.print(f"scan with: arproj scan --wall {wall} --log scan.db --drives {found['drives']} "
                          f"--scanner {found['scanner']} --laser {found['laser']} --base {found['base']} "
                          "--virtual-clock", highlight=False, soft_wrap=True)
            if projection:
                console.print(f"project with: arproj project --site SITE.yaml --wall KEY --rig RIG --screen "
                              f"{found['screen']} --left {found['camera_left']} --right {found['camera_right']} "
                              f"--head {found['head']} --laser {found['projection_laser']} "
                              f"--inclinometer {found['inclinometer']}", highlight=False,
                              soft_wrap=True)
            console.print("Ctrl-C stops them", highlight=False)
            console.file.flush()
            signal.signal(signal.SIGTERM, _interrupt)  # a service manager's stop: the same clean stop as Ctrl-C
            try:
                while True:
                    time.sleep(0.5)
            except KeyboardInterrupt:
                pass
        console.print("arproj devices serve: stopped (Ctrl-C)", highlight=False)
        raise typer.Exit(130)
