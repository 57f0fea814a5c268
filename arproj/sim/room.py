"""The room: walls as planes with their wall frames, floor and ceiling, printed targets, and exact ray casting.

Room frame: z up, floor at z = 0. A floor polygon in clockwise order (seen from above) gives wall i from
corner i to corner i+1; its wall frame has the origin at corner i on the floor (the lower-left corner seen
from the room), x along the wall, y up, z into the room. A room corner is simply two such planes.

Every drawable thing is a planar `Surface` with a local 2D coordinate system (metres): walls use wall
coordinates, floor and ceiling use room x, y, and a target uses its own board frame. Ray casting against
these planes is the ground truth the renderer is checked against.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.errors import InputError
from geometry.poses import invert, make_pose
from wallpose.pose import wall_frames

# Tolerances (metres) in one place.
RAY_EPS_M = 1e-9          # hits closer than this to the ray origin are ignored
BOUNDS_EPS_M = 1e-9       # a hit this far outside a rectangle's edge still counts (shared edges)

KIND_WALL, KIND_FLOOR, KIND_CEILING, KIND_TARGET = 0, 1, 2, 3
_SERIALS = itertools.count()


@dataclass
class Surface:
    """A planar piece of the scene. T_room_from_surface maps local (x, y, 0) to the room; normal is its z.

    extent_m: (w, h) of the local rectangle [0, w] × [0, h], or None for an unbounded plane (floor,
    ceiling: inside a closed room the nearest hit is always inside the polygon). albedo: (h, w, 3) uint8
    linear reflectance × 255, stretched over the extent; uv maps local xy to texture coordinates.
    """

    kind: int
    index: int
    T_room_from_surface: NDArray[np.float64]
    extent_m: tuple[float, float] | None
    albedo: NDArray[np.uint8]
    uv_scale: tuple[float, float]
    uv_offset: tuple[float, float]
    back_albedo: float | None = None       # reflectance of the back side (targets), None: one-sided
    polygon_xy: NDArray[np.float64] | None = None   # outline in local coordinates, for meshing
    serial: int = field(default_factory=lambda: next(_SERIALS), compare=False)  # unique: a cache key

    @property
    def normal(self) -> NDArray[np.float64]:
        return self.T_room_from_surface[:3, 2]

    @property
    def origin(self) -> NDArray[np.float64]:
        return self.T_room_from_surface[:3, 3]

    def outline_local(self) -> NDArray[np.float64]:
        """(k, 2) polygon in local coordinates (counter-clockwise)."""
        if self.polygon_xy is not None:
            return self.polygon_xy
        w, h = self.extent_m
        return np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])


@dataclass
class Wall:
    """A wall plane: name, size, pose of its wall frame in the room, reflectance and texture."""

    index: int
    name: str
    width_m: float
    height_m: float
    T_room_from_wall: NDArray[np.float64]
    albedo: float
    texture_kind: str
    texture: NDArray[np.uint8] = field(repr=False)   # (h, w, 3) linear reflectance × 255, top row = top

    @property
    def normal(self) -> NDArray[np.float64]:
        """Unit normal into the room (room frame)."""
        return self.T_room_from_wall[:3, 2]

    def to_room(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Room points (n, 3) of wall points xy (n, 2), metres."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return xy @ self.T_room_from_wall[:3, :2].T + self.T_room_from_wall[:3, 3]

    def from_room(self, points: ArrayLike) -> NDArray[np.float64]:
        """Wall coordinates (n, 3) (x, y, distance from the plane into the room) of room points (n, 3)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        T = invert(self.T_room_from_wall)
        return p @ T[:3, :3].T + T[:3, 3]


@dataclass
class Target:
    """A printed planar board (chessboard, ChArUco…) the cameras can photograph.

    texture: (h, w) or (h, w, 3) uint8 as printed (255 paper, 0 ink); size_m: (width, height) of the print.
    Target frame (OpenCV board convention): origin at the image's top-left corner, x along image columns,
    y along image rows (down), z = x × y pointing into the board; the printed side faces −z. Image pixel
    (col, row) covers [col, col+1] × [row, row+1] · (width / w, height / h). Treat a Target as immutable:
    to move a board, make a new one (its drawable surface is made once and cached).
    """

    texture: NDArray[np.uint8]
    size_m: tuple[float, float]
    T_room_from_target: NDArray[np.float64]
    paper_albedo: float = 0.85
    ink_albedo: float = 0.04

    def __post_init__(self) -> None:
        tex = np.asarray(self.texture)
        if tex.dtype != np.uint8 or tex.ndim not in (2, 3) or min(tex.shape[:2]) < 1:
            raise InputError(f"target texture must be a (h, w) or (h, w, 3) uint8 image, got "
                             f"{tex.dtype} {tex.shape}")
        w, h = (float(s) for s in self.size_m)
        if not (w > 0 and h > 0):
            raise InputError(f"target size_m must be positive, got {self.size_m!r}")
        self.size_m = (w, h)
        self.T_room_from_target = np.asarray(self.T_room_from_target, dtype=np.float64)
        if self.T_room_from_target.shape != (4, 4) or not np.all(np.isfinite(self.T_room_from_target)):
            raise InputError("target pose T_room_from_target must be a finite 4x4 matrix")

    def surface(self) -> Surface:
        """The board as a drawable surface (made once: its serial keys the renderer's and site's caches)."""
        cached = self.__dict__.get("_surface")
        if cached is None:
            cached = self.__dict__["_surface"] = self._make_surface()
        return cached

    def _make_surface(self) -> Surface:
        tex = self.texture if self.texture.ndim == 3 else np.repeat(self.texture[..., None], 3, axis=2)
        reflect = self.ink_albedo + (self.paper_albedo - self.ink_albedo) * tex.astype(np.float32) / 255.0
        albedo = np.clip(np.rint(reflect * 255.0), 0, 255).astype(np.uint8)
        w, h = self.size_m
        # Surface normal must point to the printed side (−z of the board), so flip the frame about x.
        T = self.T_room_from_target @ np.diag([1.0, -1.0, -1.0, 1.0])
        return Surface(KIND_TARGET, 0, T, (w, h), albedo, uv_scale=(1.0 / w, -1.0 / h), uv_offset=(0.0, 0.0),
                       back_albedo=0.5, polygon_xy=np.array([[0.0, -h], [w, -h], [w, 0.0], [0.0, 0.0]]))


def clockwise(corners: ArrayLike) -> NDArray[np.float64]:
    """The polygon in clockwise order (seen from above), starting at the same corner."""
    c = np.asarray(corners, dtype=np.float64)
    area2 = np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])
    return c if area2 < 0 else np.vstack([c[:1], c[:0:-1]])


def _polygon_is_simple(c: NDArray[np.float64]) -> bool:
    n = len(c)

    def cross(o: NDArray, a: NDArray, b: NDArray) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    for i in range(n):
        a, b = c[i], c[(i + 1) % n]
        if np.linalg.norm(b - a) < 1e-6:
            return False
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue
            p, q = c[j], c[(j + 1) % n]
            if (cross(a, b, p) * cross(a, b, q) < 0) and (cross(p, q, a) * cross(p, q, b) < 0):
                return False
    return True


def _texture(kind: str, albedo: float, contrast: float, size_px: tuple[int, int],
             rng: np.random.Generator) -> NDArray[np.uint8]:
    """(h, w, 3) uint8 reflectance × 255 of plaster (isotropic grain + cloudy variation), wallpaper
    (vertical stripes with a faint pattern) or a flat paint."""
    w, h = size_px
    if kind == "flat" or contrast == 0:
        return np.full((h, w, 3), round(albedo * 255), dtype=np.uint8)
    if kind == "plaster":
        grain = rng.standard_normal((h, w)).astype(np.float32)
        grain = cv2.GaussianBlur(grain, (0, 0), 0.8)
        grain /= grain.std() + 1e-9
        cloud = rng.standard_normal((max(h // 32, 2), max(w // 32, 2))).astype(np.float32)
        cloud = cv2.resize(cloud, (w, h), interpolation=cv2.INTER_CUBIC)
        cloud /= cloud.std() + 1e-9
        relative = contrast * (0.6 * grain + 0.4 * cloud)
        tint = np.array([1.0, 0.99, 0.96], dtype=np.float32)
    else:
        x = np.arange(w, dtype=np.float32)[None, :]
        y = np.arange(h, dtype=np.float32)[:, None]
        period = max(w / 40.0, 4.0)
        relative = contrast * (np.sign(np.sin(2 * np.pi * x / period)) * 0.7
                               + 0.3 * np.sin(2 * np.pi * x / period * 3) * np.cos(2 * np.pi * y / period * 2))
        relative = relative + 0.2 * contrast * rng.standard_normal((h, w)).astype(np.float32)
        tint = np.array([1.0, 0.93, 0.82], dtype=np.float32)
    reflect = albedo * (1.0 + relative)[..., None] * tint
    return np.clip(np.rint(reflect * 255.0), 0, 255).astype(np.uint8)


class Room:
    """Walls, floor and ceiling from a floor polygon and a height (scene section `room`)."""

    def __init__(self, config: dict, rng: np.random.Generator) -> None:
        corners = clockwise(config["corners_m"])
        if not _polygon_is_simple(corners):
            raise InputError(f"scene: room.corners_m = {np.asarray(config['corners_m']).tolist()} is not a "
                             "simple polygon (edges cross or corners repeat)")
        self.corners = corners
        self.height_m = float(config["height_m"])
        self.ambient_lux = float(config["ambient_lux"])
        self.walls: list[Wall] = []
        for i, (T, width) in enumerate(wall_frames(corners)):
            override = config["walls"].get(i, {})
            albedo = float(override.get("albedo", config["wall_albedo"]))
            kind = override.get("texture", config["wall_texture"])
            contrast = float(override.get("texture_contrast", config["texture_contrast"]))
            size = (max(2, round(width / config["texel_m"])), max(2, round(self.height_m / config["texel_m"])))
            texture = _texture(kind, albedo, contrast, size, rng)
            self.walls.append(Wall(i, f"wall{i}", width, self.height_m, T, albedo, kind, texture))
        self.floor_albedo = float(config["floor_albedo"])
        self.ceiling_albedo = float(config["ceiling_albedo"])

    def surfaces(self) -> list[Surface]:
        """Walls (in order), then floor and ceiling."""
        out = [Surface(KIND_WALL, w.index, w.T_room_from_wall, (w.width_m, w.height_m), w.texture,
                       uv_scale=(1.0 / w.width_m, -1.0 / w.height_m), uv_offset=(0.0, 1.0))
               for w in self.walls]
        flat = np.full((2, 2, 3), 0, dtype=np.uint8)
        floor_T = np.eye(4)
        ceiling_T = make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, self.height_m])
        out.append(Surface(KIND_FLOOR, 0, floor_T, None, flat + round(self.floor_albedo * 255),
                           (0.0, 0.0), (0.5, 0.5), polygon_xy=self.corners[::-1].copy()))
        out.append(Surface(KIND_CEILING, 0, ceiling_T, None, flat + round(self.ceiling_albedo * 255),
                           (0.0, 0.0), (0.5, 0.5), polygon_xy=self.corners * np.array([1.0, -1.0])))
        return out

    @property
    def convex(self) -> bool:
        """Whether the floor polygon is convex (then no wall can shadow another from the projector)."""
        c = self.corners
        d1 = np.roll(c, -1, axis=0) - c
        d2 = np.roll(d1, -1, axis=0)
        cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
        return bool(np.all(cross <= 1e-12) or np.all(cross >= -1e-12))

    def area_and_mean_albedo(self) -> tuple[float, float]:
        """Total surface (m²) of walls, floor and ceiling, and their area-weighted mean reflectance."""
        c = self.corners
        floor = 0.5 * abs(float(np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])))
        walls = [w.width_m * w.height_m for w in self.walls]
        area = 2.0 * floor + sum(walls)
        reflect = (floor * (self.floor_albedo + self.ceiling_albedo)
                   + sum(a * w.albedo for a, w in zip(walls, self.walls, strict=True)))
        return area, reflect / area

    def contains(self, points_xy: ArrayLike) -> NDArray[np.bool_]:
        """Whether floor points (n, 2) lie strictly inside the polygon."""
        from matplotlib.path import Path as MplPath

        return MplPath(self.corners).contains_points(np.asarray(points_xy, dtype=np.float64).reshape(-1, 2))

    def distance_to_walls(self, points_xy: ArrayLike) -> NDArray[np.float64]:
        """Smallest horizontal distance (n,) from floor points (n, 2) to any wall segment, metres."""
        p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        best = np.full(len(p), np.inf)
        n = len(self.corners)
        for i in range(n):
            a, b = self.corners[i], self.corners[(i + 1) % n]
            d = b - a
            s = np.clip(((p - a) @ d) / (d @ d), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(p - (a + s[:, None] * d), axis=1))
        return best


@dataclass
class RayHits:
    """Nearest hits of n rays: t (n,) ray parameter (distance for unit directions; inf: none), surface (n,)
    index into the surface list (-1: none), local (n, 2) coordinates on that surface (NaN: none),
    front (n,) whether the ray hit the side the normal points to."""

    t: NDArray[np.float64]
    surface: NDArray[np.int32]
    local: NDArray[np.float64]
    front: NDArray[np.bool_]


def raycast(surfaces: list[Surface], origin: ArrayLike, directions: ArrayLike) -> RayHits:
    """Exact nearest intersections of rays origin + t·d (t > 0) with the surfaces (double precision).

    origin : (3,) or (n, 3) room frame; directions : (n, 3) (any length; t is in units of their length).
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(origin, dtype=np.float64)
    single = o.shape == (3,)          # one origin for every ray: the numerator is one number per surface
    if not single:
        o = np.broadcast_to(o.reshape(-1, 3), d.shape)
    n = len(d)
    best_t = np.full(n, np.inf)
    best_s = np.full(n, -1, dtype=np.int32)
    best_xy = np.full((n, 2), np.nan)
    best_front = np.zeros(n, dtype=bool)
    for k, s in enumerate(surfaces):
        normal, p0 = s.normal, s.origin
        denom = d @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((p0 - o) @ normal) / denom
        ok = (t > RAY_EPS_M) & (t < best_t)
        if not ok.any():
            continue
        idx = np.nonzero(ok)[0]
        rel = (o - p0 if single else o[idx] - p0) + t[idx, None] * d[idx]
        xy = rel @ s.T_room_from_surface[:3, :2]
        if s.extent_m is not None:
            lo = np.array([0.0, -s.extent_m[1]]) if s.kind == KIND_TARGET else np.zeros(2)
            hi = lo + np.asarray(s.extent_m)
            inside = np.all((xy >= lo - BOUNDS_EPS_M) & (xy <= hi + BOUNDS_EPS_M), axis=1)
            idx, xy = idx[inside], xy[inside]
        best_t[idx] = t[idx]
        best_s[idx] = k
        best_xy[idx] = xy
        best_front[idx] = denom[idx] < 0
    return RayHits(best_t, best_s, best_xy, best_front)


def triangulate(polygon: NDArray[np.float64]) -> NDArray[np.int32]:
    """Ear-clipping triangulation (m, 3) of a simple counter-clockwise polygon (k, 2)."""
    idx = list(range(len(polygon)))
    tris = []

    def convex(a: NDArray, b: NDArray, c: NDArray) -> bool:
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) > 1e-12

    def inside(p: NDArray, a: NDArray, b: NDArray, c: NDArray) -> bool:
        return convex(a, b, p) and convex(b, c, p) and convex(c, a, p)

    guard = 0
    while len(idx) > 3 and guard < 10000:
        guard += 1
        for j in range(len(idx)):
            i0, i1, i2 = idx[j - 1], idx[j], idx[(j + 1) % len(idx)]
            a, b, c = polygon[i0], polygon[i1], polygon[i2]
            if not convex(a, b, c):
                continue
            if any(inside(polygon[m], a, b, c) for m in idx if m not in (i0, i1, i2)):
                continue
            tris.append((i0, i1, i2))
            idx.pop(j)
            break
    tris.append(tuple(idx))
    return np.asarray(tris, dtype=np.int32)
