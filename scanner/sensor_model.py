"""The wall scanner's forward model: what the inductive, capacitive and AC sensors read at a point of a wall.

Built to reproduce the measurements of the paper's section 3 (figures 5 and 6, a GMS120-class scanner):

- Inductive sensor: a coil whose sensitivity footprint is an anisotropic Gaussian (longer along the device's
  vertical axis) that widens with depth. The reading of a metal object is the footprint integrated over the
  object (line integral for pipes and cables, area integral for plates and steel studs, point value for screws
  and nails), scaled by material and size and falling off as (d_ref + d0)^3 / (depth + d0)^3. Consequences the
  paper reports fall out of the geometry: a pipe at 45° crosses the footprint's long axis obliquely, so its
  peak is lower and wider along a horizontal pass than a vertical pipe's; deeper objects give lower, wider
  peaks. Hysteresis: the sensor reports what it saw `hysteresis_m` earlier along the direction of motion, so
  a peak shifts with the direction of approach. Metal of the robot's own holder within ~15 cm of the device
  adds a disturbance (exponential in the 3-D distance). Copper cables are faintly visible (cross-sensitivity).
- AC sensor: a sharp peak over live cables (narrow isotropic footprint, 1/r-like fall-off); metal near a live
  cable is coupled inductively (coupling exp(-distance / coupling_length_m)): plates give a constant medium
  level over their area, pipes a low, broad signal.
- Capacitive sensor: wall-material baseline; wooden studs and water raise it, cavities lower it.
- Noise: white noise per sample plus a per-run gain and offset (run-to-run variability), drawn from the
  generator the caller passes; outputs are display units 0..1 (soft saturation 1 - exp(-raw)) and quantised
  to device counts 0..1000 by `counts`.

Everything is vectorised over samples: cost is O(samples near each object) per object.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.special import erf

from geometry.polyline import densify, distances_to_polyline
from scanner.channels import AC, CAPACITIVE, INDUCTIVE, by_name
from scanner.wall import AREA_KINDS, Wall, WallObject

COUNTS_FULL_SCALE = 1000  # device counts for display value 1.0
_SQRT2 = math.sqrt(2.0)
_CUTOFF_SIGMAS = 5.0  # footprint contributions beyond this many sigmas are below 4e-6 and skipped

# Inductive strength (raw units at the reference depth) per material, for a line object of reference size.
_IND_LINE = {"copper": 1.7, "steel": 2.1, "aluminium": 1.5, "plastic": 0.0}
_IND_CABLE = 0.35  # copper conductors of a 3 x 1.5 mm² cable: cross-sensitivity of the inductive sensor
_IND_AREA = {"steel": 2.6, "aluminium": 2.0, "copper": 2.2, "wood": 0.0}
_IND_POINT = 0.9  # a 4 mm screw, 40 mm long, at the reference depth
_CAP_BASELINE = {"drywall": 0.22, "wood": 0.30, "brick": 0.38, "concrete": 0.45, "aerated_concrete": 0.28}


@dataclass
class SensorConfig:
    """Parameters of the simulated wall scanner (units: metres, seconds, display units 0..1)."""

    rate_hz: float = 200.0  # samples per second the device measures
    max_speed_m_s: float = 0.06  # above this the device's readings are not trusted (scanner speed limit)
    ind_sigma_u_m: float = 0.011  # inductive footprint sigma across (device x) at zero depth
    ind_sigma_v_m: float = 0.016  # ... along the device's long (vertical) axis
    ac_sigma_m: float = 0.004  # AC footprint sigma at zero depth
    spread_per_depth: float = 0.55  # footprint sigma grows by this times the depth
    reference_depth_m: float = 0.02
    depth_offset_m: float = 0.015  # d0 of the inductive fall-off (d_ref + d0)^3 / (depth + d0)^3
    hysteresis_m: float = 0.003  # inductive lag along the direction of motion
    ac_spread_per_depth: float = 0.3  # the AC field is sharper than the inductive footprint
    ac_strength: float = 2.2
    ac_coupling_length_m: float = 0.6
    ac_coupled_plate_level: float = 0.55  # raw level of a plate right next to a live cable
    ac_coupled_pipe_level: float = 0.25
    ind_baseline: float = 0.03
    ac_baseline: float = 0.015
    ind_noise: float = 0.006
    ac_noise: float = 0.002
    cap_noise: float = 0.004
    run_gain_sigma: float = 0.02  # run-to-run gain variation of the inductive sensor
    run_offset_sigma: float = 0.003
    holder_metal_uv_m: list[list[list[float]]] = field(default_factory=list)  # polylines in drive coords
    holder_standoff_m: float = 0.05  # distance of the holder's metal in front of the wall surface
    holder_strength: float = 1.2
    holder_decay_m: float = 0.025

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, raw: dict[str, Any]) -> SensorConfig:
        return cls(**raw)


def _depth_gain(depth: float, cfg: SensorConfig, power: float = 3.0) -> float:
    d0 = cfg.depth_offset_m
    return ((cfg.reference_depth_m + d0) / (depth + d0)) ** power


def _sigmas(depth: float, sigma_u: float, sigma_v: float, spread: float) -> tuple[float, float]:
    extra = spread * depth
    return math.hypot(sigma_u, extra), math.hypot(sigma_v, extra)


def _line_integral(p: np.ndarray, a: np.ndarray, b: np.ndarray, su: float, sv: float) -> np.ndarray:
    """∫ exp(-½ xᵀΣ⁻¹x) ds along segment a→b, x = a + s t - p, Σ = diag(su², sv²). p : (n, 2) -> (n,) metres."""
    length = float(np.linalg.norm(b - a))
    t = (b - a) / length
    inv = np.array([1.0 / su**2, 1.0 / sv**2])
    r = a - p  # (n, 2)
    alpha = float(np.sum(t * t * inv))
    beta = r @ (t * inv)
    gamma = np.sum(r * r * inv, axis=1)
    scale = math.sqrt(2.0 * alpha)
    return (np.exp(-0.5 * (gamma - beta**2 / alpha)) * math.sqrt(math.pi / (2.0 * alpha))
            * (erf((alpha * length + beta) / scale) - erf(beta / scale)))


def _is_axis_rectangle(poly: np.ndarray) -> bool:
    if len(poly) != 4:
        return False
    xs, ys = np.unique(np.round(poly[:, 0], 9)), np.unique(np.round(poly[:, 1], 9))
    return len(xs) == 2 and len(ys) == 2


def _area_fraction(p: np.ndarray, poly: np.ndarray, su: float, sv: float) -> np.ndarray:
    """Fraction (0..1) of the normalised footprint centred at each p lying over the polygon. p : (n, 2)."""
    if _is_axis_rectangle(poly):
        x0, x1 = poly[:, 0].min(), poly[:, 0].max()
        y0, y1 = poly[:, 1].min(), poly[:, 1].max()
        fx = 0.5 * (erf((x1 - p[:, 0]) / (_SQRT2 * su)) - erf((x0 - p[:, 0]) / (_SQRT2 * su)))
        fy = 0.5 * (erf((y1 - p[:, 1]) / (_SQRT2 * sv)) - erf((y0 - p[:, 1]) / (_SQRT2 * sv)))
        return fx * fy
    # General polygon: sum over 5 mm cells inside it (cell centres tested with a ray-casting point-in-polygon).
    step = 0.005
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0] + step / 2, hi[0], step), np.arange(lo[1] + step / 2, hi[1], step))
    cells = np.column_stack([gx.ravel(), gy.ravel()])
    cells = cells[points_in_polygon(cells, poly)]
    out = np.zeros(len(p))
    norm = step * step / (2 * math.pi * su * sv)
    for chunk in np.array_split(np.arange(len(cells)), max(1, len(cells) // 256)):
        d = p[:, None, :] - cells[None, chunk, :]
        out += np.exp(-0.5 * ((d[..., 0] / su) ** 2 + (d[..., 1] / sv) ** 2)).sum(axis=1) * norm
    return out


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Ray-casting test. points : (n, 2), poly : (m, 2) -> (n,) bool."""
    x, y = points[:, 0], points[:, 1]
    inside = np.zeros(len(points), dtype=bool)
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < x_cross)
    return inside


_IND, _CAP, _AC = INDUCTIVE.index, CAPACITIVE.index, AC.index  # columns of the simulated readings
DISPLAY_CLIP = 0.999  # display values above this are saturated: their raw value is unknown
ADDITIVE_SATURATED = -math.log1p(-DISPLAY_CLIP)  # 6.9: what additive_units gives a saturated reading


def additive_units(sensor: str, values: np.ndarray) -> np.ndarray:
    """Readings in units where objects add up: the inductive and AC display's soft saturation 1 − exp(−raw)
    (SensorModel.display) undone; a linear channel (capacitive) is already additive. A saturated top (display 1)
    stays flat at ADDITIVE_SATURATED."""
    if not by_name(sensor).saturating:
        return values
    return -np.log1p(-np.clip(values, 0.0, DISPLAY_CLIP))


@dataclass
class _Term:
    """One object's contribution to one sensor channel."""

    channel: int  # its index in scanner.channels.CHANNELS
    shape: str  # line | area | point
    geometry: np.ndarray
    strength: float
    sigma_u: float
    sigma_v: float
    normalise: float  # line integrals are divided by this (sqrt(2π)·sigma_v) to be dimensionless
    hysteresis: bool
    bbox: np.ndarray  # (2, 2) [[xmin, ymin], [xmax, ymax]] already grown by the cutoff


class SensorModel:
    """Forward model of the wall scanner for one wall (see the module docstring)."""

    def __init__(self, wall: Wall, config: SensorConfig | None = None) -> None:
        self.wall = wall
        self.config = config or SensorConfig()
        self.terms: list[_Term] = []
        live = [o for o in wall.objects if o.kind == "cable" and o.live]
        for obj in wall.objects:
            self._add_object(obj, live)

    # ------------------------------------------------------------------ model construction
    def _term(self, channel: int, shape: str, obj: WallObject, strength: float, su0: float, sv0: float,
              hysteresis: bool, power: float = 3.0, spread: float | None = None) -> None:
        if strength == 0.0:
            return
        cfg = self.config
        su, sv = _sigmas(obj.depth_m, su0, sv0, cfg.spread_per_depth if spread is None else spread)
        geometry = obj.geometry_m
        grow = _CUTOFF_SIGMAS * max(su, sv) + (cfg.hysteresis_m if hysteresis else 0.0)
        bbox = np.array([geometry.min(axis=0) - grow, geometry.max(axis=0) + grow])
        self.terms.append(_Term(channel, shape, geometry, strength * _depth_gain(obj.depth_m, cfg, power),
                                su, sv, math.sqrt(2 * math.pi) * sv, hysteresis, bbox))

    def _add_object(self, obj: WallObject, live: list[WallObject]) -> None:
        cfg = self.config
        su, sv = cfg.ind_sigma_u_m, cfg.ind_sigma_v_m
        coupling = 0.0
        if obj.is_metal and obj.kind != "cable" and live:
            probe = densify(obj.geometry_m, 0.01) if len(obj.geometry_m) > 1 else obj.geometry_m
            gap = min(float(distances_to_polyline(probe, c.geometry_m).min()) for c in live)
            coupling = math.exp(-gap / cfg.ac_coupling_length_m)
        if obj.kind == "pipe":
            size = (obj.diameter_m or 0.015) / 0.015
            self._term(_IND, "line", obj, _IND_LINE[obj.material or "copper"] * size, su, sv, True)
            water = 0.15 if obj.water_filled else 0.0
            material_cap = 0.08 if obj.is_metal else 0.03
            self._term(_CAP, "line", obj, (water + material_cap) * size, 2 * su, 2 * sv, False, power=1.5)
            self._term(_AC, "line", obj, cfg.ac_coupled_pipe_level * coupling * size, 1.5 * su, 1.5 * sv, False,
                       power=1.0)
        elif obj.kind == "cable":
            self._term(_IND, "line", obj, _IND_CABLE, su, sv, True)
            self._term(_CAP, "line", obj, 0.05, 2 * su, 2 * sv, False, power=1.5)
            if obj.live:
                self._term(_AC, "line", obj, cfg.ac_strength, cfg.ac_sigma_m, cfg.ac_sigma_m, False, power=1.5,
                           spread=cfg.ac_spread_per_depth)
        elif obj.kind in ("screw", "nail"):
            size = ((obj.diameter_m or 0.004) / 0.004) ** 2 * ((obj.length_m or 0.04) / 0.04)
            self._term(_IND, "point", obj, _IND_POINT * size, su, sv, True)
        elif obj.kind in AREA_KINDS:
            if obj.kind == "cavity":
                self._term(_CAP, "area", obj, -0.15, 2 * su, 2 * sv, False, power=1.0)
                return
            thickness = (obj.thickness_m or 0.002) / 0.002 if obj.kind == "plate" else 0.6
            self._term(_IND, "area", obj, _IND_AREA[obj.material or "wood"] * min(thickness, 2.0), su, sv, True)
            cap = 0.30 if obj.material == "wood" else 0.12
            self._term(_CAP, "area", obj, cap, 2 * su, 2 * sv, False, power=1.0)
            if obj.is_metal:
                self._term(_AC, "area", obj, cfg.ac_coupled_plate_level * coupling, 1.5 * su, 1.5 * sv, False,
                           power=1.0)

    # ------------------------------------------------------------------ evaluation
    def raw(self, xy: np.ndarray, motion: np.ndarray | None = None,
            drive_uv: np.ndarray | None = None) -> np.ndarray:
        """Noise-free raw signal (before saturation).

        xy : (n, 2) true sensor positions on the wall, metres; motion : (n, 2) unit direction of motion in
        wall coordinates (zeros when standing still; None = standing still); drive_uv : (n, 2) drive position
        (for the holder's metal), metres. Returns (n, 3) float64: inductive, capacitive, ac (raw units).
        """
        cfg = self.config
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        n = len(xy)
        out = np.zeros((n, 3))
        lagged = xy if motion is None else xy - cfg.hysteresis_m * np.asarray(motion, dtype=np.float64)
        for term in self.terms:
            where = lagged if term.hysteresis else xy
            near = np.flatnonzero(np.all((where >= term.bbox[0]) & (where <= term.bbox[1]), axis=1))
            if near.size == 0:
                continue
            p = where[near]
            if term.shape == "line":
                value = np.zeros(near.size)
                for a, b in zip(term.geometry[:-1], term.geometry[1:], strict=True):
                    value += _line_integral(p, a, b, term.sigma_u, term.sigma_v)
                value /= term.normalise
            elif term.shape == "area":
                value = _area_fraction(p, term.geometry, term.sigma_u, term.sigma_v)
            else:
                d = p - term.geometry[0]
                value = np.exp(-0.5 * ((d[:, 0] / term.sigma_u) ** 2 + (d[:, 1] / term.sigma_v) ** 2))
            out[near, term.channel] += term.strength * value
        if cfg.holder_metal_uv_m and drive_uv is not None:
            uv = np.asarray(drive_uv, dtype=np.float64).reshape(-1, 2)
            for line in cfg.holder_metal_uv_m:
                gap = distances_to_polyline(uv, np.asarray(line, dtype=np.float64))
                r = np.hypot(gap, cfg.holder_standoff_m)
                out[:, 0] += cfg.holder_strength * np.exp(-(r - cfg.holder_standoff_m) / cfg.holder_decay_m)
        return out

    def display(self, xy: np.ndarray, motion: np.ndarray | None = None, drive_uv: np.ndarray | None = None,
                rng: np.random.Generator | None = None) -> np.ndarray:
        """Readings in display units 0..1, (n, 3): inductive, capacitive, ac. Noise only if rng is given.

        The rng draws, in this order: run gain and offset of the inductive channel, then per-sample noise of
        the three channels — so one generator per pass reproduces a pass exactly.
        """
        cfg = self.config
        raw = self.raw(xy, motion, drive_uv)
        ind, cap, ac = raw[:, 0], raw[:, 1], raw[:, 2]
        if rng is not None:
            gain = 1.0 + cfg.run_gain_sigma * rng.standard_normal()
            offset = cfg.run_offset_sigma * rng.standard_normal()
            noise = rng.standard_normal((len(raw), 3))
            ind = ind * gain + offset + cfg.ind_noise * noise[:, 0]
            cap = cap + cfg.cap_noise * noise[:, 1]
            ac = ac + cfg.ac_noise * noise[:, 2]
        baseline = _CAP_BASELINE[self.wall.material]
        # Baselines keep the noise visible around "nothing here", as on the device.
        readings = np.column_stack([
            1.0 - np.exp(-np.maximum(ind + cfg.ind_baseline, 0.0)),
            np.clip(baseline + cap, 0.0, 1.0),
            1.0 - np.exp(-np.maximum(ac + cfg.ac_baseline, 0.0)),
        ])
        return np.clip(readings, 0.0, 1.0)

    def counts(self, xy: np.ndarray, motion: np.ndarray | None = None, drive_uv: np.ndarray | None = None,
               rng: np.random.Generator | None = None) -> np.ndarray:
        """Device counts 0..1000 (int64), (n, 3): what the scanner transmits."""
        return np.rint(self.display(xy, motion, drive_uv, rng) * COUNTS_FULL_SCALE).astype(np.int64)

