"""The scan's live view (arproj.run.view.ScanView): the pictures it redraws window by window between sends are
the ones drawn from the whole grid, and it sends the grids only when samples fell since."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from arproj.run import view as view_module
from arproj.run.scan import ScanSettings, scan_simulated
from mapping.evidence import DEFAULT_COVERAGE_RADIUS_M, SAFETY_CHANNELS
from scanner.channels import NAMES as CHANNEL_NAMES
from scanner.wall import load_wall, shipped_walls


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
