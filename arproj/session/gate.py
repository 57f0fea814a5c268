"""The safety gate: the map is shown only while the registration on the wall is believed within tolerance.

Evidence comes from independent sources, so that each failure the gate must catch shows up in at least one:

    wall-pose covariance (and its "not enough evidence")   pattern occluded, low contrast, few corners
    head: reported vs commanded angles                      head stalled, lost command
    closed loop: projected check marks triangulated by the  head slipped (encoder unaware), projector moved,
    stereo pair vs where the model says they land           wrong or outdated rig file
    stereo triangulation residual of those marks            wrong rig file (cameras disagree with it)
    2D laser scan matched against the scan at estimation    robot moved (in-plane motion is invisible to
                                                            the cameras: camera, projector and pattern move
                                                            together)

decide() turns them into a GateDecision: show the map, or the reasons why not.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from arproj.session import tolerances as tol

HEAD_COMMAND_TOLERANCE_DEG = 0.05
ROBOT_MOTION_TOLERANCE_M = 0.003   # at the wall: translation plus heading change × distance, once significant
ROBOT_MOTION_CHI2 = 16.27          # χ² (3 dof, 99.9 %) of the scan match's (dx, dy, dθ) beyond its own noise
STEREO_RESIDUAL_MAX_PX = 1.0       # reprojection residual of triangulated check marks (root median square)
MIN_VISIBLE_FRACTION = 0.3         # fewer check marks seen than this fraction: pattern lost
LASER_PLANE_TOLERANCE_M = 0.006    # laser and cameras disagree about the wall by more: wrong rig / moved camera
SCAN_MATCH_NEIGHBOURS = 8
SCAN_MATCH_MAX_PAIR_M = 0.15
SCAN_MATCH_ITERATIONS = 12


@dataclass
class RegistrationEvidence:
    """What the session knows about its registration now. Lengths in metres on the wall."""

    pose_sigma_m: float | None = None
    pose_failure: str | None = None
    head_command_error_deg: float = 0.0
    closed_loop_errors_m: NDArray[np.float64] | None = None  # (k,) per seen check mark
    closed_loop_expected: int = 0
    # the affine error field the marks measured, at its worst over the drawn area (marks cover only part of it)
    closed_loop_field_max_m: float = float("nan")
    stereo_residual_px: float | None = None
    robot_motion_m: float = 0.0
    robot_motion_significant: bool = True  # beyond the scan match's own noise (ScanMotion.significant); unknown: yes
    laser_plane_offset_m: float | None = None  # laser returns vs the camera-measured wall (rig/mount check)
    head_failure: str | None = None
    rig_failure: str | None = None  # the rig file cannot describe this robot (registration refused)
    notes: list[str] = field(default_factory=list)

    @property
    def closed_loop_worst_m(self) -> float:
        """The loop's worst error on the drawn area: its worst mark, or the measured field's worst where larger."""
        if self.closed_loop_errors_m is None or not len(self.closed_loop_errors_m):
            return 0.0
        worst = float(np.max(self.closed_loop_errors_m))
        return max(worst, self.closed_loop_field_max_m) if np.isfinite(self.closed_loop_field_max_m) else worst


# What the craftsman at the wall reads on the warning frame: what happened, in plain words, and what to do.
# The technical reasons (with device names and figures) go to the log and the operator's terminal.
SAY_NO_WALL_POSE = "The wall could not be measured. Clear the beam and keep the wall in view."
SAY_HEAD_SILENT = "The projector head does not answer. Call the operator."
SAY_HEAD_MOVED = "The projector head has moved. Wait until this warning goes."
SAY_ROBOT_MOVED = "The robot has moved. Do not touch it while it measures again."
SAY_PATTERN_HIDDEN = "The check marks are hidden. Step out of the beam."
SAY_RIG = "The robot's cameras or laser disagree. Call the operator."
SAY_LASER = ("The cameras and the laser see the wall in different places. Clear the space before the wall; "
             "if this stays, call the operator.")


def _say_off_by(mm: float) -> str:
    return f"The picture may be up to {mm:.0f} mm off. Wait until this warning goes."


@dataclass
class GateDecision:
    show_map: bool
    reasons: list[str]
    registration_sigma_m: float  # 1σ used for the safety bands
    bound_m: float               # 95 % bound of the registration error compared with the tolerance
    craftsman: list[str] = field(default_factory=list)  # the warning frame's lines, one per kind of reason


def decide(ev: RegistrationEvidence, tolerance_m: float = tol.REGISTRATION_TOLERANCE_M) -> GateDecision:
    reasons: list[str] = []
    say: list[str] = []

    def fail(reason: str, words: str) -> None:
        reasons.append(reason)
        if words not in say:
            say.append(words)

    if ev.pose_failure:
        fail(f"wall pose unknown: {ev.pose_failure}", SAY_NO_WALL_POSE)
    if ev.pose_sigma_m is None and not ev.pose_failure and not ev.rig_failure:
        fail("wall pose not estimated yet", SAY_NO_WALL_POSE)
    if ev.rig_failure:
        fail(f"rig in doubt: {ev.rig_failure}", SAY_RIG)
    if ev.head_failure:
        fail(f"head not answering: {ev.head_failure.split(' — ')[0]}", SAY_HEAD_SILENT)
    if ev.head_command_error_deg > HEAD_COMMAND_TOLERANCE_DEG:
        fail(f"head not where commanded ({ev.head_command_error_deg:.2f}° off)", SAY_HEAD_MOVED)
    if robot_moved(ev):
        fail(f"robot moved {ev.robot_motion_m * 1000:.0f} mm since the wall pose was estimated", SAY_ROBOT_MOVED)
    sigma = ev.pose_sigma_m if ev.pose_sigma_m is not None else np.inf
    loop_max = 0.0
    if ev.closed_loop_expected > 0:
        seen = 0 if ev.closed_loop_errors_m is None else len(ev.closed_loop_errors_m)
        if seen < max(tol.CLOSED_LOOP_MIN_FEATURES, MIN_VISIBLE_FRACTION * ev.closed_loop_expected):
            fail(f"pattern lost: {seen} of {ev.closed_loop_expected} check marks seen", SAY_PATTERN_HIDDEN)
        elif ev.closed_loop_errors_m is not None:
            loop_max = ev.closed_loop_worst_m  # the worst mark or field: the map must hold everywhere
            if loop_max > tolerance_m:
                fail(f"projection lands up to {loop_max * 1000:.0f} mm off where it should (head slipped, "
                     "projector moved or wrong rig)", _say_off_by(loop_max * 1000))
    if ev.laser_plane_offset_m is not None and np.isfinite(ev.laser_plane_offset_m) and \
            ev.laser_plane_offset_m > LASER_PLANE_TOLERANCE_M:
        fail(f"laser and cameras disagree about the wall by {ev.laser_plane_offset_m * 1000:.0f} mm: something "
             "before the wall where the pattern fell, a wrong rig file or a camera moved?", SAY_LASER)
    if ev.stereo_residual_px is not None and ev.stereo_residual_px > STEREO_RESIDUAL_MAX_PX:
        fail(f"cameras disagree with the rig file (residual {ev.stereo_residual_px:.1f} px): wrong or outdated "
             "rig?", SAY_RIG)
    # The closed loop measures the projector against the camera-measured wall, so it cannot see an error of
    # that wall estimate itself (both share it): its worst mark and the pose's 95 % error add up.
    bound = tol.Z95 * sigma + loop_max + ev.robot_motion_m
    if np.isfinite(bound) and bound > tolerance_m and not reasons:
        fail(f"registration uncertain: ±{bound * 1000:.1f} mm exceeds the {tolerance_m * 1000:.0f} mm tolerance",
             _say_off_by(bound * 1000))
    registration_sigma = float(max(sigma, loop_max / tol.Z95)) if np.isfinite(sigma) else np.inf
    return GateDecision(not reasons, reasons, registration_sigma, float(bound), say)


# -- laser scan matching (robot moved?) -------------------------------------------------------------------
@dataclass
class ScanMotion:
    """Motion of the robot between two 2D scans: the current scan's points map onto the reference by
    (dx, dy, dtheta); rms_m the point-to-line residual; n pairs used; cov the (3, 3) covariance of
    (dx, dy, dtheta) from the match itself, σ² (JᵀJ)⁻¹ with σ the residual: what the scans' noise leaves."""

    dx: float
    dy: float
    dtheta_rad: float
    rms_m: float
    n: int
    cov: NDArray[np.float64] = field(default_factory=lambda: np.full((3, 3), np.nan))

    @property
    def significant(self) -> bool:
        """The motion is more than the scans' noise explains (χ² test on (dx, dy, dθ) with cov); an unmatched
        scan (n = 0) counts as moved: nothing says it did not."""
        if not self.n:
            return True
        x = np.array([self.dx, self.dy, self.dtheta_rad])
        try:
            chi2 = float(x @ np.linalg.solve(self.cov, x))
        except np.linalg.LinAlgError:
            return True
        return not np.isfinite(chi2) or chi2 > ROBOT_MOTION_CHI2

    def displacement_at(self, distance_m: float) -> float:
        """Worst displacement (metres) of a point distance_m away caused by this motion."""
        return float(np.hypot(self.dx, self.dy) + abs(self.dtheta_rad) * distance_m)


def scan_motion(reference_xy: NDArray[np.float64], current_xy: NDArray[np.float64]) -> ScanMotion:
    """Point-to-line ICP of current onto reference (both (n, 2), metres, robot frame at their time)."""
    ref = np.asarray(reference_xy, dtype=np.float64).reshape(-1, 2)
    cur = np.asarray(current_xy, dtype=np.float64).reshape(-1, 2)
    ref = ref[np.all(np.isfinite(ref), axis=1)]
    cur = cur[np.all(np.isfinite(cur), axis=1)]
    if len(ref) < SCAN_MATCH_NEIGHBOURS or len(cur) < 3:
        return ScanMotion(np.nan, np.nan, np.nan, np.nan, 0)
    tree = cKDTree(ref)
    _, nbr = tree.query(ref, k=SCAN_MATCH_NEIGHBOURS)
    # each reference point stands for the line through its neighbours: measured from their centroid, a residual
    # is not shrunk by picking the nearest noisy point (which made σ² (JᵀJ)⁻¹ half the true spread)
    centroid = ref[nbr].mean(axis=1)
    local = ref[nbr] - centroid[:, None, :]
    cov = np.einsum("nki,nkj->nij", local, local)
    _, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]  # smallest eigenvalue: across the wall
    theta, t = 0.0, np.zeros(2)
    rms, n = np.nan, 0
    cov = np.full((3, 3), np.nan)
    for _ in range(SCAN_MATCH_ITERATIONS):
        c, s = np.cos(theta), np.sin(theta)
        moved = cur @ np.array([[c, -s], [s, c]]).T + t
        dist, idx = tree.query(moved)
        keep = dist < SCAN_MATCH_MAX_PAIR_M
        if keep.sum() < 3:
            break
        nrm = normals[idx[keep]]
        p = moved[keep]
        r = np.einsum("ij,ij->i", p - centroid[idx[keep]], nrm)
        # robust: drop pairs far beyond the typical residual (outlier beams)
        mad = np.median(np.abs(r)) * 1.4826 + 1e-6
        ok = np.abs(r) < 4 * mad + 0.005
        J = np.column_stack([nrm[:, 0], nrm[:, 1], nrm[:, 0] * -p[:, 1] + nrm[:, 1] * p[:, 0]])[ok]
        step, *_ = np.linalg.lstsq(J, -r[ok], rcond=None)
        t = t + step[:2]
        theta += step[2]
        rms, n = float(np.sqrt(np.mean(r[ok] ** 2))), int(ok.sum())
        with np.errstate(divide="ignore", invalid="ignore"):
            r_after = r[ok] + J @ step
            # σ² = the residual's variance: the current point's noise plus its line's (σ²/K for K neighbours).
            # The reference scan is as noisy as the current one and moves the match as much: its noise counts
            # twice, σ_point² (JᵀJ)⁻¹ · 2 = σ² (JᵀJ)⁻¹ · 2K / (K + 1)
            both_scans = 2 * SCAN_MATCH_NEIGHBOURS / (SCAN_MATCH_NEIGHBOURS + 1)
            cov = both_scans * float(r_after @ r_after) / max(n - 3, 1) * np.linalg.pinv(J.T @ J)
        if np.linalg.norm(step) < 1e-7:
            break
    # the current scan maps onto the reference by (theta, t): that is the robot's motion seen from the old pose
    return ScanMotion(float(t[0]), float(t[1]), float(theta), rms, n, cov)


def robot_moved(ev: RegistrationEvidence) -> bool:
    """The one test of "the robot moved": the laser's motion matters at the wall and is more than the scan
    match's own noise. Used by decide() and by the session's re-estimate trigger alike."""
    return ev.robot_motion_m > ROBOT_MOTION_TOLERANCE_M and ev.robot_motion_significant
