"""The empty wall's level and noise in a signal map, robust to the objects on it, and z-scores over it.

Below the grid and the object extraction (both use it), so that neither needs the other for it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

CLIP_SIGMAS = 3.0  # two-sided background: values this many σ from the level are objects
TWO_SIDED_RATIO = 2.0  # ... and the mode's spread replaces the lower quantiles' when this much narrower
_CLIP_ROUNDS = 10


def background_level(values: NDArray[np.float64], two_sided: bool = False) -> tuple[float, float]:
    """(level, σ) of the empty-wall background among finite values, robust even when objects cover most of
    the area: from the lower quantiles only (for Gaussian noise q25 − q05 = 0.971 σ, median = q25 + 0.674 σ).
    Valid while at least a quarter of the cells are background.

    two_sided: objects may also lower the level (the capacitive map: cavities), so the lowest values need not
    be background. The mode is then estimated too — median and interquartile range of the values within
    CLIP_SIGMAS of the level, iterated from the median (valid while most cells are background) — and taken
    where the lower quantiles are at least TWO_SIDED_RATIO times as wide: lowered objects in them. Otherwise
    the one-sided estimate stands (it holds with objects over up to three quarters of the wall)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return 0.0, 1.0
    q05, q25, q99 = np.percentile(v, [5, 25, 99.9])
    floor = max(1e-9, 1e-3 * float(q99 - q05))
    sigma = max((q25 - q05) / 0.971, floor)
    level = float(q25 + 0.674 * sigma)
    if not two_sided:
        return level, float(sigma)
    mode = float(np.median(v))
    spread = max(1.4826 * float(np.median(np.abs(v - mode))), floor)
    for _ in range(_CLIP_ROUNDS):
        near = v[np.abs(v - mode) <= CLIP_SIGMAS * spread]
        if near.size < 10:
            break
        lo, mid, hi = np.percentile(near, [25, 50, 75])
        new_mode, new_spread = float(mid), max(float(hi - lo) / 1.349, floor)
        if abs(new_mode - mode) <= 1e-3 * spread and abs(new_spread - spread) <= 1e-3 * spread:
            mode, spread = new_mode, new_spread
            break
        mode, spread = new_mode, new_spread
    return (mode, spread) if TWO_SIDED_RATIO * spread < sigma else (level, float(sigma))


def normalise(signal: NDArray[np.float64], two_sided: bool = False) -> tuple[NDArray[np.float64], float, float]:
    """(z-scores with NaN→0, background level, background σ) of a signal map with NaN unknown (two_sided: see
    background_level)."""
    known = np.isfinite(signal)
    if not known.any():
        return np.zeros(signal.shape), 0.0, 1.0
    level, sigma = background_level(signal[known], two_sided)
    z = np.where(known, (signal - level) / sigma, 0.0)
    return z, level, sigma
