"""The `arproj` command line.

Each module in this package adds its own commands through `register(app, bench_app)`, so a feature's CLI
lives beside nothing else and this file never needs editing. Bad input (geometry.InputError) is printed as
one line naming what to fix, with exit status 2, never a traceback.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import typer

from geometry.errors import InputError

app = typer.Typer(
    name="arproj",
    help="Find what is hidden inside a wall (power lines, pipes, cavities) and project it back onto that "
    "wall, undistorted.\n\nStart with `arproj demo`: the whole system on a simulated site, no hardware.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode="markdown",
)
bench_app = typer.Typer(
    help="Speed and accuracy benchmarks. Each runs its peer (OpenCV, pyrender, the paper's method) on the "
    "same input in the same run and prints the ratio; --json for machines.",
    no_args_is_help=True,
)
app.add_typer(bench_app, name="bench")

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
    importlib.import_module(f"{__name__}.{_module}").register(app, bench_app)


def main() -> None:
    """Console-script entry point."""
    from arproj.console import err_console

    try:
        app()  # standalone: usage errors print a hint; Ctrl-C becomes "Aborted!" and exit 1
    except InputError as err:
        err_console.print(f"[bold red]arproj: error:[/] {err}", highlight=False, soft_wrap=True)
        sys.exit(2)
