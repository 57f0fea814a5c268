"""Camera and stereo calibration from board views: per-camera, then stereo, then one joint refinement.

Pipeline (calibrate_stereo):
1. each camera alone (cv2.calibrateCamera) on every view it saw, dropping outlier views (per-view RMS far
   above the median) one at a time;
2. the stereo pose from the pairs both cameras kept (cv2.stereoCalibrate with fixed intrinsics) — OpenCV's
   R, T (X_right = R X_left + T) become T_camera_right_from_camera_left here and nowhere else;
3. a joint bundle adjustment of both cameras' intrinsics, the stereo pose and one board pose per capture
   (shared by both images of a pair: that coupling is what the two-stage OpenCV pipeline lacks), then
   outlier pairs are dropped and the adjustment repeated.

The distortion model is chosen by the caller (default k1 k2 p1 p2 k3, OpenCV's plumb_bob). Measured on
OpenCV's stereo sample images (held-out pairs), the tangential terms matter (epipolar 0.137 → 0.108 px) while
k3 changes nothing; OpenCV's rational model overfits half the pairs.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.boards import Board, BoardView, reverse_view
from calibration.bundle import BundleResult, Observation, bundle_adjust
from calibration.camera_model import DISTORTION_MODELS, dist5_from, solve_pnp
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import make_pose, pose_from_rvec_tvec, rvec_tvec_from_pose

# --- tolerances and thresholds, in one place --------------------------------------------------------------
MIN_VIEWS = 4  # fewer views leave focal length, principal point and distortion poorly determined
OUTLIER_FACTOR = 3.0  # a view is an outlier when its RMS exceeds this many times the median …
OUTLIER_MIN_PX = 0.5  # … and this absolute floor (sharp views all sit well below it)
FRONTAL_MAX_DEG = 12.0  # boards tilted less than this are "frontal": they cannot fix the focal length
TILT_BIN_DEG = 20.0  # coverage: a tilt direction counts as covered from this angle on
COVERAGE_GRID = 3  # coverage: the image is split into 3x3 regions
COVERAGE_MIN_FRACTION = 0.02  # a region is covered when it holds this fraction of all corners
REGION_NAMES = (("top-left", "top", "top-right"), ("left", "centre", "right"),
                ("bottom-left", "bottom", "bottom-right"))
DEFAULT_MODEL = "k1k2p1p2k3"
MIN_PAIR_CORNERS = 6  # a pair needs this many corners seen by both cameras
# A pair whose two images disagree with the stereo geometry (the board moved between the exposures, a corner
# mismatched) shows in its epipolar error even where the shared board pose hides it in the reprojection RMS.
# Robust outlier test over the pairs: above the median by this many robust standard deviations (1.4826 MAD) …
EPIPOLAR_OUTLIER_SIGMAS = 3.5
EPIPOLAR_OUTLIER_MIN_PX = 0.15  # … and above this floor (good pairs of real cameras lie at 0.05-0.17 px)
# quality gate: sub-pixel corners leave residuals of a few tenths of a pixel (OpenCV's sample pairs: 0.2 px RMS,
# 0.11 px epipolar); a wrong board size or mixed-up images leaves tens to thousands. The limit grows with the
# image, as blur and corner error in pixels do.
GATE_MIN_PX = 1.0
GATE_PER_DIAGONAL_PX = 1.0 / 1000.0  # limit = max(GATE_MIN_PX, this × the image diagonal in pixels)
GATE_BASELINE_PER_DISTANCE = 2.0  # both cameras saw the board: a baseline past twice its distance cannot be


@dataclass
class CameraCalibration:
    """One camera: intrinsics, the views used (with their board poses), per-view RMS, rejected views."""

    intrinsics: Intrinsics
    rms_px: float
    views: list[BoardView]
    T_camera_from_board: list[NDArray[np.float64]]
    per_view_rms_px: list[float]
    rejected: list[tuple[str, float]] = field(default_factory=list)  # (source, rms px)
    distortion_model: str = DEFAULT_MODEL

    def quality(self) -> dict:
        """The figures `arproj calibrate camera` writes and prints, laid out as the stereo command's."""
        return {
            "reprojection_rms_px": round(self.rms_px, 4),
            "views_used": len(self.views),
            "views_rejected": [{"view": source, "rms_px": round(rms, 4),
                                "why": f"view RMS {rms:.3f} px above {OUTLIER_FACTOR:g}x the median view RMS "
                                       f"and above {OUTLIER_MIN_PX:g} px"} for source, rms in self.rejected],
            "distortion_model": self.distortion_model,
            "per_view_rms_px": {Path(v.source).name: round(r, 4) for v, r in
                                zip(self.views, self.per_view_rms_px, strict=True)},
            "coverage": coverage_report(self.views, self.T_camera_from_board),
        }


@dataclass
class StereoCalibration:
    """Both cameras, T_camera_right_from_camera_left, and the quality figures of the joint refinement."""

    left: Intrinsics
    right: Intrinsics
    T_right_from_left: NDArray[np.float64]
    rms_px: float
    epipolar_px_per_image: float
    pair_sources: list[tuple[str, str]]
    per_pair_rms_px: list[float]
    T_left_from_board: list[NDArray[np.float64]]
    per_pair_epipolar_px: list[float] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    rejected_why: dict[str, str] = field(default_factory=dict)  # pair → the test it failed, with its figure
    coverage: dict = field(default_factory=dict)
    mono_rms_px: tuple[float, float] = (float("nan"), float("nan"))
    distortion_model: str = DEFAULT_MODEL
    bundle: BundleResult | None = None  # the joint refinement (its covariance: stereo_covariance_doc)

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T_right_from_left[:3, 3]))

    def quality(self) -> dict:
        """The figures written into rig.yaml and printed by --json."""
        return {
            "reprojection_rms_px": round(self.rms_px, 4),
            "epipolar_error_px_per_image": round(self.epipolar_px_per_image, 4),
            "mono_rms_px": {"camera_left": round(self.mono_rms_px[0], 4),
                            "camera_right": round(self.mono_rms_px[1], 4)},
            "baseline_m": round(self.baseline_m, 6),
            "pairs_used": len(self.pair_sources),
            "pairs_rejected": list(self.rejected),
            "pairs_rejected_why": dict(self.rejected_why),
            "distortion_model": self.distortion_model,
            "per_pair_rms_px": {f"{Path(a).name} | {Path(b).name}": round(r, 4) for (a, b), r in
                                zip(self.pair_sources, self.per_pair_rms_px, strict=True)},
            "per_pair_epipolar_px": {f"{Path(a).name} | {Path(b).name}": round(e, 4) for (a, b), e in
                                     zip(self.pair_sources, self.per_pair_epipolar_px, strict=True)},
            "coverage": self.coverage,
        }


def residual_limit_px(size: tuple[int, int]) -> float:
    """The largest RMS / epipolar residual (px) a sound calibration of images of this size shows."""
    return max(GATE_MIN_PX, GATE_PER_DIAGONAL_PX * float(np.hypot(*size)))


def camera_quality_problems(calib: CameraCalibration) -> list[str]:
    """Why a camera calibration is far outside its expected residuals (empty: it is not)."""
    limit = residual_limit_px(calib.intrinsics.size)
    if np.isfinite(calib.rms_px) and calib.rms_px <= limit:
        return []
    return [f"reprojection RMS {calib.rms_px:.2f} px (a sound one stays under {limit:.2f} px)"]


def stereo_quality_problems(calib: StereoCalibration) -> list[str]:
    """Why a stereo calibration is far outside its expected residuals or geometry (empty: it is not)."""
    limit = residual_limit_px(calib.left.size)
    problems = []
    if not (np.isfinite(calib.rms_px) and calib.rms_px <= limit):
        problems.append(f"reprojection RMS {calib.rms_px:.2f} px (a sound one stays under {limit:.2f} px)")
    if not (np.isfinite(calib.epipolar_px_per_image) and calib.epipolar_px_per_image <= limit):
        problems.append(f"epipolar error {calib.epipolar_px_per_image:.2f} px per image (under {limit:.2f} px)")
    distances = [float(np.linalg.norm(T[:3, 3])) for T in calib.T_left_from_board]
    distance = float(np.median(distances)) if distances else float("nan")
    if not (np.isfinite(calib.baseline_m) and calib.baseline_m <= GATE_BASELINE_PER_DISTANCE * distance):
        problems.append(f"baseline {calib.baseline_m:.3f} m, implausible with the board {distance:.2f} m away "
                        f"(at most {GATE_BASELINE_PER_DISTANCE:g}x that, or one camera could not see it)")
    return problems


def _calib_flags(model: str) -> int:
    free = DISTORTION_MODELS[model]
    flags = 0
    if 2 not in free:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    for index, flag in ((0, cv2.CALIB_FIX_K1), (1, cv2.CALIB_FIX_K2), (4, cv2.CALIB_FIX_K3)):
        if index not in free:
            flags |= flag
    return flags


def _check_model(model: str) -> None:
    if model not in DISTORTION_MODELS:
        raise InputError(f"distortion model {model!r} is unknown", f"use one of {', '.join(DISTORTION_MODELS)}")


def _view_rms(view: BoardView, K: NDArray, dist: NDArray, T_cam_from_board: NDArray) -> float:
    rvec, tvec = rvec_tvec_from_pose(T_cam_from_board)
    uv, _ = cv2.projectPoints(view.object_points, rvec, tvec, K, dist)
    return float(np.sqrt(np.mean(np.sum((uv.reshape(-1, 2) - view.image_points) ** 2, axis=1))))


def view_tilt_deg(T_camera_from_board: NDArray[np.float64]) -> tuple[float, float]:
    """(yaw, pitch) of the board normal seen from the camera, degrees: yaw > 0 turned right, pitch > 0 down."""
    n = T_camera_from_board[:3, 2].copy()
    if n[2] > 0:
        n = -n  # the normal towards the camera
    return (float(np.degrees(np.arctan2(n[0], -n[2]))), float(np.degrees(np.arctan2(n[1], -n[2]))))


def guess_tilts(views: list[BoardView]) -> list[float]:
    """Board tilt (degrees from frontal) per view from a rough camera guess (focal = image width).

    Good enough to tell frontal from tilted before any calibration exists.
    """
    out = []
    for v in views:
        w, h = v.image_size
        K = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1.0]])
        x = solve_pnp(v.object_points, v.image_points, K, np.zeros(5))
        T = pose_from_rvec_tvec(x[:3], x[3:])
        yaw, pitch = view_tilt_deg(T)
        out.append(float(np.hypot(yaw, pitch)))
    return out


def check_views(views: list[BoardView], camera: str = "camera") -> None:
    """InputError when there are too few views or all of them are frontal."""
    if len(views) < MIN_VIEWS:
        names = ", ".join(v.source for v in views) or "none"
        raise InputError(f"{camera}: only {len(views)} usable board view(s) ({names}); at least {MIN_VIEWS} "
                         "are needed", "take more pictures of the board, tilted in different directions and "
                         "filling different parts of the image")
    tilts = guess_tilts(views)
    if max(tilts) < FRONTAL_MAX_DEG:
        raise InputError(f"{camera}: every board view is frontal (largest tilt {max(tilts):.0f}°, views "
                         f"{', '.join(v.source for v in views[:6])}{'…' if len(views) > 6 else ''}); the focal "
                         "length cannot be determined", f"add views with the board turned or tilted by "
                         f"{TILT_BIN_DEG:.0f}-45° towards the camera")


def calibrate_camera(views: list[BoardView], model: str = DEFAULT_MODEL, reject_outliers: bool = True,
                     camera: str = "camera") -> CameraCalibration:
    """Calibrate one camera from its board views, dropping outlier views one at a time."""
    _check_model(model)
    check_views(views, camera)
    size = views[0].image_size
    for v in views:
        if v.image_size != size:
            raise InputError(f"{v.source}: image size {v.image_size[0]}x{v.image_size[1]} differs from "
                             f"{views[0].source} ({size[0]}x{size[1]})", "use images from one camera mode")
    kept = list(views)
    rejected: list[tuple[str, float]] = []
    while True:
        obj = [v.object_points.astype(np.float32) for v in kept]
        img = [v.image_points.astype(np.float32).reshape(-1, 1, 2) for v in kept]
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
        rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None, flags=_calib_flags(model),
                                                         criteria=criteria)
        poses = [pose_from_rvec_tvec(r, t) for r, t in zip(rvecs, tvecs, strict=True)]
        per_view = [_view_rms(v, K, dist, T) for v, T in zip(kept, poses, strict=True)]
        worst = int(np.argmax(per_view))
        limit = max(OUTLIER_FACTOR * float(np.median(per_view)), OUTLIER_MIN_PX)
        if not reject_outliers or per_view[worst] <= limit or len(kept) <= MIN_VIEWS:
            break
        rejected.append((kept[worst].source, per_view[worst]))
        del kept[worst]
    intr = Intrinsics.from_K(K, size[0], size[1], dist5_from(np.asarray(dist, dtype=np.float64)))
    return CameraCalibration(intr, float(rms), kept, poses, per_view, rejected, model)


def _orient_pair(left: BoardView, right: BoardView, board: Board | None) -> BoardView:
    """Number the right view's corners like the left's (a chessboard may be found from either end)."""
    if board is None or board.kind != "chessboard":
        return right
    dl = left.image_points[-1] - left.image_points[0]
    dr = right.image_points[-1] - right.image_points[0]
    return reverse_view(right, board) if float(dl @ dr) < 0 else right


def _common(left: BoardView, right: BoardView) -> tuple[BoardView, BoardView]:
    """Keep the corners both views saw (ChArUco boards may be partly hidden)."""
    common = np.intersect1d(left.ids, right.ids)
    if len(common) == len(left.ids) == len(right.ids):
        return left, right

    def keep(v: BoardView) -> BoardView:
        sel = np.isin(v.ids, common)
        return replace(v, image_points=v.image_points[sel], object_points=v.object_points[sel], ids=v.ids[sel])

    return keep(left), keep(right)


def pair_views(left_views: list[BoardView | None], right_views: list[BoardView | None],
               board: Board | None = None) -> list[tuple[BoardView, BoardView]]:
    """The pairs where both cameras found the board, numbered alike and cut to the corners both saw."""
    pairs = []
    for lv, rv in zip(left_views, right_views, strict=True):
        if lv is not None and rv is not None:
            lv2, rv2 = _common(lv, _orient_pair(lv, rv, board))
            if len(lv2.ids) >= MIN_PAIR_CORNERS:
                pairs.append((lv2, rv2))
    return pairs


def calibrate_stereo(left_views: list[BoardView | None], right_views: list[BoardView | None],
                     board: Board | None = None, model: str = DEFAULT_MODEL,
                     reject_outliers: bool = True) -> StereoCalibration:
    """Calibrate a stereo pair from aligned view lists (entry i of each is the same moment; None = not found).

    Views seen by one camera only still help that camera's intrinsics.
    """
    _check_model(model)
    if len(left_views) != len(right_views):
        raise InputError(f"{len(left_views)} left images but {len(right_views)} right images",
                         "give one right image per left image, taken at the same moment")
    pairs = pair_views(left_views, right_views, board)
    if len(pairs) < MIN_VIEWS:
        raise InputError(f"the board was found in both images of only {len(pairs)} pair(s); at least "
                         f"{MIN_VIEWS} are needed", "take more pairs with the whole board in view of both cameras")
    left_all = [v for v in left_views if v is not None]
    right_all = [v for v in right_views if v is not None]
    mono_left = calibrate_camera(left_all, model, reject_outliers, "camera_left")
    mono_right = calibrate_camera(right_all, model, reject_outliers, "camera_right")
    left_rejected = {s for s, _ in mono_left.rejected}
    rejected_sources = left_rejected | {s for s, _ in mono_right.rejected}
    rejected = sorted(rejected_sources)
    why = {source: f"{'left' if source in left_rejected else 'right'} camera alone: view RMS above "
                   f"{OUTLIER_FACTOR:g}x the median view's and {OUTLIER_MIN_PX:g} px" for source in rejected}
    pairs = [(lv, rv) for lv, rv in pairs if lv.source not in rejected_sources
             and rv.source not in rejected_sources]
    while True:
        result = _joint(pairs, mono_left, mono_right, model)
        outlier = _outlier_pair(result) if reject_outliers and len(pairs) > MIN_VIEWS else None
        if outlier is None:
            break
        worst, reason = outlier
        name = f"{pairs[worst][0].source} | {pairs[worst][1].source}"
        rejected.append(name)
        why[name] = reason
        del pairs[worst]
    result.rejected = rejected
    result.rejected_why = why
    result.coverage = coverage_report([lv for lv, _ in pairs], result.T_left_from_board)
    result.mono_rms_px = (mono_left.rms_px, mono_right.rms_px)
    return result


def _outlier_pair(result: StereoCalibration) -> tuple[int, str] | None:
    """The worst pair by reprojection RMS, else by epipolar error, when it fails its test; (index, why)."""
    rms = np.asarray(result.per_pair_rms_px)
    worst = int(np.argmax(rms))
    limit = max(OUTLIER_FACTOR * float(np.median(rms)), OUTLIER_MIN_PX)
    if rms[worst] > limit:
        return worst, (f"pair RMS {rms[worst]:.3f} px above {OUTLIER_FACTOR:g}x the median pair's and "
                       f"{OUTLIER_MIN_PX:g} px")
    epi = np.asarray(result.per_pair_epipolar_px)
    worst = int(np.argmax(epi))
    median = float(np.median(epi))
    spread = 1.4826 * float(np.median(np.abs(epi - median)))
    limit = max(median + EPIPOLAR_OUTLIER_SIGMAS * spread, EPIPOLAR_OUTLIER_MIN_PX)
    if epi[worst] > limit:
        return worst, (f"epipolar error {epi[worst]:.3f} px per image above {limit:.3f} px (the median pair's "
                       f"{median:.3f} px + {EPIPOLAR_OUTLIER_SIGMAS:g} robust standard deviations)")
    return None


def _joint(pairs: list[tuple[BoardView, BoardView]], mono_left: CameraCalibration,
           mono_right: CameraCalibration, model: str) -> StereoCalibration:
    from calibration.epipolar import epipolar_errors

    K1, d1 = mono_left.intrinsics.K, mono_left.intrinsics.dist_array
    K2, d2 = mono_right.intrinsics.K, mono_right.intrinsics.dist_array
    obj = [lv.object_points.astype(np.float32) for lv, _ in pairs]
    _, _, _, _, _, R, T, _, _ = cv2.stereoCalibrate(
        obj, [lv.image_points.astype(np.float32) for lv, _ in pairs],
        [rv.image_points.astype(np.float32) for _, rv in pairs], K1, d1, K2, d2, mono_left.intrinsics.size,
        flags=cv2.CALIB_FIX_INTRINSIC)
    T_right_from_left = make_pose(R, T.ravel())  # OpenCV: X_right = R X_left + T

    observations = []
    poses0 = []
    for i, (lv, rv) in enumerate(pairs):
        observations.append(Observation(0, i, lv.image_points, lv.object_points))
        observations.append(Observation(1, i, rv.image_points, rv.object_points))
        x = solve_pnp(lv.object_points, lv.image_points, K1, d1)
        poses0.append(pose_from_rvec_tvec(x[:3], x[3:]))
    fit = bundle_adjust([mono_left.intrinsics, mono_right.intrinsics], [model, model], observations, poses0,
                        T_right_from_left)
    left, right = fit.cameras
    assert fit.T_1_from_0 is not None  # two cameras: the bundle refined the right one's pose
    per_pair = [float(np.sqrt(np.mean(np.sum(np.concatenate([fit.residuals[2 * i], fit.residuals[2 * i + 1]]) ** 2,
                                             axis=1)))) for i in range(len(pairs))]
    epi = [float(np.mean(epipolar_errors(left, right, fit.T_1_from_0, lv.image_points, rv.image_points)))
           for lv, rv in pairs]
    return StereoCalibration(left, right, fit.T_1_from_0, fit.rms_px, float(np.mean(epi)),
                             [(lv.source, rv.source) for lv, rv in pairs], per_pair, fit.T_0_from_view,
                             per_pair_epipolar_px=epi, distortion_model=model, bundle=fit)


def stereo_covariance_doc(calib: StereoCalibration) -> dict:
    """The joint refinement's covariance of both cameras' intrinsics and T_right_from_left (rvec, tvec), as
    written into rig.yaml's stereo quality, so later steps can carry the pair's uncertainty."""
    assert calib.bundle is not None and calib.bundle.covariance is not None
    return {"parameters": list(calib.bundle.parameters),
            "matrix": [[float(f"{v:.6g}") for v in row] for row in calib.bundle.covariance]}


def sample_stereo(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray[np.float64], doc: dict,
                  distortion_model: str, rng: np.random.Generator, n: int
                  ) -> list[tuple[Intrinsics, Intrinsics, NDArray[np.float64]]]:
    """n draws of (left, right, T_right_from_left) from a stereo_covariance_doc."""
    fit = BundleResult([left, right], np.asarray(T_right_from_left, dtype=np.float64), [], [],
                       covariance=np.asarray(doc["matrix"], dtype=np.float64), parameters=list(doc["parameters"]),
                       models=[distortion_model] * 2, fixed=[False, False])
    out = []
    for (l_, r_), T in fit.sample_cameras(rng, n):
        assert T is not None
        out.append((l_, r_, T))
    return out


def coverage_report(views: list[BoardView], T_camera_from_board: list[NDArray[np.float64]]) -> dict:
    """What the views cover: corner share per image region, tilt directions seen, and what is missing."""
    if not views:
        return {"regions_missing": [name for row in REGION_NAMES for name in row], "tilts_missing": []}
    w, h = views[0].image_size
    pts = np.concatenate([v.image_points for v in views])
    ix = np.clip((pts[:, 0] / w * COVERAGE_GRID).astype(int), 0, COVERAGE_GRID - 1)
    iy = np.clip((pts[:, 1] / h * COVERAGE_GRID).astype(int), 0, COVERAGE_GRID - 1)
    counts = np.zeros((COVERAGE_GRID, COVERAGE_GRID))
    np.add.at(counts, (iy, ix), 1)
    share = counts / counts.sum()
    missing_regions = [REGION_NAMES[r][c] for r in range(COVERAGE_GRID) for c in range(COVERAGE_GRID)
                       if share[r, c] < COVERAGE_MIN_FRACTION]
    tilts = [view_tilt_deg(T) for T in T_camera_from_board]
    seen = {
        "turned left": any(y <= -TILT_BIN_DEG for y, _ in tilts),
        "turned right": any(y >= TILT_BIN_DEG for y, _ in tilts),
        "tilted up": any(p <= -TILT_BIN_DEG for _, p in tilts),
        "tilted down": any(p >= TILT_BIN_DEG for _, p in tilts),
    }
    return {
        "region_share": np.round(share, 3).tolist(),
        "regions_missing": missing_regions,
        "tilts_deg": [[round(y, 1), round(p, 1)] for y, p in tilts],
        "tilts_missing": [k for k, v in seen.items() if not v],
    }


def coverage_advice(coverage: dict) -> list[str]:
    """Plain sentences saying which views to add."""
    advice = []
    if coverage.get("regions_missing"):
        advice.append("no board corners yet in the image region(s): " + ", ".join(coverage["regions_missing"])
                      + " — hold the board there")
    if coverage.get("tilts_missing"):
        advice.append(f"no view with the board {', '.join(coverage['tilts_missing'])} by ≥{TILT_BIN_DEG:.0f}° "
                      "— add such views")
    return advice
