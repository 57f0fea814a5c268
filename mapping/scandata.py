"""A scan as arrays (what a log holds, or a scan held in memory): the input of mapping.pipeline and of the
steps it calls (frame features, sparse lines), kept apart so that they need not import the pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray


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
