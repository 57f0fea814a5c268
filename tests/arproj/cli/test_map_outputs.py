"""`arproj map --out M` writes M whole (issue 24 item 3): every input is checked before anything is written, the
map goes to a sibling folder that then takes M's place, so a refusal, a failure or a kill -9 at any moment
leaves either the earlier complete map or the new one."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from arproj.cli import app
from geometry import provenance
from mapping.simscan import simulate_scan, write_log
from scanner.wall import load_wall, shipped_walls

ROOT = Path(__file__).resolve().parents[3]
EXE = Path(sys.executable).parent / "arproj"
DXF = "objects.dxf"  # its header holds the time it was written and a fresh GUID: compared are its ENTITIES


@pytest.fixture(scope="module")
def maps(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A log of small_test_wall and two maps of it (4 mm and 6 mm cells: every file differs but the JSON)."""
    root = tmp_path_factory.mktemp("maps")
    log = write_log(simulate_scan(load_wall(shipped_walls()["small_test_wall"]), seed=2), root / "scan.sqlite")
    for name, resolution in (("old", "4"), ("new", "6")):
        done = CliRunner().invoke(app, ["map", str(log), "--out", str(root / name), "--resolution", resolution])
        assert done.exit_code == 0, done.output
    return {"log": log, "old": root / "old", "new": root / "new"}


def _content(folder: Path) -> dict[str, bytes]:
    def entities(data: bytes) -> bytes:
        return data.partition(b"ENTITIES")[2].partition(b"OBJECTS")[0]

    return {p.name: (entities(p.read_bytes()) if p.name == DXF else p.read_bytes()) for p in sorted(folder.iterdir())}


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_a_refused_input_leaves_the_earlier_map_as_it_was(maps: dict[str, Path], tmp_path: Path) -> None:
    out = _copy(maps["old"], tmp_path / "map")
    before = _content(out)
    bad_wall = tmp_path / "bad.yaml"
    bad_wall.write_text("format: arproj-wall/1\nwidth_m: -3\n")
    bad_npz = tmp_path / "views.npz"
    bad_npz.write_text("not an npz")
    for extra in (["--wall", str(bad_wall)], ["--range-images", str(bad_npz)], ["--resolution", "0"]):
        done = CliRunner().invoke(app, ["map", str(maps["log"]), "--out", str(out), *extra])
        assert done.exit_code != 0 and done.exception is not None
        assert _content(out) == before, extra
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml", "map", "views.npz"]  # no leftovers


def test_a_folder_holding_other_files_is_refused_untouched(maps: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep\n")
    done = CliRunner().invoke(app, ["map", str(maps["log"]), "--out", str(out)])
    assert done.exit_code != 0 and "holds what a map folder does not (notes.txt)" in str(done.exception)
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


def test_a_failure_while_writing_keeps_the_old_map(maps: dict[str, Path], tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from mapping.exports import signals_png

    out = _copy(maps["old"], tmp_path / "map")
    before = _content(out)

    def broken(job: object) -> Path:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(signals_png, "write", broken)  # the last-but-one file: the others are written by then
    done = CliRunner().invoke(app, ["map", str(maps["log"]), "--out", str(out), "--resolution", "6"])
    assert isinstance(done.exception, OSError)
    assert _content(out) == before and [p.name for p in tmp_path.iterdir()] == ["map"]


@pytest.mark.skipif(not EXE.exists(), reason="the arproj console script is not installed here")
def test_kill_9_at_any_moment_of_writing_leaves_the_old_or_the_new_map(maps: dict[str, Path], tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "map"
    command = ["map", str(maps["log"]), "--out", str(out), "--resolution", "6"]
    # the files record the command that made them: the new map made here as the killed processes make it
    monkeypatch.setattr(provenance, "_command", [provenance.PROGRAM, *command])
    reference = maps["log"].parent / "kill-new"  # beside the log: tmp_path holds only the map and its siblings
    assert CliRunner().invoke(app, [*command[:3], str(reference), *command[4:]]).exit_code == 0
    old, new = _content(maps["old"]), _content(reference)
    outcomes = []
    # kill once the new folder holds none, one, half, all but one and all of the files (each kill is a process
    # of seconds; tests/arproj/cli/test_map_kill.py kills at random moments inside files' writes)
    for written in sorted({0, 1, len(new) // 2, len(new) - 1, len(new)}):
        _copy(maps["old"], out)
        proc = subprocess.Popen([str(EXE), *command], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                cwd=ROOT)
        tmp = tmp_path / f".map.new-{proc.pid}"
        while proc.poll() is None and not (tmp.is_dir() and len(list(tmp.iterdir())) >= written):
            time.sleep(0.002)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        state = _content(out)
        assert state in (old, new), f"killed with {written} files written: a mixed folder {sorted(state)}"
        outcomes.append("new" if state == new else "old")
        if written < len(new):
            shutil.rmtree(out)
    # one run after all the kills clears what every killed one left (a process per kill costs seconds)
    done = CliRunner().invoke(app, command)
    assert done.exit_code == 0, done.output
    assert _content(out) == new and [p.name for p in tmp_path.iterdir()] == ["map"]
    print(f"kill -9 outcomes: {outcomes}")
    assert "old" in outcomes  # the kills came while writing, not only after the swap


def test_a_shipped_wall_name_is_the_truth_of_wall(maps: dict[str, Path], tmp_path: Path) -> None:
    done = CliRunner().invoke(app, ["map", str(maps["log"]), "--out", str(tmp_path / "map"), "--wall",
                                    "small_test_wall"])
    assert done.exit_code == 0, done.output
    assert "against small_test_wall: recall 100.0% (2/2)" in done.output


def test_the_progress_bar_ends_at_its_total(maps: dict[str, Path], tmp_path: Path) -> None:
    """The bar counts the steps there are (reading, mapping, one per export): it ends at N/N, not 9/8."""
    import re

    done = CliRunner().invoke(app, ["map", str(maps["log"]), "--out", str(tmp_path / "map")])
    assert done.exit_code == 0, done.output
    counts = re.findall(r"(\d+)/(\d+) ", done.output)
    assert counts and counts[-1][0] == counts[-1][1], done.output
