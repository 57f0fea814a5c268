"""Sensor fusion and classification, using the sensors' cross-sensitivity (paper sections 3 and 6).

What each channel sees (GMS120-class scanner):
  * AC: a sharp, narrow peak over a live cable; a flat *medium* level on metal near a power line (coupling),
    so a pipe near a cable shows in the AC map as a broad, low ridge without a sharp crest;
  * inductive: any metal — pipes, plates, screws, nails, and the copper of power lines (a weaker, narrower
    peak than a pipe's);
  * capacitive: wood (studs, beams) and water as a raised level, cavities as a lowered one. It cannot tell
    a wooden stud from a water-filled plastic pipe, and metal raises it too.

Per detected object we measure the height of each channel's signal over its background in robust standard
deviations (z): along a line's centre line, or over the cells inside an outline; for lines also the AC
crest's sharpness (the AC height on the line relative to the AC level 2.5 cm to either side). Logistic
evidence functions turn them into class probabilities:
    power_line  AC crest high and sharp (with or without an inductive peak)
    metal_pipe  inductive ridge, AC without a sharp crest, wider than a cable
    metal       metal for sure but not which (short ridge, plates, steel studs, ambiguous widths)
    fastener    small round inductive peak
    non_metal   raised capacitive level where the inductive channel looked and found no metal: a wooden
                stud or a water-filled plastic pipe (the capacitive channel cannot tell which)
    cavity      lowered capacitive region
beside a "nothing here" alternative: no channel supports any class. The confidence is the named class's
probability among all alternatives, "nothing here" included; where "nothing here" is the likeliest, the
class is "unknown" and the confidence that of the likeliest class (below one half). Nothing is called
non-metal without an inductive channel, and nothing metal without one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.special import expit

from geometry.polyline import midpoint_samples
from mapping.background import normalise
from mapping.grid import GridInfo, WallGrid
from mapping.map_object import MapObject
from mapping.objects import LINE_SIGMA_M, ridge_width, smooth_derivatives
from scanner.channels import AC, CAPACITIVE, INDUCTIVE, TWO_SIDED
from scanner.sensor_model import additive_units, points_in_polygon

CLASSES: tuple[str, ...] = ("power_line", "metal_pipe", "metal", "non_metal", "cavity", "fastener")
METAL_CLASSES: tuple[str, ...] = ("power_line", "metal_pipe", "metal", "fastener")  # what the inductive sensor sees
UNKNOWN = "unknown"  # no class is better supported than "nothing here"
# Channels whose objects lower the level as well as raise it (cavities lower the capacitive one): their
# background is estimated two-sided (mapping.background.background_level)
TWO_SIDED_CHANNELS: tuple[str, ...] = TWO_SIDED


@dataclass(frozen=True)
class FusionParams:
    """Thresholds of the evidence functions (z = robust standard deviations over the background)."""

    ac_crest_z: float = 30.0  # AC height on a line that says "live cable"
    ac_sharpness: float = 0.7  # (on-line − beside) / on-line AC above this is a crest, below a plateau
    side_offset_m: float = 0.025  # where "beside the line" is measured
    metal_min_z: float = 6.0  # inductive height that says "metal here"
    # Depth-compensated inductive strength, relative to a 15 mm copper pipe at the same depth: copper cables
    # are ~0.2, pipes 0.5–2.6 (a 32 mm steel pipe: 2.1/1.7 · 32/15), sheet metal seen as a ridge (a steel stud's
    # 5 cm flange) ≥ 5, measured on the map in additive units (a saturated display widens the ridge: deeper, and so
    # stronger still). The step sits at the two ranges' geometric mean.
    cable_max_ratio: float = 0.48
    area_min_ratio: float = 3.7
    # capacitive height (raised or lowered) that says "wood, water or a cavity": 4 σ, the level beyond which the
    # evidence layer (mapping.evidence.UNEXPLAINED_SIGMAS) calls a response something
    capacitive_min_z: float = 4.0
    softness: float = 0.15  # relative width of the logistic transitions


@dataclass(frozen=True)
class InductiveModel:
    """What fusion needs of the scanner's inductive sensor (scanner.sensor_model.SensorConfig names).

    The footprint is Gaussian, σ_u across × σ_v along the device, widening by `spread_per_depth`·depth; a
    line's peak falls off as ((d_ref + d0)/(depth + d0))³. `pipe_strength` is the raw peak of a 15 mm copper
    pipe at the reference depth; readings are display units 1 − exp(−(raw + baseline)).
    """

    ind_sigma_u_m: float = 0.011
    ind_sigma_v_m: float = 0.016
    spread_per_depth: float = 0.55
    reference_depth_m: float = 0.02
    depth_offset_m: float = 0.015
    pipe_strength: float = 1.7

    @classmethod
    def from_meta(cls, sensor: dict | None) -> InductiveModel:
        sensor = sensor or {}
        names = ("ind_sigma_u_m", "ind_sigma_v_m", "spread_per_depth", "reference_depth_m", "depth_offset_m")
        return cls(**{k: float(sensor[k]) for k in names if isinstance(sensor.get(k), (int, float))})

    def depth_from_width(self, fwhm_m: float, direction: NDArray[np.float64]) -> float:
        """Depth (m) at which a line along `direction` gives a cross profile of this half-maximum width."""
        d = direction / max(float(np.linalg.norm(direction)), 1e-12)
        nx, ny = -d[1], d[0]
        base = nx**2 * self.ind_sigma_u_m**2 + ny**2 * self.ind_sigma_v_m**2
        sigma2 = (fwhm_m / 2.3548) ** 2
        return float(np.sqrt(max(sigma2 - base, 0.0)) / self.spread_per_depth)

    def pipe_peak_raw(self, depth_m: float, direction: NDArray[np.float64] | None = None) -> float:
        """Raw peak of a 15 mm copper pipe at this depth running along `direction` (the line integral of
        the anisotropic footprint: a horizontal line meets its short axis and peaks lower)."""
        g = (self.reference_depth_m + self.depth_offset_m) / (depth_m + self.depth_offset_m)
        factor = 1.0
        if direction is not None:
            t = np.asarray(direction, dtype=np.float64) / max(float(np.linalg.norm(direction)), 1e-12)
            su2 = self.ind_sigma_u_m**2 + (self.spread_per_depth * depth_m) ** 2
            sv2 = self.ind_sigma_v_m**2 + (self.spread_per_depth * depth_m) ** 2
            factor = 1.0 / np.sqrt(sv2 * (t[0] ** 2 / su2 + t[1] ** 2 / sv2))
        return float(self.pipe_strength * g**3 * factor)


def raw_from_display(display: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """Display units 1 − exp(−raw) back to raw units (saturation undone)."""
    return -np.log(np.clip(1.0 - np.asarray(display, dtype=np.float64), 1e-6, 1.0))


def _sigmoid(x: NDArray[np.float64] | float) -> NDArray[np.float64] | float:
    return expit(np.asarray(x, dtype=np.float64))  # 1 / (1 + exp(−x)), without overflow far from the step


def _sample(z: NDArray[np.float64], info: GridInfo, xy: NDArray[np.float64]) -> NDArray[np.float64]:
    pix = info.to_pixel(xy)
    return ndimage.map_coordinates(z, [pix[:, 1], pix[:, 0]], order=1, mode="nearest")


class Fuser:
    """Measures channel features of objects on one WallGrid and classifies them."""

    def __init__(self, grid: WallGrid, params: FusionParams | None = None,
                 inductive: InductiveModel | None = None) -> None:
        self.grid = grid
        self.params = params or FusionParams()
        self.inductive = inductive or InductiveModel()
        self.z: dict[str, NDArray[np.float64]] = {}
        self.signal: dict[str, NDArray[np.float64]] = {}
        self.background: dict[str, float] = {}
        self._ridge: tuple | None = None  # the inductive map's smoothed height and Hessian in additive units
        for s in grid.sensors:
            self.signal[s] = grid.signal(s)
            self.z[s], self.background[s], _ = normalise(self.signal[s], s in TWO_SIDED_CHANNELS)

    def features(self, obj: MapObject) -> dict[str, float]:
        p = self.params
        info = self.grid.info
        f: dict[str, float] = {"length_m": obj.length_m(), "width_m": obj.width_m}
        if obj.kind == "outline":
            # the region's interior, not its ring: the ring is the half-maximum edge (or the object's own edge),
            # where each channel shows a fraction of what the region holds
            for s, z in self.z.items():
                f[f"{s}_z"] = self._median_inside(s, z, obj.points_m)
            return f
        pts, normals = midpoint_samples(obj.points_m, 0.005) if obj.kind == "line" else (obj.points_m, None)
        for s, z in self.z.items():
            f[f"{s}_z"] = float(np.median(_sample(z, info, pts)))
        if AC.name in self.z and normals is not None:
            on = _sample(self.z[AC.name], info, pts)
            side = 0.5 * (_sample(self.z[AC.name], info, pts + p.side_offset_m * normals)
                          + _sample(self.z[AC.name], info, pts - p.side_offset_m * normals))
            f["ac_sharpness"] = float(np.median((on - side) / np.maximum(np.abs(on), 1.0)))
        if INDUCTIVE.name in self.signal and obj.kind == "line":
            sig = np.nan_to_num(self.signal[INDUCTIVE.name], nan=self.background[INDUCTIVE.name])
            peak = float(np.median(_sample(sig, info, pts)))
            amp = float(raw_from_display(peak) - raw_from_display(self.background[INDUCTIVE.name]))
            seg = np.diff(obj.points_m, axis=0)
            main = seg[int(np.argmax(np.linalg.norm(seg, axis=1)))]
            # the width in units where the footprint adds up: a shallow pipe's saturated display top widens
            # its map ridge, which would put it deeper and make it stronger than a pipe
            width = self._additive_width(pts, normals) if normals is not None else obj.width_m
            depth = self.inductive.depth_from_width(width, main)
            f["inductive_width_m"] = width
            f["inductive_raw"] = amp
            f["depth_est_m"] = depth
            f["strength_ratio"] = amp / self.inductive.pipe_peak_raw(depth, main)
        return f

    def _additive_width(self, pts: NDArray[np.float64], normals: NDArray[np.float64]) -> float:
        """Median half-maximum width (m) of the inductive ridge across a line's points (normals: unit, across),
        measured as the line detector measures it (ridge_width) on the map in additive units."""
        if self._ridge is None:
            raw = additive_units(INDUCTIVE.name, self.signal[INDUCTIVE.name])
            z, _, _ = normalise(raw)
            sigma_px = LINE_SIGMA_M / self.grid.info.resolution
            s, _gx, _gy, hxx, hxy, hyy, _w = smooth_derivatives(z, np.isfinite(raw), sigma_px)
            self._ridge = (s, hxx, hxy, hyy, sigma_px)
        s, hxx, hxy, hyy, sigma_px = self._ridge
        info = self.grid.info
        nx, ny = normals[:, 0], normals[:, 1]
        curvature = (nx**2 * _sample(hxx, info, pts) + 2 * nx * ny * _sample(hxy, info, pts)
                     + ny**2 * _sample(hyy, info, pts))
        return float(np.median(ridge_width(_sample(s, info, pts), curvature, sigma_px, info)))

    def _median_inside(self, sensor: str, z: NDArray[np.float64], ring: NDArray[np.float64]) -> float:
        """Median z of the channel over the known cells whose centres lie inside the ring (k, 2); a ring too
        small to hold a cell centre is sampled at its centroid."""
        info = self.grid.info
        ring = np.asarray(ring, dtype=np.float64)
        ring = ring[:-1] if len(ring) > 3 and np.allclose(ring[0], ring[-1]) else ring
        xs, ys = info.cell_centres()
        lo, hi = ring.min(axis=0), ring.max(axis=0)
        ci = np.flatnonzero((xs >= lo[0]) & (xs <= hi[0]))
        ri = np.flatnonzero((ys >= lo[1]) & (ys <= hi[1]))
        if ci.size and ri.size:
            cc, rr = np.meshgrid(ci, ri)
            inside = points_in_polygon(np.column_stack([xs[cc.ravel()], ys[rr.ravel()]]), ring)
            rows, cols = rr.ravel()[inside], cc.ravel()[inside]
            known = np.isfinite(self.signal[sensor][rows, cols])
            if known.any():
                return float(np.median(z[rows[known], cols[known]]))
        return float(_sample(z, info, ring.mean(axis=0, keepdims=True))[0])

    def classify(self, obj: MapObject) -> MapObject:
        """Fills obj.cls, obj.confidence and obj.features (with p_<class> and p_nothing); returns obj."""
        p = self.params
        f = self.features(obj)
        obj.features.update(f)
        s = p.softness
        looked_for_metal = INDUCTIVE.name in self.z
        ind = f.get("inductive_z", 0.0)
        metal = float(_sigmoid((ind - p.metal_min_z) / (s * p.metal_min_z))) if looked_for_metal else 0.0
        cap = f.get("capacitive_z", 0.0)
        seen_cap = "capacitive_z" in f
        raised = float(_sigmoid((cap - p.capacitive_min_z) / (s * p.capacitive_min_z))) if seen_cap else 0.0
        lowered = float(_sigmoid((-cap - p.capacitive_min_z) / (s * p.capacitive_min_z))) if seen_cap else 0.0
        # "not metal" is a claim only the inductive channel can make (metal raises the capacitive level too)
        no_metal = (1.0 - metal) if looked_for_metal else 0.0
        if obj.kind == "point":
            scores = {"fastener": metal}
        elif obj.kind == "outline" and obj.features.get("polarity", 1.0) < 0:
            scores = {"cavity": lowered}  # a lowered level: metal, wood and water all raise it
        elif obj.kind == "outline":
            scores = {"metal": metal, "non_metal": no_metal * raised}
        else:
            ac = f.get("ac_z", 0.0)
            sharp = f.get("ac_sharpness", 0.0)
            live = float(_sigmoid((ac - p.ac_crest_z) / (s * p.ac_crest_z))
                         * _sigmoid((sharp - p.ac_sharpness) / 0.05))
            log_ratio = float(np.log(max(f.get("strength_ratio", 1.0), 1e-6)))
            copper_cable = float(_sigmoid((np.log(p.cable_max_ratio) - log_ratio) / 0.3))
            sheet = float(_sigmoid((log_ratio - np.log(p.area_min_ratio)) / 0.3))
            scores = {
                "power_line": live + (1 - live) * metal * copper_cable,
                "metal_pipe": (1 - live) * metal * (1 - copper_cable) * (1 - sheet),
                "metal": (1 - live) * metal * sheet,
                "non_metal": (1 - live) * no_metal * raised,
            }
        return _decide(obj, scores)


def _decide(obj: MapObject, scores: dict[str, float]) -> MapObject:
    """The likeliest class beside "nothing here" (the complement of the classes' evidence, ≥ 0)."""
    nothing = max(1.0 - sum(scores.values()), 0.0)
    total = sum(scores.values()) + nothing
    probs = {c: v / total for c, v in scores.items()} if total > 1e-12 else dict.fromkeys(scores, 0.0)
    best = max(probs, key=probs.get)  # type: ignore[arg-type]
    p_nothing = nothing / total if total > 1e-12 else 1.0
    obj.features.update({f"p_{c}": v for c, v in probs.items()})
    obj.features["p_nothing"] = p_nothing
    obj.cls = best if probs[best] >= p_nothing else UNKNOWN
    obj.confidence = float(probs[best])
    return obj


def class_map(grid: WallGrid, threshold: float = 0.7) -> tuple[NDArray[np.int16], NDArray[np.float64]]:
    """Per-cell class from the log-odds layers: (index into CLASSES or −1, its probability).

    AC occupancy → power_line, inductive → metal, capacitive above → non_metal (metal raises the capacitive
    level too: inductive wins). Objects, not cells, carry the finer classes; this map is the background of
    the texture.
    """
    shape = grid.info.shape
    idx = np.full(shape, -1, np.int16)
    prob = np.zeros(shape)
    order = [(CAPACITIVE.name, "non_metal"), (INDUCTIVE.name, "metal"), (AC.name, "power_line")]  # later wins
    for sensor, cls in order:
        if sensor not in grid.models:
            continue
        p = np.nan_to_num(grid.probability(sensor), nan=0.0)
        hit = p >= threshold
        idx[hit] = CLASSES.index(cls)
        prob[hit] = p[hit]
    return idx, prob
