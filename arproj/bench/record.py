"""What recording a scan costs: `arproj scan --record FILE.mcap` (ROS 2 in MCAP) and `--view FILE.rrd` (Rerun),
against the plain scan as the peer, on the same walls in the same run (issue 22).

Each wall is scanned on the simulated site by the path `arproj scan --sim` takes (the device simulators over
serial), without a log, plain, recorded and viewed, in turns (trial by trial, so that the machine's load falls on
all alike). Two figures per recording: the time spent in the writer (its opening, its calls during the scan and
its closing, timed around them: what the recording adds to the scan, free of the scan's own run-to-run noise) and
the difference of the median run times (the same cost seen from outside, noisier). Target: the writer's time ≤ 5 %
of the plain scan's run time. The recording's first use in a process (importing its writer, rerun-sdk or mcap,
and opening one) is paid once, whatever the scan's length: it is measured apart, in a fresh interpreter that has
loaded what the plain scan loads, and shown in its own column; the trials run after it, so that the first wall's
first recorded trial does not carry it (with two trials, as --quick runs, it would be half the median).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from arproj.bench import BenchTable, cells, column, columns
from scanner.sim.world import FrameReport

TARGET_SHARE = 0.05
WALLS = ("paper_test_plate", "drywall_studs", "demo_brick_wall")
QUICK_WALLS = ("small_test_wall", "paper_test_plate")
KINDS = ("plain", "mcap", "rerun")


class TimedWatcher:
    """A ScanWatcher that times the one it wraps."""

    def __init__(self, inner: Any) -> None:
        self.inner, self.seconds = inner, 0.0

    def frame(self, row: dict[str, Any], report: FrameReport) -> None:
        start = time.perf_counter()
        self.inner.frame(row, report)
        self.seconds += time.perf_counter() - start

    def scanned(self, row: dict[str, Any], samples: dict[str, NDArray[Any]]) -> None:
        start = time.perf_counter()
        self.inner.scanned(row, samples)
        self.seconds += time.perf_counter() - start


_FIRST_USE = """
import sys, tempfile, time
from pathlib import Path
import arproj.run.scan, arproj.run.watch  # what the plain scan has loaded already
from arproj.bench.record import open_empty
with tempfile.TemporaryDirectory() as tmp:
    start = time.perf_counter()
    open_empty(sys.argv[1], Path(tmp))
    print(time.perf_counter() - start)
"""


def open_empty(kind: str, folder: Path) -> None:
    """Open and close a recording of `kind` on a scan that brings nothing: its writer's first use."""
    from arproj.run.watch import open_watchers

    target = folder / ("empty.mcap" if kind == "mcap" else "empty.rrd")
    with open_watchers({"wall_width_m": 1.0, "wall_height_m": 1.0},
                       target if kind == "mcap" else None, str(target) if kind == "rerun" else None):
        pass


def first_use(kind: str) -> float:
    """The seconds a recording's first use in a process costs (a fresh interpreter; see the module's note)."""
    done = subprocess.run([sys.executable, "-c", _FIRST_USE, kind], capture_output=True, text=True, check=True)
    return float(done.stdout.split()[-1])


def trial(wall_name: str, kind: str, folder: Path, seed: int) -> tuple[float, float, int, int]:
    """One scan: (run time s, writer time s, recording bytes, samples)."""
    from arproj.run.scan import ScanSettings, resolve_wall, scan_simulated
    from arproj.run.watch import open_watchers

    wall, _ = resolve_wall(wall_name)
    settings = ScanSettings(plan="adaptive", seed=seed, serial=True)
    target = folder / kind / ("scan.mcap" if kind == "mcap" else "scan.rrd")
    target.parent.mkdir(parents=True, exist_ok=True)
    meta = {"wall_width_m": wall.width_m, "wall_height_m": wall.height_m, "sensor": settings.sensor.to_dict()}
    start = time.perf_counter()
    writer = 0.0
    with open_watchers(meta, target if kind == "mcap" else None, str(target) if kind == "rerun" else None) as w:
        opening = time.perf_counter() - start
        timed = TimedWatcher(w) if w is not None else None
        result = scan_simulated(wall, settings, watch=timed).result
        closing = time.perf_counter()
    end = time.perf_counter()
    if timed is not None:
        writer = opening + timed.seconds + (end - closing)
    size = target.stat().st_size if target.exists() else 0
    return end - start, writer, size, len(result.samples.get("time_s", ()))


@dataclass
class RecordRow:
    wall: str = column("wall")
    samples: int = column("samples")
    recording: str = column("recording")
    scan_s: float = column("plain scan s (peer)")
    run_s: float = column("recorded scan s")
    writer_s: float = column("writer s")
    writer_share: float = column("writer / plain %")
    run_share: float = column("run-time difference %")
    first_use_s: float = column("first use s (once a process)")
    size_mib: float = column("file MiB")
    met: str = column(f"≤ {TARGET_SHARE:.0%}")


def run(quick: bool = False, seed: int = 0) -> BenchTable:
    from arproj.console import progress_bar

    walls = QUICK_WALLS if quick else WALLS
    trials = 2 if quick else 3
    times: dict[tuple[str, str], list[tuple[float, float, int, int]]] = {}
    once = {kind: first_use(kind) for kind in KINDS[1:]}
    with tempfile.TemporaryDirectory() as tmp, progress_bar() as bar:
        for kind in KINDS[1:]:  # paid here, not in the first trial (measured above, apart)
            open_empty(kind, Path(tmp))
        task = bar.add_task("scans", total=len(walls) * trials * len(KINDS))
        for wall in walls:
            for k in range(trials):
                order = KINDS if k % 2 == 0 else KINDS[::-1]
                for kind in order:
                    bar.update(task, description=f"{wall}: {kind} ({k + 1}/{trials})")
                    times.setdefault((wall, kind), []).append(trial(wall, kind, Path(tmp) / wall, seed))
                    bar.advance(task)
    rows: list[RecordRow] = []
    worst = {kind: 0.0 for kind in KINDS[1:]}
    for wall in walls:
        plain = float(np.median([t[0] for t in times[(wall, "plain")]]))
        for kind in KINDS[1:]:
            runs = times[(wall, kind)]
            run_s = float(np.median([t[0] for t in runs]))
            writer = float(np.median([t[1] for t in runs]))
            share = writer / plain
            worst[kind] = max(worst[kind], share)
            rows.append(RecordRow(wall, runs[0][3], "MCAP (ROS 2)" if kind == "mcap" else "Rerun .rrd",
                                  round(plain, 2), round(run_s, 2), round(writer, 3), round(100 * share, 2),
                                  round(100 * (run_s / plain - 1.0), 1), round(once[kind], 2),
                                  round(runs[-1][2] / 2**20, 2),
                                  "yes" if share <= TARGET_SHARE else "NO"))
    return BenchTable(
        name="record",
        title="Recording a scan: --record FILE.mcap and --view FILE.rrd against the plain scan (the peer), "
              f"median of {trials} trials",
        columns=columns(RecordRow), rows=[cells(r) for r in rows],
        notes=["the scan: `arproj scan --sim` (adaptive plan, device simulators over serial), no log",
               "first use s: importing the writer and opening a recording in a fresh interpreter that has loaded "
               "what the plain scan loads; paid once by each arproj command that records, whatever the scan's length",
               "writer s: opening the recording, the time inside its calls during the scan, and its closing; the "
               "run-time difference is the same cost seen from outside, with the scan's own run-to-run noise in it"],
        headline={
            f"{'MCAP' if kind == 'mcap' else 'Rerun'} writer share": {
                "arproj": round(100 * worst[kind], 2), "unit": " % of the scan", "peer": 100.0,
                "peer_name": "plain scan", "target": f"≤ {100 * TARGET_SHARE:.0f} %",
                "met": worst[kind] <= TARGET_SHARE}
            for kind in KINDS[1:]},
        environment={"walls": list(walls), "trials": trials,
                     "first_use_s": {kind: round(t, 3) for kind, t in once.items()}},
    )
