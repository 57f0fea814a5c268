"""Kinematic model of the 3-DOF pan/tilt(/roll) head that carries the projector.

Product of exponentials: with every joint at its zero, the projector sits at T_robot_from_projector_zero;
joint i turns about the line through points[i] along axes[i] (both in the robot frame at the zero pose):

    T_robot_from_projector(θ) = E1(θ1 + o1) · E2(θ2 + o2) · E3(θ3 + o3) · T_robot_from_projector_zero

where Ei(a) rotates by a about joint i's line and oi is joint i's zero offset (encoder zero error).
The simulated site uses it as truth; calibration fits it from measured projector poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.errors import InputError
from geometry.inputs import float_array
from geometry.poses import invert, make_pose, rotation_matrices, rotation_vector

JOINT_NAMES = ("pan", "tilt", "roll")


@dataclass(frozen=True)
class JointSlip:
    """HeadModel.joint_slip: the pan and tilt change (degrees) that explains a measured projector pose best,
    and the rotation (degrees) and translation (metres) of that pose no joint change explains."""

    pan_deg: float
    tilt_deg: float
    unexplained_deg: float
    unexplained_m: float
    unexplained_translation_m: NDArray[np.float64]  # (3,) in the robot frame: measured minus explained


@dataclass
class HeadModel:
    """axes, points: (3, 3) in the robot frame; zero_offsets_deg: (3,); T_robot_from_projector_zero: 4x4."""

    axes: NDArray[np.float64]
    points: NDArray[np.float64]
    T_robot_from_projector_zero: NDArray[np.float64]
    zero_offsets_deg: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.axes = np.asarray(self.axes, dtype=np.float64).reshape(3, 3)
        norms = np.linalg.norm(self.axes, axis=1)
        if np.any(norms < 1e-9):
            raise InputError("head model: a joint axis has zero length")
        self.axes = self.axes / norms[:, None]
        self.points = np.asarray(self.points, dtype=np.float64).reshape(3, 3)
        self.T_robot_from_projector_zero = np.asarray(self.T_robot_from_projector_zero, dtype=np.float64)
        self.zero_offsets_deg = np.asarray(self.zero_offsets_deg, dtype=np.float64).reshape(3)

    def T_robot_from_projector(self, angles_deg: ArrayLike) -> NDArray[np.float64]:
        """Projector pose for the (pan, tilt, roll) joint angles in degrees."""
        a = np.radians(np.asarray(angles_deg, dtype=np.float64).reshape(3) + self.zero_offsets_deg)
        T = np.eye(4)
        for R, p in zip(rotation_matrices(self.axes * a[:, None]), self.points, strict=True):  # about each line
            T = T @ make_pose(R, p - R @ p)
        return T @ self.T_robot_from_projector_zero

    def T_robot_from_head(self, angles_deg: ArrayLike) -> NDArray[np.float64]:
        """The head's moving plate for the (pan, tilt, roll) joint angles in degrees: at the tilt axis's point,
        turned with the joints (the frame between robot and projector in a REP 105 tree: the projector holds
        still on it, T_head_from_projector = T_robot_from_head⁻¹ · T_robot_from_projector whatever the angles)."""
        turned = self.T_robot_from_projector(angles_deg) @ invert(self.T_robot_from_projector_zero)
        return turned @ make_pose(None, self.points[1])

    def joint_slip(self, angles_deg: ArrayLike, T_robot_from_projector_measured: ArrayLike,
                   rotation_sigma_deg: float, translation_sigma_m: float) -> JointSlip:
        """The pan and tilt change that best explains a measured projector pose at the reported angles — a
        mount that slipped on its joints moves the projector only so — and what it leaves unexplained. The two
        parts of the residual are weighed by their σ (how well the measurement knows each)."""
        from scipy.optimize import least_squares  # here: geometry's import stays light for the CLI's start

        reported = np.asarray(angles_deg, dtype=np.float64).reshape(-1)
        T_meas = np.asarray(T_robot_from_projector_measured, dtype=np.float64)

        def parts(change: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            T = self.T_robot_from_projector([reported[0] + change[0], reported[1] + change[1], 0.0])
            return rotation_vector(T[:3, :3].T @ T_meas[:3, :3]), T_meas[:3, 3] - T[:3, 3]

        def residual(change: NDArray[np.float64]) -> NDArray[np.float64]:
            rot, trans = parts(change)
            return np.concatenate([rot / np.radians(rotation_sigma_deg), trans / translation_sigma_m])

        change = least_squares(residual, np.zeros(2)).x
        rot, trans = parts(change)
        return JointSlip(float(change[0]), float(change[1]), float(np.degrees(np.linalg.norm(rot))),
                         float(np.linalg.norm(trans)), trans)

    def to_dict(self) -> dict:
        return {
            "model": "product_of_exponentials",
            "joints": list(JOINT_NAMES),
            "axes": self.axes.tolist(),
            "points_m": self.points.tolist(),
            "zero_offsets_deg": self.zero_offsets_deg.tolist(),
            "T_robot_from_projector_zero": self.T_robot_from_projector_zero.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "head model") -> HeadModel:
        for key in ("axes", "points_m", "T_robot_from_projector_zero"):
            if key not in d:
                raise InputError(f"{source}: key {key!r} is missing")
        return cls(axes=float_array(source, "axes", d["axes"], (3, 3), -10.0, 10.0),
                   points=float_array(source, "points_m", d["points_m"], (3, 3), -100.0, 100.0, unit="metres"),
                   T_robot_from_projector_zero=float_array(source, "T_robot_from_projector_zero",
                                                           d["T_robot_from_projector_zero"], (4, 4), -100.0, 100.0),
                   zero_offsets_deg=float_array(source, "zero_offsets_deg", d.get("zero_offsets_deg", [0.0] * 3),
                                                (3,), -360.0, 360.0, unit="degrees"))
