"""The live-calibration coverage of `arproj bench calibration`: the Wilson interval, the pooling and the verdict,
against values worked out by hand (z = 1.96)."""

from __future__ import annotations

import pytest

from arproj.bench.calibration import coverage, live_coverage, wilson_interval


def test_wilson_interval_matches_hand_computed_values() -> None:
    # 19 of 20: centre (0.95 + 0.09604) / 1.19208 = 0.87749, half 1.96 / 1.19208 · √(0.002375 + 0.0024010) = 0.11363
    assert wilson_interval(19, 20) == pytest.approx((0.76386, 0.99112), abs=1e-4)
    # every trial within: the lower end is n / (n + z²), the upper 1
    assert wilson_interval(10, 10) == pytest.approx((10 / (10 + 1.96**2), 1.0), abs=1e-4)
    # none within: 0 and z² / (n + z²)
    assert wilson_interval(0, 5) == pytest.approx((0.0, 1.96**2 / (5 + 1.96**2)), abs=1e-4)
    with pytest.raises(ValueError):
        wilson_interval(0, 0)


def test_coverage_per_quantity_and_pooled_over_every_check() -> None:
    checks = {
        "projector fx": [{"within": True}, {"within": True}, {"within": False}],
        "mount rotation": [{"within": True}, {"within": True}, {"within": True}],
    }
    per, pooled = live_coverage(checks)
    assert (per["projector fx"].within, per["projector fx"].trials) == (2, 3)
    assert (per["mount rotation"].within, per["mount rotation"].trials) == (3, 3)
    assert (pooled.within, pooled.trials) == (5, 6)
    assert (pooled.low, pooled.high) == pytest.approx(wilson_interval(5, 6))
    assert pooled.share == pytest.approx(5 / 6)


def test_verdict_is_met_above_95_percent_not_met_below_and_unknown_between() -> None:
    assert coverage([True] * 80).verdict is True  # lower end 80 / 83.84 = 0.954
    assert coverage([True] * 20).verdict is None  # lower end 20 / 23.84 = 0.839: 20 seeds cannot show 95 %
    assert coverage([True] * 19 + [False]).verdict is None
    assert coverage([True] * 14 + [False] * 6).verdict is False  # upper end 0.86
