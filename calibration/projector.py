"""Projector calibration: Gray-code decoding, local homographies, projector as an inverse camera.

Two ways (issue 4):
- **one camera + printed board** (Moreno & Taubin 2012): at each board pose the projector shows the Gray
  code; every camera pixel decodes to a projector pixel; around each board corner a homography fitted from
  the camera pixels to their decoded projector pixels maps the (subpixel) corner into the projector image.
  The projector is then calibrated like a camera that "sees" the board corners there.
- **calibrated stereo pair**: the projected Gray code is decoded in both cameras; a local homography maps a
  grid of projector pixels into each camera with subpixel accuracy; triangulation gives 3-D points on the
  wall; the projector is solved as an inverse camera from (3-D point, projector pixel) pairs.

A flat wall seen from one projector pose cannot fix the projector's intrinsics (focal length trades against
distance); `check_projector_poses` needs ≥ MIN_PROJECTOR_POSES poses whose wall planes are tilted against each
other by ≥ MIN_PLANE_SPREAD_DEG, and says which tilts to add.

Captures follow cv2.structured_light.GrayCodePattern.generate(): for each column bit (most significant
first) the pattern then its inverse, then the same for the rows; then a white and a black image.
"""

from __future__ import annotations

import glob
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2
from scipy.stats import f as f_dist

from calibration.boards import Board, BoardView, detect, read_gray
from calibration.bundle import Observation, bundle_adjust, intrinsics_95
from calibration.camera_model import DISTORTION_MODELS, solve_pnp
from calibration.stereo import calibrate_camera, view_tilt_deg
from calibration.validation import snap_points_to_plane
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, make_pose, pose_from_rvec_tvec
from geometry.robust import best_hypothesis, draw_samples, fit_plane, refine
from geometry.triangulation import triangulate

# --- tolerances, in one place ------------------------------------------------------------------------------
GRAY_MIN_CONTRAST = 4.0  # grey levels between a pattern and its inverse for a bit to count as decoded
SHADOW_MIN_CONTRAST = 15.0  # white minus black: less means the projector does not reach the pixel
SIZE_CHECK_BEYOND_FRACTION = 0.02  # decoded pixels outside the given size: beyond this share, warn
SIZE_CHECK_MIN_PIXELS = 500  # too few decoded pixels say nothing about the size
HOMOGRAPHY_HALF_WINDOW_FRACTION = 0.5  # Moreno-Taubin window half-size, as a fraction of the square in pixels
HOMOGRAPHY_MIN_HALF_WINDOW = 6
HOMOGRAPHY_MAX_HALF_WINDOW = 40
HOMOGRAPHY_MIN_PIXELS = 30  # decoded pixels needed to fit a local homography
HOMOGRAPHY_SURROUND_FRACTION = 0.5  # decoded pixels must reach this far (x half-window) on every side
HOMOGRAPHY_OUTLIER_PX = 1.5  # decoded pixels farther than this (projector px) from the fit are misdecoded
INVERSE_MAP_RADIUS_PX = 6.0  # projector-pixel radius of the patch used to map projector → camera
MIN_PROJECTOR_POSES = 3
MIN_PLANE_SPREAD_DEG = 10.0  # the wall's normal must differ by this much between some poses
MIN_VIEWS_FOR_K3 = 10
# A fit outside these is no projector (a focal length collapsed to 0, say): refused, not written. Throw ratios of
# real projectors give focal lengths of about 0.5-5 image widths.
PROJECTOR_FOCAL_RANGE_WIDTHS = (0.25, 10.0)
PROJECTOR_MAX_ASPECT = 1.2  # fx/fy (square projector pixels: about 1)
PROJECTOR_MAX_RMS_PX = 2.0  # decoded Gray code reprojects to about a tenth of this
WALL_PLANE_TOLERANCE_M = 0.03  # triangulated wall points scatter by ~1 cm in depth at 2 m
WALL_PLANE_ITERATIONS = 200
PROJECTOR_MODEL = "k1k2"  # lens shift puts image corners far off-axis (r ≈ 0.5): k2 matters; p, k3 overfit

Tracker = Callable[[Iterable, str, int], Iterator]


def _plain_iter(items: Iterable, description: str, total: int) -> Iterator:
    del description, total
    yield from items


def gray_code_patterns(width: int, height: int) -> list[NDArray[np.uint8]]:
    """The images to project: GrayCodePattern.generate() order, then white, then black (uint8, h x w)."""
    pattern = cv2.structured_light.GrayCodePattern.create(width, height)
    ok, images = pattern.generate()
    if not ok:
        raise InputError(f"OpenCV could not make Gray code patterns for a {width}x{height} projector")
    white = np.full((height, width), 255, np.uint8)
    return [*(np.asarray(image, dtype=np.uint8) for image in images), white, np.zeros_like(white)]


def gray_code_bits(width: int, height: int) -> tuple[int, int]:
    """(column bits, row bits) of the Gray code for this projector size."""
    return int(np.ceil(np.log2(width))), int(np.ceil(np.log2(height)))


def _decode_codes(captures: list[NDArray] | NDArray, projector_size: tuple[int, int], min_contrast: float,
                  shadow_contrast: float) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
    """(column code, row code, decodable) per camera pixel, before the codes are checked against the size."""
    width, height = projector_size
    n_col, n_row = gray_code_bits(width, height)
    expected = 2 * (n_col + n_row) + 2
    if len(captures) != expected:
        raise InputError(f"{len(captures)} captures given; a {width}x{height} projector's Gray code needs "
                         f"{expected} (2x{n_col} column + 2x{n_row} row patterns, white, black)",
                         "check --projector and that every capture is in the folder")
    imgs = np.stack([np.asarray(c, dtype=np.float32) if np.ndim(c) == 2 else
                     cv2.cvtColor(np.asarray(c), cv2.COLOR_BGR2GRAY).astype(np.float32) for c in captures])
    white, black = imgs[-2], imgs[-1]
    valid = (white - black) >= shadow_contrast

    def decode(first: int, bits: int) -> NDArray[np.int64]:
        value = np.zeros(imgs.shape[1:], np.int64)
        prev = np.zeros(imgs.shape[1:], np.int64)
        nonlocal valid
        for k in range(bits):
            a, b = imgs[first + 2 * k], imgs[first + 2 * k + 1]
            valid &= np.abs(a - b) >= min_contrast
            g = (a > b).astype(np.int64)
            prev = prev ^ g  # Gray → binary, most significant bit first
            value = (value << 1) | prev
        return value

    col = decode(0, n_col)
    row = decode(2 * n_col, n_row)
    return col, row, valid


def decode_gray_code(captures: list[NDArray] | NDArray, projector_size: tuple[int, int],
                     min_contrast: float = GRAY_MIN_CONTRAST,
                     shadow_contrast: float = SHADOW_MIN_CONTRAST) -> NDArray[np.float64]:
    """Projector pixel (column, row) seen by every camera pixel; NaN where undecodable.

    captures: the camera images in pattern order (Gray code pairs, white, black), each (h, w) grey.
    Returns (h, w, 2) float64. Same decoding as GrayCodePattern.getProjPixel (bit = pattern > inverse),
    vectorised; pixels in shadow or with too little contrast in any bit are NaN.
    """
    width, height = projector_size
    col, row, valid = _decode_codes(captures, projector_size, min_contrast, shadow_contrast)
    valid &= (col < width) & (row < height)
    out = np.stack([col, row], axis=-1).astype(np.float64)
    out[~valid] = np.nan
    return out


def projector_size_warning(captures: list[NDArray] | NDArray, projector_size: tuple[int, int],
                           min_contrast: float = GRAY_MIN_CONTRAST,
                           shadow_contrast: float = SHADOW_MIN_CONTRAST) -> str | None:
    """A warning when the decoded codes do not fit the given size: column codes span the width and row codes
    the height, so codes beyond one but inside the other mean WIDTHxHEIGHT was given height first."""
    width, height = projector_size
    col, row, valid = _decode_codes(captures, projector_size, min_contrast, shadow_contrast)
    if valid.sum() < SIZE_CHECK_MIN_PIXELS:
        return None
    beyond = float(np.mean((col[valid] >= width) | (row[valid] >= height)))
    if beyond < SIZE_CHECK_BEYOND_FRACTION:
        return None
    # A high percentile, not the maximum: a few misdecoded pixels reach any code.
    col_span = int(np.percentile(col[valid], 99.5)) + 1
    row_span = int(np.percentile(row[valid], 99.5)) + 1
    what = (f"{100 * beyond:.0f} % of the decoded pixels lie outside a {width}x{height} projector (column codes "
            f"up to {col_span}, row codes up to {row_span})")
    if col_span <= height and row_span <= width:
        return f"--projector {width}x{height} looks swapped: {what}; did you mean {height}x{width} (WIDTHxHEIGHT)?"
    return f"{what}: check --projector (WIDTHxHEIGHT)"


def _fit_homography(src: NDArray[np.float64], dst: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Least-squares homography src → dst (both (n, 2)), conditioned by centring and scaling."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    ss = np.sqrt(2) / max(np.mean(np.linalg.norm(src - ms, axis=1)), 1e-9)
    sd = np.sqrt(2) / max(np.mean(np.linalg.norm(dst - md, axis=1)), 1e-9)
    Ts = np.array([[ss, 0, -ss * ms[0]], [0, ss, -ss * ms[1]], [0, 0, 1]])
    Td = np.array([[sd, 0, -sd * md[0]], [0, sd, -sd * md[1]], [0, 0, 1]])
    H, _ = cv2.findHomography((src - ms) * ss, (dst - md) * sd, 0)
    if H is None:
        return None
    return np.linalg.inv(Td) @ H @ Ts


def _apply_h(H: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    q = H @ np.array([p[0], p[1], 1.0])
    return q[:2] / q[2]


def camera_to_projector(decoded: NDArray[np.float64], camera_points: NDArray[np.float64],
                        half_windows: NDArray[np.int64] | int) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Moreno-Taubin: subpixel projector pixels (n, 2) of camera points (n, 2) via local homographies."""
    h, w = decoded.shape[:2]
    pts = np.asarray(camera_points, dtype=np.float64).reshape(-1, 2)
    halves = np.broadcast_to(np.asarray(half_windows), (len(pts),))
    out = np.full((len(pts), 2), np.nan)
    ok = np.zeros(len(pts), bool)
    for i, (p, r) in enumerate(zip(pts, halves, strict=True)):
        x0, x1 = max(int(p[0]) - r, 0), min(int(p[0]) + r + 1, w)
        y0, y1 = max(int(p[1]) - r, 0), min(int(p[1]) + r + 1, h)
        patch = decoded[y0:y1, x0:x1].reshape(-1, 2)
        ys, xs = np.mgrid[y0:y1, x0:x1]
        cam = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
        good = np.isfinite(patch[:, 0])
        H = _robust_homography(cam[good], patch[good], p, r)
        if H is None:
            continue
        out[i] = _apply_h(H, p)
        ok[i] = True
    return out, ok


def _robust_homography(src: NDArray[np.float64], dst: NDArray[np.float64], centre: NDArray[np.float64],
                       half_window: float) -> NDArray[np.float64] | None:
    """Local homography src → dst from decoded pixels around centre, or None when it cannot be trusted.

    Pixels must surround the centre (a corner at the edge of the lit area is extrapolated otherwise), and
    misdecoded pixels (Gray-code errors at stripe edges and shadow borders) are dropped by their residual.
    """
    if len(src) < HOMOGRAPHY_MIN_PIXELS:
        return None
    reach = HOMOGRAPHY_SURROUND_FRACTION * half_window
    d = src - centre
    if not (d[:, 0].min() < -reach and d[:, 0].max() > reach and d[:, 1].min() < -reach and d[:, 1].max() > reach):
        return None
    keep = np.ones(len(src), bool)
    H = None
    for _ in range(3):
        H = _fit_homography(src[keep], dst[keep])
        if H is None:
            return None
        q = np.column_stack([src, np.ones(len(src))]) @ H.T
        res = np.linalg.norm(q[:, :2] / q[:, 2:3] - dst, axis=1)
        limit = max(HOMOGRAPHY_OUTLIER_PX, 3.0 * float(np.median(res[keep])))
        new_keep = res < limit
        if new_keep.sum() < HOMOGRAPHY_MIN_PIXELS:
            return None
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return H


def projector_to_camera(decoded: NDArray[np.float64], projector_points: NDArray[np.float64],
                        radius: float = INVERSE_MAP_RADIUS_PX) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Subpixel camera pixels (m, 2) where projector pixels (m, 2) land, via local homographies."""
    valid = np.isfinite(decoded[..., 0])
    ys, xs = np.nonzero(valid)
    proj = decoded[ys, xs]
    cam = np.column_stack([xs, ys]).astype(np.float64)
    targets = np.asarray(projector_points, dtype=np.float64).reshape(-1, 2)
    out = np.full((len(targets), 2), np.nan)
    ok = np.zeros(len(targets), bool)
    if len(proj) == 0:
        return out, ok
    # Bucket decoded pixels by projector pixel so each target only looks at its neighbourhood.
    r = int(np.ceil(radius))
    key_cols = int(np.nanmax(proj[:, 0])) + 2 * r + 2
    keys = proj[:, 1].astype(np.int64) * key_cols + proj[:, 0].astype(np.int64)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    for i, t in enumerate(targets):
        rows = np.arange(int(t[1]) - r, int(t[1]) + r + 1)
        lo = np.searchsorted(sorted_keys, rows * key_cols + int(t[0]) - r)
        hi = np.searchsorted(sorted_keys, rows * key_cols + int(t[0]) + r + 1)
        idx = np.concatenate([order[a:b] for a, b in zip(lo, hi, strict=True)])
        if len(idx) < HOMOGRAPHY_MIN_PIXELS:
            continue
        near = idx[np.linalg.norm(proj[idx] - t, axis=1) <= radius]
        if len(near) < HOMOGRAPHY_MIN_PIXELS or np.ptp(proj[near, 0]) < 2 or np.ptp(proj[near, 1]) < 2:
            continue
        H = _fit_homography(proj[near], cam[near])
        if H is None:
            continue
        out[i] = _apply_h(H, t)
        ok[i] = True
    return out, ok


@dataclass
class ProjectorCalibration:
    """Projector intrinsics and its pose per capture; for the board method also the camera and their pose."""

    projector: Intrinsics
    projector_rms_px: float
    T_projector_from_view: list[NDArray[np.float64]]  # per pose: projector from the pose's reference frame
    camera: Intrinsics | None = None
    camera_rms_px: float = float("nan")
    T_projector_from_camera: NDArray[np.float64] | None = None
    per_pose_rms_px: list[float] = field(default_factory=list)
    sources: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    projector_sigma: dict[str, float] | None = None  # σ of fx, fy, cx, cy (px) from the fit's covariance

    def quality(self) -> dict:
        return {
            "projector_rms_px": round(self.projector_rms_px, 4),
            "camera_rms_px": round(self.camera_rms_px, 4) if self.camera is not None else None,
            "poses_used": len(self.T_projector_from_view),
            "per_pose_rms_px": {Path(s).name or str(i): round(r, 4) for i, (s, r) in
                                enumerate(zip(self.sources or [""] * len(self.per_pose_rms_px),
                                              self.per_pose_rms_px, strict=True))},
            "projector": {"fx": self.projector.fx, "fy": self.projector.fy, "cx": self.projector.cx,
                          "cy": self.projector.cy, "dist": list(self.projector.dist)},
            "T_projector_from_camera": (None if self.T_projector_from_camera is None
                                        else np.asarray(self.T_projector_from_camera).tolist()),
            "warnings": list(self.warnings),
            # 95 % bounds (1.96 σ, px) of the projector's fx, fy, cx, cy from the fit's covariance
            "projector_95": None if self.projector_sigma is None else intrinsics_95(self.projector_sigma),
        }


def plane_spread_deg(normals: list[NDArray[np.float64]]) -> float:
    """Largest angle between any two plane normals (sign-free), degrees."""
    n = np.array([v / np.linalg.norm(v) for v in normals])
    c = np.clip(np.abs(n @ n.T), 0.0, 1.0)
    return float(np.degrees(np.arccos(c.min())))


def check_projector_poses(normals_in_projector: list[NDArray[np.float64]], what: str = "projector poses") -> None:
    """InputError when the poses cannot fix projector intrinsics (too few, or planes all alike)."""
    if len(normals_in_projector) < MIN_PROJECTOR_POSES:
        raise InputError(f"{what}: {len(normals_in_projector)} usable pose(s); at least {MIN_PROJECTOR_POSES} "
                         "are needed", "add poses with the surface turned left/right and tilted up/down by "
                         "15-30° relative to the projector")
    spread = plane_spread_deg(normals_in_projector)
    if spread < MIN_PLANE_SPREAD_DEG:
        tilts = [view_tilt_deg(make_pose(_basis_from_normal(n))) for n in normals_in_projector]
        raise InputError(f"{what} are degenerate: the surface planes differ by only {spread:.1f}° (tilts "
                         + ", ".join(f"{y:+.0f}°/{p:+.0f}°" for y, p in tilts)
                         + "); a flat wall at one orientation cannot fix the projector's focal length",
                         f"add poses with the surface (or the head) turned by ≥{MIN_PLANE_SPREAD_DEG + 5:.0f}° "
                         "left/right and up/down")


def _basis_from_normal(n: NDArray[np.float64]) -> NDArray[np.float64]:
    n = n / np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, n)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(n, x), n])


def plane_frame(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """T_frame_from_plane for points (n, 3) near a plane: origin at their centroid, z along the normal."""
    c, n = fit_plane(points)
    if n[2] > 0:
        n = -n  # normal towards the device that looks at it (its z is forward)
    return make_pose(_basis_from_normal(n), c)


def calibrate_inverse_camera(points_3d: list[NDArray[np.float64]], projector_pixels: list[NDArray[np.float64]],
                             projector_size: tuple[int, int], model: str = PROJECTOR_MODEL,
                             sources: list[str] | None = None) -> ProjectorCalibration:
    """Projector intrinsics and per-pose T_projector_from_reference from 3-D points and their projector pixels.

    points_3d[i]: (n_i, 3) metres in pose i's reference frame (e.g. the left camera), on (near) one plane;
    projector_pixels[i]: (n_i, 2) px. Initialised by treating each plane as a board (cv2.calibrateCamera),
    then refined with the points' true 3-D positions.
    """
    if model not in DISTORTION_MODELS:
        raise InputError(f"distortion model {model!r} is unknown", f"use one of {', '.join(DISTORTION_MODELS)}")
    frames = [plane_frame(p) for p in points_3d]
    local = [(p - T[:3, 3]) @ T[:3, :3] for p, T in zip(points_3d, frames, strict=True)]  # plane coordinates
    w, h = projector_size
    flat_obj = [np.column_stack([q[:, :2], np.zeros(len(q))]).astype(np.float32) for q in local]
    img = [np.asarray(u, np.float32).reshape(-1, 1, 2) for u in projector_pixels]
    f0 = 1.5 * w
    K0 = np.array([[f0, 0, (w - 1) / 2], [0, f0, (h - 1) / 2], [0, 0, 1.0]])
    normals = []
    for q, u in zip(local, projector_pixels, strict=True):
        x = solve_pnp(np.column_stack([q[:, :2], np.zeros(len(q))]), u, K0, np.zeros(5))
        normals.append(pose_from_rvec_tvec(x[:3], x[3:])[:3, 2])
    check_projector_poses(normals)
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
    if model in ("none", "k1"):
        flags |= cv2.CALIB_FIX_K2 | (cv2.CALIB_FIX_K1 if model == "none" else 0)
    try:  # a focal length that goes through 0 on the way (garbage in) is refused like a degenerate result
        _, K, dist, _, _ = cv2.calibrateCamera(flat_obj, img, (w, h), K0, np.zeros(5), flags=flags)
        intr0 = Intrinsics.from_K(K, w, h, dist.ravel()[:5])
        poses0 = []
        for q, u in zip(local, projector_pixels, strict=True):
            x = solve_pnp(q, u, intr0.K, intr0.dist_array)
            poses0.append(pose_from_rvec_tvec(x[:3], x[3:]))
        observations = [Observation(0, i, np.asarray(u, np.float64), q)
                        for i, (q, u) in enumerate(zip(local, projector_pixels, strict=True))]
        fit = bundle_adjust([intr0], [model], observations, poses0)
    except InputError as err:
        raise InputError(f"the projector fit is degenerate ({err.message}), nothing written", DEGENERATE_HINT
                         ) from None
    check_projector_fit(fit.cameras[0], fit.rms_px)
    T_proj_from_ref = [T @ invert(F) for T, F in zip(fit.T_0_from_view, frames, strict=True)]
    per_pose = [float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) for r in fit.residuals]
    return ProjectorCalibration(fit.cameras[0], fit.rms_px, T_proj_from_ref, per_pose_rms_px=per_pose,
                                sources=list(sources or []), projector_sigma=fit.intrinsics_sigma[0])


DEGENERATE_HINT = ("the captured pictures do not match the patterns shown: check that the cameras see the projected "
                   "image on the wall with nothing in the beam, and that each capture shows its pattern (raise "
                   "--settle), then calibrate again")


def check_projector_fit(projector: Intrinsics, rms_px: float) -> None:
    """InputError when a fitted projector is degenerate: the captures cannot have shown the patterns in order."""
    lo, hi = PROJECTOR_FOCAL_RANGE_WIDTHS
    w = projector.width
    problems = [f"{k} = {v:.1f} px is not {lo:g}-{hi:g} image widths" for k, v in
                (("fx", projector.fx), ("fy", projector.fy)) if not lo * w <= v <= hi * w]
    if not problems and max(projector.fx / projector.fy, projector.fy / projector.fx) > PROJECTOR_MAX_ASPECT:
        problems.append(f"fx/fy = {projector.fx / projector.fy:.2f} (square pixels: about 1)")
    if not rms_px <= PROJECTOR_MAX_RMS_PX:
        problems.append(f"the points reproject to {rms_px:.2f} px RMS (limit {PROJECTOR_MAX_RMS_PX:g})")
    if problems:
        raise InputError("the projector fit is degenerate (" + "; ".join(problems) + "), nothing written",
                         DEGENERATE_HINT)


# --- stereo path ---------------------------------------------------------------------------------------------

def projector_grid(projector_size: tuple[int, int], step_px: int) -> NDArray[np.float64]:
    """Projector pixels (m, 2) on a regular grid with margin, row by row."""
    w, h = projector_size
    xs = np.arange(step_px // 2, w - step_px // 2 + 1, step_px, dtype=np.float64)
    ys = np.arange(step_px // 2, h - step_px // 2 + 1, step_px, dtype=np.float64)
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def stereo_correspondences(decoded_left: NDArray[np.float64], decoded_right: NDArray[np.float64],
                           projector_size: tuple[int, int], step_px: int = 32
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(left camera pixels (m, 2), right camera pixels (m, 2), projector pixels (m, 2)) of a grid of projector
    pixels found in both cameras' decoded Gray code; all empty when fewer than 12."""
    grid = projector_grid(projector_size, step_px)
    cl, okl = projector_to_camera(decoded_left, grid)
    cr, okr = projector_to_camera(decoded_right, grid)
    ok = okl & okr
    if ok.sum() < 12:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2))
    return cl[ok], cr[ok], grid[ok]


def wall_points_from_stereo(decoded_left: NDArray[np.float64], decoded_right: NDArray[np.float64],
                            left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray[np.float64],
                            projector_size: tuple[int, int], step_px: int = 32
                            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(3-D points (m, 3) in the left camera frame, projector pixels (m, 2)) for one projected Gray code."""
    cl, cr, grid = stereo_correspondences(decoded_left, decoded_right, projector_size, step_px)
    return triangulate(left, right, T_right_from_left, cl, cr), grid


def on_wall_plane(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray[np.float64],
                  left_px: NDArray[np.float64], right_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """Wall points (n, 3) triangulated from both cameras' pixels and moved onto their fitted plane along both
    camera rays. The inverse-camera fit takes its points as exact; the stereo pair's depth noise (5-10 mm per
    point on the simulated site's small cameras at 2 m) would bias it (errors in the variables: the focal
    length came out 0.9 % short and cy 1 px off with the truth's stereo pair); on the plane each point keeps a
    ray's lateral precision and gets the depth precision of the whole plane."""
    X = triangulate(left, right, T_right_from_left, left_px, right_px)
    snapped, _ = snap_points_to_plane(X, left, right, T_right_from_left, left_px, right_px,
                                      max_rms_m=WALL_PLANE_TOLERANCE_M)
    return snapped


def wall_inliers(points: NDArray[np.float64], tolerance_m: float = WALL_PLANE_TOLERANCE_M,
                 seed: int = 0) -> NDArray[np.bool_]:
    """The points (n, 3) on the dominant plane (RANSAC, then least squares): the wall, without whatever stands
    in the beam before it (a board still held up, a person); the inverse-camera fit starts from one plane per
    pose."""
    n = len(points)
    if n < 3:
        return np.ones(n, bool)
    samples = draw_samples(np.random.default_rng(seed), n, 3, WALL_PLANE_ITERATIONS)
    a, b, c = points[samples[:, 0]], points[samples[:, 1]], points[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    length = np.linalg.norm(normals, axis=1)
    normals = normals / np.where(length > 1e-12, length, np.inf)[:, None]  # degenerate samples score 0 ...
    offsets = np.einsum("ij,ij->i", normals, a)

    def support(h: slice) -> NDArray[np.int64]:
        d = np.abs(points @ normals[h].T - offsets[h])
        return np.asarray(np.sum(d < tolerance_m, axis=0) * (length[h] > 1e-12), np.int64)  # ... here

    best = best_hypothesis(len(samples), support, chunk=256)

    def refit(inliers: NDArray[np.bool_]) -> tuple[None, NDArray[np.bool_]]:
        centre, normal = fit_plane(points[inliers])
        return None, np.abs((points - centre) @ normal) < tolerance_m

    first = np.abs(points @ normals[best] - offsets[best]) < tolerance_m
    _, inliers = refine(first, refit, rounds=3, min_inliers=3)
    return inliers


def small_sample_widening(dims: int, dof: int, level: float = 0.95) -> float:
    """How much wider a covariance estimated with `dof` degrees of freedom must be for its χ²_dims region at
    `level` to hold that share: Hotelling's T² quantile over χ²'s (Student's t² over z² for one dimension)."""
    dims = min(dims, dof)  # fewer samples than dimensions: their spread spans only dof directions
    t2 = dof * dims / (dof - dims + 1) * float(f_dist.ppf(level, dims, dof - dims + 1))
    return t2 / float(chi2.ppf(level, dims))


@dataclass
class ProjectorSamples:
    """Other outcomes the projector fit could have had, each (intrinsics, T_projector_from_view per pose):
    `jackknife`, one per pose left out (the poses' own errors, whatever their correlation within a pose), and
    `stereo`, one per draw of the stereo pair from its covariance (the triangulated points move with it)."""

    jackknife: list[tuple[Intrinsics, list[NDArray[np.float64]]]]
    stereo: list[tuple[Intrinsics, list[NDArray[np.float64]]]]

    def covariance(self, f: Callable[[Intrinsics, list[NDArray[np.float64]]], NDArray[np.float64]],
                   dims: int = 1) -> NDArray[np.float64]:
        """Covariance of f(intrinsics, poses): the jackknife's ((n-1)/n Σ), widened for its few degrees of
        freedom, plus the stereo draws' sample covariance. dims: how many of f's values are judged together
        (1: a scalar's ±1.96 σ; 3: a vector's χ²₃ ellipsoid); the widening makes that 95 % region a 95 % region
        despite the n - 1 degrees of freedom: Student's t² for a scalar, Hotelling's T² for a vector."""
        out: NDArray[np.float64] | float = 0.0
        if len(self.jackknife) >= 2:
            v = np.array([f(*s) for s in self.jackknife])
            n = len(v)
            d = v - v.mean(axis=0)
            out = out + small_sample_widening(dims, n - 1) * (n - 1) / n * d.T @ d
        if len(self.stereo) >= 2:
            out = out + np.atleast_2d(np.cov(np.array([f(*s) for s in self.stereo]), rowvar=False))
        return np.asarray(out, dtype=np.float64)


def projector_poses(points_3d: list[NDArray[np.float64]], projector_pixels: list[NDArray[np.float64]],
                    projector: Intrinsics) -> list[NDArray[np.float64]]:
    """T_projector_from_reference per pose for given intrinsics (PnP on each pose's points)."""
    out = []
    for X, u in zip(points_3d, projector_pixels, strict=True):
        x = solve_pnp(X, u, projector.K, projector.dist_array)
        out.append(pose_from_rvec_tvec(x[:3], x[3:]))
    return out


def projector_samples(points_3d: list[NDArray[np.float64]], projector_pixels: list[NDArray[np.float64]],
                      projector_size: tuple[int, int], camera_pixels: list[tuple[NDArray[np.float64],
                                                                               NDArray[np.float64]]],
                      stereo_draws: list[tuple[Intrinsics, Intrinsics, NDArray[np.float64]]],
                      model: str = PROJECTOR_MODEL) -> ProjectorSamples:
    """The projector refitted with each pose left out (then every pose solved with those intrinsics) and with
    the points triangulated by each stereo draw onto their wall plane (on_wall_plane; camera_pixels: per pose,
    its left and right pixels)."""
    jackknife = []
    for i in range(len(points_3d)):
        keep = [j for j in range(len(points_3d)) if j != i]
        try:
            fit = calibrate_inverse_camera([points_3d[j] for j in keep], [projector_pixels[j] for j in keep],
                                           projector_size, model)
        except InputError:
            continue  # this pose was needed to fix the intrinsics: the jackknife goes without it
        jackknife.append((fit.projector, projector_poses(points_3d, projector_pixels, fit.projector)))
    stereo = []
    for left, right, T_rl in stereo_draws:
        X = [on_wall_plane(left, right, T_rl, cl, cr) for cl, cr in camera_pixels]
        fit = calibrate_inverse_camera(X, projector_pixels, projector_size, model)
        stereo.append((fit.projector, fit.T_projector_from_view))
    return ProjectorSamples(jackknife, stereo)


# --- one camera + printed board (Moreno & Taubin) ------------------------------------------------------------

@dataclass
class BoardCaptures:
    """One board pose: the captured images in pattern order (Gray code pairs, white, black)."""

    images: list[NDArray]
    source: str = ""


def board_corners_in_projector(board: Board, capture: BoardCaptures, projector_size: tuple[int, int]
                               ) -> tuple[BoardView | None, BoardView | None]:
    """(camera view of the board, projector 'view' of the board) for one pose; None when not found."""
    white = capture.images[-2]
    cam_view = detect(board, white, source=capture.source)
    if cam_view is None:
        return None, None
    decoded = decode_gray_code(capture.images, projector_size)
    pts = cam_view.image_points
    # Window from the board's square size in the image (nearest-neighbour spacing of its corners).
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    spacing = float(np.median(d.min(axis=1)))
    half = int(np.clip(round(HOMOGRAPHY_HALF_WINDOW_FRACTION * spacing), HOMOGRAPHY_MIN_HALF_WINDOW,
                       HOMOGRAPHY_MAX_HALF_WINDOW))
    proj, ok = camera_to_projector(decoded, pts, half)
    if ok.sum() < max(6, len(pts) // 2):
        return cam_view, None
    proj_view = BoardView(proj[ok], cam_view.object_points[ok], cam_view.ids[ok], projector_size, capture.source)
    return cam_view, proj_view


def calibrate_projector_with_board(board: Board, captures: list[BoardCaptures], projector_size: tuple[int, int],
                                   camera: Intrinsics | None = None, model: str = PROJECTOR_MODEL,
                                   track: Tracker = _plain_iter) -> ProjectorCalibration:
    """Moreno & Taubin projector (and camera) calibration from Gray-code captures of a printed board."""
    cam_views: list[BoardView] = []
    proj_views: list[BoardView] = []
    warnings: list[str] = []
    # The first pose suffices: the size is the same at every pose.
    size_warning = projector_size_warning(captures[0].images, projector_size) if captures else None
    if size_warning is not None:
        warnings.append(size_warning)
    for cap in track(captures, "decoding Gray code", len(captures)):
        cv_, pv = board_corners_in_projector(board, cap, projector_size)
        if cv_ is None:
            warnings.append(f"{cap.source}: board not found in the white image (pose skipped)")
            continue
        if pv is None:
            warnings.append(f"{cap.source}: too few board corners lit by the projector (pose skipped)")
            continue
        keep = np.isin(cv_.ids, pv.ids)
        cam_views.append(BoardView(cv_.image_points[keep], cv_.object_points[keep], cv_.ids[keep],
                                   cv_.image_size, cv_.source))
        proj_views.append(pv)
    if len(cam_views) < MIN_PROJECTOR_POSES:
        raise InputError(f"only {len(cam_views)} usable board pose(s) ({'; '.join(warnings) or 'none given'})",
                         f"capture at least {MIN_PROJECTOR_POSES} poses, the board tilted differently each time")
    camera_fixed = camera is not None
    # k3 needs many views; with a handful it overfits and drags the focal length along.
    camera_model = "k1k2p1p2k3" if len(cam_views) >= MIN_VIEWS_FOR_K3 else "k1k2p1p2"
    if camera is None:
        camera = calibrate_camera(cam_views, model=camera_model, camera="camera").intrinsics
    T_cam_from_board = []
    for v in cam_views:
        x = solve_pnp(v.object_points, v.image_points, camera.K, camera.dist_array)
        T_cam_from_board.append(pose_from_rvec_tvec(x[:3], x[3:]))
    # Board points in the camera frame are 3-D points on one plane per pose: the inverse-camera solver gives
    # the projector's intrinsics and its pose relative to the camera at every board pose ...
    pts3d = [v.object_points @ T[:3, :3].T + T[:3, 3] for v, T in zip(cam_views, T_cam_from_board, strict=True)]
    inverse = calibrate_inverse_camera(pts3d, [pv.image_points for pv in proj_views], projector_size, model,
                                       sources=[pv.source for pv in proj_views])
    # ... then, the projector being rigid with the camera, one joint refinement of camera (unless given),
    # projector, their relative pose and the board poses.
    observations = []
    for i, (cv_, pv) in enumerate(zip(cam_views, proj_views, strict=True)):
        observations.append(Observation(0, i, cv_.image_points, cv_.object_points))
        observations.append(Observation(1, i, pv.image_points, pv.object_points))
    fit = bundle_adjust([camera, inverse.projector], [camera_model, model], observations, T_cam_from_board,
                        _mean_pose(inverse.T_projector_from_view), fixed=[camera_fixed, False])
    assert fit.T_1_from_0 is not None  # two cameras: the bundle refined the projector's pose
    cam_res = np.concatenate(fit.residuals[0::2])
    proj_res = fit.residuals[1::2]
    return ProjectorCalibration(
        projector=fit.cameras[1],
        projector_rms_px=float(np.sqrt(np.mean(np.sum(np.concatenate(proj_res) ** 2, axis=1)))),
        T_projector_from_view=[fit.T_1_from_0] * len(cam_views),
        camera=fit.cameras[0],
        camera_rms_px=float(np.sqrt(np.mean(np.sum(cam_res ** 2, axis=1)))),
        T_projector_from_camera=fit.T_1_from_0,
        per_pose_rms_px=[float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) for r in proj_res],
        sources=[pv.source for pv in proj_views],
        warnings=warnings + inverse.warnings,
        projector_sigma=fit.intrinsics_sigma[1],
    )


def _mean_pose(poses: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """Chordal mean of rotations and mean translation."""
    M = sum(T[:3, :3] for T in poses)
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return make_pose(R, np.mean([T[:3, 3] for T in poses], axis=0))


def load_board_captures(pattern: str, projector_size: tuple[int, int],
                        track: Tracker = _plain_iter) -> list[BoardCaptures]:
    """One BoardCaptures per folder matching pattern; images in a folder are sorted by name."""
    folders = sorted(Path(p) for p in glob.glob(str(Path(pattern).expanduser())) if Path(p).is_dir())
    if not folders:
        raise InputError(f"--captures: no folders match {pattern!r}",
                         "give a glob of folders, one per board pose, e.g. 'DIR/capture_*' (quoted)")
    w, h = projector_size
    n_col, n_row = gray_code_bits(w, h)
    expected = 2 * (n_col + n_row) + 2
    out = []
    for folder in track(folders, "reading captures", len(folders)):
        files = sorted(f for f in folder.iterdir() if f.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp",
                                                                           ".tif", ".tiff", ".pgm"))
        if len(files) != expected:
            raise InputError(f"{folder}: {len(files)} images, but a {w}x{h} projector's Gray code needs {expected} "
                             f"({2 * n_col} column + {2 * n_row} row patterns, then white, then black)",
                             "check --projector and re-capture this pose")
        out.append(BoardCaptures([read_gray(f) for f in files], str(folder)))
    return out


def calibrate_projector_from_folders(pattern: str, projector_size: tuple[int, int], board: Board,
                                     camera: Intrinsics | None = None,
                                     track: Tracker = _plain_iter) -> ProjectorCalibration:
    """`arproj calibrate projector`: folders of captures → projector (and camera) calibration."""
    captures = load_board_captures(pattern, projector_size, track)
    return calibrate_projector_with_board(board, captures, projector_size, camera, track=track)
