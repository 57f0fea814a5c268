"""The sensor simulator against the paper's section 3 (figures 5 and 6) and basic physics."""

import numpy as np
import pytest

from scanner.peaks import detect_peaks
from scanner.sensor_model import SensorConfig, SensorModel
from scanner.wall import Wall, WallObject, load_wall, shipped_walls

SCAN_Y = 0.30


def _sweep(model, direction=1.0, seed=0, x=None):
    x = np.arange(0.0, 1.8, 0.0005) if x is None else x
    xy = np.column_stack([x, np.full_like(x, SCAN_Y)])
    motion = np.tile([direction, 0.0], (len(x), 1))
    return x, model.display(xy, motion, rng=np.random.default_rng(seed))


def _peak_near(x, y, centre, half=0.08):
    sel = np.abs(x - centre) < half
    peaks = detect_peaks(x[sel], y[sel])
    assert peaks, f"no peak near {centre}"
    return max(peaks, key=lambda p: p.height)


@pytest.fixture(scope="module")
def plate():
    return SensorModel(load_wall(shipped_walls()["paper_test_plate"]))


def test_inductive_peaks_of_the_paper_test_plate(plate):
    x, r = _sweep(plate)
    ind = r[:, 0]
    found = [p for p in detect_peaks(x, ind) if p.height > 0.3]
    # figure 5: mounting plate first, then the 45° pipe at ~0.8 m, then the vertical pipe at ~1.4 m
    assert [round(p.position, 1) for p in found] == [0.2, 0.8, 1.4]
    plate_peak, pipe45, pipe90 = found
    assert pipe45.height < pipe90.height  # slightly lower ...
    assert pipe45.height > 0.85 * pipe90.height  # ... only slightly
    assert pipe45.width > 1.3 * pipe90.width  # ... and wider
    assert plate_peak.height > 0.5  # a strong peak: half of full scale, ~80 σ of the 0.006 noise
    # the cord's copper is faintly visible inductively (cross-sensitivity), far below the pipes
    cord = _peak_near(x, ind, 0.35)
    assert cord.height < 0.5 * pipe90.height  # "far below": under half


def test_ac_sensor_of_the_paper_test_plate(plate):
    x, r = _sweep(plate)
    ac = r[:, 2]
    cord = _peak_near(x, ac, 0.35)
    assert cord.position == pytest.approx(0.35, abs=0.002)  # sharp and exactly placed (no hysteresis)
    assert cord.height > 0.7  # figure 6: the live cord near full scale
    ind_pipe = _peak_near(x, r[:, 0], 1.4)
    assert cord.width < 0.8 * ind_pipe.width  # sharper than the inductive peaks (4 mm vs 11 mm footprint σ)
    base = np.median(ac[(x > 1.6)])
    plate_level = ac[np.abs(x - 0.16) < 0.01].mean()  # metal near the power line: medium level by coupling
    assert 0.2 < plate_level - base < 0.6 * cord.height  # medium: between the pipes' low and the cord's level
    low_08 = ac[np.abs(x - 0.8) < 0.01].mean() - base  # pipes coupled to the line: low signals
    low_14 = ac[np.abs(x - 1.4) < 0.01].mean() - base
    assert 0.02 < low_14 < low_08 < 0.3  # low: above 10 σ of the 0.002 AC noise, below the plate's 0.2


def test_inductive_hysteresis_depends_on_the_direction_of_approach(plate):
    x, right = _sweep(plate, +1.0, seed=1)
    _, left = _sweep(plate, -1.0, seed=2)
    shift = _peak_near(x, right[:, 0], 1.4).position - _peak_near(x, left[:, 0], 1.4).position
    assert shift == pytest.approx(2 * plate.config.hysteresis_m, abs=0.0015)  # a quarter of the 6 mm shift
    ac_shift = _peak_near(x, right[:, 2], 0.35).position - _peak_near(x, left[:, 2], 0.35).position
    assert abs(ac_shift) < 0.001  # no AC hysteresis: a sixth of the inductive shift, two 0.5 mm samples


def test_runs_are_reproducible_and_ac_more_so_than_inductive(plate):
    runs = [_sweep(plate, seed=s)[1] for s in range(3)]
    for ch in (0, 2):
        spread = np.std([r[:, ch] for r in runs], axis=0).mean()
        assert 0 < spread < 0.02  # the 0.006 noise plus 2 % gain / 0.003 offset per run: 0.02 is ~3x
    ind_spread = np.std([r[:, 0] for r in runs], axis=0).mean()
    ac_spread = np.std([r[:, 2] for r in runs], axis=0).mean()
    assert ac_spread < ind_spread
    np.testing.assert_array_equal(_sweep(plate, seed=5)[1], _sweep(plate, seed=5)[1])


def _pipe_wall(depth, diameter=0.015, material="copper"):
    pipe = WallObject(kind="pipe", id="p", depth_m=depth, points_m=np.array([[0.5, 0.0], [0.5, 1.0]]),
                      material=material, diameter_m=diameter, water_filled=True)
    return Wall(width_m=1.0, height_m=1.0, material="brick", objects=[pipe])


def test_deeper_smaller_plastic_pipes_give_lower_wider_or_no_peaks():
    x = np.arange(0.2, 0.8, 0.0005)
    peaks = {}
    for key, wall in {"shallow": _pipe_wall(0.02), "deep": _pipe_wall(0.05), "thin": _pipe_wall(0.02, 0.010),
                      "plastic": _pipe_wall(0.02, material="plastic")}.items():
        _, r = _sweep(SensorModel(wall), x=x)
        peaks[key] = detect_peaks(x, r[:, 0])
    shallow, deep, thin = peaks["shallow"][0], peaks["deep"][0], peaks["thin"][0]
    # 2 -> 5 cm deep: depth gain (0.035 / 0.065)^3 = 0.16; footprint σ = 11 mm + 0.55 depth: 22 -> 39 mm
    assert deep.height < 0.6 * shallow.height and deep.width > 1.3 * shallow.width
    assert thin.height < shallow.height
    assert peaks["plastic"] == []  # no metal: invisible to the inductive sensor


def test_metal_of_the_holder_within_15_cm_disturbs_the_inductive_reading():
    empty = Wall(width_m=1.0, height_m=1.0, material="brick")
    cfg = SensorConfig(holder_metal_uv_m=[[[0.0, -1.0], [0.0, 3.0]]])  # a vertical steel profile at u = 0
    model, clean = SensorModel(empty, cfg), SensorModel(empty)
    u = np.array([0.03, 0.08, 0.12, 0.20, 0.30])
    uv = np.column_stack([u, np.full_like(u, 0.5)])
    disturbed = model.display(uv, drive_uv=uv)[:, 0] - clean.display(uv, drive_uv=uv)[:, 0]
    assert disturbed[0] > 0.3 and disturbed[1] > 0.05  # close metal: a large false reading
    assert disturbed[3] < 0.01 and disturbed[4] < 0.001  # beyond 15 cm: below the sensor noise
    assert np.all(np.diff(disturbed) < 0)
