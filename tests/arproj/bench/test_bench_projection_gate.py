"""The projection bench's gate figures from scene outcomes (no rendering): what counts as unsafe, as a false
alarm and as not checkable, and the reserve fitted on the tuning scenes only."""

import math

from arproj.bench import projection as bench
from arproj.session import scenarios


def _o(seed, show, true_max, verified=True, loop=0.001, kind="sunlight"):
    return scenarios.Outcome(kind, "-", seed, show, [] if show else ["x"], true_max, true_max, 0.008, loop,
                             verified)


def test_gate_figures_count_unsafe_false_alarms_and_unchecked_apart():
    outcomes = [_o(1, True, 0.002), _o(2, False, 0.002), _o(3, False, 0.002, verified=False),
                _o(4, True, 0.03), _o(5, False, 0.03), _o(6, False, math.nan, verified=False)]
    notes = []
    g = bench._gate_figures(outcomes, notes, "judged")
    assert (g.n, g.unsafe, g.bad, g.good, g.false_alarms, g.unverified_good) == (6, 1, 2, 3, 1, 1)
    assert g.false_alarm_share == 0.5  # of the fine scenes the cameras could check
    assert g.seeds == "1–6"
    assert any(n.startswith("UNSAFE (judged, seed 4)") for n in notes)


def test_the_reserve_is_fitted_on_fine_checked_scenes_only():
    tuning = [_o(20_000 + k, True, 0.001, loop=0.0001 * k) for k in range(11)]
    tuning += [_o(20_100, False, 0.05, loop=0.02), _o(20_101, False, 0.001, verified=False, loop=0.02)]
    (note,) = bench._reserve_fit(tuning)
    assert "= 1.0 mm" in note and "11 fine" in note  # p99 of 0 … 1 mm, rounded up to 0.5 mm
