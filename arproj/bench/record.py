"""What recording a scan costs: `arproj scan --record FILE.mcap` (ROS 2 in MCAP) and `--view FILE.rrd` (Rerun),
against the plain scan as the peer, on the same walls in the same run (issue 22).

Each wall is scanned on the simulated site by the path `arproj scan --sim` takes (the device simulators over
serial, threads of this process), without a log, plain, recorded and viewed, in turns (trial by trial, so that
the machine's load falls on all alike). The target's figure, recording / plain: the time the scan's thread spends
inside the writer (its opening, its calls during the scan and its closing, wall clock: the scan waits that long)
plus the CPU time of the threads the recording runs beside the scan (rerun-sdk's batcher and file writer), over
the plain scan's run time. Timed around the writer, it is free of the scan's own run-to-run noise; the difference
of the median run times, the same cost seen from outside, is shown with the plain scans' run-to-run spread beside
it: the simulated scan mostly waits on its simulators, so its run time follows the machine's load, and on a loaded
machine that spread is many times the recording's cost (the 7-41 % run-time differences seen before were that
spread: two plain scans of drywall_studs in one run took 7.7 and 16.5 s). The recording's first use in a process
(importing its writer, rerun-sdk or mcap, and opening one) is paid once, whatever the scan's length: it is
measured apart, in a fresh interpreter that has loaded what the plain scan loads, and shown in its own column; the
trials run after it, so that the first wall's first recorded trial does not carry it (with two trials, as --quick
runs, it would be half the median).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
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
_NAME = {"mcap": "MCAP", "rerun": "Rerun"}


class TimedWatcher:
    """A ScanWatcher that times the one it wraps: wall clock (`seconds`) and this thread's CPU (`cpu_s`)."""

    def __init__(self, inner: Any) -> None:
        self.inner, self.seconds, self.cpu_s = inner, 0.0, 0.0

    def frame(self, row: dict[str, Any], report: FrameReport) -> None:
        start, cpu = time.perf_counter(), time.thread_time()
        self.inner.frame(row, report)
        self.seconds += time.perf_counter() - start
        self.cpu_s += time.thread_time() - cpu

    def scanned(self, row: dict[str, Any], samples: dict[str, NDArray[Any]]) -> None:
        start, cpu = time.perf_counter(), time.thread_time()
        self.inner.scanned(row, samples)
        self.seconds += time.perf_counter() - start
        self.cpu_s += time.thread_time() - cpu


def thread_cpu() -> dict[str, float]:
    """CPU seconds so far of each thread of this process, by thread id (Linux /proc; empty elsewhere)."""
    out: dict[str, float] = {}
    task = Path("/proc/self/task")
    for thread in task.iterdir() if task.is_dir() else ():
        try:
            out[thread.name] = int((thread / "schedstat").read_text().split()[0]) / 1e9
        except (OSError, ValueError, IndexError):  # ended meanwhile, or no scheduler statistics
            continue
    return out


def background_cpu(before: dict[str, float], alive: dict[str, float], *after: dict[str, float]) -> float:
    """The CPU seconds since `before` of the threads `alive` (bar this one), read last in `after` (the latest
    reading that still has each): alive when the scan started, they are the recording's (rerun-sdk's batcher,
    file writer, runtime) and idle pools, not the scan's simulators, which start with the scan."""
    own = str(threading.get_native_id())
    total = 0.0
    for thread in set(alive) - {own}:
        last = next((reading[thread] for reading in reversed(after) if thread in reading), alive[thread])
        total += last - before.get(thread, 0.0)
    return total


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


@dataclass
class Trial:
    """One scan of the bench."""

    run_s: float  # wall clock of the whole scan, recording included
    cpu_s: float  # the process's CPU time over it: every thread (the scan's, the simulators', the recording's)
    writer_s: float  # wall clock in the scan's thread inside the writer: its opening, its calls, its closing
    writer_cpu_s: float  # that thread's CPU time in them
    background_cpu_s: float  # CPU time of the threads beside the scan (the recording's: rerun-sdk's)
    size: int  # the recording's bytes
    samples: int


def trial(wall_name: str, kind: str, folder: Path, seed: int) -> Trial:
    """One scan of `wall_name` with the recording `kind` (or none: plain)."""
    from arproj.run.scan import ScanSettings, resolve_wall, scan_simulated
    from arproj.run.watch import open_watchers

    wall, _ = resolve_wall(wall_name)
    settings = ScanSettings(plan="adaptive", seed=seed, serial=True)
    target = folder / kind / ("scan.mcap" if kind == "mcap" else "scan.rrd")
    target.parent.mkdir(parents=True, exist_ok=True)
    meta = {"wall_width_m": wall.width_m, "wall_height_m": wall.height_m, "sensor": settings.sensor.to_dict()}
    before = thread_cpu()
    start, cpu, process = time.perf_counter(), time.thread_time(), time.process_time()
    with open_watchers(meta, target if kind == "mcap" else None, str(target) if kind == "rerun" else None) as w:
        opening, opening_cpu = time.perf_counter() - start, time.thread_time() - cpu
        alive = thread_cpu()
        timed = TimedWatcher(w) if w is not None else None
        result = scan_simulated(wall, settings, watch=timed).result
        scanned = thread_cpu()  # a thread the closing ends (rerun's file writer) is read here last
        closing, closing_cpu = time.perf_counter(), time.thread_time()
    end, end_cpu = time.perf_counter(), time.thread_time()
    threads = background_cpu(before, alive, scanned, thread_cpu())
    writer = writer_cpu = 0.0
    if timed is not None:
        writer = opening + timed.seconds + (end - closing)
        writer_cpu = opening_cpu + timed.cpu_s + (end_cpu - closing_cpu)
    size = target.stat().st_size if target.exists() else 0
    return Trial(end - start, time.process_time() - process, writer, writer_cpu, threads, size,
                 len(result.samples.get("time_s", ())))


@dataclass
class RecordRow:
    wall: str = column("wall")
    samples: int = column("samples")
    recording: str = column("recording")
    scan_s: float = column("plain scan s (peer)")
    run_s: float = column("recorded scan s")
    writer_s: float = column("writer s")
    writer_cpu_s: float = column("writer CPU s")
    background_s: float = column("its threads' CPU s")
    share: float = column("recording / plain %")
    cpu_share: float = column("writer CPU / plain %")
    run_share: float = column("run-time difference %")
    plain_spread: float = column("plain run-to-run spread %")
    cpu_difference_s: float = column("process CPU difference s")
    first_use_s: float = column("first use s (once a process)")
    size_mib: float = column("file MiB")
    met: str = column(f"≤ {TARGET_SHARE:.0%}")


def _median(trials: list[Trial], figure: str) -> float:
    return float(np.median([getattr(t, figure) for t in trials]))


def run(quick: bool = False, seed: int = 0) -> BenchTable:
    from arproj.console import progress_bar

    walls = QUICK_WALLS if quick else WALLS
    trials = 2 if quick else 3
    times: dict[tuple[str, str], list[Trial]] = {}
    load = [round(os.getloadavg()[0], 1)]
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
    load.append(round(os.getloadavg()[0], 1))
    rows: list[RecordRow] = []
    worst = {kind: 0.0 for kind in KINDS[1:]}
    worst_cpu = {kind: 0.0 for kind in KINDS[1:]}
    for wall in walls:
        plain_trials = times[(wall, "plain")]
        plain = _median(plain_trials, "run_s")
        spread = (max(t.run_s for t in plain_trials) - min(t.run_s for t in plain_trials)) / plain
        for kind in KINDS[1:]:
            runs = times[(wall, kind)]
            run_s, writer = _median(runs, "run_s"), _median(runs, "writer_s")
            # the threads beside the scan less what they take in a plain scan (idle pools, rerun-sdk's leftovers)
            background = max(0.0, _median(runs, "background_cpu_s") - _median(plain_trials, "background_cpu_s"))
            share = (writer + background) / plain
            cpu_share = (_median(runs, "writer_cpu_s") + background) / plain
            worst[kind] = max(worst[kind], share)
            worst_cpu[kind] = max(worst_cpu[kind], cpu_share)
            rows.append(RecordRow(wall, runs[0].samples, "MCAP (ROS 2)" if kind == "mcap" else "Rerun .rrd",
                                  round(plain, 2), round(run_s, 2), round(writer, 3),
                                  round(_median(runs, "writer_cpu_s"), 3), round(background, 3),
                                  round(100 * share, 2), round(100 * cpu_share, 2),
                                  round(100 * (run_s / plain - 1.0), 1),
                                  round(100 * spread, 1),
                                  round(_median(runs, "cpu_s") - _median(plain_trials, "cpu_s"), 2),
                                  round(once[kind], 2), round(runs[-1].size / 2**20, 2),
                                  "yes" if share <= TARGET_SHARE else "NO"))
    return BenchTable(
        name="record",
        title="Recording a scan: --record FILE.mcap and --view FILE.rrd against the plain scan (the peer), "
              f"median of {trials} trials",
        columns=columns(RecordRow), rows=[cells(r) for r in rows],
        notes=["the scan: `arproj scan --sim` (adaptive plan, device simulators over serial, threads of this "
               "process), no log",
               "writer s: wall clock in the scan's thread inside the writer (its opening, its calls, its closing): "
               "the scan's thread waits that long; it holds the time other processes and the simulators' threads "
               "took the CPU meanwhile, so it is at least the writer CPU s (that thread's CPU time in them)",
               "its threads' CPU s: the CPU time of the threads running beside the scan (rerun-sdk's batcher, file "
               "writer, runtime; Linux /proc, 0 elsewhere), less that of a plain scan",
               "recording / plain %: (writer s + its threads' CPU s) / the plain scan's run time: the target's "
               "figure, the machine's load in it (a loaded machine stretches the writer's bursts of work more than "
               "the scan's waiting); writer CPU / plain %: the same with the writer's CPU time, its own work",
               "run-time difference %: the recorded scan's median run time against the plain one's; the plain "
               "scans' own run-to-run spread (max − min over median) beside it: where the spread is larger, the "
               "difference is the machine's load, not the recording (the scan mostly waits on the simulators, so "
               "its run time follows the load); process CPU difference s: all threads' CPU time, recorded less "
               "plain, the same cost without the waiting, still with the simulators' run-to-run noise",
               "first use s: importing the writer and opening a recording in a fresh interpreter that has loaded "
               "what the plain scan loads; paid once by each arproj command that records, whatever the scan's "
               "length"],
        headline={
            **{f"{_NAME[kind]} recording share (wall clock in the writer + its threads' CPU)": {
                "arproj": round(100 * worst[kind], 2), "unit": " % of the scan's run time", "peer": 100.0,
                "peer_name": "plain scan", "target": f"≤ {100 * TARGET_SHARE:.0f} %",
                "met": worst[kind] <= TARGET_SHARE} for kind in KINDS[1:]},
            **{f"{_NAME[kind]} writer CPU share (its own work, without the machine's load)": {
                "arproj": round(100 * worst_cpu[kind], 2), "unit": " % of the scan's run time", "peer": 100.0,
                "peer_name": "plain scan", "target": "", "met": None} for kind in KINDS[1:]}},
        environment={"walls": list(walls), "trials": trials, "load_average_1min": {"start": load[0], "end": load[1]},
                     "first_use_s": {kind: round(t, 3) for kind, t in once.items()},
                     "plain_background_cpu_s": {wall: round(_median(times[(wall, "plain")], "background_cpu_s"), 3)
                                                for wall in walls}},
    )
