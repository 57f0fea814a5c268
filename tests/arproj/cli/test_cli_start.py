"""The command line answers at once (issue 23 item 4): `arproj --help` imports none of the heavy libraries (they
are imported where they are used), an unquoted glob's extra arguments get a hint, and shipped wall names are
accepted by every --wall/--truth and checked before any work."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from arproj.bench.cli import heavy_modules_loaded
from arproj.cli import app, glob_hint
from geometry.errors import InputError
from scanner.wall import shipped_walls, wall_file


def test_help_and_version_import_no_heavy_module() -> None:
    assert heavy_modules_loaded(["--help"]) == []
    assert heavy_modules_loaded(["--version"]) == []


def test_the_probe_sees_a_heavy_import() -> None:
    """The check above can fail: a module that imports OpenCV, run through the same probe, shows it."""
    code = ("import sys, json; from arproj.bench.cli import HEAVY_MODULES; import cv2; "
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} & set(HEAVY_MODULES))))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "cv2" in json.loads(done.stdout)


def test_extra_arguments_that_are_files_get_the_glob_hint(tmp_path: Path) -> None:
    names = [tmp_path / f"left{i}.jpg" for i in range(3)]
    for name in names:
        name.write_bytes(b"")
    done = CliRunner().invoke(app, ["calibrate", "stereo", "--left", str(names[0]), str(names[1]), str(names[2]),
                                    "--right", "x", "--out", str(tmp_path / "rig")])
    assert done.exit_code == 2
    text = " ".join(done.output.replace("│", " ").split())  # rich wraps the message to the terminal's width
    assert "unquoted glob" in text and "quote the glob" in text
    assert not (tmp_path / "rig").exists()


def test_extra_arguments_that_are_not_files_keep_typers_message() -> None:
    message = "Got unexpected extra argument(s) (no-such-file another)"
    assert glob_hint(message) == message
    assert glob_hint("Missing option '--out'.") == "Missing option '--out'."


def test_shipped_wall_names_resolve_and_unknown_ones_name_them(tmp_path: Path) -> None:
    assert wall_file("small_test_wall") == shipped_walls()["small_test_wall"]
    own = tmp_path / "w.yaml"
    own.write_text("")
    assert wall_file(own) == own
    with pytest.raises(InputError, match=r"--truth nowall: no such file.*small_test_wall"):
        wall_file("nowall", "--truth")


@pytest.mark.parametrize("args", [["map", "LOG", "--wall", "nowall", "--out", "OUT"],
                                  ["project", "--truth", "nowall", "--sim"],
                                  ["scan", "--sim", "--wall", "nowall", "--log", "OUT"],
                                  ["demo", "--wall", "nowall", "--out", "OUT"],
                                  ["devices", "serve", "--wall", "nowall"],
                                  ["import-scan", "LOG", "--out", "OUT", "--wall", "nowall"]])
def test_an_unknown_wall_is_refused_before_any_work(tmp_path: Path, args: list[str],
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """Refused with exit 2 before the log is read (it does not exist here), the simulated site is built or an
    output is written."""
    from arproj.cli import main

    out = tmp_path / "out"
    args = [str(tmp_path / "missing.db") if a == "LOG" else str(out) if a == "OUT" else a for a in args]
    monkeypatch.setattr(sys, "argv", ["arproj", *args])
    with pytest.raises(SystemExit) as done:
        main()
    assert done.value.code == 2
    assert "nowall: no such file" in capsys.readouterr().err
    assert not out.exists()


def test_live_calibration_without_a_stereo_pair_is_refused_before_the_site_starts(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """`calibrate projector --live --sim` on a rig folder with no stereo pair (and no --stereo N): one line,
    exit 2, and the simulated site (a process of its own, seconds to start) never started."""
    import arproj.sim.live
    from arproj.cli import main

    def no_site(*args: object, **kwargs: object) -> None:
        raise AssertionError("the simulated site was started")

    monkeypatch.setattr(arproj.sim.live, "SpawnedLiveSite", no_site)
    monkeypatch.setattr(sys, "argv", ["arproj", "calibrate", "projector", "--live", "--sim", "--rig",
                                      str(tmp_path / "rig")])
    with pytest.raises(SystemExit) as done:
        main()
    assert done.value.code == 2
    assert "no calibrated stereo pair" in capsys.readouterr().err


def test_the_shipped_scene_is_taken_by_its_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`arproj site --scene default` is the built-in scene (as without --scene); a file of that name in the
    working directory would win, as a wall file does over a shipped wall's name."""
    import arproj.sim

    built: list[object] = []

    def build(scene: object = None, seed: int = 0) -> None:
        built.append(scene)
        raise InputError("stopped before building")

    monkeypatch.setattr(arproj.sim.Site, "build", staticmethod(build))
    monkeypatch.chdir(tmp_path)
    for _ in range(2):
        done = CliRunner().invoke(app, ["site", "--scene", "default", "--out", str(tmp_path / "pictures")])
        assert done.exit_code == 1 and isinstance(done.exception, InputError)
        Path("default").write_text("room: {}\n")
    assert built == [None, Path("default")]


def test_resume_takes_the_shipped_wall_by_its_name(tmp_path: Path) -> None:
    """`arproj scan --resume LOG --wall NAME` resolves NAME as `--log` does (it was refused as "no such wall
    file"); the wall is still checked against the log's."""
    log = tmp_path / "scan.db"
    done = CliRunner().invoke(app, ["scan", "--sim", "--fast", "--wall", "small_test_wall", "--log", str(log),
                                    "--no-site"])
    assert done.exit_code == 0, done.output
    done = CliRunner().invoke(app, ["scan", "--resume", str(log), "--wall", "small_test_wall", "--no-site"])
    assert done.exit_code == 0, done.output
    assert "scan already complete" in done.output
    done = CliRunner().invoke(app, ["scan", "--resume", str(log), "--wall", "paper_test_plate", "--no-site"])
    assert done.exit_code == 1 and "from another wall" in str(done.exception)
