"""The recording bench's account of the threads beside the scan (arproj.bench.record): those alive when the scan
started are the recording's and count from the reading before it opened; the scan's own threads, started after,
and the scan's thread itself do not; a thread the closing ended counts as last read."""

from __future__ import annotations

import sys
import threading

import pytest

from arproj.bench.record import background_cpu, thread_cpu


def test_the_threads_beside_the_scan_are_those_alive_when_it_started() -> None:
    own = str(threading.get_native_id())
    before = {own: 5.0, "pool": 1.0}
    alive = {own: 5.1, "pool": 1.0, "batcher": 0.01, "file_writer": 0.02}
    scanned = {own: 9.0, "pool": 1.25, "batcher": 0.3, "file_writer": 0.5, "simulator": 2.0}
    closed = {own: 9.1, "pool": 1.25, "batcher": 0.4, "simulator": 2.5}  # the file writer ended at the close
    assert background_cpu(before, alive, scanned, closed) == pytest.approx(0.25 + 0.4 + 0.5)
    assert background_cpu(before, alive) == pytest.approx(0.03)  # never read again: as alive


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread CPU time from Linux /proc")
def test_every_thread_of_the_process_is_read() -> None:
    started = threading.Event()
    stop = threading.Event()

    def wait() -> None:
        started.set()
        stop.wait()

    other = threading.Thread(target=wait)
    other.start()
    started.wait()
    try:
        assert other.native_id is not None
        readings = thread_cpu()
        assert {str(threading.get_native_id()), str(other.native_id)} <= set(readings)
        assert all(v >= 0.0 for v in readings.values())
    finally:
        stop.set()
        other.join()
