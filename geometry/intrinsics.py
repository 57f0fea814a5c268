"""Pinhole intrinsics with OpenCV distortion, for cameras and projectors alike, and ROS camera_info YAML.

The principal point may lie anywhere, even outside the image: a projector with lens shift has cy near or
beyond the bottom edge. Distortion is OpenCV's model in its order (k1, k2, p1, p2, k3[, k4, k5, k6[, ...]]);
geometry.distortion has it in numpy for vectorised fits.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.distortion import distort_normalized
from geometry.errors import InputError
from geometry.inputs import fail, float_array, integer, load_document


@dataclass(frozen=True)
class Intrinsics:
    """fx, fy, cx, cy in pixels; width, height in pixels; dist: OpenCV distortion coefficients."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        if not (self.fx > 0 and self.fy > 0):
            raise InputError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if not (self.width > 0 and self.height > 0):
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        if len(self.dist) not in (0, 4, 5, 8, 12, 14):
            raise InputError(f"distortion has {len(self.dist)} coefficients; OpenCV takes 4, 5, 8, 12 or 14")
        # All-zero coefficients and none are the same optics: one canonical form keeps equality honest.
        dist = tuple(float(d) for d in self.dist)
        object.__setattr__(self, "dist", dist if any(dist) else ())

    @classmethod
    def from_K(cls, K: ArrayLike, width: int, height: int, dist: ArrayLike = ()) -> Intrinsics:
        K = np.asarray(K, dtype=np.float64)
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height),
                   tuple(np.asarray(dist, dtype=np.float64).ravel()))

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, cx: float | None = None,
                 cy: float | None = None, dist: ArrayLike = ()) -> Intrinsics:
        """Square pixels with the given horizontal field of view; principal point defaults to the centre."""
        f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2.0)
        return cls(f, f, (width - 1) / 2.0 if cx is None else cx, (height - 1) / 2.0 if cy is None else cy,
                   width, height, tuple(np.asarray(dist, dtype=np.float64).ravel()))

    @property
    def K(self) -> NDArray[np.float64]:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> NDArray[np.float64]:
        return np.asarray(self.dist if self.dist else (0.0, 0.0, 0.0, 0.0, 0.0), dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        return any(abs(d) > 0 for d in self.dist)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), the order OpenCV's functions take."""
        return (self.width, self.height)

    def without_distortion(self) -> Intrinsics:
        return replace(self, dist=())

    def scaled(self, factor: float) -> Intrinsics:
        """The same optics sampled at factor times the resolution (pixel centres at integer coordinates)."""
        s = float(factor)
        return replace(self, fx=self.fx * s, fy=self.fy * s, cx=(self.cx + 0.5) * s - 0.5,
                       cy=(self.cy + 0.5) * s - 0.5, width=round(self.width * s),
                       height=round(self.height * s))

    def project(self, points_cam: ArrayLike, distort: bool = True) -> NDArray[np.float64]:
        """Pixels (n, 2) of points (n, 3) in this camera's (OpenCV) frame, via cv2.projectPoints."""
        p = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:  # cv2.projectPoints gives a single value for no points, not (0, 2)
            return np.zeros((0, 2))
        dist = self.dist_array if distort else np.zeros(5)
        uv, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), self.K, dist)
        return np.asarray(uv, dtype=np.float64).reshape(-1, 2)

    def pixels_of_normalized(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Pixels (..., 2) of ideal normalised coordinates (x/z, y/z) (..., 2), through the lens: project's
        result by geometry.distortion's vectorised model, for thousands of points (cv2.projectPoints' per-call
        and per-point cost is several times this)."""
        d = distort_normalized(xy, self.dist_array)
        return np.stack([self.fx * d[..., 0] + self.cx, self.fy * d[..., 1] + self.cy], axis=-1)

    def rays(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Unit-z rays (n, 3) in the camera frame through pixels (n, 2), undoing distortion."""
        uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if len(uv) == 0:  # cv2.undistortPoints returns None for no points
            return np.zeros((0, 3))
        if self.has_distortion:
            # Tight iteration: the default stops at ~1e-3 px, too coarse for sub-0.05 px work.
            xy = cv2.undistortPoints(uv, self.K, self.dist_array, None, None, None,
                                     (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
        else:
            xy = cv2.undistortPoints(uv, self.K, None)
        xy = xy.reshape(-1, 2)
        return np.column_stack([xy, np.ones(len(xy))])

    def undistorted_pixels(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Where pixels (n, 2) lie in the ideal pinhole image with the same K: lens distortion removed."""
        rays = self.rays(pixels)
        return np.column_stack([self.fx * rays[:, 0] + self.cx, self.fy * rays[:, 1] + self.cy])


MAX_PIXELS = 16384  # an image side: larger is no camera or beamer of this system
# A poorly constrained fit's focal lengths and rational terms reach 1e5 and more (OpenCV writes them; a poor rig
# is refused by the calibration's quality gate unless --accept-poor, not by its reader): matrices' entries are
# only refused at absurd magnitudes; the image size above bounds what is allocated.
MAX_ENTRY = 1e12
_DISTORTION_MODEL = {4: "plumb_bob", 5: "plumb_bob", 8: "rational_polynomial"}


def write_camera_info(path: str | Path, intr: Intrinsics, camera_name: str = "camera",
                      R: ArrayLike | None = None, P: ArrayLike | None = None) -> None:
    """Write intrinsics as ROS camera_info YAML, laid out as ROS camera_calibration writes it."""
    dist = list(intr.dist) if intr.dist else [0.0] * 5
    if len(dist) not in _DISTORTION_MODEL:
        raise InputError(f"{path}: camera_info has no distortion model for {len(dist)} coefficients")
    R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64)
    P = np.hstack([intr.K, np.zeros((3, 1))]) if P is None else np.asarray(P, dtype=np.float64)

    def matrix(rows: int, cols: int, data: ArrayLike) -> str:
        values = ", ".join(f"{v:.12g}" for v in np.asarray(data, dtype=np.float64).ravel())
        return f"  rows: {rows}\n  cols: {cols}\n  data: [{values}]\n"

    text = (
        f"image_width: {intr.width}\n"
        f"image_height: {intr.height}\n"
        f"camera_name: {camera_name}\n"
        f"camera_matrix:\n{matrix(3, 3, intr.K)}"
        f"distortion_model: {_DISTORTION_MODEL[len(dist)]}\n"
        f"distortion_coefficients:\n{matrix(1, len(dist), dist)}"
        f"rectification_matrix:\n{matrix(3, 3, R)}"
        f"projection_matrix:\n{matrix(3, 4, P)}"
    )
    Path(path).write_text(text)


def read_camera_info(path: str | Path) -> Intrinsics:
    """Read a ROS camera_info YAML file (camera_calibration's layout) into Intrinsics.

    Raises InputError naming the file and the key when the file is missing, not YAML, or incomplete.
    """
    path = Path(path)
    source = str(path)
    doc = load_document(path, "camera_info file", "pass the YAML written by `arproj calibrate` or ROS "
                        "camera_calibration")
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a camera_info mapping with image_width, camera_matrix, …",
                         "fix the file or recalibrate")

    def get(key: str) -> Any:  # a YAML value, checked where it is used
        if key not in doc:
            raise InputError(f"{path}: camera_info key {key!r} is missing",
                             "a camera_info file needs image_width, image_height, camera_matrix and "
                             "distortion_coefficients")
        return doc[key]

    def matrix(key: str, rows: int | None, cols: int | None) -> NDArray[np.float64]:
        m = get(key)
        if not isinstance(m, dict) or "data" not in m:
            raise fail(source, key, m, "must have rows, cols and data", "fix the file or recalibrate")
        data = float_array(source, f"{key}.data", m["data"], (None,), -MAX_ENTRY, MAX_ENTRY, max_rows=64,
                           hint="fix the file or recalibrate")
        r = integer(source, f"{key}.rows", m.get("rows", rows or 1), 1, 64)
        c = integer(source, f"{key}.cols", m.get("cols", cols or data.size), 1, 64)
        if data.size != r * c or (rows is not None and r != rows) or (cols is not None and c != cols):
            raise InputError(f"{path}: {key} has {data.size} values for rows={r}, cols={c}"
                             + (f"; expected {rows}x{cols}" if rows and cols else ""))
        return data.reshape(r, c)

    width = integer(source, "image_width", get("image_width"), 1, MAX_PIXELS, "fix the file or recalibrate")
    height = integer(source, "image_height", get("image_height"), 1, MAX_PIXELS, "fix the file or recalibrate")
    K = matrix("camera_matrix", 3, 3)
    dist = matrix("distortion_coefficients", None, None).ravel()
    model = doc.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial", "equidistant"):
        raise InputError(f"{path}: distortion_model {model!r} is not supported",
                         "use plumb_bob or rational_polynomial")
    if model == "equidistant":
        raise InputError(f"{path}: the fisheye (equidistant) model is not supported",
                         "recalibrate with plumb_bob or rational_polynomial")
    if not np.allclose(K[2], [0, 0, 1]):
        raise fail(source, "camera_matrix.data", K.ravel().tolist(), "is not a camera matrix [fx 0 cx; 0 fy cy; "
                   "0 0 1]", "fix the file or recalibrate")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"{path}: camera_matrix has non-positive focal length fx={K[0, 0]}, fy={K[1, 1]}")
    try:
        return Intrinsics.from_K(K, width, height, dist)
    except InputError as err:
        raise InputError(f"{path}: {err.message}", err.hint) from None
