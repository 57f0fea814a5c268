"""The projected pattern: a checkerboard with a few coded (ArUco) marker blocks.

Every interior X-corner of the checkerboard is found with subpixel accuracy (an X-junction keeps its position
under blur and perspective); the marker blocks name where in the board a camera is looking, so corners are
matched between both cameras and the projector without ambiguity even when only part of the pattern lands on
the wall. Each corner's projector pixel is known exactly from the layout.

Pixel convention (as geometry.Intrinsics): pixel centres at integer coordinates, so the corner between
pixel columns x-1 and x lies at x - 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import rotation_about, transform_points
from wallpose import limits

MARKER_DICTIONARY = cv2.aruco.DICT_4X4_100
MARKER_CELLS = 6  # a 4x4 ArUco marker with its one-cell black border


@dataclass(frozen=True)
class CheckerPattern:
    """Layout of the pattern in the projector image.

    projector_size: (width, height) px; square_px: side of one checker square; origin_px: (x, y) of the board's
    top-left pixel; cols, rows: squares across and down; block: side of a marker block in squares;
    marker_blocks: (k, 2) int (i, j) of each block's top-left square, marker id = its row index;
    white: grey level of the white squares (the rest of the projector image is black);
    camera_px_per_projector_px: expected scale of the pattern in the camera images (a hint for the marker
    detector, which then skips candidates much smaller than a marker).
    """

    projector_size: tuple[int, int]
    square_px: int
    origin_px: tuple[int, int]
    cols: int
    rows: int
    block: int
    marker_blocks: NDArray[np.int64] = field(repr=False)
    white: int = 255
    camera_px_per_projector_px: float = 1.0

    def __post_init__(self) -> None:
        w, h = self.projector_size
        ox, oy = self.origin_px
        if self.square_px < 4 or self.cols < 3 or self.rows < 3:
            raise InputError(f"pattern too small: {self.cols}x{self.rows} squares of {self.square_px} px",
                             "use at least 3x3 squares of 4 px or more")
        if ox < 0 or oy < 0 or ox + self.cols * self.square_px > w or oy + self.rows * self.square_px > h:
            raise InputError(f"pattern of {self.cols}x{self.rows} squares of {self.square_px} px at {ox},{oy} "
                             f"does not fit the {w}x{h} projector image")

    # --- geometry ------------------------------------------------------------------------------------------
    @property
    def marker_px(self) -> int:
        """Side of a marker in projector pixels: whole cells, with at least one cell of white around it."""
        cell = max(1, (self.block * self.square_px) // (MARKER_CELLS + 2))
        return MARKER_CELLS * cell

    @cached_property
    def corner_grid(self) -> NDArray[np.int64]:
        """(n, 2) int grid indices (i, j) of the usable X-corners; corner id = row index."""
        i, j = np.meshgrid(np.arange(1, self.cols), np.arange(1, self.rows))
        ij = np.column_stack([i.ravel(), j.ravel()])
        keep = np.ones(len(ij), dtype=bool)
        for bi, bj in self.marker_blocks:
            keep &= ~((ij[:, 0] >= bi) & (ij[:, 0] <= bi + self.block)
                      & (ij[:, 1] >= bj) & (ij[:, 1] <= bj + self.block))
        return ij[keep]

    @property
    def n_corners(self) -> int:
        return len(self.corner_grid)

    @cached_property
    def corner_projector_px(self) -> NDArray[np.float64]:
        """(n, 2) exact projector pixel of every corner."""
        s = self.square_px
        return np.column_stack([self.origin_px[0] + self.corner_grid[:, 0] * s - 0.5,
                                self.origin_px[1] + self.corner_grid[:, 1] * s - 0.5]).astype(np.float64)

    @cached_property
    def corner_parity(self) -> NDArray[np.bool_]:
        """(n,) True where the squares up-left and down-right of the corner are black."""
        return (self.corner_grid.sum(axis=1) % 2) == 0

    def marker_origin_px(self, marker_id: int) -> tuple[int, int]:
        bi, bj = self.marker_blocks[marker_id]
        offset = (self.block * self.square_px - self.marker_px) // 2
        return (self.origin_px[0] + bi * self.square_px + offset, self.origin_px[1] + bj * self.square_px + offset)

    def marker_corners_px(self, marker_id: int) -> NDArray[np.float64]:
        """(4, 2) projector pixels of a marker's outer corners in ArUco order (TL, TR, BR, BL)."""
        x, y = self.marker_origin_px(marker_id)
        m = self.marker_px
        return np.array([[x, y], [x + m, y], [x + m, y + m], [x, y + m]], dtype=np.float64) - 0.5

    @property
    def centre_px(self) -> NDArray[np.float64]:
        """(2,) projector pixel at the board's centre (where 'distance at the pattern's centre' is taken)."""
        return np.array([self.origin_px[0] + self.cols * self.square_px / 2.0 - 0.5,
                         self.origin_px[1] + self.rows * self.square_px / 2.0 - 0.5])

    def square_corners_px(self, i: int, j: int) -> NDArray[np.float64]:
        """(4, 2) projector pixels of square (i, j)'s corners."""
        s = self.square_px
        x, y = self.origin_px[0] + i * s - 0.5, self.origin_px[1] + j * s - 0.5
        return np.array([[x, y], [x + s, y], [x + s, y + s], [x, y + s]], dtype=np.float64)

    # --- image ---------------------------------------------------------------------------------------------
    def image(self) -> NDArray[np.uint8]:
        """(height, width) uint8 projector image: the board on black."""
        w, h = self.projector_size
        s = self.square_px
        img = np.zeros((h, w), dtype=np.uint8)
        i, j = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        board = np.where((i + j) % 2 == 1, self.white, 0).astype(np.uint8)
        board = np.repeat(np.repeat(board, s, axis=0), s, axis=1)
        ox, oy = self.origin_px
        img[oy:oy + self.rows * s, ox:ox + self.cols * s] = board
        dictionary = cv2.aruco.getPredefinedDictionary(MARKER_DICTIONARY)
        for marker_id, (bi, bj) in enumerate(self.marker_blocks):
            x0, y0 = ox + bi * s, oy + bj * s
            img[y0:y0 + self.block * s, x0:x0 + self.block * s] = self.white
            marker = cv2.aruco.generateImageMarker(dictionary, marker_id, self.marker_px, borderBits=1)
            mx, my = self.marker_origin_px(marker_id)
            img[my:my + self.marker_px, mx:mx + self.marker_px] = np.where(marker > 127, self.white, 0)
        return img


def layout(projector_size: tuple[int, int], square_px: int, region_px: tuple[int, int, int, int],
           block: int, white: int = 255, camera_px_per_projector_px: float = 1.0) -> CheckerPattern:
    """A pattern filling region_px = (x0, y0, x1, y1) with squares of square_px and a lattice of marker blocks."""
    x0, y0, x1, y1 = region_px
    cols, rows = (x1 - x0) // square_px, (y1 - y0) // square_px
    if cols < block + 2 or rows < block + 2:
        raise InputError(f"the pattern region {x1 - x0}x{y1 - y0} px holds only {cols}x{rows} squares of "
                         f"{square_px} px", "move closer to the wall or use a smaller square size")
    origin = (x0 + ((x1 - x0) - cols * square_px) // 2, y0 + ((y1 - y0) - rows * square_px) // 2)
    step = block + limits.MARKER_SPACING_SQUARES

    def starts(n: int) -> list[int]:
        count = max(1, (n - 2 + limits.MARKER_SPACING_SQUARES) // step)
        used = count * block + (count - 1) * limits.MARKER_SPACING_SQUARES
        first = max(1, (n - used) // 2)
        return [first + k * step for k in range(count) if first + k * step + block <= n - 1]

    blocks = np.array([(bi, bj) for bj in starts(rows) for bi in starts(cols)], dtype=np.int64).reshape(-1, 2)
    dictionary_size = 100
    if len(blocks) > dictionary_size:
        blocks = blocks[:dictionary_size]
    return CheckerPattern(projector_size=projector_size, square_px=square_px, origin_px=origin, cols=cols,
                          rows=rows, block=block, marker_blocks=blocks, white=white,
                          camera_px_per_projector_px=camera_px_per_projector_px)


def _plane_hit(origin: NDArray, dirs: NDArray, normal: NDArray, point: NDArray) -> tuple[NDArray, NDArray]:
    """Points where rays origin + lam * dirs meet the plane through point with normal, and lam."""
    lam = ((point - origin) @ normal) / (dirs @ normal)
    return origin + lam[:, None] * dirs, lam


def choose_pattern(views: object, distance_m: float, incidence_deg: float = 0.0,
                   white: int = 255) -> CheckerPattern:
    """Pick square size, marker size and extent for a wall about distance_m ahead of the projector.

    The wall is modelled as a plane at distance_m along the projector's axis, turned by incidence_deg about the
    projector's vertical axis. The pattern covers the largest rectangle of the projector image that both
    cameras see (with a margin); squares are as small as the cameras can still resolve there, so there are as
    many corners as the optics allow. views: a ViewRig.
    """
    if not (0.2 <= distance_m <= 20.0):
        raise InputError(f"distance {distance_m} m is outside 0.2–20 m", "pass the approximate wall distance")
    proj: Intrinsics = views.projector  # type: ignore[attr-defined]
    w, h = proj.width, proj.height
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 33), np.linspace(0, h - 1, 21))
    px = np.column_stack([gx.ravel(), gy.ravel()])
    rays = proj.rays(px)
    normal = rotation_about([0, 1, 0], np.radians(incidence_deg)) @ np.array([0.0, 0.0, -1.0])
    hits, lam = _plane_hit(np.zeros(3), rays, normal, np.array([0.0, 0.0, distance_m]))
    visible = lam > 0
    ratios = np.full(len(px), np.inf)
    T_left_from_projector = views.T_camera_left_from_projector  # type: ignore[attr-defined]
    T_right_from_left = views.T_camera_right_from_camera_left  # type: ignore[attr-defined]
    # camera pixels per projector pixel, from a one-pixel step in x and in y
    hits_dx, _ = _plane_hit(np.zeros(3), proj.rays(px + np.array([1.0, 0.0])), normal, np.array([0.0, 0.0, distance_m]))
    hits_dy, _ = _plane_hit(np.zeros(3), proj.rays(px + np.array([0.0, 1.0])), normal, np.array([0.0, 0.0, distance_m]))
    for T_cam_from_projector, cam in (
        (T_left_from_projector, views.camera_left),  # type: ignore[attr-defined]
        (T_right_from_left @ T_left_from_projector, views.camera_right),  # type: ignore[attr-defined]
    ):
        pc = transform_points(T_cam_from_projector, hits)
        in_front = pc[:, 2] > 0.05
        uv = cam.project(np.where(in_front[:, None], pc, [0.0, 0.0, 1.0]))
        margin = 0.03 * cam.width
        visible &= in_front & (uv[:, 0] > margin) & (uv[:, 0] < cam.width - margin) \
            & (uv[:, 1] > margin) & (uv[:, 1] < cam.height - margin)
        du = np.linalg.norm(cam.project(transform_points(T_cam_from_projector, hits_dx)) - uv, axis=1)
        dv = np.linalg.norm(cam.project(transform_points(T_cam_from_projector, hits_dy)) - uv, axis=1)
        ratios = np.minimum(ratios, np.minimum(du, dv))
    mask = visible.reshape(gy.shape)
    if mask.sum() < 4:
        raise InputError(f"at {distance_m:.2f} m and {incidence_deg:.0f}° the cameras do not see the projector's image",
                         "check the rig calibration and the head angles")
    r0, r1, c0, c1 = _largest_rectangle(mask)
    margin_x, margin_y = limits.PATTERN_MARGIN_FRACTION * w, limits.PATTERN_MARGIN_FRACTION * h
    region = (int(max(gx[0, c0], margin_x)), int(max(gy[r0, 0], margin_y)),
              int(min(gx[0, c1], w - margin_x)), int(min(gy[r1, 0], h - margin_y)))
    ratio = float(np.min(ratios[visible]))
    square = int(np.ceil(limits.MIN_SQUARE_CAMERA_PX / max(ratio, 1e-3)))
    square = max(square, 8)
    cam_width = views.camera_left.width  # type: ignore[attr-defined]
    detect_scale = min(1.0, limits.MARKER_DETECT_MAX_PX / cam_width)
    marker_fraction = MARKER_CELLS / (MARKER_CELLS + 2)
    block = int(np.ceil(limits.MIN_MARKER_DETECT_PX / (marker_fraction * square * ratio * detect_scale)))
    return layout((w, h), square, region, max(block, 2), white=white, camera_px_per_projector_px=ratio)


def _largest_rectangle(mask: NDArray[np.bool_]) -> tuple[int, int, int, int]:
    """(r0, r1, c0, c1) inclusive bounds of the largest-area all-True rectangle in a small boolean grid."""
    rows, cols = mask.shape
    best, best_area = (0, 0, 0, 0), -1.0
    for r0 in range(rows):
        run = np.ones(cols, dtype=bool)
        for r1 in range(r0, rows):
            run &= mask[r1]
            c = 0
            while c < cols:
                if not run[c]:
                    c += 1
                    continue
                c_end = c
                while c_end + 1 < cols and run[c_end + 1]:
                    c_end += 1
                area = (r1 - r0) * (c_end - c)
                if area > best_area:
                    best, best_area = (r0, r1, c, c_end), area
                c = c_end + 1
    return best

