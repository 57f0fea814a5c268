"""Depth of mapped pipes, cables and fasteners behind the wall surface, with its 1σ, from the width of their peaks.

Why the width: the scanner's footprints widen with depth (scanner.sensor_model): the inductive one is an
anisotropic Gaussian, σ_u across × σ_v along the device at zero depth, each widened as hypot(σ, k·depth)
(k = spread_per_depth); the AC one is isotropic, hypot(σ_ac, k_ac·depth). A line integral of such a footprint
across a straight line of normal n is a Gaussian in the distance s to the line with variance

    σ_⊥² = n_x² σ_u² + n_y² σ_v² + (k·depth)²            (lines)

and a pass through a point object (a screw) along unit direction a sees a Gaussian slice of variance

    σ_a² = 1 / (a_x² / (σ_u² + (k·depth)²) + a_y² / (σ_v² + (k·depth)²))      (points)

so every measured width gives the *excess* x = (k·depth)², linear in the measured variance, and depth =
√max(x, 0) / k. Peak heights would tell too, but they scale with the unknown material and size; widths do not.

Measurements, best first:
  * crossings: one pass crossing a line (|sin| of the angle ≥ MIN_CROSSING_SIN) or passing through a point,
    away from the line's ends and bends. The readings within ±3σ of the expected peak (at least ±1.5σ on
    the pass) are taken in raw units (the display saturation undone: raw = −ln(1 − display) − background),
    weighted by their noise (white noise estimated per pass from sample-to-sample differences, plus the
    device's count quantisation, which grows as 1/(1 − display) near saturation; saturated samples are left
    out), and fitted (robust soft-L1 least squares) with background + slope + Gaussian, the Gaussian's width
    along the pass being σ_⊥ / |sin|.
    Other mapped objects crossing the fitting window are fitted as Gaussians of their own, so a neighbour's
    flank does not widen the peak. The angle comes from the line through the crossings' fitted peak centres
    (sharper than the map's direction, whose error at 45° would widen or narrow every peak alike).
    Positions along a pass come from the drives (rigid within a pass) with the inductive lag undone, so
    frame pose errors do not widen anything.
  * strips: a line that no pass crosses (a horizontal pipe under a horizontal raster) is profiled across the
    passes running along it: per frame (one rigid set of passes), each pass's mean raw reading along the line
    (samples near other objects masked out) against its distance to the line; the same Gaussian is fitted to
    these points, its uncertainty scaled by their scatter (which holds the per-pass gain variation).
  * grid: only when the samples cannot be split into passes, cross profiles of lines in the grid's signal
    layer. The grid is the samples' display readings smoothed by its splat kernel (a Gaussian of σ =
    SIGNAL_SPLAT_SIGMA_M cut at 2σ, plus the bilinear split and read-back), which adds its variance to every
    width in quadrature; since it averages display values, the fit models it as it happens (raw Gaussian →
    display → smoothed by the kernel) rather than subtracting the variance from a saturated peak's width.
Power lines are measured on the AC channel first (a live cable's crest is sharper and far less noisy); every
other object, and any cable the AC channel does not resolve (a dead one), on the inductive one.

Combination: the per-measurement excesses x_i (variance v_i from each fit) are combined by a random-effects
weighted mean (DerSimonian–Laird: the scatter between measurements beyond their own errors becomes an extra
variance τ², so the standard error reflects the spread of the per-crossing estimates) after dropping outliers
(> OUTLIER_MADS robust σ from the median). A model term adds the footprint width model's tolerance
(WIDTH_MODEL_REL of the width, i.e. 2·WIDTH_MODEL_REL of the variance) in quadrature; even in simulation,
where the footprint is exact, it is what covers the biases the spread cannot see (up to ~0.6 mm: an unmapped
neighbour's flank, the map's geometry), the spread alone being 0.01–0.3 mm. depth_sigma_m is half
the depth interval that x̄ ± δx maps to (honest near the surface, where depth = √x / k is steep). Fewer than
MIN_MEASUREMENTS accepted crossings (and no strip), or a σ above MAX_DEPTH_SIGMA_M, leave the depth None:
no channel tells — so do saturated peaks (their cores hold no reading), objects on a frame seam (no single
pass reaches across) and lines crossed only near their ends. Outlines (studs, plates, cavities) are left None: their
edges, not a footprint width, shape their profiles.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from geometry.polyline import distances_to_polyline
from geometry.robust import fit_line
from mapping import tolerances as tol
from mapping.fusion import InductiveModel
from mapping.grid import WallGrid
from mapping.map_object import MapObject
from scanner.channels import AC, INDUCTIVE
from scanner.sensor_model import COUNTS_FULL_SCALE

MIN_CROSSING_SIN = 0.3  # a pass at < 17° to a line sees a peak > 3.3x wider and is used as a strip instead
WINDOW_SIGMAS = 3.0  # fitting window: ±3σ of the expected peak (background on both sides)
MIN_SIDE_SIGMAS = 1.5  # ... of which at least ±1.5σ must lie on the pass (else the background is a guess)
END_MARGIN_SIGMAS = 2.0  # crossings this close to a line's end or bend see a truncated line integral
CENTRE_TOLERANCE_M = 0.008  # the fitted peak may sit this far (across the line) from the mapped line
MIN_AMPLITUDE_SNR = 8.0  # a peak less significant than this gives no usable width
MAX_WIDTH_REL_ERROR = 0.15  # crossings whose width is worse than ±15 % (1σ) are dropped
SATURATED_DISPLAY = 1.0 - 1.5 / COUNTS_FULL_SCALE  # the top count: the true reading is anywhere above
MAX_SATURATED_FRACTION = 0.3  # more of the peak's core saturated than this: its width is not measured
MIN_MEASUREMENTS = 3  # fewer accepted crossings than this: their spread (and so σ) is not known
MAX_CROSSINGS = 40  # per object and channel, spread along it: beyond that σ is model-limited anyway
FIRST_ROUND_CROSSINGS = 12  # the first round only sizes the windows of the next
ROUNDS = 3  # guess from the map's width → estimate → estimate again if it moved
GUESS_SETTLED_M = 0.002  # a guess this close to the estimate sizes the same windows (±3σ moves < 1.5 mm)
FALLBACK_GUESS_M = 0.02  # where the map's width gave windows that found nothing
OUTLIER_MADS = 4.0
WIDTH_MODEL_REL = 0.02  # the footprint model's σ is trusted to 2 % (calibration, non-Gaussian tails)
MAX_DEPTH_SIGMA_M = 0.02  # a 1σ beyond this says nothing about where to drill
MAX_DEPTH_M = 0.12  # deepest a guess may be (the sensors see nothing deeper)
STRIP_MIN_PASSES = 6
STRIP_MIN_HALF_WIDTH_M = 0.035  # strips need ≥ 3 passes either side even for a sharp AC crest (1 cm rows)
MAX_GRID_PROFILES = 12  # per segment
DIRECTION_MIN_SPAN_M = 0.1  # crossings spanning this much of a segment give its direction to < 0.5°
DIRECTION_MAX_CHANGE_DEG = 5.0  # a larger change is a crossing on something else, not a better direction
SOFT_L1_SCALE = 3.0  # residuals (in noise σ) beyond this count linearly: unmapped bumps do not dominate


@dataclass(frozen=True)
class AcModel:
    """The AC sensor's footprint (scanner.sensor_model.SensorConfig names): isotropic Gaussian of σ ac_sigma_m
    at zero depth, widening as hypot(ac_sigma_m, ac_spread_per_depth·depth)."""

    ac_sigma_m: float = 0.004
    ac_spread_per_depth: float = 0.3

    @classmethod
    def from_meta(cls, sensor: dict | None) -> AcModel:
        sensor = sensor or {}
        names = ("ac_sigma_m", "ac_spread_per_depth")
        return cls(**{k: float(sensor[k]) for k in names if isinstance(sensor.get(k), (int, float))})


@dataclass(frozen=True)
class Footprint:
    """A channel's Gaussian footprint: σ along wall x (sigma_u_m) and y (sigma_v_m) at zero depth, widening by
    `spread` per metre of depth (σ² + (spread·depth)²)."""

    sigma_u_m: float
    sigma_v_m: float
    spread: float

    def var_across(self, normal: NDArray[np.float64], depth: float) -> float:
        """σ_⊥² (m²) of a line's cross profile, the line having unit normal `normal`."""
        return float(normal[0] ** 2 * self.sigma_u_m**2 + normal[1] ** 2 * self.sigma_v_m**2
                     + (self.spread * depth) ** 2)

    def var_slice(self, along: NDArray[np.float64], depth: float) -> float:
        """σ_a² (m²) of a point's profile along a pass of unit direction `along`."""
        x = (self.spread * depth) ** 2
        return float(1.0 / (along[0] ** 2 / (self.sigma_u_m**2 + x) + along[1] ** 2 / (self.sigma_v_m**2 + x)))

    def excess_slice(self, var: float, along: NDArray[np.float64]) -> float:
        """x = (spread·depth)² giving a slice variance `var` along `along` (the root of the slice relation,
        c(a + x)(b + x) = a_x²(b + x) + a_y²(a + x) with c = 1/var; negative when narrower than at depth 0)."""
        a, b, c = self.sigma_u_m**2, self.sigma_v_m**2, 1.0 / var
        ux2, uy2 = along[0] ** 2, along[1] ** 2
        qb = c * (a + b) - (ux2 + uy2)
        qc = c * a * b - ux2 * b - uy2 * a
        return float((-qb + math.sqrt(max(qb * qb - 4.0 * c * qc, 0.0))) / (2.0 * c))

    def depth(self, excess: float) -> float:
        return math.sqrt(max(excess, 0.0)) / self.spread


def inductive_footprint(model: InductiveModel) -> Footprint:
    return Footprint(model.ind_sigma_u_m, model.ind_sigma_v_m, model.spread_per_depth)


def ac_footprint(model: AcModel) -> Footprint:
    return Footprint(model.ac_sigma_m, model.ac_sigma_m, model.ac_spread_per_depth)


@dataclass
class _Pass:
    """One pass of one channel: samples ordered along the pass (t metres from `origin` along `unit`)."""

    pass_id: int
    group: int  # frame: passes of one group share one pose (rigid to each other)
    origin: NDArray[np.float64]
    unit: NDArray[np.float64]  # direction of motion
    t: NDArray[np.float64]
    xy: NDArray[np.float64]  # (m, 2) positions (lag undone)
    raw: NDArray[np.float64]
    sigma: NDArray[np.float64]  # noise of each raw reading
    saturated: NDArray[np.bool_]
    lo: NDArray[np.float64] | None = None  # bounding box of xy (None: not computed)
    hi: NDArray[np.float64] | None = None

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.array([-self.unit[1], self.unit[0]])


@dataclass
class _Measurement:
    """One width measurement: excess x = (spread·depth)² and its variance."""

    excess: float
    var: float
    kind: str  # crossing | strip | grid


@dataclass
class _Target:
    """What the fits know of one object: its geometry and current depth guess."""

    obj: MapObject
    depth_guess: float


def _to_raw(display: NDArray[np.float64]) -> NDArray[np.float64]:
    return -np.log(np.clip(1.0 - display, 1e-6, 1.0))


def _median(x: NDArray[np.float64]) -> float:
    """np.median of a finite 1-D array (the same order statistics, without its per-call overhead)."""
    n = x.size
    h = n // 2
    if n % 2:
        return float(np.partition(x, h)[h])
    part = np.partition(x, (h - 1, h))
    return float((part[h - 1] + part[h]) / 2.0)


def _pass_order(samples: dict[str, NDArray], xy: NDArray[np.float64]) -> NDArray[np.int64] | None:
    """Indices of the samples with a finite position, ordered by pass, then by time (ties in their original
    order); None without samples["pass_id"]."""
    if "pass_id" not in samples:
        return None
    pids = np.asarray(samples["pass_id"])
    okidx = np.flatnonzero(np.all(np.isfinite(xy), axis=1))
    time = samples.get("time_s", samples.get("seq"))
    if time is None:
        return okidx[np.argsort(pids[okidx], kind="stable")]
    return okidx[np.lexsort((np.asarray(time)[okidx], pids[okidx]))]


def _passes(samples: dict[str, NDArray], xy: NDArray[np.float64], channel: str, lag_m: float,
            order: NDArray[np.int64] | None = None) -> list[_Pass]:
    """The channel's readings split into passes (needs samples["pass_id"]); positions moved back along the
    motion by lag_m (the inductive hysteresis). order: _pass_order(samples, xy), if known."""
    if channel not in samples or "pass_id" not in samples:
        return []
    values = np.asarray(samples[channel], dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    if order is None:
        order = _pass_order(samples, xy)
        assert order is not None  # samples has a pass_id (checked above)
    # the usable samples ordered by pass, then by time
    sidx = order[np.isfinite(values[order])]
    if sidx.size == 0:
        return []
    groups = samples.get("frame_id")
    pids = np.asarray(samples["pass_id"])
    pk = pids[sidx]
    same = pk[1:] == pk[:-1]
    bounds = np.flatnonzero(np.r_[True, ~same, True])
    # per-sample quantities in that order, computed once for all passes
    display_all = values[sidx]
    raw_all = _to_raw(display_all)
    background = float(np.percentile(raw_all, 20))
    raw_all -= background
    saturated_all = display_all >= SATURATED_DISPLAY
    # one count of quantisation is 1/(1 − display) in raw units: uniform, variance q²/12
    quant_all = (1.0 / COUNTS_FULL_SCALE) / np.maximum(1.0 - display_all, 1e-3) / math.sqrt(12.0)
    p_all = xy[sidx]
    # each pass's bounding box (shifting by the lag after taking the extremes gives the same numbers)
    p_lo = np.minimum.reduceat(p_all, bounds[:-1], axis=0)
    p_hi = np.maximum.reduceat(p_all, bounds[:-1], axis=0)
    group_ids = np.asarray(groups) if groups is not None else None
    # each pass's direction of motion from its first and last sample (as one pass at a time would)
    spans = list(itertools.pairwise(bounds.tolist()))
    units = np.zeros((len(spans), 2))
    kept = []
    for k, (lo, hi) in enumerate(spans):
        if hi - lo < 20:
            continue
        motion = p_all[hi - 1] - p_all[lo]
        length = float(np.linalg.norm(motion))
        if length < 0.02:
            continue
        units[k] = motion / length
        kept.append(k)
    if not kept:
        return []
    counts = np.diff(bounds)
    p_all = p_all - lag_m * np.repeat(units, counts, axis=0)  # the lag undone along each pass's motion
    rel_all = p_all - np.repeat(p_all[bounds[:-1]], counts, axis=0)
    t_all = np.zeros(p_all.shape[0])
    for k in kept:
        lo, hi = spans[k]
        t_all[lo:hi] = rel_all[lo:hi] @ units[k]
    origins = p_all[bounds[:-1]].copy()  # the first sample in time
    # passes not in order along their motion are sorted (stably, as one pass at a time)
    back = np.flatnonzero((t_all[1:] < t_all[:-1]) & same) + 1
    for k in np.unique(np.searchsorted(bounds, back, side="right") - 1).tolist():
        lo, hi = spans[k]
        srt = lo + np.argsort(t_all[lo:hi], kind="stable")
        for arr in (t_all, p_all, raw_all, saturated_all, quant_all):
            arr[lo:hi] = arr[srt]
    white = np.zeros(len(spans))
    passes = []
    for k in kept:
        lo, hi = spans[k]
        raw, saturated = raw_all[lo:hi], saturated_all[lo:hi]
        good = ~saturated
        if np.count_nonzero(good) < 20:
            continue
        diffs = np.diff(raw[good])
        w = 1.4826 * _median(np.abs(diffs - _median(diffs))) / math.sqrt(2.0)
        white[k] = max(w, 1e-4)
        passes.append(k)
    sigma_all = np.hypot(np.repeat(white, counts), quant_all)
    out = []
    for k in passes:
        lo, hi = spans[k]
        group = int(group_ids[sidx[lo]]) if group_ids is not None else 0
        unit = units[k]
        out.append(_Pass(int(pids[sidx[lo]]), group, origins[k], unit, t_all[lo:hi], p_all[lo:hi], raw_all[lo:hi],
                         sigma_all[lo:hi], saturated_all[lo:hi], p_lo[k] - lag_m * unit, p_hi[k] - lag_m * unit))
    return out


# ---- geometry of objects against a pass ---------------------------------------------------------------------

def _segments(obj: MapObject) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    p = obj.points_m
    return [(a, b) for a, b in itertools.pairwise(p) if np.linalg.norm(b - a) > 1e-6]


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


@dataclass
class _Feature:
    """Where an object's peak lies along a pass: position t and expected σ along the pass."""

    t: float
    sigma_t: float


def _tagged_features(targets: list[_Target], fp: Footprint, ps: _Pass,
                     lines: _LineTable | None = None) -> list[tuple[tuple[int, int], _Feature]]:
    """Peaks the pass should show from the mapped objects (lines crossing it, points beside it), each with
    its (target index, segment index), in that order. lines: the targets' segments (_LineTable) if known."""
    out = []
    for i, tg in enumerate(targets):
        obj = tg.obj
        if obj.kind == "point":
            rel = obj.points_m[0] - ps.origin
            var = fp.var_slice(ps.unit, tg.depth_guess)
            offset = abs(float(rel @ ps.normal))
            if offset < 3.0 * math.sqrt(fp.var_slice(ps.normal, tg.depth_guess)):
                out.append(((i, 0), _Feature(float(rel @ ps.unit), math.sqrt(var))))
    lines = lines or _LineTable(targets, fp)
    if lines.tags:
        e, a = lines.e, lines.a
        sin = ps.unit[0] * e[:, 1] - ps.unit[1] * e[:, 0]
        rel = a - ps.origin
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (rel[:, 0] * e[:, 1] - rel[:, 1] * e[:, 0]) / sin
        foot = ps.origin + t[:, None] * ps.unit - a
        s = foot[:, 0] * e[:, 0] + foot[:, 1] * e[:, 1]
        # near-parallel (|sin| < 0.2): a plateau along the pass, taken by the background terms
        ok = (np.abs(sin) >= 0.2) & (-2.0 * lines.sig <= s) & (s <= lines.length + 2.0 * lines.sig)
        for m in np.flatnonzero(ok).tolist():
            out.append((lines.tags[m], _Feature(float(t[m]), float(lines.sig[m] / abs(sin[m])))))
        out.sort(key=lambda f: f[0])  # target by target, as the objects are listed
    return out


class _LineTable:
    """The line targets' segments as arrays: start a, unit direction e, length, σ across at the depth guess."""

    def __init__(self, targets: list[_Target], fp: Footprint) -> None:
        self.tags: list[tuple[int, int]] = []
        a, e, length, sig = [], [], [], []
        for i, tg in enumerate(targets):
            if tg.obj.kind != "line":
                continue
            for j, (p, q) in enumerate(_segments(tg.obj)):
                d = (q - p) / np.linalg.norm(q - p)
                self.tags.append((i, j))
                a.append(p)
                e.append(d)
                length.append(float(np.linalg.norm(q - p)))
                sig.append(math.sqrt(fp.var_across(np.array([-d[1], d[0]]), tg.depth_guess)))
        self.a = np.array(a, dtype=np.float64).reshape(-1, 2)
        self.e = np.array(e, dtype=np.float64).reshape(-1, 2)
        self.length = np.array(length, dtype=np.float64)
        self.sig = np.array(sig, dtype=np.float64)


def _features_on_pass(targets: list[_Target], fp: Footprint, ps: _Pass, skip: tuple[int, int] | None,
                      ) -> list[_Feature]:
    """Peaks the pass should show from the mapped objects (lines crossing it, points beside it), except the
    segment `skip` = (target index, segment index) being measured."""
    return [f for tag, f in _tagged_features(targets, fp, ps) if tag != skip]


class _PassSet:
    """A channel's passes with their geometry as arrays (one row per pass: which passes cross or run along a
    segment is then a few array operations) and, per pass, the peaks the mapped objects put on it, computed
    once while the depth guesses hold (reset() when they change)."""

    def __init__(self, passes: list[_Pass]) -> None:
        self.passes = passes
        n = len(passes)
        self.origin = np.array([ps.origin for ps in passes], dtype=np.float64).reshape(n, 2)
        self.unit = np.array([ps.unit for ps in passes], dtype=np.float64).reshape(n, 2)
        self.t_first = np.array([ps.t[0] for ps in passes], dtype=np.float64)
        self.t_last = np.array([ps.t[-1] for ps in passes], dtype=np.float64)
        self.lo = np.array([ps.xy.min(axis=0) if ps.lo is None else ps.lo for ps in passes],
                           dtype=np.float64).reshape(n, 2)
        self.hi = np.array([ps.xy.max(axis=0) if ps.hi is None else ps.hi for ps in passes],
                           dtype=np.float64).reshape(n, 2)
        self._features: dict[int, list[tuple[tuple[int, int], _Feature]]] = {}
        self._lines: _LineTable | None = None

    def reset(self) -> None:
        self._features.clear()
        self._lines = None

    def sin_to(self, e: NDArray[np.float64]) -> NDArray[np.float64]:
        """_cross(unit, e) of every pass."""
        return self.unit[:, 0] * e[1] - self.unit[:, 1] * e[0]

    def features(self, k: int, targets: list[_Target], fp: Footprint, skip: tuple[int, int]) -> list[_Feature]:
        """_features_on_pass of pass k."""
        got = self._features.get(k)
        if got is None:
            if self._lines is None:
                self._lines = _LineTable(targets, fp)
            got = self._features[k] = _tagged_features(targets, fp, self.passes[k], self._lines)
        return [f for tag, f in got if tag != skip]


# ---- 1-D profile fit ----------------------------------------------------------------------------------------

@dataclass
class _Fit:
    sigma: float
    sigma_err: float
    amplitude: float
    centre: float


def _gaussians(t: NDArray[np.float64], p: NDArray[np.float64], n_bg: int,
               centre: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Model background polynomial (n_bg terms in t − centre) + Gaussians (amplitude, centre, σ triples) and
    its Jacobian (len(t), len(p))."""
    tc = t - centre
    jac = np.empty((t.size, p.size))
    f = np.zeros(t.size)
    for k in range(n_bg):
        jac[:, k] = tc**k
        f += p[k] * jac[:, k]
    for k in range(n_bg, p.size, 3):
        u = (t - p[k + 1]) / p[k + 2]
        g = np.exp(-0.5 * u * u)
        f += p[k] * g
        jac[:, k] = g
        jac[:, k + 1] = p[k] * g * u / p[k + 2]
        jac[:, k + 2] = p[k] * g * u * u / p[k + 2]
    return f, jac


def _least_squares(t: NDArray[np.float64], y: NDArray[np.float64], noise: NDArray[np.float64],
                   x0: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64], n_bg: int,
                   centre: float, robust: bool) -> tuple[NDArray[np.float64], bool]:
    """Levenberg–Marquardt with box constraints (steps clipped) and, if robust, soft-L1 weights (IRLS).
    Small dense problems: a few numpy operations per iteration, ~20x cheaper than scipy's general solver."""
    p = np.clip(x0, lo, hi)

    def cost_of(r: NDArray[np.float64]) -> float:
        if not robust:
            return float(np.sum(r * r))
        z = (r / SOFT_L1_SCALE) ** 2
        return float(np.sum(2.0 * (np.sqrt(1.0 + z) - 1.0))) * SOFT_L1_SCALE**2

    f, jac = _gaussians(t, p, n_bg, centre)
    r = (f - y) / noise
    cost = cost_of(r)
    lam = 1e-3
    for _ in range(100):
        w = 1.0 / np.sqrt(1.0 + (r / SOFT_L1_SCALE) ** 2) if robust else np.ones_like(r)
        J = jac / noise[:, None]
        A = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        d = np.maximum(np.diag(A), 1e-30)
        improved = False
        while lam < 1e12:
            try:
                step = np.linalg.solve(A + lam * np.diag(d), -g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            trial = np.clip(p + step, lo, hi)
            f_t, jac_t = _gaussians(t, trial, n_bg, centre)
            r_t = (f_t - y) / noise
            cost_t = cost_of(r_t)
            if cost_t <= cost:
                improved = True
                # converged when the cost (χ² in noise units) drops by < 1e-3: parameters then move by
                # < 3 % of their own σ
                small = cost - cost_t <= max(1e-3, 1e-9 * cost)
                p, f, jac, r, cost = trial, f_t, jac_t, r_t, cost_t
                lam = max(lam / 5.0, 1e-9)
                break
            lam *= 4.0
        if not improved:
            return p, True  # no step lowers the cost: a minimum within the bounds
        if small:
            return p, True
    return p, False


def _fit_profile(t: NDArray[np.float64], y: NDArray[np.float64], noise: NDArray[np.float64], centre: float,
                 sigma_guess: float, sigma_bounds: tuple[float, float], centre_tol: float,
                 neighbours: list[_Feature], slope: bool = True, robust: bool = True,
                 scale_by_scatter: bool = False) -> _Fit | None:
    """Background (+ slope) + Gaussian (+ one Gaussian per neighbour) by (robust) weighted least squares.
    Returns the main Gaussian's σ with its 1σ error — the covariance scaled by the residuals' scatter where
    that exceeds the noise model (or always, with scale_by_scatter) — or None when the fit does not
    determine it (at a bound, peak not significant, width too uncertain)."""
    n_bg = 2 if slope else 1
    base = float(np.percentile(y, 20))
    near = np.abs(t - centre) < 0.3 * sigma_guess
    top = float(np.max(y[near])) if near.any() else float(np.max(y))
    x0 = [*[base, 0.0][:n_bg], max(top - base, 1e-3), centre, sigma_guess]
    lo = [*[-np.inf, -np.inf][:n_bg], 0.0, centre - centre_tol, sigma_bounds[0]]
    hi = [*[np.inf, np.inf][:n_bg], np.inf, centre + centre_tol, sigma_bounds[1]]
    for nb in neighbours:
        close = np.abs(t - nb.t) < 0.3 * nb.sigma_t
        height = float(np.max(y[close])) - base if close.any() else 0.0
        x0 += [max(height, 0.0) + 1e-4, nb.t, nb.sigma_t]
        lo += [0.0, nb.t - centre_tol, 0.3 * nb.sigma_t]
        hi += [np.inf, nb.t + centre_tol, 5.0 * nb.sigma_t]  # wider: a pipe coupled to a live cable (AC)
    n_par = len(x0)
    if t.size < n_par + 3:
        return None
    p, converged = _least_squares(t, y, noise, np.asarray(x0), np.asarray(lo), np.asarray(hi), n_bg, centre,
                                  robust)
    f, jac = _gaussians(t, p, n_bg, centre)
    r = (f - y) / noise
    J = jac / noise[:, None]
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    chi2 = float(np.sum(r**2)) / max(t.size - n_par, 1)
    cov *= chi2 if scale_by_scatter else max(chi2, 1.0)
    i_amp, i_c, i_sig = n_bg, n_bg + 1, n_bg + 2
    amp, amp_err = float(p[i_amp]), math.sqrt(max(cov[i_amp, i_amp], 0.0))
    sig, sig_err = float(p[i_sig]), math.sqrt(max(cov[i_sig, i_sig], 0.0))
    at_bound = (sig <= sigma_bounds[0] * 1.02 or sig >= sigma_bounds[1] * 0.98
                or abs(float(p[i_c]) - centre) >= 0.98 * centre_tol)
    if not converged or at_bound or amp <= MIN_AMPLITUDE_SNR * amp_err or sig_err > MAX_WIDTH_REL_ERROR * sig:
        return None
    return _Fit(sig, sig_err, amp, float(p[i_c]))


# ---- measurements -------------------------------------------------------------------------------------------

def _window(ps: _Pass, centre: float, sigma_t: float, neighbours: list[_Feature]) -> NDArray[np.bool_] | None:
    """Samples of the pass within ±WINDOW_SIGMAS·σ of centre, widened to take in the cores (±2σ) of the
    neighbours whose flanks reach into it (a neighbour fitted from its flank alone trades width with the
    peak); None if the pass does not reach far enough to either side or too much of the core is saturated."""
    half = WINDOW_SIGMAS * sigma_t
    if ps.t[0] > centre - MIN_SIDE_SIGMAS * sigma_t or ps.t[-1] < centre + MIN_SIDE_SIGMAS * sigma_t:
        return None
    lo, hi = centre - half, centre + half
    for nb in neighbours:
        lo, hi = min(lo, nb.t - 2.0 * nb.sigma_t), max(hi, nb.t + 2.0 * nb.sigma_t)
    sel = (ps.t >= lo) & (ps.t <= hi)
    core = sel & (np.abs(ps.t - centre) <= sigma_t)
    if core.sum() < 5 or ps.saturated[core].mean() > MAX_SATURATED_FRACTION:
        return None
    return sel & ~ps.saturated


def _near_sheet_metal(outlines: list[NDArray[np.float64]], pts: NDArray[np.float64], clearance: float) -> bool:
    from scanner.sensor_model import points_in_polygon

    for ring in outlines:
        if points_in_polygon(pts, ring[:-1]).any() or distances_to_polyline(pts, ring).min() < clearance:
            return True
    return False


def _line_crossings(i: int, targets: list[_Target], pset: _PassSet, fp: Footprint,
                    outlines: list[NDArray[np.float64]], max_crossings: int = 40) -> list[_Measurement]:
    tg = targets[i]
    segs = _segments(tg.obj)
    found: list[tuple[float, int, int, float, float, NDArray[np.float64]]] = []
    for j, (a, b) in enumerate(segs):
        length = float(np.linalg.norm(b - a))
        e = (b - a) / length
        normal = np.array([-e[1], e[0]])
        sig = math.sqrt(fp.var_across(normal, tg.depth_guess))
        sin_all = pset.sin_to(e)
        cand = np.flatnonzero(np.abs(sin_all) >= MIN_CROSSING_SIN)
        if cand.size == 0:
            continue
        sin_c = sin_all[cand]
        rel = a - pset.origin[cand]
        t_c = (rel[:, 0] * e[1] - rel[:, 1] * e[0]) / sin_c
        foot = pset.origin[cand] + t_c[:, None] * pset.unit[cand] - a
        s = foot[:, 0] * e[0] + foot[:, 1] * e[1]
        # an oblique pass runs along the line too: its peak's core (±MIN_SIDE_SIGMAS) must keep clear of
        # the line's ends as well as its centre
        abs_sin = np.abs(sin_c)
        margin = sig * (END_MARGIN_SIGMAS + MIN_SIDE_SIGMAS * np.sqrt(np.maximum(1.0 - sin_c * sin_c, 0.0)) / abs_sin)
        reach = MIN_SIDE_SIGMAS * sig / abs_sin
        ok = ((margin <= s) & (s <= length - margin) & (pset.t_first[cand] + reach <= t_c)
              & (t_c <= pset.t_last[cand] - reach))
        for m in np.flatnonzero(ok).tolist():
            found.append((float(s[m]) + 10.0 * j, int(cand[m]), j, float(t_c[m]), float(abs_sin[m]), normal))
    if len(found) > max_crossings:  # evenly along the object
        found.sort(key=lambda f: f[0])
        found = [found[k] for k in np.linspace(0, len(found) - 1, max_crossings).round().astype(int)]
    fits: dict[int, list[tuple[_Pass, _Fit]]] = {}
    for _, k, j, t, sin, normal in found:
        ps = pset.passes[k]
        sig = math.sqrt(fp.var_across(normal, tg.depth_guess)) / sin
        nbs = [f for f in pset.features(k, targets, fp, (i, j))
               if abs(f.t - t) < WINDOW_SIGMAS * sig + 2.5 * f.sigma_t]
        sel = _window(ps, t, sig, nbs)
        if sel is None:
            continue
        ends = ps.origin + np.array([t - WINDOW_SIGMAS * sig, t + WINDOW_SIGMAS * sig])[:, None] * ps.unit
        if outlines and _near_sheet_metal(outlines, np.linspace(ends[0], ends[1], 25), sig * sin):
            continue
        lo = 0.5 * math.sqrt(fp.var_across(normal, 0.0)) / sin
        hi = 3.0 * math.sqrt(fp.var_across(normal, MAX_DEPTH_M)) / sin
        fit = _fit_profile(ps.t[sel], ps.raw[sel], ps.sigma[sel], t, sig, (lo, hi), CENTRE_TOLERANCE_M / sin, nbs)
        if fit is not None:
            fits.setdefault(j, []).append((ps, fit))
    out = []
    for j, got in fits.items():
        a, b = segs[j]
        e = _refined_direction([ps.origin + f.centre * ps.unit for ps, f in got], (b - a) / np.linalg.norm(b - a))
        normal = np.array([-e[1], e[0]])
        for ps, fit in got:
            sin = abs(_cross(ps.unit, e))
            var = (fit.sigma * sin) ** 2
            var_err = 2.0 * fit.sigma * sin**2 * fit.sigma_err
            out.append(_Measurement(var - fp.var_across(normal, 0.0), var_err**2, "crossing"))
    return out


def _refined_direction(centres: list[NDArray[np.float64]], e: NDArray[np.float64]) -> NDArray[np.float64]:
    """The segment's direction through its crossings' fitted peak centres where they span enough of it: the
    width along a pass is σ_⊥ / |sin|, and at 45° each degree of the map's direction error is 1.7 % of the
    width (~1 mm of depth at 5 cm); the peaks place the line to a fraction of a millimetre."""
    c = np.asarray(centres)
    if c.shape[0] < MIN_MEASUREMENTS or np.ptp(c @ e) < DIRECTION_MIN_SPAN_M:
        return e
    _, u = fit_line(c)
    d = u if float(u @ e) >= 0 else -u
    return d if float(d @ e) >= math.cos(math.radians(DIRECTION_MAX_CHANGE_DEG)) else e


def _point_crossings(i: int, targets: list[_Target], pset: _PassSet, fp: Footprint,
                     outlines: list[NDArray[np.float64]]) -> list[_Measurement]:
    tg = targets[i]
    centre = tg.obj.points_m[0]
    out = []
    # passes within ~1σ of the point (across the pass) see ≥ 60 % of its peak; the passes clearly farther
    # are dropped in a few array operations (with a margin: the test below decides)
    rel_all = centre - pset.origin
    offset = np.abs(rel_all[:, 1] * pset.unit[:, 0] - rel_all[:, 0] * pset.unit[:, 1])
    x = (fp.spread * tg.depth_guess) ** 2
    var = 1.0 / (pset.unit[:, 1] ** 2 / (fp.sigma_u_m**2 + x) + pset.unit[:, 0] ** 2 / (fp.sigma_v_m**2 + x))
    for k in np.flatnonzero(offset <= np.sqrt(var) * (1.0 + 1e-9) + 1e-12).tolist():
        ps = pset.passes[k]
        rel = centre - ps.origin
        if abs(float(rel @ ps.normal)) > math.sqrt(fp.var_slice(ps.normal, tg.depth_guess)):
            continue
        t = float(rel @ ps.unit)
        sig = math.sqrt(fp.var_slice(ps.unit, tg.depth_guess))
        nbs = [f for f in pset.features(k, targets, fp, (i, 0))
               if abs(f.t - t) < WINDOW_SIGMAS * sig + 2.5 * f.sigma_t]
        sel = _window(ps, t, sig, nbs)
        if sel is None:
            continue
        if outlines and _near_sheet_metal(outlines, centre[None], WINDOW_SIGMAS * sig):
            continue
        lo = 0.5 * math.sqrt(fp.var_slice(ps.unit, 0.0))
        hi = 3.0 * math.sqrt(fp.var_slice(ps.unit, MAX_DEPTH_M))
        fit = _fit_profile(ps.t[sel], ps.raw[sel], ps.sigma[sel], t, sig, (lo, hi), CENTRE_TOLERANCE_M, nbs)
        if fit is None:
            continue
        x = fp.excess_slice(fit.sigma**2, ps.unit)
        h = 1e-3 * fit.sigma
        dx = (fp.excess_slice((fit.sigma + h) ** 2, ps.unit) - fp.excess_slice((fit.sigma - h) ** 2, ps.unit)) / (2 * h)
        out.append(_Measurement(x, (dx * fit.sigma_err) ** 2, "crossing"))
    return out


def _line_strips(i: int, targets: list[_Target], pset: _PassSet, fp: Footprint) -> list[_Measurement]:
    """Cross profiles from passes running along a segment, per frame (see the module docstring)."""
    tg = targets[i]
    others = [t for k, t in enumerate(targets) if k != i and t.obj.kind in ("line", "point")]
    # samples nearer another object than 2.5x its footprint's larger σ are masked (crossing pipes, screws)
    mask_radius = [2.5 * math.sqrt(max(fp.sigma_u_m, fp.sigma_v_m) ** 2 + (fp.spread * t.depth_guess) ** 2)
                   for t in others]
    radius_arr = np.array(mask_radius, dtype=np.float64)[:, None]
    other_lo = np.array([t.obj.points_m.min(axis=0) for t in others], dtype=np.float64).reshape(-1, 2)
    other_hi = np.array([t.obj.points_m.max(axis=0) for t in others], dtype=np.float64).reshape(-1, 2)
    out = []
    for a, b in _segments(tg.obj):
        length = float(np.linalg.norm(b - a))
        e = (b - a) / length
        normal = np.array([-e[1], e[0]])
        sig = math.sqrt(fp.var_across(normal, tg.depth_guess))
        half = max(WINDOW_SIGMAS * sig, STRIP_MIN_HALF_WIDTH_M)
        margin = END_MARGIN_SIGMAS * sig
        by_group: dict[int, list[tuple[float, float]]] = {}
        # passes along the segment whose samples reach its strip (|s| ≤ half beside it) at all
        lo_xy, hi_xy = np.minimum(a, b) - half - 1e-6, np.maximum(a, b) + half + 1e-6
        along = ((np.abs(pset.sin_to(e)) < MIN_CROSSING_SIN) & np.all(pset.hi >= lo_xy, axis=1)
                 & np.all(pset.lo <= hi_xy, axis=1))
        for k in np.flatnonzero(along).tolist():
            ps = pset.passes[k]
            if abs(_cross(ps.unit, e)) >= MIN_CROSSING_SIN:
                continue
            rel = ps.xy - a
            q, s = rel @ e, rel @ normal
            sel = (q >= margin) & (q <= length - margin) & (np.abs(s) <= half) & ~ps.saturated
            if sel.sum() < 20:
                continue
            keep = np.flatnonzero(sel)
            lo_xy, hi_xy = ps.xy[keep].min(axis=0), ps.xy[keep].max(axis=0)
            # the others too far from these samples to mask any of them are passed over
            far = np.any(other_lo > hi_xy + radius_arr, axis=1) | np.any(other_hi < lo_xy - radius_arr, axis=1)
            for m in np.flatnonzero(~far).tolist():
                # only samples inside the other's box widened by the radius can lie within the radius of it
                pts = ps.xy[keep]
                reach = radius_arr[m] + 1e-9
                near = np.flatnonzero(np.all(pts >= other_lo[m] - reach, axis=1)
                                      & np.all(pts <= other_hi[m] + reach, axis=1))
                if near.size:
                    masked = np.zeros(keep.size, bool)
                    masked[near] = ~(distances_to_polyline(pts[near], others[m].obj.points_m) > mask_radius[m])
                    keep = keep[~masked]
                if keep.size == 0:
                    break
            if keep.size < 20 or np.ptp(q[keep]) < 0.02:
                continue
            by_group.setdefault(ps.group, []).append((float(np.mean(s[keep])), float(np.mean(ps.raw[keep]))))
        for rows in by_group.values():
            if len(rows) < STRIP_MIN_PASSES:
                continue
            arr = np.array(sorted(rows))
            s, y = arr[:, 0], arr[:, 1]
            if s.min() > -0.5 * sig or s.max() < 0.5 * sig or (s < 0).sum() < 2 or (s > 0).sum() < 2:
                continue
            lo = 0.5 * math.sqrt(fp.var_across(normal, 0.0))
            hi = 3.0 * math.sqrt(fp.var_across(normal, MAX_DEPTH_M))
            # few points, no slope, ordinary least squares; the error scaled by their actual scatter (the
            # per-pass gain variation is not known a priori)
            noise = np.full(s.size, max(float(np.std(y)) * 1e-3, 1e-6))
            fit = _fit_profile(s, y, noise, 0.0, sig, (lo, hi), CENTRE_TOLERANCE_M, [], slope=False, robust=False,
                               scale_by_scatter=True)
            if fit is None:
                continue
            var = fit.sigma**2
            out.append(_Measurement(var - fp.var_across(normal, 0.0), (2.0 * fit.sigma * fit.sigma_err) ** 2,
                                    "strip"))
    return out


def _grid_kernel_var(resolution: float) -> float:
    """Variance (m²) the grid adds to a profile sampled from it: the splat Gaussian as scipy cuts it (at 2σ,
    WallGrid._blur), the bilinear split of each sample onto cells and the bilinear read-back (map_coordinates
    order 1), each a triangle of one cell (res²/6)."""
    sigma_px = tol.SIGNAL_SPLAT_SIGMA_M / resolution
    radius = int(2.0 * sigma_px + 0.5)
    k = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * (k / sigma_px) ** 2)
    return float((w * k**2).sum() / w.sum() + 2.0 / 6.0) * resolution**2


def _fit_display_profile(ts: NDArray[np.float64], y: NDArray[np.float64], kernel_var: float, sigma_guess: float,
                         bounds: tuple[float, float]) -> _Fit | None:
    """A grid cross profile y (display units, regular ts) fitted as the grid makes it: Gaussian + background
    in raw units, saturated to display, then smoothed by the grid's kernel (Gaussian of kernel_var). The
    grid averages display values, so smoothing cannot be undone after converting to raw (a saturated peak
    would look narrower than it is)."""
    from scipy.ndimage import gaussian_filter1d
    from scipy.optimize import least_squares

    step = float(ts[1] - ts[0])
    sk = math.sqrt(kernel_var) / step
    pad = math.ceil(4.0 * sk) + 1
    ext = np.concatenate([ts[0] - step * np.arange(pad, 0, -1), ts, ts[-1] + step * np.arange(1, pad + 1)])

    def model(p: NDArray[np.float64]) -> NDArray[np.float64]:
        z = p[0] + p[1] * ext + p[2] * np.exp(-0.5 * ((ext - p[3]) / p[4]) ** 2)
        return gaussian_filter1d(1.0 - np.exp(-np.maximum(z, 0.0)), sk, mode="nearest")[pad:-pad]

    raw = _to_raw(y)
    base = float(np.percentile(raw, 20))
    x0 = np.array([base, 0.0, max(float(raw[np.abs(ts) < 0.3 * sigma_guess].max()) - base, 1e-3), 0.0,
                   sigma_guess])
    lo = np.array([-np.inf, -np.inf, 0.0, -CENTRE_TOLERANCE_M, bounds[0]])
    hi = np.array([np.inf, np.inf, np.inf, CENTRE_TOLERANCE_M, bounds[1]])
    scale = np.array([0.1, 1.0, 0.1, sigma_guess, sigma_guess])
    sol = least_squares(lambda p: model(p) - y, np.clip(x0, lo + 1e-12, hi - 1e-12), bounds=(lo, hi),
                        x_scale=scale)
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac)
    except np.linalg.LinAlgError:
        return None
    # error from the residuals' scatter; the map's values are correlated over the kernel, so there are
    # ~1 / (2√π σ_k) independent ones per unit length, not 1 / step
    dof = max(ts.size - 5, 1)
    cov *= float(np.sum(sol.fun**2)) / dof * (2.0 * math.sqrt(math.pi) * sk)
    p = sol.x
    amp_err, sig_err = math.sqrt(max(cov[2, 2], 0.0)), math.sqrt(max(cov[4, 4], 0.0))
    if (not sol.success or p[4] <= bounds[0] * 1.02 or p[4] >= bounds[1] * 0.98
            or abs(p[3]) >= 0.98 * CENTRE_TOLERANCE_M or p[2] <= MIN_AMPLITUDE_SNR * amp_err
            or sig_err > MAX_WIDTH_REL_ERROR * p[4]):
        return None
    return _Fit(float(p[4]), sig_err, float(p[2]), float(p[3]))


def _grid_profiles(i: int, targets: list[_Target], grid: WallGrid, channel: str,
                   fp: Footprint) -> list[_Measurement]:
    """Cross profiles of a line in the grid's signal layer (fallback when the samples cannot be split into
    passes). Sound where the samples lie closer than the splat σ along the profile (the map is then a
    convolution), as along the passes of a raster; profiles another mapped object reaches are skipped."""
    tg = targets[i]
    if channel not in grid.models or tg.obj.kind != "line":
        return []
    info = grid.info
    signal = grid.signal(channel)
    kernel = _grid_kernel_var(info.resolution)
    step = 0.5 * info.resolution
    out = []
    for j, (a, b) in enumerate(_segments(tg.obj)):
        length = float(np.linalg.norm(b - a))
        e = (b - a) / length
        normal = np.array([-e[1], e[0]])
        sig = math.sqrt(fp.var_across(normal, tg.depth_guess) + kernel)
        margin = END_MARGIN_SIGMAS * sig
        n = min(int((length - 2 * margin) // (2.0 * sig)), MAX_GRID_PROFILES)  # 2σ apart: nearly independent
        for q in np.linspace(margin, length - margin, max(n, 0)):
            centre = a + q * e
            ts = np.arange(-WINDOW_SIGMAS * sig, WINDOW_SIGMAS * sig + step / 2, step)
            probe = _Pass(-1, 0, centre, normal, ts, np.empty((0, 2)), ts, ts, np.zeros(ts.size, bool))
            if any(abs(f.t) < WINDOW_SIGMAS * sig + 2.5 * f.sigma_t for f in _features_on_pass(
                    targets, fp, probe, (i, j))):
                continue
            pix = info.to_pixel(centre + ts[:, None] * normal)
            y = ndimage.map_coordinates(signal, [pix[:, 1], pix[:, 0]], order=1, mode="constant", cval=np.nan)
            if not np.all(np.isfinite(y)) or y.max() >= SATURATED_DISPLAY:
                continue
            bounds = (0.5 * math.sqrt(fp.var_across(normal, 0.0)), 3.0 * math.sqrt(fp.var_across(normal, MAX_DEPTH_M)))
            fit = _fit_display_profile(ts, y, kernel, math.sqrt(fp.var_across(normal, tg.depth_guess)), bounds)
            if fit is not None:
                out.append(_Measurement(fit.sigma**2 - fp.var_across(normal, 0.0),
                                        (2.0 * fit.sigma * fit.sigma_err) ** 2, "grid"))
    return out


# ---- combination --------------------------------------------------------------------------------------------

def _enough(measurements: list[_Measurement]) -> bool:
    """MIN_MEASUREMENTS crossings, or one strip (its error already comes from the scatter of its own
    ≥ STRIP_MIN_PASSES passes)."""
    return len(measurements) >= MIN_MEASUREMENTS or any(m.kind == "strip" for m in measurements)


def combine(measurements: list[_Measurement], fp: Footprint, var0: float) -> tuple[float, float, float] | None:
    """(depth m, 1σ m, 1σ of the measurements alone m) from per-measurement excesses (see the module
    docstring), or None.

    var0: the zero-depth footprint variance of the object's profile (for the model term)."""
    if not _enough(measurements):
        return None
    x = np.array([m.excess for m in measurements])
    v = np.array([max(m.var, 1e-16) for m in measurements])
    med = float(np.median(x))
    mad = 1.4826 * float(np.median(np.abs(x - med)))
    keep = np.abs(x - med) <= OUTLIER_MADS * max(mad, float(np.median(np.sqrt(v))))
    kept = [m for m, k in zip(measurements, keep, strict=True) if k]
    if not _enough(kept):
        return None
    x, v = x[keep], v[keep]
    n = x.size
    w = 1.0 / v
    mean_fixed = float(np.sum(w * x) / np.sum(w))
    tau2 = 0.0
    if n >= 2:  # DerSimonian–Laird: scatter beyond the measurements' own errors
        q = float(np.sum(w * (x - mean_fixed) ** 2))
        tau2 = max(0.0, (q - (n - 1)) / max(float(np.sum(w) - np.sum(w**2) / np.sum(w)), 1e-30))
    w_re = 1.0 / (v + tau2)
    mean = float(np.sum(w_re * x) / np.sum(w_re))
    se = 1.0 / math.sqrt(float(np.sum(w_re)))
    model = 2.0 * WIDTH_MODEL_REL * (var0 + max(mean, 0.0))
    dx = math.hypot(se, model)
    depth = fp.depth(mean)
    sigma = 0.5 * (fp.depth(mean + dx) - fp.depth(mean - dx))
    if sigma > MAX_DEPTH_SIGMA_M:
        return None
    return depth, sigma, 0.5 * (fp.depth(mean + se) - fp.depth(mean - se))


def _var0(obj: MapObject, fp: Footprint) -> float:
    if obj.kind == "point":
        return 0.5 * (fp.sigma_u_m**2 + fp.sigma_v_m**2)
    seg = np.diff(obj.points_m, axis=0)
    main = seg[int(np.argmax(np.linalg.norm(seg, axis=1)))]
    e = main / max(float(np.linalg.norm(main)), 1e-12)
    return fp.var_across(np.array([-e[1], e[0]]), 0.0)


def _initial_guess(obj: MapObject, fp: Footprint) -> float:
    """A depth from the map's width (biased, but only sizes the first fitting window)."""
    sigma2 = (obj.width_m / 2.3548) ** 2
    return float(np.clip(fp.depth(sigma2 - _var0(obj, fp)), 0.005, 0.06))


def _ac_first(obj: MapObject) -> bool:
    return obj.kind == "line" and obj.cls == "power_line"


def estimate_depths(objects: list[MapObject], grid: WallGrid, samples: dict[str, np.ndarray], xy: np.ndarray,
                    model: InductiveModel, lag_m: float = 0.0, ac: AcModel | None = None) -> None:
    """Set depth_m and depth_sigma_m (metres) of each line and point object in place (see module docstring).

    samples: the scan's sample columns (scanner.log: pass_id, frame_id, time_s, inductive, ac in display
    units 0..1); xy : (n, 2) float64 wall metres, the samples' positions as mapped (the inductive lag not yet
    undone: lag_m, the sensor's hysteresis, is undone here along each pass's motion). ac: the AC footprint
    (defaults to the scanner's). Objects no channel tells about keep None; outlines, and objects that
    already have a depth, are not touched.
    features["depth_measurements"], ["depth_channel_ac"] and ["depth_sigma_stat_m"] (the σ without the model
    term) record what the estimate rests on.
    """
    ac = ac or AcModel()
    fps = {INDUCTIVE.name: inductive_footprint(model), AC.name: ac_footprint(ac)}
    xy = np.asarray(xy, dtype=np.float64)
    order = _pass_order(samples, xy)
    passes = {INDUCTIVE.name: _PassSet(_passes(samples, xy, INDUCTIVE.name, lag_m, order)),
              AC.name: _PassSet(_passes(samples, xy, AC.name, 0.0, order))}
    outlines = [o.points_m for o in objects if o.kind == "outline" and o.features.get("polarity", 1.0) > 0
                and o.cls == "metal"]
    wanted = [o for o in objects if o.kind in ("line", "point")]
    for channel in (AC.name, INDUCTIVE.name):
        fp = fps[channel]
        # every mapped line and point is a possible neighbour in a fit, measured or not
        targets = [_Target(o, o.depth_m if o.depth_m is not None else _initial_guess(o, fp)) for o in wanted]
        pending = [k for k, o in enumerate(wanted)
                   if o.depth_m is None and (channel == INDUCTIVE.name or _ac_first(o))]
        done: dict[int, tuple[float, float, float, int]] = {}
        for round_ in range(ROUNDS):
            passes[channel].reset()  # the depth guesses moved: so did the peaks they put on each pass
            for k in pending:
                ms = _measure(k, targets, passes[channel], fp, outlines, grid, channel,
                              FIRST_ROUND_CROSSINGS if round_ == 0 else MAX_CROSSINGS)
                res = combine(ms, fp, _var0(wanted[k], fp))
                if res is not None:
                    done[k] = (*res, len(ms))
            # refit with windows sized by the estimates (the map's width is a poor guess); where the first
            # round found nothing, once more with the windows of a shallow object (the narrowest)
            again = []
            for k in pending:
                guess = done[k][0] if k in done else (FALLBACK_GUESS_M if round_ == 0 else None)
                if guess is not None and (round_ == 0 or abs(guess - targets[k].depth_guess) > GUESS_SETTLED_M):
                    targets[k].depth_guess = float(np.clip(guess, 0.0, MAX_DEPTH_M))
                    again.append(k)
            pending = again
        for k, (d, sigma, sigma_stat, n) in done.items():
            obj = wanted[k]
            obj.depth_m, obj.depth_sigma_m = d, sigma
            obj.features["depth_measurements"] = float(n)
            obj.features["depth_sigma_stat_m"] = sigma_stat
            obj.features["depth_channel_ac"] = 1.0 if channel == AC.name else 0.0


def _measure(k: int, targets: list[_Target], passes: _PassSet, fp: Footprint,
             outlines: list[NDArray[np.float64]], grid: WallGrid, channel: str,
             max_crossings: int) -> list[_Measurement]:
    obj = targets[k].obj
    if passes.passes:
        if obj.kind == "point":
            return _point_crossings(k, targets, passes, fp, outlines)
        return (_line_crossings(k, targets, passes, fp, outlines, max_crossings)
                + _line_strips(k, targets, passes, fp))
    return _grid_profiles(k, targets, grid, channel, fp)
