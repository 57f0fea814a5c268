"""The scan's live view (arproj.run.view.ScanView): the pictures it redraws window by window between sends are
the ones drawn from the whole grid, and it sends the grids only when samples fell since; its detections are the
adaptive plan's own peaks where the plan searched, its own search elsewhere, and lie on the site's objects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from arproj.run import view as view_module
from arproj.run.scan import ScanSettings, scan_simulated
from geometry.polyline import distances_to_polyline
from mapping.evidence import DEFAULT_COVERAGE_RADIUS_M, SAFETY_CHANNELS
from scanner.channels import INDUCTIVE
from scanner.channels import NAMES as CHANNEL_NAMES
from scanner.peaks import detect_peaks
from scanner.wall import Wall, load_wall, shipped_walls


def test_the_pictures_redrawn_by_window_are_those_of_the_whole_grid(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(view_module, "IMAGE_PERIOD_S", 0.0)  # a redraw after every pass: many small windows
    wall = load_wall(shipped_walls()["small_test_wall"])
    view = view_module.ScanView(str(tmp_path / "scan.rrd"), wall.width_m, wall.height_m)
    logged: list[str] = []
    log = view.rec.log

    def counted(entity: str, *args: object, **kwargs: object) -> None:
        logged.append(entity)
        log(entity, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(view.rec, "log", counted)
    samples = scan_simulated(wall, ScanSettings(plan="adaptive", serial=False), watch=view).result.samples
    view.close()
    xy = np.column_stack([samples["x_m"], samples["y_m"]])
    rows, cols, inside = view.info.cell_of(xy)
    for channel in CHANNEL_NAMES:  # the sums, pass by pass over each pass's box, are those of all samples at once
        values = np.asarray(samples[channel], dtype=np.float64)
        ok = inside & np.isfinite(values)
        sums, counts = np.zeros(view.info.shape), np.zeros(view.info.shape)
        np.add.at(sums, (rows[ok], cols[ok]), values[ok])
        np.add.at(counts, (rows[ok], cols[ok]), 1.0)
        np.testing.assert_array_equal(view.counts[channel], counts)
        np.testing.assert_allclose(view.sums[channel], sums, rtol=1e-12, atol=1e-12)
    res = view.info.resolution
    covered = {}
    for channel in SAFETY_CHANNELS:  # the whole grid at once, as the view drew it before it kept its pictures
        radius = DEFAULT_COVERAGE_RADIUS_M[channel] / res
        r = int(np.ceil(radius))
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        covered[channel] = ndimage.binary_dilation(view.counts[channel] > 0, structure=np.hypot(dx, dy) <= radius + 0.5)
        np.testing.assert_array_equal(view.covered[channel], covered[channel])
    cover = np.zeros_like(view.cover)
    cover[np.any(list(covered.values()), axis=0)] = (240, 170, 0, 120)
    cover[np.all(list(covered.values()), axis=0)] = (0, 170, 60, 120)
    np.testing.assert_array_equal(view.cover, cover)
    assert (view.cover[..., 3] > 0).mean() > 0.5  # the scan covered most of the wall: the check is not empty
    for channel in CHANNEL_NAMES:
        seen = view.counts[channel] > 0
        mean = np.divide(view.sums[channel], view.counts[channel], out=np.zeros(seen.shape), where=seen)
        np.testing.assert_array_equal(view.maps[channel][..., 0], np.clip(255 * mean, 0, 255).astype(np.uint8))
        np.testing.assert_array_equal(view.maps[channel][..., 3], 255 * seen)
    # grids went out once per pass that brought samples (and the first), never again at the close
    sends = logged.count("wall/coverage")
    assert sends == len({e for e in logged if e.startswith("wall/samples/")}) and sends > 10
    assert all(logged.count(f"wall/map/{c}") == sends for c in CHANNEL_NAMES)


class _Seen:
    """A watcher between the scan and the view that keeps what the view was handed."""

    def __init__(self, view: view_module.ScanView) -> None:
        self.view, self.passes = view, []

    def frame(self, row: dict, report: object) -> None:
        self.view.frame(row, report)  # type: ignore[arg-type]

    def scanned(self, row: dict, samples: dict) -> None:
        self.passes.append((row, samples))
        self.view.scanned(row, samples)


def _expected_detections(view: view_module.ScanView, passes: list) -> dict[str, np.ndarray]:
    """Where the view should put each channel's detections: the plan's peaks (handed in the row) where the
    plan searched the pass, else detect_peaks on the pass's samples at the view's step; on the wall."""
    out: dict[str, list] = {c: [] for c in CHANNEL_NAMES}
    for row, samples in passes:
        if row["axis"] not in ("x", "y"):
            continue
        coord = samples["drive_u_m" if row["axis"] == "x" else "drive_v_m"]
        order = np.argsort(coord)
        for channel in CHANNEL_NAMES:
            if channel in row.get("peaks", {}):
                at = list(row["peaks"][channel])
            else:
                lag = view.hysteresis_m * row["direction"] if channel == INDUCTIVE.name else 0.0
                at = [p.position - lag for p in detect_peaks(coord, samples[channel],
                                                             grid_step_m=view_module.DETECTION_STEP_M)]
            out[channel] += [(np.interp(a, coord[order], samples["x_m"][order]),
                              np.interp(a, coord[order], samples["y_m"][order])) for a in at]
    return {c: np.array(p).reshape(-1, 2) for c, p in out.items()}


def _found(view: view_module.ScanView, channel: str) -> np.ndarray:
    found = np.concatenate(view.found[channel]) if view.found[channel] else np.zeros((0, 2))
    return np.column_stack([found[:, 0], view.top - found[:, 1]])  # back from the screen to the wall


def _distance_to_truth(wall: Wall, points: np.ndarray) -> np.ndarray:
    lines = [o.points_m for o in wall.objects if o.points_m is not None]
    return np.min([distances_to_polyline(points, p) if len(p) > 1 else np.linalg.norm(points - p[0], axis=1)
                   for p in lines], axis=0)


@pytest.mark.parametrize("plan", ["adaptive", "dense"])
def test_the_views_detections_are_the_plans_own_peaks_and_lie_on_the_objects(plan: str, tmp_path: Path) -> None:
    """The adaptive plan hands the view its own per-channel peaks of the passes it searched (corrected for the
    inductive lag); the view searches the rest itself (the capacitive channel, a raster plan's passes). Either
    way the detections lie on the simulated site's objects."""
    wall = load_wall(shipped_walls()["small_test_wall"])
    settings = ScanSettings(plan=plan, serial=False)
    view = view_module.ScanView(str(tmp_path / "scan.rrd"), wall.width_m, wall.height_m,
                                hysteresis_m=settings.sensor.hysteresis_m)
    seen = _Seen(view)
    scan_simulated(wall, settings, watch=seen)
    view.close()
    handed = [row for row, _ in seen.passes if "peaks" in row]
    assert bool(handed) == (plan == "adaptive")
    expected = _expected_detections(view, seen.passes)
    for channel in CHANNEL_NAMES:
        found = _found(view, channel)
        assert found.shape == expected[channel].shape, channel
        np.testing.assert_allclose(found, expected[channel], atol=1e-12, err_msg=channel)
        if channel != "capacitive":  # a copper pipe and a live cable: both metal, one live
            assert len(found) >= 5, channel
        if len(found):  # on the objects (a point object shows on passes beside it too: the median)
            assert np.median(_distance_to_truth(wall, found)) < 0.004, channel
