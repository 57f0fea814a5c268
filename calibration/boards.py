"""Calibration boards: specs parsed from strings, detection with subpixel corners, synthetic renderings.

A spec string names the board:

    chessboard:9x6:0.025                 9 x 6 inner corners, 25 mm squares
    charuco:7x5:0.04:0.03[:DICT_4X4_50]   7 x 5 squares of 40 mm, 30 mm ArUco markers

Corners are refined to subpixel accuracy with a window sized from the board's own square size in the image
(a fixed 11x11 window, as OpenCV's samples use, reaches into the neighbouring corners when squares are
~30 px wide; that alone costs a third of the held-out epipolar error on OpenCV's stereo sample images).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.defaults import DEFAULT_BOARD as DEFAULT_BOARD  # re-exported
from geometry.errors import InputError
from geometry.inputs import read_image

# Subpixel refinement: half-window = this fraction of the local corner spacing, clipped to the range below.
SUBPIX_WINDOW_FRACTION = 0.25
SUBPIX_MIN_HALF_WINDOW = 2
SUBPIX_MAX_HALF_WINDOW = 15
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, 100, 1e-4)
# A refined corner farther from its neighbours' prediction than this (px, or this fraction of the local spacing,
# whichever is larger) is refined again from the prediction (see grid_predictions for how near good ones are).
SUBPIX_RETRY_MIN_PX = 1.0
SUBPIX_RETRY_FRACTION = 0.05
SB_RNG_SEED = 0x5B  # findChessboardCornersSB's random sampling, fixed (see detect)
# A chessboard's outer squares alternate dark and bright all round. A grid found one square off (the board
# partly hidden, its edge against the white margin taken for a row of corners) has the margin where one side's
# outer squares should alternate: each side must match the pattern in at least this share of its squares.
RING_MIN_MATCH = 0.75
RING_SAMPLE_HALF = 0.15  # each square's brightness: the mean over ±this share of a square about a point …
RING_DEPTH = 0.3  # … this share of a square out from the grid's edge for the outer squares (a print trimmed
# near the board's edge leaves them narrower), their centre for the inner ones
RING_MIN_CONTRAST = 8.0  # grey levels between the inner dark and bright squares, else the check cannot tell

# Squares above this are implausible for a printed board: the size was most likely typed in mm or cm.
MAX_SQUARE_M = 0.3
MIN_SQUARE_M = 0.003


@dataclass(frozen=True)
class Board:
    """A planar calibration target. corners are in the board frame (z = 0), metres."""

    kind: str  # "chessboard" or "charuco"
    cols: int  # chessboard: inner corners across; charuco: squares across
    rows: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = "DICT_4X4_50"
    spec: str = field(default="", compare=False)

    @property
    def pattern_size(self) -> tuple[int, int]:
        """Inner corners (cols, rows), as findChessboardCorners takes them."""
        if self.kind == "chessboard":
            return (self.cols, self.rows)
        return (self.cols - 1, self.rows - 1)

    @property
    def n_corners(self) -> int:
        c, r = self.pattern_size
        return c * r

    def object_points(self) -> NDArray[np.float64]:
        """(n, 3) float64, metres: inner corners row by row, x along cols, y along rows, z = 0."""
        c, r = self.pattern_size
        grid = np.mgrid[0:c, 0:r].T.reshape(-1, 2).astype(np.float64) * self.square_m
        return np.column_stack([grid, np.zeros(len(grid))])

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, dictionary)

    def render(self, pixels_per_square: int = 40, margin_squares: float = 1.0) -> NDArray[np.uint8]:
        """A printable image of the board (uint8 grey), white margin of margin_squares around it.

        For a chessboard the outer squares are (cols + 1) x (rows + 1); corner (0, 0) sits at pixel
        (margin + 1 square) from the top-left of the image.
        """
        s = int(pixels_per_square)
        m = round(margin_squares * s)
        if self.kind == "charuco":
            charuco = self.charuco_board().generateImage((self.cols * s + 2 * m, self.rows * s + 2 * m),
                                                         marginSize=m)
            return np.asarray(charuco, dtype=np.uint8)
        nx, ny = self.cols + 1, self.rows + 1
        img = np.full((ny * s + 2 * m, nx * s + 2 * m), 255, np.uint8)
        for j in range(ny):
            for i in range(nx):
                if (i + j) % 2 == 0:
                    img[m + j * s:m + (j + 1) * s, m + i * s:m + (i + 1) * s] = 0
        return img


def _check_square_size(spec: str, text: str, square: float) -> None:
    """InputError for a square over MAX_SQUARE_M, suggesting the readings as millimetres or centimetres."""
    if square <= MAX_SQUARE_M:
        return
    readings = [f"{square / div:g} m ({text} {unit})" for div, unit in ((1000, "mm"), (100, "cm"))
                if MIN_SQUARE_M <= square / div <= MAX_SQUARE_M]
    guess = f"did you mean {' or '.join(readings)}?" if readings else "give the square size in metres"
    raise InputError(f"board spec {spec!r}: a {square:g} m square is implausible for a printed board (over "
                     f"{MAX_SQUARE_M:g} m); {guess}", "the square size is in metres, e.g. chessboard:9x6:0.025")


def parse_board(spec: str) -> Board:
    """Board from 'chessboard:COLSxROWS:SQUARE_M' or 'charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]'."""
    parts = str(spec).strip().split(":")
    hint = "use e.g. chessboard:9x6:0.025 (inner corners, square in metres) or charuco:7x5:0.04:0.03"
    if len(parts) < 3 or parts[0] not in ("chessboard", "charuco"):
        raise InputError(f"board spec {spec!r} is not understood", hint)
    try:
        cols, rows = (int(v) for v in parts[1].lower().split("x"))
        square = float(parts[2])
    except ValueError:
        raise InputError(f"board spec {spec!r}: size {parts[1]!r} or square {parts[2]!r} is not a number",
                         hint) from None
    if cols < 2 or rows < 2 or not square > 0:
        raise InputError(f"board spec {spec!r}: needs at least 2x2 corners and a positive square size", hint)
    _check_square_size(spec, parts[2], square)
    if parts[0] == "chessboard":
        if len(parts) != 3:
            raise InputError(f"board spec {spec!r}: a chessboard takes exactly COLSxROWS:SQUARE_M", hint)
        if cols == rows:
            raise InputError(f"board spec {spec!r}: a square chessboard ({cols}x{rows}) has no defined "
                             "orientation", "use a board with different corner counts across and down")
        return Board("chessboard", cols, rows, square, spec=spec)
    if len(parts) not in (4, 5):
        raise InputError(f"board spec {spec!r}: a ChArUco board takes COLSxROWS:SQUARE_M:MARKER_M[:DICT]", hint)
    try:
        marker = float(parts[3])
    except ValueError:
        raise InputError(f"board spec {spec!r}: marker size {parts[3]!r} is not a number", hint) from None
    dictionary = parts[4] if len(parts) == 5 else "DICT_4X4_50"
    if not hasattr(cv2.aruco, dictionary):
        raise InputError(f"board spec {spec!r}: unknown ArUco dictionary {dictionary!r}",
                         "use one of DICT_4X4_50, DICT_5X5_100, DICT_6X6_250, …")
    if not 0 < marker < square:
        raise InputError(f"board spec {spec!r}: the marker ({marker}) must be smaller than the square ({square})")
    return Board("charuco", cols, rows, square, marker, dictionary, spec=spec)


@dataclass
class BoardView:
    """One detection: image_points (n, 2) float64 px, matching object_points (n, 3) m and corner ids (n,)."""

    image_points: NDArray[np.float64]
    object_points: NDArray[np.float64]
    ids: NDArray[np.int64]
    image_size: tuple[int, int]  # (width, height)
    source: str = ""
    image: NDArray[np.uint8] | None = field(default=None, repr=False)  # the grey image, for re-refinement


def read_gray(path: str | Path) -> NDArray[np.uint8]:
    """Read an image file as uint8 grey; InputError naming the file when it cannot be read."""
    return read_image(path, "image file")


def as_gray(image: NDArray, channel_order: Literal["bgr", "rgb"] = "bgr") -> NDArray[np.uint8]:
    """A grey uint8 image from a grey or colour one. channel_order: "bgr" as OpenCV reads files and cameras,
    "rgb" as arproj's renderer and simulated cameras give them."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY if channel_order == "rgb" else cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def refine_corners(gray: NDArray[np.uint8], corners: NDArray, pattern_size: tuple[int, int]) -> NDArray:
    """Subpixel corners (n, 2) float64 with a window scaled to each corner's distance to its grid neighbours.

    A raw corner several pixels off (findChessboardCorners does that now and then) lies outside its window,
    and cornerSubPix settles somewhere else: a corner that comes back far from where its grid neighbours put it
    is refined again from that prediction, and the retry kept when it agrees better with the neighbours (one
    corner at a time, the worst first).
    """
    c, r = pattern_size
    pts = np.asarray(corners, dtype=np.float64).reshape(r, c, 2)
    grid_spacing = np.full((r, c), np.inf)
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(pts, axis=axis), axis=2)
        pad = [(0, 0), (0, 0)]
        pad[axis] = (1, 0)
        grid_spacing = np.minimum(grid_spacing, np.pad(d, pad, constant_values=np.inf))
        pad[axis] = (0, 1)
        grid_spacing = np.minimum(grid_spacing, np.pad(d, pad, constant_values=np.inf))
    spacing = grid_spacing.ravel()
    half = _half_windows(spacing, SUBPIX_WINDOW_FRACTION)
    out = _subpix(gray, pts.reshape(-1, 2), half)
    limit = np.maximum(SUBPIX_RETRY_MIN_PX, SUBPIX_RETRY_FRACTION * spacing)
    tried = np.zeros(len(out), bool)
    # Worst first, predictions renewed after each: a bad corner also pulls its neighbours' predictions.
    while True:
        predicted = grid_predictions(out, pattern_size)
        miss = np.linalg.norm(out - predicted, axis=1)
        excess = np.where(tried, 0.0, miss / limit)
        k = int(np.argmax(excess))
        if excess[k] <= 1.0:
            return out
        tried[k] = True
        retry = _subpix(gray, predicted[k:k + 1], half[k:k + 1])[0]
        if np.linalg.norm(retry - predicted[k]) < miss[k]:
            out[k] = retry


def grid_predictions(pts: NDArray[np.float64], pattern_size: tuple[int, int]) -> NDArray[np.float64]:
    """Where each chessboard corner (n, 2), row by row, should be from its neighbours alone.

    A homography from grid to image fitted to the corners one grid step around (two at the board's corners,
    which have only three such neighbours), the corner itself left out: perspective is exact there and lens
    distortion small over so few squares (on OpenCV's sample images good corners sit within 0.85 px of it,
    median 0.25 px). A corner whose neighbourhood gives no homography predicts itself.
    """
    c, r = pattern_size
    flat = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    grid = _grid_positions(pattern_size)
    ii, jj = grid[:, 0], grid[:, 1]
    out = flat.copy()
    for k in range(r * c):
        for steps in (1, 2):
            near = np.flatnonzero((np.abs(ii - ii[k]) <= steps) & (np.abs(jj - jj[k]) <= steps))
            near = near[near != k]
            if len(near) >= 5:
                break
        H, _ = cv2.findHomography(grid[near], flat[near])
        if H is None:
            continue
        p = H @ [grid[k, 0], grid[k, 1], 1.0]
        out[k] = p[:2] / p[2]
    return out


def _grid_positions(pattern_size: tuple[int, int]) -> NDArray[np.float64]:
    """(n, 2) grid coordinates (column, row) of a chessboard's corners, row by row as the detectors give them."""
    c, r = pattern_size
    rows, cols = np.divmod(np.arange(r * c), c)
    return np.column_stack([cols, rows]).astype(np.float64)


def _half_windows(spacing: NDArray[np.float64], fraction: float) -> NDArray[np.int64]:
    return np.clip(np.round(fraction * spacing), SUBPIX_MIN_HALF_WINDOW, SUBPIX_MAX_HALF_WINDOW).astype(np.int64)


def _subpix(gray: NDArray[np.uint8], pts: NDArray[np.float64], half: NDArray[np.int64]) -> NDArray[np.float64]:
    """cv2.cornerSubPix on points (n, 2), each with its own half-window (grouped by size)."""
    out = np.asarray(pts, dtype=np.float32).reshape(-1, 2).copy()
    for h in np.unique(half):
        sel = np.flatnonzero(half == h)
        out[sel] = cv2.cornerSubPix(gray, out[sel].reshape(-1, 1, 2).copy(), (int(h), int(h)), (-1, -1),
                                    SUBPIX_CRITERIA).reshape(-1, 2)
    return out.astype(np.float64)


def refine_scattered_corners(gray: NDArray[np.uint8], corners: NDArray[np.float64],
                             window_fraction: float = SUBPIX_WINDOW_FRACTION) -> NDArray[np.float64]:
    """Subpixel refinement of corners (n, 2) without grid order (ChArUco): window from the nearest neighbour."""
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    if len(pts) < 2:
        return pts
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    return _subpix(gray, pts, _half_windows(d.min(axis=1), window_fraction))


def detect(board: Board, image: NDArray, source: str = "") -> BoardView | None:
    """Find the board in an image (grey or BGR uint8); None when it is not (fully) visible."""
    gray = as_gray(image)
    size = (gray.shape[1], gray.shape[0])
    if board.kind == "chessboard":
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(gray, board.pattern_size, flags=flags)
        if not found:
            # The sector-based detector copes with blur and uneven light where the classic one gives up. It
            # samples with OpenCV's global RNG: seeded here, a detection depends on the image alone (unseeded, the
            # same image gave a board in one call and none in the next).
            cv2.setRNGSeed(SB_RNG_SEED)
            found, corners = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=cv2.CALIB_CB_EXHAUSTIVE)
            if not found:
                return None
        pts = refine_corners(gray, corners, board.pattern_size)
        if not outer_squares_alternate(gray, pts, board.pattern_size):
            return None  # corners numbered a square off: worse than no view (a stereo pair would disagree)
        pts = canonical_order(pts, board.pattern_size)
        return BoardView(pts, board.object_points(), np.arange(board.n_corners), size, source, gray)
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < 6:
        return None
    corner_ids = ids.ravel().astype(np.int64)
    obj = board.object_points()[corner_ids]
    # The window must stay inside the white gap between a corner and the nearest marker edges.
    gap = 0.5 * (board.square_m - board.marker_m) / board.square_m
    pts = refine_scattered_corners(gray, corners.reshape(-1, 2).astype(np.float64), 0.8 * gap)
    return BoardView(pts, obj, corner_ids, size, source, gray)


def outer_squares_alternate(gray: NDArray[np.uint8], pts: NDArray[np.float64], pattern_size: tuple[int, int]
                            ) -> bool:
    """Whether the squares just outside a chessboard's corner grid (n, 2), row by row, alternate as a board's
    outer squares do: dark and bright by parity, as the inner squares are. Each side in view is judged alone;
    True when the inner squares have too little contrast to judge."""
    c, r = pattern_size
    H, _ = cv2.findHomography(_grid_positions(pattern_size), np.asarray(pts, dtype=np.float64).reshape(-1, 2))
    if H is None:
        return False
    # Square (i, j) spans grid i..i+1, j..j+1: inner squares i in 0..c-2, the outer ring -1 and c-1.
    offsets = np.linspace(-RING_SAMPLE_HALF, RING_SAMPLE_HALF, 3)
    patch = np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2)

    def brightness(i: NDArray[np.float64], j: NDArray[np.float64]) -> NDArray[np.float64]:
        """Mean grey of squares (i, j) (nan where a sample falls outside the image): inner squares about their
        centre, outer ones RING_DEPTH out from the grid's edge."""
        x = np.where(i < 0, -RING_DEPTH, np.where(i > c - 2, c - 1 + RING_DEPTH, i + 0.5))
        y = np.where(j < 0, -RING_DEPTH, np.where(j > r - 2, r - 1 + RING_DEPTH, j + 0.5))
        centres = np.stack([x, y], axis=-1)[:, None, :] + patch[None]
        img = cv2.perspectiveTransform(centres.reshape(-1, 1, 2), H).reshape(len(i), -1, 2)
        h, w = gray.shape[:2]
        inside = np.all((img >= 0) & (img <= [w - 1, h - 1]), axis=(1, 2))
        xy = np.clip(np.rint(img).astype(np.int64), 0, [w - 1, h - 1])
        mean = gray[xy[..., 1], xy[..., 0]].mean(axis=1)
        return np.where(inside, mean, np.nan)

    ii, jj = (a.ravel().astype(np.float64) for a in np.meshgrid(np.arange(c - 1), np.arange(r - 1)))
    inner = brightness(ii, jj)
    parity = (ii + jj) % 2
    levels = [float(np.nanmean(inner[parity == k])) for k in (0, 1)]
    if not all(np.isfinite(levels)) or abs(levels[0] - levels[1]) < RING_MIN_CONTRAST:
        return True
    threshold, dark_parity = sum(levels) / 2, int(np.argmin(levels))
    along_x, along_y = np.arange(-1, c, dtype=np.float64), np.arange(-1, r, dtype=np.float64)
    sides = [(along_x, np.full_like(along_x, -1.0)), (along_x, np.full_like(along_x, r - 1.0)),
             (np.full_like(along_y, -1.0), along_y), (np.full_like(along_y, c - 1.0), along_y)]
    for i, j in sides:
        value = brightness(i, j)
        seen = np.isfinite(value)
        if not seen.any():
            continue
        dark_expected = (i + j) % 2 == dark_parity
        if np.mean((value[seen] < threshold) == dark_expected[seen]) < RING_MIN_MATCH:
            return False
    return True


def canonical_order(pts: NDArray[np.float64], pattern_size: tuple[int, int]) -> NDArray[np.float64]:
    """A chessboard with uneven sides is still 180° ambiguous: start at the corner nearer the image's top-left.

    Two cameras of a stereo rig looking at the same board then number its corners alike (checked again,
    per pair, in calibration.stereo).
    """
    first, last = pts[0], pts[-1]
    if first.sum() > last.sum():
        return pts[::-1].copy()
    return pts


def reverse_view(view: BoardView, board: Board) -> BoardView:
    """The same detection numbered from the opposite corner (a chessboard's 180° ambiguity)."""
    if board.kind != "chessboard":
        return view
    return replace(view, image_points=view.image_points[::-1].copy())


def detect_file(board: Board, path: str | Path) -> BoardView | None:
    return detect(board, read_gray(path), source=str(path))
