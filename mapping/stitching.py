"""Frame stitching (paper section 4.2): wall plane per frame, frame poses, weighted linear least squares.

A *frame* is one robot stop: the scanner rasters a ~0.35 m wide rectangle and every sample is known in the
frame's own coordinates (the xy drives' positions). The frame's pose on the wall is the planar rigid motion
x_i = (tx, ty, θ) [m, m, rad] with p_wall = R(θ)·p_frame + t.

Constraints (each Gaussian, with its own covariance Σ):
  * prior        — the localization solution for frame i: z = x_i;
  * relative     — the laser's relative measurement between frames i and j: z = x_j − x_i;
  * laser fix    — the 2-D lasers' fix of frame i's pose against the side walls and the floor (scanner.laser,
                   logged per frame with σ per coordinate): z = tx_i, ty_i, θ_i (1 row each);
  * point        — one in-wall feature (screw, nail, a pipe's bend) seen in frames i and j at frame
                   coordinates p_i and p_j: R_i p_i + t_i − (R_j p_j + t_j) = 0 (2 rows);
  * line         — a pipe or cable crossing the border between frames i and j: a point p_j of frame j on frame
                   i's line (through a_i with normal n, frame i coordinates):
                   (R_i n)·(R_j p_j + t_j − t_i) − n·a_i = 0 (1 row; slides along the line).
Rotations are linearised about the localization's θ (the paper's 'collaborative setup with rather bounded
errors'), making the problem linear: r = z − J x, minimised by x = (JᵀΣ⁻¹J)⁻¹ JᵀΣ⁻¹ z, solved with a sparse
Cholesky-like factorisation of the 3N×3N normal matrix (scipy.sparse, SuperLU).

`fit_plane` finds a frame's wall plane from its laser/3-D points: RANSAC then least squares on the inliers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike, NDArray

from geometry import robust
from geometry.errors import InputError
from mapping import tolerances as tol

# A laser fix is never trusted beyond these σ (x m, y m, θ rad): mounting calibration residue, floor flatness
LASER_SIGMA_FLOOR = (0.0002, 0.0002, 1e-4)


# ---- planes ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Plane:
    """n·p = d with unit normal n (3,); inliers (m,) bool over the input points; rms residual, metres."""

    normal: NDArray[np.float64]
    d: float
    centroid: NDArray[np.float64]
    inliers: NDArray[np.bool_]
    rms_m: float

    def distance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Signed distances (n,) of points (n, 3) to the plane, metres."""
        return np.asarray(points, dtype=np.float64).reshape(-1, 3) @ self.normal - self.d

    def covariance(self, points: ArrayLike) -> NDArray[np.float64]:
        """3×3 covariance of (tilt about the plane's first in-plane axis [rad], tilt about the second [rad],
        offset along the normal at the centroid [m]) from the inliers' scatter and residual rms:
        σ²(XᵀX)⁻¹ of the least-squares model n-offset = a·u + b·v + c over the inliers."""
        q = np.asarray(points, dtype=np.float64).reshape(-1, 3)[self.inliers]
        _, _, vt = np.linalg.svd(q - self.centroid, full_matrices=False)
        u, v = vt[0], vt[1]
        X = np.column_stack([(q - self.centroid) @ u, (q - self.centroid) @ v, np.ones(len(q))])
        dof = max(len(q) - 3, 1)
        sigma2 = float(np.sum(((q - self.centroid) @ self.normal) ** 2)) / dof
        return sigma2 * np.linalg.inv(X.T @ X)


def fit_plane(points: ArrayLike, inlier_m: float = tol.PLANE_INLIER_M, iterations: int = tol.RANSAC_ITERATIONS,
              seed: int = 0, toward: ArrayLike | None = None, what: str = "points") -> Plane:
    """The dominant plane of points (n, 3) metres: RANSAC, then least squares on the inliers (twice).

    NaN points are ignored. `toward`: a point (e.g. the sensor) the normal should face. Raises InputError
    naming `what` when fewer than PLANE_MIN_POINTS sound points remain or they are degenerate (a line).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.all(np.isfinite(p), axis=1)
    q = p[finite]
    if q.shape[0] < tol.PLANE_MIN_POINTS:
        raise InputError(f"{what}: only {q.shape[0]} sound points, too few for a wall plane "
                         f"(need {tol.PLANE_MIN_POINTS})", "the frame keeps its localization pose")
    trip = robust.draw_samples(np.random.default_rng(seed), q.shape[0], 3, iterations)
    a, b, c = q[trip[:, 0]], q[trip[:, 1]], q[trip[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    good = norms > 1e-9
    if not good.any():
        raise InputError(f"{what}: points are collinear; no plane can be fitted")
    normals = normals[good] / norms[good, None]
    ds = np.einsum("ij,ij->i", normals, a[good])
    # Scored in chunks of 50 hypotheses: counts of points within inlier_m
    best = robust.best_hypothesis(len(normals),
                                  lambda h: (np.abs(q @ normals[h].T - ds[h]) < inlier_m).sum(axis=0), chunk=50)
    inl = np.abs(q @ normals[best] - ds[best]) < inlier_m
    if inl.sum() < 3:
        raise InputError(f"{what}: no plane with at least 3 points within {inlier_m * 1000:.0f} mm")

    def refit(inl: NDArray[np.bool_]) -> tuple[None, NDArray[np.bool_]]:
        centroid, n = robust.fit_plane(q[inl])
        resid = (q - centroid) @ n
        new_inl = np.abs(resid) < max(inlier_m, 3.0 * float(np.std(resid[inl])))
        return None, new_inl if new_inl.sum() >= 3 else inl  # too few: keep the last inliers

    _, inl = robust.refine(inl, refit, rounds=2)
    centroid, n = robust.fit_plane(q[inl])
    sv = np.linalg.svd(q[inl] - centroid, compute_uv=False)
    if sv.size < 2 or sv[1] < 1e-6 * max(sv[0], 1e-12):
        raise InputError(f"{what}: inlier points are collinear; no plane can be fitted")
    if toward is not None and (np.asarray(toward, dtype=np.float64) - centroid) @ n < 0:
        n = -n
    d = float(n @ centroid)
    rms = float(np.sqrt(np.mean(((q[inl] - centroid) @ n) ** 2)))
    mask = np.zeros(p.shape[0], bool)
    mask[np.flatnonzero(finite)[inl]] = True
    return Plane(n, d, centroid, mask, rms)


def fit_frame_planes(points_by_frame: dict[int, ArrayLike], seed: int = 0,
                     toward: ArrayLike | None = None) -> tuple[dict[int, Plane | None], list[str]]:
    """The wall plane of every frame from its laser/3-D points (RANSAC + least squares); frames whose points
    cannot give a plane get None and a message, and the rest is still fitted."""
    planes: dict[int, Plane | None] = {}
    problems: list[str] = []
    for frame_id, pts in points_by_frame.items():
        try:
            planes[frame_id] = fit_plane(pts, seed=seed + int(frame_id), toward=toward,
                                         what=f"frame {frame_id} laser points")
        except InputError as err:
            planes[frame_id] = None
            problems.append(str(err))
    return planes, problems


# ---- frame graph ------------------------------------------------------------------------------------------
def _rot(theta: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def apply_pose(pose: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Frame points (n, 2) to wall points with pose (tx, ty, θ)."""
    tx, ty, th = np.asarray(pose, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    c, s = np.cos(th), np.sin(th)
    return np.column_stack([c * p[:, 0] - s * p[:, 1] + tx, s * p[:, 0] + c * p[:, 1] + ty])


@dataclass
class FrameGraph:
    """Poses of N frames with Gaussian constraints; `solve()` aligns them.

    linearisation : (N, 3) poses about whose θ rotations are linearised (normally the priors themselves).
    """

    linearisation: NDArray[np.float64]
    _blocks: list[tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return int(self.linearisation.shape[0])

    @property
    def n_blocks(self) -> int:
        """Constraint blocks added so far (solve_robust's feature_blocks_from counts these)."""
        return len(self._blocks)

    def _add(self, i: ArrayLike, j: ArrayLike | None, Ji: NDArray, Jj: NDArray | None, z: NDArray,
             info: NDArray) -> None:
        """Constraints z = Ji x_i + Jj x_j, each (m rows); info = Σ⁻¹ (k, m, m)."""
        i = np.asarray(i, dtype=np.int64).reshape(-1)
        k = i.shape[0]
        if j is None:
            j = i.copy()
            Jj = np.zeros_like(Ji)
        elif Jj is None:
            raise ValueError("a constraint between two frames needs Jj")
        j = np.asarray(j, dtype=np.int64).reshape(-1)
        for name, idx in (("i", i), ("j", j)):
            if idx.size and (idx.min() < 0 or idx.max() >= self.n_frames):
                raise InputError(f"constraint frame index {name} out of range 0…{self.n_frames - 1}")
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(info))):
            raise InputError("a stitching constraint has a NaN observation or covariance")
        self._blocks.append((i, j, Ji.reshape(k, -1, 3), Jj.reshape(k, -1, 3), z.reshape(k, -1),
                             info.reshape(k, z.shape[-1] if z.ndim > 1 else 1, -1)))

    @staticmethod
    def _info(cov: ArrayLike, k: int, m: int) -> NDArray[np.float64]:
        cov = np.asarray(cov, dtype=np.float64)
        if cov.ndim == 1 and cov.shape[0] == m:  # standard deviations
            cov = np.diag(cov**2)
        cov = np.broadcast_to(cov, (k, m, m))
        try:
            return np.linalg.inv(cov)
        except np.linalg.LinAlgError:
            raise InputError("a stitching covariance is singular; give positive variances") from None

    def add_priors(self, poses: ArrayLike, cov: ArrayLike) -> None:
        """Localization: poses (N, 3); cov (3, 3), (N, 3, 3) or standard deviations (3,)."""
        z = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        k = z.shape[0]
        self._add(np.arange(k), None, np.broadcast_to(np.eye(3), (k, 3, 3)).copy(), None, z,
                  self._info(cov, k, 3))

    def add_relative(self, i: ArrayLike, j: ArrayLike, delta: ArrayLike, cov: ArrayLike) -> None:
        """Laser relative measurement: x_j − x_i = delta (k, 3)."""
        z = np.asarray(delta, dtype=np.float64).reshape(-1, 3)
        k = z.shape[0]
        eye = np.broadcast_to(np.eye(3), (k, 3, 3))
        self._add(i, j, -eye.copy(), eye.copy(), z, self._info(cov, k, 3))

    def add_coordinate(self, i: ArrayLike, axis: int, value: ArrayLike, sigma: ArrayLike) -> None:
        """An absolute measurement of one pose coordinate (axis 0 tx, 1 ty, 2 θ) of frames i: z = x_i[axis]."""
        i = np.asarray(i, dtype=np.int64).reshape(-1)
        k = i.shape[0]
        J = np.zeros((k, 1, 3))
        J[:, 0, axis] = 1.0
        sig = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (k,))
        if np.any(sig <= 0):
            raise InputError("a stitching standard deviation is not positive")
        self._add(i, None, J, None, np.asarray(value, dtype=np.float64).reshape(k, 1), (1.0 / sig**2)[:, None, None])

    def _point_terms(self, idx: NDArray, p: NDArray) -> tuple[NDArray, NDArray]:
        """Linearised R(θ)p + t = J·x + c about the linearisation θ: returns (J (k,2,3), c (k,2))."""
        th0 = self.linearisation[idx, 2]
        rp = np.einsum("kab,kb->ka", _rot(th0), p)
        q = np.column_stack([-rp[:, 1], rp[:, 0]])  # dR/dθ · p
        J = np.zeros((idx.shape[0], 2, 3))
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        J[:, :, 2] = q
        return J, rp - q * th0[:, None]

    def add_points(self, i: ArrayLike, p_i: ArrayLike, j: ArrayLike, p_j: ArrayLike, cov: ArrayLike) -> None:
        """A point feature seen in frames i and j at frame coordinates p_i, p_j (k, 2); cov (2, 2) or σ (2,)."""
        i = np.asarray(i, dtype=np.int64).reshape(-1)
        j = np.asarray(j, dtype=np.int64).reshape(-1)
        pi = np.asarray(p_i, dtype=np.float64).reshape(-1, 2)
        pj = np.asarray(p_j, dtype=np.float64).reshape(-1, 2)
        Ji, ci = self._point_terms(i, pi)
        Jj, cj = self._point_terms(j, pj)
        # Ji x_i + ci − Jj x_j − cj = 0  →  z = cj − ci
        self._add(i, j, Ji, -Jj, cj - ci, self._info(cov, i.shape[0], 2))

    def add_lines(self, i: ArrayLike, a_i: ArrayLike, normal_i: ArrayLike, j: ArrayLike, p_j: ArrayLike,
                  sigma_m: ArrayLike) -> None:
        """A line (pipe, cable) seen in frames i and j: the point p_j (k, 2) of frame j lies on frame i's line
        through a_i (k, 2) with unit normal normal_i (k, 2), both in frame i's coordinates. One row each:
        f = (R_i n)·(R_j p_j + t_j − t_i) − n·a_i = 0, linearised about the linearisation poses (the normal
        turns with frame i, so distant points on a long line constrain correctly)."""
        i = np.asarray(i, dtype=np.int64).reshape(-1)
        j = np.asarray(j, dtype=np.int64).reshape(-1)
        a = np.asarray(a_i, dtype=np.float64).reshape(-1, 2)
        n = np.asarray(normal_i, dtype=np.float64).reshape(-1, 2)
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        pj = np.asarray(p_j, dtype=np.float64).reshape(-1, 2)
        x0i, x0j = self.linearisation[i], self.linearisation[j]
        Ri, Rj = _rot(x0i[:, 2]), _rot(x0j[:, 2])
        perp = np.array([[0.0, -1.0], [1.0, 0.0]])  # dR/dθ = perp @ R
        m = np.einsum("kab,kb->ka", Ri, n)  # wall normal
        dm = m @ perp.T
        wj = np.einsum("kab,kb->ka", Rj, pj) + x0j[:, :2]
        f0 = np.einsum("ka,ka->k", m, wj - x0i[:, :2]) - np.einsum("ka,ka->k", n, a)
        Ji = np.zeros((i.shape[0], 1, 3))
        Jj = np.zeros((i.shape[0], 1, 3))
        Ji[:, 0, :2] = -m
        Ji[:, 0, 2] = np.einsum("ka,ka->k", dm, wj - x0i[:, :2])
        Jj[:, 0, :2] = m
        Jj[:, 0, 2] = np.einsum("ka,ka->k", m, np.einsum("kab,kb->ka", Rj, pj) @ perp.T)
        # f(x) ≈ f0 + Ji(x_i − x0_i) + Jj(x_j − x0_j) = 0  →  Ji x_i + Jj x_j = Ji x0_i + Jj x0_j − f0
        z = (np.einsum("kma,ka->km", Ji, x0i) + np.einsum("kma,ka->km", Jj, x0j))[:, 0] - f0
        sig = np.broadcast_to(np.asarray(sigma_m, dtype=np.float64), (i.shape[0],))
        self._add(i, j, Ji, Jj, z[:, None], (1.0 / sig**2)[:, None, None])

    def mahalanobis(self, x: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        """Per block, each constraint's Mahalanobis distance √(rᵀΣ⁻¹r) at poses x (N, 3)."""
        out = []
        for i, j, Ji, Jj, z, W in self._blocks:
            r = z - np.einsum("kma,ka->km", Ji, x[i]) - np.einsum("kma,ka->km", Jj, x[j])
            out.append(np.sqrt(np.einsum("km,kmn,kn->k", r, W, r)))
        return out

    def keep(self, masks: list[NDArray[np.bool_]]) -> int:
        """Keep only the constraints where masks (one per block) are True; returns how many were dropped."""
        dropped = 0
        blocks = []
        for (i, j, Ji, Jj, z, W), m in zip(self._blocks, masks, strict=True):
            dropped += int((~m).sum())
            if m.any():
                blocks.append((i[m], j[m], Ji[m], Jj[m], z[m], W[m]))
        self._blocks = blocks
        return dropped

    def solve_robust(self, feature_blocks_from: int, gate: float = 4.0,
                     rounds: int = 10) -> tuple[NDArray[np.float64], int]:
        """Solve; while some feature constraint (blocks from index feature_blocks_from on) lies farther than
        `gate` (Mahalanobis) from the solution, drop the worst one (a wrong association distorts its
        neighbours too, so one at a time) and re-solve. Returns (poses (N, 3), constraints dropped)."""
        dropped = 0
        x, _ = self.solve()
        for _ in range(rounds):
            d = self.mahalanobis(x)
            worst, block = 0.0, -1
            for b in range(feature_blocks_from, len(d)):
                if d[b].size and float(d[b].max()) > worst:
                    worst, block = float(d[b].max()), b
            if worst <= gate:
                break
            masks = [np.ones(len(di), bool) for di in d]
            masks[block] = d[block] < worst
            dropped += self.keep(masks)
            x, _ = self.solve()
        return x, dropped

    # ---- assembly and solution ----------------------------------------------------------------------------
    def normal_equations(self) -> tuple[sp.csc_matrix, NDArray[np.float64]]:
        """(JᵀΣ⁻¹J (3N, 3N) sparse, JᵀΣ⁻¹z (3N,)), assembled block by block (3×3 per frame pair)."""
        n3 = 3 * self.n_frames
        rows, cols, vals = [], [], []
        g = np.zeros(n3)
        c3 = np.arange(3)
        for i, j, Ji, Jj, z, W in self._blocks:
            Wz = np.matmul(W, z[:, :, None])  # (k, m, 1)
            terms = [(i, Ji)] if not Jj.any() else [(i, Ji), (j, Jj)]
            WJ = [np.matmul(W, Jb) for _, Jb in terms]
            for a_idx, Ja in terms:
                JaT = Ja.transpose(0, 2, 1)
                g += np.bincount((3 * a_idx[:, None] + c3).ravel(), np.matmul(JaT, Wz)[:, :, 0].ravel(),
                                 minlength=n3)
                r = np.broadcast_to((3 * a_idx)[:, None, None] + c3[None, :, None], (len(a_idx), 3, 3))
                for (b_idx, _), WJb in zip(terms, WJ, strict=True):
                    rows.append(r.ravel())
                    cols.append(np.broadcast_to((3 * b_idx)[:, None, None] + c3[None, None, :],
                                                (len(b_idx), 3, 3)).ravel())
                    vals.append(np.matmul(JaT, WJb).ravel())
        H = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n3, n3)).tocsc()
        return H, g

    def whitened_system(self) -> tuple[sp.csr_matrix, NDArray[np.float64]]:
        """(L J, L z) with LᵀL = Σ⁻¹ per constraint: the same problem for a general least-squares solver."""
        rows, cols, vals, rhs = [], [], [], []
        offset = 0
        for i, j, Ji, Jj, z, W in self._blocks:
            k, m = z.shape
            L = np.linalg.cholesky(W).transpose(0, 2, 1)  # W = LᵀL
            for a_idx, Ja in ((i, Ji), (j, Jj)):
                LJ = L @ Ja  # (k, m, 3)
                r = offset + m * np.arange(k)[:, None, None] + np.arange(m)[None, :, None]
                c = 3 * a_idx[:, None, None] + np.arange(3)[None, None, :]
                rows.append(np.broadcast_to(r, LJ.shape).ravel())
                cols.append(np.broadcast_to(c, LJ.shape).ravel())
                vals.append(LJ.ravel())
            rhs.append(np.einsum("kmn,kn->km", L, z).ravel())
            offset += k * m
        A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(offset, 3 * self.n_frames))
        return A, np.concatenate(rhs)

    def solve(self, covariance: bool = False) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Aligned poses (N, 3) and, if asked, their marginal covariances (N, 3, 3).

        Raises InputError if the constraints leave a frame's pose undetermined (no prior reaches it).
        """
        if not self._blocks:
            raise InputError("no constraints to align frames with")
        H, g = self.normal_equations()
        try:
            lu = spla.splu(H)
        except RuntimeError:
            raise InputError("frame alignment is under-determined: some frame has no localization prior "
                             "or chain of constraints to one") from None
        x = lu.solve(g)
        if not np.all(np.isfinite(x)):
            raise InputError("frame alignment is under-determined (singular normal matrix)")
        cov = None
        if covariance:
            n = self.n_frames
            cov = np.empty((n, 3, 3))
            for f in range(n):
                e = np.zeros((3 * n, 3))
                e[3 * f:3 * f + 3] = np.eye(3)
                cov[f] = lu.solve(e)[3 * f:3 * f + 3]
        return x.reshape(-1, 3), cov


def laser_constraints(graph: FrameGraph, frames: dict[str, NDArray]) -> int:
    """Add every frame's logged laser fix (frames: scan-log frame arrays, in graph order, with laser_x_m,
    laser_y_m, laser_phi_rad and their *_sigma_*) as absolute coordinate constraints; coordinates without a
    sound fix are skipped (a version 1 log has none). Returns how many frames got at least one."""
    fixed = np.zeros(graph.n_frames, bool)
    for axis, (value_key, sigma_key) in enumerate((("laser_x_m", "laser_x_sigma_m"), ("laser_y_m", "laser_y_sigma_m"),
                                                   ("laser_phi_rad", "laser_phi_sigma_rad"))):
        if value_key not in frames or sigma_key not in frames:
            continue
        value = np.asarray(frames[value_key], dtype=np.float64)
        sigma = np.asarray(frames[sigma_key], dtype=np.float64)
        ok = np.isfinite(value) & np.isfinite(sigma) & (sigma > 0)
        if ok.any():
            graph.add_coordinate(np.flatnonzero(ok), axis, value[ok], np.maximum(sigma[ok], LASER_SIGMA_FLOOR[axis]))
            fixed |= ok
    return int(fixed.sum())


def seam_error(poses_est: ArrayLike, poses_true: ArrayLike, border_points: ArrayLike,
               pairs: ArrayLike) -> NDArray[np.float64]:
    """Seam errors (k,) metres: how far apart two neighbouring frames map the same wall point.

    For pair (i, j) and a true wall point w on their border, frame i holds it at Tᵢ_true⁻¹ w and frame j at
    Tⱼ_true⁻¹ w; the map places them at T̂ᵢ(·) and T̂ⱼ(·). The seam error is the distance between the two.
    border_points : (k, 2) wall points, one per pair; pairs : (k, 2) frame indices.
    """
    est = np.asarray(poses_est, dtype=np.float64)
    true = np.asarray(poses_true, dtype=np.float64)
    w = np.asarray(border_points, dtype=np.float64).reshape(-1, 2)
    pr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    out = np.empty(w.shape[0])
    for k, (i, j) in enumerate(pr):
        pi = _inverse_apply(true[i], w[k:k + 1])
        pj = _inverse_apply(true[j], w[k:k + 1])
        out[k] = float(np.linalg.norm(apply_pose(est[i], pi) - apply_pose(est[j], pj)))
    return out


def _inverse_apply(pose: NDArray[np.float64], wall_points: NDArray[np.float64]) -> NDArray[np.float64]:
    tx, ty, th = pose
    c, s = np.cos(th), np.sin(th)
    d = wall_points - np.array([tx, ty])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
