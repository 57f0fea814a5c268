"""The object type of a map: what mapping.objects extracts, fusion classifies, depth and evidence annotate.

Kept apart from the extraction so that the steps that only read or write objects need not import it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from geometry.polyline import polyline_length


@dataclass
class MapObject:
    """One extracted object. kind: 'line' | 'point' | 'outline'. cls: class name (fusion fills it)."""

    kind: str
    points_m: NDArray[np.float64]  # (k, 2) wall metres; one point for 'point', closed ring for 'outline'
    width_m: float
    strength: float = 0.0  # ridge/blob height over background, in robust standard deviations
    cls: str = "unknown"
    confidence: float = 0.0
    features: dict[str, float] = field(default_factory=dict)
    # Depth of the object behind the surface and its 1σ, metres (mapping.depth); None where no channel tells.
    depth_m: float | None = None
    depth_sigma_m: float | None = None

    def length_m(self) -> float:
        return polyline_length(self.points_m)

    def to_json(self) -> dict:
        return {"class": self.cls, "kind": self.kind,
                "points_m": [[round(float(x), 5), round(float(y), 5)] for x, y in self.points_m],
                "width_m": round(float(self.width_m), 4), "confidence": round(float(self.confidence), 3)}
