"""Joint refinement (bundle adjustment) of one or two cameras, their relative pose and the target poses.

Unknowns: each non-fixed camera's fx, fy, cx, cy and its free distortion terms; T_1_from_0 when there are two
cameras (camera 1 = right camera or projector); one pose T_0_from_view per view (board or wall pose), shared
by both cameras' observations of that view. Residuals: reprojection errors in pixels.
The Jacobian is taken by finite differences over column groups (scipy's sparse scheme: one residual call per
group, not per unknown), then solved densely with the exact trust-region solver.

Uncertainty: the covariance of the unknowns at the solution is s²·(JᵀJ)⁻¹ with s² the residual variance
(sum of squares over residuals minus unknowns); each free camera's fx, fy, cx, cy get their σ from it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative, group_columns

from calibration.camera_model import DISTORTION_MODELS, dist5_from, project
from geometry.intrinsics import Intrinsics
from geometry.poses import pose_from_rvec_tvec, rotation_matrices, rotation_matrix, rvec_tvec_from_pose
from geometry.threads import single_threaded

BA_TOLERANCE = 1e-10
BA_MAX_EVALUATIONS = 200


@dataclass
class Observation:
    """Camera `camera` saw view `view`: image_points (n, 2) px of object_points (n, 3) m in the view frame."""

    camera: int
    view: int
    image_points: NDArray[np.float64]
    object_points: NDArray[np.float64]


@dataclass
class BundleResult:
    cameras: list[Intrinsics]
    T_1_from_0: NDArray[np.float64] | None
    T_0_from_view: list[NDArray[np.float64]]
    residuals: list[NDArray[np.float64]]  # per observation, (n, 2) px, in the order given
    intrinsics_sigma: list[dict[str, float] | None] = field(default_factory=list)  # per camera (None: fixed)
    # Covariance of the unknowns other than the view poses, in the order of `parameters` (see sample_cameras).
    covariance: NDArray[np.float64] | None = None
    parameters: list[str] = field(default_factory=list)
    models: list[str] = field(default_factory=list)
    fixed: list[bool] = field(default_factory=list)

    def sample_cameras(self, rng: np.random.Generator, n: int
                       ) -> list[tuple[list[Intrinsics], NDArray[np.float64] | None]]:
        """n draws of (cameras, T_1_from_0) from the fit's covariance (Gaussian, first order): what the
        cameras might be, for carrying their uncertainty into what is computed from them."""
        if self.covariance is None:
            raise ValueError("this bundle result has no covariance")
        x0 = _camera_vector(self.cameras, self.models, self.fixed, self.T_1_from_0)
        draws = rng.multivariate_normal(x0, self.covariance, size=n, method="eigh")
        return [_cameras_from_vector(x, self.cameras, self.models, self.fixed, self.T_1_from_0 is not None)
                for x in draws]

    @property
    def rms_px(self) -> float:
        r = np.concatenate(self.residuals)
        return float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


class _Problem:
    def __init__(self, cameras: list[Intrinsics], models: list[str], fixed: list[bool],
                 observations: list[Observation], n_views: int) -> None:
        self.cameras = cameras
        self.free = [DISTORTION_MODELS[m] for m in models]
        self.fixed = fixed
        self.offsets = []
        offset = 0
        for i in range(len(cameras)):
            self.offsets.append(offset)
            if not fixed[i]:
                offset += 4 + len(self.free[i])
        self.stereo_offset = offset
        self.pose_offset = offset + (6 if len(cameras) == 2 else 0)
        self.n_params = self.pose_offset + 6 * n_views
        self.n_views = n_views
        self.observations = observations
        # Observations are stacked per camera so each camera projects in one vectorised call.
        self.groups = []
        for cam in range(len(cameras)):
            idx = [k for k, o in enumerate(observations) if o.camera == cam]
            if not idx:
                continue
            obs = [observations[k] for k in idx]
            view_index = np.concatenate([np.full(len(o.object_points), o.view) for o in obs])
            obj = np.concatenate([o.object_points for o in obs])
            img = np.concatenate([o.image_points for o in obs])
            self.groups.append((cam, idx, view_index, obj, img))

    def camera_params(self, x: NDArray, cam: int) -> tuple[float, float, float, float, NDArray]:
        if self.fixed[cam]:
            c = self.cameras[cam]
            return c.fx, c.fy, c.cx, c.cy, np.asarray(c.dist, dtype=np.float64)  # a fixed camera keeps its model
        o, free = self.offsets[cam], self.free[cam]
        d = np.zeros(5)
        d[list(free)] = x[o + 4:o + 4 + len(free)]
        return x[o], x[o + 1], x[o + 2], x[o + 3], d

    def residual_blocks(self, x: NDArray[np.float64]) -> list[tuple[list[int], NDArray[np.float64]]]:
        poses = x[self.pose_offset:].reshape(self.n_views, 6)
        R_views = rotation_matrices(poses[:, :3])
        out = []
        for cam, idx, view_index, obj, img in self.groups:
            fx, fy, cx, cy, d = self.camera_params(x, cam)
            p = np.einsum("nij,nj->ni", R_views[view_index], obj) + poses[view_index, 3:]
            if cam == 1:
                s = x[self.stereo_offset:self.stereo_offset + 6]
                p = p @ rotation_matrix(s[:3]).T + s[3:]
            out.append((idx, project(p, fx, fy, cx, cy, d) - img))
        return out

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.concatenate([r.ravel() for _, r in self.residual_blocks(x)])

    def sparsity(self) -> NDArray[np.int8]:
        rows = []
        for cam, _, view_index, _, _ in self.groups:
            block = np.zeros((len(view_index), self.n_params), np.int8)
            if not self.fixed[cam]:
                o = self.offsets[cam]
                block[:, o:o + 4 + len(self.free[cam])] = 1
            if cam == 1:
                block[:, self.stereo_offset:self.stereo_offset + 6] = 1
            for k in range(6):
                block[np.arange(len(view_index)), self.pose_offset + 6 * view_index + k] = 1
            rows.append(np.repeat(block, 2, axis=0))
        return np.concatenate(rows)


def bundle_adjust(cameras: list[Intrinsics], models: list[str], observations: list[Observation],
                  T_0_from_view: list[NDArray[np.float64]], T_1_from_0: NDArray[np.float64] | None = None,
                  fixed: list[bool] | None = None) -> BundleResult:
    """Refine cameras (unless fixed), T_1_from_0 (two cameras) and view poses from initial values."""
    fixed = list(fixed) if fixed is not None else [False] * len(cameras)
    problem = _Problem(cameras, models, fixed, observations, len(T_0_from_view))
    if len(cameras) == 2 and T_1_from_0 is None:
        raise ValueError("two cameras need an initial T_1_from_0")
    x0 = [_camera_vector(cameras, models, fixed, T_1_from_0 if len(cameras) == 2 else None)]
    x0.extend(np.concatenate(rvec_tvec_from_pose(T)) for T in T_0_from_view)
    x_start = np.concatenate(x0)
    sparsity = problem.sparsity()
    groups = group_columns(sparsity)

    def jacobian(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return approx_derivative(problem.residuals, x, method="2-point", sparsity=(sparsity, groups)).toarray()

    # BLAS on one thread: the exact solver's SVD of a few thousand rows by a few dozen columns cost 45x its
    # single-thread CPU on OpenBLAS's threads on a loaded 2-core machine (geometry.threads).
    with single_threaded():
        fit = least_squares(problem.residuals, x_start, jac=jacobian, method="trf", x_scale="jac",
                            ftol=BA_TOLERANCE, xtol=BA_TOLERANCE, gtol=BA_TOLERANCE, tr_solver="exact",
                            max_nfev=BA_MAX_EVALUATIONS)
    x = fit.x
    out_cams = []
    for cam, intr in enumerate(cameras):
        fx, fy, cx, cy, d = problem.camera_params(x, cam)
        dist = tuple(intr.dist) if fixed[cam] else tuple(d)
        out_cams.append(Intrinsics(float(fx), float(fy), float(cx), float(cy), intr.width, intr.height, dist))
    T10 = None
    if len(cameras) == 2:
        s = x[problem.stereo_offset:problem.stereo_offset + 6]
        T10 = pose_from_rvec_tvec(s[:3], s[3:])
    poses = [pose_from_rvec_tvec(p[:3], p[3:]) for p in x[problem.pose_offset:].reshape(-1, 6)]
    residuals: dict[int, NDArray[np.float64]] = {}
    for idx, r in problem.residual_blocks(x):
        bounds = np.cumsum([0, *[len(observations[k].object_points) for k in idx]])
        for k, a, b in zip(idx, bounds[:-1], bounds[1:], strict=True):
            residuals[k] = r[a:b]
    with single_threaded():
        cov = _covariance(fit.fun, jacobian(x))
    return BundleResult(out_cams, T10, poses, [residuals[k] for k in range(len(observations))],
                        _intrinsics_sigma(problem, cov), cov[:problem.pose_offset, :problem.pose_offset],
                        _parameter_names(problem, models), list(models), fixed)


def _covariance(r: NDArray[np.float64], J: NDArray[np.float64]) -> NDArray[np.float64]:
    """s²·(JᵀJ)⁻¹ at the solution."""
    dof = max(len(r) - J.shape[1], 1)
    return float(r @ r) / dof * np.linalg.pinv(J.T @ J)


def _intrinsics_sigma(problem: _Problem, cov: NDArray[np.float64]) -> list[dict[str, float] | None]:
    """σ of each free camera's fx, fy, cx, cy."""
    out: list[dict[str, float] | None] = []
    for cam in range(len(problem.cameras)):
        if problem.fixed[cam]:
            out.append(None)
            continue
        o = problem.offsets[cam]
        sd = np.sqrt(np.diag(cov)[o:o + 4])
        out.append({k: float(v) for k, v in zip(("fx", "fy", "cx", "cy"), sd, strict=True)})
    return out


def intrinsics_95(sigma: dict[str, float]) -> dict[str, float]:
    """95 % bounds (1.96 σ, px, rounded as written) of one camera's fx, fy, cx, cy from its intrinsics_sigma."""
    return {k: round(1.96 * v, 4) for k, v in sigma.items()}


def _parameter_names(problem: _Problem, models: list[str]) -> list[str]:
    names = []
    for cam in range(len(problem.cameras)):
        if not problem.fixed[cam]:
            dist = ("k1", "k2", "p1", "p2", "k3")
            free = [dist[i] for i in DISTORTION_MODELS[models[cam]]]
            names += [f"{cam}:{k}" for k in ("fx", "fy", "cx", "cy", *free)]
    if len(problem.cameras) == 2:
        names += [f"T_1_from_0:{k}" for k in ("rx", "ry", "rz", "tx", "ty", "tz")]
    return names


def _camera_vector(cameras: list[Intrinsics], models: list[str], fixed: list[bool],
                   T_1_from_0: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """The unknowns other than the view poses, as bundle_adjust orders them."""
    x = []
    for cam, intr in enumerate(cameras):
        if not fixed[cam]:
            d = dist5_from(intr.dist)
            free = list(DISTORTION_MODELS[models[cam]])
            x.append(np.concatenate([[intr.fx, intr.fy, intr.cx, intr.cy], d[free]]))
    if T_1_from_0 is not None:
        x.append(np.concatenate(rvec_tvec_from_pose(T_1_from_0)))
    return np.concatenate(x) if x else np.zeros(0)


def _cameras_from_vector(x: NDArray[np.float64], cameras: list[Intrinsics], models: list[str], fixed: list[bool],
                         with_pose: bool) -> tuple[list[Intrinsics], NDArray[np.float64] | None]:
    out, o = [], 0
    for cam, intr in enumerate(cameras):
        if fixed[cam]:
            out.append(intr)
            continue
        free = DISTORTION_MODELS[models[cam]]
        d = np.zeros(5)
        d[list(free)] = x[o + 4:o + 4 + len(free)]
        out.append(Intrinsics(float(x[o]), float(x[o + 1]), float(x[o + 2]), float(x[o + 3]), intr.width,
                              intr.height, tuple(float(v) for v in d)))
        o += 4 + len(free)
    return out, (pose_from_rvec_tvec(x[o:o + 3], x[o + 3:o + 6]) if with_pose else None)
