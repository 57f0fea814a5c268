"""Lines from sparse scans (adaptive plans): 1-D peaks per pass, linked into lines by sequential RANSAC.

A dense raster fills the grid and mapping.objects finds ridges in it; an adaptive plan (coarse passes 25 cm
apart, then short passes to confirm and trace) leaves most of the wall unknown, so there the lines are built
from the passes themselves: every pass's inductive and AC peaks (scanner.peaks: half-maximum midpoints, the
inductive lag undone) are points where a line crosses the pass; collinear points from several passes are one
straight run (RANSAC, then least squares on the inliers), runs are split at gaps and joined at bends like the
dense ridges. Classification uses each line's peaks: a narrow AC crest is a live cable; the inductive height
against the height a pipe would give at the depth its width implies separates cables, pipes and sheet metal.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
from numpy.typing import NDArray
from scipy.special import expit

from geometry.polyline import distances_to_polyline
from geometry.robust import best_hypothesis, draw_samples, fit_line, refine
from mapping import tolerances as tol
from mapping.background import background_level
from mapping.fusion import FusionParams, InductiveModel, raw_from_display
from mapping.map_object import MapObject
from mapping.objects import join_polylines
from scanner.channels import AC, CAPACITIVE, INDUCTIVE
from scanner.peaks import PeakConfig, detect_peaks, level_crossings
from scanner.sensor_model import additive_units

RANSAC_INLIER_M = 0.004  # a peak this close to a line belongs to it
MIN_CROSSING_SIN = float(np.sin(np.radians(20.0)))  # ... if its pass crosses the line at 20° or more
RANSAC_PAIRS = 400
MIN_PEAKS_PER_LINE = 3
MAX_GAP_M = 0.40  # peaks of one run are at most this far apart along the line (coarse passes: 25 cm)
AC_CREST_MAX_WIDTH_M = 0.03  # an AC peak narrower than this (FWHM) is a live cable's crest


@dataclass
class PassPeaks:
    """Peaks of all passes of one channel: xy (n, 2) wall metres, height (n,) display units over the pass's
    baseline, width (n,) FWHM metres, axis (n,) 0 = along x, pass_id (n,)."""

    xy: NDArray[np.float64]
    height: NDArray[np.float64]
    width: NDArray[np.float64]
    axis: NDArray[np.int64]
    pass_id: NDArray[np.int64]
    baseline: float


def pass_peaks(samples: dict[str, NDArray], xy: NDArray[np.float64], channel: str, lag_m: float = 0.0,
               min_height: float = 0.04, base: float | None = None) -> PassPeaks:
    """Peaks of `channel` along every pass; the along-pass coordinate is shifted back by lag_m (hysteresis);
    heights over `base` (default: the scan's 20th percentile of the channel)."""
    pids = samples["pass_id"]
    order = np.argsort(pids, kind="stable")
    pid_sorted = pids[order]
    starts = np.flatnonzero(np.r_[True, pid_sorted[1:] != pid_sorted[:-1]])
    ends = np.r_[starts[1:], len(order)]
    cfg = PeakConfig(min_height=min_height, min_prominence=0.75 * min_height, min_distance_m=0.015)
    out: dict[str, list] = {"xy": [], "height": [], "width": [], "axis": [], "pass_id": []}
    values = samples[channel]
    finite = values[np.isfinite(values)]
    # one background for the whole scan: a short trace pass's own 20th percentile sits on the peak's tails
    # and would shrink both the height and the width
    global_base = base if base is not None else float(np.percentile(finite, 20)) if finite.size else 0.0
    rows: list[_Row] = []  # every crossing pass, sorted along
    for a, b in zip(starts, ends, strict=True):
        idx = order[a:b]
        p = xy[idx]
        v = values[idx]
        ok = np.all(np.isfinite(p), axis=1) & np.isfinite(v)
        if ok.sum() < 10:
            continue
        p, v = p[ok], v[ok]
        axis = int(samples["axis"][idx[0]])
        if axis > 1:
            continue  # a following pass runs along a line: its peaks are not crossings
        direction = float(samples["direction"][idx[0]])
        along = p[:, axis] - direction * lag_m
        srt = np.argsort(along)
        row = _Row(axis, float(np.median(p[srt, 1 - axis])), along[srt], p[srt], v[srt],
                   int(samples["pass_id"][idx[0]]), int(samples["frame_id"][idx[0]]) if "frame_id" in samples else 0)
        rows.append(row)
        _add_peaks(out, row, detect_peaks(row.along, row.values, cfg), global_base, channel)
    # Where two frames' passes meet end to end at a seam, an object in the narrow overlap is cut by both passes'
    # ends; the two passes joined show it whole.
    for ri, rj in _seam_pairs(rows):
        lo, hi = max(ri.along[0], rj.along[0]), min(ri.along[-1], rj.along[-1])
        keep_i = (ri.along >= lo - SEAM_WINDOW_M) & (ri.along <= hi + SEAM_WINDOW_M)
        keep_j = ((rj.along >= lo - SEAM_WINDOW_M) & (rj.along <= hi + SEAM_WINDOW_M)
                  & ((rj.along < ri.along[0]) | (rj.along > ri.along[-1])))
        along = np.concatenate([ri.along[keep_i], rj.along[keep_j]])
        srt = np.argsort(along)
        joined = _Row(ri.axis, ri.across, along[srt], np.vstack([ri.xy[keep_i], rj.xy[keep_j]])[srt],
                      np.concatenate([ri.values[keep_i], rj.values[keep_j]])[srt], ri.pass_id, ri.frame_id)
        have = [q[ri.axis] for q, a, pp in zip(out["xy"], out["axis"], out["pass_id"], strict=True)
                if a == ri.axis and pp in (ri.pass_id, rj.pass_id)]
        found = [pk for pk in detect_peaks(joined.along, joined.values, cfg)
                 if lo - SEAM_REACH_M <= pk.position <= hi + SEAM_REACH_M
                 and all(abs(pk.position - h) > cfg.min_distance_m for h in have)]
        _add_peaks(out, joined, found, global_base, channel)
    xy_all = np.array(out["xy"]).reshape(-1, 2)
    # in the order of the wall, not of the passes: the lines found do not depend on the order the plan ran
    # its passes in (priors reorder them), only on what they measured
    order = np.lexsort((np.round(xy_all[:, 1], 6), np.round(xy_all[:, 0], 6)))
    return PassPeaks(xy_all[order], np.array(out["height"], dtype=np.float64)[order],
                     np.array(out["width"], dtype=np.float64)[order], np.array(out["axis"], dtype=np.int64)[order],
                     np.array(out["pass_id"], dtype=np.int64)[order], global_base)


SEAM_ACROSS_M = 0.012  # passes of two frames this close across (frames land a few mm apart), meeting end to end,
# are one row: the footprint (σ 11-16 mm) sees the same crossing from either
SEAM_WINDOW_M = 0.06  # ... joined this far either side of their overlap (a footprint's full width)
SEAM_REACH_M = 0.03  # ... for peaks this close to the overlap


@dataclass
class _Row:
    """One crossing pass: its axis (0: along x, 1: along y), where it runs across, and its samples sorted along
    (lag undone)."""

    axis: int
    across: float
    along: NDArray[np.float64]
    xy: NDArray[np.float64]
    values: NDArray[np.float64]
    pass_id: int
    frame_id: int


def _seam_pairs(rows: list[_Row]) -> list[tuple[_Row, _Row]]:
    """Pairs of crossing passes of different frames along the same row that meet end to end (overlapping, or a
    gap under 1 cm, neither inside the other)."""
    ordered = sorted(rows, key=lambda r: (r.axis, r.across))
    pairs = []
    for n, ri in enumerate(ordered):
        for rj in ordered[n + 1:]:
            if rj.axis != ri.axis or rj.across - ri.across > SEAM_ACROSS_M:
                break
            a, b = ri.along, rj.along
            meet = min(a[-1], b[-1]) - max(a[0], b[0]) > -0.01
            nested = (a[0] <= b[0] and b[-1] <= a[-1]) or (b[0] <= a[0] and a[-1] <= b[-1])
            if rj.frame_id != ri.frame_id and meet and not nested:
                pairs.append((ri, rj))
    return pairs


def _add_peaks(out: dict[str, list], row: _Row, peaks: list, base: float, channel: str) -> None:
    for pk in peaks:
        height, width = _height_width(row.along, row.values, pk.position, base, channel)
        if not np.isfinite(width):
            continue  # the half-maximum lies beyond the pass's end: the centre is not trustworthy
        point = np.empty(2)
        point[row.axis] = pk.position
        point[1 - row.axis] = float(np.interp(pk.position, row.along, row.xy[:, 1 - row.axis]))
        out["xy"].append(point)
        out["height"].append(height)
        out["width"].append(width)
        out["axis"].append(row.axis)
        out["pass_id"].append(row.pass_id)


def _height_width(along: NDArray[np.float64], v: NDArray[np.float64], position: float,
                  base: float, channel: str = "") -> tuple[float, float]:
    """(height over base, full width at half maximum) of the peak at `position` of the sorted profile; an
    inductive peak's width in additive units (the footprint's own: a saturated display top is wider)."""
    k = int(np.clip(np.searchsorted(along, position), 0, len(along) - 1))
    lo, hi = max(0, k - 3), min(len(v), k + 4)
    top = float(np.median(np.sort(v[lo:hi])[-3:]))  # robust to one noisy sample
    height = top - base
    if channel == INDUCTIVE.name:
        v = additive_units(channel, v)
        top, base = (float(x) for x in additive_units(channel, np.array([top, base])))
    crossings = level_crossings(along, v, k, base + 0.5 * (top - base))
    if crossings is None:
        return height, float("nan")
    return height, crossings[1] - crossings[0]


def _crosses(axis: NDArray, u: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Whether passes along `axis` (0: x, 1: y) cross a line of unit direction u (2,) or directions (h, 2) at
    MIN_CROSSING_SIN or more; (n,) or (h, n). Only a crossing pass's peak is a crossing of the line: a pass along
    a stud sees its nails one after another, peaks in a row that are no line."""
    across = np.where(axis == 0, u[..., 1, None], u[..., 0, None])
    return np.abs(across) >= MIN_CROSSING_SIN


def _refit_run(p: NDArray[np.float64], axis: NDArray, inl: NDArray[np.bool_]) -> tuple[None, NDArray[np.bool_]]:
    """Least squares through a run's peaks p[inl], then the peaks near that line whose pass crosses it."""
    c, u = fit_line(p[inl])
    nrm = np.array([-u[1], u[0]])
    return None, (np.abs((p - c) @ nrm) < RANSAC_INLIER_M) & _crosses(axis, u)


def ransac_lines(peaks: PassPeaks, seed: int = 0) -> list[tuple[NDArray[np.float64], NDArray[np.int64]]]:
    """Straight runs through the peaks: [(endpoints (2, 2), indices of their peaks)], strongest first."""
    rng = np.random.default_rng(seed)
    remaining = np.arange(peaks.xy.shape[0])
    runs = []
    while remaining.size >= MIN_PEAKS_PER_LINE:
        p = peaks.xy[remaining]
        a, b = draw_samples(rng, p.shape[0], 2, RANSAC_PAIRS, by_column=True).T
        d = p[b] - p[a]
        length = np.linalg.norm(d, axis=1)
        good = (length > 0.01) & (length < 1.0) & (peaks.pass_id[remaining][a] != peaks.pass_id[remaining][b])
        if not good.any():
            break
        a, d, length = a[good], d[good], length[good]
        n = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
        dist = np.abs(np.einsum("hj,hnj->hn", n, p[None, :, :] - p[a][:, None, :]))  # (hypotheses, points)
        axis = peaks.axis[remaining]
        crossing = _crosses(axis, d / length[:, None])  # (hypotheses, points)
        counts = ((dist < RANSAC_INLIER_M) & crossing).sum(axis=1)
        best = best_hypothesis(len(counts), counts.__getitem__)
        if counts[best] < MIN_PEAKS_PER_LINE:
            break
        inl = (dist[best] < RANSAC_INLIER_M) & crossing[best]
        _, inl = refine(inl, partial(_refit_run, p, axis), rounds=2, min_inliers=2)
        idx = remaining[inl]
        c, u = fit_line(peaks.xy[idx]) if idx.size >= 2 else (peaks.xy[idx[0]], np.array([1.0, 0.0]))
        t = (peaks.xy[idx] - c) @ u
        srt = np.argsort(t)
        t, idx_sorted = t[srt], idx[srt]
        cuts = np.flatnonzero(np.diff(t) > MAX_GAP_M) + 1
        for tt, ii in zip(np.split(t, cuts), np.split(idx_sorted, cuts), strict=True):
            if ii.size >= MIN_PEAKS_PER_LINE and len(set(peaks.pass_id[ii].tolist())) >= 2 and \
                    tt[-1] - tt[0] >= tol.LINE_MIN_LENGTH_M:
                cc, uu = fit_line(peaks.xy[ii])
                ts = (peaks.xy[ii] - cc) @ uu
                runs.append((np.array([cc + ts.min() * uu, cc + ts.max() * uu]), ii))
        remaining = remaining[~inl]
    return runs


ALONG_LATERAL_M = 0.006  # samples of a pass this close to a run's centre line measure it (a line 6 mm aside still
# gives 86 % of its level: the inductive footprint σ across is 11 mm)
ALONG_BIN_M = 0.01  # ... in bins this long
ALONG_MIN_COVER = 0.5  # a run is judged along its length where passes along it cover this share of its bins
ALONG_MAX_LOW = 0.5  # ... and is no line where more than this share of them falls below half its weakest crossing


SHORT_RUN_M = 0.10  # runs shorter than this may be one point crossed by a few passes at its flanks


def _a_point_seen_by_its_flanks(poly: NDArray[np.float64], tops: NDArray[np.float64], baseline: float,
                                channel: str) -> bool:
    """A short run whose crossings differ more than twofold in height (additive units, over the background) is a
    point crossed by passes at its centre and its flanks, not a line: a line's crossings keep its level (gain
    jitter 2 %, the footprint's anisotropy 1.45 at most between crossing angles)."""
    if float(np.linalg.norm(poly[1] - poly[0])) >= SHORT_RUN_M or len(tops) < 2:
        return False
    base = float(additive_units(channel, np.array([baseline]))[0])
    h = additive_units(channel, np.asarray(tops, dtype=np.float64)) - base
    return bool(h.min() < 0.5 * h.max())


MIN_CROSSING_PLACES = 3  # a line is crossed in at least this many places along it ...
CROSSING_PLACE_GAP_M = 0.02  # ... peaks closer than this along it being one place


def _crossed_in_few_places(poly: NDArray[np.float64], xy: NDArray[np.float64]) -> bool:
    """A run whose peaks lie in fewer than MIN_CROSSING_PLACES places along it joins objects, not a course: two
    screws or a nail and a cable's crossing, each crossed by several passes, line up with anything. The
    adaptive plan crosses every course it traces where it found it, beside that (the confirm pass, 3 cm off)
    and at each trace step; a raster crosses a course every centimetre. (On the 24 hard-case walls every true
    run had peaks in 3 places or more, and 7 runs in 2 places were all false.)"""
    u = poly[1] - poly[0]
    u = u / max(float(np.linalg.norm(u)), 1e-12)
    t = np.sort((xy - poly[0]) @ u)
    return 1 + int(np.sum(np.diff(t) > CROSSING_PLACE_GAP_M)) < MIN_CROSSING_PLACES


def _refuted_along(poly: NDArray[np.float64], height: float, baseline: float, xy: NDArray[np.float64],
                   values: NDArray[np.float64], axis: NDArray) -> bool:
    """A straight run of peaks that passes running along it show is no line: the nails of a stud, crossed one
    by one by short passes, line up like a cable, but a pass along the stud falls to nothing between them where
    a cable keeps its level. Only passes parallel to the run (or following passes) count."""
    u = poly[1] - poly[0]
    length = float(np.linalg.norm(u))
    if length < 2 * ALONG_BIN_M:
        return False
    u = u / length
    parallel = (axis > 1) | ~_crosses(axis, u)  # following passes (axis 2) run along their line
    rel = xy - poly[0]
    t = rel @ u
    off = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
    near = parallel & np.isfinite(values) & (off <= ALONG_LATERAL_M) & (t >= 0.0) & (t <= length)
    if not near.any():
        return False
    n_bins = int(length / ALONG_BIN_M) + 1
    top = _top_by_bin(t[near], values[near], n_bins)
    covered = np.isfinite(top)
    if covered.sum() < ALONG_MIN_COVER * n_bins:
        return False
    low = top - baseline < 0.5 * height
    return bool(low[covered].mean() > ALONG_MAX_LOW)


def _top_by_bin(t: NDArray[np.float64], values: NDArray[np.float64], n_bins: int) -> NDArray[np.float64]:
    """The highest value in each ALONG_BIN_M bin of t ≥ 0 (the last bin takes what lies beyond); −inf where
    no sample fell."""
    top = np.full(n_bins, -np.inf)
    np.maximum.at(top, np.minimum((t / ALONG_BIN_M).astype(np.int64), n_bins - 1), values)
    return top


EXTEND_REACH_M = 0.30  # a run is extended along a following pass at most this far beyond its end crossing


def _extended_along(poly: NDArray[np.float64], heights: NDArray[np.float64], baseline: float,
                    xy: NDArray[np.float64], values: NDArray[np.float64], axis: NDArray,
                    channel: str = INDUCTIVE.name) -> NDArray[np.float64]:
    """The run lengthened at each end as far as a following pass (axis 2) measured it on: bins of ALONG_BIN_M
    beyond the end crossing, within ALONG_LATERAL_M of its line, each covered, at least half the run's
    weakest crossing (heights: display units over the background) and at most twice its strongest (additive
    units): the first bin that is not ends it. The plan follows a course to the wall's edge or its end past
    its last crossing, and what was measured there is drawn; a rise far above the course's own level is what
    it runs into (a box), not more of it."""
    out = poly.copy()
    follow = (axis > 1) & np.isfinite(values)
    if not follow.any():
        return out
    p, v = xy[follow], values[follow]
    base = float(additive_units(channel, np.array([baseline]))[0])
    strongest = float(additive_units(channel, np.array([baseline + float(np.max(heights))]))[0]) - base
    n_bins = int(EXTEND_REACH_M / ALONG_BIN_M)
    for end, other in ((1, 0), (0, 1)):
        u = poly[end] - poly[other]
        u = u / max(float(np.linalg.norm(u)), 1e-12)
        rel = p - poly[end]
        t = rel @ u
        near = (np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0]) <= ALONG_LATERAL_M) & (t > 0) & (t <= EXTEND_REACH_M)
        if not near.any():
            continue
        top = _top_by_bin(t[near], v[near], n_bins)
        on = (top - baseline >= 0.5 * float(np.min(heights))) & (additive_units(channel, top) - base <= 2 * strongest)
        k = int(np.argmin(on)) if not on.all() else n_bins  # bins on the object before the first that is not
        if k:
            out[end] = poly[end] + u * min(k * ALONG_BIN_M, float(t[near].max()))
    return out


def lines_from_passes(samples: dict[str, NDArray], xy: NDArray[np.float64], lag_m: float,
                      inductive: InductiveModel, params: FusionParams) -> list[MapObject]:
    """Classified line objects from the passes of a (sparse) scan."""
    objects: list[MapObject] = []
    if AC.name in samples:
        ac = pass_peaks(samples, xy, AC.name, 0.0, min_height=0.03)
        crest = ac.width < AC_CREST_MAX_WIDTH_M
        ac_crests = PassPeaks(ac.xy[crest], ac.height[crest], ac.width[crest], ac.axis[crest], ac.pass_id[crest],
                              ac.baseline)
        objects += _build(ac_crests, AC.name, inductive, params)
    if INDUCTIVE.name in samples:
        ind = pass_peaks(samples, xy, INDUCTIVE.name, lag_m, min_height=0.04)
        kept = list(objects)
        along = (xy, samples[INDUCTIVE.name], samples["axis"])
        for obj in _build(ind, INDUCTIVE.name, inductive, params, along):
            pts = np.vstack([obj.points_m[0] + t * (obj.points_m[-1] - obj.points_m[0])
                             for t in np.linspace(0, 1, 11)])
            if kept and np.min([distances_to_polyline(pts, k.points_m) for k in kept], axis=0).mean() < 0.015:
                continue  # a cable the AC sensor already placed
            objects.append(obj)
    return objects


def _build(peaks: PassPeaks, channel: str, model: InductiveModel, params: FusionParams,
           along: tuple[NDArray[np.float64], NDArray[np.float64], NDArray] | None = None) -> list[MapObject]:
    runs = ransac_lines(peaks)
    runs = [r for r in runs if not _a_point_seen_by_its_flanks(r[0], peaks.height[r[1]] + peaks.baseline,
                                                               peaks.baseline, channel)
            and not _crossed_in_few_places(r[0], peaks.xy[r[1]])]
    if along is not None:
        # against the run's weakest crossing: a cable running into a box keeps its own level, lower than the box's
        runs = [r for r in runs if not _refuted_along(r[0], float(np.min(peaks.height[r[1]])), peaks.baseline,
                                                      *along)]
        runs = [(_extended_along(r[0], peaks.height[r[1]], peaks.baseline, *along, channel), r[1]) for r in runs]
    if not runs:
        return []
    polys = [r[0] for r in runs]
    members = [r[1] for r in runs]
    widths, strengths = [], []
    for poly, ii in zip(polys, members, strict=True):
        u = poly[1] - poly[0]
        u = u / max(float(np.linalg.norm(u)), 1e-12)
        # a pass crossing the line obliquely sees a wider peak: width across = FWHM · |sin(angle)|
        pass_dir = np.where(peaks.axis[ii][:, None] == 0, [[1.0, 0.0]], [[0.0, 1.0]])
        sin = np.abs(pass_dir[:, 0] * u[1] - pass_dir[:, 1] * u[0])
        widths.append(float(np.median(peaks.width[ii] * sin)))
        strengths.append(float(np.median(peaks.height[ii])))
    joined, widths, strengths = join_polylines(polys, widths, strengths)
    out = []
    for poly, width, height in zip(joined, widths, strengths, strict=True):
        obj = MapObject("line", poly, width, height)
        obj.features = {"length_m": obj.length_m(), "width_m": width, f"{channel}_peak": height,
                        "source": 1.0 if channel == AC.name else 0.0}
        if channel == AC.name:
            obj.cls, obj.confidence = "power_line", float(expit((height - 0.05) / 0.01))
        else:
            _classify_inductive(obj, peaks.baseline, model, params)
        out.append(obj)
    return out


def _classify_inductive(obj: MapObject, baseline: float, model: InductiveModel, params: FusionParams) -> None:
    seg = np.diff(obj.points_m, axis=0)
    main = seg[int(np.argmax(np.linalg.norm(seg, axis=1)))]
    depth = model.depth_from_width(obj.width_m, main)
    amp = float(raw_from_display(baseline + obj.strength) - raw_from_display(baseline))
    ratio = amp / model.pipe_peak_raw(depth, main)
    obj.features.update({"inductive_raw": amp, "depth_est_m": depth, "strength_ratio": ratio})
    log_ratio = float(np.log(max(ratio, 1e-6)))
    cable = float(expit((np.log(params.cable_max_ratio) - log_ratio) / 0.3))
    sheet = float(expit((log_ratio - np.log(params.area_min_ratio)) / 0.3))
    scores = {"power_line": cable, "metal_pipe": (1 - cable) * (1 - sheet), "metal": (1 - cable) * sheet}
    obj.cls = max(scores, key=scores.get)  # type: ignore[arg-type]
    obj.confidence = float(scores[obj.cls] / max(sum(scores.values()), 1e-9))


CAP_MIN_SIGMAS = 10.0  # a capacitive crossing rises (or a cavity falls) this many background σ: 0.04 at the
# simulated 0.004 noise; a wooden stud behind drywall rises 0.28, a water-filled pipe 2-3 cm deep ~0.1, a cavity
# falls 0.19 (hard-case walls)
CAP_METAL_HEIGHT = 0.04  # inductive display units over its background beside a crossing: metal there (pass_peaks'
# own inductive threshold), so the raised capacitive level is metal's echo, not wood or water
CAP_METAL_REACH_M = 0.015  # ... looked for within the crossing's half width, or this far if that is less
CAVITY_MIN_LENGTH_M = 0.03  # a lowered stretch shorter than this is no cavity (the dense map's narrowest region)
CAVITY_EDGE_SHARE = 0.5  # a stretch lowered by less than this share of the deepest within CAVITY_NEIGHBOUR_M ...
CAVITY_NEIGHBOUR_M = 0.3  # ... ran beside that cavity, outside its edge (a footprint at the edge sees half)


def capacitive_from_passes(samples: dict[str, NDArray], xy: NDArray[np.float64], lateral_m: float,
                           params: FusionParams) -> tuple[list[MapObject], list[MapObject]]:
    """(non-metal lines, cavities) from the capacitive readings of a sparse scan's crossing passes.

    Non-metal: capacitive peaks of the crossing passes where the inductive channel, on the same pass, shows no
    metal (the capacitive level rises over metal too: there it is metal's echo, which the inductive lines
    name), linked into straight runs as the inductive peaks are (ransac_lines, the same refusals: a run crossed
    in fewer than MIN_CROSSING_PLACES places, a point seen by its flanks, a run that passes along it refute),
    joined at bends. Each is a line of class "non_metal" (a wooden stud or a water-filled pipe: the channel
    cannot tell which; the caller tells a stud by its fasteners). Cavities: every stretch of a crossing pass
    where the capacitive level falls below the wall's by CAP_MIN_SIGMAS σ and more, between its half-depth
    points, is a measured stretch of a cavity: an outline along it, lateral_m (the channel's coverage radius)
    to each side. Nothing is drawn where no pass measured; stretches of one row that overlap (a cavity cut by
    two frames' passes) are one outline."""
    if CAPACITIVE.name not in samples or INDUCTIVE.name not in samples:
        return [], []
    cap = np.asarray(samples[CAPACITIVE.name], dtype=np.float64)
    crossing = (np.asarray(samples["axis"]) <= 1) & np.isfinite(cap) & np.all(np.isfinite(xy), axis=1)
    if crossing.sum() < 10:
        return [], []
    level, sigma = background_level(cap[crossing], two_sided=True)
    threshold = CAP_MIN_SIGMAS * sigma
    peaks = pass_peaks(samples, xy, CAPACITIVE.name, 0.0, min_height=threshold, base=level)
    keep = ~_metal_beside(peaks, samples, xy)
    peaks = PassPeaks(peaks.xy[keep], peaks.height[keep], peaks.width[keep], peaks.axis[keep],
                      peaks.pass_id[keep], peaks.baseline)
    along = (xy, cap, samples["axis"])
    runs = [r for r in ransac_lines(peaks)
            if not _crossed_in_few_places(r[0], peaks.xy[r[1]])
            and not _a_point_seen_by_its_flanks(r[0], peaks.height[r[1]] + level, level, CAPACITIVE.name)
            and not _refuted_along(r[0], float(np.min(peaks.height[r[1]])), level, *along)]
    lines = []
    if runs:
        widths, heights = [], []
        for poly, ii in runs:
            u = (poly[1] - poly[0]) / max(float(np.linalg.norm(poly[1] - poly[0])), 1e-12)
            sin = np.where(peaks.axis[ii] == 0, np.abs(u[1]), np.abs(u[0]))  # oblique crossings look wider
            widths.append(float(np.median(peaks.width[ii] * sin)))
            heights.append(float(np.median(peaks.height[ii])))
        joined, widths, heights = join_polylines([r[0] for r in runs], widths, heights)
        s = params.softness
        for poly, width, height in zip(joined, widths, heights, strict=True):
            z = height / sigma
            obj = MapObject("line", poly, width, z)
            raised = float(expit((z - params.capacitive_min_z) / (s * params.capacitive_min_z)))
            obj.cls, obj.confidence = ("non_metal", raised) if raised >= 0.5 else ("unknown", raised)
            obj.features = {"length_m": obj.length_m(), "width_m": width, "capacitive_z": z,
                            "capacitive_peak": height, "p_non_metal": raised, "p_nothing": 1.0 - raised}
            if obj.cls == "non_metal":
                lines.append(obj)
    return lines, _cavities(samples, xy, cap, level, threshold, sigma, lateral_m, params)


def _samples_by_pass(pass_ids: NDArray) -> dict[int, NDArray[np.int64]]:
    """{pass id: its samples' indices in log order}, from one sort rather than a scan of every sample per pass."""
    order = np.argsort(pass_ids, kind="stable")
    ids, starts = np.unique(pass_ids[order], return_index=True)
    return {int(i): idx for i, idx in zip(ids, np.split(order, starts[1:]), strict=True)}


def _metal_beside(peaks: PassPeaks, samples: dict[str, NDArray], xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(n,) whether the inductive channel shows metal beside each capacitive peak on its own pass: a reading
    CAP_METAL_HEIGHT over the inductive background within the peak's half width (CAP_METAL_REACH_M at least)."""
    ind = np.asarray(samples[INDUCTIVE.name], dtype=np.float64)
    finite = ind[np.isfinite(ind)]
    base = float(np.percentile(finite, 20)) if finite.size else 0.0
    by_pass = _samples_by_pass(np.asarray(samples["pass_id"]))
    out = np.zeros(len(peaks.xy), bool)
    for k, (point, width, pid) in enumerate(zip(peaks.xy, peaks.width, peaks.pass_id, strict=True)):
        on_pass = by_pass[int(pid)]
        near = on_pass[np.linalg.norm(xy[on_pass] - point, axis=1) <= max(0.5 * width, CAP_METAL_REACH_M)]
        values = ind[near]
        values = values[np.isfinite(values)]
        out[k] = values.size == 0 or float(values.max()) - base >= CAP_METAL_HEIGHT
    return out


def _cavities(samples: dict[str, NDArray], xy: NDArray[np.float64], cap: NDArray[np.float64], level: float,
              threshold: float, sigma: float, lateral_m: float, params: FusionParams) -> list[MapObject]:
    """Cavity outlines from the lowered stretches of the crossing passes (see capacitive_from_passes)."""
    axes = np.asarray(samples["axis"])
    pieces: list[tuple[int, float, float, float, float]] = []  # (axis, across, start, end, depth)
    for idx in _samples_by_pass(np.asarray(samples["pass_id"])).values():
        if axes[idx[0]] > 1:  # crossing passes only
            continue
        ok = np.isfinite(cap[idx]) & np.all(np.isfinite(xy[idx]), axis=1)
        idx = idx[ok]
        if idx.size < 10:
            continue
        axis = int(axes[idx[0]])
        t = xy[idx, axis]
        srt = np.argsort(t)
        t, v = t[srt], level - cap[idx][srt]  # how far the level falls
        across = float(np.median(xy[idx, 1 - axis]))
        # stretches entered at threshold and left at half of it: noise at a flank starts no stretch of its own
        low = v >= 0.5 * threshold
        starts = np.flatnonzero(low & ~np.r_[False, low[:-1]])
        ends = np.flatnonzero(low & ~np.r_[low[1:], False])
        for a, b in zip(starts, ends, strict=True):
            if float(v[a:b + 1].max()) < threshold:
                continue
            depth = float(np.percentile(v[a:b + 1], 90))
            half = 0.5 * depth
            # from its deepest sample out to the half-depth points, or the pass's end where the cavity runs on
            lo = hi = a + int(np.argmax(v[a:b + 1]))
            while lo > 0 and v[lo - 1] >= half:
                lo -= 1
            while hi < len(v) - 1 and v[hi + 1] >= half:
                hi += 1
            start = float(np.interp(half, [v[lo - 1], v[lo]], [t[lo - 1], t[lo]])) if lo > 0 else float(t[0])
            end = float(np.interp(half, [v[hi + 1], v[hi]], [t[hi + 1], t[hi]])) if hi < len(v) - 1 else \
                float(t[-1])
            if end - start >= CAVITY_MIN_LENGTH_M:
                pieces.append((axis, across, start, end, depth))
    # stretches of one row (two frames' passes, a few mm apart across) that overlap are one stretch
    pieces.sort()
    merged: list[list[float]] = []
    for axis, across, start, end, depth in pieces:
        last = merged[-1] if merged else None
        if last is not None and last[0] == axis and abs(across - last[1]) <= SEAM_ACROSS_M and start <= last[3]:
            last[3] = max(last[3], end)
            last[4] = max(last[4], depth)
        else:
            merged.append([axis, across, start, end, depth])
    # a pass over a cavity sees at least half its depth (half at its edge); one that sees less beside a deeper
    # stretch runs beside the cavity, outside its edge: its lowered level stays an unexplained response
    segments = [np.array([(a, c) if ax == 0 else (c, a) for a in (lo, hi)]) for ax, c, lo, hi, _ in merged]
    out = []
    s = params.softness
    for (row_axis, across, start, end, depth), seg in zip(merged, segments, strict=True):
        near = [m[4] for m, other in zip(merged, segments, strict=True)
                if float(distances_to_polyline(np.linspace(seg[0], seg[1], 11), other).min()) <= CAVITY_NEIGHBOUR_M]
        if depth < CAVITY_EDGE_SHARE * max(near):
            continue
        corners = [(start, across - lateral_m), (end, across - lateral_m), (end, across + lateral_m),
                   (start, across + lateral_m), (start, across - lateral_m)]
        ring = np.array([(a, b) if row_axis == 0 else (b, a) for a, b in corners])
        z = depth / sigma
        lowered = float(expit((z - params.capacitive_min_z) / (s * params.capacitive_min_z)))
        obj = MapObject("outline", ring, 2.0 * lateral_m, z, "cavity", lowered)
        obj.features = {"polarity": -1.0, "capacitive_z": -z, "p_cavity": lowered, "p_nothing": 1.0 - lowered,
                        "area_m2": (end - start) * 2.0 * lateral_m}
        out.append(obj)
    return out
