"""The paper's method, as the baseline: project ONE square, find its four corners in both camera images,
triangulate them by stereo and put a plane through the four points.

Corners: the square's outline (Otsu threshold, largest contour, polygon approximation to four vertices, a line
fitted to each side and the sides intersected), each refined with cv2.cornerSubPix; the four are matched
between the cameras by their order around the square. The threshold sits halfway between the background and
Otsu's level so the dim far end of the square stays in at oblique incidence. No projector view, no
uncertainty: that is the method the paper describes.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.robust import fit_plane
from wallpose import limits
from wallpose.evidence import EvidenceCode, NotEnoughEvidenceError
from wallpose.pattern import CheckerPattern
from wallpose.plane import plane_in_frame
from wallpose.rig import ViewRig
from wallpose.triangulate import triangulate_stereo

SQUARE_FRACTION = 0.8   # side of the square as a fraction of the pattern region's shorter side
SUBPIX_HALF_WINDOW = 5


@dataclass(frozen=True)
class SquarePattern:
    """One white square on black: projector_size (w, h), top-left pixel and side in projector pixels."""

    projector_size: tuple[int, int]
    origin_px: tuple[int, int]
    side_px: int

    @classmethod
    def like(cls, pattern: CheckerPattern, fraction: float = SQUARE_FRACTION) -> SquarePattern:
        """A square of fraction times the checker pattern's shorter side, centred where the pattern is."""
        side = int(fraction * min(pattern.cols, pattern.rows) * pattern.square_px)
        cx, cy = pattern.centre_px + 0.5
        return cls(pattern.projector_size, (round(cx - side / 2), round(cy - side / 2)), side)

    @property
    def corners_px(self) -> NDArray[np.float64]:
        """(4, 2) projector pixels of the square's corners (TL, TR, BR, BL)."""
        x, y, s = self.origin_px[0] - 0.5, self.origin_px[1] - 0.5, self.side_px
        return np.array([[x, y], [x + s, y], [x + s, y + s], [x, y + s]], dtype=np.float64)

    def image(self) -> NDArray[np.uint8]:
        w, h = self.projector_size
        img = np.zeros((h, w), np.uint8)
        x, y = self.origin_px
        img[y:y + self.side_px, x:x + self.side_px] = 255
        return img

    @property
    def centre_px(self) -> NDArray[np.float64]:
        return np.array([self.origin_px[0] + self.side_px / 2 - 0.5, self.origin_px[1] + self.side_px / 2 - 0.5])


@dataclass
class BaselineEstimate:
    """Plane in the robot frame (normal into the room, normal·X = -distance) and the four triangulated corners
    (robot frame, metres)."""

    normal: NDArray[np.float64]
    distance: float
    corners: NDArray[np.float64]

    def normal_error_deg(self, true_normal: NDArray[np.float64]) -> float:
        c = np.clip(self.normal @ (true_normal / np.linalg.norm(true_normal)), -1.0, 1.0)
        return float(np.degrees(np.arccos(c)))

    def offset_at(self, point: NDArray[np.float64]) -> float:
        return float(self.normal @ point + self.distance)


def square_corners(image: NDArray[np.uint8], camera_name: str = "camera") -> NDArray[np.float64]:
    """(4, 2) camera pixels of the projected square's corners, clockwise from the top-left."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    lo, hi = np.percentile(gray, [1, 99.5])
    if hi - lo < limits.MIN_PATTERN_CONTRAST:
        raise NotEnoughEvidenceError(EvidenceCode.NO_PATTERN,
                                     f"{camera_name}: low contrast ({hi - lo:.0f} grey levels), "
                                     "no square to see")
    smooth = cv2.GaussianBlur(gray, (5, 5), 0)
    otsu, _ = cv2.threshold(smooth, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    # halfway between the background and Otsu's level: the square's dim far end stays in at oblique incidence
    level = 0.5 * (float(np.median(smooth)) + otsu)
    _, binary = cv2.threshold(smooth, level, 255, cv2.THRESH_BINARY)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise NotEnoughEvidenceError(EvidenceCode.NO_PATTERN, f"{camera_name}: the square is not visible")
    contour = max(contours, key=cv2.contourArea).reshape(-1, 2)
    quad = cv2.approxPolyDP(contour.reshape(-1, 1, 2), 0.02 * cv2.arcLength(contour.reshape(-1, 1, 2), True),
                            True).reshape(-1, 2)
    if len(quad) != 4 or cv2.contourArea(contour.reshape(-1, 1, 2)) < 400:
        raise NotEnoughEvidenceError(EvidenceCode.NO_PATTERN,
                                     f"{camera_name}: the square's outline has {len(quad)} corners")
    # each side: a line fitted to the outline between two vertices (ends trimmed), corners where they meet
    at = [int(np.argmin(np.linalg.norm(contour - q, axis=1))) for q in quad]
    lines = []
    for k in range(4):
        a, b = at[k], at[(k + 1) % 4]
        side = np.roll(contour, -a, axis=0)[:(b - a) % len(contour) + 1]
        trim = max(1, len(side) // 8)
        side = side[trim:-trim] if len(side) > 2 * trim + 2 else side
        vx, vy, x0, y0 = cv2.fitLine(side.astype(np.float32), cv2.DIST_L2, 0, 0.01, 0.01).ravel()
        lines.append((np.array([x0, y0]), np.array([vx, vy])))
    corners = []
    for k in range(4):
        (p1, d1), (p2, d2) = lines[k - 1], lines[k]
        t = np.linalg.solve(np.column_stack([d1, -d2]), p2 - p1)
        corners.append(p1 + t[0] * d1)
    quad = np.array(corners)
    centre = quad.mean(axis=0)
    angles = np.arctan2(quad[:, 1] - centre[1], quad[:, 0] - centre[0])
    quad = quad[np.argsort(angles)]              # image y down: increasing angle runs clockwise on screen
    start = int(np.argmin(quad.sum(axis=1)))      # top-left first
    quad_px = np.roll(quad, -start, axis=0).astype(np.float32).reshape(-1, 1, 2)
    cv2.cornerSubPix(gray, quad_px, (SUBPIX_HALF_WINDOW, SUBPIX_HALF_WINDOW), (-1, -1),
                     (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    return quad_px.reshape(4, 2).astype(np.float64)


def estimate_plane_baseline(image_left: NDArray[np.uint8], image_right: NDArray[np.uint8],
                            views: ViewRig) -> BaselineEstimate:
    """The paper's four-corner estimate of the wall plane (robot frame)."""
    left = views.camera_left.rays(square_corners(image_left, "camera_left"))[:, :2]
    right = views.camera_right.rays(square_corners(image_right, "camera_right"))[:, :2]
    points = triangulate_stereo(left, right, views.T_camera_right_from_camera_left)
    if not np.all(np.isfinite(points)):
        raise NotEnoughEvidenceError(EvidenceCode.NO_PATTERN, "the square's corners do not triangulate")
    centroid, normal = fit_plane(points)
    p = normal / (normal @ centroid)
    nd = plane_in_frame(p, views.T_robot_from_camera_left)
    T = views.T_robot_from_camera_left
    return BaselineEstimate(nd[:3], float(nd[3]), points @ T[:3, :3].T + T[:3, 3])
