"""The map's export formats: one module each, found by the package, written in order; a new module is a new
format."""

import sys
import types

from mapping import exports


def test_every_format_module_is_found_in_writing_order() -> None:
    names = [m.FILE_NAME for m in exports.formats()]
    # the projection session's mesh first; the files `arproj map` has always written, each once
    assert names == ["wall.glb", "objects.json", "coverage.npz", "map.png", "signals.png", "objects.dxf"]


def test_a_new_module_is_a_new_format(tmp_path, monkeypatch) -> None:
    """A module dropped into the package (here a made-up CSV of object classes) is written with the rest."""
    package_dir = tmp_path / "extra"
    package_dir.mkdir()
    (package_dir / "classes_csv.py").write_text(
        "from pathlib import Path\n"
        "FILE_NAME = 'classes.csv'\n"
        "ORDER = 70\n"
        "def write(job) -> Path:\n"
        "    path = job.out_dir / FILE_NAME\n"
        "    path.write_text('\\n'.join(o.cls for o in job.objects))\n"
        "    return path\n")
    monkeypatch.setattr(exports, "__path__", [*exports.__path__, str(package_dir)])
    monkeypatch.delitem(sys.modules, "mapping.exports.classes_csv", raising=False)
    found = exports.formats()
    assert [m.FILE_NAME for m in found][-1] == "classes.csv"
    job = types.SimpleNamespace(out_dir=tmp_path, objects=[types.SimpleNamespace(cls="power_line")])
    assert found[-1].write(job).read_text() == "power_line"
