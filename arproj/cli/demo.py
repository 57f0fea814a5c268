"""`arproj demo`: the whole system on the simulated site, no hardware."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command()
    def demo(
        out: Path = typer.Option(Path("arproj-out/demo"), "--out", help="Folder for the report and pictures."),
        resume: bool = typer.Option(False, "--resume", help="Skip the stages an earlier run finished."),
    ) -> None:
        """Run arproj end to end on the simulated site and write report.html with pictures and figures."""
        from arproj.demo import print_summary, run_demo

        print_summary(run_demo(out, resume=resume))
