"""A scan as arrays (what a log holds, or a scan held in memory): the input of mapping.pipeline and of the
steps it calls (frame features, sparse lines), kept apart so that they need not import the pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scanner.channels import NAMES as CHANNEL_NAMES


@dataclass
class ScanData:
    """What a log holds, as arrays. samples: dict of (n,) arrays (scanner.log columns); frames likewise."""

    source: str
    samples: dict[str, NDArray]
    frames: dict[str, NDArray]
    meta: dict[str, Any]
    warnings: list[str] = field(default_factory=list)

    @property
    def n_samples(self) -> int:
        return int(self.samples["time_s"].shape[0]) if "time_s" in self.samples else 0

    @property
    def cell_m(self) -> float | None:
        """The cell size (m) of a gridded record, whose every sample covers exactly its cell (scanner.recorded:
        meta `cell_m`); None for a scan's point samples."""
        value = self.meta.get("cell_m")
        return float(value) if isinstance(value, (int, float)) and np.isfinite(value) and value > 0 else None

    @property
    def channels(self) -> tuple[str, ...]:
        """The sensor channels the scan has: those its meta names (an imported record's, scanner.recorded),
        else every channel of the scanner."""
        named = self.meta.get("channels")
        if isinstance(named, list):
            return tuple(c for c in CHANNEL_NAMES if c in named)
        return CHANNEL_NAMES

    @classmethod
    def from_scan(cls, source: str, samples: dict[str, NDArray], frame_rows: list[dict[str, Any]],
                  meta: dict[str, Any]) -> ScanData:
        """A scan held in memory (scanner.run.ScanResult's samples and frame rows) as the log would give it."""
        frames: dict[str, NDArray] = {}
        if frame_rows:
            keys = sorted({k for r in frame_rows for k in r} - {"cov"})
            frames = {k: np.asarray([r.get(k, np.nan) for r in frame_rows], dtype=np.float64) for k in keys}
            frames["frame_id"] = frames["frame_id"].astype(np.int64)
            frames["cov"] = np.asarray([r["cov"] for r in frame_rows], dtype=np.float64).reshape(-1, 3, 3)
        return cls(source, samples, frames, {"status": "complete", **meta})
