"""The product's import graph, read from its source with `ast` (nothing is imported), and the checks on it.

Every `import` and `from … import` statement counts, also those inside functions (the lazy imports the CLI uses
to start fast) and those under `if TYPE_CHECKING:` (marked `type_only`, so a check can leave them out). Imports
built at run time (importlib.import_module) are not seen.

One record per imported module: `from wallpose.pattern import CheckerPattern, choose_pattern` is one Import of
wallpose.pattern with names ("CheckerPattern", "choose_pattern"); `from wallpose import limits`, where
wallpose/limits.py exists, is an Import of wallpose.limits with no names. A check over modules (cycles) reads
`target`; one over names (private names across modules, `private_imports`) reads `names`.
"""

from __future__ import annotations

import ast
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Import:
    """`importer` (a module, e.g. arproj.sim.site) imports `target` (a module), taking `names` from it."""

    importer: str
    target: str
    names: tuple[str, ...]
    path: Path
    line: int
    type_only: bool = False

    @property
    def importer_package(self) -> str:
        return self.importer.split(".")[0]

    @property
    def target_package(self) -> str:
        return self.target.split(".")[0]

    def where(self) -> str:
        return f"{self.path}:{self.line}"


def module_name(path: Path, root: Path) -> str:
    """The dotted module name of a .py file under root (a package's __init__.py is the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _type_checking_lines(tree: ast.AST) -> set[int]:
    """Line numbers of the statements under `if TYPE_CHECKING:` (or `if typing.TYPE_CHECKING:`)."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and (
                (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING")
                or (isinstance(node.test, ast.Attribute) and node.test.attr == "TYPE_CHECKING")):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


def _absolute(module: str | None, level: int, importer: str, is_package: bool) -> str:
    """The absolute module a (possibly relative) `from` import names."""
    if level == 0:
        return module or ""
    base = importer.split(".") if is_package else importer.split(".")[:-1]
    base = base[:len(base) - (level - 1)]
    return ".".join([*base, module] if module else base)


def read_imports(source: str, importer: str, path: Path, is_package: bool = False,
                 modules: Collection[str] = ()) -> list[Import]:
    """The imports in one module's source. `modules`: the known module names, so that `from pkg import mod`
    is recorded as an import of pkg.mod."""
    tree = ast.parse(source, filename=str(path))
    type_only = _type_checking_lines(tree)
    found: list[Import] = []
    for node in ast.walk(tree):
        guarded = getattr(node, "lineno", 0) in type_only
        if isinstance(node, ast.Import):
            found += [Import(importer, alias.name, (), path, node.lineno, guarded) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _absolute(node.module, node.level, importer, is_package)
            names = []
            for alias in node.names:
                if f"{target}.{alias.name}" in modules:
                    found.append(Import(importer, f"{target}.{alias.name}", (), path, node.lineno, guarded))
                else:
                    names.append(alias.name)
            if names:
                found.append(Import(importer, target, tuple(names), path, node.lineno, guarded))
    return sorted(found, key=lambda i: (i.line, i.target))


def product_imports(root: Path, packages: Iterable[str]) -> list[Import]:
    """Every import in every .py file of the given top-level packages under root (those that exist)."""
    files = sorted(f for package in packages if (root / package).is_dir() for f in (root / package).rglob("*.py"))
    modules = {module_name(f, root) for f in files}
    found: list[Import] = []
    for f in files:
        found += read_imports(f.read_text(encoding="utf-8"), module_name(f, root), f.relative_to(root),
                              is_package=f.name == "__init__.py", modules=modules)
    return found


def layer_violations(imports: Iterable[Import], layers: Sequence[Collection[str]],
                     allowed_siblings: Collection[tuple[str, str]] = (), data: Collection[str] = ()) -> list[str]:
    """One line per import that breaks the layering: layers[0] is the lowest; a package imports from its own
    layer only along an allowed (importer, target) sibling pair, never from a higher layer. `data` packages
    (e.g. shaders) may be imported by any package and import no package of the layers."""
    rank: Mapping[str, int] = {package: i for i, layer in enumerate(layers) for package in layer}
    problems = []
    for imp in imports:
        src, dst = imp.importer_package, imp.target_package
        if src == dst or dst not in rank:
            continue
        if src in data:
            problems.append(f"{imp.where()}: {imp.importer} imports {imp.target}, but {src} is data and imports "
                            "no package")
        elif src not in rank:
            continue
        elif rank[dst] > rank[src]:
            problems.append(f"{imp.where()}: {imp.importer} imports {imp.target}, a higher layer ({dst} is above "
                            f"{src})")
        elif rank[dst] == rank[src] and (src, dst) not in allowed_siblings:
            problems.append(f"{imp.where()}: {imp.importer} imports {imp.target}, a sibling in the same layer "
                            f"that {src} may not import")
    return problems


def is_private(name: str) -> bool:
    """One leading underscore, not a dunder (__version__, __all__ are public)."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_imports(imports: Iterable[Import], packages: Collection[str]) -> list[str]:
    """One line per import of a private name from another module of the given packages: `from x import _y`,
    or a private module (`from pkg import _mod`, `import pkg._mod`) from outside the package that holds it.
    Imports from other projects (numpy, scipy) are theirs to judge."""
    problems = []
    for imp in imports:
        if imp.target_package not in packages:
            continue
        names = [n for n in imp.names if is_private(n)]
        parts = imp.target.split(".")
        for k, part in enumerate(parts):
            holder = ".".join(parts[:k])
            if is_private(part) and not (imp.importer == holder or imp.importer.startswith(holder + ".")):
                names.append(".".join(parts[:k + 1]))
                break
        if names:
            problems.append(f"{imp.where()}: {imp.importer} imports private {', '.join(names)} from {imp.target}"
                            " (make it public if it is shared, else keep it in its module)")
    return problems


def package_edges(imports: Iterable[Import]) -> set[tuple[str, str]]:
    """(importer package, target package) pairs, between different top-level packages."""
    return {(i.importer_package, i.target_package) for i in imports if i.importer_package != i.target_package}


def module_edges(imports: Iterable[Import]) -> set[tuple[str, str]]:
    """(importer, target) pairs between two modules of the product read (those that are importers themselves),
    counting lazy and TYPE_CHECKING imports alike: a cycle under TYPE_CHECKING is the same tangle, only hidden
    from the interpreter. Importing a.b also runs a's __init__, which is not counted as an edge."""
    found = list(imports)
    modules = {i.importer for i in found}
    return {(i.importer, i.target) for i in found if i.target in modules and i.target != i.importer}


def find_cycle(edges: Collection[tuple[str, str]]) -> list[str] | None:
    """A cycle among the nodes of a directed graph (as a path that ends where it starts), or None."""
    graph: dict[str, list[str]] = {}
    for a, b in edges:
        graph.setdefault(a, []).append(b)
    state: dict[str, int] = {}     # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in graph.get(node, []):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            if nxt not in state and (cycle := visit(nxt)) is not None:
                return cycle
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start)) is not None:
            return cycle
    return None
