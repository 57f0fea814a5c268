"""A simulated hour of projection cycles: memory, GL objects and open files stay constant (issue 24).

The projection session on the simulated site (what `arproj project --sim --cycles 0` runs) updates back to back:
verify with check marks, decide, render the frame. Its clock is the session's own: each cycle advances it by
the time that cycle took, so an hour of session time is an hour of cycles at the session's own rate (about
1,200 on two cores). Measured after a warm-up: the resident memory (RSS) and Python's allocated blocks, the GL
objects made through the context and not released (counted at the context's factory methods), and the open
file descriptors. Target: memory growth ≤ 5 %, GL objects and file handles constant. No other program runs a
projection session, so there is no peer figure: the session's own warm-up state is the reference.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import wraps
from typing import Any

import numpy as np

from arproj.bench import BenchTable, cells, column, columns
from arproj.console import progress_bar

TARGET_GROWTH = 0.05
HOUR_S = 3600.0
QUICK_S = 60.0  # --quick: a minute of cycles (~50); with the set-up under 2 min (120 s took 2:12)
WARMUP_CYCLES = 3  # caches, the shader cache and the first re-estimates settle in these

# The moderngl.Context methods that make a GL object (each has .release()).
GL_FACTORIES = ("buffer", "texture", "texture_array", "texture3d", "texture_cube", "depth_texture",
                "depth_texture_cube", "framebuffer", "simple_framebuffer", "renderbuffer", "depth_renderbuffer",
                "vertex_array", "simple_vertex_array", "program", "sampler", "query", "compute_shader")


class GLObjectCount:
    """The GL objects made through `ctx` since this was attached that are not released: a renderer that leaks
    a texture per frame shows as a count that grows. Wraps the context's factory methods (moderngl keeps no
    count itself; its objects are not released when Python collects them)."""

    def __init__(self, ctx: Any) -> None:
        self.ctx = ctx
        self.made: list[Any] = []
        for name in GL_FACTORIES:
            factory = getattr(ctx, name, None)
            if factory is not None:
                setattr(ctx, name, self._counting(factory))

    def _counting(self, factory: Callable[..., Any]) -> Callable[..., Any]:
        @wraps(factory)
        def make(*args: Any, **kwargs: Any) -> Any:
            obj = factory(*args, **kwargs)
            self.made.append(obj)
            return obj
        return make

    def live(self) -> int:
        """Objects made and not released (a released moderngl object holds an InvalidObject)."""
        self.made = [o for o in self.made if type(getattr(o, "mglo", None)).__name__ != "InvalidObject"]
        return len(self.made)

    def detach(self) -> None:
        for name in GL_FACTORIES:
            self.ctx.__dict__.pop(name, None)


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def open_files() -> int:
    return len(os.listdir("/proc/self/fd"))


@dataclass
class SoakSample:
    cycle: int = column("cycle")
    session_s: float = column("session time s")
    rss_mib: float = column("RSS MiB")
    py_blocks: int = column("Python blocks")
    gl_objects: int = column("GL objects")
    files: int = column("open files")
    shown: int = column("maps shown")


def soak(seconds: float | None = None, cycles: int | None = None, seed: int = 3,
         on_cycle: Callable[[SoakSample], None] | None = None) -> list[SoakSample]:
    """Run the simulated session for `seconds` of session time or `cycles` cycles after WARMUP_CYCLES; one
    sample after the warm-up (cycle 0) and one after every cycle."""
    from arproj.session.output import MemoryOutput
    from arproj.session.robot_io import SimulatedRobot, nominal_rig
    from arproj.session.session import ProjectionSession
    from arproj.session.wallmap import wall_map_from_wall_file
    from arproj.sim.site import Site
    from render.gl import create_context
    from scanner.wall import shipped_walls

    if seconds is None and cycles is None:
        raise ValueError("soak needs seconds or cycles")
    ctx = create_context()
    count = GLObjectCount(ctx)
    site = Site.build(seed=seed, ctx=ctx, robot={"distance_m": 2.2, "incidence_deg": 20.0})
    robot = SimulatedRobot.on_site(site, 0, MemoryOutput(), seed=seed, head_speed_deg_s=600.0, timeout_s=0.1)
    samples: list[SoakSample] = []
    try:
        with ProjectionSession(nominal_rig(site), wall_map_from_wall_file(shipped_walls()["demo_brick_wall"]),
                               robot, ctx=ctx) as session:
            session.aim_at([1.3, 1.1])
            for _ in range(WARMUP_CYCLES):
                session.update()
            clock, shown, k = 0.0, 0, 0

            def sample() -> SoakSample:
                return SoakSample(k, clock, rss_bytes() / 2**20, sys.getallocatedblocks(), count.live(),
                                  open_files(), shown)

            samples.append(sample())
            while (seconds is None or clock < seconds) and (cycles is None or k < cycles):
                start = time.perf_counter()
                shown += session.update().show_map
                clock += time.perf_counter() - start
                k += 1
                samples.append(sample())
                if on_cycle is not None:
                    on_cycle(samples[-1])
    finally:
        robot.close()
        site.release()
        count.detach()
        ctx.release()
    return samples


def growth(samples: list[SoakSample]) -> dict[str, float]:
    """The last quarter of the cycles against the first (medians: RSS swings by tens of MiB within a cycle as
    frames and rasters come and go, a leak lifts the whole quarter): relative RSS and Python-block growth; the
    GL-object and open-file changes from the warm-up sample to the largest count seen."""
    quarter = max(1, len(samples) // 4)
    first, last = samples[:quarter], samples[-quarter:]

    def rise(values: Callable[[list[SoakSample]], list[float]]) -> float:
        return float(np.median(values(last)) / np.median(values(first)) - 1.0)

    return {"rss": rise(lambda ss: [s.rss_mib for s in ss]),
            "py_blocks": rise(lambda ss: [float(s.py_blocks) for s in ss]),
            "gl_objects": max(s.gl_objects for s in samples) - samples[0].gl_objects,
            "files": max(s.files for s in samples) - samples[0].files}


def run(quick: bool = False, seed: int = 0) -> BenchTable:
    seconds = QUICK_S if quick else HOUR_S
    with progress_bar() as bar:
        task = bar.add_task("projection cycles", total=seconds)
        samples = soak(seconds=seconds, seed=3 + seed,
                       on_cycle=lambda s: bar.update(task, completed=min(s.session_s, seconds)))
    g = growth(samples)
    marks = sorted({0, *(round(f * (len(samples) - 1)) for f in (0.25, 0.5, 0.75, 1.0))})
    last = samples[-1]
    per_cycle = last.session_s / max(1, last.cycle)
    met_memory = max(g["rss"], g["py_blocks"]) <= TARGET_GROWTH
    return BenchTable(
        name="soak",
        title=f"Projection session, {last.session_s / 60:.0f} min of session time ({last.cycle} cycles after "
              f"{WARMUP_CYCLES} of warm-up)",
        columns=columns(SoakSample), rows=[cells(samples[i]) for i in marks],
        notes=[f"a cycle takes {per_cycle:.2f} s here (verify with check marks, decide, render); the map was "
               f"shown in {last.shown} of {last.cycle}",
               f"growth, last quarter of the cycles against the first (medians): RSS {g['rss']:+.1%}, Python "
               f"blocks {g['py_blocks']:+.1%}; GL objects {g['gl_objects']:+.0f}, open files {g['files']:+.0f}",
               "no peer: no other program runs a projection session; the reference is the session after "
               "warm-up"],
        headline={
            "memory growth": {"arproj": round(100 * max(g["rss"], g["py_blocks"]), 2), "unit": " %",
                              "peer": "–", "peer_name": "none", "target": "≤ 5 %", "met": met_memory},
            "GL objects change": {"arproj": g["gl_objects"], "peer": "–", "peer_name": "none", "target": "0",
                                  "met": g["gl_objects"] == 0},
            "open files change": {"arproj": g["files"], "peer": "–", "peer_name": "none", "target": "0",
                                  "met": g["files"] == 0},
        },
        environment={"cycles": last.cycle, "session_s": round(last.session_s, 1), "seconds_asked": seconds},
    )
