"""The product's layers, read from its import graph: data flows one way, and the libraries know no application.

Layers, lowest first: geometry ← {scanner, calibration, wallpose, render, devices} ← mapping ← arproj. shaders is
data (any package may load it; it imports none). A package imports from its own layer only along the sibling
pairs listed below, which must stay acyclic. No module takes a private name (`_name`) from another module of
the product. No two modules import each other, directly
or around a loop, also lazily or under TYPE_CHECKING. More checks over the same graph go beside these, reading
tests.support.import_graph.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from tests.support.import_graph import (
    Import,
    find_cycle,
    layer_violations,
    module_edges,
    package_edges,
    private_imports,
    product_imports,
    read_imports,
)

ROOT = Path(__file__).resolve().parent.parent

LAYERS: list[set[str]] = [
    {"geometry"},
    {"scanner", "calibration", "wallpose", "render", "devices"},
    {"mapping"},
    {"arproj"},
]
DATA = {"shaders"}
# The libraries: packages beside arproj/ that the application uses and that know nothing of it.
LIBRARIES = ("geometry", "calibration", "wallpose", "render", "devices")
# Imports between packages of the same layer that the code has (importer, target); none may close a cycle.
SIBLING_IMPORTS = {
    ("scanner", "devices"),       # scanner.hardware and scanner.sim.devices drive the drives and the wall scanner
    ("wallpose", "calibration"),  # wallpose.detect uses calibration.boards.as_gray
}

PACKAGES = sorted(set().union(*LAYERS) | DATA)


@pytest.fixture(scope="module")
def imports() -> list[Import]:
    found = product_imports(ROOT, PACKAGES)
    assert len(found) > 500  # the whole product was read, not an empty folder
    return found


def test_every_shipped_package_has_a_layer() -> None:
    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    shipped = {pattern.rstrip("*") for pattern in include}
    assert shipped <= set(PACKAGES), f"give these packages a layer in {__file__}: {sorted(shipped - set(PACKAGES))}"


def test_no_import_from_a_lower_layer_to_a_higher_one(imports: list[Import]) -> None:
    problems = layer_violations(imports, LAYERS, SIBLING_IMPORTS, DATA)
    assert not problems, "\n".join(problems)


def test_libraries_import_nothing_from_the_application(imports: list[Import]) -> None:
    from_app = [f"{i.where()}: {i.importer} imports {i.target}" for i in imports
                if i.importer_package in LIBRARIES and i.target_package == "arproj"]
    assert not from_app, "\n".join(from_app)


def test_no_product_module_imports_the_tests(imports: list[Import]) -> None:
    from_tests = [f"{i.where()}: {i.importer} imports {i.target}" for i in imports if i.target_package == "tests"]
    assert not from_tests, "\n".join(from_tests)


def test_the_allowed_sibling_imports_exist_and_are_acyclic(imports: list[Import]) -> None:
    rank = {package: i for i, layer in enumerate(LAYERS) for package in layer}
    assert all(rank[a] == rank[b] for a, b in SIBLING_IMPORTS)
    stale = SIBLING_IMPORTS - package_edges(imports)
    assert not stale, f"no longer imported, remove from SIBLING_IMPORTS: {sorted(stale)}"
    assert find_cycle(SIBLING_IMPORTS) is None


def test_no_private_name_is_imported_across_modules(imports: list[Import]) -> None:
    problems = private_imports(imports, PACKAGES)
    assert not problems, "\n".join(problems)


def test_no_import_cycle_between_modules(imports: list[Import]) -> None:
    cycle = find_cycle(module_edges(imports))
    assert cycle is None, "modules import each other: " + " → ".join(cycle or []) + (
        " (move what they share into a module below both)")


# ---- the checker itself, on small made-up modules ------------------------------------------------------------

FAKE = Path("fake.py")


def test_reader_resolves_relative_lazy_guarded_and_submodule_imports() -> None:
    source = (
        "from typing import TYPE_CHECKING\n"
        "import geometry.poses, numpy as np\n"
        "from . import limits\n"
        "from ..render.gl import create_context\n"
        "if TYPE_CHECKING:\n"
        "    from arproj.sim import Site\n"
        "def f():\n"
        "    from mapping import fusion, build_map\n"
    )
    found = read_imports(source, "wallpose.pose", FAKE, modules={"wallpose.limits", "mapping.fusion"})
    got = {(i.target, i.names, i.type_only) for i in found}
    assert got == {("typing", ("TYPE_CHECKING",), False), ("geometry.poses", (), False), ("numpy", (), False),
                   ("wallpose.limits", (), False), ("render.gl", ("create_context",), False),
                   ("arproj.sim", ("Site",), True), ("mapping.fusion", (), False), ("mapping", ("build_map",), False)}
    # a package's own relative import starts from the package itself
    (init,) = read_imports("from .rig import ViewRig\n", "wallpose", FAKE, is_package=True)
    assert init.target == "wallpose.rig"


@pytest.mark.parametrize(("importer", "target", "complaint"), [
    ("geometry.poses", "arproj.cli", "a higher layer"),
    ("calibration.boards", "mapping.grid", "a higher layer"),
    ("render.renderer", "scanner.wall", "a sibling"),
    ("shaders", "render.gl", "is data"),
])
def test_checker_flags_a_wrong_import(importer: str, target: str, complaint: str) -> None:
    (problem,) = layer_violations([Import(importer, target, (), FAKE, 3)], LAYERS, SIBLING_IMPORTS, DATA)
    assert problem.startswith("fake.py:3: ") and complaint in problem


@pytest.mark.parametrize(("importer", "target"), [
    ("arproj.demo", "geometry.poses"), ("mapping.fusion", "scanner.wall"), ("wallpose.detect", "calibration.boards"),
    ("render.renderer", "shaders"), ("geometry.poses", "numpy"), ("arproj.cli", "arproj.demo"),
])
def test_checker_passes_a_right_import(importer: str, target: str) -> None:
    assert layer_violations([Import(importer, target, (), FAKE, 1)], LAYERS, SIBLING_IMPORTS, DATA) == []


def test_checker_reads_a_tree_on_disk(tmp_path: Path) -> None:
    (tmp_path / "geometry").mkdir()
    (tmp_path / "geometry" / "__init__.py").write_text("")
    (tmp_path / "geometry" / "poses.py").write_text("def f():\n    from arproj.cli import app\n")
    found = product_imports(tmp_path, ["geometry", "missing"])
    assert [p.split(": ")[0] for p in layer_violations(found, LAYERS)] == [str(Path("geometry/poses.py")) + ":2"]


def test_find_cycle() -> None:
    assert find_cycle({("a", "b"), ("b", "c")}) is None
    assert find_cycle({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == ["a", "b", "c", "a"]


@pytest.mark.parametrize(("source", "importer", "complaint"), [
    ("from mapping.objects import MapObject, _join\n", "mapping.sparse", "private _join from mapping.objects"),
    ("from .fusion import _raw as raw\n", "mapping.sparse", "private _raw from mapping.fusion"),
    ("def f():\n    from scanner.plan import _straight_runs\n", "arproj.bench.scan", "private _straight_runs"),
    ("import render._gl_private\n", "arproj.sim.site", "private render._gl_private"),
])
def test_private_check_flags_a_made_up_import(source: str, importer: str, complaint: str) -> None:
    found = read_imports(source, importer, FAKE)
    (problem,) = private_imports(found, PACKAGES)
    assert problem.startswith("fake.py:") and complaint in problem


@pytest.mark.parametrize(("source", "importer"), [
    ("from mapping.objects import MapObject, join_polylines\n", "mapping.sparse"),  # public names
    ("from geometry import __version__\n", "arproj.cli"),                           # a dunder is public
    ("from scipy.optimize._numdiff import approx_derivative\n", "calibration.bundle"),  # not the product's
    ("from render._gl_private import make\n", "render.gl"),                          # inside its own package
])
def test_private_check_passes_a_made_up_import(source: str, importer: str) -> None:
    assert private_imports(read_imports(source, importer, FAKE), PACKAGES) == []


def test_cycle_check_flags_a_made_up_loop_through_a_lazy_and_a_guarded_import() -> None:
    sources = {
        "mapping.grid": "from mapping.background import background_level\n",
        "mapping.objects": "from mapping.grid import GridInfo\n",
        "mapping.background": "def f():\n    from mapping.objects import MapObject\n",   # lazy: still a loop
        "mapping.pipeline": "from mapping.objects import MapObject\n",
        "mapping.frame_features": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                  "    from mapping.pipeline import ScanData\n",
    }
    found = [i for module, source in sources.items() for i in read_imports(source, module, FAKE)]
    assert find_cycle(module_edges(found)) == ["mapping.background", "mapping.objects", "mapping.grid",
                                               "mapping.background"]
    # the loop broken, a guarded import back up is one too
    without = [i for i in found if i.importer != "mapping.background"]
    assert find_cycle(module_edges(without)) is None
    back = read_imports("from mapping.frame_features import frame_features\n", "mapping.pipeline", FAKE)
    assert find_cycle(module_edges(without + back)) == ["mapping.frame_features", "mapping.pipeline",
                                                        "mapping.frame_features"]
