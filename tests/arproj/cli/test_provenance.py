"""Every output says which arproj made it and by which command (issue 22 item 4): the command line records
itself, and objects.json, the GLB's extras, the DXF header, the map_server YAML, the scan log and rig.yaml carry
it."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import ezdxf
import pytest
import trimesh
import yaml

from arproj.cli import main
from geometry import provenance
from geometry.rig import Rig
from scanner.log import ScanLog
from tests.support.hazard_wall import hazard_wall_dense_map


def test_the_version_is_the_installed_packages() -> None:
    import arproj

    assert provenance.version() == arproj.__version__


def test_the_command_line_records_what_the_user_typed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`arproj drill` through main(), as the console script runs it: the recorded command is the argv given."""
    monkeypatch.setattr(provenance, "_command", None)
    argv = ["arproj", "drill", str(tmp_path / "no such map"), "--at", "0.1,0.1"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(SystemExit):
        main()
    assert provenance.command() == shlex.join(argv)
    assert provenance.record() == {"program": "arproj", "version": provenance.version(),
                                   "command": provenance.command()}


def test_every_map_file_and_log_and_rig_names_its_maker(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mapping import exports

    monkeypatch.setattr(provenance, "_command", ["arproj", "map", "scan.db", "--out", "map"])
    made_by = provenance.record()
    assert made_by["command"] == "arproj map scan.db --out map"
    result, objects = hazard_wall_dense_map()
    job = exports.ExportJob(data=None, result=result, out_dir=tmp_path, objects=objects)  # type: ignore[arg-type]
    for module in exports.formats():
        if module.FILE_NAME in ("objects.json", "wall.glb", "objects.dxf", "map_server.yaml"):
            module.write(job)
    assert json.loads((tmp_path / "objects.json").read_text())["made_by"] == made_by
    scene = trimesh.load(tmp_path / "wall.glb")
    assert scene.metadata["extras"]["made_by"] == made_by
    header = ezdxf.readfile(tmp_path / "objects.dxf").header.custom_vars
    assert header.get("ARPROJ_VERSION") == made_by["version"]
    assert header.get("ARPROJ_COMMAND") == made_by["command"]
    assert (tmp_path / "map_server.yaml").read_text().splitlines()[0] == f"# {provenance.line()}"
    log = ScanLog.create(tmp_path / "scan.db", {"wall_fingerprint": "x"})
    log.close()
    assert ScanLog.open(tmp_path / "scan.db").meta["made_by"] == made_by
    Rig(intrinsics={}, poses={}).save(tmp_path / "rig")
    assert yaml.safe_load((tmp_path / "rig" / "rig.yaml").read_text())["made_by"] == made_by


def test_arproj_version_prints_the_version(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["arproj", "--version"])
    with pytest.raises(SystemExit) as done:
        main()
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"arproj {provenance.version()}"
