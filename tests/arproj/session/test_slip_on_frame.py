"""A head that slipped is told to the craftsman on the projected frame, not only in the operator's log (issue 24):
`arproj project --sim --head-fault slip:PAN,TILT` — the encoder reports the commanded angles, the pattern shows
the projector elsewhere; the session measures it again, still shows the (now right) map, and the frame says so."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from arproj.run.project import SessionOptions, run_session
from arproj.session import overlays
from arproj.session.session import SAY_HEAD_SLIPPED
from scanner.wall import shipped_walls

pytestmark = pytest.mark.gl


def _legend_box(frame: np.ndarray, words: list[str], legend: dict) -> tuple[np.ndarray, np.ndarray]:
    """The pixels the legend paints for `words` where the cycle says it put it (its box is opaque: the same
    on any map) and where."""
    sentinel = np.full_like(frame, (1, 2, 3))
    drawn = sentinel.copy()
    overlays.draw_layout(drawn, overlays.legend_layout(frame.shape, words, legend["classes"],
                                                       at=tuple(legend["box"][:2])))
    return drawn, np.any(drawn != sentinel, axis=2)


def test_a_slipped_head_is_told_on_the_projected_frame(tmp_path: Path) -> None:
    said: list[str] = []
    result = run_session(SessionOptions(truth=shipped_walls()["demo_brick_wall"], sim=True,
                                        head_fault="slip:1.0,0.5", cycles=1, output=tmp_path / "frames"),
                         say=said.append)
    cycle = result["cycles"][0]
    assert any(line.startswith("head model disagrees with the pattern") for line in result["log"])
    assert cycle["show_map"], cycle["reasons"]  # measured from the pattern: the map is right, and shown
    words = cycle["frame_says"]
    assert words[0] == SAY_HEAD_SLIPPED and not any("://" in w for w in words)  # words, no URLs
    last = sorted((tmp_path / "frames").glob("frame_*.png"))[-1]
    frame = cv2.imread(str(last))[..., ::-1]
    expected, box = _legend_box(frame, words, cycle["legend"])
    assert np.array_equal(frame[box], expected[box])  # exactly these lines are drawn on the beamer's frame
    without, box_without = _legend_box(frame, words[1:], cycle["legend"])
    assert not np.array_equal(frame[box_without], without[box_without])  # and the slip's line is among them
