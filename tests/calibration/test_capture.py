"""Live capture, with video files standing in for the two cameras (cv2.VideoCapture opens both alike)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.boards import parse_board
from calibration.capture import LiveCamera, capture_pairs, open_source
from geometry.errors import InputError

FRAMES_PER_PAIR = 3  # each real pair is held still for a few frames, as in front of a real camera


def _video(images: list[Path], path: Path) -> Path:
    first = cv2.imread(str(images[0]))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (first.shape[1], first.shape[0]))
    blank = first * 0 + 128  # frames without a board between the views
    for image_path in images:
        image = cv2.imread(str(image_path))
        for _ in range(FRAMES_PER_PAIR):
            writer.write(image)
        writer.write(blank)
    writer.release()
    return path


@pytest.fixture(scope="module")
def videos(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, int]:
    folder = shared_data / "opencv-stereo-chessboard"
    tmp = tmp_path_factory.mktemp("videos")
    left = sorted(folder.glob("left*.jpg"))
    right = sorted(folder.glob("right*.jpg"))
    return _video(left, tmp / "left.avi"), _video(right, tmp / "right.avi"), len(left)


def test_keeps_each_new_view_once_and_the_files_calibrate(videos: tuple[Path, Path, int], tmp_path: Path) -> None:
    left_video, right_video, n_pairs = videos
    left, right = open_source(str(left_video), "left"), open_source(str(right_video), "right")
    result = capture_pairs(left, right, parse_board("chessboard:9x6:0.025"), tmp_path / "pairs", pairs=50,
                           max_frames=1000)
    left.release()
    right.release()
    assert result.frames_read == n_pairs * (FRAMES_PER_PAIR + 1)
    # Held-still frames repeat a view: at most one kept per real pair, and most real pairs are new views.
    assert 0.6 * n_pairs <= len(result.left_files) <= n_pairs
    assert [p.name for p in result.left_files][:2] == ["left_00.png", "left_01.png"]
    done = subprocess.run([sys.executable, "-c", "from arproj.cli import main; main()", "calibrate", "stereo",
                           "--left", str(tmp_path / "pairs" / "left_*.png"), "--right",
                           str(tmp_path / "pairs" / "right_*.png"), "--board", "chessboard:9x6:0.025",
                           "--out", str(tmp_path / "rig"), "--json"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "rig" / "rig.yaml").exists()


def test_a_camera_that_does_not_open_is_named(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"left camera .*nope\.avi.* does not open"):
        open_source(str(tmp_path / "nope.avi"), "left")


class _LateStream:
    """A camera read late: frames taken before the scene changed are still queued after the settle time."""

    def __init__(self, frames: list[np.ndarray], period_s: float = 0.02) -> None:
        self.frames, self.period_s = list(frames), period_s

    def read(self) -> tuple[bool, np.ndarray | None]:
        time.sleep(self.period_s)
        if len(self.frames) > 1:
            return True, self.frames.pop(0)
        return True, self.frames[0]  # the new scene, from now on

    def release(self) -> None:
        return


def test_a_late_frame_from_before_the_change_is_not_taken() -> None:
    old = np.full((40, 60), 30, np.uint8)
    new = old.copy()
    new[:, 30:] = 200  # the next Gray-code pattern
    # Five frames of the old scene arrive after the settle time, alike: arrival time and agreement alone would
    # take one of them.
    with LiveCamera(_LateStream([old] * 5 + [new]), "camera_left") as camera:  # type: ignore[arg-type]
        got = camera.settled_frame(time.monotonic(), timeout_s=5.0, differs_from=old)
    assert np.array_equal(got, new)
    with LiveCamera(_LateStream([old] * 5 + [new]), "camera_left") as camera:  # type: ignore[arg-type]
        assert np.array_equal(camera.settled_frame(time.monotonic(), timeout_s=5.0), old)  # what went wrong


def test_a_picture_that_never_changes_is_named() -> None:
    old = np.full((40, 60), 30, np.uint8)
    with (LiveCamera(_LateStream([old]), "camera_right") as camera,  # type: ignore[arg-type]
          pytest.raises(InputError, match="camera_right: the picture did not change")):
        camera.settled_frame(time.monotonic(), timeout_s=0.5, differs_from=old)
