"""The simulated camera's fast paths give what the plain numpy formulas give."""

from __future__ import annotations

import numpy as np
from scipy import stats

from arproj.sim import optics
from arproj.sim.site import _View


def test_sensor_noise_is_standard_normal_reproducible_and_fresh_each_photo() -> None:
    rng = np.random.default_rng(11)
    first = optics.standard_normal(rng, (400, 640))
    second = optics.standard_normal(rng, (400, 640))
    sample = first.ravel().astype(np.float64)
    # n = 256,000: σ of the mean 0.002, of the std 0.0014, of skew 0.005, of kurtosis 0.01 — each bound ≥ 4 σ
    assert abs(sample.mean()) < 0.01 and abs(sample.std() - 1.0) < 0.01
    assert abs(stats.skew(sample)) < 0.02 and abs(stats.kurtosis(sample)) < 0.05
    assert stats.kstest(sample[::16], "norm").pvalue > 1e-3  # a false alarm once in a thousand seeds
    # Each photo draws new noise, uncorrelated with the last; the same seed gives the same noise.
    assert abs(np.corrcoef(first.ravel(), second.ravel())[0, 1]) < 0.01  # 5 σ: σ = 1/√n = 0.002
    np.testing.assert_array_equal(optics.standard_normal(np.random.default_rng(11), (400, 640)), first)
    colour = optics.standard_normal(rng, (200, 300, 3))
    # every channel, not just the first (n = 60,000 each: σ of the std 0.003, 0.02 is ~7 σ)
    assert np.allclose(colour.reshape(-1, 3).std(axis=0), 1.0, atol=0.02)


def test_luma_matches_the_rec709_weights() -> None:
    rgbd = np.random.default_rng(2).random((50, 70, 4), dtype=np.float32)
    expected = rgbd[..., :3] @ optics.LUMA_RGB
    # float32 round-off of a three-term sum in [0, 1] is ~1e-7
    np.testing.assert_allclose(optics.luma(np.ascontiguousarray(rgbd[..., :3])), expected, atol=1e-6)
    np.testing.assert_allclose(optics.luma(rgbd), expected, atol=1e-6)


def test_blur_level_weights_interpolate_like_numpy_and_sum_to_one() -> None:
    sigma = np.random.default_rng(4).uniform(0.2, 6.0, (60, 80)).astype(np.float32)
    zeros = np.zeros_like(sigma)
    view = _View(albedo_rgb=np.zeros((60, 80, 3), np.float32), irradiance=zeros, ambient_lux=0.0, depth=zeros,
                 map_u=zeros, map_v=zeros, sigma_px=sigma, seen=zeros > 0, sigma_range=(0.2, 6.0),
                 blur=optics.BlurPlan((0.5,), [None]))
    levels = (0.5, 1.0, 2.0, 3.5)  # weights in [0, 1], float32: 1e-6 is a few units of round-off
    weights = view.level_weights(levels)
    position = np.interp(sigma, levels, np.arange(len(levels)))
    for k, weight in enumerate(weights):
        expected = np.clip(1.0 - np.abs(position - k), 0.0, 1.0)
        np.testing.assert_allclose(0.0 if weight is None else weight, expected, atol=1e-6)
    np.testing.assert_allclose(sum(w for w in weights if w is not None), 1.0, atol=1e-6)
    assert view.level_weights(levels) is weights  # cached per view
