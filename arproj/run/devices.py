"""Virtual hardware as separate processes: the simulators `arproj devices serve` runs, each on loopback
`socket://` URLs, found in one registry so that another simulator (a virtual screen, cameras) is one more entry.

A simulator factory takes the `ServeRequest` (the wall, the seed, the fault rate, whether the projection site
is asked for) and returns what it serves — an object with `urls` (name → URL, the names `arproj scan`/`arproj
project` take as options) and `close()` — or None when the request does not ask for it. `serve_devices` starts
every registered one; the scanning robot's four (drives, scanner, base, laser) are scanner.sim.devices.SiteServers
on the same simulated site `arproj scan --sim` builds, so a scan against them gives the samples of `arproj scan
--sim` with the same seed.

With `projection`, the projection robot's site is served instead of the bare head (arproj.sim.live.LiveSite on
the site `arproj project --sim --site` builds around the wall, simulated_projection_scene): the beamer's screen
(tcp://), the two cameras (MJPEG over http://), the head on it, its 2-D laser (`projection_laser`, the
laser's line protocol) and its inclinometer — what `arproj project --screen --left --right --head --laser
--inclinometer` opens on hardware.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import yaml

from devices.sim import FaultConfig, HeadFaults, HeadSimulator
from geometry.errors import InputError
from scanner.plan import DriveConfig
from scanner.run import simulated_site
from scanner.sensor_model import SensorConfig
from scanner.sim.devices import SiteServers
from scanner.wall import Wall

URLS_FORMAT = "arproj-devices/1"


@dataclass(frozen=True)
class ServeRequest:
    wall: Wall
    wall_source: str
    seed: int = 0
    faults: float = 0.0  # probability of a fault per frame a device sends (devices.sim.FaultConfig.rate)
    projection: bool = False  # also the projection robot's site (screen, cameras, head, laser)
    distance_m: float = 2.5  # the projection robot's distance to the wall (as `arproj project --distance`)


class Served(Protocol):
    @property
    def urls(self) -> dict[str, str]: ...

    def close(self) -> None: ...


SimulatorFactory = Callable[[ServeRequest], Served | None]
SIMULATORS: dict[str, SimulatorFactory] = {}  # name -> factory, in the order they are served


def register_simulator(name: str) -> Callable[[SimulatorFactory], SimulatorFactory]:
    """Decorator: serve this simulator factory under `name` in `arproj devices serve`."""
    def add(factory: SimulatorFactory) -> SimulatorFactory:
        if name in SIMULATORS:
            raise ValueError(f"simulator {name!r} registered twice")
        SIMULATORS[name] = factory
        return factory
    return add


@register_simulator("scanning robot")
def scanning_robot(request: ServeRequest) -> SiteServers:
    """GRBL drives, wall scanner, robot base and 2-D laser on the simulated scanning site."""
    world, robot = simulated_site(request.wall, SensorConfig(), DriveConfig(), request.seed)
    return SiteServers(world, robot, FaultConfig(rate=request.faults, seed=request.seed))


class _Head:
    def __init__(self, head: HeadSimulator) -> None:
        self.head = head

    @property
    def urls(self) -> dict[str, str]:
        return {"head": self.head.url}

    def close(self) -> None:
        self.head.close()


def _head_faults(rate: float) -> HeadFaults:
    """The fault rate split over dropped, corrupted and garbled replies."""
    return HeadFaults(drop_reply_rate=rate / 4, corrupt_reply_rate=rate / 4, garbage_rate=rate / 2)


@register_simulator("pan/tilt head")
def pan_tilt_head(request: ServeRequest) -> _Head | None:
    """The projection robot's Pelco-D head alone (with `projection` the projection site's own head instead)."""
    if request.projection:
        return None
    return _Head(HeadSimulator(faults=_head_faults(request.faults), seed=request.seed))


class _ProjectionSite:
    PROJECTION_LASER = "projection_laser"

    def __init__(self, request: ServeRequest) -> None:
        from arproj.sim.live import LiveSite
        from arproj.site_file import simulated_projection_scene

        scene, _ = simulated_projection_scene(request.wall.width_m, request.wall.height_m, request.distance_m)
        self.live = LiveSite(seed=request.seed, scene=scene, head_faults=_head_faults(request.faults))

    @property
    def urls(self) -> dict[str, str]:
        u = self.live.urls
        return {"screen": u.screen, "camera_left": u.camera_left, "camera_right": u.camera_right, "head": u.head,
                self.PROJECTION_LASER: u.laser2d, "inclinometer": u.inclinometer}

    def close(self) -> None:
        self.live.close()


@register_simulator("projection site")
def projection_site(request: ServeRequest) -> _ProjectionSite | None:
    """The projection robot on the simulated site around the wall: screen, cameras, head, 2-D laser and
    inclinometer."""
    return _ProjectionSite(request) if request.projection else None


@contextmanager
def serve_devices(request: ServeRequest) -> Iterator[dict[str, dict[str, str]]]:
    """Start every registered simulator; yields {simulator name: {device: URL}}; stops them all on exit."""
    with ExitStack() as stack:
        served: dict[str, dict[str, str]] = {}
        for name, factory in SIMULATORS.items():
            simulator = factory(request)
            if simulator is None:
                continue
            stack.callback(simulator.close)
            served[name] = simulator.urls
        yield served


def device_urls(served: dict[str, dict[str, str]]) -> dict[str, str]:
    """{device: URL} over every simulator (device names are unique across them)."""
    urls: dict[str, str] = {}
    for name, devices in served.items():
        for device, url in devices.items():
            if device in urls:
                raise ValueError(f"device {device!r} served by two simulators (the second: {name})")
            urls[device] = url
    return urls


def write_urls(path: Path, request: ServeRequest, served: dict[str, dict[str, str]]) -> None:
    """The URLs as a small YAML file a script reads (written whole, then renamed: never half a file)."""
    document: dict[str, Any] = {"format": URLS_FORMAT, "wall": request.wall_source, "seed": request.seed,
                                "faults": request.faults, "urls": device_urls(served)}
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(yaml.safe_dump(document, sort_keys=False))
        tmp.replace(path)
    except OSError as err:
        raise InputError(f"--urls {path}: cannot write it ({err.strerror})") from None


def read_urls(path: Path) -> dict[str, str]:
    """{device: URL} from a file write_urls made."""
    from geometry.inputs import load_document

    document = load_document(path, "device URL file", "give the file `arproj devices serve --urls` wrote")
    if not isinstance(document, dict) or document.get("format") != URLS_FORMAT or \
            not isinstance(document.get("urls"), dict):
        raise InputError(f"{path}: not a device URL file (format {URLS_FORMAT}, from `arproj devices serve --urls`)")
    return {str(k): str(v) for k, v in document["urls"].items()}
