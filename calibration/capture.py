"""Capture stereo calibration pairs from live cameras (cv2.VideoCapture: an index, a video file or a URL).

Frames are read from both cameras in step; a pair is kept when the board is found in both images and the
view is new: the board's centre has moved, or its apparent size or shape (tilt) has changed, by at least
`min_change` of the image compared with every pair kept so far. Kept pairs are written as
left_NN.png / right_NN.png, ready for `arproj calibrate stereo`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.boards import Board, BoardView, detect
from geometry.errors import InputError

MIN_VIEW_CHANGE = 0.08  # fraction of the image diagonal the board must move (or its outline change) to count


@dataclass
class CaptureResult:
    left_files: list[Path] = field(default_factory=list)
    right_files: list[Path] = field(default_factory=list)
    frames_read: int = 0
    frames_with_board: int = 0


def open_source(source: str, name: str) -> cv2.VideoCapture:
    """A camera by index ("0"), a video file or a stream URL; InputError when it does not open."""
    cap = cv2.VideoCapture(int(source) if source.isdigit() else source)
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
