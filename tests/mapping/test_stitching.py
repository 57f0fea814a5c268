"""Plane fitting and frame alignment by weighted linear least squares, against scipy and the truth."""

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from geometry.errors import InputError
from mapping.stitching import FrameGraph, apply_pose, fit_plane, seam_error


def test_fit_plane_with_outliers():
    rng = np.random.default_rng(1)
    n_true = np.array([0.1, -0.2, 1.0])
    n_true /= np.linalg.norm(n_true)
    u = np.cross(n_true, [1, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n_true, u)
    a, b = rng.uniform(-1, 1, (2, 400))
    pts = 2.0 * n_true + a[:, None] * u + b[:, None] * v + rng.normal(0, 0.002, (400, 1)) * n_true
    outliers = rng.uniform(-1, 1, (80, 3)) + np.array([0.0, 0.0, 3.0])
    plane = fit_plane(np.vstack([pts, outliers, [[np.nan] * 3]]), toward=[0, 0, 0])
    # 5 σ of the least-squares tilt (σ ≈ 1.7e-4 rad = 0.01° per axis, below); a bare 3-point RANSAC plane would not do
    assert np.degrees(np.arccos(abs(plane.normal @ n_true))) < 0.05
    assert plane.normal @ n_true < 0  # faces the origin
    assert abs(abs(plane.d) - 2.0) < 5e-4  # 5 σ of the offset (2 mm / √400 = 1e-4 m)
    assert plane.inliers[:400].mean() > 0.97 and not plane.inliers[400:].any()  # 1 cm band = 5 σ of the noise
    assert plane.rms_m < 0.0025  # the 2 mm noise; its rms over 400 points is known to 3.5 % (1/√800)
    cov = plane.covariance(np.vstack([pts, outliers, [[np.nan] * 3]]))
    # 2 mm noise over ±1 m: tilt σ ≈ 2e-3 / (0.58 · √400) ≈ 1.7e-4 rad, offset σ ≈ 2e-3 / √400 = 1e-4 m
    assert 0.5e-4 < np.sqrt(cov[0, 0]) < 4e-4 and 0.5e-4 < np.sqrt(cov[2, 2]) < 2e-4


def test_fit_plane_too_few_points():
    with pytest.raises(InputError, match="too few"):
        fit_plane(np.random.default_rng(0).random((5, 3)), what="frame 3 laser")


def _chain(n=60, seed=0):
    rng = np.random.default_rng(seed)
    true = np.column_stack([np.arange(n) * 0.35, rng.normal(0, 0.01, n), rng.normal(0, 0.002, n)])
    sig = np.array([0.02, 0.01, np.radians(1.0)])
    est = true + rng.normal(size=(n, 3)) * sig
    return rng, true, est, sig


def _inverse(pose, w):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = w - pose[:2]
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])


def test_alignment_with_point_and_line_features_beats_priors_and_matches_lsqr():
    rng, true, est, sig = _chain()
    n = len(true)
    g = FrameGraph(est.copy())
    g.add_priors(est, sig)
    i = np.arange(n - 1)
    j = i + 1
    # two screws per seam, seen in both frames with 0.5 mm noise
    for height in (0.3, 1.6):
        w = np.column_stack([true[i, 0] + 0.35, np.full(n - 1, height)])
        pi = np.array([_inverse(true[a], w[k]) for k, a in enumerate(i)]) + rng.normal(0, 5e-4, (n - 1, 2))
        pj = np.array([_inverse(true[b], w[k]) for k, b in enumerate(j)]) + rng.normal(0, 5e-4, (n - 1, 2))
        g.add_points(i, pi, j, pj, [5e-4, 5e-4])
    # a horizontal pipe at y = 1.0 crossing every seam, seen 4 cm apart on either side
    for a, b in zip(i, j, strict=True):
        wa = np.array([true[a, 0] + 0.33, 1.0])
        wb = np.array([true[a, 0] + 0.37, 1.0])
        ca, sa = np.cos(true[a, 2]), np.sin(true[a, 2])
        normal_local = np.array([sa, ca])  # R_aᵀ (0, 1): the wall's "up" seen in frame a
        g.add_lines([a], _inverse(true[a], wa), normal_local, [b], _inverse(true[b], wb), 1e-3)
    x, cov = g.solve(covariance=True)
    border = np.column_stack([true[i, 0] + 0.35, np.full(n - 1, 1.0)])
    pairs = np.column_stack([i, j])
    before = seam_error(est, true, border, pairs).mean()
    after = seam_error(x, true, border, pairs).mean()
    # Before: the 2 cm / 1 cm / 1° pose noise (~3 cm seams); after: within 2x the 0.5 mm feature noise.
    assert before > 0.015 and after < 0.001
    A, b = g.whitened_system()
    ref = spla.lsqr(A, b, atol=1e-14, btol=1e-14, iter_lim=20000)[0].reshape(-1, 3)
    np.testing.assert_allclose(x, ref, atol=1e-6)  # 1 µm / 1 µrad: far below the 0.5 mm noise, above lsqr's 1e-14 stop
    assert cov is not None and np.all(np.linalg.eigvalsh(cov) > 0)
    # alignment leaves the gauge to the priors: the mean pose error shrinks, it does not vanish
    assert np.abs(x[:, 2] - true[:, 2]).mean() < np.abs(est[:, 2] - true[:, 2]).mean()


def test_line_constraint_is_exact_at_the_truth():
    _, true, est, _ = _chain(3, seed=4)
    g = FrameGraph(est.copy())
    w1, w2 = np.array([0.30, 0.8]), np.array([0.55, 0.8 + 0.25 * np.tan(0.3)])  # a diagonal line
    d = (w2 - w1) / np.linalg.norm(w2 - w1)
    c, s = np.cos(true[0, 2]), np.sin(true[0, 2])
    d_local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
    g.add_lines([0], _inverse(true[0], w1), [-d_local[1], d_local[0]], [1], _inverse(true[1], w2), 1e-3)
    r = g.mahalanobis(true)[0]
    # linearised about est (poses 1–2° off): second-order error under 1 mm at 0.5 m lever arms
    assert r[0] * 1e-3 < 1e-3


def test_under_determined_alignment_raises():
    g = FrameGraph(np.zeros((3, 3)))
    g.add_priors(np.zeros((1, 3)), [0.01, 0.01, 0.01])  # only frame 0 has a prior
    with pytest.raises(InputError):
        g.solve()


def test_apply_pose_matches_scanner_convention():
    from scanner.plan import frame_pose_apply

    uv = np.array([[0.1, 0.2], [0.3, -0.1]])
    np.testing.assert_allclose(apply_pose((0.5, 0.1, 0.3), uv), frame_pose_apply((0.5, 0.1, 0.3), uv))


def test_frames_with_too_few_laser_points_are_reported_and_skipped():
    from mapping.stitching import fit_frame_planes

    rng = np.random.default_rng(3)
    good = np.column_stack([rng.uniform(0, 1, 200), np.full(200, 2.0), rng.uniform(0, 1, 200)])
    planes, problems = fit_frame_planes({0: good, 1: good[:4], 2: np.full((50, 3), np.nan)})
    assert planes[0] is not None and abs(abs(planes[0].normal[1]) - 1) < 1e-9  # exact plane y = 2: round-off only
    assert planes[1] is None and planes[2] is None
    assert len(problems) == 2 and "frame 1 laser points" in problems[0] and "too few" in problems[0]
