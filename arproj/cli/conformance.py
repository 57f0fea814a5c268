"""`arproj devices-check scanner URL`: the wall scanner protocol's conformance checks (devices/conformance.py)
against a port, one line per check; `--sim` runs them against the simulator, which passes them all."""

from __future__ import annotations

import typer

from arproj.console import console, working

DEVICES = ("scanner",)


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("devices-check")
    def devices_check(
        device: str = typer.Argument(..., help="The device whose protocol to check: scanner (the wall scanner, "
                                     "docs/scanner-protocol.md)."),
        url: str | None = typer.Argument(None, help="Its port as a pyserial URL: /dev/ttyUSB0, "
                                         "socket://host:port, rfc2217://…"),
        sim: bool = typer.Option(False, "--sim", help="Check the simulated wall scanner instead of a port."),
        timeout_s: float = typer.Option(0.5, "--timeout", help="Seconds the device has for each answer line "
                                        "(the host's deadline)."),
    ) -> None:
        """Run the protocol's conformance checks against an implementation: identify, request-id echo, clock,
        arm/disarm, the sample buffer read back, a bad checksum refused, unknown commands and bad arguments
        answered with their error codes. Prints PASS/FAIL per check; exit status 1 if any fails."""
        from devices.conformance import run_checks
        from geometry.errors import InputError

        if device not in DEVICES:
            raise InputError(f"devices-check {device}: no conformance checks for that device",
                             f"devices with checks: {', '.join(DEVICES)}")
        if (url is None) == (not sim):
            raise InputError("devices-check scanner needs a URL or --sim (not both)")
        if not timeout_s > 0:
            raise InputError(f"--timeout {timeout_s}: must be a positive number of seconds")
        with working(f"checking {'the simulated wall scanner' if sim else url}"):
            if sim:
                from devices.sim import DeviceServer
                from scanner.plan import DriveConfig
                from scanner.sensor_model import SensorConfig
                from scanner.sim.devices import WallScannerSim
                from scanner.sim.world import SimWorld
                from scanner.wall import load_wall, shipped_walls

                world = SimWorld(load_wall(shipped_walls()["small_test_wall"]), SensorConfig(), DriveConfig(), 0)
                with DeviceServer(WallScannerSim(world)) as server:
                    results = run_checks(server.url, timeout_s)
                where = f"the simulated wall scanner ({server.url})"
            else:
                assert url is not None
                results = run_checks(url, timeout_s)
                where = url
        for result in results:
            console.print(result.line(), highlight=False, soft_wrap=True)
        failed = [r.name for r in results if not r.ok]
        console.print(f"{where}: {len(results) - len(failed)} of {len(results)} checks passed"
                      + (f"; failed: {', '.join(failed)}" if failed else ""), highlight=False, soft_wrap=True)
        if failed:
            raise typer.Exit(1)
