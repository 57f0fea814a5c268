"""A recorded scan as read from a table, before it becomes a scan log: what every format module gives."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError


@dataclass
class Record:
    """Samples read from a table (wall metres, display units).

    xy : (n, 2) float64 wall metres (x right, y up from the wall's lower-left corner); readings : per channel
    present in the table, (n,) display units 0..1 (NaN: that reading is missing); time_s : (n,) seconds or
    None when the table has no times; pass_id : (n,) int64, the pass each sample belongs to; line : (n,) the
    table's line number of each sample (1-based, for messages); cell_m : the cell size of a gridded record
    (each sample covers its cell), None for point samples; extent_m : (width, height) the samples span from the
    wall's corner (a gridded record: to its cells' far edges); meta : what the format knows beyond the samples
    (a tare, a unit), recorded in the log's `source` entry.
    """

    path: str
    format: str
    xy: NDArray[np.float64]
    readings: dict[str, NDArray[np.float64]]
    pass_id: NDArray[np.int64]
    line: NDArray[np.int64]
    time_s: NDArray[np.float64] | None = None
    cell_m: float | None = None
    extent_m: tuple[float, float] = (0.0, 0.0)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.xy.shape[0])

    @property
    def channels(self) -> list[str]:
        return list(self.readings)


def fail(path: str, line: int, what: str, hint: str | None = None) -> InputError:
    """The one-line error for a bad value on a line of a table."""
    return InputError(f"{path}, line {line}: {what}", hint)


def parse_float(path: str, line: int, column: str, text: str) -> float:
    """A finite number from a table cell, else an InputError naming the file, line, column and value."""
    try:
        value = float(text)
    except ValueError:
        raise fail(path, line, f"{column} = {text.strip()!r} is not a number") from None
    if not np.isfinite(value):
        raise fail(path, line, f"{column} = {text.strip()!r} is not a finite number")
    return value
