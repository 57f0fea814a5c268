"""The gridded record, as DIY inductive wall scanners write it: no header, the tare alone on the first line,
then one line per measured cell.

    <tare_us>
    <X>,<Y>,<reading_us>
    …

X and Y are integer cell indices (X to the right, Y up, counted from the wall's lower-left corner: cell (X, Y)
spans [X·c, (X+1)·c) × [Y·c, (Y+1)·c) for the cell size c, `--cell-m`, 3 cm typical); the reading is the mean
coil delay over the cell in microseconds. A reading above the tare is ferrous metal, below it non-ferrous;
the distance from the tare is how much metal. Cells not in the file were not measured. Blank lines and lines
starting with `#` are skipped; a cell given twice is an error.

The inductive channel is what a record gives (in display units, as the wall scanner shows it): the coil's
additive response |reading − tare| / US_PER_UNIT, saturated as the display does (1 − exp(−raw)). Which side of
the tare a cell lies on is counted (ferrous / non-ferrous cells) but no map class tells the two apart.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scanner.channels import INDUCTIVE
from scanner.recorded.record import Record, fail, parse_float

NAME = "gridded"
DEFAULT_CELL_M = 0.03
US_PER_UNIT = 1.0  # coil delay (µs) per raw unit of the inductive response (the mapping's thresholds are relative)


def detect(first_line: str) -> bool:
    """Whether a table whose first meaningful line is this one is a gridded record (the tare alone)."""
    fields = [f.strip() for f in first_line.split(",")]
    if len(fields) != 1:
        return False
    try:
        return bool(np.isfinite(float(fields[0])))
    except ValueError:
        return False


def display_from_delay(reading_us: NDArray[np.float64], tare_us: float,
                       us_per_unit: float = US_PER_UNIT) -> NDArray[np.float64]:
    """Inductive display units 0..1 of coil delays (µs) against the tare: 1 − exp(−|reading − tare| / unit)."""
    return 1.0 - np.exp(-np.abs(np.asarray(reading_us, dtype=np.float64) - tare_us) / us_per_unit)


def read(path: str, text: str, cell_m: float = DEFAULT_CELL_M, us_per_unit: float = US_PER_UNIT) -> Record:
    """The record's cells as samples at their centres (see the module docstring); InputError names the file,
    line and value."""
    if not (np.isfinite(cell_m) and cell_m > 0):
        raise fail(path, 1, f"cell size {cell_m} m is not a positive length", "give --cell-m in metres, e.g. 0.03")
    rows = [(k + 1, line) for k, line in enumerate(text.splitlines())
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise fail(path, 1, "the record is empty", "a gridded record starts with the tare alone on a line")
    tare_line, tare_text = rows[0]
    if "," in tare_text:
        raise fail(path, tare_line, f"the first line {tare_text.strip()!r} should hold the tare alone",
                   "a gridded record starts with the tare (µs), then X,Y,reading lines")
    tare = parse_float(path, tare_line, "tare", tare_text)
    if len(rows) < 2:
        raise fail(path, tare_line, "the record holds a tare but no cells")
    cells = np.zeros((len(rows) - 1, 2), np.int64)
    reading = np.zeros(len(rows) - 1)
    lines = np.zeros(len(rows) - 1, np.int64)
    seen: dict[tuple[int, int], int] = {}
    for k, (ln, line) in enumerate(rows[1:]):
        fields = line.split(",")
        if len(fields) != 3:
            raise fail(path, ln, f"{line.strip()!r} has {len(fields)} values, expected X,Y,reading")
        for axis, name in enumerate(("X", "Y")):
            text_value = fields[axis].strip()
            try:
                index = int(text_value)
            except ValueError:
                raise fail(path, ln, f"{name} = {text_value!r} is not an integer cell index") from None
            if index < 0:
                raise fail(path, ln, f"{name} = {index} is below 0",
                           "cell indices count from the wall's lower-left corner, 0 first")
            cells[k, axis] = index
        reading[k] = parse_float(path, ln, "reading", fields[2])
        key = (int(cells[k, 0]), int(cells[k, 1]))
        if key in seen:
            raise fail(path, ln, f"cell {key} was already given on line {seen[key]}")
        seen[key] = ln
        lines[k] = ln
    order = np.lexsort((cells[:, 0], cells[:, 1]))  # row by row, bottom up, left to right
    cells, reading, lines = cells[order], reading[order], lines[order]
    xy = (cells.astype(np.float64) + 0.5) * cell_m
    _, pass_id = np.unique(cells[:, 1], return_inverse=True)  # one pass per row of cells
    extent = (float((cells[:, 0].max() + 1) * cell_m), float((cells[:, 1].max() + 1) * cell_m))
    meta = {"tare_us": tare, "us_per_unit": us_per_unit, "ferrous_cells": int((reading > tare).sum()),
            "non_ferrous_cells": int((reading < tare).sum())}
    return Record(path, NAME, xy, {INDUCTIVE.name: display_from_delay(reading, tare, us_per_unit)},
                  pass_id.astype(np.int64), lines, cell_m=float(cell_m), extent_m=extent, meta=meta)


def write(path: str | Path, tare_us: float, cells: NDArray[np.int64], reading_us: NDArray[np.float64]) -> Path:
    """A gridded record: the tare, then one `X,Y,reading` line per cell (cells (n, 2) int, reading (n,) µs)."""
    path = Path(path)
    lines = [f"{tare_us:.3f}"] + [f"{int(x)},{int(y)},{float(r):.3f}"
                                  for (x, y), r in zip(np.asarray(cells), np.asarray(reading_us), strict=True)]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path
