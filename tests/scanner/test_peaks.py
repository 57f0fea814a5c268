"""The 1-D peak detector and its half-maximum walk."""

import numpy as np
import pytest

from scanner.peaks import detect_peaks, level_crossings


def _signal(x, centres, sigma, height, seed=0):
    y = 0.03 + sum(height * np.exp(-0.5 * ((x - c) / sigma) ** 2) for c in centres)
    return y + 0.006 * np.random.default_rng(seed).standard_normal(x.size)


def test_position_and_width_of_a_noisy_peak():
    x = np.arange(0.0, 0.4, 0.00025)
    peaks = detect_peaks(x, _signal(x, [0.1734], 0.01, 0.6))
    assert len(peaks) == 1
    assert peaks[0].position == pytest.approx(0.1734, abs=0.0005)  # two 0.25 mm samples, σ/20 of the 1 cm peak
    assert peaks[0].width == pytest.approx(2.3548 * 0.01, rel=0.05)  # FWHM within 5 %: the noise is 1 % of height
    assert peaks[0].height == pytest.approx(0.6, abs=0.03)  # 5 σ of the 0.006 noise


def test_two_peaks_any_order_and_a_cut_off_peak_is_not_reported():
    x = np.arange(0.0, 0.4, 0.00025)
    y = _signal(x, [0.1, 0.2, 0.395], 0.008, 0.5)
    found = detect_peaks(x[::-1], y[::-1])  # a pass in the other direction
    assert [round(p.position, 3) for p in found] == [0.1, 0.2]
    assert detect_peaks(x, _signal(x, [], 0.01, 0.0)) == []  # noise alone


def test_level_crossings_are_interpolated_between_samples_and_none_for_a_cut_off_peak():
    x = np.arange(11, dtype=np.float64) * 0.01  # a triangle peak of height 10 at x = 0.05
    y = 10.0 - np.abs(np.arange(11) - 5.0) * 2.0
    left, right = level_crossings(x, y, 5, 5.0)
    assert left == pytest.approx(0.025) and right == pytest.approx(0.075)
    assert level_crossings(x, y, 5, -1.0) is None  # never falls that low inside the profile


def test_a_peak_cut_by_the_pass_end_is_kept_at_its_top_only_when_asked():
    # an object in the overlap of two frames: its half maximum lies beyond the pass's start
    u = np.linspace(0.0, 0.4, 801)
    v = 0.02 + 0.5 * np.exp(-0.5 * ((u - 0.01) / 0.012) ** 2)
    assert detect_peaks(u, v) == []
    assert detect_peaks(u, v, keep_cut=(False, True)) == []  # only the end asked for
    (peak,) = detect_peaks(u, v, keep_cut=(True, False))
    assert peak.position == pytest.approx(0.01, abs=0.001) and np.isnan(peak.width)
    # a slope falling from the pass's start has no top inside the pass: nothing to trace from it here
    assert detect_peaks(u, 0.02 + 0.5 * np.exp(-0.5 * ((u + 0.01) / 0.012) ** 2), keep_cut=(True, True)) == []


def test_a_pass_spanning_less_than_the_minimum_height_has_no_peak_and_one_spanning_it_does():
    # the quick answer for flat passes must not drop a peak that clears the threshold by a little
    from scanner.peaks import PeakConfig

    x = np.arange(0.0, 0.4, 0.00025)
    bump = np.exp(-0.5 * ((x - 0.2) / 0.01) ** 2)
    cfg = PeakConfig()
    assert detect_peaks(x, 0.03 + 0.99 * cfg.min_height * bump) == []
    found = detect_peaks(x, 0.03 + 1.2 * cfg.min_height * bump)
    assert [round(p.position, 3) for p in found] == [0.2]
