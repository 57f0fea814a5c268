"""`arproj demo`: the whole system on the simulated site, no hardware."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command()
    def demo(
        wall: str = typer.Option("demo_brick_wall", "--wall", help="Wall file (YAML/JSON) with the truth, or a "
                                 "shipped wall's name: demo_brick_wall, small_test_wall, paper_test_plate, "
                                 "drywall_studs."),
        out: Path = typer.Option(Path("arproj-out/demo"), "--out", help="Folder for report.html, its pictures "
                                 "and every stage's files."),
        resume: bool = typer.Option(False, "--resume", help="Skip the stages an earlier run in --out finished "
                                    "(an interrupted scan continues where it stopped)."),
        quick: bool = typer.Option(False, "--quick", help="Quicker settings for tests: in-process scan, fewer "
                                   "calibration poses."),
        seed: int = typer.Option(0, "--seed", help="Seed of the simulation."),
        rig: Path = typer.Option(None, "--rig", help="Rig folder from `arproj calibrate --sim` to use instead "
                                 "of calibrating in this run (same --seed: the same simulated robot)."),
    ) -> None:
        """Run arproj end to end on the simulated site (scan → map → mesh → calibrate → wall pose → pre-warp →
        photograph) and write report.html with pictures and the accuracy against the truth."""
        from arproj.console import Interrupted
        from scanner.wall import wall_file

        wall_file(wall)  # a wrong --wall: refused at once, before the demo's imports (OpenCV, GL)
        from arproj.demo import DemoOptions, print_summary, run_demo

        try:
            ctx = run_demo(DemoOptions(out=out, wall=wall, resume=resume, quick=quick, seed=seed,
                                       rig=rig))
        except KeyboardInterrupt:
            raise Interrupted(f"the finished stages are saved in {out}; run `arproj demo --out {out} --resume` "
                              "to go on from there") from None
        print_summary(ctx)
        if any(r.status in ("failed", "not run") for r in ctx.stages.values()):
            raise typer.Exit(1)
