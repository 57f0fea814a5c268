"""devices is a library: it imports the standard library, pyserial, numpy and geometry, nothing of its users."""

import ast
import sys
from pathlib import Path

import devices

ALLOWED = {"devices", "geometry", "serial", "numpy"}


def test_devices_imports_nothing_of_scanner_mapping_or_arproj():
    root = Path(devices.__file__).parent
    found: dict[str, set[str]] = {}
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in ALLOWED and top not in sys.stdlib_module_names:
                    found.setdefault(str(path.relative_to(root)), set()).add(name)
    assert len(list(root.rglob("*.py"))) >= 8  # the walk saw the package
    assert found == {}
