"""How fast the command line answers: `arproj --help`, `arproj --version` and a command's `--help` (issue 23).

Each is started as a new process, as a user starts it, several times, interleaved with the peer so that a busy
machine slows both alike; the figure is the median wall time. Peer: `python -c "import typer, rich"` in the same
interpreter — what any typer CLI with rich help pays before it does anything — and, beside it, a one-command
typer app printing its --help (typer's help rendering: rich.console, markdown) and `python -c pass`.
Target: `arproj --help` and `arproj --version` ≤ 0.5 s. Also checked: which of the heavy modules (HEAVY_MODULES)
`arproj --help` loads — none should be; they are imported where they are used.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from arproj.bench import BenchTable, cells, column, columns

TARGET_S = 0.5
REPEATS, QUICK_REPEATS = 15, 5
# What a start must not pay for: seconds of import between them (scipy 0.5 s, OpenCV, trimesh, GL).
HEAVY_MODULES = ("scipy", "trimesh", "cv2", "moderngl", "shapely", "networkx", "pyrender", "PIL")
PEER = "python -c \"import typer, rich\""
# The floor of any typer CLI's --help: a one-command app with arproj's markup mode printing its help.
TYPER_FLOOR = "a one-command typer app --help"
TYPER_FLOOR_CODE = ("import typer\napp = typer.Typer(rich_markup_mode='markdown', add_completion=False)\n"
                    "@app.command()\ndef hello(name: str = typer.Option('x', help='Who.')) -> None:\n"
                    "    'Say hello.'\napp()\n")


def arproj_command() -> list[str]:
    """The installed console script beside this interpreter (what a user runs), else the same entry point."""
    script = Path(sys.executable).parent / "arproj"
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "from arproj.cli import main; main()"]


def heavy_modules_loaded(args: list[str]) -> list[str]:
    """The HEAVY_MODULES that `arproj ARGS` has imported by the time it exits (checked in a subprocess)."""
    probe = ("import sys, atexit, json\n"
             f"atexit.register(lambda: sys.__stderr__.write('\\nHEAVY=' + json.dumps(sorted({{m.split('.')[0] "
             f"for m in sys.modules}} & set({list(HEAVY_MODULES)!r}))) + '\\n'))\n"
             "from arproj.cli import main\n"
             f"sys.argv = ['arproj', *{args!r}]\n"
             "main()\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    for line in reversed(done.stderr.splitlines()):
        if line.startswith("HEAVY="):
            return list(json.loads(line[len("HEAVY="):]))
    raise RuntimeError(f"arproj {' '.join(args)} ended without the probe's line (exit {done.returncode}): "
                       f"{done.stderr.strip()[-500:]}")


def start_env() -> dict[str, str]:
    """The environment of the timed starts: this one, but with bytecode caching on, as a user's Python has it
    (PYTHONDONTWRITEBYTECODE=1 would compile arproj's own sources anew at every start, 0.1 s)."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def wall_time(cmd: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=60, env=start_env())
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed (exit {done.returncode}): {done.stderr.decode()[-500:]}")
    return seconds


@dataclass
class StartRow:
    what: str = column("command")
    median_s: float = column("median s")
    min_s: float = column("min s")
    max_s: float = column("max s")
    vs_peer: float = column("× peer")
    target: str = column("target")
    met: str = column("met")


def measure(repeats: int) -> dict[str, list[float]]:
    """Wall times of each command, `repeats` rounds, the commands interleaved within each round."""
    arproj = arproj_command()
    commands = {
        "arproj --help": [*arproj, "--help"],
        "arproj --version": [*arproj, "--version"],
        "arproj scan --help": [*arproj, "scan", "--help"],
        PEER: [sys.executable, "-c", "import typer, rich"],
        TYPER_FLOOR: [sys.executable, "-c", TYPER_FLOOR_CODE, "--help"],
        "python -c pass": [sys.executable, "-c", "pass"],
    }
    for cmd in commands.values():  # one untimed start each: the OS's file cache, the .pyc files written
        wall_time(cmd)
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(repeats):
        for name, cmd in commands.items():
            times[name].append(wall_time(cmd))
    return times


def run(quick: bool = False, seed: int = 0) -> BenchTable:
    del seed  # nothing random here
    repeats = QUICK_REPEATS if quick else REPEATS
    times = measure(repeats)
    peer = statistics.median(times[PEER])
    rows = []
    for name, ts in times.items():
        median = statistics.median(ts)
        targeted = name in ("arproj --help", "arproj --version")
        rows.append(StartRow(name, median, min(ts), max(ts), median / peer, f"≤ {TARGET_S} s" if targeted else "",
                             ("yes" if median <= TARGET_S else "NO") if targeted else ""))
    heavy = heavy_modules_loaded(["--help"])
    help_s, version_s = (statistics.median(times[n]) for n in ("arproj --help", "arproj --version"))
    return BenchTable(
        name="cli",
        title=f"Start-up of the command line, median of {repeats} runs each (interleaved)",
        columns=columns(StartRow), rows=[cells(r) for r in rows],
        notes=[f"peer: {PEER} in the same interpreter ({sys.executable}), run in the same rounds",
               f"{TYPER_FLOOR}: what typer's rich help costs any CLI (rich.console, markdown) beyond the peer",
               "bytecode caching on for every start (PYTHONDONTWRITEBYTECODE removed), as a user's Python has it",
               "heavy modules loaded by `arproj --help`: " + (", ".join(heavy) if heavy else "none")
               + f" (of {', '.join(HEAVY_MODULES)})"],
        headline={
            "arproj --help": {"arproj": round(help_s, 3), "unit": " s", "peer": round(peer, 3),
                              "peer_name": "import typer, rich", "target": f"≤ {TARGET_S} s",
                              "met": help_s <= TARGET_S},
            "arproj --version": {"arproj": round(version_s, 3), "unit": " s", "peer": round(peer, 3),
                                 "peer_name": "import typer, rich", "target": f"≤ {TARGET_S} s",
                                 "met": version_s <= TARGET_S},
            "heavy modules at --help": {"arproj": len(heavy), "peer": "–", "peer_name": "none",
                                        "target": "0", "met": not heavy},
        },
        environment={"repeats": repeats, "python": sys.executable, "arproj": arproj_command(),
                     "times_s": {n: [round(t, 4) for t in ts] for n, ts in times.items()}},
    )
