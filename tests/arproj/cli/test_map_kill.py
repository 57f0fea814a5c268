"""`arproj map` killed with SIGKILL at seeded random moments while it writes its output folder (issue 24): the folder
then holds the old map whole or the new map whole — every file's hash that of one reference run, never a mix,
never a truncated PNG. (tests/arproj/cli/test_map_outputs.py kills once per file count; here the moments are drawn
over the measured writing window, so kills also land inside a file's write.)"""

from __future__ import annotations

import hashlib
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from arproj.cli import app
from mapping.simscan import simulate_scan, write_log
from scanner.wall import load_wall, shipped_walls

ROOT = Path(__file__).resolve().parents[3]
EXE = Path(sys.executable).parent / "arproj"
SEED = 24
KILLS = 4  # each is a whole `arproj map` process: a handful keeps the test near a minute
DXF = "objects.dxf"  # its header holds the time it was written and a fresh GUID: its ENTITIES are hashed
PNG_END = b"IEND\xaeB`\x82"  # the last chunk of every whole PNG

pytestmark = pytest.mark.skipif(not EXE.exists(), reason="the arproj console script is not installed here")


def _hashes(folder: Path) -> dict[str, str]:
    def content(p: Path) -> bytes:
        data = p.read_bytes()
        return data.partition(b"ENTITIES")[2].partition(b"OBJECTS")[0] if p.name == DXF else data

    return {p.name: hashlib.sha256(content(p)).hexdigest() for p in sorted(folder.iterdir())}


def _map(log: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen([str(EXE), "map", str(log), "--out", str(out), "--resolution", "6"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)


def _until_writing(proc: subprocess.Popen, out: Path) -> float:
    """Wait until the process has made its temporary folder (it starts writing) or ended; the time then."""
    tmp = out.with_name(f".{out.name}.new-{proc.pid}")
    while proc.poll() is None and not tmp.is_dir():
        time.sleep(0.002)
    return time.monotonic()


@pytest.fixture(scope="module")
def references(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A log, the old map (4 mm cells) and the new one (6 mm: every file differs but the JSON), and how long
    the new map's writing takes (from its temporary folder appearing to the process's end)."""
    root = tmp_path_factory.mktemp("kill")
    log = write_log(simulate_scan(load_wall(shipped_walls()["small_test_wall"]), seed=2), root / "scan.sqlite")
    done = CliRunner().invoke(app, ["map", str(log), "--out", str(root / "old"), "--resolution", "4"])
    assert done.exit_code == 0, done.output
    # the new map is written where the test's killed runs write: their command, which the files record, is its
    out = root / "work" / "map"
    out.parent.mkdir()
    proc = _map(log, out)
    started = _until_writing(proc, out)
    assert proc.wait() == 0
    window = time.monotonic() - started
    out.rename(root / "new")
    return {"log": log, "old": root / "old", "new": root / "new", "out": out, "window_s": window}


def test_sigkill_while_writing_leaves_the_old_or_the_new_map_whole(references: dict) -> None:
    old, new = _hashes(references["old"]), _hashes(references["new"])
    differ = [k for k in old if old[k] != new.get(k)]
    assert old.keys() == new.keys() and len(differ) >= 3, differ  # a mix would show
    delays = np.random.default_rng(SEED).uniform(0.0, 1.1 * references["window_s"], KILLS)
    out = references["out"]
    outcomes = []
    for delay in delays:
        shutil.copytree(references["old"], out)
        proc = _map(references["log"], out)
        _until_writing(proc, out)
        time.sleep(float(delay))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        state = _hashes(out)
        assert state in (old, new), f"killed {delay:.3f} s into writing: a mixed folder"
        for png in out.glob("*.png"):
            data = png.read_bytes()
            assert data.endswith(PNG_END) and cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) \
                is not None, f"{png.name} truncated"
        outcomes.append("new" if state == new else "old")
        shutil.rmtree(out)
        for leftover in out.parent.glob(".map.*"):  # a killed writer's temporary folder (the next run removes it)
            shutil.rmtree(leftover)
    print(f"SIGKILL {references['window_s']:.2f} s writing window, delays {np.round(delays, 3).tolist()}: {outcomes}")
    assert "old" in outcomes  # kills came while it wrote, not only after the swap
