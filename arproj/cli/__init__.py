"""The `arproj` command line.

Each module in this package adds its own commands through `register(app, bench_app)`, so a feature's CLI
lives beside nothing else and this file never needs editing. Bad input (geometry.InputError) is printed as
one line naming what to fix, with exit status 2, never a traceback. Ctrl-C at any moment, from the first
import on, ends with one line and exit status 130 (a second Ctrl-C while the first is cleaned up exits at once).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from types import FrameType

INTERRUPTED = "arproj: interrupted (Ctrl-C)"
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report it


def _exit_now(signum: int, frame: FrameType | None) -> None:
    """A Ctrl-C while the first one is being cleaned up: write the line and leave (committed data is safe; a
    scan log's open batch is rolled back by SQLite)."""
    os.write(2, f"\n{INTERRUPTED}\n".encode())
    os._exit(EXIT_INTERRUPTED)


def _interrupt_once(signum: int, frame: FrameType | None) -> None:
    signal.signal(signal.SIGINT, _exit_now)
    raise KeyboardInterrupt


try:  # everything the commands need is imported here: a Ctrl-C meanwhile is one line, not a traceback
    import importlib
    import pkgutil

    import typer

    from arproj.console import Interrupted
    from geometry.errors import InputError

    class _Group(typer.core.TyperGroup):
        """The root command: a usage error for extra arguments that are files says how it came about."""

        def invoke(self, ctx: typer.Context) -> object:
            try:
                return super().invoke(ctx)
            except typer._click.exceptions.UsageError as err:
                err.message = glob_hint(err.message)
                raise

    app = typer.Typer(
        name="arproj",
        cls=_Group,
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

    def _print_version(asked: bool) -> None:
        if asked:
            from geometry import provenance

            print(f"arproj {provenance.version()}")
            raise typer.Exit()

    @app.callback()
    def _options(version: bool = typer.Option(False, "--version", is_eager=True, callback=_print_version,
                                              help="Print arproj's version and exit.")) -> None:
        pass

    for _module in sorted(m.name for m in pkgutil.iter_modules(__path__)):
        importlib.import_module(f"{__name__}.{_module}").register(app, bench_app)
except KeyboardInterrupt:
    print(f"\n{INTERRUPTED} while starting", file=sys.stderr)
    sys.exit(EXIT_INTERRUPTED)


def glob_hint(message: str) -> str:
    """typer's "Got unexpected extra argument(s) (A B …)", when they name files, with the likely cause: a shell
    expanded an unquoted glob (`--left DIR/left*.jpg`) into many names, of which the option took the first."""
    prefix = "Got unexpected extra argument"
    if not message.startswith(prefix) or "(" not in message:
        return message
    extra = message[message.index("(") + 1:].removesuffix(")").split(" ")
    if not any(os.path.exists(name) for name in extra):
        return message
    return (f"{message}: these are files, as the shell makes of an unquoted glob — quote the glob (e.g. "
            "'DIR/left*.jpg') so that arproj gets the pattern")


_built: dict[tuple[int, int], typer.core.TyperGroup] = {}


def _command() -> typer.core.TyperGroup:
    """The click command typer builds from `app`, built once (typer rebuilds it on every `app()`, 0.2 s: what
    in-process callers of main(), such as the bad-input suite's thousand runs, would pay each time); rebuilt
    when commands are added."""
    key = (len(app.registered_commands), len(app.registered_groups))
    if key not in _built:
        _built.clear()
        _built[key] = typer.main.get_group(app)
    return _built[key]


def main() -> None:
    """Console-script entry point."""
    from rich.markup import escape

    from arproj.console import err_console
    from geometry import provenance

    provenance.set_command(sys.argv[1:])
    previous = signal.getsignal(signal.SIGINT)
    handled = threading.current_thread() is threading.main_thread() and previous is signal.default_int_handler
    if handled:  # not when started with SIGINT ignored (or from a thread, or under another handler)
        signal.signal(signal.SIGINT, _interrupt_once)
    try:
        _command()()  # standalone: usage errors print a hint; KeyboardInterrupt becomes exit status 130
    except InputError as err:
        # escaped: a value quoted from a file ("[/x]") is text, not markup
        err_console.print(f"[bold red]arproj: error:[/] {escape(str(err))}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except Interrupted as err:  # a command that says what it kept
        err_console.print(f"\n[bold red]arproj: interrupted:[/] {err}", highlight=False, soft_wrap=True)
        sys.exit(EXIT_INTERRUPTED)
    except KeyboardInterrupt:  # outside a command (typer's own start, its output)
        err_console.print(f"\n{INTERRUPTED}", highlight=False, soft_wrap=True)
        sys.exit(EXIT_INTERRUPTED)
    except SystemExit as done:
        if done.code == EXIT_INTERRUPTED:  # typer's exit status for a KeyboardInterrupt in a command
            err_console.print(f"\n{INTERRUPTED}", highlight=False, soft_wrap=True)
        raise
    finally:
        if handled:  # main() called in-process (tests): leave the caller's Ctrl-C as it was
            signal.signal(signal.SIGINT, previous)
