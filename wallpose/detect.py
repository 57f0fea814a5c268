"""Find the pattern's corners in one camera image and name each by its corner id (hence its projector pixel).

1. Coded marker blocks are found by OpenCV's ArUco detector on a downscaled copy (they only seed).
2. Their corners give a homography H from undistorted projector coordinates to undistorted camera coordinates
   (the wall is a plane).
3. The camera image is resampled into the board's own frame through H and both lens distortions
   ("rectified"): there every square is an upright square again, whatever the incidence. Local black and
   white levels are flattened, and cv2.cornerSubPix refines each corner there, where perspective and the
   brightness fall-off across an oblique wall can no longer pull it aside; the refined point is mapped back
   to camera pixels through the same warp, so small errors of H cancel.
4. A corner is kept only if it stayed near its prediction and its four squares show the expected black/white
   parity with enough contrast; H is refitted to the kept corners of one surface (RANSAC within half a pixel)
   and steps 3–4 repeat. Parts off the wall, occluded or on another surface fail the checks and are left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.boards import as_gray
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.threads import single_threaded
from wallpose import limits
from wallpose.pattern import MARKER_DICTIONARY, CheckerPattern

RECTIFY_PASSES = 2
SURFACE_RANSAC_PX = 0.5     # refined corners farther than this from the refitted homography: another surface
MIN_RECT_SQUARE_PX = 14.0   # a square spans at least this many pixels in the rectified image
MAP_STEP_PX = 8             # the rectifying map is computed on this grid and interpolated
FLAT_FIELD_STEP = 3         # the black/white envelopes are computed on this grid (odd) and interpolated


@dataclass
class Detection:
    """Corners found in one camera image.

    corner_ids: (n,) int indices into pattern.corner_grid; pixels: (n, 2) float64 raw (distorted) camera
    pixels; normalized: (n, 2) undistorted normalized coordinates (x/z, y/z); reason: why nothing usable
    was found (None when corners were found); warnings: things worth knowing that did not stop detection;
    kept_fraction: the fraction of the corners in view that were refined (an even subset; see detect).
    """

    camera: str
    corner_ids: NDArray[np.int64]
    pixels: NDArray[np.float64]
    normalized: NDArray[np.float64]
    markers_found: int = 0
    contrast: float = float("nan")
    clipped_fraction: float = float("nan")
    reason: str | None = None
    kept_fraction: float = 1.0
    warnings: list[str] = field(default_factory=list)

    @property
    def count(self) -> int:
        return len(self.corner_ids)


def _empty(camera: str, reason: str, markers: int = 0, contrast: float = float("nan"),
           clipped: float = float("nan")) -> Detection:
    return Detection(camera, np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), markers, contrast,
                     clipped, reason)


def _aruco_detector(window_px: int, min_perimeter_rate: float) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE  # seeds only; checker corners are refined
    params.adaptiveThreshWinSizeMin = window_px
    params.adaptiveThreshWinSizeMax = 2 * window_px + 1
    params.adaptiveThreshWinSizeStep = window_px + 1
    # checker squares are several times smaller than a marker: skipping them is most of the speed
    params.minMarkerPerimeterRate = min_perimeter_rate
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(MARKER_DICTIONARY), params)


_DETECTORS: dict[tuple[int, int], cv2.aruco.ArucoDetector] = {}


def find_markers(gray: NDArray[np.uint8], pattern: CheckerPattern) -> dict[int, NDArray[np.float64]]:
    """marker id -> (4, 2) camera pixels (full resolution) of the pattern's markers found in the image."""
    scale = min(1.0, limits.MARKER_DETECT_MAX_PX / gray.shape[1])
    small = gray if scale == 1.0 else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    side = pattern.marker_px * pattern.camera_px_per_projector_px * scale   # expected marker side, px
    window = int(np.clip(side / 4, 5, 41)) | 1
    rate = round(0.5 * 4 * side / max(small.shape), 3)  # half the expected perimeter: room for perspective
    key = (window, int(1000 * rate))
    if key not in _DETECTORS:
        _DETECTORS[key] = _aruco_detector(window, rate)
    corners, ids, _ = _DETECTORS[key].detectMarkers(small)
    found: dict[int, NDArray[np.float64]] = {}
    if ids is None:
        return found
    n_markers = len(pattern.marker_blocks)
    for c, marker_id in zip(corners, ids.ravel(), strict=True):
        if 0 <= marker_id < n_markers and marker_id not in found:
            found[int(marker_id)] = (c.reshape(4, 2).astype(np.float64) + 0.5) / scale - 0.5
    return found


def _apply_h(H: NDArray[np.float64], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return p[:, :2] / p[:, 2:3]


def _sample(gray: NDArray[np.float32], pixels: NDArray[np.float64]) -> NDArray[np.float64]:
    """Bilinear grey levels at (n, 2) pixels; NaN outside the image."""
    maps = pixels.astype(np.float32).reshape(-1, 1, 2)
    # OpenCV's stubs want a map2; None is what its docs give when map1 holds both x and y (CV_32FC2)
    values = cv2.remap(gray, maps, None, cv2.INTER_LINEAR,  # type: ignore[call-overload]
                       borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return np.asarray(values, dtype=np.float64).reshape(-1)


class _Rectifier:
    """Maps between the rectified board image (scale px per projector px, origin at the board's top-left
    minus a margin) and raw camera pixels, through a homography H (normalized projector -> camera)."""

    def __init__(self, pattern: CheckerPattern, projector: Intrinsics, camera: Intrinsics, scale: float) -> None:
        self.pattern, self.projector, self.camera, self.scale = pattern, projector, camera, scale
        s = pattern.square_px
        self.margin_px = s  # projector pixels around the board
        self.origin = np.array(pattern.origin_px, dtype=np.float64) - self.margin_px - 0.5
        width = int(np.ceil((pattern.cols * s + 2 * self.margin_px) * scale))
        height = int(np.ceil((pattern.rows * s + 2 * self.margin_px) * scale))
        # coarse samples sit where cv2.resize (half-pixel centres) puts them when scaling up by MAP_STEP_PX; the
        # rectified image is a whole number of steps (a little beyond the margin), so the map needs no cropping
        nx, ny = int(np.ceil(width / MAP_STEP_PX)) + 1, int(np.ceil(height / MAP_STEP_PX)) + 1
        self.size = (nx * MAP_STEP_PX, ny * MAP_STEP_PX)
        half = (MAP_STEP_PX - 1) / 2.0
        gx = np.arange(nx) * MAP_STEP_PX + half
        gy = np.arange(ny) * MAP_STEP_PX + half
        self.grid_shape = (ny, nx)
        u, v = np.meshgrid(gx, gy)
        # projector normalized coordinates of the coarse grid (cached with the rectifier)
        self.grid_norm = projector.rays(self.to_projector(np.column_stack([u.ravel(), v.ravel()])))[:, :2]

    def to_projector(self, rect: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.origin + (rect + 0.5) / self.scale

    def to_rect(self, projector_px: NDArray[np.float64]) -> NDArray[np.float64]:
        return (projector_px - self.origin) * self.scale - 0.5

    def camera_px(self, H: NDArray[np.float64], projector_norm: NDArray[np.float64]) -> NDArray[np.float64]:
        # vectorised (the coarse map has thousands of points): a fraction of cv2.projectPoints' cost
        return self.camera.pixels_of_normalized(_apply_h(H, projector_norm))

    def warp(self, gray: NDArray[np.float32], H: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """(rectified image, valid mask) for the current H."""
        coarse = self.camera_px(H, self.grid_norm).reshape(*self.grid_shape, 2).astype(np.float32)
        full = cv2.resize(coarse, self.size, interpolation=cv2.INTER_LINEAR)   # (h, w, 2): x and y maps
        rect = cv2.remap(gray, full, None, cv2.INTER_LINEAR,  # type: ignore[call-overload]  # map2: as in _sample
                         borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        valid = np.isfinite(rect)
        return rect, valid


_RECTIFIERS: dict[tuple[int, Intrinsics, Intrinsics, float], _Rectifier] = {}


def _rectifier(pattern: CheckerPattern, projector: Intrinsics, camera: Intrinsics, scale: float) -> _Rectifier:
    key = (id(pattern), projector, camera, round(scale, 3))
    r = _RECTIFIERS.get(key)
    if r is None or r.pattern is not pattern:
        if len(_RECTIFIERS) > 8:
            _RECTIFIERS.clear()
        r = _RECTIFIERS[key] = _Rectifier(pattern, projector, camera, round(scale, 3))
    return r


def _flat_field(rect: NDArray[np.float32], valid: NDArray[np.bool_], square: float) -> NDArray[np.float32]:
    """The rectified image with its local black and white levels stretched to 0 and 255 (envelopes: max and min
    filters over about two squares, smoothed), so a brightness gradient cannot pull a corner aside.

    The envelopes are smooth over two squares, so they are computed on every FLAT_FIELD_STEP-th pixel (a
    square still spans several samples, so max and min still reach its pure interior) and interpolated back:
    the same envelopes for about 1/step² of the filtering."""
    step = int(np.clip(square // 4, 1, FLAT_FIELD_STEP))
    step -= 1 - step % 2  # odd, so the samples sit exactly where cv2.resize puts them when scaling back up
    k = int(np.clip(2.2 * square / step, 3, 101)) | 1
    start = (step - 1) // 2
    sub_rect, sub_valid = rect[start::step, start::step], valid[start::step, start::step]
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    # two box filters: a smooth envelope; outside the camera image white counts as 0 and black as 255
    white = cv2.blur(cv2.blur(cv2.dilate(np.where(sub_valid, sub_rect, 0.0).astype(np.float32), kernel), (k, k)),
                     (k, k))
    black = cv2.blur(cv2.blur(cv2.erode(np.where(sub_valid, sub_rect, 255.0).astype(np.float32), kernel), (k, k)),
                     (k, k))
    if step > 1:
        white, black = (np.ascontiguousarray(_upsample(np.asarray(e, dtype=np.float32), step, rect.shape))
                        for e in (white, black))
    img = rect.copy()
    cv2.patchNaNs(img, 0.0)  # outside the camera image (NaN in rect) reads as black
    # 255 (img - black) / max(white - black, 1), in single passes
    spread = cv2.max(cv2.subtract(white, black), 1.0)  # type: ignore[call-overload]  # a scalar src2 is allowed
    return np.asarray(cv2.divide(cv2.subtract(img, black), spread, scale=255.0), dtype=np.float32)


def _upsample(coarse: NDArray[np.float32], step: int, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """Bilinear interpolation of samples taken at pixels (step - 1) / 2 + k * step (step odd) back to an image
    of shape (h, w), flat beyond the outermost samples (a view; not contiguous)."""
    h, w = shape[:2]
    ny, nx = -(-h // step), -(-w // step)
    coarse = np.pad(coarse, ((0, ny - coarse.shape[0]), (0, nx - coarse.shape[1])), mode="edge")
    return np.asarray(cv2.resize(coarse, (nx * step, ny * step), interpolation=cv2.INTER_LINEAR),
                      dtype=np.float32)[:h, :w]


# Kronecker (R2) sequence constants: frac(i a1 + j a2) spreads evenly over [0, 1) across any part of the grid
_R2 = (0.7548776662466927, 0.5698402909980532)


def _even_subset(pattern: CheckerPattern, fraction: float) -> NDArray[np.bool_]:
    """(n,) a spatially even subset of about fraction of the pattern's corners (every corner when fraction is 1).
    Subsets for different fractions are nested, so two cameras keep mostly the same corners."""
    if fraction >= 1.0:
        return np.ones(pattern.n_corners, dtype=bool)
    i, j = pattern.corner_grid[:, 0], pattern.corner_grid[:, 1]
    return np.mod(i * _R2[0] + j * _R2[1], 1.0) < fraction


def detect(image: NDArray, pattern: CheckerPattern, camera: Intrinsics, projector: Intrinsics,
           camera_name: str = "camera", max_corners: int | None = limits.MAX_CORNERS) -> Detection:
    """Corners of pattern in a camera image (grey or RGB, uint8). Never raises on a bad picture: an empty
    Detection carries the reason instead.

    max_corners: when more corners are in view, a spatially even subset of about this many is refined (the
    plane's error grows a little and its reported bounds with it, for about half the work); None: all."""
    with single_threaded():
        return _detect(image, pattern, camera, projector, camera_name, max_corners)


def _detect(image: NDArray, pattern: CheckerPattern, camera: Intrinsics, projector: Intrinsics,
            camera_name: str, max_corners: int | None) -> Detection:
    gray = as_gray(image, channel_order="rgb")
    if gray.shape != (camera.height, camera.width):
        raise InputError(f"{camera_name}: image is {gray.shape[1]}x{gray.shape[0]} but the calibration is for "
                         f"{camera.width}x{camera.height}", "use the rig calibrated for this camera")
    markers = find_markers(gray, pattern)
    if not markers:
        return _empty(camera_name, _why_no_markers(gray))
    proj_norm = _projector_norm(pattern, projector)
    n = len(proj_norm)
    marker_proj = np.concatenate([projector.rays(pattern.marker_corners_px(i))[:, :2] for i in markers])
    marker_cam = np.concatenate([camera.rays(c)[:, :2] for c in markers.values()])
    f = camera.fx
    method = cv2.RANSAC if len(markers) >= 2 else 0
    found_H, _ = cv2.findHomography(marker_proj, marker_cam, method, 4.0 / f)
    if found_H is None:
        return _empty(camera_name, "the pattern's markers do not form a consistent view", len(markers))
    H = np.asarray(found_H, dtype=np.float64)

    s = pattern.square_px
    scale = float(np.clip(max(pattern.camera_px_per_projector_px, MIN_RECT_SQUARE_PX / s), 0.1, 1.5))
    rectifier = _rectifier(pattern, projector, camera, scale)
    corners_rect = rectifier.to_rect(pattern.corner_projector_px)
    square = s * rectifier.scale
    half_window = int(np.clip(np.round(0.35 * square), 2, 12))
    quadrant = 0.3 * square * np.array([[-1, -1], [1, 1], [1, -1], [-1, 1]], dtype=np.float64)
    ring, neighbourhood = _expected_neighbourhood(pattern)
    gray_f = gray.astype(np.float32)
    accepted = np.zeros(n, dtype=bool)
    refined = np.zeros((n, 2))
    contrast = np.zeros(n)
    white_clipped = np.zeros(n)
    max_shift = limits.MAX_CORNER_SHIFT_PX
    subset: NDArray[np.bool_] | None = None  # corner subsampling, fixed in the first pass
    kept_fraction = 1.0
    for _ in range(RECTIFY_PASSES):
        rect, valid = rectifier.warp(gray_f, H)
        flat = _flat_field(rect, valid, square)
        r = half_window + 2
        ix, iy = np.round(corners_rect[:, 0]).astype(int), np.round(corners_rect[:, 1]).astype(int)
        inside = (ix >= r) & (iy >= r) & (ix < rectifier.size[0] - r) & (iy < rectifier.size[1] - r)
        idx = np.nonzero(inside)[0]
        # the whole window must have come from inside the camera image
        whole = cv2.erode(valid.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))
        idx = idx[whole[iy[idx], ix[idx]] > 0]
        if subset is None:
            # no corner inside: nothing to thin out (and no division by zero)
            kept_fraction = 1.0 if max_corners is None or len(idx) == 0 else min(1.0, max_corners / len(idx))
            subset = _even_subset(pattern, kept_fraction)
        idx = idx[subset[idx]]
        if len(idx) == 0:
            break
        pts = corners_rect[idx].astype(np.float32).reshape(-1, 1, 2).copy()
        cv2.cornerSubPix(flat, pts, (half_window, half_window), (-1, -1),
                         (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, limits.SUBPIX_ITERATIONS,
                          limits.SUBPIX_EPS_PX))
        pts = pts.reshape(-1, 2).astype(np.float64)
        ok = np.linalg.norm(pts - corners_rect[idx], axis=1) * min(1.0, 1.0 / rectifier.scale) < max_shift
        # parity and contrast from the centres of the four squares (raw grey levels)
        probe = (corners_rect[idx][None] + quadrant[:, None, :]).reshape(-1, 2)
        samples = _sample(rect, probe).reshape(4, -1).T
        black_first = pattern.corner_parity[idx]
        dark = np.where(black_first[:, None], samples[:, :2], samples[:, 2:])
        bright = np.where(black_first[:, None], samples[:, 2:], samples[:, :2])
        c = np.min(bright, axis=1) - np.max(dark, axis=1)
        ok &= np.isfinite(c) & (c > limits.MIN_CORNER_CONTRAST)
        ok &= _neighbourhood_matches(flat, corners_rect[idx], neighbourhood[idx], ring * rectifier.scale)
        previous = accepted.copy()
        accepted[:] = False
        accepted[idx[ok]] = True
        back = projector.rays(rectifier.to_projector(pts))[:, :2]
        refined[idx] = rectifier.camera_px(H, back)
        contrast[idx] = c
        white_clipped[idx] = np.mean(bright >= limits.CLIPPED_LEVEL, axis=1)
        if accepted.sum() < 4:
            break
        cam_norm = camera.rays(refined[accepted])[:, :2]
        # refitted to the corners of one surface: their refined positions fit its homography to their noise
        # (~0.1 px). With a looser gate a board or a person some centimetres before the wall, holding part of
        # the pattern, drew a homography that splits the difference between the two surfaces (each off it by
        # a pixel or so at 2 m): it kept half of each and lost the rest of the wall's corners in that camera,
        # and a plane fitted to the few stereo corners left tilted beyond its own 95 % bound (bench scene 10212)
        H_new, _ = cv2.findHomography(proj_norm[accepted], cam_norm, cv2.RANSAC, SURFACE_RANSAC_PX / f)
        if H_new is None:
            break
        converged = np.array_equal(accepted, previous)
        H = np.asarray(H_new, dtype=np.float64)
        max_shift = limits.MAX_CORNER_SHIFT_REFINED_PX  # H fitted to refined corners predicts sub-pixel
        if converged:
            break
    n_ok = int(accepted.sum())
    if n_ok == 0:
        return _empty(camera_name, _why_no_corners(gray, len(markers)), len(markers))
    ids = np.nonzero(accepted)[0]
    det = Detection(camera_name, ids, refined[ids], camera.rays(refined[ids])[:, :2], len(markers),
                    float(np.median(contrast[ids])), float(np.mean(white_clipped[ids])),
                    kept_fraction=kept_fraction)
    if det.clipped_fraction > limits.MAX_CLIPPED_FRACTION:
        det.warnings.append(f"{camera_name} is over-exposed ({det.clipped_fraction:.0%} of the white squares "
                            "clip); lower the exposure")
    return det


_RING_CACHE: dict[int, tuple[CheckerPattern, NDArray[np.float64], NDArray[np.bool_]]] = {}


def _expected_neighbourhood(pattern: CheckerPattern) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Offsets (16, 2) in projector pixels to the centres of the 4x4 squares around a corner, and for every
    corner (n, 16) whether each should be bright, read from the projector image itself (markers included)."""
    hit = _RING_CACHE.get(id(pattern))
    if hit is not None and hit[0] is pattern:
        return hit[1], hit[2]
    s = pattern.square_px
    steps = np.array([-1.5, -0.5, 0.5, 1.5]) * s
    ring = np.array([[dx, dy] for dy in steps for dx in steps])
    img = pattern.image()
    px = np.round(pattern.corner_projector_px[:, None, :] + 0.5 + ring[None]).astype(int)
    h, w = img.shape
    inside = (px[..., 0] >= 0) & (px[..., 0] < w) & (px[..., 1] >= 0) & (px[..., 1] < h)
    bright = np.zeros(px.shape[:2], dtype=bool)
    bright[inside] = img[px[..., 1][inside], px[..., 0][inside]] > 127
    if len(_RING_CACHE) > 8:
        _RING_CACHE.clear()
    _RING_CACHE[id(pattern)] = (pattern, ring, bright)
    return ring, bright


def _neighbourhood_matches(flat: NDArray[np.float32], corners: NDArray[np.float64], expected: NDArray[np.bool_],
                           ring: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(n,) True where the 16 squares around each corner show the pattern's black and white as they should.

    A periodic checkerboard has X-corners everywhere; on another surface or behind an occluder a corner of the
    wrong identity can sit where one is predicted. Its neighbourhood (markers included) gives it away."""
    values = _sample(flat, (corners[:, None, :] + ring[None]).reshape(-1, 2)).reshape(len(corners), -1)
    seen = np.isfinite(values)
    hi = np.where(seen & expected, values, np.nan)
    lo = np.where(seen & ~expected, values, np.nan)
    with np.errstate(all="ignore"):
        contrast = np.nanmean(hi, axis=1) - np.nanmean(lo, axis=1)
        agree = np.nanmean(np.where(seen, (values > 127.5) == expected, np.nan), axis=1)
    return (seen.sum(axis=1) >= 8) & (contrast > limits.MIN_NEIGHBOURHOOD_CONTRAST) & \
        (agree >= limits.MIN_NEIGHBOURHOOD_AGREEMENT)


_NORM_CACHE: dict[tuple[int, Intrinsics], tuple[CheckerPattern, NDArray[np.float64]]] = {}


def _projector_norm(pattern: CheckerPattern, projector: Intrinsics) -> NDArray[np.float64]:
    """(n, 2) undistorted normalized projector coordinates of the corners (cached per pattern)."""
    key = (id(pattern), projector)
    hit = _NORM_CACHE.get(key)
    if hit is None or hit[0] is not pattern:
        if len(_NORM_CACHE) > 8:
            _NORM_CACHE.clear()
        hit = _NORM_CACHE[key] = (pattern, projector.rays(pattern.corner_projector_px)[:, :2])
    return hit[1]


def _why_no_markers(gray: NDArray[np.uint8]) -> str:
    clipped = float(np.mean(gray >= limits.CLIPPED_LEVEL))
    lo, hi = np.percentile(gray, [2, 98])
    if clipped > limits.MAX_CLIPPED_FRACTION:
        return f"over-exposed: {clipped:.0%} of the pixels clip, so no marker is readable; lower the exposure"
    if hi - lo < limits.MIN_PATTERN_CONTRAST:
        return (f"low contrast: the image spans only {hi - lo:.0f} grey levels; darken the room, raise the "
                "projector's brightness or the camera's exposure")
    return "no marker of the pattern is visible: is the pattern on the wall and in this camera's view?"


def _why_no_corners(gray: NDArray[np.uint8], markers: int) -> str:
    lo, hi = np.percentile(gray, [2, 98])
    if hi - lo < 2 * limits.MIN_PATTERN_CONTRAST:
        return f"low contrast ({hi - lo:.0f} grey levels): {markers} marker(s) seen but no checker corner holds up"
    return f"{markers} marker(s) seen but no checker corner around them holds up (occluded or off the wall?)"
