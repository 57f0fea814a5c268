"""Robust plane fit: RANSAC on stereo transfer error, then a maximum-likelihood fit with covariance.

The plane lives in the left camera frame as p (3,) with X·p = 1 for every point X on it (p = normal / distance,
normal pointing away from the camera): three unconstrained numbers, smooth for any plane not through the camera.

The maximum-likelihood model uses all three views: each corner's projector pixel is known exactly, so its 3-D
point is where that projector ray meets the plane; the cameras measure where the point appears. The projector's
pose on the robot is known only up to the head's repeatability, so a small correction ξ (rotation vector and
translation, in the projector frame) is estimated along with the plane, under a Gaussian prior of that size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from geometry.poses import rotation_matrices, rotation_matrix
from geometry.robust import best_hypothesis, draw_samples, fit_plane
from wallpose import limits


def plane_from_points(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Least-squares plane p (X·p = 1) through (n >= 3, 3) points; the plane must not pass through the origin."""
    centroid, normal = fit_plane(points)
    offset = normal @ centroid
    if abs(offset) < 1e-9:
        return np.full(3, np.nan)
    return normal / offset


def transfer_residuals_px(p: NDArray[np.float64], normalized_left: NDArray[np.float64],
                          normalized_right: NDArray[np.float64], T_right_from_left: NDArray[np.float64],
                          f_right: float) -> NDArray[np.float64]:
    """For planes p (h, 3): pixel distance (h, n) between where each left ray meets the plane, seen by the right
    camera, and where the right camera saw the corner. Independent of the projector's pose."""
    p = np.atleast_2d(p)
    rays = np.column_stack([normalized_left, np.ones(len(normalized_left))])
    lam = 1.0 / (p @ rays.T)                                             # (h, n)
    X = lam[..., None] * rays[None]                                      # (h, n, 3)
    Xr = X @ T_right_from_left[:3, :3].T + T_right_from_left[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = Xr[..., :2] / Xr[..., 2:3]
        err = f_right * np.linalg.norm(uv - normalized_right[None], axis=2)
    err[~np.isfinite(err) | (lam <= 0) | (Xr[..., 2] <= 0)] = np.inf
    return err


def ransac_plane(points_left: NDArray[np.float64], normalized_left: NDArray[np.float64],
                 normalized_right: NDArray[np.float64], T_right_from_left: NDArray[np.float64], f_right: float,
                 rng: np.random.Generator, iterations: int = limits.RANSAC_ITERATIONS,
                 threshold_px: float = limits.RANSAC_THRESHOLD_PX) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Plane with the most corners consistent with it (stereo transfer error < threshold) and those inliers.

    points_left: (n, 3) stereo-triangulated corners in the left frame; normalized_*: (n, 2)."""
    n = len(points_left)
    if n < 3:
        return np.full(3, np.nan), np.zeros(n, dtype=bool)
    samples = draw_samples(rng, n, 3, iterations, distinct=True)
    tri = points_left[samples]                                           # (h, 3, 3)
    # p solves tri @ p = 1 for each hypothesis
    det = np.linalg.det(tri)
    good = np.abs(det) > 1e-12
    hyp = np.linalg.solve(tri[good], np.ones((good.sum(), 3, 1)))[..., 0]
    if len(hyp) == 0:
        return np.full(3, np.nan), np.zeros(n, dtype=bool)
    # hypotheses are ranked on an even subset of the corners (a few hundred tell the best plane as well as all
    # of them); the winner's inliers are counted on all
    score = np.unique(np.linspace(0, n - 1, min(n, limits.RANSAC_SCORE_CORNERS)).astype(np.int64))

    def support(h: slice) -> NDArray[np.int64]:
        err = transfer_residuals_px(hyp[h], normalized_left[score], normalized_right[score], T_right_from_left,
                                    f_right)
        return (err < threshold_px).sum(axis=1)

    best = best_hypothesis(len(hyp), support)
    inliers = transfer_residuals_px(hyp[best], normalized_left, normalized_right, T_right_from_left,
                                    f_right)[0] < threshold_px
    if inliers.sum() >= 3:
        refit = plane_from_points(points_left[inliers])
        if np.all(np.isfinite(refit)):
            again = transfer_residuals_px(refit, normalized_left, normalized_right, T_right_from_left, f_right)[0]
            if (again < threshold_px).sum() >= inliers.sum():
                return refit, again < threshold_px
    return hyp[best], inliers


@dataclass
class ViewData:
    """What the maximum-likelihood fit needs from one camera.

    T_cam_from_left: 4x4; f: focal length (px per normalized unit); seen: (n,) bool over the corners;
    normalized: (n, 2) undistorted normalized coordinates (ignored where not seen)."""

    T_cam_from_left: NDArray[np.float64]
    f: float
    seen: NDArray[np.bool_]
    normalized: NDArray[np.float64]


# Parameter layout of the maximum-likelihood model.
PLANE = slice(0, 3)          # p: X·p = 1 in the left camera frame
PROJ_ROT = slice(3, 6)       # projector rotation correction (rad, projector frame)
PROJ_TRANS = slice(6, 9)     # projector translation correction (m, projector frame)
AFFINE = (slice(9, 15), slice(15, 21))  # per camera: image offset (2) and linear distortion (2x2), normalized
PROJ_AFFINE = slice(21, 27)  # the same for the projector: where its light really lands vs its model
N_PARAMS = 27


@dataclass
class MLModel:
    """The corners' projector rays (n, 3) (projector frame, unit z), the nominal T_left_from_projector, the
    views (left, right), and the prior standard deviations of the nuisance parameters: the projector's pose
    (rad, m: the head's repeatability) and, per camera, a small affine image correction (an offset and a
    linear gradient, in pixels at the image edge) that stands for what calibration and corner finding get
    wrong for a whole image alike (a slightly wrong stereo rotation or focal length, a shading gradient)."""

    projector_rays: NDArray[np.float64]
    T_left_from_projector: NDArray[np.float64]
    views: list[ViewData]
    sigma_rotation: float
    sigma_translation: float
    sigma_offset_px: float
    sigma_gradient_px: float
    half_width_px: float
    projector_f: float
    sigma_projector_offset_px: float
    sigma_projector_gradient_px: float
    projector_half_width_px: float

    @property
    def seen_any(self) -> NDArray[np.bool_]:
        """(n,) corners seen by at least one camera."""
        return np.logical_or.reduce([v.seen for v in self.views])

    @property
    def prior_sigmas(self) -> NDArray[np.float64]:
        sig = [self.sigma_rotation] * 3 + [self.sigma_translation] * 3
        for v in self.views:
            sig += [self.sigma_offset_px / v.f] * 2 + [self.sigma_gradient_px / self.half_width_px] * 4
        sig += [self.sigma_projector_offset_px / self.projector_f] * 2
        sig += [self.sigma_projector_gradient_px / self.projector_half_width_px] * 4
        return np.array(sig)

    def projector_pose(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        dT = np.eye(4)
        dT[:3, :3] = rotation_matrix(theta[PROJ_ROT])
        dT[:3, 3] = theta[PROJ_TRANS]
        return self.T_left_from_projector @ dT

    def points_batch(self, thetas: NDArray[np.float64], rays: NDArray[np.float64] | None = None) -> NDArray:
        """(k, n, 3) left-frame points where the projector rays meet the plane, for k parameter vectors."""
        rays = self.projector_rays if rays is None else rays
        R0, t0 = self.T_left_from_projector[:3, :3], self.T_left_from_projector[:3, 3]
        dR = rotation_matrices(thetas[:, PROJ_ROT])
        R = R0[None] @ dR                                                  # (k, 3, 3)
        o = t0[None] + thetas[:, PROJ_TRANS] @ R0.T                        # (k, 3)
        # the affine correction and the rotation written out per component: numpy's stacked matmul of 2x2 and
        # 3x3 blocks costs several times these elementwise products at a few hundred corners
        a = thetas[:, PROJ_AFFINE, None]                                   # (k, 6, 1)
        x, y = rays[None, :, 0], rays[None, :, 1]
        cx = x + a[:, 0] + x * a[:, 2] + y * a[:, 3]                       # (k, n)
        cy = y + a[:, 1] + x * a[:, 4] + y * a[:, 5]
        Rk = R[:, :, :, None]                                              # (k, 3, 3, 1)
        d = [Rk[:, i, 0] * cx + Rk[:, i, 1] * cy + Rk[:, i, 2] for i in range(3)]   # 3 x (k, n)
        p = thetas[:, PLANE, None]
        lam = (1.0 - (thetas[:, PLANE] * o).sum(axis=1))[:, None] / (p[:, 0] * d[0] + p[:, 1] * d[1] + p[:, 2] * d[2])
        return np.stack([o[:, i, None] + lam * d[i] for i in range(3)], axis=2)

    def points(self, theta: NDArray[np.float64], rays: NDArray[np.float64] | None = None) -> NDArray:
        return self.points_batch(theta[None], rays)[0]

    def _projections(self, thetas: NDArray[np.float64], view_index: int, X: NDArray) -> NDArray:
        """(k, n, 2) normalized image coordinates of points X (k, n, 3) in a view."""
        v = self.views[view_index]
        Xc = X @ v.T_cam_from_left[:3, :3].T + v.T_cam_from_left[:3, 3]
        u, w = Xc[..., 0] / Xc[..., 2], Xc[..., 1] / Xc[..., 2]           # (k, n)
        a = thetas[:, AFFINE[view_index], None]                            # (k, 6, 1)
        return np.stack([u + a[:, 0] + u * a[:, 2] + w * a[:, 3], w + a[:, 1] + u * a[:, 4] + w * a[:, 5]], axis=2)

    def pixel_residuals_batch(self, thetas: NDArray[np.float64], mask: NDArray[np.bool_]) -> NDArray:
        """(k, m) stacked (x, y) pixel residuals of every seen, unmasked corner in every view."""
        X = self.points_batch(thetas)
        out = []
        for i, v in enumerate(self.views):
            use = v.seen & mask
            uv = self._projections(thetas, i, X[:, use])
            out.append((v.f * (uv - v.normalized[use][None])).reshape(len(thetas), -1))
        return np.concatenate(out, axis=1)

    def corner_errors(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """(n,) the largest pixel error of each corner over the views that see it (0 where unseen)."""
        X = self.points_batch(theta[None])
        worst = np.zeros(X.shape[1])
        for i, v in enumerate(self.views):
            e = v.f * np.linalg.norm(self._projections(theta[None], i, X)[0] - v.normalized, axis=1)
            worst = np.where(v.seen, np.maximum(worst, np.nan_to_num(e, nan=np.inf)), worst)
        return worst

    def whitened_batch(self, thetas: NDArray[np.float64], sigma_px: float, mask: NDArray[np.bool_]) -> NDArray:
        prior = thetas[:, 3:] / self.prior_sigmas[None]
        return np.concatenate([self.pixel_residuals_batch(thetas, mask) / sigma_px, prior], axis=1)


@dataclass
class MLFit:
    """theta (21,): plane p then the nuisance parameters; covariance (21, 21); sigma_px: a-posteriori corner
    noise (px); rms_px: root-mean-square pixel residual; inliers: (n,) bool."""

    theta: NDArray[np.float64]
    covariance: NDArray[np.float64]
    sigma_px: float
    rms_px: float
    inliers: NDArray[np.bool_]
    residuals: NDArray[np.float64]     # (m,) whitened, at theta
    jacobian: NDArray[np.float64]      # (m, 21)
    row_view: NDArray[np.int64]        # (m,) view of each residual row, -1 for the priors

    def single_view(self, view: int) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """(theta, covariance, sigma_px) from one camera (and the projector) alone: one Gauss–Newton step
        from the joint solution on that camera's rows and the priors (the model is nearly linear here)."""
        rows = (self.row_view == view) | (self.row_view < 0)
        J, r = self.jacobian[rows], self.residuals[rows]
        N = J.T @ J
        delta = np.linalg.solve(N, -(J.T @ r))
        pix = (r + J @ delta)[self.row_view[rows] == view] * self.sigma_px
        sigma = max(float(np.sqrt(pix @ pix / max(len(pix) - 3, 1))), limits.SIGMA_FLOOR_PX)
        return self.theta + delta, np.linalg.inv(N) * (sigma / self.sigma_px) ** 2, sigma


_FINITE = np.r_[0:9, PROJ_AFFINE.start:PROJ_AFFINE.stop]  # parameters differentiated numerically


def _linearize(model: MLModel, theta: NDArray[np.float64], sigma: float, mask: NDArray[np.bool_]
               ) -> tuple[NDArray, NDArray]:
    """Whitened residuals r (m,) and their Jacobian J (m, 27): forward differences in one batch for the plane
    and the projector, exact columns for the cameras' affine corrections (they enter linearly)."""
    steps = np.full(N_PARAMS, 1e-7)
    steps[PLANE] = 1e-7 * np.linalg.norm(theta[PLANE])
    thetas = np.vstack([theta, theta + np.diag(steps)[_FINITE]])
    r_all = model.whitened_batch(thetas, sigma, mask)
    r = r_all[0]
    J = np.zeros((len(r), N_PARAMS))
    J[:, _FINITE] = ((r_all[1:] - r) / steps[_FINITE][:, None]).T
    X = model.points(theta)
    row = 0
    for i, v in enumerate(model.views):
        use = v.seen & mask
        Xc = X[use] @ v.T_cam_from_left[:3, :3].T + v.T_cam_from_left[:3, 3]
        uv = Xc[:, :2] / Xc[:, 2:3]
        k = len(uv)
        block = np.zeros((k, 2, 6))
        block[:, 0, 0] = block[:, 1, 1] = 1.0
        block[:, 0, 2:4] = uv
        block[:, 1, 4:6] = uv
        J[row:row + 2 * k, AFFINE[i]] = block.reshape(2 * k, 6) * (v.f / sigma)
        row += 2 * k
    prior_rows = row + np.arange(N_PARAMS - 3)
    for i in range(len(model.views)):
        cols = np.arange(AFFINE[i].start, AFFINE[i].stop)
        J[prior_rows[cols - 3], cols] = 1.0 / model.prior_sigmas[cols - 3]
    return r, J


def _solve(J: NDArray[np.float64], r: NDArray[np.float64]) -> NDArray[np.float64]:
    """Gauss–Newton step from the normal equations (the priors keep them well conditioned)."""
    return np.asarray(np.linalg.solve(J.T @ J, -(J.T @ r)), dtype=np.float64)


def fit_ml(model: MLModel, p0: NDArray[np.float64], inliers: NDArray[np.bool_],
           iterations: int = limits.GAUSS_NEWTON_ITERATIONS, theta0: NDArray[np.float64] | None = None,
           refine_inliers: bool = True) -> MLFit:
    """Gauss–Newton on the whitened residuals; the corner noise and (unless refine_inliers is False) the
    inliers are re-estimated twice."""
    theta = np.concatenate([p0, np.zeros(N_PARAMS - 3)]) if theta0 is None else theta0.copy()
    sigma = 0.25
    converged = False
    for _ in range(2):
        for _ in range(iterations):
            r, J = _linearize(model, theta, sigma, inliers)
            delta = _solve(J, r)
            theta = theta + delta
            converged = bool(np.linalg.norm(delta[PLANE]) < 1e-7 * np.linalg.norm(theta[PLANE]))
            if converged:
                break
        linearized_at = (sigma, inliers)
        pix = model.pixel_residuals_batch(theta[None], inliers)[0]
        sigma = max(float(np.sqrt(pix @ pix / max(len(pix) - 3, 1))), limits.SIGMA_FLOOR_PX)
        # inliers from a robust noise level, so a cluster of off-plane corners cannot widen its own gate
        robust = 1.4826 * float(np.median(np.abs(pix))) if len(pix) else sigma
        gate = max(limits.INLIER_FLOOR_PX, limits.INLIER_SIGMAS * robust)
        if refine_inliers:
            inliers = model.seen_any & (model.corner_errors(theta) < gate)
    if converged and np.array_equal(inliers, linearized_at[1]):
        # the last step was negligible and the corners are the same: the last linearization holds; only the
        # pixel rows' whitening changes with the new noise level (the priors' rows stay)
        pixel_rows = len(r) - (N_PARAMS - 3)
        r, J = r.copy(), J.copy()
        r[:pixel_rows] *= linearized_at[0] / sigma
        J[:pixel_rows] *= linearized_at[0] / sigma
    else:
        r, J = _linearize(model, theta, sigma, inliers)
        theta = theta + _solve(J, r)
        r, J = _linearize(model, theta, sigma, inliers)
    covariance = np.linalg.pinv(J.T @ J)
    pix = model.pixel_residuals_batch(theta[None], inliers)[0]
    row_view = np.concatenate([np.full(2 * int((v.seen & inliers).sum()), i) for i, v in enumerate(model.views)]
                              + [np.full(N_PARAMS - 3, -1)])
    return MLFit(theta, covariance, sigma, float(np.sqrt(np.mean(pix ** 2))) if len(pix) else float("nan"),
                 inliers, r, J, row_view)


def plane_in_frame(p: NDArray[np.float64], T_frame_from_left: NDArray[np.float64]) -> NDArray[np.float64]:
    """(4,) [normal (unit, pointing into the room, i.e. towards the cameras), distance] of plane p in a frame:
    normal·X = -distance for X on the plane; distance > 0 when the frame's origin is on the room side."""
    d_left = 1.0 / np.linalg.norm(p)
    n_left = -p * d_left
    n = T_frame_from_left[:3, :3] @ n_left
    return np.concatenate([n, [d_left - n @ T_frame_from_left[:3, 3]]])
