"""Head calibration against a known (perturbed) head model with angle bias and noise."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.head import fit_head, head_errors, head_plan, rebase_head
from geometry.errors import InputError
from geometry.head import HeadModel
from geometry.poses import make_pose, rotation_about

R_ZERO = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def true_head() -> HeadModel:
    axes = np.array([rotation_about([1, 0.3, 0], np.radians(0.4)) @ [0, 0, 1.0],
                     rotation_about([0.2, 0, 1], np.radians(0.3)) @ [0, -1.0, 0],
                     rotation_about([0, 1, 0.5], np.radians(0.5)) @ [1.0, 0, 0]])
    points = np.array([[0.002, -0.001, 1.1], [0.001, 0.0, 1.252], [0.1, 0.002, 1.249]])
    T_zero = make_pose(rotation_about([1, 1, 0], np.radians(0.3)) @ R_ZERO, [0.101, 0.001, 1.251])
    return HeadModel(axes, points, T_zero, zero_offsets_deg=[0.15, -0.1, 0.05])


def measure(head: HeadModel, angles: list[np.ndarray], rng: np.random.Generator, angle_noise_deg: float,
            pose_noise: tuple[float, float]) -> list[np.ndarray]:
    out = []
    for a in angles:
        T = head.T_robot_from_projector(a + rng.normal(0, angle_noise_deg, 3))
        dR = rotation_about(rng.normal(size=3), np.radians(pose_noise[0]))
        out.append(T @ make_pose(dR, rng.normal(0, pose_noise[1], 3)))
    return out


def test_fit_predicts_unseen_angles_within_targets() -> None:
    rng = np.random.default_rng(0)
    truth = true_head()
    fit_angles, check_angles = head_plan(20.0, 15.0, 10.0)
    fit = fit_head(fit_angles, measure(truth, fit_angles, rng, 0.01, (0.005, 0.0002)))
    rot, pos = head_errors(fit.model, check_angles, measure(truth, check_angles, rng, 0.0, (0.0, 0.0)))
    assert max(rot) < 0.05  # degrees
    assert max(pos) < 0.001  # metres
    assert fit.rotation_rms_deg < 0.05  # ≈ 3x the injected rms: 0.01°/joint x √3 ⊕ 0.005° per pose ≈ 0.018°


def test_noise_free_fit_is_exact_and_rebase_keeps_predictions() -> None:
    rng = np.random.default_rng(1)
    truth = true_head()
    fit_angles, check_angles = head_plan()
    fit = fit_head(fit_angles, measure(truth, fit_angles, rng, 0.0, (0.0, 0.0)))
    rot, pos = head_errors(fit.model, check_angles, measure(truth, check_angles, rng, 0.0, (0.0, 0.0)))
    # Noise-free poses: the fit is exact up to the solver's tolerance (FIT_TOLERANCE, relative, on parameters of
    # order 1 rad and 1 m) times the conditioning of 18 unknowns; 1e-11 rad and 1e-11 m leave three orders for it.
    assert max(rot) < np.degrees(1e-11) and max(pos) < 1e-11
    T_new = make_pose(rotation_about([0, 0, 1], 0.3), [0.5, -0.2, 0.1])
    moved = rebase_head(fit.model, T_new)
    for a in check_angles:
        # Rebasing is exact algebra: only float64 round-off (~1e-16) on metre-scale entries remains.
        assert np.allclose(moved.T_robot_from_projector(a), T_new @ fit.model.T_robot_from_projector(a), atol=1e-12)


def test_plan_about_an_aim_pose_is_fitted_in_absolute_angles() -> None:
    # The wizard turns the head about an aim pose (here 4° of tilt), so no pose sits at commanded (0, 0, 0);
    # the model must still map the absolute angles the head reports to the projector's pose.
    rng = np.random.default_rng(2)
    truth = true_head()
    aim = np.array([1.5, -4.1, 0.0])
    fit_angles, check_angles = head_plan(15.0, 10.0, 10.0)
    fit_abs = [aim + a for a in fit_angles]
    check_abs = [aim + a for a in check_angles] + [np.zeros(3)]
    fit = fit_head(fit_abs, measure(truth, fit_abs, rng, 0.01, (0.005, 0.0002)))
    rot, pos = head_errors(fit.model, check_abs, measure(truth, check_abs, rng, 0.0, (0.0, 0.0)))
    assert max(rot) < 0.05 and max(pos) < 0.001  # the bench's head targets (0.05°, 1 mm), as in the first test


def test_too_few_poses_or_a_joint_that_never_moves() -> None:
    truth = true_head()
    angles = [np.array([p, t, 0.0]) for p in (-20, 0, 20) for t in (-10, 0, 10)]
    poses = [truth.T_robot_from_projector(a) for a in angles]
    with pytest.raises(InputError, match=r"roll joint moved only 0\.0°"):
        fit_head(angles, poses)
    with pytest.raises(InputError, match="at least 7"):
        fit_head(angles[:4], poses[:4])
