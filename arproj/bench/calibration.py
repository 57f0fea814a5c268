"""Calibration: real stereo images vs OpenCV's pipelines (held-out pairs), and every simulated-site quantity vs truth.

Real data (../shared/data/opencv-stereo-chessboard, 13 pairs): calibrate on half the pairs, evaluate on the
other half, and the other way round; the figures are the mean of both halves. Peers, run here on the same
images: OpenCV's stereo_calib sample (initCameraMatrix2D + stereoCalibrate with its flags, rational model)
and the two-stage pipeline (calibrateCamera per camera, stereoCalibrate with FIX_INTRINSIC), both on
OpenCV's corners (findChessboardCorners + cornerSubPix 11x11, as the sample does). Rows "on arproj corners"
separate what the corner refinement gains from what the joint calibration gains.

Single camera (the left images alone): cv2.calibrateCamera on OpenCV's corners against arproj's
calibrate_camera on the same corners (every view kept: the target is the same RMS within 1 %) and arproj end to
end (its own corners, outlier views dropped), as `arproj calibrate camera` runs it.

Simulated site (arproj.sim, seed): the wizard's four steps; each recovered quantity against the truth.

Simulated live calibration (arproj.sim.live in its own process, small images; --live-seeds N, default LIVE_SEEDS,
--quick: QUICK_LIVE_SEEDS; the stereo pair from LIVE_STEREO_POSES board views, --quick: QUICK_LIVE_STEREO_POSES):
`calibrate projector --live --sim` end to end; per recovered quantity its coverage, the share of seeds whose error
lies within its reported 95 % bound, with the 95 % Wilson interval of that share (target ≥ 95 %), and the coverage
pooled over every (seed, quantity) check; beside it the mean error and mean bound, and the error in units of its
bound (|e| / bound, for vectors the Mahalanobis distance over √χ²₃,₀.₉₅: within when ≤ 1; an exact normal bound
gives a median of 0.34 for a scalar, 0.55 for a vector, so a median well below those is a bound wider than the
errors justify). Judged on the interval: met when it lies above 95 %, not met when it lies below, unknown while it
spans 95 % (a handful of seeds cannot tell an honest 95 % bound from a slightly over-confident one). For the mount
the design value's error is given beside it (the peer: the value the product used before).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from arproj.bench import BenchTable, cells, column, columns
from calibration.boards import Board, BoardView, detect_file, parse_board, read_gray
from calibration.defaults import DEFAULT_BOARD
from calibration.epipolar import evaluate_pairs
from calibration.stereo import calibrate_camera, calibrate_stereo, pair_views
from geometry.intrinsics import Intrinsics
from geometry.poses import make_pose

REAL_BOARD = "chessboard:9x6:0.025"
OPENCV_SUBPIX_WINDOW = (11, 11)  # the stereo_calib sample's window
# Seeds of the full run: the Wilson lower end of k/n reaches 95 % only from 73 of 73 (80 of 80: 95.4 %), so fewer
# seeds can never show a quantity's coverage met; 80 also tell a 90 % coverage (upper end ≤ 95 %) from a 99 % one.
LIVE_SEEDS = 80
QUICK_LIVE_SEEDS = 1
LIVE_WORKERS = 3  # seeds at once in the full run (each mostly waits for its site's frames)
# Board views of the live run's stereo step, --quick too: from 10 views seed 30's mount step found the laser on
# no panel ("0 of 5 views") and seed 0's projector fx was 1.22 bounds out (16 views: 0.56).
LIVE_STEREO_POSES = 16
QUICK_LIVE_STEREO_POSES = 16
LIVE_TARGET = 0.95
WILSON_Z = 1.959964  # two-sided 95 % normal quantile
SIM_TARGETS = {"camera focal": 0.2, "camera principal point": 1.0, "baseline": 0.5, "projector focal": 0.5,
               "projector principal point": 2.0, "head orientation": 0.05, "head position": 1.0,
               "validation (measured by the stereo pair)": 1.0, "validation (vs true landing points)": 1.0}


def _data_folder() -> Path | None:
    import os

    root = Path(os.environ.get("ARPROJ_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
    folder = root / "opencv-stereo-chessboard"
    return folder if folder.is_dir() else None


def opencv_corners(board: Board, path: Path) -> BoardView | None:
    """Corners the way OpenCV's stereo_calib sample finds them."""
    img = read_gray(path)
    found, corners = cv2.findChessboardCorners(img, board.pattern_size,
                                               cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    corners = cv2.cornerSubPix(img, corners, OPENCV_SUBPIX_WINDOW, (-1, -1),
                               (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 30, 0.01))
    pts = corners.reshape(-1, 2).astype(np.float64)
    if pts[0].sum() > pts[-1].sum():
        pts = pts[::-1].copy()
    return BoardView(pts, board.object_points(), np.arange(len(pts)), (img.shape[1], img.shape[0]), str(path))


def _cv_lists(pairs: list[tuple[BoardView, BoardView]]) -> tuple[list, list, list]:
    obj = [lv.object_points.astype(np.float32) for lv, _ in pairs]
    return (obj, [lv.image_points.astype(np.float32).reshape(-1, 1, 2) for lv, _ in pairs],
            [rv.image_points.astype(np.float32).reshape(-1, 1, 2) for _, rv in pairs])


def opencv_sample_pipeline(pairs: list[tuple[BoardView, BoardView]], size: tuple[int, int]) -> tuple:
    """OpenCV's samples/cpp/stereo_calib.cpp: (rms, left, right, T_right_from_left)."""
    obj, il, ir = _cv_lists(pairs)
    K1 = cv2.initCameraMatrix2D(obj, il, size, 0)
    K2 = cv2.initCameraMatrix2D(obj, ir, size, 0)
    flags = (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_USE_INTRINSIC_GUESS
             | cv2.CALIB_SAME_FOCAL_LENGTH | cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_K4
             | cv2.CALIB_FIX_K5)
    rms, K1, d1, K2, d2, R, T, _, _ = cv2.stereoCalibrate(
        obj, il, ir, K1, np.zeros(8), K2, np.zeros(8), size, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-5))
    return (float(rms), Intrinsics.from_K(K1, *size, d1.ravel()), Intrinsics.from_K(K2, *size, d2.ravel()),
            make_pose(R, T.ravel()))


def opencv_two_stage_pipeline(pairs: list[tuple[BoardView, BoardView]], size: tuple[int, int]) -> tuple:
    """calibrateCamera per camera, then stereoCalibrate with FIX_INTRINSIC."""
    obj, il, ir = _cv_lists(pairs)
    _, K1, d1, _, _ = cv2.calibrateCamera(obj, il, size, None, None)
    _, K2, d2, _, _ = cv2.calibrateCamera(obj, ir, size, None, None)
    rms, K1, d1, K2, d2, R, T, _, _ = cv2.stereoCalibrate(obj, il, ir, K1, d1, K2, d2, size,
                                                          flags=cv2.CALIB_FIX_INTRINSIC)
    return (float(rms), Intrinsics.from_K(K1, *size, d1.ravel()), Intrinsics.from_K(K2, *size, d2.ravel()),
            make_pose(R, T.ravel()))


def _arproj_pipeline(pairs: list[tuple[BoardView, BoardView]], board: Board) -> tuple:
    c = calibrate_stereo([lv for lv, _ in pairs], [rv for _, rv in pairs], board)
    return c.rms_px, c.left, c.right, c.T_right_from_left


SINGLE_CAMERA_TOLERANCE = 0.01  # arproj on OpenCV's corners = calibrateCamera within this relative RMS


def single_camera_comparison(folder: Path) -> dict[str, float]:
    """RMS (px) on the left images alone: cv2.calibrateCamera on OpenCV's corners, arproj's calibrate_camera on
    the same corners with every view kept (the same k1 k2 p1 p2 k3 model), and arproj end to end."""
    board = parse_board(REAL_BOARD)
    files = sorted(folder.glob("left*.jpg"))
    cv_views = [v for v in (opencv_corners(board, f) for f in files) if v is not None]
    rms, *_ = cv2.calibrateCamera([v.object_points.astype(np.float32) for v in cv_views],
                                  [v.image_points.astype(np.float32).reshape(-1, 1, 2) for v in cv_views],
                                  cv_views[0].image_size, None, None)
    on_cv = calibrate_camera(cv_views, reject_outliers=False)
    own = calibrate_camera([v for v in (detect_file(board, f) for f in files) if v is not None])
    return {"opencv calibrateCamera": float(rms), "arproj on OpenCV's corners": on_cv.rms_px,
            "arproj": own.rms_px, "arproj views rejected": float(len(own.rejected))}


class HeldOut(NamedTuple):
    """A pipeline calibrated on half the pairs and evaluated on the other half, the mean of both ways round."""

    epipolar_px_per_image: float
    reprojection_rms_px: float
    seconds: float   # per calibration


@dataclass
class RealComparison:
    """Held-out figures per pipeline, and the training RMS (px) on all pairs of arproj and both OpenCV
    pipelines (the data's README gives the latter two)."""

    held_out: dict[str, HeldOut]
    training_rms_px: dict[str, float]


@dataclass
class CalibrationRow:
    """A real-data pipeline (epipolar, RMS, time) or a simulated quantity (error, target, met)."""

    case: str = column("case")
    epipolar_px: float | str = column("epipolar px/img", "")
    rms_px: float | str = column("reproj. RMS px", "")
    error: float | str = column("error", "")
    target: str = column("target", "")
    met_or_time: str = column("met / time", "")


class SimFigure(NamedTuple):
    value: float
    unit: str


def held_out_comparison(folder: Path, attribution: bool = True) -> RealComparison:
    """Held-out epipolar error (px per image) and reprojection RMS (px) of arproj and both OpenCV pipelines.

    attribution adds the peers run on arproj's corners and arproj evaluated on OpenCV's corners.
    """
    board = parse_board(REAL_BOARD)
    lf, rf = sorted(folder.glob("left*.jpg")), sorted(folder.glob("right*.jpg"))
    from calibration.boards import detect_file

    ours = pair_views([detect_file(board, f) for f in lf], [detect_file(board, f) for f in rf], board)
    theirs = pair_views([opencv_corners(board, f) for f in lf], [opencv_corners(board, f) for f in rf], board)
    size = ours[0][0].image_size
    n = min(len(ours), len(theirs))
    halves = [(list(range(0, n, 2)), list(range(1, n, 2))), (list(range(1, n, 2)), list(range(0, n, 2)))]
    pipelines = {
        "arproj": (lambda p: _arproj_pipeline(p, board), ours, ours),
        "opencv stereo_calib": (lambda p: opencv_sample_pipeline(p, size), theirs, theirs),
        "opencv two-stage": (lambda p: opencv_two_stage_pipeline(p, size), theirs, theirs),
        "opencv stereo_calib on arproj corners": (lambda p: opencv_sample_pipeline(p, size), ours, ours),
        "opencv two-stage on arproj corners": (lambda p: opencv_two_stage_pipeline(p, size), ours, ours),
        "arproj, evaluated on opencv corners": (lambda p: _arproj_pipeline(p, board), ours, theirs),
    }
    if not attribution:
        pipelines = {k: v for k, v in pipelines.items() if k in ("arproj", "opencv stereo_calib",
                                                                  "opencv two-stage")}
    held_out: dict[str, HeldOut] = {}
    for name, (pipeline, train_set, test_set) in pipelines.items():
        epi, rms, seconds = [], [], 0.0
        for train, test in halves:
            started = time.perf_counter()
            _, left, right, T = pipeline([train_set[i] for i in train])
            seconds += time.perf_counter() - started
            ev = evaluate_pairs(left, right, T, [test_set[i] for i in test])
            epi.append(ev.epipolar_px_per_image)
            rms.append(ev.reprojection_rms_px)
        held_out[name] = HeldOut(float(np.mean(epi)), float(np.mean(rms)), seconds / 2)
    all_pairs = list(range(n))
    training = {
        "opencv stereo_calib": opencv_sample_pipeline([theirs[i] for i in all_pairs], size)[0],
        "opencv two-stage": opencv_two_stage_pipeline([theirs[i] for i in all_pairs], size)[0],
    }
    if attribution:
        training["arproj"] = _arproj_pipeline([ours[i] for i in all_pairs], board)[0]
    return RealComparison(held_out, training)


def simulated_site(seed: int, quick: bool) -> dict:
    """Run the wizard on the simulated site; every quantity's error against the truth."""
    from arproj.wizard import run_wizard

    with tempfile.TemporaryDirectory() as tmp:
        state = run_wizard(Path(tmp), sim=True, seed=seed, stereo_poses=10 if quick else None)
    return {step: state["steps"][step] for step in ("stereo", "projector", "head", "validation")}


def _sim_figures(sim: dict) -> dict[str, SimFigure]:
    """Each simulated quantity's error against the truth (the worst of its parts), from the wizard's state."""
    st, pr, hd, va = (sim[k]["truth_errors"] for k in ("stereo", "projector", "head", "validation"))
    cam_f = max(abs(st[c][k]) for c in ("camera_left", "camera_right") for k in ("fx_pct", "fy_pct"))
    cam_c = max(abs(st[c][k]) for c in ("camera_left", "camera_right") for k in ("cx_px", "cy_px"))
    return {
        "camera focal": SimFigure(cam_f, "%"), "camera principal point": SimFigure(cam_c, "px"),
        "baseline": SimFigure(abs(st["baseline_mm"]), "mm"),
        "projector focal": SimFigure(max(abs(pr["fx_pct"]), abs(pr["fy_pct"])), "%"),
        "projector principal point": SimFigure(max(abs(pr["cx_px"]), abs(pr["cy_px"])), "px"),
        "head orientation": SimFigure(hd["rotation_max_deg"], "°"),
        "head position": SimFigure(hd["position_max_mm"], "mm"),
        "validation (measured by the stereo pair)": SimFigure(sim["validation"]["quality"]["rms_mm"], "mm"),
        "validation (vs true landing points)": SimFigure(va["rms_mm"], "mm"),
    }


def live_seed(seed: int, stereo_poses: int = LIVE_STEREO_POSES) -> dict[str, dict]:
    """One simulated live calibration (`calibrate projector --live --sim --small`): its truth checks by quantity.
    Its printed summary and progress are dropped (it may run in a worker process beside others)."""
    import contextlib
    import io

    from arproj.cli.calibrate import live_projector_command
    from arproj.wizard.live_run import LiveOptions

    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()), \
            contextlib.redirect_stderr(io.StringIO()):
        opts = LiveOptions(screen="", left="", projector_size=(0, 0), rig=Path(tmp) / "rig",
                           board=DEFAULT_BOARD, stereo_poses=stereo_poses, head_poses=7, mount_poses=6)
        summary = live_projector_command(opts, "", sim=True, small=True, seed=seed, as_json=True)
    return summary["truth"]


def simulated_live(seeds: list[int], stereo_poses: int = LIVE_STEREO_POSES, workers: int = 1
                   ) -> dict[str, list[dict]]:
    """Live calibration on the simulated site per seed: {quantity: [truth check per seed]}, seeds in order.

    workers > 1 runs that many seeds at once, each in its own (spawned) process with its own simulated site: a
    seed spends most of its time waiting for the site's frames to settle, not computing."""
    if workers > 1 and len(seeds) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(min(workers, len(seeds)), mp_context=multiprocessing.get_context("spawn")) as pool:
            results = list(pool.map(live_seed, seeds, [stereo_poses] * len(seeds)))
    else:
        results = [live_seed(s, stereo_poses) for s in seeds]
    per_quantity: dict[str, list[dict]] = {}
    for truth in results:
        for name, check in truth.items():
            per_quantity.setdefault(name, []).append(check)
    return per_quantity


class Coverage(NamedTuple):
    """How many of `trials` checks held (error within its 95 % bound), and the 95 % Wilson interval of that share."""

    within: int
    trials: int
    low: float
    high: float

    @property
    def share(self) -> float:
        return self.within / self.trials

    @property
    def verdict(self) -> bool | None:
        """Against LIVE_TARGET: True when the whole interval is at or above it, False when the whole interval is
        below it, None (unknown) while the interval spans it."""
        if self.low >= LIVE_TARGET:
            return True
        if self.high < LIVE_TARGET:
            return False
        return None


def wilson_interval(within: int, trials: int, z: float = WILSON_Z) -> tuple[float, float]:
    """The Wilson score interval of a binomial share within/trials (stays inside [0, 1], sane at 0 and n)."""
    if trials <= 0:
        raise ValueError("a coverage needs at least one trial")
    p = within / trials
    z2n = z * z / trials
    centre = (p + z2n / 2) / (1 + z2n)
    half = z / (1 + z2n) * np.sqrt(p * (1 - p) / trials + z2n / (4 * trials))
    return max(0.0, float(centre - half)), min(1.0, float(centre + half))


def coverage(flags: list[bool]) -> Coverage:
    within = int(sum(bool(f) for f in flags))
    return Coverage(within, len(flags), *wilson_interval(within, len(flags)))


def live_coverage(per_quantity: dict[str, list[dict]]) -> tuple[dict[str, Coverage], Coverage]:
    """Per quantity the coverage over its seeds, and the coverage pooled over every (seed, quantity) check.

    The pooled interval treats the checks as independent; the quantities of one seed share its data (the head
    checks share one fit), so it is narrower than the evidence strictly allows: the per-quantity rows are the
    verdict, the pooled row a summary."""
    per = {name: coverage([c["within"] for c in checks]) for name, checks in per_quantity.items()}
    pooled = coverage([c["within"] for checks in per_quantity.values() for c in checks])
    return per, pooled


def _coverage_text(c: Coverage) -> str:
    return f"{c.within}/{c.trials} = {100 * c.share:.0f} % (95 % CI {100 * c.low:.0f}–{100 * c.high:.0f} %)"


def _verdict_text(v: bool | None) -> str:
    return "unknown" if v is None else ("yes" if v else "NO")


def run(quick: bool = False, seed: int = 0, live_seeds: int | None = None) -> BenchTable:
    """live_seeds: seeds of the simulated live calibration (seed, seed + 1, …); default QUICK_LIVE_SEEDS with
    quick, else LIVE_SEEDS."""
    n_live = live_seeds if live_seeds is not None else (QUICK_LIVE_SEEDS if quick else LIVE_SEEDS)
    if n_live < 1:
        raise ValueError(f"--live-seeds {n_live}: give at least 1")
    rows: list[CalibrationRow] = []
    headline: dict = {}
    notes: list[str] = []
    folder = _data_folder()
    if folder is not None:
        real = held_out_comparison(folder)
        best_peer = min(("opencv stereo_calib", "opencv two-stage"),
                        key=lambda k: real.held_out[k].epipolar_px_per_image)
        for name, fig in real.held_out.items():
            rows.append(CalibrationRow(f"real held-out: {name}", fig.epipolar_px_per_image, fig.reprojection_rms_px,
                                       met_or_time=f"{1000 * fig.seconds:.0f} ms"))
        ref = real.training_rms_px
        notes.append(f"all 13 pairs (training RMS, README: 0.605 / 0.447 px): stereo_calib "
                     f"{ref['opencv stereo_calib']:.3f} px, two-stage {ref['opencv two-stage']:.3f} px, "
                     f"arproj {ref['arproj']:.3f} px")
        for key, label in (("epipolar_px_per_image", "held-out epipolar px/image"),
                           ("reprojection_rms_px", "held-out reprojection RMS px")):
            ours = getattr(real.held_out["arproj"], key)
            peer = min(getattr(real.held_out["opencv stereo_calib"], key),
                       getattr(real.held_out["opencv two-stage"], key))
            headline[label] = {"arproj": round(ours, 4), "peer": round(peer, 4),
                               "peer_name": f"best OpenCV pipeline ({best_peer})", "unit": " px",
                               "target": "≤ best OpenCV pipeline", "met": ours <= peer}
        mono = single_camera_comparison(folder)
        cv_rms, on_cv = mono["opencv calibrateCamera"], mono["arproj on OpenCV's corners"]
        same = abs(on_cv / cv_rms - 1) <= SINGLE_CAMERA_TOLERANCE
        rows.append(CalibrationRow("real single camera (left): opencv calibrateCamera", rms_px=cv_rms))
        rows.append(CalibrationRow("real single camera (left): arproj on OpenCV's corners", rms_px=on_cv,
                                   error=f"{100 * (on_cv / cv_rms - 1):+.2f} %",
                                   target=f"= calibrateCamera ± {100 * SINGLE_CAMERA_TOLERANCE:g} %",
                                   met_or_time="yes" if same else "NO"))
        rows.append(CalibrationRow("real single camera (left): arproj", rms_px=mono["arproj"],
                                   met_or_time=f"{mono['arproj views rejected']:.0f} view(s) rejected"))
        headline["single camera RMS px (OpenCV's corners)"] = {
            "arproj": round(on_cv, 4), "peer": round(cv_rms, 4), "peer_name": "cv2.calibrateCamera",
            "unit": " px", "target": f"within {100 * SINGLE_CAMERA_TOLERANCE:g} %", "met": same}
    else:
        notes.append("real images not found (../shared/data/opencv-stereo-chessboard): real-data rows skipped")

    sim = simulated_site(seed, quick)
    for name, sim_fig in _sim_figures(sim).items():
        target = SIM_TARGETS[name]
        rows.append(CalibrationRow(f"sim: {name} error", error=sim_fig.value, target=f"≤ {target} {sim_fig.unit}",
                                   met_or_time="yes" if sim_fig.value <= target else "NO"))
        headline[f"sim {name} error"] = {"arproj": round(sim_fig.value, 4), "unit": f" {sim_fig.unit}",
                                         "target": f"≤ {target}", "met": sim_fig.value <= target, "peer": "–",
                                         "peer_name": "simulated truth"}
    notes.append(f"sim: stereo RMS {sim['stereo']['quality']['reprojection_rms_px']:.3f} px; projector RMS "
                 f"{sim['projector']['quality']['projector_rms_px']:.3f} px; head errors are maxima over 3 head "
                 f"angles not used for fitting; validation at those angles, "
                 f"{sim['validation']['truth_errors']['distance_m']:.2f} m away")
    started = time.perf_counter()
    live = simulated_live([seed + k for k in range(n_live)], QUICK_LIVE_STEREO_POSES if quick else LIVE_STEREO_POSES,
                          workers=1 if quick else LIVE_WORKERS)
    live_seconds = time.perf_counter() - started
    per, pooled = live_coverage(live)
    for name, checks in live.items():
        c, unit = per[name], checks[0]["unit"]
        peer = (f"design value {np.mean([k['design_error'] for k in checks]):.3g} {unit}; "
                if "design_error" in checks[0] else "")
        shares = [k["share_of_bound"] for k in checks]
        rows.append(CalibrationRow(f"sim live: {name} within its 95 % bound",
                                   error=f"{_coverage_text(c)}; mean |error| "
                                   f"{np.mean([abs(k['error']) for k in checks]):.3g} {unit}, mean bound "
                                   f"{np.mean([k['bound'] for k in checks]):.3g} {unit}; error in bounds: median "
                                   f"{np.median(shares):.2f}, max {np.max(shares):.2f}",
                                   target=f"≥ {100 * LIVE_TARGET:.0f} %", met_or_time=peer + _verdict_text(c.verdict)))
    rows.append(CalibrationRow(f"sim live: all {len(per)} quantities pooled", error=_coverage_text(pooled),
                               target=f"≥ {100 * LIVE_TARGET:.0f} %",
                               met_or_time=f"{_verdict_text(pooled.verdict)}; {live_seconds / n_live:.0f} s/seed"))
    notes.append(f"sim live: {n_live} seed(s) ({seed}…{seed + n_live - 1}), stereo pair from "
                 f"{QUICK_LIVE_STEREO_POSES if quick else LIVE_STEREO_POSES} board views; coverage = share of seeds "
                 f"whose error is within the reported 95 % bound, 95 % Wilson interval; met when the interval is above "
                 f"{100 * LIVE_TARGET:.0f} %, NO when below, unknown while it spans it; the pooled interval treats "
                 f"the checks of one seed as independent (they are not: a summary, not the verdict)")
    worst = min(per, key=lambda k: per[k].share) if per else None
    verdicts = [c.verdict for c in per.values()]
    headline["sim live: coverage of the 95 % bounds, pooled"] = {
        "arproj": _coverage_text(pooled), "unit": "", "target": f"≥ {LIVE_TARGET}", "met": pooled.verdict,
        "peer": "–", "peer_name": "simulated truth"}
    headline["sim live: coverage of the 95 % bounds, worst quantity"] = {
        "arproj": f"{worst}: {_coverage_text(per[worst])}" if worst else "–", "unit": "",
        "target": f"≥ {LIVE_TARGET} each",
        "met": False if False in verdicts else (True if verdicts and all(verdicts) else None),
        "peer": "–", "peer_name": "simulated truth"}
    return BenchTable(
        name="calibration",
        title="calibration — held-out real stereo pairs vs OpenCV; simulated site vs truth",
        columns=columns(CalibrationRow), rows=[cells(r) for r in rows], notes=notes, headline=headline,
        environment={"opencv": cv2.__version__, "seed": seed, "quick": quick, "live_seeds": n_live})
