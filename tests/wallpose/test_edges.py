"""The wall's edges seen by the cameras (simulated site, GL): image lines against the truth, and what they add
to the full pose (the position along the wall) when the laser is left out and the localization is off."""

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pytest

from arproj.sim.wallpose_trial import calibrated_views, photograph_pair, room_map
from geometry.poses import invert, make_pose, rotation_about, rotation_angle_deg, transform_points
from wallpose.edges import CameraImage, Projector, camera_images, find_wall_edges, project_undistorted
from wallpose.estimate import PlaneEstimate, estimate_plane
from wallpose.pattern import choose_pattern
from wallpose.pose import RoomMap, estimate_wall_pose
from wallpose.rig import ViewRig

if TYPE_CHECKING:
    from arproj.sim import Site

pytestmark = pytest.mark.gl

# A 6 m x 5 m room whose side walls reflect less than wall 0 (the simulator lights all surfaces alike; in a real
# room the walls meeting at a corner differ in lighting), cameras looking level so the floor line is in view.
ROOM = {"corners_m": [[6.0, 0.0], [0.0, 0.0], [0.0, 5.0], [6.0, 5.0]],
        "walls": {1: {"albedo": 0.55}, 3: {"albedo": 0.55}}}
CAMERAS = {"pitch_deg": 0.0}


@dataclass
class Shot:
    views: ViewRig
    images: list[CameraImage]
    plane: PlaneEstimate
    T_robot_from_projector: np.ndarray
    room: RoomMap
    T_room_from_robot: np.ndarray          # truth
    T_room_from_cameras: dict[str, np.ndarray]  # truth
    localized: np.ndarray


def _shot(site: "Site", distance: float, incidence: float, along: float, seed: int) -> Shot:
    site.place_robot(distance, incidence, along_m=along, aim_height_m=1.1)
    views = calibrated_views(site)
    pattern = choose_pattern(views, distance, incidence)
    left, right = photograph_pair(site, pattern.image(), np.random.default_rng(seed))
    plane = estimate_plane(left, right, pattern, views)
    return Shot(views, camera_images(views, left, right), plane,
                views.T_robot_from_camera_left @ plane.T_camera_left_from_projector, room_map(site),
                site.T_room_from_robot.copy(), {c: site.T_room_from(c) for c in ("camera_left", "camera_right")},
                site.localized_T_room_from_robot.copy())


@pytest.fixture(scope="module")
def site(gl_context):
    from arproj.sim import Site

    site = Site.build(seed=1, ctx=gl_context, room=ROOM, cameras=CAMERAS)
    yield site
    site.release()


@pytest.fixture(scope="module")
def corner_shot(site) -> Shot:
    """3 m from wall 0 at 20°, 1.2 m from its left end: the left room corner and the floor line in view."""
    return _shot(site, 3.0, 20.0, 1.2, seed=1)


@pytest.fixture(scope="module")
def open_shot(site, corner_shot) -> Shot:
    """1.5 m from the middle of wall 0, square on: no corner, floor or ceiling line in view."""
    return _shot(site, 1.5, 0.0, 3.0, seed=2)


def _degraded(shot: Shot) -> np.ndarray:
    """A localization 4 cm off along the wall, 2 cm towards it and 1.2° in heading."""
    return make_pose(None, [0.04, 0.02, 0.0]) @ shot.T_room_from_robot \
        @ make_pose(rotation_about([0.0, 0.0, 1.0], np.radians(1.2)), None)


def _wall_error(pose_T_wall_from_robot: np.ndarray, shot: Shot, room: RoomMap | None = None) -> np.ndarray:
    T_true = invert((room or shot.room).T_room_from_walls[0]) @ shot.T_room_from_robot
    return pose_T_wall_from_robot[:3, 3] - T_true[:3, 3]


def test_edge_lines_match_the_true_projection(corner_shot: Shot) -> None:
    shot = corner_shot
    guess = estimate_wall_pose(shot.plane, 0, shot.room, shot.localized, shot.T_robot_from_projector)
    found = find_wall_edges(shot.images, shot.room.T_room_from_walls, shot.room.sizes_m, 0, guess.T_room_from_robot,
                            guess.covariance, projector=Projector(shot.views.projector, shot.T_robot_from_projector))
    seen = {(o.edge, o.camera) for o in found}
    for camera in ("camera_left", "camera_right"):
        assert ("left corner", camera) in seen and ("floor line", camera) in seen
    for obs in found:
        # the stretch seen, as the true camera sees it, against the fitted line
        lam = np.linspace(0.0, 1.0, 25)[:, None]
        points = obs.points_room[0] + lam * (obs.points_room[1] - obs.points_room[0])
        uv = project_undistorted(shot.views.camera(obs.camera),
                                 transform_points(invert(shot.T_room_from_cameras[obs.camera]), points))
        distance = uv @ obs.line[:2] + obs.line[2]
        # max 0.4 px ≈ 3 × limits.EDGE_SYSTEMATIC_PX (a whole line's shift), rms about twice it
        assert np.sqrt(np.mean(distance**2)) < 0.25 and np.max(np.abs(distance)) < 0.4, (obs.edge, obs.camera)
        # and the reported uncertainty covers it
        assert np.max(np.abs(distance[[0, -1]]) / np.sqrt(np.diag(obs.covariance))) < 3.0
        # over limits.EDGE_MIN_POINTS, and scatter half of EDGE_MAX_SIGMA_PX (where an edge stops being clean)
        assert len(obs.pixels) >= 25 and obs.sigma_px < 0.4


def test_edges_pin_the_position_along_the_wall(corner_shot: Shot) -> None:
    shot = corner_shot
    localized = _degraded(shot)
    args = (shot.plane, 0, shot.room, localized, shot.T_robot_from_projector, None, 0.04, 1.5)
    without = estimate_wall_pose(*args)
    with_edges = estimate_wall_pose(*args, camera_images=shot.images, projector=shot.views.projector)
    assert any(s.startswith("camera edges") for s in with_edges.sources)
    assert not any(s.startswith("camera edges") for s in without.sources)
    assert {o.edge for o in with_edges.edges} == {"left corner", "floor line"} and not with_edges.edges_rejected
    e0, e1 = _wall_error(without.T_wall_from_robot, shot), _wall_error(with_edges.T_wall_from_robot, shot)
    # without the laser the position along the wall is only as good as the localization ...
    assert abs(e0[0]) > 0.03 and without.sigma_along_m > 0.03  # most of the 4 cm localization error is left
    # ... the corner seen by the cameras pins it to millimetres, and says so (3 mm: 1.5 × the README's "about
    # 2 mm (1σ) at 3 m"; a tenfold gain on the 4 cm localization)
    assert abs(e1[0]) < 0.003 and abs(e1[0]) < 3 * with_edges.sigma_along_m
    assert with_edges.sigma_along_m < without.sigma_along_m / 10
    assert abs(e1[1]) < 3 * with_edges.sigma_height_m and abs(e1[2]) < 3 * with_edges.sigma_distance_m
    # the rotation about the normal, too (floor alone: 0.1°)
    assert with_edges.sigma_roll_deg < without.sigma_roll_deg / 5
    T_true = invert(shot.room.T_room_from_walls[0]) @ shot.T_room_from_robot
    assert rotation_angle_deg(with_edges.T_wall_from_robot, T_true) < 0.05  # the 2 m normal target (bench TARGETS)


def test_no_edge_in_view_changes_nothing(corner_shot: Shot, open_shot: Shot) -> None:
    shot = open_shot
    guess = estimate_wall_pose(shot.plane, 0, shot.room, shot.localized, shot.T_robot_from_projector)
    assert find_wall_edges(shot.images, shot.room.T_room_from_walls, shot.room.sizes_m, 0,
                           guess.T_room_from_robot, guess.covariance) == []
    with_images = estimate_wall_pose(shot.plane, 0, shot.room, shot.localized, shot.T_robot_from_projector,
                                     camera_images=shot.images, projector=shot.views.projector)
    np.testing.assert_array_equal(with_images.T_wall_from_robot, guess.T_wall_from_robot)
    np.testing.assert_array_equal(with_images.covariance, guess.covariance)
    assert with_images.sources == guess.sources and with_images.edges == []
    # edges in view but washed out (contrast below what a step needs): no observation either
    flat = [CameraImage(c.name, c.intrinsics, c.T_robot_from_camera,
                        (128 + (c.image.astype(np.float32) - 128) / 6).astype(np.uint8)) for c in corner_shot.images]
    g = estimate_wall_pose(corner_shot.plane, 0, corner_shot.room, corner_shot.localized,
                           corner_shot.T_robot_from_projector)
    assert find_wall_edges(flat, corner_shot.room.T_room_from_walls, corner_shot.room.sizes_m, 0,
                           g.T_room_from_robot, g.covariance) == []


def test_wrong_edge_is_rejected_not_fused(corner_shot: Shot) -> None:
    """The map of a different room: wall 0 and the room 13 cm longer at the corner in view (about 4 σ of the
    localization). The corner is found in the photos, but not where that map puts it: rejected."""
    shot = corner_shot
    shift = 0.13
    walls = [T.copy() for T in shot.room.T_room_from_walls]
    walls[0][0, 3] += shift   # wall 0 runs from room x = 6 (its left end) towards x = 0
    walls[3][0, 3] += shift   # its neighbour at that end moves with it
    sizes = list(shot.room.sizes_m)
    sizes[0] = (sizes[0][0] + shift, sizes[0][1])
    sizes[2] = (sizes[2][0] + shift, sizes[2][1])
    wrong = RoomMap(walls, sizes)
    without = estimate_wall_pose(shot.plane, 0, wrong, shot.localized, shot.T_robot_from_projector)
    pose = estimate_wall_pose(shot.plane, 0, wrong, shot.localized, shot.T_robot_from_projector,
                              camera_images=shot.images, projector=shot.views.projector)
    assert "left corner in camera_left" in pose.edges_rejected
    assert all(o.edge != "left corner" for o in pose.edges)
    # the pose stays where the map, localization and plane put it (the floor line agrees with this map)
    assert abs(pose.T_wall_from_robot[0, 3] - without.T_wall_from_robot[0, 3]) < 0.001  # 1 mm: not the 13 cm
    assert pose.sigma_along_m > 0.02  # ten times what the corner would give (~2 mm): it was not used
