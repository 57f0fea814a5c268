"""`arproj scan`: scan a wall (the simulated site, or the devices at their URLs) into a crash-safe scan log;
`--resume LOG` continues one."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from geometry.errors import InputError

if TYPE_CHECKING:
    from arproj.run.scan import DeviceUrls, ScanSettings
    from scanner.log import ScanLog
    from scanner.plan import FrameTarget
    from scanner.run import ScanResult, ScanWatcher
    from scanner.wall import Wall


def _fmt_duration(seconds: float) -> str:
    seconds = round(seconds)
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


def _ask_operator(frame: FrameTarget) -> None:
    """Tell the operator where the robot goes for `frame` and wait until they press Enter."""
    from arproj.console import console

    console.print(f"frame {frame.frame_id}: put the robot at x = {frame.x_m:.3f} m along the wall (column "
                  f"{frame.column}), the drive frame raised to y = {frame.y_m:.3f} m (band {frame.band}), aligned "
                  "to the wall, then press Enter", highlight=False)
    try:
        input()
    except EOFError:
        raise InputError(f"frame {frame.frame_id}: nobody at the terminal to place the robot (input closed)",
                         "run the scan at a terminal, or give the robot base's URL with --base") from None


def _scan_into(scan_log: ScanLog, the_wall: Wall, settings: ScanSettings, fast: bool, faults: float,
               urls: DeviceUrls | None, virtual_clock: bool, device_timeout: float,
               watch: ScanWatcher | None = None) -> ScanResult:
    """Scan into an open log (the simulated site, or the devices at urls), print what was done, return it."""
    from arproj.console import console, progress_bar
    from arproj.run.scan import scan_on_devices, scan_simulated

    settings.serial, settings.faults = not fast, faults
    if urls is not None and urls.base is None:  # an operator at the terminal: no progress bar over the prompts
        scan = scan_on_devices(the_wall, settings, urls, scan_log, operator=_ask_operator,
                               realtime=not virtual_clock, timeout_s=device_timeout, watch=watch)
    else:
        with progress_bar() as bar:
            task = bar.add_task("scanning", total=1.0)

            def progress(t: float, total: float, passes: int) -> None:
                bar.update(task, completed=t, total=total,
                           description=f"scan {_fmt_duration(t)}/~{_fmt_duration(total)}")

            scan = scan_simulated(the_wall, settings, scan_log, progress, watch) if urls is None else \
                scan_on_devices(the_wall, settings, urls, scan_log, progress, realtime=not virtual_clock,
                                timeout_s=device_timeout, watch=watch)
    result = scan.result
    if urls is not None:
        console.print(f"device faults recovered: {scan.faults_recovered}")
    elif settings.serial and faults > 0:
        console.print(f"device faults injected: {scan.faults_injected}, recovered: {scan.faults_recovered}")
    n = len(result.samples.get("time_s", []))
    console.print(f"{scan_log.path}: {result.n_frames} frames, {result.n_passes} passes "
                  f"({result.measured_passes} measured now), {n} samples; {'' if urls else 'simulated '}scan "
                  f"time {_fmt_duration(result.scan_time_s)} ({settings.plan})")
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
    return result


def register(app: typer.Typer, bench_app: typer.Typer) -> None:
    @app.command("scan")
    def scan(
        wall: Path = typer.Option(None, "--wall", help="Wall description file (YAML/JSON), or the name of a "
                                  "shipped wall (paper_test_plate, small_test_wall, drywall_studs, "
                                  "demo_brick_wall). With --resume it is checked against the log."),
        log: Path = typer.Option(None, "--log", help="Scan log to write (SQLite)."),
        resume: Path = typer.Option(None, "--resume", help="Continue the scan recorded in this log."),
        sim: bool = typer.Option(False, "--sim", help="Scan the simulated site: starts the device simulators "
                                 "`arproj devices serve` runs (in this process, on socket:// URLs) and scans "
                                 "them by the hardware's code path."),
        drives: str = typer.Option(None, "--drives", help="Hardware: pyserial URL of the GRBL drives "
                                   "(/dev/ttyUSB0, socket://host:port, ...)."),
        scanner_url: str = typer.Option(None, "--scanner", help="Hardware: URL of the wall scanner."),
        laser: str = typer.Option(None, "--laser", help="Hardware: URL of the 2-D laser (heads H and V): fixes "
                                  "each frame against the side walls and the floor."),
        base: str = typer.Option(None, "--base", help="Hardware: URL of the robot base. Without it the command "
                                 "says where to put the robot for each frame and waits for Enter; the frame's "
                                 "pose is then the laser's fix."),
        virtual_clock: bool = typer.Option(False, "--virtual-clock", help="Hardware: the devices are simulators "
                                           "running motion on a virtual clock (`arproj devices serve`): wait for "
                                           "a lost answer by the link's timeout, not the motion's time."),
        device_timeout: float = typer.Option(0.5, "--device-timeout", help="Hardware: seconds to wait for one "
                                             "answer line before asking again."),
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
        site: Path = typer.Option(None, "--site", help="Site file to add this wall to (arproj-site/1 YAML): "
                                  "where the wall is in the room, as the laser saw it, for `arproj project "
                                  "--site`. Default: site.yaml beside the log."),
        no_site: bool = typer.Option(False, "--no-site", help="Write no site file."),
        site_key: str = typer.Option(None, "--site-key", help="The wall's key in the site file (default: the "
                                     "wall file's name without .yaml); an entry of that key is replaced."),
        site_map: Path = typer.Option(None, "--site-map", help="The map folder the site file names (default: "
                                      "map/ beside the site file, where `arproj map LOG --out DIR` writes)."),
        record: Path = typer.Option(None, "--record", help="Also write the scan as ROS 2 messages into this "
                                    ".mcap file (tf, every pass, the lasers' turns), a rosbag2 metadata.yaml "
                                    "beside it: `ros2 bag info`, RViz, Foxglove open the folder."),
        view: str = typer.Option(None, "--view", help="Show the scan live in a Rerun viewer (samples, coverage, "
                                 "the growing map, finds, robot and drive poses): `--view live` spawns the "
                                 "viewer, `--view FILE.rrd` saves the recording instead."),
    ) -> None:
        """Scan a wall: frames, passes and every sample go to a SQLite log, batch by batch (kill -9 safe)."""
        from scanner.log import WriterLock

        for path in (resume, log):  # a log another scan is writing: refused before the slow set-up below
            if path is not None:
                WriterLock(path).probe()
        if wall is not None:  # a shipped wall's name or a file; a wrong one refused before the slow imports below
            from scanner.wall import wall_file

            wall_path = wall_file(wall)
        from arproj.console import console
        from arproj.run.scan import DeviceUrls, ScanSettings, new_scan_log, resolve_wall
        from scanner.run import open_for_resume

        if not 0.0 <= faults <= 0.5:
            raise InputError(f"--faults = {faults}: must be a probability between 0 and 0.5")
        urls = None
        if any(u is not None for u in (drives, scanner_url, laser, base)):
            if sim:
                raise InputError("give --sim or the devices' URLs (--drives, --scanner, --laser, --base), not both")
            if drives is None or scanner_url is None:
                raise InputError("scanning on devices needs --drives URL and --scanner URL, and --laser URL "
                                 "(and --base URL, or an operator who places the robot)")
            if base is None and laser is None:
                raise InputError("without --base the operator places the robot and the laser fixes where: "
                                 "give --laser URL")
            if not 0.01 <= device_timeout <= 60:
                raise InputError(f"--device-timeout = {device_timeout:g} s: must lie between 0.01 and 60")
            urls = DeviceUrls(drives, scanner_url, laser, base)
        from arproj.run.watch import check_targets

        check_targets(record, view)
        if site is not None and no_site:
            raise InputError("give --site FILE or --no-site, not both")
        if site is not None and urls is not None and urls.laser is None:
            raise InputError(f"--site {site}: the site file needs the 2-D laser's view of the room",
                             "give --laser URL, or --no-site")
        # beside the log by default: it names the log and the map by relative paths, and a wall scanned without
        # one cannot be projected on hardware later; a scan without the laser (base only) writes none
        site_path = None if no_site or (site is None and urls is not None and urls.laser is None) else \
            site if site is not None else Path(log or resume).parent / "site.yaml"
        if site_path is not None:
            from arproj.site_file import check_writable

            check_writable(site_path)  # before the scan: another kind of file there is refused, kept as it is
        if resume is not None:
            if log is not None:
                raise InputError("give either --resume LOG or --log LOG, not both")
            scan_log, the_wall = open_for_resume(resume, wall_path if wall is not None else None)
            try:
                settings = ScanSettings.from_log(scan_log.meta, resume, on_devices=urls is not None)
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
            if not sim and urls is None:
                raise InputError("arproj scan needs --sim (the simulated site) or the devices' URLs",
                                 "e.g. --drives /dev/ttyUSB0 --scanner /dev/ttyUSB1 --laser /dev/ttyUSB2 "
                                 "--base /dev/ttyUSB3, or those `arproj devices serve` prints")
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
            scan_log = new_scan_log(log, the_wall, str(wall), settings, overwrite=overwrite, simulated=urls is None)
            console.print(f"{log}: {'replaced by a new' if replacing else 'new'} scan log", highlight=False)
        from arproj.run.watch import open_watchers

        with scan_log, open_watchers(scan_log.meta, record, view) as watch:
            result = _scan_into(scan_log, the_wall, settings, fast, faults, urls, virtual_clock, device_timeout,
                                watch)
            if site_path is not None:
                from arproj.run.scan import write_site

                key = site_key or Path(the_wall.source or the_wall.name).stem  # a shipped wall: its name
                replaced = write_site(site_path, key, the_wall, result, Path(scan_log.path),
                                      site_map.resolve() if site_map is not None else None)
                console.print(f"{site_path}: wall {key!r} {'replaced' if replaced else 'written'} (the room as "
                              f"{len(result.rooms)} frames' lasers saw it)", highlight=False)

    @app.command("scan-plot")
    def scan_plot(
        log: Path = typer.Argument(None, help="Scan log to draw."),
        out: Path = typer.Option(Path("scan.png"), "--out", help="PNG file to write."),
        paper: bool = typer.Option(False, "--paper", help="Instead: re-make the paper's figures 5 and 6 "
                                   "(inductive and AC along the test plate, three runs) with the simulator."),
    ) -> None:
        """Draw a scan log's inductive and AC readings on the wall (PNG), or the paper's figures 5 and 6."""
        from arproj.console import console, working

        if log is None and not paper:
            raise InputError("arproj scan-plot needs a scan LOG (or --paper)")
        with working("simulating the paper's three runs and drawing figures 5 and 6" if paper else
                     f"drawing {log}'s readings"):
            from scanner.figures import plot_log, plot_paper_figures

            written = plot_paper_figures(out) if paper else plot_log(log, out)
        console.print(f"wrote {written}")
