"""Terminal output shared by all commands: consoles, progress bars, tables."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

# Tables stay readable when output goes to a file or a CI log (rich would squeeze them to 80 columns).
console = Console(width=None if sys.stdout.isatty() else 150)
err_console = Console(stderr=True)

T = TypeVar("T")


class Interrupted(Exception):  # noqa: N818 - what a person sees: "interrupted"
    """Ctrl-C reached a command that says what it kept (`arproj demo`): the CLI prints the message as its one
    line and exits with status 130."""


def progress_bar() -> Progress:
    """A progress bar with count, elapsed time and an estimate of the time left (on stderr)."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("left"),
        TimeRemainingColumn(),
        console=err_console,
        transient=False,
    )


def track(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Iterate with a progress bar."""
    with progress_bar() as bar:
        yield from bar.track(items, total=total, description=description)
