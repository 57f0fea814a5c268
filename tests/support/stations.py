"""The projection bench's design+truth station (arproj/bench/projection.py) for tests of single degraded scenes."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from arproj.bench import projection as bench
from arproj.session import scenarios
from arproj.session.output import MemoryOutput
from arproj.session.robot_io import SimulatedRobot, nominal_rig
from arproj.session.session import ProjectionSession
from arproj.session.wallmap import wall_map_from_wall
from scanner.wall import random_wall


@contextmanager
def design_truth_station(ctx: Any, distance_m: float, incidence_deg: float) -> Iterator[scenarios.Station]:
    """The bench's design+truth station at a placement (its site, room and wall map at seed 0), registered and
    showing its map."""
    from arproj.sim.site import Site

    wall = random_wall(0, width_m=bench.WALL_SIZE_M[0], height_m=bench.WALL_SIZE_M[1], n_pipes=8, n_cables=10)
    site = Site.build(seed=0, ctx=ctx, room=bench.BENCH_ROOM,
                      robot={"distance_m": distance_m, "incidence_deg": incidence_deg})
    robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), "truth", seed=0, head_speed_deg_s=1000.0)
    session = ProjectionSession(nominal_rig(site), wall_map_from_wall(wall), robot, ctx=ctx)
    assert session.update().show_map
    station = scenarios.Station(site, session, robot, ctx)
    try:
        yield station
    finally:
        station.close()
