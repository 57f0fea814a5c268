"""Recorded scans from other devices, brought in as scan logs (`arproj import-scan`).

One module per table format, each with `NAME`, `detect(first_line)` and `read(path, text, …) -> Record`:
generic.py (a CSV with a header: x_m, y_m, any of the scanner's channels, optionally time_s and pass) and
gridded.py (a DIY inductive scanner's record: the tare, then X,Y,reading per cell). Adding a format is adding
a module and naming it in FORMATS.

`import_table` reads a table and writes a normal scan log (scanner.log): one frame at the wall's origin (the
positions are wall metres already), one pass per pass of the table (a gridded record: per row of cells), the
readings of the channels the table has (the others NULL). The log's meta records where it came from:
`source` {format, file, sha256, rows, and the format's own entries such as the tare}, `channels` (those
present), and for a gridded record `cell_m`, the cell size: mapping then treats each sample as covering
exactly its cell (mapping.pipeline).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geometry.errors import InputError
from scanner.log import ScanLog
from scanner.recorded import generic, gridded
from scanner.recorded.record import Record, fail
from scanner.wall import Wall

FORMATS = {generic.NAME: generic, gridded.NAME: gridded}
PLAN_KIND = "imported"
STAGE = "raster"  # the passes of a table are taken as raster passes (scanner.log's stages)


def detect_format(path: str, text: str) -> str:
    """The format of a table from its first meaningful line; InputError when no format fits."""
    first = next(((k + 1, line) for k, line in enumerate(text.splitlines())
                  if line.strip() and not line.lstrip().startswith("#")), None)
    if first is None:
        raise fail(path, 1, "the table is empty")
    for name, module in FORMATS.items():
        if module.detect(first[1]):
            return name
    raise fail(path, first[0], f"cannot tell the table's format from {first[1].strip()[:60]!r}",
               f"a generic table starts with a header (x_m,y_m,…), a gridded record with the tare alone; or "
               f"name it with --format {'|'.join(FORMATS)}")


def read_table(path: str | Path, fmt: str | None = None, cell_m: float = gridded.DEFAULT_CELL_M,
               us_per_unit: float = gridded.US_PER_UNIT) -> Record:
    """Read a table in the named format (None: detected)."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{source}: no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{source}: cannot read the table ({err})") from None
    name = detect_format(source, text) if fmt is None else fmt
    if name not in FORMATS:
        raise InputError(f"--format {name}: unknown format", f"use one of {', '.join(FORMATS)}")
    if name == gridded.NAME:
        return gridded.read(source, text, cell_m=cell_m, us_per_unit=us_per_unit)
    return generic.read(source, text)


@dataclass(frozen=True)
class ImportSummary:
    log: Path
    format: str
    samples: int
    passes: int
    channels: tuple[str, ...]
    wall_size_m: tuple[float, float]
    cell_m: float | None


def check_inside(record: Record, width_m: float, height_m: float, wall_source: str) -> None:
    """InputError naming the first cell of a gridded record (its line) that does not lie on the wall whole."""
    half = 0.5 * (record.cell_m or 0.0)
    outside = ((record.xy[:, 0] + half > width_m + 1e-9) | (record.xy[:, 1] + half > height_m + 1e-9))
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        x, y = record.xy[k]
        what = f"the cell centred at ({x:g}, {y:g}) m"
        raise fail(record.path, int(record.line[k]), f"{what} lies beyond the wall {wall_source} "
                   f"({width_m:g} x {height_m:g} m)", "is it the right wall, and the right --cell-m?")


def import_table(path: str | Path, out: str | Path, fmt: str | None = None,
                 cell_m: float = gridded.DEFAULT_CELL_M, us_per_unit: float = gridded.US_PER_UNIT,
                 wall: Wall | None = None, wall_path: str | None = None, overwrite: bool = False) -> ImportSummary:
    """Read a table and write it as a scan log at `out` (see the module docstring). With a wall, the log is
    that wall's (its fingerprint and size; every sample must lie on it); without, the wall is the rectangle
    from the corner to the samples' far edge and the fingerprint the table's."""
    record = read_table(path, fmt, cell_m, us_per_unit)
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    if wall is not None:
        size = (float(wall.width_m), float(wall.height_m))
        if record.cell_m is not None:  # a cell off the wall is a wrong cell size or wall (points may stray)
            check_inside(record, *size, wall_path or wall.name)
        wall_meta = {"wall_fingerprint": wall.fingerprint(), "wall_name": wall.name, "wall_path": wall_path}
    else:
        size = record.extent_m
        wall_meta = {"wall_fingerprint": f"table:{digest}", "wall_name": Path(path).stem, "wall_path": None}
    if size[0] <= 0 or size[1] <= 0:
        raise InputError(f"{path}: the samples span {size[0]:g} x {size[1]:g} m, no area to map",
                         "give --wall W for the wall they lie on")
    meta = {**wall_meta, "wall_width_m": size[0], "wall_height_m": size[1], "wall_json": None,
            "plan": {"kind": PLAN_KIND}, "sensor": {}, "drives": {}, "seed": None,
            "source": {"format": record.format, "file": Path(path).name, "sha256": digest, "rows": record.n,
                       **record.meta},
            "channels": record.channels}
    if record.cell_m is not None:
        meta["cell_m"] = record.cell_m
    if Path(out).exists() and not overwrite:  # checked here: the log's own hint speaks of resuming a scan
        raise InputError(f"{out}: already exists", "pass --overwrite to replace it, or choose another --out")
    log = ScanLog.create(out, meta, overwrite=overwrite)
    passes = 0
    with log:
        log.append_frame({"frame_id": 0, "time_s": 0.0, "cmd_x_m": 0.0, "cmd_y_m": 0.0, "cmd_phi_rad": 0.0,
                          "est_x_m": 0.0, "est_y_m": 0.0, "est_phi_rad": 0.0,
                          "cov": np.diag([1e-8, 1e-8, 1e-10])})  # the positions are the wall's own
        for pid in np.unique(record.pass_id):
            idx = np.flatnonzero(record.pass_id == pid)
            log.append_pass(_pass_row(record, idx, int(pid)), _pass_samples(record, idx))
            passes += 1
        log.set_meta("status", "complete")
    return ImportSummary(Path(out), record.format, record.n, passes, tuple(record.channels), size, record.cell_m)


def _pass_row(record: Record, idx: np.ndarray, pass_id: int) -> dict[str, object]:
    xy = record.xy[idx]
    axis, direction = _axis_direction(xy)
    t = record.time_s[idx] if record.time_s is not None else np.zeros(len(idx))
    return {"pass_id": pass_id, "frame_id": 0, "stage": STAGE, "axis": "xy"[axis], "direction": direction,
            "start_u_m": float(xy[0, 0]), "start_v_m": float(xy[0, 1]), "end_u_m": float(xy[-1, 0]),
            "end_v_m": float(xy[-1, 1]), "t_start_s": float(np.nanmin(t)) if np.isfinite(t).any() else 0.0,
            "t_end_s": float(np.nanmax(t)) if np.isfinite(t).any() else 0.0}


def _axis_direction(xy: np.ndarray) -> tuple[int, int]:
    """A pass's axis (0: along x, 1: along y, the longer span) and direction (+1/−1 from its first to its last
    sample)."""
    span = xy[-1] - xy[0]
    extent = xy.max(axis=0) - xy.min(axis=0)
    axis = int(extent[1] > extent[0])
    return axis, (1 if span[axis] >= 0 else -1)


def _pass_samples(record: Record, idx: np.ndarray) -> dict[str, np.ndarray]:
    xy = record.xy[idx]
    axis, direction = _axis_direction(xy)
    n = len(idx)
    time = record.time_s[idx] if record.time_s is not None else np.full(n, np.nan)
    return {"time_s": time, "drive_u_m": xy[:, 0], "drive_v_m": xy[:, 1], "cmd_x_m": xy[:, 0],
            "cmd_y_m": xy[:, 1], "x_m": xy[:, 0], "y_m": xy[:, 1], "axis": np.full(n, axis),
            "direction": np.full(n, direction), **{c: v[idx] for c, v in record.readings.items()}}
