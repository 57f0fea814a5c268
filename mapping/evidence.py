"""What a scan looked at, cell by cell and sensor channel by channel: the evidence the drill check judges by.

Two boolean layers per channel on the map's grid (ROS `nav_msgs/OccupancyGrid` metadata, row-major, cell
centre = origin + (i + 0.5)·resolution):

- **covered**: some sample of that channel (a finite reading) was taken within the channel's coverage radius
  of the cell's centre. The radius is half the sensor footprint's σ at the surface (inductive 11 mm →
  5.5 mm): an object anywhere in a covered cell passed within that radius of the sensor's centre, so its
  signal reached at least exp(−1/8) = 88 % of its peak. Cells farther from every sample are *unknown*; no
  outline, plan or assumption widens this.
- **response**: where the channel's reading is more than the mapped objects explain (unexplained_cells: a fit
  of the objects' footprint-blurred shapes, the residual beyond four noise σ; capacitive both ways, since
  cavities lower it). Something is there that the map does not name: never "safe".

Which channel can tell what (scanner/sensor_model.py): inductive sees metal (pipes, cables' copper, screws,
nails, plates, steel studs); capacitive sees wood, water and cavities (a water-filled plastic pipe shows
nowhere else); AC sees live cables only. So a point is only judged free when both the inductive and the
capacitive channel covered it (SAFETY_CHANNELS); AC sharpens the class but is not needed to rule out.

File: `coverage.npz` beside wall.glb (numpy, no pickle): `format` = "arproj-coverage/1", `info` = (resolution,
width, height, origin_x, origin_y), `channels` (names), `covered` and `response` (n_channels, height, width)
uint8.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.errors import InputError
from geometry.inputs import NpzFile
from mapping import tolerances as tol
from mapping.grid import GridInfo, WallGrid
from mapping.map_object import MapObject
from mapping.mapfile import MappedObject
from scanner.channels import AC, CAPACITIVE, CHANNELS, INDUCTIVE, SAFETY, by_name
from scanner.channels import NAMES as CHANNEL_NAMES
from scanner.sensor_model import additive_units

FORMAT = "arproj-coverage/1"
FILE_NAME = "coverage.npz"
SAFETY_CHANNELS = SAFETY  # between them every object that matters shows
# What a channel can tell, for messages: a point it did not cover may hide these.
CHANNEL_SEES = {c.name: c.sees for c in CHANNELS}
# 0.6 of the footprint σ at the surface (scanner.channels, from scanner.sensor_model.SensorConfig: inductive
# σu 11 mm, capacitive twice the inductive, AC 4 mm): an object in a covered cell gives ≥ exp(−0.18) = 83 % of
# its peak.
COVERAGE_RADIUS_SIGMAS = 0.6
DEFAULT_COVERAGE_RADIUS_M = {c.name: COVERAGE_RADIUS_SIGMAS * c.footprint_sigma_m for c in CHANNELS}
_DEDUPE_M = 0.0005  # sample positions are merged on this raster before the nearest-sample search
_PAIRS_PER_CHUNK = 1 << 20  # nearest-sample search: (raster column, cell row) pairs handled at a time


def coverage_radii(sensor_meta: dict | None) -> dict[str, float]:
    """Coverage radius per channel from the scan's sensor settings (SensorConfig names), else the defaults."""
    meta = sensor_meta or {}
    radii = dict(DEFAULT_COVERAGE_RADIUS_M)
    su = meta.get("ind_sigma_u_m")
    if isinstance(su, (int, float)) and su > 0:
        radii[INDUCTIVE.name] = COVERAGE_RADIUS_SIGMAS * float(su)
        radii[CAPACITIVE.name] = COVERAGE_RADIUS_SIGMAS * 2.0 * float(su)  # capacitive footprint: twice the inductive
    ac = meta.get("ac_sigma_m")
    if isinstance(ac, (int, float)) and ac > 0:
        radii[AC.name] = COVERAGE_RADIUS_SIGMAS * float(ac)
    return radii


def sample_distance(info: GridInfo, xy: ArrayLike, max_radius_m: float) -> NDArray[np.float64]:
    """(height, width) distance from each cell centre to the nearest position of xy (n, 2) wall metres, less
    the merging error (a conservative figure); inf beyond max_radius_m."""
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(p), axis=1)
    if not finite.all():
        p = p[finite]
    out = np.full(info.shape, np.inf)
    if p.size == 0:
        return out
    # Positions merged on a fine raster over the grid (and the radius beyond it): no sort, bounded memory
    x0, y0 = info.origin_x - max_radius_m, info.origin_y - max_radius_m
    nx = int(np.ceil((info.width * info.resolution + 2 * max_radius_m) / _DEDUPE_M)) + 1
    ny = int(np.ceil((info.height * info.resolution + 2 * max_radius_m) / _DEDUPE_M)) + 1
    ix = np.floor((p[:, 0] - x0) / _DEDUPE_M).astype(np.int64)
    iy = np.floor((p[:, 1] - y0) / _DEDUPE_M).astype(np.int64)
    ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    if not ok.all():
        ix, iy = ix[ok], iy[ok]
    if ix.size == 0:
        return out
    # raster column by column: the merged positions sorted by (column, row)
    fine = np.zeros(nx * ny, bool)
    fine[ix * ny + iy] = True
    keys = np.flatnonzero(fine)
    del fine
    px = x0 + (np.arange(nx) + 0.5) * _DEDUPE_M  # the merged positions' coordinates, per raster column / row
    py = y0 + (np.arange(ny) + 0.5) * _DEDUPE_M
    col_of, row_of = keys // ny, keys % ny
    xs, ys = info.cell_centres()
    lo = np.array([px[col_of.min()], py[row_of.min()]]) - max_radius_m
    hi = np.array([px[col_of.max()], py[row_of.max()]]) + max_radius_m
    ci = np.flatnonzero((xs >= lo[0]) & (xs <= hi[0]))
    ri = np.flatnonzero((ys >= lo[1]) & (ys <= hi[1]))
    if ci.size == 0 or ri.size == 0:
        return out
    qx, qy = xs[ci], ys[ri]
    # The nearest position by the exact lower envelope (what a k-d tree finds, in a few array operations):
    # per cell row and raster column the nearest merged row (the last at or below the centre or the first
    # above), then per cell the nearest over the raster columns within the radius. Squared distances are
    # summed as dx² + dy², so the minimum is the same number the tree gives.
    split = np.searchsorted(py, qy, side="right")  # raster rows [0, split) lie at or below each cell row
    cols = np.flatnonzero(np.bincount(col_of, minlength=nx))  # raster columns holding any position
    dy2 = np.empty((split.size, cols.size))  # (cell rows, occupied raster columns)
    step = max(1, _PAIRS_PER_CHUNK // split.size)
    for c0 in range(0, cols.size, step):
        cc = cols[c0:c0 + step]
        q = (cc[:, None] * ny + split[None, :]).ravel()  # (column, cell row) pairs, sorted
        pos = np.searchsorted(keys, q, side="left")
        col_q = np.repeat(cc, split.size)
        qy_q = np.tile(qy, cc.size)
        best = np.full(q.size, np.inf)
        for cand in (pos, pos - 1):  # the first merged row at or above the split, and the last below it
            c = np.clip(cand, 0, keys.size - 1)
            same = (cand >= 0) & (cand < keys.size) & (col_of[c] == col_q)
            dy = py[row_of[c]] - qy_q
            best = np.where(same, np.minimum(best, dy * dy), best)
        dy2[:, c0:c0 + step] = best.reshape(cc.size, split.size).T
    pcx = px[cols]
    first = np.searchsorted(pcx, qx - max_radius_m, side="left")
    last = np.searchsorted(pcx, qx + max_radius_m, side="right")
    d2 = np.full((ri.size, ci.size), np.inf)
    for k in range(int((last - first).max(initial=0))):
        j = first + k
        use = j < last
        jj = np.minimum(j, cols.size - 1)
        dx = pcx[jj] - qx
        d2_j = (dx * dx)[None, :] + dy2[:, jj]
        d2 = np.where(use[None, :], np.minimum(d2, d2_j), d2)
    d = np.where(d2 < max_radius_m * max_radius_m, np.sqrt(d2), np.inf)
    # a merged position is within half a raster diagonal of the real one: count it that much farther
    out[np.ix_(ri, ci)] = d + 0.7072 * _DEDUPE_M
    return out


def covered_cells(info: GridInfo, xy: ArrayLike, radius_m: float) -> NDArray[np.bool_]:
    """(height, width) True where some position of xy (n, 2) wall metres lies within radius_m of the cell
    centre."""
    return sample_distance(info, xy, radius_m) <= radius_m


# Footprints at the surface and their growth with depth (scanner.sensor_model.SensorConfig), for the model of
# what the mapped objects explain
_IND_SIGMA_M, _IND_SPREAD = 0.016, 0.55
_AC_SIGMA_M, _AC_SPREAD = 0.004, 0.3
_DEFAULT_DEPTH_M = 0.03
_KERNEL_SCALES = (0.5, 0.7, 1.0, 1.4)  # each object may be shallower or deeper than assumed: a few widths to mix
_ROBUST_ROUNDS = 2  # refits without the cells the previous fit left unexplained, so they cannot bend it
UNEXPLAINED_SIGMAS = 4.0  # residual beyond this many noise σ is a response no object explains
MODEL_SLACK = 0.2  # ... plus this share of the objects' predicted signal (the model's shape is approximate)
_NNLS_MAX_ITER = 2000  # a few hundred columns at most: Lawson–Hanson needs far fewer steps
_MIN_BACKGROUND_CELLS = 50  # fewer cells beyond every object's reach cannot fix the empty wall's level
_FIT_STRIDE = 2  # the fit uses every 2nd cell each way (the signal is smooth over 4 mm cells)
# What each channel responds to (scanner.channels: screws and nails are too small to show capacitively, and
# only live cables and metal coupled to them show in AC).
_CHANNEL_SEES_CLASS = {c.name: c.responds_to for c in CHANNELS}


def _footprint_sigma(channel: str, cls: str, depth_m: float) -> float:
    inductive = float(np.hypot(_IND_SIGMA_M, _IND_SPREAD * depth_m))
    if channel == CAPACITIVE.name:
        return 2.0 * inductive
    if channel == AC.name:
        return float(np.hypot(_AC_SIGMA_M, _AC_SPREAD * depth_m)) if cls == "power_line" else 1.5 * inductive
    return inductive


def _distance_field(obj: MapObject, xs: NDArray[np.float64], ys: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances (len(ys), len(xs)) from cell centres to the object's centre line, point or outline (0 inside)."""
    from geometry.polyline import distances_to_polyline
    from scanner.sensor_model import points_in_polygon

    gx, gy = np.meshgrid(xs, ys)
    p = np.column_stack([gx.ravel(), gy.ravel()])
    pts = np.asarray(obj.points_m, dtype=np.float64)
    if obj.kind == "outline" and len(pts) >= 3:
        ring = pts[:-1] if np.allclose(pts[0], pts[-1]) else pts
        d = distances_to_polyline(p, np.vstack([ring, ring[:1]]))
        d = np.where(points_in_polygon(p, ring), 0.0, d)
    else:  # a pipe's own width (≤ 3 cm) is small beside the footprint: the kernel widths absorb it
        d = distances_to_polyline(p, pts)
    return d.reshape(len(ys), len(xs))


def sample_noise(readings: NDArray[np.float64], pass_id: NDArray[np.int64], sensor: str) -> float:
    """Per-sample noise σ of a channel (raw units) from consecutive readings of the same pass: neighbours
    1 mm apart differ by noise alone except on an object's flanks, which the median ignores."""
    v = additive_units(sensor, np.asarray(readings, dtype=np.float64))
    same = (np.diff(pass_id) == 0) & np.isfinite(v[1:]) & np.isfinite(v[:-1])
    d = np.diff(v)[same]
    if d.size < 10:
        return float("nan")
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def _nnls_gram(gram: NDArray[np.float64], atb: NDArray[np.float64]) -> NDArray[np.float64]:
    """min ‖Ax − b‖ with x ≥ 0 for tall A (many cells, few columns), from its small Gram matrix AᵀA and Aᵀb:
    the same minimiser, since ‖Ax − b‖² = ‖Rx − R⁻ᵀAᵀb‖² + const with AᵀA = RᵀR."""
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import nnls

    gram = gram.copy()
    gram[np.diag_indices_from(gram)] += 1e-10 * max(float(np.trace(gram)), 1e-30)  # kernels at near widths
    R = cho_factor(gram, lower=False)[0]
    R = np.triu(R)
    rhs = solve_triangular(R, atb, trans="T")
    return nnls(R, rhs, maxiter=_NNLS_MAX_ITER)[0]


@dataclass
class _Block:
    """An object's kernel columns (its footprint-blurred shape at each of _KERNEL_SCALES): values on the box
    of cells its footprint reaches (rows, cols), zero elsewhere."""

    rows: slice
    cols: slice
    values: NDArray[np.float64]  # (len(_KERNEL_SCALES), box height, box width)


def _overlap(p: slice, q: slice) -> slice | None:
    lo, hi = max(p.start, q.start), min(p.stop, q.stop)
    return slice(lo, hi) if lo < hi else None


def _fit_system(blocks: list[_Block], fit_mask: NDArray[np.bool_], target: NDArray[np.float64],
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float, int]:
    """AᵀA, Aᵀb of the kernel columns over the fit cells (b = target there), each column's sum over them, Σb
    and their count: the normal equations, from the overlaps of the blocks' boxes alone (columns vanish
    outside their box)."""
    n_s = len(_KERNEL_SCALES)
    n = len(blocks) * n_s
    gram, atb, sums = np.zeros((n, n)), np.zeros(n), np.zeros(n)
    b = np.where(fit_mask, target, 0.0)
    w = fit_mask.astype(np.float64)
    for k, bk in enumerate(blocks):
        kk = slice(k * n_s, (k + 1) * n_s)
        wk = w[bk.rows, bk.cols]
        vk = bk.values * wk  # the column over the fit cells only
        atb[kk] = np.einsum("ihw,hw->i", vk, b[bk.rows, bk.cols])
        sums[kk] = np.einsum("ihw->i", vk)
        for m in range(k, len(blocks)):
            bm = blocks[m]
            rows, cols = _overlap(bk.rows, bm.rows), _overlap(bk.cols, bm.cols)
            if rows is None or cols is None:
                continue
            sub_k = vk[:, rows.start - bk.rows.start:rows.stop - bk.rows.start,
                       cols.start - bk.cols.start:cols.stop - bk.cols.start]
            sub_m = bm.values[:, rows.start - bm.rows.start:rows.stop - bm.rows.start,
                              cols.start - bm.cols.start:cols.stop - bm.cols.start]
            g = np.einsum("ihw,jhw->ij", sub_k, sub_m)
            mm = slice(m * n_s, (m + 1) * n_s)
            gram[kk, mm] = g
            gram[mm, kk] = g.T
    return gram, atb, sums, float(b.sum()), int(fit_mask.sum())


def unexplained_cells(grid: WallGrid, sensor: str, objects: list[MapObject], covered: NDArray[np.bool_],
                      noise_sigma: float = float("nan")) -> NDArray[np.bool_]:
    """(height, width) True where the channel's reading is more than the mapped objects explain.

    The reading (inductive and AC converted back from the display's 1 − exp(−raw) to raw units, where
    objects add up) is fitted as a constant background plus, for each object the channel can see, its
    footprint-blurred shape at a few widths (non-negative amounts; a cavity lowers the capacitive reading).
    What stays above the fit by UNEXPLAINED_SIGMAS per-sample noise σ (noise_sigma, sample_noise; else the
    residual's robust spread) plus MODEL_SLACK of the predicted signal is something the map does not name:
    never "found nothing". Capacitive counts both ways (a cavity the map missed lowers it)."""
    out = np.zeros(grid.info.shape, bool)
    signal = grid.signal(sensor)
    known = np.isfinite(signal) & covered
    if known.sum() < 10:
        return out
    y = additive_units(sensor, signal)
    xs, ys = grid.info.cell_centres()
    blocks: list[_Block] = []
    splat = tol.SIGNAL_SPLAT_SIGMA_M  # the grid's own Gaussian splat widens every footprint
    for obj in objects:
        if obj.cls not in _CHANNEL_SEES_CLASS.get(sensor, ()):
            continue
        depth = _DEFAULT_DEPTH_M if obj.depth_m is None else float(obj.depth_m)
        base = float(np.hypot(_footprint_sigma(sensor, obj.cls, depth), splat))
        margin = 4.0 * base * _KERNEL_SCALES[-1]
        lo, hi = obj.points_m.min(axis=0) - margin, obj.points_m.max(axis=0) + margin
        ci = np.flatnonzero((xs >= lo[0]) & (xs <= hi[0]))
        ri = np.flatnonzero((ys >= lo[1]) & (ys <= hi[1]))
        if ci.size == 0 or ri.size == 0:
            continue
        d = _distance_field(obj, xs[ci], ys[ri])
        sign = -1.0 if (sensor == CAPACITIVE.name and obj.cls == "cavity") else 1.0
        # the cell centres are sorted: ri and ci are ranges
        blocks.append(_Block(slice(int(ri[0]), int(ri[-1]) + 1), slice(int(ci[0]), int(ci[-1]) + 1),
                             np.stack([sign * np.exp(-0.5 * (d / (base * scale)) ** 2)
                                       for scale in _KERNEL_SCALES])))
    n_columns = len(blocks) * len(_KERNEL_SCALES)
    sparse = np.zeros(grid.info.shape, bool)
    sparse[::_FIT_STRIDE, ::_FIT_STRIDE] = True
    fit_mask = known & sparse if (known & sparse).sum() >= n_columns + 10 else known.copy()
    # The empty wall's level from the cells no object's footprint reaches, where there are enough of them: a
    # free constant would trade itself against the kernels' tails.
    reach = np.zeros(grid.info.shape, bool)
    for bl in blocks:
        reach[bl.rows, bl.cols] |= np.any(np.abs(bl.values) > 1e-3, axis=0)
    far = known & ~reach
    level: float | None = None
    if far.sum() >= _MIN_BACKGROUND_CELLS:
        level = float(np.median(y[far]))
    elif sensor != CAPACITIVE.name and np.isfinite(noise_sigma):
        # objects only add to these channels: the empty wall is the low end (its 10th percentile lies
        # 1.28 σ below its level), as long as a tenth of the cells are empty
        level = float(np.percentile(y[known], 10)) + 1.2816 * noise_sigma
    for _ in range(_ROBUST_ROUNDS + 1):
        if not blocks:
            coef = np.array([float(np.median(y[fit_mask])) if level is None else level])
        elif level is None:  # a free constant as two non-negative columns, ±1
            gram_k, atb_k, sums, total, count = _fit_system(blocks, fit_mask, y)
            gram = np.zeros((n_columns + 2, n_columns + 2))
            gram[:2, :2] = [[count, -count], [-count, count]]
            gram[0, 2:], gram[1, 2:] = sums, -sums
            gram[2:, 0], gram[2:, 1] = sums, -sums
            gram[2:, 2:] = gram_k
            x = _nnls_gram(gram, np.concatenate([[total, -total], atb_k]))
            coef = np.concatenate([[x[0] - x[1]], x[2:]])
        else:
            gram, atb, _, _, _ = _fit_system(blocks, fit_mask, y - level)
            x = _nnls_gram(gram, atb)
            coef = np.concatenate([[level], x])
        predicted = np.zeros(grid.info.shape)
        for k, bl in enumerate(blocks):
            for c, values in zip(coef[1 + k * len(_KERNEL_SCALES):1 + (k + 1) * len(_KERNEL_SCALES)], bl.values,
                                 strict=True):
                if c != 0.0:
                    predicted[bl.rows, bl.cols] += c * values
        residual = np.where(known, y - coef[0] - predicted, 0.0)
        spread = noise_sigma if np.isfinite(noise_sigma) and noise_sigma > 0 else \
            1.4826 * float(np.median(np.abs(residual[known] - np.median(residual[known]))))
        limit = UNEXPLAINED_SIGMAS * max(spread, 1e-9) + MODEL_SLACK * np.abs(predicted)
        excess = np.abs(residual) if by_name(sensor).two_sided else residual
        out = known & (excess > limit)
        fit_mask &= ~out  # what is left unexplained must not pull the next fit towards it
    return out


@dataclass
class Coverage:
    """Per-channel covered and response layers on one grid (see the module docstring)."""

    info: GridInfo
    covered: dict[str, NDArray[np.bool_]]
    response: dict[str, NDArray[np.bool_]]
    bounds: tuple[float, float, float, float] | None = None  # the wall (x0, y0, x1, y1); None: the grid's

    @property
    def wall_bounds(self) -> tuple[float, float, float, float]:
        if self.bounds is not None:
            return self.bounds
        x0, x1, y0, y1 = self.info.extent
        return (x0, y0, x1, y1)

    @classmethod
    def from_grid(cls, grid: WallGrid, sample_xy: dict[str, NDArray[np.float64]], objects: list[MapObject],
                  radii: dict[str, float] | None = None, bounds: tuple[float, float, float, float] | None = None,
                  noise: dict[str, float] | None = None) -> Coverage:
        """sample_xy: per channel, the wall positions (n, 2) of the samples with a finite reading; objects:
        what the map names (their signal is explained, the rest of any response is not); noise: per-sample
        noise σ per channel (sample_noise)."""
        radii = radii or DEFAULT_COVERAGE_RADIUS_M
        noise = noise or {}
        covered, response = {}, {}
        radius = {c: radii.get(c, DEFAULT_COVERAGE_RADIUS_M[INDUCTIVE.name]) for c in grid.sensors}
        positions = {c: sample_xy.get(c, np.zeros((0, 2))) for c in grid.sensors}
        distance: dict[str, NDArray[np.float64]] = {}
        for sensor in grid.sensors:
            if sensor in distance:
                continue
            # channels read at the same positions share one nearest-sample search, out to the widest radius
            group = [c for c in grid.sensors if c not in distance and positions[c].shape == positions[sensor].shape
                     and np.array_equal(positions[c], positions[sensor])]
            d = sample_distance(grid.info, positions[sensor], max(radius[c] for c in group))
            distance.update(dict.fromkeys(group, d))
        for sensor in grid.sensors:
            covered[sensor] = distance[sensor] <= radius[sensor]
            response[sensor] = unexplained_cells(grid, sensor, objects, covered[sensor],
                                                 noise.get(sensor, float("nan")))
        return cls(grid.info, covered, response, bounds)

    @classmethod
    def complete(cls, info: GridInfo, channels: tuple[str, ...] = CHANNEL_NAMES,
                 bounds: tuple[float, float, float, float] | None = None) -> Coverage:
        """Everything looked at, no response: the simulation's truth (a wall file), never a scan."""
        return cls(info, {c: np.ones(info.shape, bool) for c in channels},
                   {c: np.zeros(info.shape, bool) for c in channels}, bounds)

    @property
    def channels(self) -> list[str]:
        return list(self.covered)

    def covered_by_all(self, channels: tuple[str, ...] = SAFETY_CHANNELS) -> NDArray[np.bool_]:
        """Cells every one of these channels covered (False everywhere if one is missing)."""
        out = np.ones(self.info.shape, bool)
        for c in channels:
            out &= self.covered.get(c, False)
        return out

    def covered_share(self, channels: tuple[str, ...] = SAFETY_CHANNELS) -> float:
        return float(self.covered_by_all(channels).mean())

    def cells_within(self, xy: ArrayLike, radius_m: float) -> tuple[NDArray[np.int64], NDArray[np.int64], bool]:
        """(rows, cols, whole) of the cells whose centres lie within radius_m of wall point xy; whole is False
        when part of that disc lies outside the grid (cells there were never looked at)."""
        p = np.asarray(xy, dtype=np.float64).reshape(2)
        info = self.info
        res = info.resolution
        c0 = int(np.floor((p[0] - radius_m - info.origin_x) / res))
        c1 = int(np.floor((p[0] + radius_m - info.origin_x) / res))
        r0 = int(np.floor((p[1] - radius_m - info.origin_y) / res))
        r1 = int(np.floor((p[1] + radius_m - info.origin_y) / res))
        whole = c0 >= 0 and r0 >= 0 and c1 < info.width and r1 < info.height
        cols, rows = np.meshgrid(np.arange(max(c0, 0), min(c1, info.width - 1) + 1),
                                 np.arange(max(r0, 0), min(r1, info.height - 1) + 1))
        cx = info.origin_x + (cols + 0.5) * res
        cy = info.origin_y + (rows + 0.5) * res
        # cells the disc touches at all: centre within the radius plus half a cell diagonal
        near = np.hypot(cx - p[0], cy - p[1]) <= radius_m + 0.7072 * res
        return rows[near].ravel(), cols[near].ravel(), whole

    def sample(self, layer: str, channel: str, xy: ArrayLike) -> NDArray[np.bool_]:
        """Layer values ('covered' or 'response') at wall points xy (n, 2); False outside the grid."""
        rows, cols, inside = self.info.cell_of(xy)
        grid = (self.covered if layer == "covered" else self.response).get(channel)
        out = np.zeros(len(rows), bool)
        if grid is not None:
            out[inside] = grid[rows[inside], cols[inside]]
        return out

    # ---- file ------------------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        path = Path(path)
        names = self.channels
        i = self.info
        with open(path, "wb") as f:
            np.savez_compressed(
                f, format=np.array(FORMAT), channels=np.array(names),
                info=np.array([i.resolution, i.width, i.height, i.origin_x, i.origin_y], dtype=np.float64),
                bounds=np.array(self.wall_bounds, dtype=np.float64),
                covered=np.stack([self.covered[c] for c in names]).astype(np.uint8),
                response=np.stack([self.response[c] for c in names]).astype(np.uint8))
        return path

    @classmethod
    def load(cls, path: str | Path) -> Coverage:
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no coverage layer beside the map",
                             "this map folder was written before coverage was recorded: run `arproj map` on the "
                             "scan log again; without it no point can be judged")
        hint = "run `arproj map` again"
        with NpzFile(path, "coverage layer", hint) as z:
            fmt = str(z.array("format", ndim=0, kinds="U"))
            names = [str(c) for c in z.array("channels", ndim=1, kinds="U")]
            res, w, h, ox, oy = (float(v) for v in z.floats("info", (5,)))
            bounds = tuple(float(v) for v in z.floats("bounds", (4,)))
            if not (res > 0 and 0 < w <= 100_000 and 0 < h <= 100_000 and w == int(w) and h == int(h)):
                raise InputError(f"{path}: grid info {res, w, h} is not a grid", hint)
            shape = (len(names), int(h), int(w))
            if fmt != FORMAT:
                raise InputError(f"{path}: format {fmt!r}, expected {FORMAT!r}", hint)
            if not 0 < len(names) <= 16:
                raise InputError(f"{path}: {len(names)} channels; a coverage layer has 1 to 16", hint)
            covered = z.array("covered", kinds="ub", shape=shape)
            response = z.array("response", kinds="ub", shape=shape)
        if len(bounds) != 4 or not np.all(np.isfinite(bounds)) or bounds[2] <= bounds[0] or bounds[3] <= bounds[1]:
            raise InputError(f"{path}: wall bounds {bounds} are not a rectangle", "run `arproj map` again")
        info = GridInfo(res, int(w), int(h), ox, oy)
        return cls(info, {c: covered[k].astype(bool) for k, c in enumerate(names)},
                   {c: response[k].astype(bool) for k, c in enumerate(names)}, bounds)


def regions(mask: NDArray[np.bool_], info: GridInfo, simplify_m: float = 0.003) -> list[dict]:
    """Polygons with holes around the True cells, for drawing and for objects.json: [{"exterior": [[x, y], …],
    "holes": [[[x, y], …], …]}, …] in wall metres. Derived from the layer, never used to judge a point."""
    import cv2
    from shapely.geometry import Polygon

    m = mask.astype(np.uint8)
    contours, hierarchy = cv2.findContours(m, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return []
    hierarchy = hierarchy[0]

    def ring(c: NDArray) -> NDArray[np.float64]:
        # contour points are cell indices (col, row): cell edges lie half a cell out, to_wall gives centres
        return info.to_wall(c.reshape(-1, 2).astype(np.float64))

    out = []
    for k, c in enumerate(contours):
        if hierarchy[k][3] != -1 or len(c) < 3:
            continue  # a hole: added to its parent below
        holes = []
        child = hierarchy[k][2]
        while child != -1:
            if len(contours[child]) >= 3:
                holes.append(ring(contours[child]))
            child = hierarchy[child][0]
        poly = Polygon(ring(c), holes).simplify(simplify_m)
        if poly.is_empty or poly.area <= 0:
            continue
        polys = list(poly.geoms) if hasattr(poly, "geoms") else [poly]
        for p in polys:
            out.append({"exterior": np.round(np.asarray(p.exterior.coords), 4).tolist(),
                        "holes": [np.round(np.asarray(h.coords), 4).tolist() for h in p.interiors]})
    return out


# Channels that see each class: a stretch one of them covered was measured (scanner.channels `measures`).
CLASS_CHANNELS = {cls: tuple(c.name for c in CHANNELS if cls in c.measures)
                  for cls in dict.fromkeys(cls for c in CHANNELS for cls in c.measures)}
_STRETCH_STEP_M = 0.002  # lines are cut where their evidence changes, to this resolution


def measured_stretches(points: NDArray[np.float64], measured_at: Callable[[NDArray[np.float64]], NDArray[np.bool_]]
                       ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """A polyline (k, 2) with vertices added where its evidence changes, and one flag per segment: True where
    measured_at(points) says its stretch was measured."""
    out_pts, flags = [points[0]], []
    for a, b in itertools.pairwise(points):
        n = max(int(np.ceil(np.linalg.norm(b - a) / _STRETCH_STEP_M)), 1)
        t = (np.arange(n) + 0.5) / n
        mids = a + t[:, None] * (b - a)
        ok = measured_at(mids)
        change = np.flatnonzero(np.diff(ok.astype(np.int8))) + 1  # first piece of each new run
        starts = np.concatenate([[0], change])
        for s, e in zip(starts, [*change, n], strict=True):
            end = a + (e / n) * (b - a)
            out_pts.append(end)
            flags.append(bool(ok[s]))
    pts, fl = np.array(out_pts), np.array(flags, bool)
    # merge consecutive collinear segments of equal evidence back (the cuts inside one segment)
    keep = [0]
    for k in range(1, len(pts) - 1):
        same = fl[k - 1] == fl[k]
        d1, d2 = pts[k] - pts[keep[-1]], pts[k + 1] - pts[k]
        scale = float(np.linalg.norm(d1) * np.linalg.norm(d2))
        straight = abs(d1[0] * d2[1] - d1[1] * d2[0]) <= 1e-12 * max(scale, 1e-30)
        if not (same and straight):
            keep.append(k)
    keep.append(len(pts) - 1)
    seg_flags = [bool(fl[keep[i]]) for i in range(len(keep) - 1)]
    return pts[keep], np.array(seg_flags, bool)


def mapped_objects(objects: list[MapObject], coverage: Coverage | None, sigma_m: float) -> list[MappedObject]:
    """The mapping's objects as objects.json holds them: each line cut into measured and inferred stretches
    by the coverage of the channels that see its class (without coverage: all measured)."""
    out = []
    for o in objects:
        channels = CLASS_CHANNELS.get(o.cls, (INDUCTIVE.name,))

        def measured_at(p: NDArray[np.float64], channels: tuple[str, ...] = channels) -> NDArray[np.bool_]:
            if coverage is None:
                return np.ones(len(p), bool)
            ok = np.zeros(len(p), bool)
            for c in channels:
                ok |= coverage.sample("covered", c, p)
            return ok

        points = np.asarray(o.points_m, dtype=np.float64)
        if o.kind == "line" and len(points) >= 2:
            points, flags = measured_stretches(points, measured_at)
        else:
            # a point or an outline: measured when a channel that sees it covered its place (its middle)
            flags = np.array([bool(measured_at(points.mean(axis=0, keepdims=True))[0])])
        out.append(MappedObject(o.cls, points, float(o.width_m), float(o.confidence), sigma_m, o.depth_m,
                                o.depth_sigma_m, flags, o.kind if o.kind in ("line", "point", "outline") else None))
    return out
