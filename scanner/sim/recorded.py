"""Recorded scans of the simulated site, as other devices would write them (scanner/recorded's formats): the
ground truth that `arproj import-scan` and mapping are tested against.

A gridded record is what a DIY inductive scanner held still over each cell writes: the inductive sensor model
at the cell's centre (scanner.sensor_model, one run's gain and noise from the seed), as a coil delay about a
tare — above it where ferrous metal (steel) dominates the response, below it where non-ferrous metal does.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from scanner.channels import INDUCTIVE
from scanner.recorded.gridded import US_PER_UNIT
from scanner.sensor_model import SensorConfig, SensorModel
from scanner.wall import Wall

DEFAULT_TARE_US = 250.0
FERROUS = ("steel",)


def wall_cells(wall: Wall, cell_m: float) -> NDArray[np.int64]:
    """(n, 2) integer indices (X, Y) of every whole cell on the wall, row by row."""
    nx, ny = int(np.floor(wall.width_m / cell_m + 1e-9)), int(np.floor(wall.height_m / cell_m + 1e-9))
    gx, gy = np.meshgrid(np.arange(nx), np.arange(ny))
    return np.column_stack([gx.ravel(), gy.ravel()]).astype(np.int64)


def gridded_readings(wall: Wall, cells: NDArray[np.int64], cell_m: float, seed: int,
                     sensor: SensorConfig | None = None, tare_us: float = DEFAULT_TARE_US,
                     us_per_unit: float = US_PER_UNIT) -> NDArray[np.float64]:
    """(n,) coil delays (µs) of the cells (n, 2) as a DIY scanner records them (see the module docstring)."""
    cfg = sensor or SensorConfig()
    xy = (np.asarray(cells, dtype=np.float64) + 0.5) * cell_m
    display = SensorModel(wall, cfg).display(xy, rng=np.random.default_rng([seed, 19]))[:, INDUCTIVE.index]
    raw = -np.log(np.clip(1.0 - display, 1e-6, 1.0)) - cfg.ind_baseline  # the response above the empty wall
    ferrous = replace(wall, objects=[o for o in wall.objects if o.material in FERROUS])
    other = replace(wall, objects=[o for o in wall.objects if o.material not in FERROUS])
    side = np.where(SensorModel(ferrous, cfg).raw(xy)[:, INDUCTIVE.index]
                    >= SensorModel(other, cfg).raw(xy)[:, INDUCTIVE.index], 1.0, -1.0)
    return tare_us + side * raw * us_per_unit
