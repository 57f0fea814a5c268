"""The generic table: a CSV file with a header naming its columns.

    x_m,y_m,<channel>[,<channel>…][,time_s][,pass]

`x_m, y_m`: the sample's position on the wall (metres, x right, y up from the lower-left corner; a scanner's
positions may lie a little beyond the wall's edges, and the map keeps only what lies on it); any of the
scanner's channels (scanner.channels: inductive, capacitive, ac) in display units 0..1 (device counts / 1000),
an empty cell for a missing reading; `time_s` optional (seconds); `pass` optional (integer: the samples of one
straight pass, in order). Without `pass`, a new pass starts where consecutive samples lie more than
PASS_GAP_STEPS median steps apart (a raster's next row). Columns in any order; blank lines and lines starting
with `#` are skipped; any other column is an error naming it.
"""

from __future__ import annotations

import csv
import io

import numpy as np

from scanner.channels import NAMES as CHANNEL_NAMES
from scanner.recorded.record import Record, fail, parse_float

NAME = "generic"
POSITION_COLUMNS = ("x_m", "y_m")
TIME_COLUMN, PASS_COLUMN = "time_s", "pass"
PASS_GAP_STEPS = 5.0


def detect(first_line: str) -> bool:
    """Whether a table whose first meaningful line is this one is a generic table (its header)."""
    names = {c.strip().lower() for c in first_line.split(",")}
    return set(POSITION_COLUMNS) <= names


def read(path: str, text: str) -> Record:
    """The table's samples (see the module docstring); InputError names the file, line and value."""
    rows = [(k + 1, line) for k, line in enumerate(text.splitlines())
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise fail(path, 1, "the table is empty", "a generic table starts with a header: x_m,y_m,<channels>")
    header_line, header = rows[0]
    columns = [c.strip().lower() for c in next(csv.reader([header]))]
    known = (*POSITION_COLUMNS, *CHANNEL_NAMES, TIME_COLUMN, PASS_COLUMN)
    for name in columns:
        if name not in known:
            raise fail(path, header_line, f"unknown column {name!r}", f"columns are {', '.join(known)}")
    if len(set(columns)) != len(columns):
        raise fail(path, header_line, f"a column is named twice in {header.strip()!r}")
    missing = [c for c in POSITION_COLUMNS if c not in columns]
    if missing:
        raise fail(path, header_line, f"no {' or '.join(missing)} column", "a generic table needs x_m and y_m")
    channels = [c for c in CHANNEL_NAMES if c in columns]
    if not channels:
        raise fail(path, header_line, "no reading column", f"give at least one of {', '.join(CHANNEL_NAMES)}")
    data = rows[1:]
    if not data:
        raise fail(path, header_line, "the table has a header but no samples")
    n = len(data)
    values = {c: np.full(n, np.nan) for c in columns}
    lines = np.array([ln for ln, _ in data], dtype=np.int64)
    for k, (ln, cells) in enumerate(zip(lines.tolist(), csv.reader(io.StringIO("\n".join(t for _, t in data))),
                                        strict=True)):
        if len(cells) != len(columns):
            raise fail(path, ln, f"{len(cells)} values for {len(columns)} columns ({', '.join(columns)})")
        for name, cell in zip(columns, cells, strict=True):
            if not cell.strip():
                if name in channels:
                    continue  # a missing reading of that channel
                raise fail(path, ln, f"{name} is empty")
            value = parse_float(path, ln, name, cell)
            if name in channels and not 0.0 <= value <= 1.0:
                raise fail(path, ln, f"{name} = {cell.strip()} is outside 0..1",
                           "readings are display units 0..1 (device counts / 1000)")
            if name == PASS_COLUMN and value != int(value):
                raise fail(path, ln, f"pass = {cell.strip()} is not an integer")
            values[name][k] = value
    xy = np.column_stack([values["x_m"], values["y_m"]])
    pass_id = values[PASS_COLUMN].astype(np.int64) if PASS_COLUMN in columns else passes_from_gaps(xy)
    return Record(path, NAME, xy, {c: values[c] for c in channels}, pass_id, lines,
                  time_s=values.get(TIME_COLUMN), extent_m=(float(xy[:, 0].max()), float(xy[:, 1].max())))


def passes_from_gaps(xy: np.ndarray) -> np.ndarray:
    """(n,) pass numbers: a new pass where a step is longer than PASS_GAP_STEPS median steps."""
    if len(xy) < 2:
        return np.zeros(len(xy), np.int64)
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    typical = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    jump = steps > PASS_GAP_STEPS * typical if typical > 0 else np.zeros(len(steps), bool)
    return np.concatenate([[0], np.cumsum(jump)]).astype(np.int64)
