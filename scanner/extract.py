"""Line objects (pipes, cables) from a scan log's samples: per-pass peaks linked into straight segments.

This is the scanner package's own simple extractor (the benchmark's fallback and a check of the planners);
the full map with occupancy grid and frame stitching is mapping/'s job. Steps:
1. peaks on every pass (inductive with its hysteresis removed, and AC), placed on the wall with the measured
   positions (x_m, y_m); for dense rasters also peaks down the columns of the rows (horizontal objects run
   along the raster lines and only show as peaks across them);
2. a local direction for every peak from its nearest peak on a neighbouring parallel pass;
3. peaks linked when they lie on each other's course (within `lateral_tol_m`, directions within
   `angle_tol_deg`, gap ≤ `max_gap_m`); every linked group of ≥ 3 peaks spanning ≥ `min_extent_m` becomes a
   straight segment fitted by least squares.
It also has the evaluation used by `arproj bench scan`: recall and position error against the wall's truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scanner.peaks import PeakConfig, detect_peaks
from scanner.wall import Wall, densify, distance_to_polyline


@dataclass
class ExtractConfig:
    hysteresis_m: float = 0.003
    neighbour_max_m: float = 0.06  # partner peak for the local direction: on a parallel pass this close
    lateral_tol_m: float = 0.012
    angle_tol_deg: float = 12.0
    max_gap_m: float = 0.55  # coarse rows 0.25 m apart cross a 30° object every 0.5 m
    min_extent_m: float = 0.10  # screws and nails show as short streaks; pipes and cables are longer
    min_points: int = 3
    inlier_m: float = 0.006  # RANSAC: a peak this close to a line belongs to it
    column_step_m: float = 0.005  # column spacing of the dense raster's column detection


def pass_peaks(samples: dict[str, np.ndarray], cfg: ExtractConfig, peaks: PeakConfig | None = None) -> np.ndarray:
    """Peaks of every pass: (k, 4) array of x, y (wall metres), pass axis (0 x / 1 y), pass id."""
    out = []
    pass_ids = samples["pass_id"]
    order = np.argsort(pass_ids, kind="stable")
    bounds = np.flatnonzero(np.diff(pass_ids[order])) + 1
    for idx in np.split(order, bounds):
        if idx.size < 5:
            continue
        axis = int(samples["axis"][idx[0]])
        coord = samples["drive_u_m" if axis == 0 else "drive_v_m"][idx]
        direction = float(samples["direction"][idx[0]])
        found = []
        for channel in ("inductive", "ac"):
            lag = cfg.hysteresis_m * direction if channel == "inductive" else 0.0
            found += [p.position - lag for p in detect_peaks(coord, samples[channel][idx], peaks)]
        merged = _merge_close(found)
        order_c = np.argsort(coord)
        for pos in merged:
            x = np.interp(pos, coord[order_c], samples["x_m"][idx][order_c])
            y = np.interp(pos, coord[order_c], samples["y_m"][idx][order_c])
            out.append((x, y, axis, int(pass_ids[idx[0]])))
    return np.array(out, dtype=np.float64).reshape(-1, 4)


def column_peaks(samples: dict[str, np.ndarray], cfg: ExtractConfig, peaks: PeakConfig | None = None) -> np.ndarray:
    """For frames scanned by dense horizontal rows: peaks down each column (horizontal objects)."""
    out = []
    rows = samples["axis"] == 0
    frames = np.unique(samples["frame_id"][rows])
    column_cfg = PeakConfig(**{**(peaks or PeakConfig()).__dict__})
    for fid in frames:
        sel = np.flatnonzero(rows & (samples["frame_id"] == fid))
        v_levels = np.unique(np.round(samples["drive_v_m"][sel], 6))
        if len(v_levels) < 20 or np.median(np.diff(v_levels)) > 0.02:
            continue  # not a dense raster
        u_grid = np.arange(samples["drive_u_m"][sel].min(), samples["drive_u_m"][sel].max(), cfg.column_step_m)
        image = {ch: np.zeros((len(v_levels), len(u_grid))) for ch in ("inductive", "ac", "x_m", "y_m")}
        for channel_image in image.values():
            channel_image[:] = np.nan
        pid = samples["pass_id"][sel]
        for pass_id in np.unique(pid):
            idx = sel[pid == pass_id]
            row = np.searchsorted(v_levels, round(float(samples["drive_v_m"][idx[0]]), 6))
            u = samples["drive_u_m"][idx]
            o = np.argsort(u)
            direction = float(samples["direction"][idx[0]])
            for ch in image:
                shift = cfg.hysteresis_m * direction if ch == "inductive" else 0.0
                image[ch][row] = np.interp(u_grid, u[o] - shift, samples[ch][idx][o])
        for j in range(len(u_grid)):
            found = []
            for ch in ("inductive", "ac"):
                found += [p.position for p in detect_peaks(v_levels, image[ch][:, j], column_cfg,
                                                           grid_step_m=0.002)]
            for pos in _merge_close(found):
                out.append((np.interp(pos, v_levels, image["x_m"][:, j]), np.interp(pos, v_levels, image["y_m"][:, j]),
                            1, -1 - int(fid) * 10000 - j))
    return np.array(out, dtype=np.float64).reshape(-1, 4)


def link_segments(points: np.ndarray, cfg: ExtractConfig) -> list[np.ndarray]:
    """Straight segments (each (2, 2) endpoints, metres) from peak points (k, 4) as from pass_peaks."""
    if len(points) < 2:
        return []
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    xy = points[:, :2]
    pid = points[:, 3]
    axis = points[:, 2]
    n = len(xy)
    tree = cKDTree(xy)
    # local direction: principal axis of the peaks of the same pass axis within neighbour_max_m, when they
    # come from at least two other passes (one pass alone says nothing about the course)
    direction = np.full((n, 2), np.nan)
    for i, members in enumerate(tree.query_ball_point(xy, cfg.neighbour_max_m)):
        members = np.asarray(members)
        members = members[axis[members] == axis[i]]
        if len(np.unique(pid[members])) < 2:
            continue
        pts = xy[members] - xy[members].mean(axis=0)
        _, _, vt = np.linalg.svd(pts, full_matrices=False)
        direction[i] = vt[0]
    valid = ~np.isnan(direction[:, 0])
    pairs = tree.query_pairs(cfg.max_gap_m, output_type="ndarray")
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        keep = valid[i] | valid[j]  # a lone peak (end of an object, a single crossing) joins by the other's course
        i, j = i[keep], j[keep]
        di = np.where(valid[i][:, None], direction[i], direction[j])
        dj = np.where(valid[j][:, None], direction[j], direction[i])
        cos = np.abs(np.sum(di * dj, axis=1))
        d = xy[j] - xy[i]
        gap = np.linalg.norm(d, axis=1)
        lateral = np.maximum(np.abs(d[:, 0] * di[:, 1] - d[:, 1] * di[:, 0]),
                             np.abs(d[:, 0] * dj[:, 1] - d[:, 1] * dj[:, 0]))
        link = (cos >= math.cos(math.radians(cfg.angle_tol_deg))) & (lateral <= cfg.lateral_tol_m + 0.03 * gap)
        i, j = i[link], j[link]
    else:
        i = j = np.zeros(0, dtype=int)
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    groups: dict[int, list[int]] = {}
    for k in range(n):
        groups.setdefault(int(labels[k]), []).append(int(k))
    segments = []
    rng = np.random.default_rng(0)
    for members in groups.values():
        if len(members) >= cfg.min_points:
            segments += _fit_lines(xy[members], cfg, rng)
    return segments


def _fit_lines(pts: np.ndarray, cfg: ExtractConfig, rng: np.random.Generator) -> list[np.ndarray]:
    """Straight segments through a linked group: RANSAC lines (inliers within `inlier_m`), refitted by least
    squares, split where the inliers leave a gap > max_gap_m; repeated on the rest (bends, junctions)."""
    out = []
    remaining = pts
    while len(remaining) >= cfg.min_points:
        n = len(remaining)
        trials = min(300, n * (n - 1) // 2)
        a = rng.integers(0, n, trials)
        b = rng.integers(0, n, trials)
        keep = a != b
        a, b = a[keep], b[keep]
        if a.size == 0:
            break
        t = remaining[b] - remaining[a]
        norm = np.linalg.norm(t, axis=1)
        ok = norm > 0.01
        a, t = a[ok], t[ok] / norm[ok, None]
        if a.size == 0:
            break
        normal = np.column_stack([-t[:, 1], t[:, 0]])
        resid = np.abs(
                       np.einsum("tnk,tk->tn", remaining[None, :, :] - remaining[a][:, None, :], normal))
        inliers = resid < cfg.inlier_m
        best = int(np.argmax(inliers.sum(axis=1)))
        mask = inliers[best]
        if mask.sum() < cfg.min_points:
            break
        chosen = remaining[mask]
        centre = chosen.mean(axis=0)
        _, _, vt = np.linalg.svd(chosen - centre, full_matrices=False)
        direction = vt[0]
        s = np.sort((chosen - centre) @ direction)
        breaks = np.flatnonzero(np.diff(s) > cfg.max_gap_m)
        for lo, hi in zip(np.r_[0, breaks + 1], np.r_[breaks, len(s) - 1], strict=True):
            if hi - lo + 1 >= cfg.min_points and s[hi] - s[lo] >= cfg.min_extent_m:
                out.append(np.array([centre + s[lo] * direction, centre + s[hi] * direction]))
        remaining = remaining[~mask]
    return out


def extract_segments(samples: dict[str, np.ndarray], cfg: ExtractConfig | None = None) -> list[np.ndarray]:
    """Pipes and cables as straight segments from a scan's samples (see the module docstring)."""
    cfg = cfg or ExtractConfig()
    points = np.concatenate([pass_peaks(samples, cfg), column_peaks(samples, cfg)])
    return link_segments(points, cfg)


@dataclass
class Evaluation:
    recall: float  # fraction of pipes/cables found (>= `found_fraction` of their length within tolerance)
    length_recall: float  # fraction of their total length covered
    mean_error_m: float  # mean distance of covered truth points to the found segments
    false_length_m: float  # found segment length farther than the tolerance from any pipe/cable
    per_object: dict[str, float]  # object id -> covered fraction


def evaluate(wall: Wall, segments: list[np.ndarray], tolerance_m: float = 0.015,
             found_fraction: float = 0.7) -> Evaluation:
    """Compare found segments to the wall's pipes and cables. The defaults are the project's shared
    definition (mapping/evaluate.py): found = at least 70 % of the length within 1.5 cm of a found line."""
    per_object: dict[str, float] = {}
    errors: list[np.ndarray] = []
    covered_len = total_len = 0.0
    found = 0
    targets = wall.targets()
    for obj in targets:
        probe = densify(obj.points_m, 0.01)
        if segments:
            d = np.min([distance_to_polyline(probe, s) for s in segments], axis=0)
        else:
            d = np.full(len(probe), np.inf)
        covered = d <= tolerance_m
        frac = float(covered.mean())
        per_object[obj.id] = frac
        found += frac >= found_fraction
        covered_len += frac * obj.length()
        total_len += obj.length()
        errors.append(d[covered])
    false_len = 0.0
    for seg in segments:
        probe = densify(seg, 0.01)
        d = np.min([distance_to_polyline(probe, o.points_m) for o in targets], axis=0) if targets else \
            np.full(len(probe), np.inf)
        false_len += float((d > tolerance_m).mean()) * float(np.linalg.norm(seg[1] - seg[0]))
    all_err = np.concatenate(errors) if errors else np.zeros(0)
    return Evaluation(recall=found / max(1, len(targets)), length_recall=covered_len / max(total_len, 1e-9),
                      mean_error_m=float(all_err.mean()) if all_err.size else float("nan"),
                      false_length_m=false_len, per_object=per_object)


PEAK_MERGE_M = 0.015  # inductive and AC peaks closer than this along a pass are one object


def _merge_close(positions: list[float]) -> list[float]:
    """Sorted positions with each run of near-duplicates (within PEAK_MERGE_M) kept once, at its first."""
    merged: list[float] = []
    for pos in sorted(positions):
        if not merged or abs(pos - merged[-1]) >= PEAK_MERGE_M:
            merged.append(pos)
    return merged
