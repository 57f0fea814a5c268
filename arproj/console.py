"""Terminal output shared by all commands: consoles, progress bars, tables."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, TypeVar

from rich.console import Console

if TYPE_CHECKING:
    from rich.progress import Progress

# Tables stay readable when output goes to a file or a CI log (rich would squeeze them to 80 columns).
console = Console(width=None if sys.stdout.isatty() else 150)
err_console = Console(stderr=True)

T = TypeVar("T")


class Interrupted(Exception):  # noqa: N818 - what a person sees: "interrupted"
    """Ctrl-C reached a command that says what it kept (`arproj demo`): the CLI prints the message as its one
    line and exits with status 130."""


def progress_bar(auto_refresh: bool = True) -> Progress:
    """A progress bar with count, elapsed time and an estimate of the time left (on stderr). auto_refresh=False:
    redrawn at each step, with no thread of its own."""
    from rich.progress import (  # not at import: `arproj --help` needs none of it
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("left"),
        TimeRemainingColumn(),
        console=err_console,
        transient=False,
        auto_refresh=auto_refresh,
    )


def track(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Iterate with a progress bar. Redrawn at each item, without rich's refresh threads: a loop left by an
    exception leaves this generator to be closed by the garbage collector, at any moment, and closing one that
    joins a refresh thread then deadlocks when it happens inside rich's own lock (seen in calibrate camera)."""
    with progress_bar(auto_refresh=False) as bar:
        yield from bar.track(items, total=total, description=description)


@contextlib.contextmanager
def working(description: str) -> Iterator[Callable[[str], None]]:
    """A step with nothing to count (building a site, a registration): one line on stderr with a spinner, what
    runs and for how long, gone when it ends. Yields a function that says which part runs now; lines printed
    on err_console meanwhile appear above it."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    if not err_console.is_terminal:  # a log file: a spinner is noise there (and rich would end it with a blank line)
        yield lambda text: None
        return
    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(), console=err_console,
                  transient=True) as bar:
        task = bar.add_task(description, total=None)
        yield lambda text: bar.update(task, description=text)
