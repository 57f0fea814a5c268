"""Features shared by overlapping frames, against the truth of a simulated wall and of hand-placed features.

The simulated wall (0.9 m × 0.3 m) is scanned in three 0.3 m frames that overlap by 0.1 m (wall x 0.3–0.4 and
0.6–0.7): two screws in the first overlap, one in the second, one seen by frame 0 only, and a copper pipe
crossing both seams. simscan knows every frame's true pose, so a screw's true drive coordinates in a frame
are that pose's inverse applied to its wall position.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.polyline import distances_to_polyline
from mapping.frame_features import (
    AMBIGUITY_MARGIN_M,
    END_INSET_M,
    FEATURE_SIGMA_M,
    feature_constraints,
    frame_features,
    frames_features,
)
from mapping.map_object import MapObject
from mapping.scandata import ScanData
from mapping.simscan import simulate_scan
from mapping.stitching import FrameGraph, apply_pose, seam_error
from scanner.wall import Wall, wall_from_dict

RESOLUTION_M = 0.004  # frame_features' default grid cell
# Sub-cell peak and ridge refinement: a feature lies within half a cell of the truth (unrefined, a cell centre
# would be up to half a cell off in each axis)
FEATURE_TOL_M = RESOLUTION_M / 2
FRAME_WIDTH_M, OVERLAP_M = 0.3, 0.1
SCREWS = {"s01a": (0.35, 0.065), "s01b": (0.35, 0.255), "s12": (0.65, 0.075), "s0": (0.15, 0.10)}
PIPE = np.array([[0.0, 0.16], [0.9, 0.16]])
PIPE.setflags(write=False)  # module constants are shared by the tests: read-only
SEEN_BY = {0: {"s01a", "s01b", "s0"}, 1: {"s01a", "s01b", "s12"}, 2: {"s12"}}  # by the frames' extents


def make_wall() -> Wall:
    objects = [{"kind": "screw", "id": k, "points_m": [list(p)], "depth_m": 0.005} for k, p in SCREWS.items()]
    objects.append({"kind": "pipe", "id": "pipe", "points_m": PIPE.tolist(), "depth_m": 0.03,
                    "material": "copper", "diameter_m": 0.015})
    return wall_from_dict({"format": "arproj-wall/1", "name": "three frames", "width_m": 0.9, "height_m": 0.3,
                           "material": "brick", "objects": objects})


def scan(seed: int, loc_sigma: tuple[float, float, float] = (0.002, 0.002, 0.0003)) -> ScanData:
    return simulate_scan(make_wall(), seed=seed, frame_width_m=FRAME_WIDTH_M, overlap_m=OVERLAP_M,
                         loc_sigma=loc_sigma, laser=False)


def poses(data: ScanData, kind: str) -> NDArray[np.float64]:
    f = data.frames
    return np.column_stack([f[f"{kind}_x_m"], f[f"{kind}_y_m"], f[f"{kind}_phi_rad"]])


def to_frame(pose: NDArray[np.float64], wall_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Wall points (n, 2) in the coordinates of a frame with pose (tx, ty, θ): the inverse of apply_pose."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = np.asarray(wall_xy, dtype=np.float64).reshape(-1, 2) - pose[:2]
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def seam_vector(poses_: NDArray[np.float64], true: NDArray[np.float64], i: int, j: int,
                wall_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Where frames i and j, placed by poses_, map the true wall point wall_xy: their difference (2,), metres."""
    return (apply_pose(poses_[i], to_frame(true[i], wall_xy)) - apply_pose(poses_[j], to_frame(true[j], wall_xy)))[0]


def nearest_screw(wall_xy: NDArray[np.float64]) -> tuple[str, float]:
    names = list(SCREWS)
    d = np.linalg.norm(np.array([SCREWS[n] for n in names]) - wall_xy.reshape(1, 2), axis=1)
    return names[int(np.argmin(d))], float(d.min())


@dataclass
class RecordingGraph(FrameGraph):
    """A FrameGraph that also records which frames and frame coordinates each feature constraint joins."""

    points: list[tuple[int, int, NDArray, NDArray]] = field(default_factory=list)
    lines: list[tuple[int, int, NDArray, NDArray, NDArray]] = field(default_factory=list)

    def add_points(self, i: ArrayLike, p_i: ArrayLike, j: ArrayLike, p_j: ArrayLike, cov: ArrayLike) -> None:
        self.points.append((int(np.ravel(i)[0]), int(np.ravel(j)[0]), np.reshape(p_i, 2), np.reshape(p_j, 2)))
        super().add_points(i, p_i, j, p_j, cov)

    def add_lines(self, i: ArrayLike, a_i: ArrayLike, normal_i: ArrayLike, j: ArrayLike, p_j: ArrayLike,
                  sigma_m: ArrayLike) -> None:
        self.lines.append((int(np.ravel(i)[0]), int(np.ravel(j)[0]), np.reshape(a_i, 2), np.reshape(normal_i, 2),
                           np.reshape(p_j, 2)))
        super().add_lines(i, a_i, normal_i, j, p_j, sigma_m)


def feature_errors(data: ScanData, per_frame: list) -> float:
    """Largest distance (m) of any extracted screw or pipe vertex from the truth, in its frame's coordinates."""
    true = poses(data, "true")
    worst = 0.0
    for k, (points, lines) in enumerate(per_frame):
        for p in points:
            worst = max(worst, nearest_screw(apply_pose(true[k], p.points_m))[1])
        for ln in lines:
            worst = max(worst, float(distances_to_polyline(ln.points_m, to_frame(true[k], PIPE)).max()))
    return worst


# ---- extraction on a simulated scan ----------------------------------------------------------------------------
def test_features_are_found_at_their_true_drive_positions() -> None:
    data = scan(seed=1)
    true = poses(data, "true")
    per_frame, boxes = frames_features(data)
    assert len(per_frame) == len(boxes) == 3
    for k, ((points, lines), box) in enumerate(zip(per_frame, boxes, strict=True)):
        # The box is the drive range simscan rasters: u to the frame width plus overlap (or the wall's end)
        u_hi = min(FRAME_WIDTH_M + OVERLAP_M, 0.9 - k * FRAME_WIDTH_M)
        np.testing.assert_allclose(box[0], [0.0, 0.0], atol=1e-9)
        np.testing.assert_allclose(box[1], [u_hi, 0.3], atol=0.001)  # within one sample step (1 mm)
        found = []
        for p in points:
            expected_uv = {n: to_frame(true[k], np.array(SCREWS[n]))[0] for n in SCREWS}
            name = min(expected_uv, key=lambda n: float(np.linalg.norm(expected_uv[n] - p.points_m[0])))
            assert np.linalg.norm(expected_uv[name] - p.points_m[0]) < FEATURE_TOL_M, (k, name, p.points_m)
            found.append(name)
        assert sorted(found) == sorted(SEEN_BY[k])  # each screw once, nothing spurious
        assert len(lines) == 1  # the pipe, one straight run across the frame
        poly = lines[0].points_m
        assert float(distances_to_polyline(poly, to_frame(true[k], PIPE)).max()) < FEATURE_TOL_M
        # pairing samples END_INSET_M inside each end, so the run must reach that close to the frame's borders
        assert poly[:, 0].min() < box[0][0] + END_INSET_M and poly[:, 0].max() > box[1][0] - END_INSET_M


# ---- pairing on a simulated scan -------------------------------------------------------------------------------
def test_pairing_joins_the_overlapping_frames_through_the_same_objects() -> None:
    data = scan(seed=2)
    true, est = poses(data, "true"), poses(data, "est")
    graph = RecordingGraph(est.copy())
    added = feature_constraints(data, graph, est)
    assert added == len(graph.points) + len(graph.lines)
    # Frames 0 and 2 are 0.2 m apart: only neighbours share features
    assert {(i, j) for i, j, *_ in graph.points + graph.lines} == {(0, 1), (1, 2)}
    paired = {}
    for i, j, p_i, p_j in graph.points:
        name_i, d_i = nearest_screw(apply_pose(true[i], p_i))
        name_j, d_j = nearest_screw(apply_pose(true[j], p_j))
        assert name_i == name_j and d_i < FEATURE_TOL_M and d_j < FEATURE_TOL_M  # one screw, seen twice
        paired.setdefault((i, j), []).append(name_i)
    assert {pair: sorted(names) for pair, names in paired.items()} == {(0, 1): ["s01a", "s01b"], (1, 2): ["s12"]}
    assert sorted((i, j) for i, j, *_ in graph.lines) == [(0, 1), (1, 2)]
    for i, j, a_i, n_i, p_j in graph.lines:
        for pose, p in ((true[i], a_i), (true[j], p_j)):  # both ends lie on the pipe
            assert distances_to_polyline(apply_pose(pose, p), PIPE)[0] < FEATURE_TOL_M
        # its normal is the pipe's (the wall's y) in frame i; the run's ends, each within FEATURE_TOL_M over at
        # least a frame's width, fix its direction to 2·FEATURE_TOL_M / FRAME_WIDTH_M
        n_true = to_frame(np.r_[0.0, 0.0, true[i, 2]], np.array([0.0, 1.0]))[0]
        cos = abs(float(n_i @ n_true)) / float(np.linalg.norm(n_i))
        assert np.arccos(min(cos, 1.0)) < 2 * FEATURE_TOL_M / FRAME_WIDTH_M


def test_a_frame_placed_far_beyond_its_uncertainty_is_not_paired() -> None:
    data = scan(seed=2)
    est = poses(data, "est")
    est[2, 1] += 0.04  # 40 mm: 14 σ of the frames' relative localization (2 mm each), no sound gate admits it
    graph = RecordingGraph(est.copy())
    feature_constraints(data, graph, est)
    assert {(i, j) for i, j, *_ in graph.points + graph.lines} == {(0, 1)}


def test_shared_features_recover_a_known_frame_offset() -> None:
    sigma_loc = 0.01  # metres, per frame: the robot's localization
    data = scan(seed=3, loc_sigma=(sigma_loc, sigma_loc, 0.0003))
    true = poses(data, "true")
    est = true + np.array([[0.0, 0.0, 0.0], [0.008, -0.006, 0.0], [-0.004, 0.005, 0.0]])  # known offsets
    features = frames_features(data)
    border = np.array([SCREWS["s01a"], SCREWS["s01b"], [0.35, 0.16], SCREWS["s12"], [0.65, 0.16]])
    pairs = np.array([[0, 1]] * 3 + [[1, 2]] * 2)

    without = FrameGraph(est.copy())
    without.add_priors(est, data.frames["cov"])
    with_features = FrameGraph(est.copy())
    with_features.add_priors(est, data.frames["cov"])
    assert feature_constraints(data, with_features, est, features) == 5  # 3 screws, 2 pipe crossings
    before = seam_error(without.solve()[0], true, border, pairs)
    after = seam_error(with_features.solve()[0], true, border, pairs)
    np.testing.assert_allclose(before, [0.01] * 3 + [np.hypot(0.012, 0.011)] * 2, atol=1e-9)  # priors alone
    # What the priors still pull: a seam with one screw weighs the relative prior (variance 2σ_loc²) against the
    # screw (variance 2σ_f², two features): share σ_f²/(σ_f² + σ_loc²); ×2 as frame 1 lies on both seams.
    # The features' own location errors (measured against the truth) pass at most 1:1 from each frame.
    share = 2 * FEATURE_SIGMA_M**2 / (FEATURE_SIGMA_M**2 + sigma_loc**2)
    assert np.all(after < share * before + 2 * feature_errors(data, features[0]))
    assert np.all(after < before)  # better than the priors alone, at every seam point


def test_a_line_constrains_only_across_itself() -> None:
    sigma_loc = 0.01
    data = scan(seed=3, loc_sigma=(sigma_loc, sigma_loc, 0.0003))
    true = poses(data, "true")
    est = true + np.array([[0.0, 0.0, 0.0], [0.008, -0.006, 0.0], [-0.004, 0.005, 0.0]])
    per_frame, boxes = frames_features(data)
    lines_only = ([([], lines) for _, lines in per_frame], boxes)
    graph = FrameGraph(est.copy())
    graph.add_priors(est, data.frames["cov"])
    assert feature_constraints(data, graph, est, lines_only) == 2
    x, _ = graph.solve()
    share = 2 * FEATURE_SIGMA_M**2 / (FEATURE_SIGMA_M**2 + sigma_loc**2)  # as for the screws above
    slack = 2 * feature_errors(data, lines_only[0])
    for (i, j), crossing in (((0, 1), [0.35, 0.16]), ((1, 2), [0.65, 0.16])):
        before, after = (seam_vector(p, true, i, j, np.array(crossing)) for p in (est, x))
        assert abs(after[1]) < share * abs(before[1]) + slack  # across the pipe: corrected
        # along the (horizontal) pipe it slides: x is seen only through the pipe's slope in the frame, a few
        # mrad of rotation, so at most a few per mille of the x error may change; 5 % bounds that
        assert abs(after[0] - before[0]) < 0.05 * abs(before[0])


# ---- pairing rules on hand-placed features -----------------------------------------------------------------------
TRUE_TWO = np.array([[0.0, 0.0, 0.02], [0.30, 0.01, -0.03]])  # rotations large enough to matter
BOX = (np.array([0.0, 0.0]), np.array([0.4, 0.3]))
SIGMA_GATE = 0.004  # σ per frame in the hand-made tests: gate 3·√2·σ ≈ 17 mm (no rotation uncertainty)
GATE_M = 3 * np.hypot(SIGMA_GATE, SIGMA_GATE)  # "a gate of three localization standard deviations"
SCREW_W = np.array([0.35, 0.10])
LINE_W = np.array([[0.0, 0.20], [0.7, 0.22]])  # a pipe across the seam (not axis-aligned)
for _a in (TRUE_TWO, *BOX, SCREW_W, LINE_W):
    _a.setflags(write=False)


def two_frames(sigma: float = SIGMA_GATE) -> ScanData:
    cov = np.tile(np.diag([sigma**2, sigma**2, 0.0]), (2, 1, 1))
    return ScanData("hand-placed", {}, {"frame_id": np.array([0, 1]), "cov": cov}, {})


def point(frame: int, wall_xy: NDArray[np.float64], true: NDArray[np.float64] = TRUE_TWO) -> MapObject:
    return MapObject("point", to_frame(true[frame], wall_xy), 0.004, 20.0)


def line_piece(frame: int, x0: float, x1: float, lateral: float = 0.0,
               true: NDArray[np.float64] = TRUE_TWO) -> MapObject:
    """The part of LINE_W between wall x0 and x1, moved `lateral` metres along its normal, in frame coords."""
    d = (LINE_W[1] - LINE_W[0]) / np.linalg.norm(LINE_W[1] - LINE_W[0])
    n = np.array([-d[1], d[0]])
    ends = [LINE_W[0] + d * (x - LINE_W[0, 0]) / d[0] + lateral * n for x in (x0, x1)]
    return MapObject("line", to_frame(true[frame], np.array(ends)), 0.01, 20.0)


def test_exact_features_give_constraints_that_vanish_at_the_truth() -> None:
    other = SCREW_W + np.array([0.01, 0.15])
    features = ([([point(0, SCREW_W), point(0, other)], [line_piece(0, 0.02, 0.39)]),
                 ([point(1, other), point(1, SCREW_W)], [line_piece(1, 0.31, 0.68)])], [BOX, BOX])  # listed apart
    graph = FrameGraph(TRUE_TWO.copy())  # linearised at the truth: the residuals there are exact
    assert feature_constraints(two_frames(), graph, TRUE_TWO, features) == 3
    assert np.all(np.concatenate(graph.mahalanobis(TRUE_TWO)) < 1e-9)  # round-off of metre-scale coordinates
    d = (LINE_W[1] - LINE_W[0]) / np.linalg.norm(LINE_W[1] - LINE_W[0])
    n = np.array([-d[1], d[0]])
    moved = TRUE_TWO.copy()
    moved[1, :2] += 0.001 * d  # frame 1 slides 1 mm along the pipe
    r_point_along, _, r_line_along = np.concatenate(graph.mahalanobis(moved))  # points first, then the line
    moved = TRUE_TWO.copy()
    moved[1, :2] += 0.001 * n  # ... or 1 mm across it
    r_point_across, _, r_line_across = np.concatenate(graph.mahalanobis(moved))
    assert r_line_along < 1e-9 < r_line_across  # the line slides along itself
    assert r_point_along > 1e-9 and abs(r_point_along / r_point_across - 1) < 1e-9  # a point is isotropic
    assert abs(r_line_across / r_point_across - 1) < 1e-9  # 1 mm across either: the same misalignment


def test_only_frames_that_overlap_or_nearly_touch_are_paired() -> None:
    for gap, expected in ((0.005, 1), (0.05, 0)):  # within the gate (frames side by side) / well beyond it
        true = np.array([[0.0, 0.0, 0.0], [BOX[1][0] + gap, 0.0, 0.0]])
        x1 = float(true[1, 0])
        # the pipe's ends face each other across the gap, closer than the 0.15 m a crossing may bridge
        features = ([([], [line_piece(0, 0.02, 0.39, true=true)]),
                     ([], [line_piece(1, x1 + 0.01, x1 + 0.3, true=true)])], [BOX, BOX])
        graph = FrameGraph(true.copy())
        assert feature_constraints(two_frames(), graph, true, features) == expected, gap


def test_a_candidate_beyond_the_gate_is_not_paired() -> None:
    direction = np.array([0.6, 0.8])
    for distance, sigma_override, expected in ((0.8 * GATE_M, None, 1), (1.25 * GATE_M, None, 0),
                                               (1.25 * GATE_M, 2 * SIGMA_GATE, 1)):  # a looser gate takes it
        features = ([([point(0, SCREW_W)], []), ([point(1, SCREW_W + distance * direction)], [])], [BOX, BOX])
        graph = FrameGraph(TRUE_TWO.copy())
        override = None if sigma_override is None else np.tile([sigma_override, 0.0, 0.0], (2, 1))
        assert feature_constraints(two_frames(), graph, TRUE_TWO, features, override) == expected, distance


def test_points_pair_only_as_mutual_nearest_neighbours() -> None:
    near, far = SCREW_W, SCREW_W + np.array([0.0, 0.006])  # both within the gate of frame 1's one screw
    features = ([([point(0, far), point(0, near)], []), ([point(1, near)], [])], [BOX, BOX])
    graph = RecordingGraph(TRUE_TWO.copy())
    assert feature_constraints(two_frames(), graph, TRUE_TWO, features) == 1
    (_, _, p_i, _), = graph.points
    np.testing.assert_allclose(apply_pose(TRUE_TWO[0], p_i)[0], near, atol=1e-12)


def test_ambiguous_or_non_continuing_lines_are_not_paired() -> None:
    left = line_piece(0, 0.02, 0.39)
    cases = [
        ([line_piece(1, 0.31, 0.68)], 1),  # its continuation
        # a parallel run beside it, inside the gate and less than 2·0 + AMBIGUITY_MARGIN_M worse: ambiguous
        ([line_piece(1, 0.31, 0.68), line_piece(1, 0.31, 0.68, lateral=0.5 * AMBIGUITY_MARGIN_M)], 0),
        ([line_piece(1, 0.31, 0.68), line_piece(1, 0.31, 0.68, lateral=2 * GATE_M)], 1),  # beyond the gate
        ([line_piece(1, 0.31, 0.68, lateral=2 * GATE_M)], 0),  # only a line that does not continue it
    ]
    perpendicular = MapObject("line", to_frame(TRUE_TWO[1], np.array([[0.33, 0.21], [0.33, 0.29]])), 0.01, 20.0)
    cases.append(([perpendicular], 0))  # an end nearby, but turned 90°
    for lines_j, expected in cases:
        features = ([([], [left]), ([], lines_j)], [BOX, BOX])
        graph = FrameGraph(TRUE_TWO.copy())
        assert feature_constraints(two_frames(), graph, TRUE_TWO, features) == expected, len(lines_j)


# ---- degenerate input --------------------------------------------------------------------------------------------
def test_a_pipe_crossing_is_not_taken_for_a_screw() -> None:
    pipe = {"kind": "pipe", "depth_m": 0.03, "material": "copper", "diameter_m": 0.015}
    wall = wall_from_dict({"format": "arproj-wall/1", "width_m": 0.35, "height_m": 0.3, "objects": [
        {**pipe, "id": "v", "points_m": [[0.1, 0.0], [0.1, 0.3]]},
        {**pipe, "id": "h", "points_m": [[0.0, 0.18], [0.35, 0.18]]},
        {"kind": "screw", "id": "s", "points_m": [[0.27, 0.07]], "depth_m": 0.005}]})
    data = simulate_scan(wall, seed=0, laser=False)  # one frame
    true = poses(data, "true")[0]
    s = data.samples
    points, lines = frame_features(np.column_stack([s["drive_u_m"], s["drive_v_m"]]), s["inductive"])
    assert len(lines) == 2
    # the crossing is a round peak too, but it lies on the lines: only the screw is a point
    assert len(points) == 1
    assert np.linalg.norm(points[0].points_m[0] - to_frame(true, np.array([0.27, 0.07]))[0]) < FEATURE_TOL_M


def test_frames_without_inductive_readings_give_no_features() -> None:
    data = scan(seed=4)
    del data.samples["inductive"]
    per_frame, boxes = frames_features(data)
    assert per_frame == [([], [])] * 3 and boxes == [None] * 3
    graph = FrameGraph(poses(data, "est"))
    assert feature_constraints(data, graph, poses(data, "est"), (per_frame, boxes)) == 0
