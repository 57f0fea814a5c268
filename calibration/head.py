"""Pan/tilt/roll head calibration: fit geometry.HeadModel to projector poses measured at commanded angles.

Unknowns: each joint's axis direction (2 DOF) and line position (2 DOF), and the projector's pose at zero
(6 DOF). The joints' zero offsets are not separately observable once axes and the zero pose are free (an
offset on joint i is the same motion as turning joints i+1.. and the zero pose by that angle), so they are
absorbed there and written as 0: the fitted model maps *commanded* angles to the projector pose directly,
including the drive's constant angle bias. The head should approach every calibration angle from the same
side (the plan does) so backlash is constant too.

Residuals per measured pose: rotation error (radians, scaled by ROTATION_WEIGHT_M metres per radian so one
degree weighs like 17 mm) and position error (metres).

A head whose roll (or any) joint never turns — a Pelco-D pan/tilt head has no roll axis — is fitted with that
joint given in `fixed_joints`: at a constant angle its axis and line are unobservable and its rotation is
absorbed in the zero pose, so they are not unknowns (the model keeps the nominal or initial ones).

Uncertainty: the unknowns' covariance is the least-squares sandwich (JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹ at the solution,
Σ diagonal with the rotation and the position residuals' own variances (each from its residuals, corrected
for the unknowns' share of the degrees of freedom); `HeadFit.pose_covariance(angles)` carries it to the
projector's predicted pose (rotation vector, position) at any angles.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative

from geometry.errors import InputError
from geometry.head import HeadModel
from geometry.poses import (
    invert,
    make_pose,
    rotation_about,
    rotation_angle_deg,
    rotation_matrix,
    rotation_vector,
    rotation_vectors,
)

ROTATION_WEIGHT_M = 1.0
MIN_HEAD_POSES = 7
MIN_JOINT_SPAN_DEG = 10.0  # each joint must move at least this much across the poses
FIT_TOLERANCE = 1e-14


@dataclass
class HeadFit:
    model: HeadModel
    rotation_rms_deg: float
    position_rms_m: float
    per_pose_rotation_deg: list[float]
    per_pose_position_m: list[float]
    covariance: NDArray[np.float64] | None = None  # of the unknowns x (see fit_head)
    model_from: Callable[[NDArray[np.float64]], HeadModel] | None = None
    x: NDArray[np.float64] | None = None

    def pose_covariance(self, angles_deg: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(3x3 covariance of the predicted projector orientation as a rotation vector, rad²; 3x3 of its
        position, m²) at these commanded angles, in the fit's base frame."""
        if self.covariance is None or self.model_from is None or self.x is None:
            raise ValueError("this head fit has no covariance")
        model_from, x = self.model_from, self.x
        T0 = self.model.T_robot_from_projector(angles_deg)

        def pose_vector(v: NDArray[np.float64]) -> NDArray[np.float64]:
            T = model_from(v).T_robot_from_projector(angles_deg)
            return np.concatenate([rotation_vector(T[:3, :3] @ T0[:3, :3].T), T[:3, 3]])

        G = approx_derivative(pose_vector, x, method="3-point")
        C = G @ self.covariance @ G.T
        return C[:3, :3], C[3:, 3:]

    def quality(self) -> dict:
        return {"rotation_rms_deg": round(self.rotation_rms_deg, 5),
                "position_rms_mm": round(1000 * self.position_rms_m, 4),
                "poses": len(self.per_pose_position_m)}


def head_plan(pan_deg: float = 30.0, tilt_deg: float = 20.0, roll_deg: float = 10.0,
              approach_deg: float = 2.0) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]]]:
    """(fit angles, check angles): commanded (pan, tilt, roll) degrees for calibration and for validation.

    Every joint is moved alone and in combination, so its axis is seen turning on its own; check angles lie
    between the fit angles. approach_deg is used by the wizard to come at each angle from below.
    """
    del approach_deg
    fit = [np.array(a, dtype=np.float64) for a in (
        (0, 0, 0), (pan_deg, 0, 0), (-pan_deg, 0, 0), (0, tilt_deg, 0), (0, -tilt_deg / 2, 0),
        (0, 0, roll_deg), (0, 0, -roll_deg), (pan_deg, tilt_deg, roll_deg), (-pan_deg, tilt_deg, -roll_deg),
        (pan_deg / 2, -tilt_deg / 2, roll_deg / 2), (-pan_deg / 2, tilt_deg / 2, 0),
        # More combinations: each costs one measurement and tightens axes, offsets and the zero pose.
        (pan_deg, -tilt_deg / 2, -roll_deg), (-pan_deg, -tilt_deg / 2, roll_deg), (pan_deg / 2, tilt_deg, -roll_deg),
        (-pan_deg / 2, tilt_deg, roll_deg), (0, tilt_deg / 2, roll_deg / 2), (pan_deg * 0.75, 0, -roll_deg / 2),
        (-pan_deg * 0.75, tilt_deg * 0.75, 0), (pan_deg / 4, -tilt_deg / 4, -roll_deg))]
    check = [np.array(a, dtype=np.float64) for a in (
        (pan_deg * 0.7, tilt_deg * 0.3, -roll_deg * 0.4), (-pan_deg * 0.4, tilt_deg * 0.8, roll_deg * 0.6),
        (pan_deg * 0.2, -tilt_deg * 0.3, roll_deg * 0.2))]
    return fit, check


def _perp_basis(a: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def _initial_model(angles: list[NDArray[np.float64]], poses: list[NDArray[np.float64]],
                   nominal: HeadModel | None) -> HeadModel:
    """Axes and points from poses where one joint moved alone from a reference pose (else the nominal model).

    The reference is the pose at commanded (0, 0, 0) if there is one, else the first pose (a head plan starts
    at its centre). Axes seen about a reference away from zero are slightly turned by the joints before
    them; the least-squares fit removes that.
    """
    zero = [k for k, a in enumerate(angles) if np.allclose(a, 0.0)]
    if not zero and nominal is not None:
        return HeadModel(nominal.axes.copy(), nominal.points.copy(), nominal.T_robot_from_projector_zero.copy())
    ref = zero[0] if zero else 0
    axes = nominal.axes.copy() if nominal is not None else np.eye(3)[[2, 1, 0]] * np.array([[1], [-1], [1]])
    points = nominal.points.copy() if nominal is not None else np.tile(poses[ref][:3, 3], (3, 1))
    T_ref = poses[ref]
    for j in range(3):
        deltas = [a - angles[ref] for a in angles]
        moves = [k for k, d in enumerate(deltas) if abs(d[j]) > 1.0 and np.allclose(np.delete(d, j), 0.0)]
        estimates, pts = [], []
        for k in moves:
            M = poses[k] @ invert(T_ref)  # rotation about joint j's line
            v = rotation_vector(M[:3, :3])
            angle = np.linalg.norm(v)
            if angle < 1e-6:
                continue
            axis = v / angle * np.sign(deltas[k][j])
            estimates.append(axis)
            # Points p on the line satisfy (I - R) p = t; least squares gives the one nearest the origin.
            p, *_ = np.linalg.lstsq(np.eye(3) - M[:3, :3], M[:3, 3], rcond=1e-9)  # rank 2: drop the axis
            pts.append(p)
        if estimates:
            a = np.mean(estimates, axis=0)
            axes[j] = a / np.linalg.norm(a)
            points[j] = np.mean(pts, axis=0)
    # T_ref = E1(a1) E2(a2) E3(a3) T_zero, so T_zero = E3(-a3) E2(-a2) E1(-a1) T_ref.
    T_zero = T_ref.copy()
    for j in range(3):
        R = rotation_about(axes[j], -np.radians(angles[ref][j]))
        T_zero = make_pose(R, points[j] - R @ points[j]) @ T_zero
    return HeadModel(axes, points, T_zero)


def fit_head(angles_deg: list[ArrayLike], T_base_from_projector: list[NDArray[np.float64]],
             nominal: HeadModel | None = None, fixed_joints: Sequence[int] = ()) -> HeadFit:
    """Fit the head model (in the poses' base frame, e.g. robot or camera_left) to measured projector poses.

    angles_deg: commanded (pan, tilt, roll) per pose; T_base_from_projector: the measured poses (4x4);
    fixed_joints: joints (0 pan, 1 tilt, 2 roll) held at one angle throughout, whose axes are not fitted.
    """
    angles = [np.asarray(a, dtype=np.float64).reshape(3) for a in angles_deg]
    poses = [np.asarray(T, dtype=np.float64) for T in T_base_from_projector]
    if len(angles) != len(poses):
        raise InputError(f"head calibration: {len(angles)} angle sets but {len(poses)} measured poses")
    if len(poses) < MIN_HEAD_POSES:
        raise InputError(f"head calibration: {len(poses)} poses measured; at least {MIN_HEAD_POSES} are needed",
                         "measure the projector at more head angles (each joint alone and combined)")
    span = np.ptp(np.array(angles), axis=0)
    fixed = sorted(set(int(j) for j in fixed_joints))
    for j in fixed:
        if span[j] > 0:
            raise InputError(f"head calibration: joint {j} is to be held fixed but moved by {span[j]:.2f}°")
    for j, name in enumerate(("pan", "tilt", "roll")):
        if j not in fixed and span[j] < MIN_JOINT_SPAN_DEG:
            raise InputError(f"head calibration: the {name} joint moved only {span[j]:.1f}° across the poses",
                             f"move it by at least {MIN_JOINT_SPAN_DEG:.0f}° (both directions) while measuring")
    init = _initial_model(angles, poses, nominal)
    bases = [_perp_basis(a) for a in init.axes]
    moving = [j for j in range(3) if j not in fixed]
    n_joint = 4 * len(moving)

    def model_from(x: NDArray[np.float64]) -> HeadModel:
        axes = init.axes.copy()
        points = init.points.copy()
        for k, j in enumerate(moving):
            e1, e2 = bases[j]
            a = init.axes[j] + x[4 * k] * e1 + x[4 * k + 1] * e2
            axes[j] = a / np.linalg.norm(a)
            points[j] = init.points[j] + x[4 * k + 2] * e1 + x[4 * k + 3] * e2
        dR = rotation_matrix(x[n_joint:n_joint + 3])
        T0 = init.T_robot_from_projector_zero
        T_zero = make_pose(dR @ T0[:3, :3], T0[:3, 3] + x[n_joint + 3:n_joint + 6])
        return HeadModel(axes, points, T_zero)

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        m = model_from(x)
        P = np.array([m.T_robot_from_projector(a) for a in angles])
        T = np.asarray(poses, dtype=np.float64)
        rotation = ROTATION_WEIGHT_M * rotation_vectors(np.transpose(P[:, :3, :3], (0, 2, 1)) @ T[:, :3, :3])
        return np.column_stack([rotation, P[:, :3, 3] - T[:, :3, 3]]).ravel()  # per pose: rotation, position

    sol = least_squares(residuals, np.zeros(n_joint + 6), method="lm", xtol=FIT_TOLERANCE, ftol=FIT_TOLERANCE,
                        gtol=FIT_TOLERANCE, max_nfev=5000)
    model = model_from(sol.x)
    rot, pos = head_errors(model, angles, poses)
    return HeadFit(model, float(np.sqrt(np.mean(np.square(rot)))), float(np.sqrt(np.mean(np.square(pos)))),
                   rot, pos, _sandwich_covariance(sol.fun, sol.jac), model_from, sol.x.copy())


def _sandwich_covariance(r: NDArray[np.float64], J: NDArray[np.float64]) -> NDArray[np.float64]:
    """Covariance of the unweighted fit's unknowns with rotation and position residuals of their own variance.

    Residuals come per pose as (rotation 3, position 3); each group's variance is its sum of squares over its
    share of the degrees of freedom."""
    m, n = J.shape
    rows = np.arange(m) % 6 < 3
    dof_share = max(m - n, 1) / m
    var = np.where(rows, np.sum(r[rows] ** 2) / (rows.sum() * dof_share),
                   np.sum(r[~rows] ** 2) / ((~rows).sum() * dof_share))
    A = np.linalg.pinv(J.T @ J)
    return A @ (J.T * var) @ J @ A


def head_errors(model: HeadModel, angles_deg: Sequence[ArrayLike], T_base_from_projector: list[NDArray[np.float64]]
                ) -> tuple[list[float], list[float]]:
    """(rotation errors in degrees, position errors in metres) of the model's predictions vs measured poses."""
    rot, pos = [], []
    for a, T in zip(angles_deg, T_base_from_projector, strict=True):
        P = model.T_robot_from_projector(a)
        rot.append(rotation_angle_deg(P, T))
        pos.append(float(np.linalg.norm(P[:3, 3] - np.asarray(T)[:3, 3])))
    return rot, pos


def rebase_head(model: HeadModel, T_new_from_base: NDArray[np.float64]) -> HeadModel:
    """The same head expressed in another base frame (e.g. fitted in camera_left, wanted in robot)."""
    R, t = T_new_from_base[:3, :3], T_new_from_base[:3, 3]
    return HeadModel(axes=model.axes @ R.T, points=model.points @ R.T + t,
                     T_robot_from_projector_zero=T_new_from_base @ model.T_robot_from_projector_zero,
                     zero_offsets_deg=model.zero_offsets_deg.copy())
