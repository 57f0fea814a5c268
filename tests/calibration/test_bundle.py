"""Bundle adjustment against ground truth: known cameras, T_1_from_0 and board poses, projected by OpenCV.

The truth is projected with cv2.projectPoints (independent of calibration.camera_model), the initial guess is
perturbed, pixel noise has a fixed seed. Statistical bounds come from an independent reference model of the
same problem (cv2.projectPoints again, central differences): the parameter covariance σ²(JᵀJ)⁻¹ at the truth
and the residual degrees of freedom.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.stats import chi2, norm

from calibration.boards import parse_board
from calibration.bundle import BA_TOLERANCE, BundleResult, Observation, bundle_adjust
from calibration.camera_model import DISTORTION_MODELS
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import make_pose, pose_from_rvec_tvec, rotation_about, rvec_tvec_from_pose
from tests.support.synthetic_calibration import board_poses

CAM0 = Intrinsics(800.0, 806.0, 322.0, 236.0, 640, 480, (-0.15, 0.06, 0.0012, -0.0008, 0.0))
CAM1 = Intrinsics(790.0, 793.0, 315.0, 245.0, 640, 480, (-0.12, 0.04, -0.0006, 0.0009, 0.0))
CAM_K1 = Intrinsics(812.0, 809.0, 318.0, 241.0, 640, 480, (-0.11, 0.0, 0.0, 0.0, 0.0))
T_1_FROM_0 = make_pose(rotation_about([0.1, 1.0, 0.05], np.radians(3.0)), [-0.11, 0.003, 0.002])
T_1_FROM_0.setflags(write=False)  # shared by the tests: read-only
BOARD = parse_board("chessboard:9x6:0.03")
MODEL = "k1k2p1p2"  # the truth's k3 is 0, so this model contains the truth
N_VIEWS = 6
NOISE_PX = 0.2  # pixel noise σ per coordinate
Z_MAX = 4.0  # |error| / standard error: a correct estimator exceeds this with probability 6e-5 per parameter
P_FALSE_ALARM = 1e-4  # significance of the joint χ² and residual-rms checks
Z_RMS = float(norm.ppf(1 - P_FALSE_ALARM / 2))  # two-sided normal quantile for the residual rms
# xtol stops when a step is below BA_TOLERANCE relative to the parameters; at a zero-residual optimum the
# remaining error is below that last step (Gauss–Newton converges at least linearly); ×10 margin
NOISE_FREE_REL = 10 * BA_TOLERANCE


def project_cv(intr: Intrinsics, T_cam_from_board: NDArray[np.float64], obj: NDArray[np.float64]) -> NDArray:
    """The independent projector: cv2.projectPoints of board points (n, 3) m → (n, 2) px."""
    rvec, tvec = rvec_tvec_from_pose(T_cam_from_board)
    uv, _ = cv2.projectPoints(obj, rvec, tvec, intr.K, intr.dist_array)
    return uv.reshape(-1, 2)


def synthetic(cameras: list[Intrinsics], noise_px: float, seed: int,
              n_views: int = N_VIEWS) -> tuple[list[NDArray[np.float64]], list[Observation]]:
    """True T_0_from_view poses and both (or the one) cameras' noisy observations of every view."""
    rng = np.random.default_rng(seed)
    poses = board_poses(BOARD, n_views, rng, distance_m=0.7)
    obj = BOARD.object_points()
    observations = []
    for v, T in enumerate(poses):
        for cam, intr in enumerate(cameras):
            T_cam = T if cam == 0 else T_1_FROM_0 @ T
            uv = project_cv(intr, T_cam, obj) + rng.normal(0.0, noise_px, (len(obj), 2))
            observations.append(Observation(cam, v, uv, obj))
    return poses, observations


def perturbed(T: NDArray[np.float64], rng: np.random.Generator, deg: float = 1.0, m: float = 0.01) -> NDArray:
    return make_pose(rotation_about(rng.normal(size=3), np.radians(deg)), rng.normal(size=3) * m / np.sqrt(3)) @ T


def rough(intr: Intrinsics, sign: float) -> Intrinsics:
    """A start 3 % off in focal length, 6 px off in the principal point, with no distortion."""
    return Intrinsics(intr.fx * (1 + 0.03 * sign), intr.fy * (1 + 0.03 * sign), intr.cx + 6 * sign,
                      intr.cy - 5 * sign, intr.width, intr.height)


class Reference:
    """The same least-squares problem written independently (cv2.projectPoints per observation), for standard
    errors. Parameters: per free camera fx fy cx cy and its model's free distortion terms; rvec, tvec of
    T_1_from_0 for two cameras; rvec, tvec of each T_0_from_view."""

    def __init__(self, cameras: list[Intrinsics], models: list[str], fixed: list[bool],
                 observations: list[Observation], n_views: int) -> None:
        self.cameras, self.free, self.fixed = cameras, [DISTORTION_MODELS[m] for m in models], fixed
        self.observations, self.n_views = observations, n_views

    def pack(self, cameras: list[Intrinsics], T_1_from_0: NDArray | None, poses: list[NDArray]) -> NDArray:
        x: list[float] = []
        for cam, intr in enumerate(cameras):
            if not self.fixed[cam]:
                x += [intr.fx, intr.fy, intr.cx, intr.cy, *intr.dist_array[list(self.free[cam])]]
        if len(cameras) == 2:
            x += list(np.concatenate(rvec_tvec_from_pose(T_1_from_0)))
        for T in poses:
            x += list(np.concatenate(rvec_tvec_from_pose(T)))
        return np.asarray(x)

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        k = 0
        cams = []
        for cam, intr in enumerate(self.cameras):
            if self.fixed[cam]:
                cams.append(intr)
                continue
            n = 4 + len(self.free[cam])
            d = np.zeros(5)
            d[list(self.free[cam])] = x[k + 4:k + n]
            cams.append(Intrinsics(x[k], x[k + 1], x[k + 2], x[k + 3], intr.width, intr.height, tuple(d)))
            k += n
        T10 = None
        if len(self.cameras) == 2:
            T10 = pose_from_rvec_tvec(x[k:k + 3], x[k + 3:k + 6])
            k += 6
        poses = [pose_from_rvec_tvec(x[k + 6 * v:k + 6 * v + 3], x[k + 6 * v + 3:k + 6 * v + 6])
                 for v in range(self.n_views)]
        out = []
        for o in self.observations:
            T = poses[o.view] if o.camera == 0 else T10 @ poses[o.view]
            out.append((project_cv(cams[o.camera], T, o.object_points) - o.image_points).ravel())
        return np.concatenate(out)

    def jacobian(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Central differences (error ~1e-12 relative with these steps)."""
        J = np.empty((self.residuals(x).size, x.size))
        for k in range(x.size):
            h = np.zeros_like(x)
            h[k] = 1e-6 * max(1.0, abs(x[k]))
            J[:, k] = (self.residuals(x + h) - self.residuals(x - h)) / (2 * h[k])
        return J

    def covariance(self, x_true: NDArray[np.float64], sigma_px: float) -> NDArray[np.float64]:
        """σ²(JᵀJ)⁻¹ at the truth."""
        J = self.jacobian(x_true)
        return sigma_px**2 * np.linalg.inv(J.T @ J)


def assert_statistically_consistent(ref: Reference, fit: BundleResult, x_true: NDArray[np.float64]) -> None:
    """Each parameter within Z_MAX standard errors, the whole vector within the χ² bound, the residual rms at
    the noise floor for the residual degrees of freedom, and the result at the least-squares optimum."""
    cov = ref.covariance(x_true, NOISE_PX)
    std = np.sqrt(np.diag(cov))
    x_fit = ref.pack(fit.cameras, fit.T_1_from_0, fit.T_0_from_view)
    d = x_fit - x_true
    z = d / std
    assert np.all(np.abs(z) < Z_MAX), f"parameters off by {np.round(z, 1)} standard errors"
    assert d @ np.linalg.solve(cov, d) < chi2.ppf(1 - P_FALSE_ALARM, d.size)
    m = sum(2 * len(o.object_points) for o in ref.observations)  # scalar residuals
    dof = m - d.size
    expected = NOISE_PX * np.sqrt(2 * dof / m)  # rms_px is per point (2 coordinates): E Σr² = σ²(m − p)
    half_width = Z_RMS / np.sqrt(2 * dof)  # Σr²/σ² ~ χ²(dof): relative std of the rms ≈ 1/√(2 dof)
    assert abs(fit.rms_px / expected - 1) < half_width, (fit.rms_px, expected)
    # Distance to the optimum (one Gauss–Newton step of the reference model) in standard errors: it costs
    # ½σ²|z|² above the optimum's cost ½σ²·dof, and ftol stops once a step gains < BA_TOLERANCE of the cost,
    # so |z| ≲ √(BA_TOLERANCE·dof); ×10 margin for the convergence rate
    newton = np.linalg.lstsq(ref.jacobian(x_fit), -ref.residuals(x_fit), rcond=None)[0]
    assert np.linalg.norm(newton / std) < 10 * np.sqrt(BA_TOLERANCE * dof)


def test_noise_free_stereo_converges_to_the_truth_within_the_solver_tolerance() -> None:
    poses, observations = synthetic([CAM0, CAM1], 0.0, seed=1)
    rng = np.random.default_rng(2)
    fit = bundle_adjust([rough(CAM0, 1), rough(CAM1, -1)], [MODEL, MODEL], observations,
                        [perturbed(T, rng) for T in poses], perturbed(T_1_FROM_0, rng, 2.0, 0.01))
    for est, true in zip(fit.cameras, (CAM0, CAM1), strict=True):
        scale_px = true.fx  # a relative parameter change ε moves pixels by about ε·f
        for a, b in ((est.fx, true.fx), (est.fy, true.fy), (est.cx, true.cx), (est.cy, true.cy)):
            assert abs(a - b) < NOISE_FREE_REL * scale_px
        np.testing.assert_allclose(est.dist_array, true.dist_array, rtol=0, atol=NOISE_FREE_REL)  # O(1) terms
        assert (est.width, est.height) == (true.width, true.height)
    assert fit.T_1_from_0 is not None
    np.testing.assert_allclose(fit.T_1_from_0, T_1_FROM_0, rtol=0, atol=NOISE_FREE_REL)  # rotations, ~0.1 m
    for est_T, true_T in zip(fit.T_0_from_view, poses, strict=True):
        np.testing.assert_allclose(est_T, true_T, rtol=0, atol=NOISE_FREE_REL)  # rotations, ~1 m translations
    assert fit.rms_px < NOISE_FREE_REL * CAM0.fx
    assert len(fit.residuals) == len(observations)


def test_noisy_stereo_errors_are_within_standard_errors_and_rms_at_noise_floor() -> None:
    poses, observations = synthetic([CAM0, CAM1], NOISE_PX, seed=3)
    rng = np.random.default_rng(4)
    fit = bundle_adjust([rough(CAM0, -1), rough(CAM1, 1)], [MODEL, MODEL], observations,
                        [perturbed(T, rng) for T in poses], perturbed(T_1_FROM_0, rng, 2.0, 0.01))
    ref = Reference([CAM0, CAM1], [MODEL, MODEL], [False, False], observations, len(poses))
    assert_statistically_consistent(ref, fit, ref.pack([CAM0, CAM1], T_1_FROM_0, poses))


def test_fixed_camera_stays_exactly_as_given_and_the_free_one_is_recovered() -> None:
    poses, observations = synthetic([CAM0, CAM1], NOISE_PX, seed=5)
    rng = np.random.default_rng(6)
    start_poses = [perturbed(T, rng) for T in poses]
    start_T10 = perturbed(T_1_FROM_0, rng, 2.0, 0.01)
    fit = bundle_adjust([CAM0, rough(CAM1, 1)], [MODEL, MODEL], observations, start_poses, start_T10,
                        fixed=[True, False])
    assert fit.cameras[0] == CAM0
    ref = Reference([CAM0, CAM1], [MODEL, MODEL], [True, False], observations, len(poses))
    assert_statistically_consistent(ref, fit, ref.pack([CAM0, CAM1], T_1_FROM_0, poses))

    # A wrong fixed camera (1 % aspect-ratio error, which no pose can absorb) stays wrong, and the fit then
    # cannot reach the noise floor
    wrong = Intrinsics(CAM0.fx * 1.01, CAM0.fy, CAM0.cx, CAM0.cy, CAM0.width, CAM0.height, CAM0.dist)
    bad = bundle_adjust([wrong, rough(CAM1, 1)], [MODEL, MODEL], observations, start_poses, start_T10,
                        fixed=[True, False])
    assert bad.cameras[0] == wrong
    m = 2 * sum(len(o.object_points) for o in observations)
    dof = m - (8 + 6 + 6 * len(poses))
    assert bad.rms_px > NOISE_PX * np.sqrt(2 * dof / m) * (1 + Z_RMS / np.sqrt(2 * dof))


def test_single_camera_with_k1_model_keeps_unmodelled_terms_zero() -> None:
    poses, observations = synthetic([CAM_K1], NOISE_PX, seed=7)
    rng = np.random.default_rng(8)
    fit = bundle_adjust([rough(CAM_K1, 1)], ["k1"], observations, [perturbed(T, rng) for T in poses],
                        T_1_from_0=T_1_FROM_0)  # ignored with one camera
    assert fit.T_1_from_0 is None
    assert len(fit.cameras) == 1
    assert fit.cameras[0].dist[1:] == (0.0, 0.0, 0.0, 0.0)  # k2 p1 p2 k3 are not free in "k1"
    ref = Reference([CAM_K1], ["k1"], [False], observations, len(poses))
    assert_statistically_consistent(ref, fit, ref.pack([CAM_K1], None, poses))


def test_residuals_are_per_observation_in_the_order_given() -> None:
    poses, observations = synthetic([CAM0, CAM1], NOISE_PX, seed=9, n_views=4)
    order = np.random.default_rng(10).permutation(len(observations))  # cameras and views interleaved
    shuffled = [observations[k] for k in order]
    rng = np.random.default_rng(11)
    fit = bundle_adjust([rough(CAM0, 1), rough(CAM1, 1)], [MODEL, MODEL], shuffled,
                        [perturbed(T, rng) for T in poses], perturbed(T_1_FROM_0, rng, 2.0, 0.01))
    assert fit.T_1_from_0 is not None and len(fit.residuals) == len(shuffled)
    mine = []
    for o, r in zip(shuffled, fit.residuals, strict=True):
        T = fit.T_0_from_view[o.view] if o.camera == 0 else fit.T_1_from_0 @ fit.T_0_from_view[o.view]
        mine.append(project_cv(fit.cameras[o.camera], T, o.object_points) - o.image_points)
        # the numpy and OpenCV projections of one model agree to round-off (~1e-12 px at 1000 px)
        np.testing.assert_allclose(r, mine[-1], rtol=0, atol=1e-9)
    all_r = np.concatenate(mine)
    assert fit.rms_px == pytest.approx(np.sqrt(np.mean(np.sum(all_r**2, axis=1))), abs=1e-9)


def test_two_cameras_need_an_initial_relative_pose() -> None:
    poses, observations = synthetic([CAM0, CAM1], 0.0, seed=12, n_views=2)
    with pytest.raises(ValueError, match="T_1_from_0"):
        bundle_adjust([CAM0, CAM1], [MODEL, MODEL], observations, poses)


def test_fixed_rational_camera_is_modelled_as_given_or_refused() -> None:
    # A valid Intrinsics with OpenCV's rational model (read_camera_info accepts rational_polynomial files)
    rational = Intrinsics(800.0, 806.0, 322.0, 236.0, 640, 480, (1.8, 0.4, 0.0012, -0.0008, 0.01, 1.95, 0.7, 0.05))
    poses, observations = synthetic([rational], 0.0, seed=13, n_views=4)
    try:
        fit = bundle_adjust([rational], ["none"], observations, poses, fixed=[True])
    except (ValueError, InputError):
        return  # refusing a model it cannot project is a fix too
    assert fit.cameras[0] == rational
    assert fit.rms_px < NOISE_FREE_REL * rational.fx  # exact data seen through the given optics: no residual
