"""`arproj scan`: scan a wall (simulated site) into a crash-safe scan log; `--resume LOG` continues one."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from geometry.errors import InputError

if TYPE_CHECKING:
    from arproj.run.scan import ScanSettings
    from scanner.log import ScanLog
    from scanner.wall import Wall


def _fmt_duration(seconds: float) -> str:
    seconds = round(seconds)
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


def _scan_into(scan_log: ScanLog, the_wall: Wall, settings: ScanSettings, fast: bool, faults: float) -> None:
    """Scan into an open log and print what was done."""
    from arproj.console import console, progress_bar
    from arproj.run.scan import scan_simulated

    settings.serial, settings.faults = not fast, faults
    with progress_bar() as bar:
        task = bar.add_task("scanning", total=1.0)

        def progress(t: float, total: float, passes: int) -> None:
            bar.update(task, completed=t, total=total,
                       description=f"scan {_fmt_duration(t)}/~{_fmt_duration(total)}")

        scan = scan_simulated(the_wall, settings, scan_log, progress)
    result = scan.result
    if settings.serial and faults > 0:
        console.print(f"device faults injected: {scan.faults_injected}, recovered: {scan.faults_recovered}")
    n = len(result.samples.get("time_s", []))
    console.print(f"{scan_log.path}: {result.n_frames} frames, {result.n_passes} passes "
                  f"({result.measured_passes} measured now), {n} samples; simulated scan time "
                  f"{_fmt_duration(result.scan_time_s)} ({settings.plan})")
    if result.plan_report or result.plan_priors:
        from scanner.plan import PRIORS_RULE, STOPPING_RULE

        console.print(f"stopping rule: {STOPPING_RULE}")
        console.print(f"priors: {PRIORS_RULE}")
        for line in result.plan_priors:  # which zones and sockets ordered the passes
            console.print(f"  {line}")
        for row in result.plan_report:
            first = f"; traced first: found in {row['first_in']}" if row.get("first_in") else ""
            console.print(f"  frame {row['frame_id']} object {row['object']} ({row['channel']}): "
                          f"{row['length_m']:.2f} m traced, {100 * row['measured_share']:.0f} % measured "
                          f"by following passes; ends: {', '.join(row['ends'])}{first}")


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("scan")
    def scan(
        wall: Path = typer.Option(None, "--wall", help="Wall description file (YAML/JSON), or the name of a "
                                  "shipped wall (paper_test_plate, small_test_wall, drywall_studs, "
                                  "demo_brick_wall). With --resume it is checked against the log."),
        log: Path = typer.Option(None, "--log", help="Scan log to write (SQLite)."),
        resume: Path = typer.Option(None, "--resume", help="Continue the scan recorded in this log."),
        sim: bool = typer.Option(False, "--sim", help="Scan the simulated site (device simulators on "
                                 "socket:// URLs, the same code path as hardware)."),
        plan: str = typer.Option("adaptive", "--plan", help="dense (raster, 1 cm lines: the paper's way) or "
                                 "adaptive (coarse grid, then confirm and trace; DIN 18015-3 installation zones "
                                 "and the wall file's known sockets and openings order its passes, never replace "
                                 "one)."),
        priors: bool = typer.Option(True, "--priors/--no-priors", help="Adaptive plan: let the installation "
                                    "zones and known sockets order the passes (the same coarse passes either "
                                    "way; a known socket no coarse pass came near is searched first). A "
                                    "resumed scan keeps its log's setting."),
        row_spacing: float = typer.Option(0.25, "--row-spacing", help="Adaptive plan: metres between its coarse "
                                          "rows. 0.25 finds every pipe and cable at about 1/5 of the dense "
                                          "raster's time; a loose screw shows only within 4 cm of a row, so "
                                          "0.075 finds those too, at about 0.3 of it."),
        seed: int = typer.Option(0, "--seed", help="Seed of the simulation (robot errors, sensor noise)."),
        faults: float = typer.Option(0.0, "--faults", help="Simulation: probability of a fault per device "
                                     "output line (garbage, truncation, drops, disconnects)."),
        fast: bool = typer.Option(False, "--fast", help="Simulation: evaluate the site in-process instead of "
                                  "through the serial simulators (identical samples, faster)."),
        overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing log at --log."),
    ) -> None:
        """Scan a wall: frames, passes and every sample go to a SQLite log, batch by batch (kill -9 safe)."""
        from scanner.log import WriterLock

        for path in (resume, log):  # a log another scan is writing: refused before the slow set-up below
            if path is not None:
                WriterLock(path).probe()
        from arproj.console import console
        from arproj.run.scan import ScanSettings, new_scan_log, resolve_wall
        from scanner.run import open_for_resume

        if not 0.0 <= faults <= 0.5:
            raise InputError(f"--faults = {faults}: must be a probability between 0 and 0.5")
        if resume is not None:
            if log is not None:
                raise InputError("give either --resume LOG or --log LOG, not both")
            scan_log, the_wall = open_for_resume(resume, wall)
            try:
                settings = ScanSettings.from_log(scan_log.meta, resume)
            except BaseException:
                scan_log.close()
                raise
            done = scan_log.pass_count()
            if scan_log.meta.get("status") == "complete":
                console.print(f"{resume}: scan already complete ({done} passes)")
                scan_log.close()
                return
            console.print(f"{resume}: resuming after {done} recorded passes" if done else
                          f"{resume}: no pass recorded yet; the scan starts from its first pass", highlight=False)
        else:
            if wall is None or log is None:
                raise InputError("arproj scan needs --wall FILE and --log LOG (or --resume LOG)")
            if not sim:
                raise InputError("only the simulated site can be scanned from this command: add --sim",
                                 "real devices are driven by scanner.hardware.DeviceBackend with their serial URLs")
            if plan not in ("dense", "adaptive"):
                raise InputError(f"--plan = {plan!r}: use dense or adaptive")
            the_wall, wall = resolve_wall(wall)
            if not 0.02 <= row_spacing <= the_wall.height_m:
                raise InputError(f"--row-spacing = {row_spacing:g} m: must lie between 0.02 m and the wall's height "
                                 f"({the_wall.height_m:g} m)", "the default 0.25 is the plan's; 0.075 finds loose "
                                 "fasteners too")
            settings = ScanSettings(plan=plan, plan_options={"priors": priors, "coarse_row_spacing_m": row_spacing}
                                    if plan == "adaptive" else None, seed=seed)
            replacing = overwrite and log.exists()
            scan_log = new_scan_log(log, the_wall, str(wall), settings, overwrite=overwrite)
            console.print(f"{log}: {'replaced by a new' if replacing else 'new'} scan log", highlight=False)
        with scan_log:
            _scan_into(scan_log, the_wall, settings, fast, faults)

    @app.command("scan-plot")
    def scan_plot(
        log: Path = typer.Argument(None, help="Scan log to draw."),
        out: Path = typer.Option(Path("scan.png"), "--out", help="PNG file to write."),
        paper: bool = typer.Option(False, "--paper", help="Instead: re-make the paper's figures 5 and 6 "
                                   "(inductive and AC along the test plate, three runs) with the simulator."),
    ) -> None:
        """Draw a scan log's inductive and AC readings on the wall (PNG), or the paper's figures 5 and 6."""
        from arproj.console import console
        from scanner.figures import plot_log, plot_paper_figures

        if paper:
            console.print(f"wrote {plot_paper_figures(out)}")
            return
        if log is None:
            raise InputError("arproj scan-plot needs a scan LOG (or --paper)")
        console.print(f"wrote {plot_log(log, out)}")
