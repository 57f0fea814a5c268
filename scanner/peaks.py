"""A simple 1-D peak detector for one pass of the wall scanner (used by the adaptive planner).

The full map / object extraction lives in mapping/; this is only what planning needs: where along a pass a
reading rises clearly above the device's baseline, how high and how wide. The position is the midpoint of the
two half-maximum crossings (robust to the flat, saturated tops the device shows), the width the FWHM.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks


@dataclass
class PeakConfig:
    min_height: float = 0.10  # display units above the pass's baseline
    min_prominence: float = 0.06
    min_distance_m: float = 0.015
    merge_distance_m: float = 0.015  # peaks of different channels closer than this are one object
    grid_step_m: float = 0.0005  # resampling step along the pass (samples are uniform in time, not space)


CUT_PEAK_INSIDE_M = 0.005  # a cut peak's maximum at least this far inside the pass: a top, not a slope


@dataclass
class Peak:
    position: float  # metres along the pass coordinate
    height: float  # above baseline, display units
    width: float  # full width at half maximum, metres


def detect_peaks(coord: np.ndarray, values: np.ndarray, config: PeakConfig | None = None,
                 grid_step_m: float | None = None, keep_cut: tuple[bool, bool] = (False, False)) -> list[Peak]:
    """Peaks of `values` along `coord`. coord, values : (n,) (metres, display units); any order.

    A peak whose half-maximum lies beyond an end of the pass has no known centre and is dropped, unless
    keep_cut says so for that end (low coordinate, high coordinate): then its maximum, if that lies inside the
    pass, stands for its position (width NaN). A planner needs it where an object lies in the overlap of two
    frames, cut by both frames' reach."""
    cfg = config or PeakConfig()
    coord = np.asarray(coord, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if coord.size < 5 or np.ptp(coord) < 4 * cfg.grid_step_m:
        return []
    # resampling and smoothing stay within the readings' range and the baseline is one of them: a pass that
    # spans less than min_height has no peak (a quick answer for the many flat passes)
    if np.ptp(values) < cfg.min_height:
        return []
    order = np.argsort(coord, kind="stable")
    c, v = coord[order], values[order]
    c, first = np.unique(c, return_index=True)
    v = v[first]
    step = grid_step_m or max(cfg.grid_step_m, float(np.median(np.diff(c))) if len(c) > 1 else cfg.grid_step_m)
    grid = np.arange(c[0], c[-1] + step / 2, step)
    y = np.interp(grid, c, v)
    # ~2 mm moving average against sample noise, of odd length: centred, so it shifts no peak
    smooth = max(1, round(0.002 / step)) | 1
    if smooth > 1:
        kernel = np.ones(smooth) / smooth
        y = np.convolve(np.pad(y, smooth // 2, mode="edge"), kernel, mode="valid")
    baseline = float(np.percentile(y, 20))
    above = y - baseline
    idx, _ = find_peaks(np.pad(above, 1, constant_values=0.0), height=cfg.min_height,
                        prominence=cfg.min_prominence, distance=max(1, round(cfg.min_distance_m / step)))
    idx = idx - 1
    peaks = []
    for i in idx:
        crossings = level_crossings(grid, above, int(i), 0.5 * above[i])
        if crossings is None:  # cut off by the end of the pass: its centre is unknown
            inside = round(CUT_PEAK_INSIDE_M / step)
            cut_low = bool(np.all(above[:i + 1] > 0.5 * above[i]))
            cut_high = bool(np.all(above[i:] > 0.5 * above[i]))
            if (cut_low != cut_high and keep_cut[0 if cut_low else 1]
                    and inside <= i < len(grid) - inside):
                peaks.append(Peak(position=float(grid[i]), height=float(above[i]), width=float("nan")))
            continue
        x_left, x_right = crossings
        peaks.append(Peak(position=0.5 * (x_left + x_right), height=float(above[i]), width=x_right - x_left))
    return peaks


def level_crossings(x: np.ndarray, y: np.ndarray, i: int, level: float) -> tuple[float, float] | None:
    """Where the sampled profile y(x) falls to `level` left and right of sample i, interpolated linearly (the
    half-maximum points of a peak); None when it does not fall that low before an end of the profile."""
    left = i
    while left > 0 and y[left] > level:
        left -= 1
    right = i
    while right < len(y) - 1 and y[right] > level:
        right += 1
    if y[left] > level or y[right] > level:
        return None
    return _crossing(x, y, left, left + 1, level), _crossing(x, y, right - 1, right, level)


def _crossing(x: np.ndarray, y: np.ndarray, i: int, j: int, level: float) -> float:
    if y[j] == y[i]:
        return float(x[i])
    return float(x[i] + (level - y[i]) * (x[j] - x[i]) / (y[j] - y[i]))
