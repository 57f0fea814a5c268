"""In-wall features shared by overlapping frames, as stitching constraints (beyond the paper).

Each frame's samples are mapped in the frame's own drive coordinates (u, v), where they are consistent to
the drives' precision; screws and nails (points) and pipes/cables crossing into the neighbouring frame (lines)
are extracted there. Where two frames overlap on the wall (by their localization poses), a feature of one
frame is paired with the nearest like feature of the other inside a gate of three localization standard
deviations, and becomes a point constraint (2 rows) or a line constraint (1 row, along the normal) in the
FrameGraph.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from geometry.polyline import distances_to_polyline
from mapping.grid import GridInfo, SensorModel, WallGrid
from mapping.map_object import MapObject
from mapping.objects import extract_lines, extract_points
from mapping.scandata import ScanData
from mapping.stitching import FrameGraph, apply_pose
from scanner.channels import INDUCTIVE
from scanner.sensor_model import additive_units

FEATURE_SIGMA_M = 0.002  # how well one feature is located within one frame


def frame_features(uv: NDArray[np.float64], inductive: NDArray[np.float64],
                   resolution: float = 0.004) -> tuple[list[MapObject], list[MapObject]]:
    """(points, lines) found in one frame's samples, in the frame's drive coordinates (metres)."""
    ok = np.all(np.isfinite(uv), axis=1) & np.isfinite(inductive)
    if ok.sum() < 100:
        return [], []
    uv, a = uv[ok], inductive[ok]
    lo, hi = uv.min(axis=0) - 0.01, uv.max(axis=0) + 0.01
    info = GridInfo.covering(lo[0], lo[1], hi[0], hi[1], resolution)
    grid = WallGrid(info, {INDUCTIVE.name: SensorModel.from_readings(INDUCTIVE.name, a)})
    grid.add_samples(uv, {INDUCTIVE.name: a})
    sig = grid.signal(INDUCTIVE.name)
    lines = extract_lines(sig, info)
    points = [p for p in extract_points(additive_units(INDUCTIVE.name, sig), info, min_strength=8.0)
              if all(distances_to_polyline(p.points_m[0], ln.points_m)[0] > 0.02 for ln in lines)]
    return points, lines


FrameFeatures = tuple[list, list]  # (points, lines) of one frame, frame coordinates


def frames_features(data: ScanData) -> tuple[list[FrameFeatures], list]:
    """Per frame (in data.frames order): its (points, lines) and its drive-coordinate box, or None."""
    s = data.samples
    per_frame: list[FrameFeatures] = []
    boxes: list = []
    if INDUCTIVE.name not in s or "drive_u_m" not in s:
        return [([], []) for _ in data.frames["frame_id"]], [None for _ in data.frames["frame_id"]]
    for fid in data.frames["frame_id"]:
        sel = s["frame_id"] == fid
        uv = np.column_stack([s["drive_u_m"][sel], s["drive_v_m"][sel]])
        if sel.sum() < 100 or not np.isfinite(uv).any():
            per_frame.append(([], []))
            boxes.append(None)
            continue
        per_frame.append(frame_features(uv, s[INDUCTIVE.name][sel]))
        boxes.append((np.nanmin(uv, axis=0), np.nanmax(uv, axis=0)))
    return per_frame, boxes


def feature_constraints(data: ScanData, graph: FrameGraph, est: NDArray[np.float64],
                        features: tuple[list[FrameFeatures], list] | None = None,
                        sigma_override: NDArray[np.float64] | None = None) -> int:
    """Add point/line constraints between neighbouring frames to graph (pairing them by the poses est);
    returns how many were added. features: frames_features(data), to compute them once for several rounds;
    sigma_override (N, 3): pose uncertainty to gate with (after a first alignment, smaller than the log's)."""
    ids = data.frames["frame_id"]
    cov = data.frames["cov"]
    if sigma_override is not None:
        sigma = np.hypot(sigma_override[:, 0], sigma_override[:, 1])
        sigma_phi = sigma_override[:, 2]
    else:
        sigma = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2)[:, :2], 0.0, None)).max(axis=1)
        sigma_phi = np.sqrt(np.clip(cov[:, 2, 2], 0.0, None))
    per_frame, boxes = features if features is not None else frames_features(data)
    added = 0
    for i in range(len(ids)):
        for j in range(i + 1, len(ids)):
            if boxes[i] is None or boxes[j] is None:
                continue
            # position uncertainty at the far corners includes the rotation's lever arm
            reach = float(np.linalg.norm(boxes[i][1] - boxes[i][0]))
            gate = 3.0 * max(float(np.hypot(sigma[i], sigma[j])) + reach * float(np.hypot(sigma_phi[i],
                             sigma_phi[j])), 0.005)
            if not _near(est[i], boxes[i], est[j], boxes[j], gate):
                continue
            added += _pair_points(graph, i, j, est, per_frame[i][0], per_frame[j][0], gate)
            added += _pair_lines(graph, i, j, est, per_frame[i][1], per_frame[j][1], gate)
    return added


Box = tuple[NDArray[np.float64], NDArray[np.float64]]  # (lowest, highest) drive coordinates of a frame's samples


def _corners(pose: NDArray[np.float64], box: Box) -> NDArray[np.float64]:
    (u0, v0), (u1, v1) = box
    return apply_pose(pose, np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]]))


def _near(pi: NDArray[np.float64], bi: Box, pj: NDArray[np.float64], bj: Box, gap: float) -> bool:
    """True if the two frames' wall rectangles overlap or lie within `gap` of each other."""
    ci, cj = _corners(pi, bi), _corners(pj, bj)
    lo = np.maximum(ci.min(axis=0), cj.min(axis=0))
    hi = np.minimum(ci.max(axis=0), cj.max(axis=0))
    return bool(np.all(hi - lo > -gap))


def _pair_points(graph: FrameGraph, i: int, j: int, est: NDArray[np.float64], pts_i: list[MapObject],
                 pts_j: list[MapObject], gate: float) -> int:
    if not pts_i or not pts_j:
        return 0
    wi = np.vstack([apply_pose(est[i], p.points_m) for p in pts_i])
    wj = np.vstack([apply_pose(est[j], p.points_m) for p in pts_j])
    d = np.linalg.norm(wi[:, None] - wj[None], axis=2)
    n = 0
    for a in range(len(pts_i)):
        b = int(np.argmin(d[a]))
        if d[a, b] < gate and int(np.argmin(d[:, b])) == a:  # mutual nearest
            graph.add_points([i], pts_i[a].points_m, [j], pts_j[b].points_m, [FEATURE_SIGMA_M] * 2)
            n += 1
    return n


AMBIGUITY_MARGIN_M = 0.02  # the runner-up pairing must be this much worse than the best
END_INSET_M = 0.03  # a line's last centimetres are its least reliable (the ridge fades); sample inside


def _end_segments(poly: NDArray[np.float64]) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """(point END_INSET_M inside each end, unit direction pointing out of the polyline there)."""
    out = []
    for end, prev in ((poly[0], poly[1]), (poly[-1], poly[-2])):
        d = end - prev
        length = max(float(np.linalg.norm(d)), 1e-12)
        u = d / length
        out.append((end - u * min(END_INSET_M, 0.5 * length), u))
    return out


def _pair_lines(graph: FrameGraph, i: int, j: int, est: NDArray[np.float64], lines_i: list[MapObject],
                lines_j: list[MapObject], gate: float) -> int:
    """A line leaving frame i and one entering frame j that continue each other (same direction, the end of
    one on the other's extension) are one pipe or cable crossing the border: constrain them collinear."""
    n = 0
    used_j: set[int] = set()
    for li in lines_i:
        wi = apply_pose(est[i], li.points_m)
        best = None
        candidates: list[float] = []
        for k, lj in enumerate(lines_j):
            if k in used_j:
                continue
            wj = apply_pose(est[j], lj.points_m)
            for ei, di in _end_segments(wi):
                for ej, dj in _end_segments(wj):
                    if di @ dj > -np.cos(np.radians(5.0)):  # the ends must face each other
                        continue
                    gap = ej - ei
                    span = float(np.linalg.norm(gap))
                    if span > 0.15 + gate:
                        continue
                    lateral = abs(float(di[0] * gap[1] - di[1] * gap[0]))
                    if lateral < gate:
                        candidates.append(lateral)
                        if best is None or lateral < best[0]:
                            best = (lateral, k, ei, di, ej)
        if best is None:
            continue
        # Ambiguous (another line nearly as well aligned, e.g. parallel runs): no constraint rather than a
        # wrong one
        others = sorted(candidates)[1:]
        if others and others[0] < 2.0 * best[0] + AMBIGUITY_MARGIN_M:
            continue
        _, k, ei, di, ej = best
        used_j.add(k)
        c, s_ = np.cos(est[i][2]), np.sin(est[i][2])
        d_local = np.array([c * di[0] + s_ * di[1], -s_ * di[0] + c * di[1]])  # direction in frame i
        normal = np.array([-d_local[1], d_local[0]])
        graph.add_lines([i], _inverse(est[i], ei), normal, [j], _inverse(est[j], ej), FEATURE_SIGMA_M)
        n += 1
    return n


def _inverse(pose: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    tx, ty, th = pose
    c, s = np.cos(th), np.sin(th)
    d = np.asarray(w, dtype=np.float64).reshape(2) - np.array([tx, ty])
    return np.array([[c * d[0] + s * d[1], -s * d[0] + c * d[1]]])
