"""Scans on the simulated site or on devices, as `arproj scan`, `arproj demo` and the benchmarks run them.

The scan itself is `scanner.run.run_scan`; what is set up around it here — the wall by file or shipped name,
the settings a new log records and a resumed one restores, the device simulators (or the in-process site), the
devices at their URLs (`scan_on_devices`: real ports or `arproj devices serve`) — was written out again by each
of those callers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from geometry.errors import InputError
from mapping.pipeline import MapResult, build_map
from mapping.scandata import ScanData
from scanner.hardware import DeviceBackend, DeviceRobot, Operator
from scanner.laser import LaserConfig
from scanner.log import ScanLog
from scanner.plan import DriveConfig, make_planner
from scanner.run import (
    DirectBackend,
    ProgressFn,
    ScanResult,
    ScanWatcher,
    config_from_meta,
    run_scan,
    scan_meta,
    simulated_site,
)
from scanner.sensor_model import SensorConfig
from scanner.wall import Wall, load_wall, wall_file


def resolve_wall(wall: str | Path) -> tuple[Wall, Path]:
    """The wall file, or a shipped wall by its name (e.g. `paper_test_plate`), loaded and checked; returns the
    wall and its path as found. InputError names what is wrong."""
    path = wall_file(wall)
    return load_wall(path), path


@dataclass
class ScanSettings:
    """How a scan on the simulated site runs. A log records all but `serial` and `faults`."""

    plan: str = "adaptive"                     # dense | adaptive (scanner.plan.make_planner)
    plan_options: dict[str, Any] | None = None  # as make_planner takes them; None: the plan's defaults
    seed: int = 0                              # robot errors, sensor noise (and injected faults)
    serial: bool = True   # through the GRBL and wall-scanner simulators over socket:// (the hardware's code
    #                       path); False: the site evaluated in-process (the same samples, faster)
    faults: float = 0.0   # serial only: probability of a fault per device output line
    sensor: SensorConfig = field(default_factory=SensorConfig)
    drives: DriveConfig = field(default_factory=DriveConfig)

    @classmethod
    def from_log(cls, meta: dict[str, Any], path: str | Path, on_devices: bool = False) -> ScanSettings:
        """The settings a scan's log was made with (to resume it). A log made on devices resumes only on
        devices (on_devices): InputError otherwise, and for a simulated log resumed on devices."""
        hardware = meta.get("seed") is None
        if hardware != on_devices:
            raise InputError(f"{path}: the log was not made on the simulated site: resume it on the devices "
                             "(--drives URL --scanner URL --laser URL [--base URL])" if hardware else
                             f"{path}: the log was made on the simulated site: resume it with --sim")
        sensor, drives = config_from_meta(meta)
        return cls(plan=meta["plan"]["kind"], plan_options=meta["plan"], seed=0 if hardware else int(meta["seed"]),
                   sensor=sensor, drives=drives)


@dataclass
class SimulatedScan:
    """A scan on the simulated site or on devices, and what the serial path met on the way."""

    result: ScanResult
    faults_injected: int = 0    # serial: faults the device simulators injected (0 on devices: not known) …
    faults_recovered: int = 0   # … and those the device backend and robot recovered from


@dataclass(frozen=True)
class DeviceUrls:
    """Where the scanning robot's devices are (pyserial URLs). Without a base an operator places the robot."""

    drives: str
    scanner: str
    laser: str | None = None
    base: str | None = None


def new_scan_log(path: str | Path, wall: Wall, wall_source: str, settings: ScanSettings,
                 overwrite: bool = False, simulated: bool = True) -> ScanLog:
    """A new log for a scan with `settings` (simulated: on the simulated site, which records its seed and wall;
    else on devices); the plan's reach is checked before the file is made."""
    planner = make_planner(settings.plan, wall, settings.drives, settings.sensor.hysteresis_m,
                           settings.plan_options)
    planner.frames()
    return ScanLog.create(path, scan_meta(wall, wall_source, planner.describe(), settings.sensor, settings.drives,
                                         settings.seed if simulated else None, simulated=simulated),
                          overwrite=overwrite)


def scan_simulated(wall: Wall, settings: ScanSettings, log: ScanLog | None = None,
                   progress: ProgressFn | None = None, watch: ScanWatcher | None = None) -> SimulatedScan:
    """Scan `wall` on the simulated site; every pass goes to `log` if given (resuming from what it holds), and
    every frame and pass to `watch` (a recording, a live view)."""
    world, robot = simulated_site(wall, settings.sensor, settings.drives, settings.seed)
    options: dict[str, Any] = {"plan_kind": settings.plan, "plan_options": settings.plan_options,
                               "sensor": settings.sensor, "drives": settings.drives, "log": log, "progress": progress,
                               "watch": watch}
    if not settings.serial:
        return SimulatedScan(run_scan(wall, DirectBackend(world), robot, **options))
    from devices.sim import FaultConfig
    from scanner.hardware import simulated_devices

    with simulated_devices(world, robot, FaultConfig(rate=settings.faults, seed=settings.seed)) as devices:
        result = run_scan(wall, devices.backend, devices.robot, **options)
        return SimulatedScan(result, devices.servers.faults_injected, devices.faults_recovered)


def scan_on_devices(wall: Wall, settings: ScanSettings, urls: DeviceUrls, log: ScanLog | None = None,
                    progress: ProgressFn | None = None, operator: Operator | None = None, realtime: bool = True,
                    timeout_s: float = 0.5, watch: ScanWatcher | None = None) -> SimulatedScan:
    """Scan `wall` (its size and plan; what is inside it is measured) with the devices at `urls`, the hardware
    code path `scan_simulated` runs on its simulators. realtime False: the devices run motion on a virtual clock
    (`arproj devices serve`), so a lost answer is waited for by the link's timeout, not by the motion's time."""
    backend = DeviceBackend(urls.drives, urls.scanner, settings.drives, settings.sensor, timeout_s,
                            realtime=realtime)
    robot = DeviceRobot(urls.laser, urls.base, LaserConfig(), operator, timeout_s)
    try:
        backend.start()
        robot.start()
        result = run_scan(wall, backend, robot, plan_kind=settings.plan, plan_options=settings.plan_options,
                          sensor=settings.sensor, drives=settings.drives, log=log, progress=progress,
                          watch=watch)
    finally:
        backend.close()
        robot.close()
    return SimulatedScan(result, 0, backend.faults_recovered + robot.faults_recovered)


def write_site(path: Path, key: str, wall: Wall, result: ScanResult, scan_log: Path,
               map_dir: Path | None = None) -> bool:
    """Add the scanned wall to the site file at `path` (arproj.site_file): the room its frames' lasers saw, the
    wall's place in it, the map folder (default `map` beside the site file) and the log. Returns True when an
    entry of that key was replaced."""
    from arproj.site_file import site_wall_from_scan, write_site_wall

    site_wall = site_wall_from_scan(key, wall, result.rooms, result.frames, LaserConfig(),
                                    map_dir if map_dir is not None else path.parent / "map", scan_log)
    return write_site_wall(path, site_wall)


def scan_and_map(wall: Wall, plan: str, seed: int, options: dict[str, Any] | None = None
                 ) -> tuple[ScanResult, MapResult]:
    """Scan `wall` with `plan` and its `options` (in-process site, no log) and map it as `arproj map` does."""
    settings = ScanSettings(plan=plan, plan_options=options, seed=seed, serial=False)
    scan = scan_simulated(wall, settings).result
    meta = scan_meta(wall, wall.source, {"kind": plan, **(options or {})}, settings.sensor, settings.drives, seed,
                     True)
    data = ScanData.from_scan(f"{plan} scan of {wall.name}", scan.samples, scan.frames, meta)
    return scan, build_map(data)
