"""Occupancy grid on the wall surface: per-sensor log-odds and signal layers, vectorised inverse sensor model.

Metadata follows ROS `nav_msgs/OccupancyGrid` (`MapMetaData`): `resolution` [m/cell], `width` and `height`
[cells], and an origin pose — here the wall-frame (x, y) of the lower-left corner of cell (0, 0), no rotation.
Data are row-major arrays of shape (height, width): row r runs along wall y (row 0 lowest), column c along
wall x. The centre of cell (r, c) is origin + ((c + 0.5)·res, (r + 0.5)·res) (nav2's costmap convention).

Each sensor (inductive, capacitive, ac) has
  * a log-odds layer updated by an inverse sensor model: a reading at or above `threshold_occupied` adds
    evidence for "something in the wall here", at or below `threshold_free` evidence against, inside the
    sensor's measurement cone (a Gaussian footprint of radius `cone_radius_m` on the surface); in between
    the reading says nothing. Values are clamped to [LOG_ODDS_MIN, LOG_ODDS_MAX] after every batch.
  * a signal layer: the footprint-weighted mean reading (normalised convolution), which keeps the peak shape
    for sub-millimetre object localisation.
Vectorised as splat-then-convolve: each sample is split bilinearly onto its 4 nearest cell centres (np.bincount),
and the per-cell sums are convolved with the Gaussian footprint (linear, so equal to summing every sample's own
footprint, up to the bilinear split's sub-cell blur).
Cells no sample's footprint reached are *unknown* (NaN in float layers, -1 in the ROS int8 view), never free.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from geometry.errors import InputError
from mapping import tolerances as tol
from mapping.background import background_level
from scanner.channels import NAMES as CHANNEL_NAMES

SENSORS: tuple[str, ...] = CHANNEL_NAMES
_CHUNK = 500_000  # samples per vectorised batch (bounds memory to ~100 MB)


@dataclass(frozen=True)
class GridInfo:
    """nav_msgs/MapMetaData for a grid lying in the wall plane (z = 0), axis-aligned with the wall frame."""

    resolution: float
    width: int
    height: int
    origin_x: float = 0.0
    origin_y: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise InputError(f"grid resolution must be a positive number of metres, got {self.resolution}")
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"grid size must be positive, got {self.width}x{self.height} cells")
        if self.width * self.height > 60_000_000:
            raise InputError(f"grid of {self.width}x{self.height} cells is too large",
                             "use a coarser --resolution or a smaller wall")

    @classmethod
    def covering(cls, x_min: float, y_min: float, x_max: float, y_max: float,
                 resolution: float = tol.DEFAULT_RESOLUTION_M) -> GridInfo:
        """The grid of cells of `resolution` whose lower-left corner is (x_min, y_min) covering the box."""
        width = max(1, int(np.ceil((x_max - x_min) / resolution - 1e-9)))
        height = max(1, int(np.ceil((y_max - y_min) / resolution - 1e-9)))
        return cls(float(resolution), width, height, float(x_min), float(y_min))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the grid's outer edges, metres (matplotlib's `extent` order)."""
        return (self.origin_x, self.origin_x + self.width * self.resolution,
                self.origin_y, self.origin_y + self.height * self.resolution)

    def cell_centres(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(xs (width,), ys (height,)): wall coordinates of the cell centres, metres."""
        xs = self.origin_x + (np.arange(self.width, dtype=np.float64) + 0.5) * self.resolution
        ys = self.origin_y + (np.arange(self.height, dtype=np.float64) + 0.5) * self.resolution
        return xs, ys

    def cell_of(self, xy: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
        """(rows, cols, inside) of the cells containing wall points xy (n, 2)."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        cols = np.floor((p[:, 0] - self.origin_x) / self.resolution).astype(np.int64)
        rows = np.floor((p[:, 1] - self.origin_y) / self.resolution).astype(np.int64)
        inside = (cols >= 0) & (cols < self.width) & (rows >= 0) & (rows < self.height)
        return rows, cols, inside

    def to_pixel(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Continuous (col, row) coordinates of wall points (n, 2), cell centres at integers."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([(p[:, 0] - self.origin_x) / self.resolution - 0.5,
                                (p[:, 1] - self.origin_y) / self.resolution - 0.5])

    def to_wall(self, col_row: ArrayLike) -> NDArray[np.float64]:
        """Wall (x, y) metres of continuous (col, row) coordinates (n, 2); inverse of to_pixel."""
        q = np.asarray(col_row, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([self.origin_x + (q[:, 0] + 0.5) * self.resolution,
                                self.origin_y + (q[:, 1] + 0.5) * self.resolution])

    def to_ros(self, frame_id: str = "wall") -> dict:
        """The MapMetaData as a ROS-style mapping (origin as a pose with identity orientation)."""
        return {"header": {"frame_id": frame_id}, "info": {
            "resolution": self.resolution, "width": self.width, "height": self.height,
            "origin": {"position": {"x": self.origin_x, "y": self.origin_y, "z": 0.0},
                       "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}}


@dataclass(frozen=True)
class SensorModel:
    """Inverse sensor model of one wall-scanner channel.

    threshold_occupied / threshold_free: readings (the scanner's units) at/above which a cell is evidence
    for an object, at/below which evidence for none. cone_radius_m: radius of the measurement cone's
    footprint on the surface. log_odds_hit / log_odds_miss: evidence at the cone's centre.
    """

    name: str
    threshold_occupied: float
    threshold_free: float
    cone_radius_m: float = 0.012
    log_odds_hit: float = 0.85
    log_odds_miss: float = -0.4

    def __post_init__(self) -> None:
        if not self.threshold_free <= self.threshold_occupied:
            raise InputError(f"sensor model {self.name}: threshold_free {self.threshold_free} is above "
                             f"threshold_occupied {self.threshold_occupied}")
        if self.cone_radius_m <= 0:
            raise InputError(f"sensor model {self.name}: cone_radius_m must be positive")

    @classmethod
    def from_readings(cls, name: str, readings: ArrayLike, cone_radius_m: float = 0.012) -> SensorModel:
        """Thresholds from the readings themselves: background level plus multiples of its noise.

        Needs no knowledge of the scanner's units; the background is estimated from the lower quantiles
        (mapping.background.background_level), which stay background even where objects cover much of the wall.
        """
        a = np.asarray(readings, dtype=np.float64)
        a = a[np.isfinite(a)]
        if a.size == 0:
            raise InputError(f"sensor {name}: no finite readings to set thresholds from")
        level, spread = background_level(a)
        spread = max(spread, 1e-6 * max(1.0, abs(level)), 0.02 * float(np.percentile(a, 99.9) - level))
        return cls(name, threshold_occupied=level + 8.0 * spread, threshold_free=level + 3.0 * spread,
                   cone_radius_m=cone_radius_m)


@dataclass
class WallGrid:
    """Per-sensor layers on one GridInfo. Build with `add_samples` (any number of batches)."""

    info: GridInfo
    models: dict[str, SensorModel]
    log_odds: dict[str, NDArray[np.float32]] = field(default_factory=dict)
    signal_sum: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    weight_sum: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    samples_used: int = 0
    samples_rejected: int = 0
    _blurred: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        for name in self.models:
            self.log_odds.setdefault(name, np.zeros(self.info.shape, np.float32))
            self.signal_sum.setdefault(name, np.zeros(self.info.shape, np.float64))
            self.weight_sum.setdefault(name, np.zeros(self.info.shape, np.float64))

    @property
    def sensors(self) -> list[str]:
        return list(self.models)

    def add_samples(self, xy: ArrayLike, readings: Mapping[str, ArrayLike]) -> None:
        """Fuse samples taken at wall positions xy (n, 2) metres with readings {sensor: (n,)}.

        Samples with non-finite positions are skipped; a NaN reading skips that sensor only. Vectorised in
        batches; each batch's log-odds are clamped after it is added.
        """
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        values = {s: np.asarray(readings[s], dtype=np.float64).reshape(-1) for s in self.models
                  if s in readings}
        for s, v in values.items():
            if v.shape[0] != p.shape[0]:
                raise InputError(f"{s} readings have {v.shape[0]} values for {p.shape[0]} positions")
        for start in range(0, p.shape[0], _CHUNK):
            stop = start + _CHUNK
            self._add_chunk(p[start:stop], {s: v[start:stop] for s, v in values.items()})

    def _add_chunk(self, p: NDArray[np.float64], values: dict[str, NDArray[np.float64]]) -> None:
        finite = np.all(np.isfinite(p), axis=1)
        self.samples_rejected += int((~finite).sum())
        p = p[finite]
        values = {s: v[finite] for s, v in values.items()}
        if p.shape[0] == 0:
            return
        self.samples_used += int(p.shape[0])
        self._blurred.clear()
        idx, w = self._bilinear(self.info.to_pixel(p))
        n_cells = self.info.width * self.info.height
        for s, v in values.items():
            ok = np.isfinite(v)
            wk = w * ok[:, None]
            a = np.where(ok, v, 0.0)
            self.signal_sum[s] += np.bincount(idx.ravel(), (wk * a[:, None]).ravel(),
                                              minlength=n_cells).reshape(self.info.shape)
            self.weight_sum[s] += np.bincount(idx.ravel(), wk.ravel(), minlength=n_cells).reshape(self.info.shape)
            # Inverse sensor model: each sample's evidence spread over its measurement cone
            m = self.models[s]
            delta = np.where(v >= m.threshold_occupied, m.log_odds_hit,
                             np.where(v <= m.threshold_free, m.log_odds_miss, 0.0))
            delta = np.where(ok, delta, 0.0)
            splat = np.asarray(np.bincount(idx.ravel(), (wk * delta[:, None]).ravel(), minlength=n_cells),
                               dtype=np.float64)  # weighted counts are floats (numpy's stubs say int)
            cone = self._blur(splat.reshape(self.info.shape), m.cone_radius_m, peak_one=True)
            layer = self.log_odds[s]
            layer += cone.astype(np.float32)
            np.clip(layer, tol.LOG_ODDS_MIN, tol.LOG_ODDS_MAX, out=layer)

    def _bilinear(self, uv: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Flat indices (n, 4) and bilinear weights (n, 4) of the cells around each continuous (col, row)."""
        c0 = np.floor(uv[:, 0]).astype(np.int64)
        r0 = np.floor(uv[:, 1]).astype(np.int64)
        fc = uv[:, 0] - c0
        fr = uv[:, 1] - r0
        cols = np.stack([c0, c0 + 1, c0, c0 + 1], axis=1)
        rows = np.stack([r0, r0, r0 + 1, r0 + 1], axis=1)
        w = np.stack([(1 - fc) * (1 - fr), fc * (1 - fr), (1 - fc) * fr, fc * fr], axis=1)
        inside = (cols >= 0) & (cols < self.info.width) & (rows >= 0) & (rows < self.info.height)
        w = np.where(inside, w, 0.0)
        return np.where(inside, rows * self.info.width + cols, 0), w

    def _blur(self, layer: NDArray[np.float64], radius_m: float, peak_one: bool = False) -> NDArray[np.float64]:
        """Gaussian footprint (σ = radius/2, cut at the radius). peak_one: kernel scaled to 1 at its centre
        (evidence per sample), else normalised to sum 1 (a weighted mean)."""
        sigma = 0.5 * radius_m / self.info.resolution
        out = ndimage.gaussian_filter(layer, sigma, truncate=2.0, mode="constant")
        return out * (2.0 * np.pi * sigma**2) if peak_one else out

    def _blurred_sums(self, sensor: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if sensor not in self._blurred:
            radius = 2.0 * tol.SIGNAL_SPLAT_SIGMA_M
            self._blurred[sensor] = (self._blur(self.signal_sum[sensor], radius),
                                     self._blur(self.weight_sum[sensor], radius))
        return self._blurred[sensor]

    # ---- views -------------------------------------------------------------------------------------------
    def known(self, sensor: str) -> NDArray[np.bool_]:
        """Cells some sample's footprint reached (the rest is unknown)."""
        return self._blurred_sums(self._check(sensor))[1] > tol.KNOWN_WEIGHT

    def signal(self, sensor: str) -> NDArray[np.float64]:
        """(height, width) footprint-weighted mean reading, NaN where unknown."""
        s = self._check(sensor)
        num, den = self._blurred_sums(s)
        known = den > tol.KNOWN_WEIGHT
        out = np.full(self.info.shape, np.nan)
        out[known] = num[known] / den[known]
        return out

    def probability(self, sensor: str) -> NDArray[np.float64]:
        """(height, width) occupancy probability from the log-odds, NaN where unknown."""
        s = self._check(sensor)
        p = 1.0 / (1.0 + np.exp(-self.log_odds[s].astype(np.float64)))
        p[~self.known(s)] = np.nan
        return p

    def occupancy_int8(self, sensor: str) -> NDArray[np.int8]:
        """ROS OccupancyGrid data (height, width): -1 unknown, 0…100 occupancy probability in percent."""
        p = self.probability(sensor)
        out = np.full(p.shape, -1, np.int8)
        known = np.isfinite(p)
        out[known] = np.rint(100.0 * p[known]).astype(np.int8)
        return out

    def _check(self, sensor: str) -> str:
        if sensor not in self.models:
            raise InputError(f"no {sensor!r} layer in this map; layers: {', '.join(self.models)}")
        return sensor


def cell_resolution(cell_m: float, resolution: float) -> float:
    """The map cell size nearest below `resolution` that divides a record's cell `cell_m` exactly, so that the
    record's cell edges are map cell edges (a map cell lies in one record cell or in none)."""
    return cell_m / max(1, int(np.ceil(cell_m / resolution - 1e-9)))


def cell_points(xy: ArrayLike, values: ArrayLike, cell_m: float, resolution: float
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A gridded record's readings on the map: the centres of the map cells inside each record cell (xy (n, 2)
    record cell centres, wall metres, on a lattice of pitch cell_m from the wall's corner; the map's cells of
    `resolution` divide cell_m, cell_resolution) and the reading there, interpolated bilinearly between the
    centres of the measured record cells around it (a sampled field's reconstruction: a pipe across the cells
    stays a ridge, not a staircase). Only measured cells' points are given, so a reading covers exactly its
    cell; a cell whose reading is NaN gives NaN. Returns (points (m, 2), values (m,))."""
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    k = round(cell_m / resolution)
    offsets = (np.arange(k) + 0.5) * resolution - 0.5 * cell_m
    ox, oy = np.meshgrid(offsets, offsets)
    points = (p[:, None, :] + np.column_stack([ox.ravel(), oy.ravel()])[None, :, :]).reshape(-1, 2)
    owner = np.repeat(np.arange(len(p)), k * k)
    if p.size == 0:
        return points, np.zeros(0)
    ij = np.rint(p / cell_m - 0.5).astype(np.int64)  # lattice indices of the record cells
    lo = ij.min(axis=0)
    shape = tuple((ij.max(axis=0) - lo + 1)[::-1])
    lattice = np.full(shape, np.nan)  # (rows along y, columns along x)
    lattice[ij[:, 1] - lo[1], ij[:, 0] - lo[0]] = v
    q = points / cell_m - 0.5 - lo  # continuous lattice coordinates, cell centres at integers
    c0, r0 = np.floor(q[:, 0]).astype(np.int64), np.floor(q[:, 1]).astype(np.int64)
    fc, fr = q[:, 0] - c0, q[:, 1] - r0
    num, den = np.zeros(len(q)), np.zeros(len(q))
    for dc, dr, w in ((0, 0, (1 - fc) * (1 - fr)), (1, 0, fc * (1 - fr)), (0, 1, (1 - fc) * fr), (1, 1, fc * fr)):
        cc, rr = c0 + dc, r0 + dr
        inside = (cc >= 0) & (cc < shape[1]) & (rr >= 0) & (rr < shape[0])
        got = np.full(len(q), np.nan)
        got[inside] = lattice[rr[inside], cc[inside]]
        ok = np.isfinite(got)
        num[ok] += w[ok] * got[ok]
        den[ok] += w[ok]
    out = np.where(np.isfinite(v[owner]) & (den > 0), num / np.maximum(den, 1e-300), np.nan)
    return points, out


def build_grid(xy: ArrayLike, readings: Mapping[str, ArrayLike], info: GridInfo | None = None,
               models: Mapping[str, SensorModel] | None = None,
               sensors: Sequence[str] = SENSORS, resolution: float = tol.DEFAULT_RESOLUTION_M,
               margin_m: float = 0.02) -> WallGrid:
    """A WallGrid from samples in one call: grid covering the samples, thresholds from the readings.

    xy : (n, 2) float64, wall metres. readings: {sensor: (n,)} in the scanner's units (NaN = missing).
    """
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(p), axis=1)
    if not finite.any():
        raise InputError("no samples with a finite position to build a map from")
    if info is None:
        lo, hi = p[finite].min(axis=0) - margin_m, p[finite].max(axis=0) + margin_m
        info = GridInfo.covering(lo[0], lo[1], hi[0], hi[1], resolution)
    present = [s for s in sensors if s in readings]
    if not present:
        raise InputError(f"no readings of any sensor {', '.join(sensors)}")
    chosen: dict[str, SensorModel] = {}
    for s in present:
        if models is not None and s in models:
            chosen[s] = models[s]
        elif np.isfinite(np.asarray(readings[s], dtype=np.float64)).any():
            chosen[s] = SensorModel.from_readings(s, readings[s])
    if not chosen:
        raise InputError("every reading is NaN; nothing to map")
    grid = WallGrid(info, chosen)
    grid.add_samples(p, {s: readings[s] for s in chosen})
    return grid
