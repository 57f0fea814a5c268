"""The console helpers every command reports its progress with: a step with nothing to count (`working`) shows
what runs, and the bars of its parts show inside it (nested live displays) rather than failing."""

from __future__ import annotations

import io

import pytest
from rich.console import Console

import arproj.console
from arproj.console import progress_bar, track, working


@pytest.fixture
def terminal(monkeypatch: pytest.MonkeyPatch) -> io.StringIO:
    """err_console as a terminal writing into a string (the live displays render only on a terminal)."""
    text = io.StringIO()
    monkeypatch.setattr(arproj.console, "err_console", Console(file=text, force_terminal=True, width=100))
    return text


def test_a_step_shows_its_name_and_the_bars_inside_it(terminal: io.StringIO) -> None:
    with working("building the site") as step:
        assert list(track(range(3), "photos")) == [0, 1, 2]
        step("fitting the plane")
        with progress_bar() as bar:
            task = bar.add_task("frames", total=2)
            bar.advance(task, 2)
        arproj.console.err_console.print("a line meanwhile")
    out = terminal.getvalue()
    for text in ("building the site", "photos", "3/3", "fitting the plane", "frames", "2/2", "a line meanwhile"):
        assert text in out, text


def test_a_step_off_a_terminal_prints_nothing_of_its_own(monkeypatch: pytest.MonkeyPatch) -> None:
    """In a log file the spinner would be noise: only what the step prints itself is written."""
    text = io.StringIO()
    monkeypatch.setattr(arproj.console, "err_console", Console(file=text, force_terminal=False))
    with working("building the site"):
        arproj.console.err_console.print("a line meanwhile")
    assert text.getvalue() == "a line meanwhile\n"
