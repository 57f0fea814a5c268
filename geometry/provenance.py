"""Which arproj made a file, and by which command: every output records it (objects.json, the GLB's extras, the
DXF header, the scan log's meta, rig.yaml, the report, the map_server YAML), so a file found on a site laptop
months later says where it came from.

The command is what the user typed (`arproj map scan.db --out map`): arproj's command line records it when it
starts (`set_command`); a file written by a library call from elsewhere names that process's own command line.
"""

from __future__ import annotations

import shlex
import sys
from functools import cache

PROGRAM = "arproj"
_command: list[str] | None = None


@cache
def version() -> str:
    """The installed arproj's version (the package metadata pyproject.toml gives)."""
    from importlib import metadata  # 0.07 s: paid by --version and the outputs, not by every start

    try:
        return metadata.version(PROGRAM)
    except metadata.PackageNotFoundError:  # a source tree that was never installed
        return "unknown (not installed)"


def set_command(argv: list[str]) -> None:
    """Record the arproj command line being run: its arguments after the program name."""
    global _command
    _command = [PROGRAM, *argv]


def command() -> str:
    """The command that is making the file, as a shell would take it."""
    return shlex.join(_command if _command is not None else sys.argv)


def record() -> dict[str, str]:
    """{"program", "version", "command"}: what outputs store under "made_by" (no time: two runs of one command
    write the same bytes where the file has no time of its own)."""
    return {"program": PROGRAM, "version": version(), "command": command()}


def line() -> str:
    """One line for text outputs' headers and comments."""
    return f"made by {PROGRAM} {version()}: {command()}"
