"""Live cameras (cv2.VideoCapture: an index, a video file or a URL): stereo calibration pairs, and settled
frames for projected patterns.

Frames are read from both cameras in step; a pair is kept when the board is found in both images and the
view is new: the board's centre has moved, or its apparent size or shape (tilt) has changed, by at least
`min_change` of the image compared with every pair kept so far. Kept pairs are written as
left_NN.png / right_NN.png, ready for `arproj calibrate stereo`.

A pattern shown on a beamer is photographed by `LiveCamera.settled_frame`: a thread reads the camera all the
time, and a frame counts once it arrived after the pattern was shown plus a settle time and the next frame agrees
with it within the sensor's noise (the beamer has switched and the exposure holds the new image only), bounded by
a timeout. Arrival time alone does not prove what a frame shows: a loaded machine reads a stream late, and frames
exposed before the pattern changed then queue in the network and decoder buffers and arrive after the settle
time, two alike. So when the scene changed (a new pattern, the board moved), the frame must also differ from the
frame taken for the previous capture: a stream delivers frames in order, so every frame after the first that
differs was exposed after the change.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.boards import Board, BoardView, detect
from geometry.errors import InputError

MIN_VIEW_CHANGE = 0.08  # fraction of the image diagonal the board must move (or its outline change) to count
STABLE_LEVEL = 24  # grey levels: a pixel differing by more than this between two frames has changed ...
STABLE_FRACTION = 0.002  # ... and two frames agree when at most this share of pixels has
SETTLE_TIMEOUT_S = 10.0


@dataclass
class CaptureResult:
    left_files: list[Path] = field(default_factory=list)
    right_files: list[Path] = field(default_factory=list)
    frames_read: int = 0
    frames_with_board: int = 0


def open_source(source: str, name: str) -> cv2.VideoCapture:
    """A camera by index ("0"), a video file or a stream URL (through FFmpeg); InputError when it does not open."""
    if source.isdigit():
        cap = cv2.VideoCapture(int(source))
    elif "://" in source:
        cap = cv2.VideoCapture(source, cv2.CAP_FFMPEG)  # e.g. an MJPEG stream over HTTP
    else:
        cap = cv2.VideoCapture(source)
    if not cap.isOpened():
        raise InputError(f"{name} camera {source!r} does not open",
                         "check the index, file or URL and that no other program holds the camera")
    return cap


def _signature(view: BoardView) -> NDArray[np.float64]:
    """The board's outline as four extreme corners, scaled by the image diagonal: position, size and tilt."""
    p = view.image_points
    s, d = p.sum(axis=1), p[:, 0] - p[:, 1]
    outline = p[[s.argmin(), d.argmax(), s.argmax(), d.argmin()]]
    return outline.ravel() / float(np.hypot(*view.image_size))


def capture_pairs(left: cv2.VideoCapture, right: cv2.VideoCapture, board: Board, out: Path, pairs: int,
                  max_frames: int, on_frame: Callable[[int, int], None] | None = None,
                  min_change: float = MIN_VIEW_CHANGE) -> CaptureResult:
    """Read up to max_frames frame pairs, keep up to `pairs` new views of the board seen by both cameras."""
    out.mkdir(parents=True, exist_ok=True)
    result = CaptureResult()
    kept: list[NDArray[np.float64]] = []
    while result.frames_read < max_frames and len(result.left_files) < pairs:
        ok_l, image_l = left.read()
        ok_r, image_r = right.read()
        if not (ok_l and ok_r) or image_l is None or image_r is None:
            break  # end of a file, or a camera that stopped delivering
        result.frames_read += 1
        view_l = detect(board, image_l, source=f"frame {result.frames_read} left")
        view_r = detect(board, image_r, source=f"frame {result.frames_read} right") if view_l else None
        if view_l is not None and view_r is not None:
            result.frames_with_board += 1
            sig = _signature(view_l)
            # New when some outline corner moved by min_change of the diagonal against every kept view.
            if all(np.abs(sig - k).reshape(4, 2).max() >= min_change for k in kept):
                kept.append(sig)
                n = len(result.left_files)
                for image, files, side in ((image_l, result.left_files, "left"),
                                           (image_r, result.right_files, "right")):
                    path = out / f"{side}_{n:02d}.png"
                    if not cv2.imwrite(str(path), image):
                        raise InputError(f"cannot write {path}", "check the output folder is writable")
                    files.append(path)
        if on_frame is not None:
            on_frame(result.frames_read, len(result.left_files))
    return result


def frames_agree(a: NDArray[np.uint8], b: NDArray[np.uint8], level: int = STABLE_LEVEL,
                 fraction: float = STABLE_FRACTION) -> bool:
    """Whether two frames of one camera show the same scene: at most `fraction` of the pixels differ by more
    than `level` grey levels (sensor noise and compression stay well below)."""
    if a.shape != b.shape:
        return False
    changed = cv2.absdiff(a, b) > level
    return float(np.count_nonzero(changed)) <= fraction * changed.size


class LiveCamera:
    """A camera read continuously by a thread; frames are grey (h, w) uint8 with the time they arrived.

    Use as a context manager or call close(); the capture is released then.
    """

    def __init__(self, cap: cv2.VideoCapture, name: str) -> None:
        self.cap, self.name = cap, name
        self._cond = threading.Condition()
        self._frames: list[tuple[float, NDArray[np.uint8]]] = []  # the last two: (arrival time, frame)
        self._failed = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True, name=f"camera-{name}")
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            ok, image = self.cap.read()
            with self._cond:
                if not ok or image is None:
                    self._failed = True
                    self._cond.notify_all()
                    return
                grey = np.asarray(image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), np.uint8)
                self._frames = [*self._frames, (time.monotonic(), grey)][-2:]
                self._cond.notify_all()

    def latest(self, timeout_s: float = SETTLE_TIMEOUT_S) -> NDArray[np.uint8]:
        """The newest frame (waiting for the first one); InputError when none comes."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._frames:
                left = deadline - time.monotonic()
                if self._failed or left <= 0:
                    raise InputError(f"{self.name}: the camera delivers no pictures", "check its cable or stream URL")
                self._cond.wait(timeout=left)
            return self._frames[-1][1]

    def settled_frame(self, after: float, timeout_s: float = SETTLE_TIMEOUT_S,
                      differs_from: NDArray[np.uint8] | None = None) -> NDArray[np.uint8]:
        """The first frame that arrived at or after `after` (time.monotonic()), that the next frame agrees with
        and, if given, that differs from `differs_from` (the frame of the scene before it changed); InputError
        when none settles within timeout_s or the camera stops delivering."""
        deadline = time.monotonic() + timeout_s
        stale = 0
        with self._cond:
            while True:
                if self._failed:
                    raise InputError(f"{self.name}: the camera stopped delivering pictures",
                                     "check its cable or stream URL")
                fresh = [(t, f) for t, f in self._frames if t >= after]
                if len(fresh) == 2 and frames_agree(fresh[0][1], fresh[1][1]):
                    if differs_from is None or not frames_agree(fresh[0][1], differs_from):
                        return fresh[0][1]
                    stale += 1
                    after = fresh[1][0]  # in order: a changed frame can only come after this one
                left = deadline - time.monotonic()
                if left <= 0:
                    if differs_from is not None and stale:
                        raise InputError(f"{self.name}: the picture did not change within {timeout_s:.0f} s of "
                                         "the scene changing (a new pattern, the board moved)",
                                         "check the projected image and the board are in this camera's view and "
                                         "the camera is not frozen, or raise --settle-timeout")
                    raise InputError(f"{self.name}: no two frames agreed within {timeout_s:.0f} s of the pattern "
                                     "being shown", "keep the scene still, check the camera's auto exposure is "
                                     "off, or raise --settle-timeout")
                self._cond.wait(timeout=left)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.cap.release()

    def __enter__(self) -> LiveCamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
