"""The wall's own edges seen by the cameras: the vertical room corners it shares with its neighbours, the floor
line and the ceiling line. Two surfaces meet there and are lit (or coloured) differently, so each edge is an
intensity step in the photos; where it lies fixes what the plane cannot: the position along the wall.

For a robot pose guess and its covariance, each of the wall's four boundary lines (known from the room map) is
projected into each camera; where it is in the image and not hidden, the image is searched perpendicular to the
predicted line, within ± a few σ of the pose uncertainty, for a step; steps are localised to subpixel
accuracy, a line is fitted robustly (RANSAC, then least squares with a robust σ) in undistorted pixel
coordinates, where a 3-D line stays straight. No clean edge, too little contrast, or a line that is not where
the edge should be: no observation, never a confident wrong one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.intrinsics import Intrinsics
from geometry.poses import invert, pose_from_vector, transform_points
from geometry.robust import best_hypothesis, draw_samples, principal_axes, refine
from wallpose import limits
from wallpose.rig import ViewRig

EDGE_NAMES = ("left corner", "right corner", "floor line", "ceiling line")


@dataclass(frozen=True)
class CameraImage:
    """One camera's photo with what is needed to predict where things appear in it."""

    name: str
    intrinsics: Intrinsics
    T_robot_from_camera: NDArray[np.float64]
    image: NDArray


@dataclass(frozen=True)
class WallEdge:
    """A boundary line of a wall in the room frame (metres): start_room, end_room (3,)."""

    name: str
    start_room: NDArray[np.float64]
    end_room: NDArray[np.float64]


@dataclass
class EdgeObservation:
    """A wall edge found in one camera image.

    line: (a, b, c) with a² + b² = 1, a·u + b·v + c = 0 in undistorted pixels (u = fx·x/z + cx, v = fy·y/z +
    cy); points_room (2, 3): the ends of the stretch of the 3-D edge that was seen; covariance (2, 2), px²:
    of the line's perpendicular offset at those two ends; sigma_px: scatter of the edge points about the line;
    pixels (n, 2): the edge points used, in the (distorted) image; contrast: median step, grey levels."""

    edge: str
    camera: str
    line: NDArray[np.float64]
    points_room: NDArray[np.float64]
    covariance: NDArray[np.float64]
    sigma_px: float
    contrast: float
    pixels: NDArray[np.float64] = field(repr=False)
    profiles: int = 0


def camera_images(views: ViewRig, left: NDArray, right: NDArray) -> list[CameraImage]:
    """The two photos with the rig's intrinsics and camera poses on the robot."""
    return [CameraImage("camera_left", views.camera_left, np.asarray(views.T_robot_from_camera_left), left),
            CameraImage("camera_right", views.camera_right, np.asarray(views.T_robot_from_camera_right), right)]


def wall_edges(T_room_from_wall: NDArray[np.float64], size_m: tuple[float, float]) -> list[WallEdge]:
    """The four boundary lines of a wall (wall frame: x right, y up, origin lower left) in the room frame."""
    width, height = size_m
    corners = {"ll": (0.0, 0.0), "ul": (0.0, height), "lr": (width, 0.0), "ur": (width, height)}
    pts = {k: transform_points(T_room_from_wall, np.array([[x, y, 0.0]]))[0] for k, (x, y) in corners.items()}
    return [WallEdge("left corner", pts["ll"], pts["ul"]), WallEdge("right corner", pts["lr"], pts["ur"]),
            WallEdge("floor line", pts["ll"], pts["lr"]), WallEdge("ceiling line", pts["ul"], pts["ur"])]


def project_undistorted(intr: Intrinsics, points_cam: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 3) camera-frame points → (n, 2) undistorted pixels."""
    z = points_cam[:, 2]
    return np.column_stack([intr.fx * points_cam[:, 0] / z + intr.cx, intr.fy * points_cam[:, 1] / z + intr.cy])


def _hidden(camera_room: NDArray, points_room: NDArray, walls: list[tuple[NDArray, tuple[float, float]]]
            ) -> NDArray[np.bool_]:
    """Per point (n, 3): does another wall of the map stand between the camera and it?"""
    hidden = np.zeros(len(points_room), dtype=bool)
    d = points_room - camera_room
    for T_room_from_wall, (width, height) in walls:
        n, o = T_room_from_wall[:3, 2], T_room_from_wall[:3, 3]
        denom = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((o - camera_room) @ n) / denom
        hit = camera_room + t[:, None] * d
        local = (hit - o) @ T_room_from_wall[:3, :2]
        # hits within 2 cm of the point itself are the edge's own walls
        before = (t > 1e-6) & (t < 1.0 - 0.02 / np.maximum(np.linalg.norm(d, axis=1), 1e-9))
        inside = (local[:, 0] > 0) & (local[:, 0] < width) & (local[:, 1] > 0) & (local[:, 1] < height)
        hidden |= before & inside
    return hidden


def _gray(image: NDArray) -> NDArray[np.float32]:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img.astype(np.float32)


@dataclass(frozen=True)
class Projector:
    """The projector lighting the scene while the photos were taken: where its light may fall near an edge
    the step there is the pattern's as much as the room's, so that stretch is not searched."""

    intrinsics: Intrinsics
    T_robot_from_projector: NDArray[np.float64]

    def lights(self, T_room_from_robot: NDArray, points_room: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Per room point (n, 3): inside the projector's image (grown by a margin for blur and spill)?"""
        pc = transform_points(invert(T_room_from_robot @ self.T_robot_from_projector), points_room)
        out = np.zeros(len(pc), dtype=bool)
        front = pc[:, 2] > 0.01
        if np.any(front):
            uv = self.intrinsics.project(pc[front])
            m = limits.EDGE_LIT_MARGIN_FRACTION * self.intrinsics.width
            out[front] = ((uv[:, 0] > -m) & (uv[:, 0] < self.intrinsics.width + m)
                          & (uv[:, 1] > -m) & (uv[:, 1] < self.intrinsics.height + m))
        return out


def find_wall_edges(cameras: Sequence[CameraImage], T_room_from_walls: Sequence[NDArray],
                    sizes_m: Sequence[tuple[float, float]], wall: int, T_room_from_robot: NDArray,
                    covariance: NDArray, seed: int = 0, gamma: float = limits.EDGE_CAMERA_GAMMA,
                    projector: Projector | None = None) -> list[EdgeObservation]:
    """Find the wall's edges in the photos around where the pose guess puts them.

    T_room_from_robot: the pose guess; covariance (6, 6): of δ (rotation vector rad, translation m) in the
    robot frame, T_true ≈ T_room_from_robot · exp(δ), sizing the search windows; gamma: the cameras' encoding
    (grey = 255·light^(1/gamma)); projector: when it was on, the stretches it lights are left out.
    Returns the edges found."""
    walls = [(np.asarray(T), (float(s[0]), float(s[1]))) for T, s in zip(T_room_from_walls, sizes_m, strict=True)]
    others = [w for k, w in enumerate(walls) if k != wall]
    rng = np.random.default_rng(seed)
    found = []
    for edge in wall_edges(*walls[wall]):
        for cam in cameras:
            obs = _find_edge(edge, cam, others, np.asarray(T_room_from_robot, dtype=np.float64),
                             np.asarray(covariance, dtype=np.float64), rng, gamma, projector)
            if obs is not None:
                found.append(obs)
    return found


def _predict(edge: WallEdge, cam: CameraImage, T_room_from_robot: NDArray, delta: NDArray | None = None
             ) -> tuple[NDArray, NDArray, NDArray]:
    """Dense samples of the edge: room points (n, 3), camera-frame points (n, 3), image pixels (n, 2)."""
    lam = np.linspace(0.0, 1.0, limits.EDGE_SAMPLES_3D)
    pts = edge.start_room + lam[:, None] * (edge.end_room - edge.start_room)
    T = T_room_from_robot if delta is None else T_room_from_robot @ pose_from_vector(delta)
    T_cam_from_room = invert(T @ cam.T_robot_from_camera)
    pc = transform_points(T_cam_from_room, pts)
    px = np.full((len(pts), 2), np.nan)
    front = pc[:, 2] > 0.05
    if np.any(front):
        px[front] = cam.intrinsics.project(pc[front])
    return pts, pc, px


def _find_edge(edge: WallEdge, cam: CameraImage, others: list, T_room_from_robot: NDArray, covariance: NDArray,
               rng: np.random.Generator, gamma: float, projector: Projector | None) -> EdgeObservation | None:
    intr = cam.intrinsics
    w, h = intr.width, intr.height
    pts, _, px = _predict(edge, cam, T_room_from_robot)
    camera_room = (T_room_from_robot @ cam.T_robot_from_camera)[:3, 3]
    ok = np.all(np.isfinite(px), axis=1)
    ok &= (px[:, 0] > -0.5) & (px[:, 0] < w - 0.5) & (px[:, 1] > -0.5) & (px[:, 1] < h - 0.5)
    ok[ok] &= ~_hidden(camera_room, pts[ok], others)
    if projector is not None:
        ok[ok] &= ~projector.lights(T_room_from_robot, pts[ok])
    if ok.sum() < 3:
        return None
    # Profiles evenly spaced along the predicted curve (the edge's image is curved by lens distortion), from the
    # first to the last usable sample; stretches in between that are lit or hidden are skipped.
    first, last = np.flatnonzero(ok)[[0, -1]]
    idx = np.arange(first, last + 1)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(px[idx], axis=0), axis=1))])
    stations = np.arange(arc[0] + limits.EDGE_PROFILE_SPACING_PX / 2, arc[-1], limits.EDGE_PROFILE_SPACING_PX)
    j = np.clip(np.searchsorted(arc, stations), 1, len(idx) - 2)
    pick = idx[j]
    tangent = px[idx[j + 1]] - px[idx[j - 1]]
    usable = ok[pick]
    pick, tangent = pick[usable], tangent[usable]
    if len(pick) * limits.EDGE_PROFILE_SPACING_PX < limits.EDGE_MIN_LENGTH_PX:
        return None
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    centre = px[pick]
    # Search window from the pose uncertainty: σ of the predicted point's shift along the normal.
    G = np.empty((len(pick), 6))
    for k in range(6):
        step = np.zeros(6)
        step[k] = 1e-6
        _, _, moved = _predict(edge, cam, T_room_from_robot, step)
        G[:, k] = np.sum((moved[pick] - centre) * normal, axis=1) / 1e-6
    sigma_perp = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", G, covariance, G), 0.0))
    half = float(limits.EDGE_WINDOW_SIGMAS * np.max(sigma_perp) + limits.EDGE_WINDOW_EXTRA_PX)
    if not np.isfinite(half) or half > limits.EDGE_WINDOW_MAX_PX:
        return None
    half_n = int(np.ceil(half))
    offsets = np.arange(-half_n - 6, half_n + 7, dtype=np.float64)   # room for the step's two sides
    rows = np.arange(-limits.EDGE_PROFILE_HALF_WIDTH_PX, limits.EDGE_PROFILE_HALF_WIDTH_PX + 1, dtype=np.float64)
    ends = np.concatenate([centre + normal * offsets[0], centre + normal * offsets[-1]])
    margin = limits.EDGE_IMAGE_MARGIN_PX
    inside = ((ends[:, 0] > margin) & (ends[:, 0] < w - 1 - margin)
              & (ends[:, 1] > margin) & (ends[:, 1] < h - 1 - margin))
    keep = inside[:len(centre)] & inside[len(centre):]
    # near the edge's ends a third surface meets it (floor, ceiling, the next wall): its step leans on this one
    clearance = half_n + 6 + limits.EDGE_PROFILE_HALF_WIDTH_PX + limits.EDGE_END_CLEARANCE_PX
    for end in (px[0], px[-1]):
        if np.all(np.isfinite(end)):
            keep &= np.linalg.norm(centre - end, axis=1) > clearance
    if keep.sum() < limits.EDGE_MIN_POINTS:
        return None
    centre, normal, tangent, pick = centre[keep], normal[keep], tangent[keep], pick[keep]
    # Sample (profiles, rows, offsets) with cubic interpolation and average the parallel rows. Each profile's
    # sample grid is shifted by its own fraction of a pixel (golden-ratio dither): the subpixel peak's residual
    # bias depends on where the edge falls between samples, and would otherwise be the same all along a line
    # predicted parallel to the true one.
    dither = (np.arange(len(centre)) * 0.6180339887) % 1.0 - 0.5
    shifted = offsets[None, :] + dither[:, None]
    grid = (centre[:, None, None, :] + rows[None, :, None, None] * tangent[:, None, None, :]
            + shifted[:, None, :, None] * normal[:, None, None, :])
    map_xy = grid.reshape(-1, len(offsets), 2).astype(np.float32)
    sampled = cv2.remap(_gray(cam.image), map_xy[..., 0], map_xy[..., 1], cv2.INTER_CUBIC)
    encoded = sampled.reshape(len(centre), len(rows), len(offsets))
    # Blur acts on light, the camera's gamma comes after it: a step's gradient peaks at the edge only in linear
    # light (in encoded grey levels it leans towards the dark side).
    linear = 255.0 * (np.clip(encoded, 0.0, 255.0) / 255.0) ** np.float32(gamma)
    cand = _step_candidates(linear.mean(axis=1), encoded.mean(axis=1), offsets, half)
    if len(cand) == 0:
        return None
    cand[:, 1] += dither[cand[:, 0].astype(int)]
    prof_i, off, sign, contrast = cand.T
    prof_i = prof_i.astype(int)
    raw = centre[prof_i] + off[:, None] * normal[prof_i]
    und = intr.undistorted_pixels(raw)
    # the predicted line's direction in undistorted pixels
    pred_und = project_undistorted(intr, transform_points(invert(T_room_from_robot @ cam.T_robot_from_camera),
                                                         pts[pick]))
    fit = _robust_line(und, prof_i, sign, np.abs(contrast), pred_und, rng)
    if fit is None:
        return None
    line, inl, sigma = fit
    if len(inl) < limits.EDGE_MIN_POINTS or len(inl) < limits.EDGE_MIN_INLIER_FRACTION * len(centre):
        return None
    direction = np.array([line[1], -line[0]])
    s = und[inl] @ direction
    if s.max() - s.min() < limits.EDGE_MIN_LENGTH_PX:
        return None
    # ends of the stretch seen, as points of the 3-D edge (the profiles' sample points)
    start_i, end_i = prof_i[inl][np.argmin(s)], prof_i[inl][np.argmax(s)]
    points_room = pts[pick[[start_i, end_i]]]
    sigma = max(sigma, limits.EDGE_SIGMA_FLOOR_PX)
    s_c = s - s.mean()
    ends_s = np.array([s.min(), s.max()]) - s.mean()
    cov = (sigma**2 / len(s) + limits.EDGE_SYSTEMATIC_PX**2) * np.ones((2, 2)) \
        + sigma**2 / float(s_c @ s_c) * np.outer(ends_s, ends_s)
    return EdgeObservation(edge.name, cam.name, line, points_room, cov, float(sigma),
                           float(np.median(np.abs(contrast[inl]))), raw[inl], len(centre))


def _step_candidates(profiles: NDArray[np.float32], encoded: NDArray[np.float32], offsets: NDArray, half: float
                     ) -> NDArray[np.float64]:
    """(m, 4): profile index, subpixel offset (px along the normal), sign of the step, step height (grey).

    profiles (n, k): in linear light (located there); encoded (n, k): as the camera gave them (the contrast)."""
    g = np.zeros_like(profiles)
    g[:, 1:-1] = 0.5 * (profiles[:, 2:] - profiles[:, :-2])
    a = np.abs(g)
    peak = np.zeros_like(a, dtype=bool)
    peak[:, 1:-1] = (a[:, 1:-1] >= a[:, :-2]) & (a[:, 1:-1] > a[:, 2:])
    peak &= (np.abs(offsets) <= half)[None, :]
    out = []
    for i in range(len(profiles)):
        ks = np.flatnonzero(peak[i])
        if len(ks) == 0:
            continue
        ks = ks[np.argsort(-a[i, ks])][:limits.EDGE_CANDIDATES_PER_PROFILE]
        for k in ks:
            lo, hi = encoded[i, max(k - 5, 0):k - 1], encoded[i, k + 2:k + 6]
            if len(lo) == 0 or len(hi) == 0:
                continue
            step = float(hi.mean() - lo.mean())
            if abs(step) < limits.EDGE_MIN_CONTRAST:
                continue
            # parabola through the log of the gradient: exact for a Gaussian-blurred step
            lm, l0, lp = np.log(np.maximum(a[i, k - 1:k + 2], 1e-3))
            den = lm - 2 * l0 + lp
            frac = 0.5 * (lm - lp) / den if den < 0 else 0.0
            out.append((i, offsets[k] + float(np.clip(frac, -0.5, 0.5)), np.sign(step), step))
    return np.array(out, dtype=np.float64).reshape(-1, 4)


def _fit_line(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Total least squares line (a, b, c), a² + b² = 1, through (n, 2) points."""
    mean, axes = principal_axes(points)
    n = axes[1]
    return np.array([n[0], n[1], -n @ mean])


def _robust_line(und: NDArray, prof: NDArray, sign: NDArray, strength: NDArray, predicted: NDArray,
                 rng: np.random.Generator) -> tuple[NDArray, NDArray, float] | None:
    """RANSAC over the step candidates (one per profile, one polarity), then refits with a robust σ, keeping
    only steps of about the line's typical height (where the projected pattern lights one side, the step is
    taller and leans towards the pattern's own edges). Returns (line, inlier candidate indices, σ px) or None."""
    pd = predicted[-1] - predicted[0]
    pd /= np.linalg.norm(pd)
    max_sin = np.sin(np.radians(limits.EDGE_MAX_ANGLE_DEG))
    n_cand = len(und)
    if n_cand < 2:
        return None

    def inliers(line: NDArray, polarity: float, threshold: float, typical: float | None = None
                ) -> NDArray[np.int64]:
        d = np.abs(und @ line[:2] + line[2])
        ok = (d < threshold) & (sign == polarity)
        if typical is not None:
            ratio = limits.EDGE_CONTRAST_RATIO
            ok &= (strength > typical / ratio) & (strength < typical * ratio)
        idx = np.flatnonzero(ok)
        # one point per profile: the one nearest the line
        order = idx[np.lexsort((d[idx], prof[idx]))]
        _, first = np.unique(prof[order], return_index=True)
        return order[first]

    # hypotheses: lines through two steps of one polarity on different profiles, near the predicted direction
    lines, polarities = [], []
    for i, j in draw_samples(rng, n_cand, 2, limits.EDGE_RANSAC_ITERATIONS, distinct=True):
        if prof[i] == prof[j] or sign[i] != sign[j]:
            continue
        d = und[j] - und[i]
        length = np.linalg.norm(d)
        if length < limits.EDGE_MIN_LENGTH_PX / 4 or abs(d[0] * pd[1] - d[1] * pd[0]) / length > max_sin:
            continue
        n = np.array([-d[1], d[0]]) / length
        lines.append(np.array([n[0], n[1], -n @ und[i]]))
        polarities.append(float(sign[i]))
    if not lines:
        return None

    def support(h: slice) -> list[int]:
        return [len(inliers(lines[k], polarities[k], limits.EDGE_RANSAC_THRESHOLD_PX))
                for k in range(*h.indices(len(lines)))]

    best = best_hypothesis(len(lines), support)
    line, polarity = lines[best], polarities[best]
    inl = inliers(line, polarity, limits.EDGE_RANSAC_THRESHOLD_PX)
    if len(inl) < limits.EDGE_MIN_POINTS:
        return None

    def refit(inl: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        line = _fit_line(und[inl])
        r = und[inl] @ line[:2] + line[2]
        sigma = float(1.4826 * np.median(np.abs(r - np.median(r))))
        threshold = max(limits.EDGE_INLIER_SIGMAS * sigma, limits.EDGE_INLIER_FLOOR_PX)
        return line, inliers(line, polarity, threshold, float(np.median(strength[inl])))

    _, inl = refine(inl, refit, rounds=4, min_inliers=3)
    if len(inl) < 3:
        return None
    line = _fit_line(und[inl])
    r = und[inl] @ line[:2] + line[2]
    sigma = float(np.sqrt(np.mean(r**2)))
    direction = np.array([line[1], -line[0]])
    if abs(direction[0] * pd[1] - direction[1] * pd[0]) > max_sin or sigma > limits.EDGE_MAX_SIGMA_PX:
        return None
    return line, inl, sigma
