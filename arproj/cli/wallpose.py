"""`arproj wallpose`: measure the wall's pose once from the projected pattern and print (and draw) it.

    arproj wallpose --sim --distance 2 --incidence 30            on the simulated site, compared with its truth
    arproj wallpose --sim --distance 3 --incidence 20 --along 1.2   ... standing near a room corner (in view)
    arproj wallpose --pattern-out pattern.png --rig RIG --head 0,5,0 --distance 2   the image to project
    arproj wallpose --rig RIG --head 0,5,0 --distance 2 --left L.png --right R.png  from real photos
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from arproj.console import console, working


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("wallpose")
    def wallpose(
        sim: bool = typer.Option(False, "--sim", help="Use the simulated site (and compare with its truth)."),
        distance: float = typer.Option(2.0, "--distance", help="Approximate distance to the wall, m (sizes the "
                                       "pattern; with --sim: where the robot stands)."),
        incidence: float = typer.Option(0.0, "--incidence", help="Approximate incidence angle on the wall, °."),
        seed: int = typer.Option(0, "--seed", help="Seed of the simulated site."),
        along: float | None = typer.Option(None, "--along", help="With --sim: aim point along wall 0, m from its "
                                           "left end (default: the middle); near an end a room corner is in view."),
        rig: Path | None = typer.Option(None, "--rig", help="Calibrated rig folder (rig.yaml)."),
        head: str | None = typer.Option(None, "--head", help="The head's current pan,tilt,roll in degrees."),
        left: Path | None = typer.Option(None, "--left", help="Left camera photo of the projected pattern."),
        right: Path | None = typer.Option(None, "--right", help="Right camera photo of the projected pattern."),
        pattern_out: Path | None = typer.Option(None, "--pattern-out", help="Write the pattern to project (PNG)."),
        picture: Path = typer.Option(Path("wallpose.png"), "--picture", help="Where to draw the result."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
    ) -> None:
        """Measure the wall's pose once from the projected checker pattern seen by both cameras."""
        with working("wall pose: " + ("building the simulated site, " if sim else "")
                     + "detecting the pattern in both photos, fitting the plane"):
            from arproj.run.wallpose import WallposeSettings, run_wallpose

            result = run_wallpose(WallposeSettings(sim=sim, distance=distance, incidence=incidence, seed=seed,
                                                   along=along, rig=rig, head=head, left=left, right=right,
                                                   pattern_out=pattern_out, picture=picture))
        if as_json:
            print(json.dumps(result, indent=2))
            return
        for section, values in result.items():
            if isinstance(values, dict):
                console.print(f"[bold]{section}[/]")
                for key, value in values.items():
                    console.print(f"  {key}: {value}", highlight=False)
            else:
                console.print(f"[bold]{section}[/]: {values}", highlight=False)
