"""A shorter run of the simulated hour of projection cycles (`arproj bench soak` runs the hour, with its ≤ 5 %
memory target): after the warm-up, the GL objects the session holds and its open files stay exactly constant
cycle after cycle, and memory does not grow beyond the noise of a short run."""

from __future__ import annotations

from typing import Any

import pytest

from arproj.bench.soak import GLObjectCount, growth, soak

pytestmark = pytest.mark.gl

CYCLES = 12  # about a minute of session time here


def test_cycles_hold_gl_objects_files_and_memory_constant() -> None:
    samples = soak(cycles=CYCLES)
    assert len(samples) == CYCLES + 1 and samples[-1].shown >= CYCLES // 2  # a working session, not a stuck one
    assert samples[0].gl_objects > 0  # the counter sees the session's own objects
    assert {s.gl_objects for s in samples} == {samples[0].gl_objects}, [s.gl_objects for s in samples]
    assert {s.files for s in samples} == {samples[0].files}, [s.files for s in samples]
    g = growth(samples)
    assert g["py_blocks"] <= 0.01, g  # Python's objects: nearly deterministic, a leak of one per cycle shows
    assert g["rss"] <= 0.10, g  # RSS swings by tens of MiB within a cycle: bounded here, judged in the bench


def test_the_gl_object_count_sees_a_leak(gl_context: Any) -> None:
    count = GLObjectCount(gl_context)
    try:
        with gl_context:  # made current: another test may have left its own context current
            made = [gl_context.buffer(reserve=64) for _ in range(3)]
            assert count.live() == 3
            made[0].release()
            assert count.live() == 2
            for b in made[1:]:
                b.release()
            assert count.live() == 0
    finally:
        count.detach()
