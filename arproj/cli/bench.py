"""`arproj bench NAME` for every module in arproj.bench, and `arproj bench all`."""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Callable

import typer

from arproj.bench import QUICK_CAVEAT, BenchTable, benchmark_docs, headline_table
from arproj.console import console, err_console


def _run_and_print(name: str, as_json: bool, quick: bool, seed: int, **options: object) -> None:
    # Whatever a benchmark says while it runs goes to stderr: stdout carries only the table (or the JSON).
    import importlib  # the benchmark (scipy, OpenCV, GL) only when it runs: `--help` stays fast

    module = importlib.import_module(f"arproj.bench.{name}")
    with contextlib.redirect_stdout(sys.stderr):
        table: BenchTable = module.run(quick=quick, seed=seed, **options)
    table.environment["quick"] = quick
    if as_json:
        print(table.to_json())
    else:
        table.print()


_JSON_HELP = "Print the results as JSON instead of a table."
_QUICK_HELP = "Fewer trials, for a fast check (figures are noisier; targets are judged on the full run)."
_SEED_HELP = "Seed of the simulated inputs."


def _command(name: str, doc: str) -> Callable[..., None]:
    def command(
        as_json: bool = typer.Option(False, "--json", help=_JSON_HELP),
        quick: bool = typer.Option(False, "--quick", help=_QUICK_HELP),
        seed: int = typer.Option(0, "--seed", help=_SEED_HELP),
    ) -> None:
        _run_and_print(name, as_json, quick, seed)

    command.__doc__ = doc.strip()
    return command


def _calibration_command(doc: str) -> Callable[..., None]:
    def command(
        as_json: bool = typer.Option(False, "--json", help=_JSON_HELP),
        quick: bool = typer.Option(False, "--quick", help=_QUICK_HELP),
        seed: int = typer.Option(0, "--seed", help=_SEED_HELP),
        live_seeds: int | None = typer.Option(None, "--live-seeds", min=1, help="Seeds of the simulated live "
                                              "calibration (seed, seed+1, …; about 100 s each); default 20, "
                                              "--quick 1."),
    ) -> None:
        _run_and_print("calibration", as_json, quick, seed, live_seeds=live_seeds)

    command.__doc__ = doc.strip()
    return command


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    modules = benchmark_docs()
    for name, doc in modules.items():
        bench_app.command(name)(_calibration_command(doc) if name == "calibration" else _command(name, doc))

    @bench_app.command("all")
    def bench_all(
        as_json: bool = typer.Option(False, "--json", help="Print every result as one JSON document."),
        quick: bool = typer.Option(False, "--quick", help="Fewer trials in every benchmark."),
        seed: int = typer.Option(0, "--seed", help="Seed of the simulated inputs."),
    ) -> None:
        """Run every benchmark, each in its own process, and print one summary table of the headline figures."""
        results: dict[str, BenchTable | str] = {}
        for name in modules:
            err_console.print(f"[bold]bench {name}[/] …")
            results[name] = _run_isolated(name, quick, seed)
            if isinstance(results[name], str):
                err_console.print(f"[red]bench {name} failed:[/] {results[name]}")
            elif not as_json:
                results[name].print(targets=False)  # the summary below has them all
        if as_json:
            print(json.dumps({n: (json.loads(t.to_json()) if isinstance(t, BenchTable) else {"failed": t})
                              for n, t in results.items()}, indent=2))
            return
        summary = headline_table([(n, t.headline) for n, t in results.items() if isinstance(t, BenchTable)],
                                 title="arproj bench all — headline figures" + (QUICK_CAVEAT if quick else ""))
        for name, table in results.items():
            if isinstance(table, str):
                summary.add_row(name, "failed", "–", "–", "", "", "NO")
        console.print(summary)
        if any(isinstance(t, str) for t in results.values()):
            raise typer.Exit(1)


def _run_isolated(name: str, quick: bool, seed: int) -> BenchTable | str:
    """One benchmark in a fresh process: GL contexts, EGL displays (pyrender terminates its display when it is
    done) and memory of one benchmark cannot disturb the next. Returns the table, or why it failed."""
    import subprocess

    cmd = [sys.executable, "-c", "from arproj.cli import main; main()", "bench", name, "--json", "--seed", str(seed)]
    if quick:
        cmd.append("--quick")
    done = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=None, text=True)
    if done.returncode != 0:
        return f"exit status {done.returncode} (its messages are above)"
    try:
        return BenchTable(**json.loads(done.stdout))
    except (json.JSONDecodeError, TypeError) as err:
        return f"unreadable result ({err})"
