"""Objects from signal maps: pipes and cables as polylines, fasteners as points, studs and cavities as outlines.

Lines are found with Steger's sub-pixel ridge detector (Hessian of the Gaussian-smoothed signal: a ridge point
lies where the first derivative across the ridge vanishes, to a fraction of a cell), linked into chains of
points whose directions agree, ordered along each chain, simplified into polylines (Douglas–Peucker), refined
by least squares per straight piece (vertices at the intersections of neighbouring pieces), and finally joined
across small gaps (a crossing pipe interrupts a ridge) and at bends.

Everything is in wall coordinates, metres: `Polyline.points_m` (k, 2).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from geometry.polyline import distances_to_polyline, polyline_length
from geometry.robust import fit_line
from mapping import tolerances as tol
from mapping.background import normalise
from mapping.grid import GridInfo
from mapping.map_object import MapObject

BRANCH_OFFSET_M = 0.008  # ridge points farther than this from a chain's main path form a branch of their own


@dataclass(frozen=True)
class RidgePoints:
    """Sub-pixel ridge points: xy (n, 2) wall metres, direction (n, 2) unit along the ridge, strength (n,)
    (smoothed height over background, robust σ), width (n,) metres (half-maximum width of the cross profile)."""

    xy: NDArray[np.float64]
    direction: NDArray[np.float64]
    strength: NDArray[np.float64]
    width: NDArray[np.float64]
    pixel: NDArray[np.int64]  # (n, 2) (row, col) of the cell each point came from


def smooth_derivatives(z: NDArray[np.float64], known: NDArray[np.bool_], sigma_px: float
                       ) -> tuple[NDArray[np.float64], ...]:
    """Normalised-convolution Gaussian derivatives: unknown cells do not drag edges down."""
    w = ndimage.gaussian_filter(known.astype(np.float64), sigma_px)
    wsafe = np.maximum(w, 1e-6)
    s = ndimage.gaussian_filter(z, sigma_px) / wsafe
    s[w < 1e-3] = 0.0
    # Derivatives by Gaussian derivative filters (unbiased at sub-cell level, unlike finite differences);
    # the extra 1-cell blur is symmetric and does not move a ridge.
    d = 1.0
    gx = ndimage.gaussian_filter(s, d, order=(0, 1))
    gy = ndimage.gaussian_filter(s, d, order=(1, 0))
    gxx = ndimage.gaussian_filter(s, d, order=(0, 2))
    gyy = ndimage.gaussian_filter(s, d, order=(2, 0))
    gxy = ndimage.gaussian_filter(s, d, order=(1, 1))
    return ndimage.gaussian_filter(s, d), gx, gy, gxx, gxy, gyy, w


LINE_SIGMA_M = 0.006  # smoothing of the line detector (ridge_points)


def ridge_width(height: NDArray[np.float64], curvature: NDArray[np.float64], sigma_px: float,
                info: GridInfo) -> NDArray[np.float64]:
    """Half-maximum width (m) of a Gaussian ridge from its smoothed height and curvature across it (σ_total² =
    h/|λ|, in cells²), without the smoothing (sigma_px, and the derivative filters' 1 cell) and the map's own
    footprint (Gaussian splat + bilinear split)."""
    sigma_total2 = np.maximum(height / np.maximum(-curvature, 1e-9), 0.0)
    grid_px2 = (tol.SIGNAL_SPLAT_SIGMA_M / info.resolution) ** 2 + 1.0 / 6.0
    return 2.3548 * np.sqrt(np.maximum(sigma_total2 - sigma_px**2 - 1.0 - grid_px2, 0.0)) * info.resolution


def ridge_points(signal: NDArray[np.float64], info: GridInfo, sigma_m: float = LINE_SIGMA_M,
                 min_strength: float = 6.0, polarity: float = 1.0, two_sided: bool = False) -> RidgePoints:
    """Steger ridge points of a signal map (height, width), NaN unknown; polarity −1 finds valleys.

    min_strength: smoothed height over the background in robust standard deviations (two_sided: objects
    raise and lower the map, see background_level).
    """
    z, _, _ = normalise(signal, two_sided)
    z = polarity * z
    known = np.isfinite(signal)
    sigma_px = sigma_m / info.resolution
    s, gx, gy, hxx, hxy, hyy, w = smooth_derivatives(z, known, sigma_px)
    # Most negative eigenvalue of the Hessian and its eigenvector (the direction across the ridge)
    tr_half = 0.5 * (hxx + hyy)
    disc = np.sqrt(np.maximum(0.25 * (hxx - hyy) ** 2 + hxy**2, 0.0))
    lam = tr_half - disc
    # Eigenvector of lam: two algebraically equal forms; take the better conditioned one per cell
    ax, ay = hxy, lam - hxx
    bx, by = lam - hyy, hxy
    use_b = np.hypot(bx, by) > np.hypot(ax, ay)
    nx = np.where(use_b, bx, ax)
    ny = np.where(use_b, by, ay)
    lam_other = tr_half + disc
    nn = np.hypot(nx, ny)
    nn[nn == 0] = 1.0
    nx, ny = nx / nn, ny / nn
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(gx * nx + gy * ny) / lam
    ox, oy = t * nx, t * ny
    # A ridge curves strongly across and little along (line ends and blobs curve both ways)
    # |offset| ≤ 0.6 rather than 0.5 cell: a ridge midway between two cells is taken by both (the Newton
    # step is a few % off there) rather than by neither
    cand = ((lam < 0) & (np.abs(lam_other) < 0.5 * np.abs(lam)) & (np.abs(ox) <= 0.6) & (np.abs(oy) <= 0.6)
            & (s >= min_strength) & (w > 0.5) & np.isfinite(t))
    rows, cols = np.nonzero(cand)
    col_sub = cols + ox[rows, cols]
    row_sub = rows + oy[rows, cols]
    xy = info.to_wall(np.column_stack([col_sub, row_sub]))
    direction = np.column_stack([-ny[rows, cols], nx[rows, cols]])
    height = s[rows, cols]
    width = ridge_width(height, lam[rows, cols], sigma_px, info)
    return RidgePoints(xy, direction, height, width, np.column_stack([rows, cols]))


def _chains(r: RidgePoints, max_turn_deg: float = 25.0,
            subset: NDArray[np.int64] | None = None) -> list[NDArray[np.int64]]:
    """Groups of ridge-point indices linked through 8-neighbouring cells with agreeing directions
    (among `subset` of the points only, if given)."""
    if subset is not None:
        sub = RidgePoints(r.xy[subset], r.direction[subset], r.strength[subset], r.width[subset],
                          r.pixel[subset])
        return [subset[g] for g in _chains(sub, max_turn_deg)]
    n = r.xy.shape[0]
    if n == 0:
        return []
    rows, cols = r.pixel[:, 0], r.pixel[:, 1]
    h, w = int(rows.max()) + 3, int(cols.max()) + 3
    index = np.full((h, w + 2), -1, np.int64)  # one spare column on the left for negative offsets
    index[rows, cols + 2] = np.arange(n)
    cos_min = np.cos(np.radians(max_turn_deg))
    src, dst = [], []
    for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1), (0, 2), (2, 0), (2, 1), (1, 2), (2, -1), (1, -2)):
        m = index[rows + dr, cols + dc + 2]
        k = np.flatnonzero(m >= 0)
        m = m[k]
        agree = np.abs(np.einsum("ij,ij->i", r.direction[k], r.direction[m])) >= cos_min
        src.append(k[agree])
        dst.append(m[agree])
    src, dst = np.concatenate(src), np.concatenate(dst)
    g = coo_matrix((np.ones(len(src)), (src, dst)), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    order = np.argsort(labels, kind="stable")
    splits = np.flatnonzero(np.diff(labels[order])) + 1
    return [grp for grp in np.split(order, splits)]


def _order_along(points: NDArray[np.float64]) -> NDArray[np.int64]:
    """Indices ordering points (m, 2) along their chain: the longest path of their minimum spanning tree."""
    return _main_path(points)[0]


def _main_path(points: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """(order of all points along the chain's main path, mask of points off that path — a branch)."""
    m = points.shape[0]
    if m < 3:
        return np.arange(m), np.zeros(m, bool)
    # Spanning tree over a neighbourhood graph (k-d tree pairs within a few cells; sparse, O(m log m))
    pairs = cKDTree(points).query_pairs(r=0.02, output_type="ndarray")
    if pairs.shape[0] == 0:
        return np.argsort(points[:, 0] + points[:, 1]), np.zeros(m, bool)
    d = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1) + 1e-9
    tree = minimum_spanning_tree(coo_matrix((d, (pairs[:, 0], pairs[:, 1])), shape=(m, m)))
    sym = tree + tree.T
    far = breadth_first_order(sym, 0, directed=False, return_predecessors=False)
    end_a = int(far[-1])
    order_b, pred = breadth_first_order(sym, end_a, directed=False, return_predecessors=True)
    # Path from end_a to the farthest point along the tree (by hop count, adequate for chains)
    end_b = int(order_b[-1])
    path = [end_b]
    while path[-1] != end_a:
        path.append(int(pred[path[-1]]))
    path = np.array(path[::-1])
    # Points off the main path (branch stubs, other components) are attached by projection onto it
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points[path], axis=0), axis=1))])
    off, nearest = cKDTree(points[path]).query(points)
    return np.argsort(along[nearest], kind="stable"), off > BRANCH_OFFSET_M


def _douglas_peucker(p: NDArray[np.float64], eps: float) -> list[int]:
    """Indices of the vertices kept by Douglas–Peucker simplification of the ordered points p (m, 2)."""
    keep = [0, p.shape[0] - 1]
    stack = [(0, p.shape[0] - 1)]
    while stack:
        a, b = stack.pop()
        if b <= a + 1:
            continue
        seg = p[b] - p[a]
        length = np.linalg.norm(seg)
        if length < 1e-12:
            dist = np.linalg.norm(p[a + 1:b] - p[a], axis=1)
        else:
            u = seg / length
            rel = p[a + 1:b] - p[a]
            dist = np.abs(u[0] * rel[:, 1] - u[1] * rel[:, 0])
        k = int(np.argmax(dist))
        if dist[k] > eps:
            mid = a + 1 + k
            keep.append(mid)
            stack.extend([(a, mid), (mid, b)])
    return sorted(set(keep))


def _intersect(c1: NDArray[np.float64], d1: NDArray[np.float64], c2: NDArray[np.float64],
               d2: NDArray[np.float64]) -> NDArray[np.float64] | None:
    A = np.column_stack([d1, -d2])
    if abs(np.linalg.det(A)) < 1e-6:
        return None
    s, _ = np.linalg.solve(A, c2 - c1)
    return c1 + s * d1


def _drop_corner_cuts(lines: list) -> list:
    """Remove short runs between two longer ones that meet near them: the blur rounds a bend into a short
    diagonal, and the bend's vertex is where its neighbours intersect."""
    changed = True
    while changed and len(lines) >= 3:
        changed = False
        for k in range(1, len(lines) - 1):
            (_c, _d), run = lines[k]
            length = float(np.linalg.norm(run[-1] - run[0]))
            if length >= 2.0 * tol.MIN_RUN_M:
                continue
            (c1, d1), _ = lines[k - 1]
            (c2, d2), _ = lines[k + 1]
            x = _intersect(c1, d1, c2, d2)
            if x is not None and np.linalg.norm(x - run.mean(axis=0)) < length:
                del lines[k]
                changed = True
                break
    return lines


def _polyline_from_chain(xy: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """Ordered chain points → one or more refined polylines (split where the chain has a gap)."""
    out = []
    gaps = np.flatnonzero(np.linalg.norm(np.diff(xy, axis=0), axis=1) > tol.LINE_GAP_M) + 1
    for piece in np.split(xy, gaps):
        if piece.shape[0] < tol.RIDGE_MIN_POINTS:
            continue
        keep = _douglas_peucker(piece, 2.5 * tol.LINE_INLIER_M)
        # Least-squares line per straight run; drop the ends of runs (bend regions are biased)
        lines = []
        for a, b in itertools.pairwise(keep):
            run = piece[a:b + 1]
            # Short runs are the hooks a ridge detector draws where a line ends or crosses another
            if run.shape[0] >= 4 and np.linalg.norm(run[-1] - run[0]) >= tol.MIN_RUN_M:
                lines.append((fit_line(run), run))
        if not lines:
            continue
        lines = _drop_corner_cuts(lines)
        verts = []
        (c0, d0), run0 = lines[0]
        verts.append(c0 + d0 * ((run0[0] - c0) @ d0))
        for ((c1, d1), _), ((c2, d2), _) in itertools.pairwise(lines):
            x = _intersect(c1, d1, c2, d2)
            if x is not None:
                verts.append(x)
        (cl, dl), runl = lines[-1]
        verts.append(cl + dl * ((runl[-1] - cl) @ dl))
        poly = np.array(verts)
        if np.linalg.norm(np.diff(poly, axis=0), axis=1).sum() >= tol.LINE_MIN_LENGTH_M:
            out.append(poly)
    return out


def join_polylines(polys: list[NDArray[np.float64]], widths: list[float],
                   strengths: list[float]) -> tuple[list[NDArray[np.float64]], list[float], list[float]]:
    """Join polylines whose ends meet: first collinear ends (a ridge interrupted where another crosses it),
    then angled ends into bends, except at a crossing (where another polyline passes the joint)."""
    polys = [p.copy() for p in polys]
    for allow_bend in (False, True):
        changed = True
        while changed:
            changed = False
            for a in range(len(polys)):
                for b in range(a + 1, len(polys)):
                    others = [p for k, p in enumerate(polys) if k not in (a, b)]
                    joined = _try_join(polys[a], polys[b], allow_bend, others)
                    if joined is None:
                        continue
                    la, lb = polyline_length(polys[a]), polyline_length(polys[b])
                    polys[a] = joined
                    widths[a] = (widths[a] * la + widths[b] * lb) / max(la + lb, 1e-12)
                    strengths[a] = (strengths[a] * la + strengths[b] * lb) / max(la + lb, 1e-12)
                    del polys[b], widths[b], strengths[b]
                    changed = True
                    break
                if changed:
                    break
    return polys, widths, strengths


def _distance_to_polyline(x: NDArray[np.float64], poly: NDArray[np.float64]) -> float:
    """Distance (metres) of one point (2,) to a polyline (k, 2)."""
    return float(distances_to_polyline(np.asarray(x, dtype=np.float64).reshape(1, 2), poly)[0])


def _try_join(p: NDArray[np.float64], q: NDArray[np.float64], allow_bend: bool,
              others: list[NDArray[np.float64]]) -> NDArray[np.float64] | None:
    best = None
    for pe in (0, -1):
        for qe in (0, -1):
            gap = float(np.linalg.norm(p[pe] - q[qe]))
            if best is None or gap < best[0]:
                best = (gap, pe, qe)
    gap, pe, qe = best  # type: ignore[misc]
    if gap > tol.JOIN_ENDPOINT_M:
        # A longer gap is bridged only where other lines cross it (their ridges interrupt this one) and
        # both pieces lie on one straight line
        if allow_bend or gap > tol.BRIDGE_GAP_M or not others:
            return None
        a, b = p[pe], q[qe]
        da = p[pe] - p[1 if pe == 0 else -2]
        db = q[1 if qe == 0 else -2] - q[qe]
        u = (b - a) / gap
        if min(float(da @ u) / np.linalg.norm(da), float(db @ u) / np.linalg.norm(db)) < np.cos(
                np.radians(tol.BRIDGE_MAX_ANGLE_DEG)):
            return None
        probe = a + np.linspace(0.1, 0.9, 9)[:, None] * (b - a)
        if not any(distances_to_polyline(probe, o).min() < tol.BRIDGE_CROSSING_M for o in others):
            return None
        pp = p if pe == -1 else p[::-1]
        qq = q if qe == 0 else q[::-1]
        return np.vstack([pp, qq])
    pp = p if pe == -1 else p[::-1]  # pp ends at the joint
    qq = q if qe == 0 else q[::-1]  # qq starts at the joint
    dp = pp[-1] - pp[-2]
    dq = qq[1] - qq[0]
    dp /= np.linalg.norm(dp)
    dq /= np.linalg.norm(dq)
    angle = np.degrees(np.arccos(np.clip(dp @ dq, -1.0, 1.0)))
    if angle < tol.JOIN_MIN_ANGLE_DEG:
        # Collinear: both must also lie on one line (not two parallel pipes side by side)
        rel = qq[0] - pp[-1]
        off = abs(float(dp[0] * rel[1] - dp[1] * rel[0]))
        if off > 2.0 * tol.LINE_INLIER_M:
            return None
        return np.vstack([pp[:-1], 0.5 * (pp[-1] + qq[0]), qq[1:]]) if len(pp) > 1 and len(qq) > 1 else None
    if not allow_bend:
        return None
    x = _intersect(pp[-2], dp, qq[0], dq)
    if x is not None and any(_distance_to_polyline(x, o) < tol.JOIN_ENDPOINT_M for o in others):
        return None  # a crossing, not a bend
    if x is None or np.linalg.norm(x - pp[-1]) > tol.JOIN_ENDPOINT_M or np.linalg.norm(x - qq[0]) > \
            tol.JOIN_ENDPOINT_M:
        return None
    return np.vstack([pp[:-1], x, qq[1:]])


def extract_lines(signal: NDArray[np.float64], info: GridInfo, sigma_m: float = LINE_SIGMA_M,
                  min_strength: float = 6.0, two_sided: bool = False) -> list[MapObject]:
    """Pipes/cables (any straight, bent or diagonal run) in one signal map as 'line' MapObjects (two_sided:
    objects raise and lower the map, see background_level)."""
    r = ridge_points(signal, info, sigma_m, min_strength, two_sided=two_sided)
    polys, widths, strengths = [], [], []
    todo = [g for g in _chains(r) if g.size >= tol.RIDGE_MIN_POINTS]
    rounds = 0
    while todo and rounds < 200:
        rounds += 1
        grp = todo.pop()
        order, branch = _main_path(r.xy[grp])
        # A chain with a branch (a line ending on another: a T) is its main path, and the branch again
        if branch.any():
            rest = grp[branch]
            if rest.size >= tol.RIDGE_MIN_POINTS:
                todo += [g for g in _chains(r, subset=rest) if g.size >= tol.RIDGE_MIN_POINTS]
            keep = ~branch
            grp, order = grp[keep], np.argsort(np.argsort(order)[keep], kind="stable")
        idx = grp[order]
        for poly in _polyline_from_chain(r.xy[idx]):
            polys.append(poly)
            widths.append(float(np.median(r.width[idx])))
            strengths.append(float(np.median(r.strength[idx])))
    polys, widths, strengths = join_polylines(polys, widths, strengths)
    polys = [p[_douglas_peucker(p, tol.LINE_INLIER_M)] for p in polys]  # drop vertices left by merges
    return [MapObject("line", p, w, s) for p, w, s in zip(polys, widths, strengths, strict=True)]


POINT_RAY_DIRECTIONS = 16  # directions in which a point's surroundings are probed
POINT_RAY_M = (0.012, 0.030)  # ... from this far out: beyond a fastener's footprint half-width, within a line's run
POINT_MIN_REL = 0.3  # a point stands at least this share above what it sits on (a line, a stud): pass-to-pass gain
# jitter (2 % σ) ripples a strong line by under a tenth of its level, a fastener on it adds over half
BOX_RAY_M = (0.035, 0.08)  # a socket box's rays: beyond a 6-7 cm box's edge, to where its response is gone
BOX_MIN_PLATEAU = 0.45  # a peak still holding this share of its height 1.2-3 cm out is a box's plateau: a 6-7 cm
# box's edge lies 3-3.5 cm out, a screw's or nail's footprint (σ 11-16 mm) has lost most of it there (24 hard-case
# and 6 random walls: fasteners 0.07-0.38 on dense scans, up to 0.50 on adaptive ones, where a pass 1 cm beside a
# loose screw spreads it along that pass; socket and junction boxes 0.49-0.78)
BOX_MIN_HALF_WIDTH_M = 0.03  # ... and it falls half-way to the empty wall beside it no nearer than this (median
# over its rays): a box at its edge, 3-3.5 cm out, a fastener within 2-2.6 cm (boxes 0.034-0.043 m; fasteners
# 0.017-0.026 m on dense scans, and the adaptive ones with a plateau over 0.4 at most 0.020 m)


def extract_points(signal: NDArray[np.float64], info: GridInfo, sigma_m: float = 0.004,
                   min_strength: float = 6.0, min_rel: float = POINT_MIN_REL,
                   saturated: float | None = None, boxes: bool = False) -> list[MapObject]:
    """Small peaks (screws, nails) as 'point' MapObjects with sub-cell positions, alone or on top of a line or
    an area (a screw on a pipe, a steel stud's screws): signal in units where objects add up.

    Each local maximum of the smoothed map is compared with what it sits on: along POINT_RAY_DIRECTIONS rays
    from POINT_RAY_M[0] to POINT_RAY_M[1], the lowest value on each ray, and the highest of those over the
    rays (a line through the peak keeps its level along its own direction; a point alone falls off on every
    ray; a short stretch of line or a wide area does not fall off within the rays at all). The peak is a point
    when it rises min_strength robust σ and min_rel of that level above it. features: "base" (what it sits on,
    σ units), "half_width_m" (median over the rays of the distance where it has fallen half-way to the base).
    saturated: the signal value of a saturated reading; a peak on a saturated top (a shallow screw on a steel
    stud saturates over 3 cm) is that top's middle, not whichever of its equal cells the maximum filter keeps,
    and its rays start at the top's edge (its equivalent radius): rays from an off-centre cell, or too short,
    would end on the top or its tail and read it as what the point sits on.

    boxes: also find socket and junction boxes (metal larger than a screw, never a fastener). A 6-7 cm box's
    rays up to 3 cm end on the box itself, which then seems to sit on its own plateau; so the rays run on to
    BOX_RAY_M[1] and each peak is judged again against what it sits on beyond a box's edge ("box_base", σ units:
    over the rays, the highest of each ray's lowest value within BOX_RAY_M — a line that runs into the box, or
    the empty wall). A peak is a box where it rises min_strength and min_rel above that, still holds
    BOX_MIN_PLATEAU of that rise at its near rays' ends ("plateau": (base − box_base) / (height − box_base)) and
    falls half-way to the lowest of those rays' values (the wall beside it) no nearer than BOX_MIN_HALF_WIDTH_M
    ("box_half_width_m", median over the rays measured to BOX_RAY_M[1]). A box has feature "box", twice that
    half width as its width and its rise over box_base as its strength; it is kept whether or not it passes the
    point test. Where two lines cross or a line bends, the same plateau shows: metal there too.
    """
    z, _, _ = normalise(signal)
    known = np.isfinite(signal)
    sigma_px = sigma_m / info.resolution
    s, gx, gy, hxx, hxy, hyy, w = smooth_derivatives(z, known, sigma_px)
    peak = (s == ndimage.maximum_filter(s, size=5)) & (s >= min_strength) & (w > 0.5)
    rows, cols = np.nonzero(peak)
    if rows.size == 0:
        return []
    origin = np.column_stack([rows, cols]).astype(np.float64)  # where the rays start, (row, col)
    on_top = np.zeros(rows.size, bool)
    radius = np.zeros(rows.size)  # cells: the rays start this far out, at a saturated top's edge
    if saturated is not None:
        top = np.nan_to_num(signal, nan=-np.inf) >= saturated - 1e-9
        labels, n = ndimage.label(top)
        label = labels[rows, cols]
        if n:
            middles = np.array(ndimage.center_of_mass(top, labels, np.arange(1, n + 1))).reshape(-1, 2)
            first = np.zeros(rows.size, bool)
            first[np.unique(label, return_index=True)[1]] = True
            keep = (label == 0) | first  # one peak per saturated top
            on_top = label > 0
            origin[on_top] = middles[label[on_top] - 1]
            areas = ndimage.sum_labels(top, labels, np.arange(1, n + 1))
            radius[on_top] = np.sqrt(areas[label[on_top] - 1] / np.pi)
            rows, cols, origin, on_top, radius = rows[keep], cols[keep], origin[keep], on_top[keep], radius[keep]
    angles = np.arange(POINT_RAY_DIRECTIONS) * 2.0 * np.pi / POINT_RAY_DIRECTIONS
    step = min(info.resolution, 0.002)
    n_near = len(np.arange(0.0, POINT_RAY_M[1] + 1e-9, step))  # the point's own rays; a box's run on
    steps = np.arange(0.0, (BOX_RAY_M[1] if boxes else POINT_RAY_M[1]) + 1e-9, step) / info.resolution
    far = (steps >= POINT_RAY_M[0] / info.resolution) & (np.arange(len(steps)) < n_near)
    # (peaks, directions, steps) profiles of the smoothed map along the rays
    reach = steps[None, None, :] + radius[:, None, None]
    rr = origin[:, 0, None, None] + np.sin(angles)[None, :, None] * reach
    cc = origin[:, 1, None, None] + np.cos(angles)[None, :, None] * reach
    profile = ndimage.map_coordinates(s, [rr.ravel(), cc.ravel()], order=1, mode="nearest").reshape(rr.shape)
    # On a sparse map only rays along measured passes tell what the point sits on: a ray counts where its far
    # end was measured, over its measured steps (between passes the smoothing spreads the peak's own values)
    seen = ndimage.map_coordinates(w, [rr.ravel(), cc.ravel()], order=1, mode="nearest").reshape(rr.shape) > 0.5
    height = s[rows, cols]
    base = _ray_base(_ray_lows(profile, seen, far, n_near - 1))
    bump = height - base
    is_point = (bump >= min_strength) & (bump >= min_rel * np.maximum(base, 0.0))
    box_base = np.full(rows.size, np.inf)
    box_half = np.full(rows.size, np.nan)
    plateau = np.full(rows.size, np.nan)
    is_box = np.zeros(rows.size, bool)
    if boxes:
        lows = _ray_lows(profile, seen, steps >= BOX_RAY_M[0] / info.resolution, len(steps) - 1)
        box_base = _ray_base(lows)
        floor = np.where(np.isfinite(lows), lows, np.inf).min(axis=1)  # the empty wall beside it
        box_bump = height - box_base
        judged = np.isfinite(base) & np.isfinite(box_base) & (box_bump > 0)
        with np.errstate(all="ignore"):
            plateau = np.where(judged, (base - box_base) / box_bump, np.nan)
        box_half = _half_widths(profile, seen[:, :, -1], 0.5 * (height + floor), steps, radius) * info.resolution
        is_box = judged & (box_bump >= min_strength) & (box_bump >= min_rel * np.maximum(box_base, 0.0)) & \
            (plateau >= BOX_MIN_PLATEAU) & (box_half >= BOX_MIN_HALF_WIDTH_M)
    out = []
    for k in np.flatnonzero(is_point | is_box):
        rr_k, cc_k = rows[k], cols[k]
        H = np.array([[hxx[rr_k, cc_k], hxy[rr_k, cc_k]], [hxy[rr_k, cc_k], hyy[rr_k, cc_k]]])
        g = np.array([gx[rr_k, cc_k], gy[rr_k, cc_k]])
        try:
            off = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            continue
        if on_top[k]:
            off = origin[k, ::-1] - [cc_k, rr_k]  # the saturated top's middle
        elif not np.all(np.isfinite(off)) or np.any(np.abs(off) > 1.0):
            off = np.zeros(2)  # a flat top: the cell itself
        xy = info.to_wall(np.array([[cc_k + off[0], rr_k + off[1]]]))
        near_profile = profile[k:k + 1, :, :n_near]
        half_width = float(_half_widths(near_profile, np.ones((1, POINT_RAY_DIRECTIONS), bool),
                                        np.array([base[k] + 0.5 * bump[k]]), steps[:n_near], radius[k:k + 1])[0])
        half_width *= info.resolution
        if is_box[k]:  # as wide as its response over the wall beside it, as high as it stands over what lies beyond
            obj = MapObject("point", xy, 2.0 * float(box_half[k]), float(height[k] - box_base[k]))
            obj.features["box"] = 1.0
        else:
            obj = MapObject("point", xy, 2.0 * half_width, float(bump[k]))
        obj.features["base"] = float(base[k])
        obj.features["half_width_m"] = half_width
        if boxes:
            obj.features["box_base"] = float(box_base[k])
            obj.features["box_half_width_m"] = float(box_half[k])
            obj.features["plateau"] = float(plateau[k])
        out.append(obj)
    return out


def _ray_lows(profile: NDArray[np.float64], seen: NDArray[np.bool_], window: NDArray[np.bool_],
              end: int) -> NDArray[np.float64]:
    """Each ray's lowest measured value within `window` (steps), (n, directions); NaN on rays not measured at
    step `end`."""
    low = np.where(seen[:, :, window], profile[:, :, window], np.inf).min(axis=2)
    return np.where(seen[:, :, end], low, np.nan)


def _ray_base(lows: NDArray[np.float64]) -> NDArray[np.float64]:
    """What each peak sits on (n,): the highest of its rays' lows (_ray_lows); +inf where no ray was measured to
    its end (nothing to judge the peak against)."""
    measured = np.isfinite(lows).any(axis=1)
    return np.where(measured, np.max(np.where(np.isfinite(lows), lows, -np.inf), axis=1), np.inf)


def _half_widths(profile: NDArray[np.float64], rays: NDArray[np.bool_], level: NDArray[np.float64],
                 steps: NDArray[np.float64], radius: NDArray[np.float64]) -> NDArray[np.float64]:
    """Median over the chosen rays (n, directions) of the first step where each peak's profile falls to its
    level (n,), plus the rays' start radius, cells; a ray that never does counts its last step; NaN where no
    ray is chosen."""
    below = np.asarray(profile <= level[:, None, None], dtype=np.bool_)
    first = np.where(below.any(axis=2), below.argmax(axis=2), len(steps) - 1)
    dist = np.where(rays, steps[first], np.nan)
    chosen = np.asarray(np.any(rays, axis=1), dtype=np.bool_)
    with np.errstate(all="ignore"):
        out = np.asarray(np.nanmedian(np.where(chosen[:, None], dist, 0.0), axis=1) + radius, dtype=np.float64)
    out[~chosen] = np.nan
    return out


def extract_regions(signal: NDArray[np.float64], info: GridInfo, polarity: float, min_strength: float = 4.0,
                    min_area_m2: float = 0.004, min_width_m: float = 0.03, sigma_m: float = 0.006,
                    exclude: NDArray[np.bool_] | None = None, two_sided: bool = False) -> list[MapObject]:
    """Wide regions (studs, plates: polarity +1; cavities: −1) as 'outline' MapObjects (closed rings).

    Regions narrower than min_width_m are removed by a morphological opening (lines are not areas);
    exclude (height, width) masks cells already explained (e.g. around detected pipes and cables);
    two_sided: objects raise and lower the map (see background_level).
    """
    import cv2

    z, _, _ = normalise(signal, two_sided)
    known = np.isfinite(signal)
    s, *_rest, w = smooth_derivatives(polarity * z, known, sigma_m / info.resolution)
    mask = (s >= min_strength) & (w > 0.5)
    if exclude is not None:
        mask &= ~exclude
    # The outline is the half-maximum contour of each blob (the object's edge under a symmetric footprint)
    labels, n = ndimage.label(mask)
    if n:
        peaks = ndimage.maximum(s, labels, index=np.arange(1, n + 1))
        mask &= s >= 0.5 * np.concatenate([[np.inf], peaks])[labels]
    radius = max(1, round(0.5 * min_width_m / info.resolution))
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    disk = xx**2 + yy**2 <= radius**2
    mask = ndimage.binary_opening(mask, structure=disk)
    labels, n = ndimage.label(mask)
    out = []
    for k in range(1, n + 1):
        region = labels == k
        area = float(region.sum()) * info.resolution**2
        if area < min_area_m2:
            continue
        contours, _ = cv2.findContours(region.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        contour = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float32)
        rect = cv2.minAreaRect(contour)
        box = cv2.boxPoints(rect).astype(np.float64)  # (4, 2) col,row
        ring = info.to_wall(np.vstack([box, box[:1]]))
        width = min(rect[1]) * info.resolution
        obj = MapObject("outline", ring, float(width), float(np.median(s[region])))
        obj.features["area_m2"] = area
        obj.features["polarity"] = float(polarity)
        out.append(obj)
    return out


def near_lines(lines: list[MapObject], info: GridInfo, clearance_m: float) -> NDArray[np.bool_]:
    """(height, width) mask of cells within clearance_m of any line object."""
    import cv2

    canvas = np.zeros(info.shape, np.uint8)
    for ln in lines:
        pix = np.rint(info.to_pixel(ln.points_m) * 4).astype(np.int32)
        thick = max(1, round(2 * clearance_m / info.resolution))
        cv2.polylines(canvas, [pix], False, 1, thick, cv2.LINE_8, shift=2)
    return canvas.astype(bool)


POINT_END_M = 0.04  # a point this close to a line's end is where the line ends (a socket or junction box, 6-7 cm)
POINT_END_LATERAL_M = 0.015  # ... and on the line's course: a screw beside a line's end stays a fastener


def points_on_lines(points: list[MapObject], lines: list[MapObject],
                    clearance_m: float = tol.JOIN_ENDPOINT_M * 0.5) -> tuple[list[MapObject], list[MapObject]]:
    """(fasteners, boxes) of the point peaks given the lines: a box-sized peak (extract_points' feature "box":
    a plateau wider than a screw's footprint) is a box wherever it lies; a peak where two lines meet or cross,
    or at a line's end, is what the lines meet at (a box, a junction, the crossing itself: metal, not a
    fastener); the others — alone or on one line's run — are fasteners."""
    polylines = [ln for ln in lines if ln.points_m.shape[0] >= 2]
    fasteners: list[MapObject] = []
    boxes: list[MapObject] = []
    for p in points:
        if p.features.get("box"):
            boxes.append(p)
            continue
        q = p.points_m[0]
        near = [ln for ln in polylines if _distance_to_polyline(q, ln.points_m) <= max(clearance_m, ln.width_m)]
        at_end = any(_beyond_end(q, ln.points_m) for ln in polylines)
        (boxes if len(near) >= 2 or at_end else fasteners).append(p)
    return fasteners, boxes


def _beyond_end(q: NDArray[np.float64], poly: NDArray[np.float64]) -> bool:
    """q lies within POINT_END_M of one of the polyline's ends, on its course (within POINT_END_LATERAL_M of
    the end segment's line): where a cable runs into its box."""
    for end, inner in ((poly[0], poly[1]), (poly[-1], poly[-2])):
        d = end - inner
        d = d / max(float(np.linalg.norm(d)), 1e-12)
        r = q - end
        if np.linalg.norm(r) <= POINT_END_M and abs(d[0] * r[1] - d[1] * r[0]) <= POINT_END_LATERAL_M:
            return True
    return False
