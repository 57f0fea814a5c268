"""What is drawn on the wall: classes in distinct colours with a legend, safety bands (inferred stretches
dashed), DIN 18015-3 zones and the drill-point check (mapping.drill decides; this draws it).

Everything except the legend is rasterised in WALL coordinates into the texture of the projected mesh (so it
is pre-warped by the renderer with the projector's exact intrinsics, pose and distortion); the legend and
status text are drawn in the projector's own pixels, where text stays legible.

Safety band of an object: half-width = width/2 + BASE_SAFETY_MARGIN + Z95 · sqrt(σ_map² + σ_registration²):
its own size, a fixed margin for the drill, and a margin that grows with how well the object is mapped and
how well the projection is registered.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from arproj.session import tolerances as tol
from arproj.session.wallmap import WallMap, WallRoom
from mapping import drill
from mapping.drill import DrillVerdict, band_half_width_m, distance_to_object_m, safety_margin_m
from mapping.mapfile import MappedObject
from mapping.texture import dashed_polyline

__all__ = ["DrillVerdict", "band_half_width_m", "check_drill_point", "distance_to_object_m", "draw_map",
           "safety_margin_m"]

# Legend entries: (label, RGB colour, mapping classes drawn in that colour). Colours are bright (a projector
# adds light; dark colours vanish on a lit wall) and differ in hue and lightness (Okabe–Ito inspired), so
# red/green colour blindness still separates them; power lines are additionally hatched.
LEGEND: tuple[tuple[str, tuple[int, int, int], tuple[str, ...]], ...] = (
    ("power line / live", (255, 45, 45), ("power_line",)),
    ("metal pipe", (40, 150, 255), ("metal_pipe",)),
    ("other metal", (255, 215, 0), ("metal", "fastener")),
    ("non-metal: stud or water pipe", (0, 210, 140), ("non_metal",)),
    ("cavity", (215, 120, 255), ("cavity",)),
)
CLASS_COLOR: dict[str, tuple[int, int, int]] = {c: colour for _, colour, classes in LEGEND for c in classes}
# Drawing order: outlines under lines, power lines on top (the most dangerous object is never hidden).
DRAW_ORDER = ("cavity", "non_metal", "fastener", "metal", "metal_pipe", "power_line")

VERDICT_SAFE, VERDICT_KEEP_AWAY, VERDICT_UNKNOWN = drill.SAFE, drill.KEEP_AWAY, drill.UNKNOWN
# The drill marker's colours are never a class's: each is at least MIN_VERDICT_DELTA_E (CIEDE2000) from every
# class colour and from the other verdicts (keep-away is magenta, not the power line's red; unknown is orange,
# not "other metal"'s yellow), and the marker is a ringed cross outlined in black, a shape no class has.
VERDICT_COLOR = {VERDICT_SAFE: (150, 255, 45), VERDICT_KEEP_AWAY: (255, 0, 135), VERDICT_UNKNOWN: (240, 135, 0)}
MIN_VERDICT_DELTA_E = 20.0
MARKER_OUTLINE = (0, 0, 0)
INFERRED_DASH_M = 0.03  # inferred stretches: 3 cm dashes, 3 cm gaps


# -- DIN 18015-3 --------------------------------------------------------------------------------------------
def din_zones(x0: float, y0: float, x1: float, y1: float, openings: list[tuple[float, float, float, float]]
              | None = None, work_surface: bool = False) -> list[tuple[float, float, float, float]]:
    """Installation zones (x0, y0, x1, y1) of DIN 18015-3 on a wall spanning x0…x1, floor y0, ceiling y1.

    Horizontal zones 0.15–0.45 m below the ceiling and above the floor (and 0.90–1.30 m above the floor on
    walls with work surfaces); vertical zones 0.10–0.30 m beside the wall's corners and beside each opening
    (door, window: (x0, y0, x1, y1)), where electrical lines are to be laid. Lines may be anywhere in
    practice — the zones say where to expect them, not where they are absent.
    """
    zones = [
        (x0, y1 - tol.DIN_HORIZONTAL_TOP_FROM_CEILING_M[1], x1, y1 - tol.DIN_HORIZONTAL_TOP_FROM_CEILING_M[0]),
        (x0, y0 + tol.DIN_HORIZONTAL_BOTTOM_FROM_FLOOR_M[0], x1, y0 + tol.DIN_HORIZONTAL_BOTTOM_FROM_FLOOR_M[1]),
        (x0 + tol.DIN_VERTICAL_FROM_EDGE_M[0], y0, x0 + tol.DIN_VERTICAL_FROM_EDGE_M[1], y1),
        (x1 - tol.DIN_VERTICAL_FROM_EDGE_M[1], y0, x1 - tol.DIN_VERTICAL_FROM_EDGE_M[0], y1),
    ]
    if work_surface:
        zones.append((x0, y0 + tol.DIN_HORIZONTAL_MIDDLE_FROM_FLOOR_M[0], x1,
                      y0 + tol.DIN_HORIZONTAL_MIDDLE_FROM_FLOOR_M[1]))
    for ox0, _oy0, ox1, oy1 in openings or []:
        near, far = tol.DIN_VERTICAL_FROM_EDGE_M
        zones += [(ox0 - far, y0, ox0 - near, y1), (ox1 + near, y0, ox1 + far, y1)]
        zones.append((ox0 - far, oy1 + near, ox1 + far, oy1 + far))  # above the opening
    return zones


def room_zones(room: WallRoom) -> list[tuple[float, float, float, float]]:
    """The DIN 18015-3 zones (x0, y0, x1, y1) of a wall from its room: floor, ceiling and the room's corners
    (not the map's extent), its doors and windows, and a vertical strip through each known socket (its lines
    run vertically to it)."""
    x0, x1 = room.corner_x_m
    zones = din_zones(x0, room.floor_y_m, x1, room.ceiling_y_m, [o[1:] for o in room.openings])
    half = tol.DIN_SOCKET_HALF_WIDTH_M
    zones += [(float(sx) - half, room.floor_y_m, float(sx) + half, room.ceiling_y_m) for sx, _ in room.sockets]
    return zones


def zone_rects(wall_map: WallMap) -> list[tuple[float, float, float, float]]:
    """The DIN zones (x0, y0, x1, y1) of a map: its room's when it knows its room, else (nothing better known)
    the map's extent standing in for the room."""
    return room_zones(wall_map.room) if wall_map.room is not None else din_zones(*wall_map.extent)


def zone_mask(wall_map: WallMap, raster: WallRaster) -> NDArray[np.bool_]:
    """(h, w) True on the raster's texels inside a DIN zone (zone_rects) where the wall was not scanned."""
    h, w = raster.image.shape[:2]
    mask = np.zeros((h, w), dtype=np.uint8)
    for zx0, zy0, zx1, zy1 in zone_rects(wall_map):
        (c0, r0), (c1, r1) = raster.to_px(np.array([[zx0, zy1], [zx1, zy0]]))
        cv2.rectangle(mask, (round(c0), round(r0)), (round(c1), round(r1)), 1, -1)
    return mask.astype(bool) & ~scanned_mask(wall_map, raster)


def _label_zones(img: NDArray[np.uint8], zone: NDArray[np.bool_], raster: WallRaster,
                 rects: list[tuple[float, float, float, float]]) -> int:
    """Write DIN_ZONE_WORDS along each horizontal zone where a stretch of it wide enough is unscanned (vertical
    strips keep only the hatch); returns how many were written."""
    scale = max(0.4, 0.045 * raster.px_per_m / 22.0)  # letters ~4.5 cm high on the wall (Hershey: 22 px at scale 1)
    thickness = max(1, round(scale * 1.5))
    (tw, th), _ = cv2.getTextSize(tol.DIN_ZONE_WORDS, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    h, w = zone.shape
    written = 0
    for zx0, zy0, zx1, zy1 in rects:
        if zx1 - zx0 <= zy1 - zy0:
            continue
        (c0, r0), (c1, r1) = raster.to_px(np.array([[zx0, zy1], [zx1, zy0]]))
        r0, r1 = max(r0, 0.0), min(r1, h - 1.0)  # the part of the zone on the map
        cy = round(0.5 * (r0 + r1) + 0.5 * th)
        if r1 - r0 < th + 4 or not th <= cy < h:
            continue
        x = max(0, round(c0) + 4)
        while x + tw < min(w, round(c1)):
            if zone[cy - th:cy + 1, x:x + tw].all():
                cv2.putText(img, tol.DIN_ZONE_WORDS, (x, cy), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255, 255),
                            thickness, cv2.LINE_AA)
                written += 1
                x += 3 * tw
            else:
                x += max(1, tw // 4)
    return written


# -- wall raster ----------------------------------------------------------------------------------------------
@dataclass
class WallRaster:
    """An RGBA image laid over the wall: texel (row, col) covers x0 + col/s … and y1 - row/s … (s = px_per_m)."""

    image: NDArray[np.uint8]
    x0: float
    y1: float
    px_per_m: float
    zone_texels: int = 0  # texels drawn as a DIN zone (unscanned), and the zones' labels written
    zone_labels: int = 0
    # (h, w) True under what the craftsman must see (objects, their bands, labels, the drill marker, the
    # scale bar): the legend never covers it. None: nothing marked (e.g. the closed loop's check marks).
    busy: NDArray[np.bool_] | None = None
    classes: tuple[str, ...] = ()  # the classes drawn, in LEGEND order: the legend lists only these

    @property
    def width_m(self) -> float:
        return self.image.shape[1] / self.px_per_m

    @property
    def height_m(self) -> float:
        return self.image.shape[0] / self.px_per_m

    def to_px(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Wall (x, y) metres → (col, row) pixel-centre coordinates, as cv2 drawing takes them."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([(xy[:, 0] - self.x0) * self.px_per_m - 0.5,
                                (self.y1 - xy[:, 1]) * self.px_per_m - 0.5])

    def uv(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Texture coordinates (trimesh convention: v up) of wall points (n, 2)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([(xy[:, 0] - self.x0) / self.width_m,
                                1.0 - (self.y1 - xy[:, 1]) / self.height_m])


def empty_raster(extent: tuple[float, float, float, float], px_per_m: float = tol.OVERLAY_PX_PER_M) -> WallRaster:
    x0, y0, x1, y1 = extent
    px_per_m = min(px_per_m, tol.OVERLAY_MAX_TEXELS / max(x1 - x0, y1 - y0, 1e-6))
    w = max(1, int(np.ceil((x1 - x0) * px_per_m)))
    h = max(1, int(np.ceil((y1 - y0) * px_per_m)))
    return WallRaster(np.zeros((h, w, 4), dtype=np.uint8), x0, y1, px_per_m)


def scanned_mask(wall_map: WallMap, raster: WallRaster) -> NDArray[np.bool_]:
    """(h, w) True where the channels that rule objects out both covered the wall (the coverage layer);
    nothing without one."""
    h, w = raster.image.shape[:2]
    if wall_map.coverage is None:
        return np.zeros((h, w), dtype=bool)
    cov = wall_map.coverage
    looked = cov.covered_by_all()
    # the grid is axis-aligned with the wall: a texel's cell is (its row's grid row, its column's grid column)
    x = raster.x0 + (np.arange(w, dtype=np.float64) + 0.5) / raster.px_per_m
    y = raster.y1 - (np.arange(h, dtype=np.float64) + 0.5) / raster.px_per_m
    _, c, _ = cov.info.cell_of(np.column_stack([x, np.zeros(w)]))
    r, _, _ = cov.info.cell_of(np.column_stack([np.zeros(h), y]))
    col_in = (c >= 0) & (c < cov.info.width)
    row_in = (r >= 0) & (r < cov.info.height)
    out = np.zeros((h, w), dtype=bool)
    out[np.ix_(row_in, col_in)] = looked[np.ix_(r[row_in], c[col_in])]
    return out


def _sample_map_texture(wall_map: WallMap, raster: WallRaster) -> NDArray[np.uint8]:
    """The mapping's RGBA texture resampled onto the raster's texels (nearest: alpha marks coverage)."""
    assert wall_map.texture is not None and wall_map.uv_from_xy is not None
    h, w = raster.image.shape[:2]
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    x = raster.x0 + (cols + 0.5) / raster.px_per_m
    y = raster.y1 - (rows + 0.5) / raster.px_per_m
    A = wall_map.uv_from_xy
    u = A[0, 0] * x + A[0, 1] * y + A[0, 2]
    v = A[1, 0] * x + A[1, 1] * y + A[1, 2]
    th, tw = wall_map.texture.shape[:2]
    map_x = (u * tw - 0.5).astype(np.float32)
    map_y = ((1.0 - v) * th - 0.5).astype(np.float32)
    return cv2.remap(wall_map.texture, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=(0, 0, 0, 0))


def _blend(image: NDArray[np.uint8], layer: NDArray[np.uint8], mask: NDArray[np.bool_], opacity: float) -> None:
    rgb = image[..., :3]
    rgb[mask] = (rgb[mask] * (1.0 - opacity) + layer[mask] * opacity).astype(np.uint8)
    image[..., 3][mask] = 255


def _hatch(shape: tuple[int, int], period_px: int, origin: tuple[int, int] = (0, 0)) -> NDArray[np.bool_]:
    """Diagonal stripes over a (h, w) window whose top-left texel is origin (row, col) of the raster: the same
    stripes wherever the window lies."""
    rows = np.arange(origin[0], origin[0] + shape[0])[:, None]
    cols = np.arange(origin[1], origin[1] + shape[1])[None, :]
    return ((rows + cols) % period_px) < period_px // 2


def draw_map(wall_map: WallMap, registration_sigma_m: float, drill_xy: NDArray[np.float64] | None = None,
             show_zones: bool = True, px_per_m: float = tol.OVERLAY_PX_PER_M,
             clip: NDArray[np.float64] | None = None) -> WallRaster:
    """The projected picture in wall coordinates: dimmed map texture, DIN zones where unscanned, safety bands
    (margin at half brightness, the object itself at full colour), and the drill point in its verdict colour."""
    raster = empty_raster(wall_map.extent, px_per_m)
    img = raster.image
    h, w = img.shape[:2]
    s = raster.px_per_m
    if wall_map.texture is not None and wall_map.uv_from_xy is not None:
        sampled = _sample_map_texture(wall_map, raster)
        alpha = sampled[..., 3:4].astype(np.float32) / 255.0 * tol.MAP_LAYER_OPACITY  # the map's own alpha
        img[..., :3] = (img[..., :3] * (1.0 - alpha) + sampled[..., :3] * alpha).astype(np.uint8)
        img[..., 3][sampled[..., 3] > 0] = 255
    if show_zones:
        zones = zone_mask(wall_map, raster)
        _blend(img, np.full((h, w, 3), 255, np.uint8), zones & _hatch((h, w), max(4, int(0.04 * s))),
               tol.DIN_ZONE_OPACITY)
        raster.zone_labels = _label_zones(img, zones, raster, zone_rects(wall_map))
        raster.zone_texels = int(zones.sum())
    before = img.copy()
    for kind in DRAW_ORDER:
        for obj in (o for o in wall_map.objects if o.cls == kind):
            _draw_object(img, raster, obj, registration_sigma_m)
    labels = np.zeros((h, w), dtype=bool)  # where depth labels are written: none is written over another
    for obj in wall_map.objects:
        _draw_depth_label(img, raster, obj, registration_sigma_m, labels)
    if drill_xy is not None:
        check = check_drill_point(wall_map, drill_xy, registration_sigma_m)
        draw_drill_marker(img, raster.to_px(drill_xy)[0], s, VERDICT_COLOR[check.verdict])
    raster.busy = np.any(img != before, axis=2)
    raster.classes = tuple(sorted({o.cls for o in wall_map.objects}))
    inside = np.ones((h, w), dtype=np.uint8)
    if clip is not None:
        inside[:] = 0
        poly = np.round(raster.to_px(clip) * 16).astype(np.int32).reshape(-1, 1, 2)
        cv2.fillPoly(inside, [poly], 1, shift=4)
    _draw_scale_bar(img, raster, inside.astype(bool))
    if clip is not None:  # only the well-registered part is shown, its edge outlined in grey
        img[inside == 0] = 0
        raster.busy &= inside.astype(bool)
        cv2.polylines(img, [poly], True, (110, 110, 110, 255), max(2, round(0.004 * s)), cv2.LINE_AA, shift=4)
    return raster


def draw_drill_marker(img: NDArray[np.uint8], centre_px: NDArray[np.float64], px_per_m: float,
                      colour: tuple[int, int, int]) -> None:
    """The drill point: a ringed cross (a shape no class has: classes are lines, bands and hatched outlines)
    in its verdict colour, outlined in black so it stands out on every class colour and on the bare wall."""
    c = (round(float(centre_px[0])), round(float(centre_px[1])))
    r = 0.03 * px_per_m
    th = max(2, round(0.004 * px_per_m))
    outline = th + 2 * max(2, round(0.003 * px_per_m))
    for ink, width in (((*MARKER_OUTLINE, 255), outline), ((*colour, 255), th)):
        for dx, dy in ((r, 0.0), (0.0, r)):
            cv2.line(img, (round(c[0] - dx), round(c[1] - dy)), (round(c[0] + dx), round(c[1] + dy)), ink, width,
                     cv2.LINE_8)
        cv2.circle(img, c, round(0.6 * r), ink, width, cv2.LINE_8)


SCALE_BAR_LENGTHS_M = (0.1, 0.2, 0.5, 1.0)


def _draw_scale_bar(img: NDArray[np.uint8], raster: WallRaster, shown: NDArray[np.bool_]) -> None:
    """A scale bar in wall metres (the longest of SCALE_BAR_LENGTHS_M up to a quarter of the map's width,
    ticked every 10 cm, white outlined in black) where nothing else is drawn and the map is shown (shown:
    (h, w) mask), nearest the bottom left; added to raster.busy. Left out when there is no free place."""
    s = raster.px_per_m
    h, w = img.shape[:2]
    length_m = max([n for n in SCALE_BAR_LENGTHS_M if n <= 0.25 * raster.width_m] or [0.0])
    if length_m == 0.0:
        return
    text = f"{length_m * 100:.0f} cm" if length_m < 1.0 else f"{length_m:.0f} m"
    scale = DEPTH_LABEL_HEIGHT_M * s / 22.0
    thick = max(1, round(scale * 2))
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    bar_px, bar_h = round(length_m * s), max(3, round(0.008 * s))
    pad = max(2, round(0.01 * s))
    box_w, box_h = max(bar_px, tw) + 2 * pad, bar_h + th + 3 * pad
    assert raster.busy is not None
    found = free_box(raster.busy | ~shown, box_w, box_h, prefer=(0.0, 1.0), step=max(1, pad))
    if found is None:
        return
    x, y = found
    x0, y_bar = x + pad, y + box_h - pad - bar_h
    cv2.rectangle(img, (x0 - 2, y_bar - 2), (x0 + bar_px + 2, y_bar + bar_h + 2), (0, 0, 0, 255), -1)
    cv2.rectangle(img, (x0, y_bar), (x0 + bar_px, y_bar + bar_h), (255, 255, 255, 255), -1)
    for k in range(1, round(length_m / 0.1)):  # ticks every 10 cm
        tx = x0 + round(k * 0.1 * s)
        cv2.line(img, (tx, y_bar), (tx, y_bar + bar_h), (0, 0, 0, 255), max(1, bar_h // 3))
    org = (x0, y_bar - pad)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0, 255), thick + 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255, 255), thick, cv2.LINE_AA)
    raster.busy[max(0, y):min(h, y + box_h), max(0, x):min(w, x + box_w)] = True


def free_box(busy: NDArray[np.bool_], box_w: int, box_h: int, prefer: tuple[float, float] = (0.0, 0.0),
             step: int = 4, least: bool = False) -> tuple[int, int] | None:
    """Top-left (x, y) of a box_w × box_h box over no True pixel of busy (h, w), nearest the preferred corner
    prefer = (fx, fy) (fractions of the free range: (0, 0) top left, (1, 1) bottom right). None when no such
    box fits, or (least=True) the box over fewest busy pixels."""
    h, w = busy.shape
    if box_w > w or box_h > h:
        return None
    ys = np.arange(0, h - box_h + 1, step)
    xs = np.arange(0, w - box_w + 1, step)
    ys = np.unique(np.append(ys, h - box_h))
    xs = np.unique(np.append(xs, w - box_w))

    def box_sums(mask: NDArray[np.bool_]) -> NDArray[np.int64]:
        integral = cv2.integral(mask.astype(np.uint8), sdepth=cv2.CV_32S).astype(np.int64)
        Y, X = np.meshgrid(ys, xs, indexing="ij")
        return integral[Y + box_h, X + box_w] - integral[Y, X + box_w] - integral[Y + box_h, X] + integral[Y, X]

    hits = box_sums(busy)
    if not least and not (hits == 0).any():
        return None
    Y, X = np.meshgrid(ys, xs, indexing="ij")
    cost = np.hypot(X - prefer[0] * (w - box_w), Y - prefer[1] * (h - box_h)).astype(np.float64)
    cost += hits.astype(np.float64) * (4.0 * (w + h))  # one pixel covered weighs more than any distance
    i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return int(xs[j]), int(ys[i])


def _distance_field(raster: WallRaster, obj: MappedObject, reach_m: float, pts: NDArray[np.float64] | None = None
                    ) -> tuple[NDArray[np.float32], tuple[slice, slice]]:
    """Distance in metres from every texel centre to the object's centre line, point or outline edge (inf
    beyond reach_m of it): exact, so band edges are where the safety margin says, to half a texel. Over the
    window (rows, cols) of the raster that holds everything within reach_m (and an outline's inside); nothing
    outside it is within reach. pts: one part of the object (a measured or inferred stretch), default the whole."""
    h, w = raster.image.shape[:2]
    pts = obj.points_m if pts is None else pts
    segments = np.concatenate([pts, pts[:1]]) if obj.is_outline else pts
    pairs = [(segments[i], segments[i + 1]) for i in range(len(segments) - 1)] or [(pts[0], pts[0])]
    s = raster.px_per_m
    boxes = []
    for a, b in pairs:
        lo = np.minimum(a, b) - reach_m
        hi = np.maximum(a, b) + reach_m
        boxes.append((int(np.floor((raster.y1 - hi[1]) * s)), int(np.ceil((raster.y1 - lo[1]) * s)) + 1,
                      int(np.floor((lo[0] - raster.x0) * s)), int(np.ceil((hi[0] - raster.x0) * s)) + 1))
    wr0, wr1 = max(0, min(b[0] for b in boxes)), max(0, min(h, max(b[1] for b in boxes)))
    wc0, wc1 = max(0, min(b[2] for b in boxes)), max(0, min(w, max(b[3] for b in boxes)))
    wr1, wc1 = max(wr0, wr1), max(wc0, wc1)
    field = np.full((wr1 - wr0, wc1 - wc0), np.inf, dtype=np.float32)
    for (a, b), (r0, r1, c0, c1) in zip(pairs, boxes, strict=True):
        r0, r1, c0, c1 = max(0, r0), min(h, r1), max(0, c0), min(w, c1)
        if c0 >= c1 or r0 >= r1:
            continue
        x = raster.x0 + (np.arange(c0, c1) + 0.5) / s
        y = raster.y1 - (np.arange(r0, r1) + 0.5) / s
        px, py = np.meshgrid(x - a[0], y - a[1])
        ab = b - a
        t = np.clip((px * ab[0] + py * ab[1]) / max(float(ab @ ab), 1e-18), 0.0, 1.0)
        d = np.hypot(px - t * ab[0], py - t * ab[1]).astype(np.float32)
        sub = field[r0 - wr0:r1 - wr0, c0 - wc0:c1 - wc0]
        np.minimum(sub, d, out=sub)
    return field, (slice(wr0, wr1), slice(wc0, wc1))


def _paint(img: NDArray[np.uint8], mask: NDArray[np.bool_], colour: tuple[int, ...]) -> None:
    img[mask] = (*colour, 255)


def _draw_object(img: NDArray[np.uint8], raster: WallRaster, obj: MappedObject, registration_sigma_m: float
                 ) -> None:
    """An object, its safety band and (power lines, outlines) their hatching; each painted over the window of
    the raster its band reaches (the rest of the raster is beyond it)."""
    s = raster.px_per_m
    colour = CLASS_COLOR[obj.cls]
    margin_colour = tuple(int(0.5 * c) for c in colour)
    band = band_half_width_m(obj, registration_sigma_m)
    if obj.is_outline:
        d, window = _distance_field(raster, obj, band + 2.0 / s)
        part_img = img[window]
        origin = (window[0].start, window[1].start)
        _paint(part_img, d <= band - 0.5 * obj.width_m, margin_colour)
        inside = np.zeros(d.shape, dtype=np.uint8)
        pts = np.round(raster.to_px(obj.points_m) * 16).astype(np.int32) - 16 * np.array(origin[::-1], np.int32)
        cv2.fillPoly(inside, [pts.reshape(-1, 1, 2)], 1, shift=4)
        hatch = inside.astype(bool) & _hatch(inside.shape, max(6, int(0.05 * s)), origin)
        _blend(part_img, np.full((*inside.shape, 3), colour, np.uint8), hatch, 0.5)
        _paint(part_img, d <= max(0.5 * obj.width_m, 2.0 / s), colour)
        return
    for part in obj.parts(measured=True):
        d, window = _distance_field(raster, obj, band + 2.0 / s, part)
        part_img = img[window]
        _paint(part_img, d <= band, margin_colour)
        if obj.cls == "power_line":  # hatch the margin too: "live" must not rely on colour alone
            _paint(part_img, (d <= band) & _hatch(d.shape, max(6, int(0.02 * s)),
                                                  (window[0].start, window[1].start)),
                   tuple(int(0.8 * c) for c in colour))
        _paint(part_img, d <= max(0.5 * obj.width_m, 1.0 / s), colour)
    for part in obj.parts(measured=False):
        # Inferred, not measured: the band's outline and a dashed centre line, so it never reads as a scan.
        d, window = _distance_field(raster, obj, band + 2.0 / s, part)
        edge = (d <= band) & (d > band - max(2.0 / s, 0.003))
        _paint(img[window], edge, margin_colour)
        thick = max(2, round(max(obj.width_m, 0.004) * s))
        dashed_polyline(img, raster.to_px(part), (*colour, 255), thick, INFERRED_DASH_M * s)


DEPTH_LABEL_HEIGHT_M = 0.025  # text 2.5 cm high on the wall: legible from a few metres
DEPTH_UNKNOWN_WORDS = "depth unknown"


def _draw_depth_label(img: NDArray[np.uint8], raster: WallRaster, obj: MappedObject,
                      registration_sigma_m: float, labels: NDArray[np.bool_]) -> None:
    """The object's depth ("32 mm deep", or "depth unknown" when the scan could not tell it) beside the middle
    of its longest measured stretch, outside its band; an outline's (a cavity's) at its centre."""
    parts = obj.parts(measured=True)
    if not parts:
        return
    part = max(parts, key=lambda p: float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0)
    if obj.is_outline:
        anchor, normal = obj.points_m.mean(axis=0), np.zeros(2)
    elif len(part) == 1:
        anchor, normal = part[0], np.array([1.0, 1.0]) / np.sqrt(2.0)
    else:
        seg = np.diff(part, axis=0)
        lengths = np.linalg.norm(seg, axis=1)
        k = int(np.searchsorted(np.cumsum(lengths), 0.5 * lengths.sum()))
        k = min(k, len(seg) - 1)
        direction = seg[k] / max(float(lengths[k]), 1e-12)
        anchor = part[k] + 0.5 * seg[k]
        normal = np.array([-direction[1], direction[0]])
        if normal[1] < 0 or (abs(normal[1]) < 1e-9 and normal[0] < 0):
            normal = -normal  # labels above or right of the line
    text = DEPTH_UNKNOWN_WORDS if obj.depth_m is None else f"{obj.depth_m * 1000:.0f} mm deep"
    s = raster.px_per_m
    scale = DEPTH_LABEL_HEIGHT_M * s / 22.0  # FONT_HERSHEY_SIMPLEX is ~22 px high at scale 1
    thick = max(1, round(scale * 2))
    (tw, th), baseline = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    # the text's half-extent along the normal (with descenders and its dark outline) plus 3 mm of air
    half_px = 0.5 * (abs(normal[1]) * (th + baseline) + abs(normal[0]) * tw) + thick + 3
    offset = 0.0 if obj.is_outline else band_half_width_m(obj, registration_sigma_m) + 0.003 + half_px / s
    h, w = labels.shape
    for side in (normal, -normal):  # the other side of the line when a label is already there
        c, r = raster.to_px((anchor + side * offset)[None])[0]
        org = (round(c - tw / 2), round(r + (th - baseline) / 2))
        box = (slice(max(0, org[1] - th - thick - 2), max(0, min(h, org[1] + baseline + thick + 2))),
               slice(max(0, org[0] - thick - 2), max(0, min(w, org[0] + tw + thick + 2))))
        if not labels[box].any():
            break
    else:
        return  # both sides taken (a cluster of small objects): one label there is enough to read
    labels[box] = True
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0, 255), thick + 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (*CLASS_COLOR[obj.cls], 255), thick, cv2.LINE_AA)


# -- drill-point check ----------------------------------------------------------------------------------------
def check_drill_point(wall_map: WallMap, xy: NDArray[np.float64], registration_sigma_m: float,
                      drill_radius_m: float = drill.DRILL_RADIUS_M) -> DrillVerdict:
    """mapping.drill's verdict for drilling at wall point xy (metres) on this map; without a coverage layer
    every point is unknown."""
    if wall_map.coverage is None:
        return DrillVerdict(float(xy[0]), float(xy[1]), drill.UNKNOWN, "no coverage layer: nothing was looked at",
                            None, float("inf"), float("inf"))
    return drill.check_point(xy, wall_map.objects, wall_map.coverage, wall_map.coverage.wall_bounds,
                             registration_sigma_m, drill_radius_m)


# -- projector-space parts: legend and status ---------------------------------------------------------------
@dataclass
class LegendLayout:
    """Where the legend goes in a frame and what it says: entries (text, colour, is a class swatch), its box
    (x, y, width, height) in frame pixels, and where it was put ("free wall", "outside the map", "over the map":
    no free place was large enough)."""

    entries: list[tuple[str, tuple[int, int, int], bool]]
    box: tuple[int, int, int, int]
    placed: str
    scale: float
    thickness: int
    line_h: int


def frame_layers(alpha: NDArray[np.uint8]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """(busy, mapped) masks of a rendered frame from its alpha channel (projection.textured_mesh encodes the
    raster's busy texels as BUSY_ALPHA, the rest of the map as MAP_ALPHA): what the legend must not cover,
    and where the map is at all."""
    return alpha >= (BUSY_ALPHA + MAP_ALPHA) // 2, alpha >= MAP_ALPHA // 2


BUSY_ALPHA, MAP_ALPHA = 255, 96


# The map frame's status lines, in the craftsman's words (the figures behind them go to the log). One place for
# the one-wall session and the room session alike.
def say_accuracy(bound_m: float, walls: list[int] | None = None) -> str:
    """How far the picture may be off (95 %), and on which walls when there are several."""
    where = "" if walls is None else " on wall " + ", ".join(str(i) for i in walls)
    mm = bound_m * 1000
    return f"Picture accurate to {mm:.1f} mm{where}." if mm < 10 else f"Picture accurate to {mm:.0f} mm{where}."


def say_clipped(share: float) -> str:
    return f"Shown only where accurate enough ({100 * share:.0f} % of the map, outlined); outside it nothing is known."


def say_zones() -> str:
    return f"Hatched: not scanned ({tol.DIN_ZONE_WORDS}). Do not drill there."


def say_dark_walls(walls: list[int]) -> str:
    return "Wall " + ", ".join(str(i) for i in walls) + " not checked: left dark. Do not drill by it."


def say_drill(check: DrillVerdict) -> str:
    return f"Drill point - {check.message}"


def legend_layout(shape: tuple[int, ...], lines: list[str] | tuple[str, ...] = (),
                  present: tuple[str, ...] | list[str] | None = None, busy: NDArray[np.bool_] | None = None,
                  mapped: NDArray[np.bool_] | None = None, corner: str = "top-left",
                  at: tuple[int, int] | None = None) -> LegendLayout:
    """The legend of a frame of `shape`: the classes present (None: every class) and the status lines (wrapped
    to stay inside the frame), placed over no busy pixel (objects, bands, labels, the drill marker), else
    outside the map, nearest the preferred corner (at: top-left corner given, e.g. to redraw a recorded one)."""
    h, w = shape[:2]
    scale = max(0.45, min(w, h) / 1400.0)
    thickness = max(1, round(scale * 2))
    line_h = int(34 * scale)
    pad = int(12 * scale)
    classes = [(label, colour, True) for label, colour, kinds in LEGEND
               if present is None or any(k in present for k in kinds)]
    text_w = w - 2 * pad - int(60 * scale)
    status = [(part, (255, 255, 255), False) for text in lines for part in _wrap(text, text_w, scale, thickness)]
    entries = classes + status
    widest = max((cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)[0][0] for t, _, _ in entries),
                 default=0)
    box_w = min(w - 2, int(widest + 60 * scale))
    box_h = min(h - 2, line_h * len(entries) + int(12 * scale))
    prefer = (0.0 if "left" in corner else 1.0, 0.0 if "top" in corner else 1.0)
    step = max(2, pad // 2)
    # A margin round the box: the legend never touches an object's band.
    grow = np.ones((2 * pad + 1, 2 * pad + 1), np.uint8)
    placed, found = "free wall", at
    if busy is not None and at is None:
        found = free_box(cv2.dilate(busy.astype(np.uint8), grow).astype(bool), box_w, box_h, prefer, step)
        if found is None and mapped is not None:
            placed = "outside the map"
            found = free_box(mapped, box_w, box_h, prefer, step)
        if found is None:
            placed = "over the map"
            found = free_box(busy, box_w, box_h, prefer, step, least=True)
    if found is None:  # nothing known about the frame: the preferred corner
        found = (pad if prefer[0] == 0.0 else w - box_w - pad, pad if prefer[1] == 0.0 else h - box_h - pad)
    return LegendLayout(entries, (found[0], found[1], box_w, box_h), placed, scale, thickness, line_h)


def draw_legend(frame: NDArray[np.uint8], lines: list[str] | tuple[str, ...] = (),
                present: tuple[str, ...] | list[str] | None = None, busy: NDArray[np.bool_] | None = None,
                mapped: NDArray[np.bool_] | None = None, corner: str = "top-left") -> NDArray[np.uint8]:
    """Draws the class legend (the classes present) and status lines into an RGB frame (h, w, 3) in place,
    where legend_layout puts it; returns the frame."""
    draw_layout(frame, legend_layout(frame.shape, lines, present, busy, mapped, corner))
    return frame


def draw_layout(frame: NDArray[np.uint8], layout: LegendLayout) -> None:
    x, y, box_w, box_h = layout.box
    scale, line_h = layout.scale, layout.line_h
    cv2.rectangle(frame, (x, y), (x + box_w, y + box_h), (30, 30, 30), -1)
    for i, (text, colour, swatch) in enumerate(layout.entries):
        ty = y + int(8 * scale) + line_h * i
        if swatch:
            cv2.rectangle(frame, (x + int(8 * scale), ty + int(6 * scale)),
                          (x + int(38 * scale), ty + line_h - int(6 * scale)), colour, -1)
        cv2.putText(frame, text, (x + int(48 * scale), ty + line_h - int(9 * scale)), cv2.FONT_HERSHEY_SIMPLEX,
                    scale, colour, layout.thickness, cv2.LINE_AA)


def _wrap(text: str, max_width_px: int, scale: float, thickness: int) -> list[str]:
    """text broken at spaces into lines no wider than max_width_px (a single over-long word stays whole)."""
    lines: list[str] = []
    for word in text.split():
        trial = f"{lines[-1]} {word}" if lines else word
        if lines and cv2.getTextSize(trial, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)[0][0] <= max_width_px:
            lines[-1] = trial
        else:
            lines.append(word)
    return lines or [""]


def warning_frame(width: int, height: int, messages: list[str]) -> NDArray[np.uint8]:
    """The frame projected instead of the map when the safety gate closes: a red-bordered warning whose title
    and messages (the gate's words for the craftsman) are wrapped and, if need be, shrunk to stay inside it."""
    frame = np.zeros((height, width, 3), dtype=np.uint8)
    border = max(8, min(width, height) // 40)
    cv2.rectangle(frame, (border // 2, border // 2), (width - border // 2, height - border // 2),
                  (255, 40, 40), border)
    inner_w = width - 2 * border - 2 * max(4, width // 40)
    inner_h = height - 2 * border - 2 * max(4, height // 40)
    texts = [("MAP HIDDEN", 1.0, (255, 60, 60)), ("Do not drill by this picture.", 0.6, (255, 230, 120))]
    texts += [(m, 0.55, (255, 255, 255)) for m in messages[:6]]
    scale = max(0.6, min(width, height) / 500.0)
    while True:  # shrink until every wrapped line fits the frame's height (widths are wrapped to fit)
        laid = []
        for text, rel, colour in texts:
            s = scale * rel
            t = max(1, round(s * 2))
            laid.extend((line, s, t, colour) for line in _wrap(text, inner_w, s, t))
        heights = [int(cv2.getTextSize(line, cv2.FONT_HERSHEY_SIMPLEX, s, t)[0][1] * 1.9) + 4
                   for line, s, t, _ in laid]
        widest = max(cv2.getTextSize(line, cv2.FONT_HERSHEY_SIMPLEX, s, t)[0][0] for line, s, t, _ in laid)
        if (sum(heights) <= inner_h and widest <= inner_w) or scale < 0.2:
            break
        scale *= 0.85
    y = (height - sum(heights)) // 2
    for (line, s, t, colour), step in zip(laid, heights, strict=True):
        size = cv2.getTextSize(line, cv2.FONT_HERSHEY_SIMPLEX, s, t)[0]
        y += step
        cv2.putText(frame, line, ((width - size[0]) // 2, y - (step - size[1]) // 2), cv2.FONT_HERSHEY_SIMPLEX,
                    s, colour, t, cv2.LINE_AA)
    return frame
