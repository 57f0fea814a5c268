"""What watches a scan besides its log: a ROS 2 recording (`--record FILE.mcap`, mapping.ros) and the live
view (`--view`, arproj.run.view), both fed by scanner.run's ScanWatcher calls."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from scanner.run import ScanWatcher
from scanner.sim.world import FrameReport


class Watchers:
    """Several ScanWatchers as one."""

    def __init__(self, watchers: list[Any]) -> None:
        self.watchers = watchers

    def frame(self, row: dict[str, Any], report: FrameReport) -> None:
        for w in self.watchers:
            w.frame(row, report)

    def scanned(self, row: dict[str, Any], samples: dict[str, NDArray[Any]]) -> None:
        for w in self.watchers:
            w.scanned(row, samples)


def check_targets(record: Path | None, view: str | None) -> None:
    """Refuse a bad --record or --view before anything is written (InputError)."""
    if record is not None:
        from mapping.ros.bag import check_path

        check_path(record)
    if view is not None:
        from arproj.run.view import check_target

        check_target(view)


@contextmanager
def open_watchers(meta: dict[str, Any], record: Path | None, view: str | None) -> Iterator[ScanWatcher | None]:
    """The watchers --record and --view ask for over a scan whose log has `meta` (None: neither); closed (the
    bag's metadata.yaml written, the recording flushed) when the block ends, also on Ctrl-C or an error."""
    closers = []
    watchers: list[Any] = []
    try:
        if record is not None:
            from mapping.ros.bag import RosBag
            from mapping.ros.record import ScanRecorder, start_ns

            bag = RosBag(record)
            closers.append(bag.close)
            watchers.append(ScanRecorder(bag, start_ns(meta)))
        if view is not None:
            from arproj.run.view import ScanView

            live = ScanView(view, float(meta["wall_width_m"]), float(meta["wall_height_m"]),
                            hysteresis_m=float((meta.get("sensor") or {}).get("hysteresis_m", 0.0) or 0.0))
            closers.append(live.close)
            watchers.append(live)
        yield Watchers(watchers) if watchers else None
    finally:
        try:
            for close in reversed(closers[1:]):  # the view first: the bag's metadata.yaml is written last, whatever
                close()
        finally:
            if closers:
                closers[0]()
