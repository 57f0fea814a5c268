"""Board views from image files named by glob patterns, with the checks a person needs to fix a capture set."""

from __future__ import annotations

import glob
import hashlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from calibration.boards import Board, BoardView, detect_file
from geometry.errors import InputError

T = TypeVar("T")
MAX_IMAGES = 5000  # images of one capture set (a calibration uses 20 to 100)
Tracker = Callable[[Iterable[T], str, int], Iterator[T]]


def _plain_iter(items: Iterable[T], description: str, total: int) -> Iterator[T]:
    del description, total
    yield from items


def expand(pattern: str, what: str) -> list[Path]:
    """Files matching a glob pattern, sorted by name; InputError when there are none."""
    files = sorted(Path(p) for p in glob.glob(str(Path(pattern).expanduser())) if Path(p).is_file())
    if len(files) > MAX_IMAGES:
        raise InputError(f"{what}: {len(files):,} files match {pattern!r}; a calibration takes at most "
                         f"{MAX_IMAGES:,}", "narrow the pattern to the capture set")
    if not files:
        raise InputError(f"{what}: no files match {pattern!r}",
                         "check the folder and quote the pattern so the shell does not expand it")
    return files


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_distinct_pairs(left_files: list[Path], right_files: list[Path]) -> None:
    """InputError when a left and a right image are the same file or the same bytes (the same glob twice, or
    one camera's images copied): the pair would calibrate to a zero baseline."""
    for lf, rf in zip(left_files, right_files, strict=True):
        same_path = lf.resolve() == rf.resolve()
        if same_path or (lf.stat().st_size == rf.stat().st_size and _digest(lf) == _digest(rf)):
            how = "the same file" if same_path else "identical files"
            raise InputError(f"--left {lf} and --right {rf} are {how}: a stereo pair needs one image from each "
                             "camera", "point --left and --right at the two cameras' images")


@dataclass
class ImageSet:
    """One camera's detections (None where the board was not found) and the files without a board."""

    files: list[Path]
    views: list[BoardView | None]
    no_board: list[str] = field(default_factory=list)


def detect_image_set(pattern: str, board: Board, what: str = "--images",
                     track: Tracker = _plain_iter) -> ImageSet:
    """Detect the board in every image matching pattern (sorted by name)."""
    files = expand(pattern, what)
    views = [detect_file(board, f) for f in track(files, "finding the board", len(files))]
    return ImageSet(files, views, [str(f) for f, v in zip(files, views, strict=True) if v is None])


@dataclass
class StereoImageSet:
    """Aligned detections (None where the board was not found) and the files without a board."""

    left_files: list[Path]
    right_files: list[Path]
    left: list[BoardView | None]
    right: list[BoardView | None]
    no_board: list[str] = field(default_factory=list)


def detect_stereo_set(left_pattern: str, right_pattern: str, board: Board,
                      track: Tracker = _plain_iter) -> StereoImageSet:
    """Detect the board in every left/right image (paired by sorted name)."""
    left_files = expand(left_pattern, "--left")
    right_files = expand(right_pattern, "--right")
    if len(left_files) != len(right_files):
        raise InputError(f"{len(left_files)} left images ({left_pattern}) but {len(right_files)} right images "
                         f"({right_pattern})", "give exactly one right image per left image; pairs are matched "
                         "by sorted file name")
    check_distinct_pairs(left_files, right_files)
    both = list(zip(left_files, right_files, strict=True))
    left: list[BoardView | None] = []
    right: list[BoardView | None] = []
    for lf, rf in track(both, "finding the board", len(both)):
        left.append(detect_file(board, lf))
        right.append(detect_file(board, rf))
    no_board = [str(f) for f, v in zip(left_files + right_files, left + right, strict=True) if v is None]
    sizes = {v.image_size for v in left if v is not None}
    if len(sizes) > 1:
        raise InputError(f"left images have different sizes {sorted(sizes)}", "use one camera mode for all")
    return StereoImageSet(left_files, right_files, left, right, no_board)
