"""Validation: project a known grid, measure where it lands with the stereo pair, compare with the prediction.

The grid is a chessboard drawn in projector pixels (its inner corners' projector coordinates are exact). Both
cameras find its corners; triangulation gives where they truly landed (as the stereo pair measures it). The
calibration predicts the same points by casting each corner's projector ray (projector intrinsics + its
pose, e.g. from the head model) onto the wall plane. The 3-D distance between the two is the error a user
sees on the wall.

Pixel convention: integer coordinates are pixel centres (OpenCV's), so the edge between projector columns
c-1 and c is at x = c - 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from calibration.boards import Board, BoardView, detect
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, transform_points
from geometry.robust import fit_plane
from geometry.triangulation import triangulate

PROJECTED_MARKER_FRACTION = 0.7  # ArUco marker size in a projected ChArUco square
PLANE_SNAP_MAX_M = 0.003  # triangulated points are snapped to their fitted plane when it fits this well
PLANE_OUTLIER_SIGMAS = 4.0  # a point farther off the plane than this many robust σ …
PLANE_OUTLIER_MIN_M = 0.006  # … and this distance is a misidentified corner


@dataclass
class ProjectedGrid:
    image: NDArray[np.uint8]  # (h, w) what the projector shows
    board: Board  # its corner layout (square size in projector pixels, not metres)
    corners_px: NDArray[np.float64]  # (n, 2) projector pixels of corner id 0..n-1 (row by row, top-left first)


def projected_chessboard(width: int, height: int, square_px: int, margin_px: int | None = None) -> ProjectedGrid:
    """A chessboard filling the projector image (white border of margin_px), and its inner corners."""
    margin = square_px if margin_px is None else margin_px
    nx = (width - 2 * margin) // square_px
    ny = (height - 2 * margin) // square_px
    if nx < 3 or ny < 3:
        raise ValueError(f"a {square_px}px chessboard does not fit a {width}x{height} projector")
    if nx == ny:
        ny -= 1  # a square pattern would be ambiguous
    ox = (width - nx * square_px) // 2
    oy = (height - ny * square_px) // 2
    img = np.full((height, width), 255, np.uint8)
    for j in range(ny):
        for i in range(nx):
            if (i + j) % 2 == 0:
                img[oy + j * square_px:oy + (j + 1) * square_px, ox + i * square_px:ox + (i + 1) * square_px] = 0
    cols, rows = nx - 1, ny - 1
    gx, gy = np.meshgrid(ox + square_px * np.arange(1, nx) - 0.5, oy + square_px * np.arange(1, ny) - 0.5)
    corners = np.column_stack([gx.ravel(), gy.ravel()])
    board = Board("chessboard", cols, rows, float(square_px), spec=f"chessboard:{cols}x{rows}:{square_px}px")
    return ProjectedGrid(img, board, corners)


def projected_charuco(width: int, height: int, square_px: int, dictionary: str = "DICT_4X4_250"
                      ) -> ProjectedGrid:
    """A ChArUco board filling the projector image: its corners are found even when partly out of view."""
    nx = (width - square_px) // square_px
    ny = (height - square_px) // square_px
    board = Board("charuco", nx, ny, float(square_px), PROJECTED_MARKER_FRACTION * square_px, dictionary,
                  spec=f"charuco:{nx}x{ny}:{square_px}px")
    ox = (width - nx * square_px) // 2
    oy = (height - ny * square_px) // 2
    img = np.full((height, width), 255, np.uint8)
    img[oy:oy + ny * square_px, ox:ox + nx * square_px] = board.charuco_board().generateImage(
        (nx * square_px, ny * square_px), marginSize=0)
    board_corners = np.asarray(board.charuco_board().getChessboardCorners(), dtype=np.float64)
    corners = board_corners[:, :2] + np.array([ox, oy]) - 0.5
    return ProjectedGrid(img, board, corners)


def order_like(view: BoardView, expected_px: NDArray[np.float64]) -> BoardView:
    """Number a detected grid like expected_px (n, 2) (both orders are tried; the closer one wins)."""
    a = np.sqrt(np.mean(np.sum((view.image_points - expected_px) ** 2, axis=1)))
    b = np.sqrt(np.mean(np.sum((view.image_points[::-1] - expected_px) ** 2, axis=1)))
    if b < a:
        return replace(view, image_points=view.image_points[::-1].copy())
    return view


def cast_onto_plane(projector: Intrinsics, T_ref_from_projector: NDArray[np.float64], pixels: NDArray[np.float64],
                    plane_point: NDArray[np.float64], plane_normal: NDArray[np.float64]) -> NDArray[np.float64]:
    """Where projector pixels (n, 2) land on a plane, in the reference frame (n, 3), metres."""
    rays = projector.rays(pixels) @ T_ref_from_projector[:3, :3].T
    origin = T_ref_from_projector[:3, 3]
    t = ((plane_point - origin) @ plane_normal) / (rays @ plane_normal)
    return origin + t[:, None] * rays


@dataclass
class GridMeasurement:
    """Corners found in both cameras: projector pixels (n, 2), triangulated points (n, 3) in camera_left."""

    projector_px: NDArray[np.float64]
    points_left: NDArray[np.float64]
    left_px: NDArray[np.float64]
    right_px: NDArray[np.float64]


def measure_grid(grid: ProjectedGrid, left_image: NDArray, right_image: NDArray, left: Intrinsics,
                 right: Intrinsics, T_right_from_left: NDArray[np.float64], snap_to_plane: bool = True,
                 expected_left_px: NDArray[np.float64] | None = None) -> GridMeasurement | None:
    """Find the projected grid in both images and triangulate it; None when the cameras share < 12 corners.

    snap_to_plane: a wall is flat to well under the stereo pair's depth noise (≈2 mm per point at 2 m), so
    when the points fit one plane within PLANE_SNAP_MAX_M, each is replaced by the mean of its two camera
    rays' intersections with that plane (lateral precision of a ray, depth precision of the whole plane).
    expected_left_px: (chessboards only) roughly where the corners should appear in the left image, to fix
    their numbering; else the canonical order (starting nearest the image's top-left) is trusted.
    """
    lv = detect(grid.board, left_image, "left")
    rv = detect(grid.board, right_image, "right")
    if lv is None or rv is None:
        return None
    if grid.board.kind == "charuco":
        common, il, ir = np.intersect1d(lv.ids, rv.ids, return_indices=True)
        if len(common) < 12:
            return None
        pl, pr = lv.image_points[il], rv.image_points[ir]
        X = triangulate(left, right, T_right_from_left, pl, pr)
        ids = common
    else:
        if expected_left_px is not None:
            lv = order_like(lv, expected_left_px)
        # Number the right view like the left one: the order that triangulates consistently wins.
        best = None
        for cand in (rv.image_points, rv.image_points[::-1]):
            Xc = triangulate(left, right, T_right_from_left, lv.image_points, cand)
            reproj = right.project(transform_points(T_right_from_left, Xc))
            err = float(np.sqrt(np.mean(np.sum((reproj - cand) ** 2, axis=1))))
            if best is None or err < best[0]:
                best = (err, Xc, cand)
        assert best is not None
        _, X, pr = best
        pl = lv.image_points
        ids = lv.ids
    if snap_to_plane:
        X, keep = snap_points_to_plane(X, left, right, T_right_from_left, pl, pr)
        X, pl, pr, ids = X[keep], pl[keep], pr[keep], ids[keep]
    return GridMeasurement(grid.corners_px[ids], X, pl, pr)


def snap_points_to_plane(X: NDArray[np.float64], left: Intrinsics, right: Intrinsics,
                         T_right_from_left: NDArray[np.float64], left_px: NDArray[np.float64],
                         right_px: NDArray[np.float64], max_rms_m: float = PLANE_SNAP_MAX_M
                         ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Triangulated points (n, 3) moved onto their best plane along both camera rays (see measure_grid).

    Returns (points, keep): points off the plane by more than PLANE_OUTLIER_M (a misidentified corner) are
    marked to drop. A surface that is not flat (its points off the plane by more than max_rms_m, RMS) keeps its
    triangulated points.
    """
    keep = np.ones(len(X), bool)
    for _ in range(3):
        point, normal = fit_plane(X[keep])
        off = np.abs((X - point) @ normal)
        sigma = 1.4826 * float(np.median(off[keep]))
        new_keep = off < max(PLANE_OUTLIER_SIGMAS * sigma, PLANE_OUTLIER_MIN_M)
        if np.array_equal(new_keep, keep) or new_keep.sum() < 12:
            break
        keep = new_keep
    if np.sqrt(np.mean(off[keep] ** 2)) > max_rms_m:
        return X, np.ones(len(X), bool)  # not a flat surface: keep the triangulated points
    on_left = cast_onto_plane(left, np.eye(4), left_px, point, normal)
    on_right = cast_onto_plane(right, invert(T_right_from_left), right_px, point, normal)
    return 0.5 * (on_left + on_right), keep


@dataclass
class ValidationResult:
    rms_mm: float
    max_mm: float
    n_points: int
    distance_m: float  # mean distance from the left camera to the measured points

    def quality(self) -> dict:
        return {"rms_mm": round(self.rms_mm, 4), "max_mm": round(self.max_mm, 4), "points": self.n_points,
                "distance_m": round(self.distance_m, 3)}


def compare(measured: NDArray[np.float64], predicted: NDArray[np.float64]) -> ValidationResult:
    """3-D error statistics between measured and predicted points (n, 3) in metres."""
    d = np.linalg.norm(np.asarray(measured) - np.asarray(predicted), axis=1)
    return ValidationResult(float(1000 * np.sqrt(np.mean(d ** 2))), float(1000 * d.max()), len(d),
                            float(np.mean(np.linalg.norm(measured, axis=1))))


def validate_grid(measurement: GridMeasurement, projector: Intrinsics,
                  T_left_from_projector: NDArray[np.float64]) -> tuple[ValidationResult, NDArray[np.float64]]:
    """Compare the measured landing points with the calibration's prediction on the measured wall plane."""
    point, normal = fit_plane(measurement.points_left)
    predicted = cast_onto_plane(projector, T_left_from_projector, measurement.projector_px, point, normal)
    return compare(measurement.points_left, predicted), predicted
