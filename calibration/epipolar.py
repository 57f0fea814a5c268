"""Quality figures of a stereo calibration: epipolar error, reprojection RMS, and held-out evaluation.

The epipolar error follows OpenCV's stereo_calib sample: undistort both images' corners to pixels of the
same camera matrix, and measure each corner's distance to the epipolar line of its partner. The sample sums
the two images' distances; we report the average per image (the sample's figure / 2). The undistortion is
geometry.Intrinsics' own, iterated to convergence (the sample's cv2.undistortPoints stops after 5 iterations,
which on the real pairs moves the figure by ~4e-5 px).

On held-out pairs the board pose is unknown, so `evaluate_pairs` fits one board pose per pair (shared by both
cameras through the calibrated stereo pose) with the calibration held fixed, then reports the RMS of both
images' reprojection residuals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from calibration.boards import BoardView
from calibration.camera_model import solve_pnp
from geometry.intrinsics import Intrinsics
from geometry.poses import rotation_matrix


def skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fundamental_matrix(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray) -> NDArray:
    """F with x_right^T F x_left = 0 for undistorted pixels."""
    E = skew(T_right_from_left[:3, 3]) @ T_right_from_left[:3, :3]
    return np.linalg.inv(right.K).T @ E @ np.linalg.inv(left.K)


def epipolar_errors(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray,
                    left_pixels: NDArray[np.float64], right_pixels: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per corresponding point (n,): mean of its two point-to-epipolar-line distances (px, per image)."""
    F = fundamental_matrix(left, right, T_right_from_left)
    hl = np.column_stack([left.undistorted_pixels(left_pixels), np.ones(len(left_pixels))])
    hr = np.column_stack([right.undistorted_pixels(right_pixels), np.ones(len(right_pixels))])
    lines_r = hl @ F.T  # epipolar lines in the right image
    lines_l = hr @ F  # in the left image
    dr = np.abs(np.sum(hr * lines_r, axis=1)) / np.hypot(lines_r[:, 0], lines_r[:, 1])
    dl = np.abs(np.sum(hl * lines_l, axis=1)) / np.hypot(lines_l[:, 0], lines_l[:, 1])
    return 0.5 * (dl + dr)


@dataclass
class Evaluation:
    """Figures over a set of pairs: epipolar px per image (mean over pairs), reprojection RMS px."""

    epipolar_px_per_image: float
    reprojection_rms_px: float
    per_pair_epipolar_px: list[float]
    per_pair_rms_px: list[float]


def fit_pair_pose(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray, lv: BoardView,
                  rv: BoardView) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Board pose (6,) in the left camera frame seen by both cameras, and the residuals (2n, 2) px."""
    x0 = solve_pnp(lv.object_points, lv.image_points, left.K, left.dist_array)
    R_rl, t_rl = T_right_from_left[:3, :3], T_right_from_left[:3, 3]

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        R = rotation_matrix(x[:3])
        pl = lv.object_points @ R.T + x[3:]
        pr = (rv.object_points @ R.T + x[3:]) @ R_rl.T + t_rl
        # cv2.projectPoints takes any OpenCV distortion model (the peers' rational one too).
        ul = left.project(pl)
        ur = right.project(pr)
        return np.concatenate([(ul - lv.image_points).ravel(), (ur - rv.image_points).ravel()])

    fit = least_squares(residuals, x0, method="lm", xtol=1e-12, ftol=1e-12)
    return fit.x, fit.fun.reshape(-1, 2)


def evaluate_pairs(left: Intrinsics, right: Intrinsics, T_right_from_left: NDArray,
                   pairs: list[tuple[BoardView, BoardView]]) -> Evaluation:
    """Epipolar error and reprojection RMS of a calibration on pairs (typically ones it was not fitted on)."""
    epi, rms, sq, n = [], [], 0.0, 0
    for lv, rv in pairs:
        epi.append(float(np.mean(epipolar_errors(left, right, T_right_from_left, lv.image_points,
                                                 rv.image_points))))
        _, res = fit_pair_pose(left, right, T_right_from_left, lv, rv)
        s = float(np.sum(res ** 2))
        rms.append(float(np.sqrt(s / len(res))))
        sq += s
        n += len(res)
    return Evaluation(float(np.mean(epi)), float(np.sqrt(sq / n)), epi, rms)
