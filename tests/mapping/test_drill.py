"""The drill check against the simulated truth: safe only where the sensors looked and found nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geometry.errors import InputError
from mapping import drill
from mapping.evaluate import false_safe
from mapping.evidence import Coverage, measured_stretches, regions
from mapping.grid import GridInfo
from mapping.mapfile import MappedObject, read_objects
from mapping.pipeline import MapSettings, build_map
from mapping.simscan import simulate_scan
from tests.support.hazard_wall import CLEAR_SPOT, hazard_wall, hazard_wall_dense_map


@pytest.fixture(scope="module")
def wall():
    return hazard_wall()


@pytest.fixture(scope="module")
def dense(wall):
    return hazard_wall_dense_map()


def _verdict(result, objects, xy, **kw):
    return drill.check_point(xy, objects, result.coverage, result.bounds, **kw)


def test_dense_scan_never_calls_a_hazard_safe_and_keeps_away_from_the_metal(wall, dense):
    result, objects = dense
    fs = false_safe(objects, result.coverage, wall)
    assert set(fs.probed_m) == {"live", "dead", "copper", "water"}
    assert fs.share == 0.0, fs.safe_m
    # the metal hazards are mapped, so along most of them the check says keep away, not merely unknown
    for key in ("live", "dead", "copper"):
        assert fs.unknown_m[key] <= 0.5 * fs.probed_m[key], key


def test_a_clear_spot_that_was_scanned_is_safe_and_names_the_nearest_object(dense):
    result, objects = dense
    v = _verdict(result, objects, CLEAR_SPOT)
    assert v.verdict == drill.SAFE, v.reason
    assert v.nearest is not None and v.distance_m > 0.03
    doc = v.to_json()
    assert set(doc) == {"x_m", "y_m", "verdict", "reason", "nearest"}
    assert set(doc["nearest"]) == {"class", "distance_m", "depth_m"}


def test_outside_the_wall_is_unknown(dense):
    result, objects = dense
    for xy in ((-0.01, 0.2), (0.2, 0.41), (7.0, 7.0), (np.nan, 0.1)):
        v = _verdict(result, objects, xy)
        assert v.verdict == drill.UNKNOWN and v.reason == "outside the wall"


def test_a_missed_object_still_shows_as_an_unexplained_response(wall, dense):
    # The same scan's evidence as if the map had found nothing: over each hazard the sensors responded, so
    # the check must not say safe there although no object is named.
    from mapping.evidence import coverage_radii, sample_noise

    result, _ = dense
    data = simulate_scan(wall, seed=4, robot_sigma=(0.0, 0.0, 0.0), loc_sigma=(1e-4, 1e-4, 1e-5))
    s = data.samples
    looked = {c: result.sample_xy[np.isfinite(s[c])] for c in result.grid.sensors}
    noise = {c: sample_noise(s[c], s["pass_id"], c) for c in result.grid.sensors}
    blind = Coverage.from_grid(result.grid, looked, [], coverage_radii(None), result.bounds, noise)
    fs = false_safe([], blind, wall)
    assert fs.share == 0.0, fs.safe_m
    v = drill.check_point((0.08, 0.2), [], blind, result.bounds)
    assert v.verdict == drill.UNKNOWN and "unexplained" in v.reason


def test_between_coarse_passes_is_unknown_not_safe(wall):
    # Passes 6 cm apart: the inductive footprint's 5.5 mm coverage radius leaves most of the wall unlooked at.
    data = simulate_scan(wall, seed=5, line_spacing_m=0.06, robot_sigma=(0.0, 0.0, 0.0),
                         loc_sigma=(1e-4, 1e-4, 1e-5))
    result = build_map(data, MapSettings(stitch=False))
    objects = result.mapped_objects()
    assert false_safe(objects, result.coverage, wall).share == 0.0
    between = _verdict(result, objects, (CLEAR_SPOT[0], 0.03))  # passes at y = 0, 0.06: 3 cm from both
    assert between.verdict == drill.UNKNOWN and "not scanned" in between.reason
    share = result.coverage.covered_share()
    assert 0.05 < share < 0.3  # ≈ 2·5.5 mm of every 60 mm is covered by both channels


def test_without_the_capacitive_channel_nothing_is_safe(wall):
    data = simulate_scan(wall, seed=6, robot_sigma=(0.0, 0.0, 0.0), loc_sigma=(1e-4, 1e-4, 1e-5))
    del data.samples["capacitive"]
    result = build_map(data, MapSettings(stitch=False))
    v = _verdict(result, result.mapped_objects(), CLEAR_SPOT)
    assert v.verdict == drill.UNKNOWN and "channel missing: no capacitive" in v.reason
    assert "plastic" in v.reason


def test_an_inferred_stretch_is_never_safe_and_a_measured_one_keeps_away(dense):
    result, _ = dense
    line = MappedObject("metal_pipe", np.array([[0.0, 0.05], [0.1, 0.05], [0.2, 0.05]]), 0.015,
                        measured=np.array([True, False]))
    on_measured = _verdict(result, [line], (0.05, 0.05))
    on_inferred = _verdict(result, [line], (0.15, 0.05))
    assert on_measured.verdict == drill.KEEP_AWAY and on_measured.nearest is line
    assert on_inferred.verdict == drill.UNKNOWN and "inferred only" in on_inferred.reason


def test_band_and_registration_uncertainty_set_the_keep_away_distance(dense):
    result, _ = dense
    pipe = MappedObject("metal_pipe", np.array([[0.0, 0.2], [0.35, 0.2]]), 0.02, sigma_m=0.002)
    reach = drill.DRILL_RADIUS_M + drill.band_half_width_m(pipe)  # hole edge meets the band edge here
    assert _verdict(result, [pipe], (0.3, 0.2 + reach - 0.0005)).verdict == drill.KEEP_AWAY
    assert _verdict(result, [pipe], (0.3, 0.2 + reach + 0.0005)).verdict != drill.KEEP_AWAY
    # a registration error of 5 mm (1σ) widens the band by 1.96·(√(2² + 5²) − 2) mm
    wider = drill.DRILL_RADIUS_M + drill.band_half_width_m(pipe, 0.005)
    assert wider - reach == pytest.approx(drill.Z95 * (np.hypot(0.002, 0.005) - 0.002))
    v = _verdict(result, [pipe], (0.3, 0.2 + reach + 0.0005), registration_sigma_m=0.005)
    assert v.verdict == drill.KEEP_AWAY


def test_measured_stretches_cut_a_line_where_its_coverage_ends():
    points = np.array([[0.0, 0.0], [1.0, 0.0]])
    pts, flags = measured_stretches(points, lambda p: p[:, 0] < 0.3)
    assert flags.tolist() == [True, False]
    assert pts[1, 0] == pytest.approx(0.3, abs=0.002)  # the cut lies within one probing step of the edge
    pts, flags = measured_stretches(points, lambda p: (p[:, 0] < 0.3) | (p[:, 0] > 0.6))
    assert flags.tolist() == [True, False, True]


def test_scanned_regions_keep_their_holes():
    info = GridInfo.covering(0.0, 0.0, 1.0, 1.0, 0.01)
    mask = np.zeros(info.shape, bool)
    mask[10:90, 10:90] = True
    mask[40:60, 40:60] = False  # a hole no footprint reached
    polys = regions(mask, info)
    assert len(polys) == 1 and len(polys[0]["holes"]) == 1
    from shapely.geometry import Point, Polygon

    shape = Polygon(polys[0]["exterior"], polys[0]["holes"])
    assert shape.contains(Point(0.2, 0.2)) and not shape.contains(Point(0.5, 0.5))
    # outer edge within a cell of the mask's edge (cell centres from 0.105 to 0.895 m)
    assert shape.bounds == pytest.approx((0.105, 0.105, 0.895, 0.895), abs=0.011)


def test_coverage_round_trips_and_bad_files_are_named(dense, tmp_path):
    result, _ = dense
    path = result.coverage.save(tmp_path / "coverage.npz")
    back = Coverage.load(path)
    assert back.channels == result.coverage.channels and back.wall_bounds == result.bounds
    for c in back.channels:
        np.testing.assert_array_equal(back.covered[c], result.coverage.covered[c])
        np.testing.assert_array_equal(back.response[c], result.coverage.response[c])
    with pytest.raises(InputError, match="no coverage layer"):
        Coverage.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(InputError, match=r"junk\.npz"):
        Coverage.load(tmp_path / "junk.npz")


def test_objects_json_round_trips_measured_flags_and_depth(dense, tmp_path):
    import copy

    from mapping.mapfile import write_objects

    objects = copy.deepcopy(dense[1])  # the module's map stays as the other tests read it
    objects[0].depth_m, objects[0].depth_sigma_m = 0.021, 0.002
    path = write_objects(tmp_path / "objects.json", objects)
    back = read_objects(path)
    assert [o.cls for o in back] == [o.cls for o in objects]
    assert back[0].depth_m == pytest.approx(0.021) and back[0].depth_sigma_m == pytest.approx(0.002)
    for a, b in zip(back, objects, strict=True):
        np.testing.assert_array_equal(a.measured_segments(), b.measured_segments())
        np.testing.assert_allclose(a.points_m, b.points_m, atol=1e-5)  # written with 5 decimals
    doc = json.loads(path.read_text())
    assert doc["format"] == "arproj-objects/2"


def test_the_raster_of_verdicts_is_check_point_at_every_cell(dense) -> None:
    """verdict_raster is check_point at each cell's centre (the map_server export and others read it), with and
    without a registration σ; every verdict occurs, so the comparison means something."""
    result, objects = dense
    info = result.coverage.info
    for sigma in (0.0, 0.003):
        raster = drill.verdict_raster(objects, result.coverage, result.bounds, registration_sigma_m=sigma)
        rows, cols = np.meshgrid(np.arange(info.height), np.arange(info.width), indexing="ij")
        xy = np.column_stack([info.origin_x + (cols.ravel() + 0.5) * info.resolution,
                              info.origin_y + (rows.ravel() + 0.5) * info.resolution])
        expected = np.array([drill.VERDICT_CODES[v.verdict] for v in drill.check_points(
            xy, objects, result.coverage, result.bounds, registration_sigma_m=sigma)], np.int8)
        assert set(np.unique(expected)) == set(drill.VERDICT_CODES.values())
        np.testing.assert_array_equal(raster.ravel(), expected)
