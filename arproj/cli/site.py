"""`arproj site`: build a simulated site and write pictures of what its cameras see."""

from __future__ import annotations

from pathlib import Path

import typer

from arproj.console import console, working

SHIPPED_SCENE = "default"  # arproj/sim/scenes/default.yaml, the scene without --scene


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("site")
    def site_command(
        out: Path = typer.Option(Path("site-pictures"), "--out", help="Folder for the pictures."),
        scene: Path | None = typer.Option(None, "--scene", help="Scene YAML, or `default`: the built-in "
                                          "typical room (arproj/sim/scenes/default.yaml, which documents every "
                                          "key), also without --scene."),
        seed: int = typer.Option(0, "--seed", help="Seed of everything random in the simulation."),
    ) -> None:
        """Build the simulated site and write what each camera sees with a projected test pattern, the
        ground truth drawn over it, and a plan view."""
        if scene is not None and not scene.exists() and scene.parent == Path() and scene.stem == SHIPPED_SCENE:
            scene = None  # the shipped scene by its name, as --wall takes a shipped wall's
        with working("building the simulated site and rendering its pictures"):
            from arproj.sim import Site
            from arproj.sim.pictures import write_site_pictures

            with Site.build(scene, seed=seed) as site:
                paths = write_site_pictures(site, out)
        for path in paths:
            console.print(f"wrote {path}", highlight=False)
