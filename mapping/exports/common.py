"""What every export of a map reads: the job (scan data, map result, objects cut once, options) and the cells
the safety channels covered."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray

from mapping import mapfile
from mapping.evidence import SAFETY_CHANNELS
from mapping.pipeline import MapResult
from mapping.scandata import ScanData


@dataclass
class ExportJob:
    """One map to export into out_dir. `objects` are the map's objects cut into measured and inferred stretches,
    made once for every export (result.mapped_objects() when not given)."""

    data: ScanData
    result: MapResult
    out_dir: Path
    mesh: trimesh.Trimesh | None = None  # the wall's surface (wall frame); None: a flat wall over the bounds
    title: str = ""
    signal_y: float | None = None  # wall height of signals.png's rows; None: the height most lines cross
    objects: list[mapfile.MappedObject] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        if not self.objects:
            self.objects = self.result.mapped_objects()


def looked(result: MapResult) -> NDArray[np.bool_]:
    """Cells both safety channels covered (what may ever be called free), from the coverage layer."""
    if result.coverage is None:
        raise ValueError("the map result has no coverage layer")
    return np.asarray(result.coverage.covered_by_all(SAFETY_CHANNELS), dtype=np.bool_)


def scanned_regions(result: MapResult) -> list[dict]:
    """The area both safety channels covered, as polygons with holes in wall metres (for drawing)."""
    from mapping.evidence import regions

    return regions(looked(result), result.grid.info)
