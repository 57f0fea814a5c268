"""Registration geometry: wall frame from a measured plane, rays to the wall, fold-over guard, closed-loop
measurement and the laser/plane check — against exact constructions."""

import numpy as np
import pytest

from arproj.session import gate, registration
from geometry import Intrinsics, invert, look_at, make_pose, rotation_about, transform_points

PROJECTOR = Intrinsics(1664.0, 1664.0, 639.5, 639.5, 1280, 800, (0.02, -0.01, 0.0, 0.0, 0.0))


def _T_wall_from_robot():
    # robot 2 m in front of the wall, facing it (robot x towards the wall, z up)
    R = np.column_stack([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # wall axes of robot x, y, z
    return make_pose(R, [1.5, 0.0, 2.0])


def test_snap_to_plane_keeps_the_prior_in_plane_and_takes_the_measured_plane():
    truth = _T_wall_from_robot()
    T_robot_from_wall = invert(truth)
    normal, distance = T_robot_from_wall[:3, 2], -T_robot_from_wall[:3, 2] @ T_robot_from_wall[:3, 3]
    prior = make_pose(rotation_about([0, 0, 1], np.radians(0.5)) @ rotation_about([1, 0, 0], np.radians(1.0)),
                      [0.004, -0.003, 0.05]) @ truth  # tilted and 5 cm off the wall
    snapped = registration.snap_to_plane(prior, normal, distance)
    on_wall = transform_points(invert(snapped), [[0.3, 0.7, 0.0], [2.0, 1.5, 0.0]])
    assert np.abs(transform_points(truth, on_wall)[:, 2]).max() < 1e-9  # z = 0 is the measured plane
    assert np.allclose(snapped[:3, :3] @ snapped[:3, :3].T, np.eye(3))


def test_rays_land_where_projection_says_and_fold_over_is_rejected():
    T = look_at([1.0, 1.2, 2.5], [1.6, 1.1, 0.0], up=[0, 1, 0])
    pixels = np.array([[100.0, 100.0], [640.0, 400.0], [1200.0, 700.0]])
    pts = registration.rays_to_wall(T, PROJECTOR, pixels)
    assert np.abs(pts[:, 2]).max() < 1e-12  # float64 round-off at metres: ~1e-15 m
    # 1e-6 px: undistortion iterated to 1e-12 (geometry.intrinsics), round-off times f
    assert np.allclose(PROJECTOR.project(transform_points(invert(T), pts)), pixels, atol=1e-6)
    far = transform_points(invert(T), [[40.0, 1.0, 0.0]])  # far outside the view: distortion folds it back
    _, inside = registration.project_in_view(PROJECTOR, far)
    assert not inside[0]
    assert registration.project_in_view(PROJECTOR, transform_points(invert(T), pts))[1].all()


def test_closed_loop_measures_a_known_offset_exactly():
    cam = Intrinsics.from_fov(1280, 800, 70.0, dist=(-0.1, 0.05, 0.0, 0.0, 0.0))
    T_wall_from_left = look_at([1.4, 1.2, 2.0], [1.5, 1.2, 0.0], up=[0, 1, 0])
    T_left_from_right = make_pose(rotation_about([0, 1, 0], np.radians(-0.5)), [0.2, 0.0, 0.0])
    T_right_from_left = invert(T_left_from_right)
    marks = np.array([[x, y] for x in np.linspace(1.0, 2.0, 5) for y in np.linspace(0.8, 1.6, 4)])
    offset = np.array([0.0021, -0.0013])
    landed = np.column_stack([marks + offset, np.zeros(len(marks))])
    uv_l = cam.project(transform_points(invert(T_wall_from_left), landed))
    uv_r = cam.project(transform_points(invert(T_wall_from_left @ T_left_from_right), landed))
    loop = registration.measure_marks(marks, uv_l, uv_r, cam, cam, T_right_from_left, T_wall_from_left)
    # exact pixels: residual and offsets at round-off (1e-7 m is a ten-thousandth of a millimetre)
    assert loop.seen.all() and loop.residual_px < 1e-6
    assert np.allclose(loop.errors_xy, offset, atol=1e-7)
    uv_r[3] += [6.0, -4.0]  # one mis-detected mark is dropped, not averaged in
    loop = registration.measure_marks(marks, uv_l, uv_r, cam, cam, T_right_from_left, T_wall_from_left)
    assert loop.seen.sum() == len(marks) - 1 and np.allclose(loop.offset_xy, offset, atol=1e-7)


def _marks_seen(landed_xy, noise_px, seed):
    cam = Intrinsics.from_fov(1280, 800, 70.0, dist=(-0.1, 0.05, 0.0, 0.0, 0.0))
    T_wall_from_left = look_at([1.4, 1.2, 2.0], [1.5, 1.2, 0.0], up=[0, 1, 0])
    T_left_from_right = make_pose(rotation_about([0, 1, 0], np.radians(-0.5)), [0.2, 0.0, 0.0])
    landed = np.column_stack([landed_xy, np.zeros(len(landed_xy))])
    rng = np.random.default_rng(seed)
    uv_l = cam.project(transform_points(invert(T_wall_from_left), landed))
    uv_r = cam.project(transform_points(invert(T_wall_from_left @ T_left_from_right), landed))
    uv_l, uv_r = (uv + rng.normal(0, noise_px, uv.shape) for uv in (uv_l, uv_r))
    return uv_l, uv_r, cam, cam, invert(T_left_from_right), T_wall_from_left


@pytest.mark.parametrize("seed", range(5))
def test_a_lone_outlier_mark_is_dropped_but_a_slip_of_every_mark_is_kept(seed):
    marks = np.array([[x, y] for x in np.linspace(1.0, 2.0, 6) for y in np.linspace(0.8, 1.6, 5)])
    # a mark on a board in front of the wall (or a sunlight patch the finder took): 5 mm off alone,
    # seen alike by both cameras so the stereo checks pass it; 0.15 px detection noise (~0.3 mm here)
    landed = marks.copy()
    landed[11] += [0.004, 0.003]
    loop = registration.measure_marks(marks, *_marks_seen(landed, 0.15, seed))
    assert loop.rejected == 1 and not loop.seen[11] and loop.seen.sum() == len(marks) - 1
    assert loop.errors_m.max() < 0.0015 and "1 lone outlier" in loop.summary()
    fine = gate.RegistrationEvidence(pose_sigma_m=0.0008, closed_loop_errors_m=loop.errors_m,
                                     closed_loop_expected=len(marks), stereo_residual_px=loop.residual_px)
    assert gate.decide(fine).show_map
    # a slipped head: every mark moves together (11 mm and 0.3° about the pattern's centre), none is dropped,
    # the worst stays in the evidence and the gate warns
    c, s = np.cos(np.radians(0.3)), np.sin(np.radians(0.3))
    centre = marks.mean(axis=0)
    slipped = (marks - centre) @ np.array([[c, -s], [s, c]]).T + centre + [0.011, -0.002]
    loop = registration.measure_marks(marks, *_marks_seen(slipped, 0.15, seed))
    truth = np.linalg.norm(slipped - marks, axis=1)
    assert loop.rejected == 0 and loop.seen.all()
    assert loop.errors_m.max() == pytest.approx(truth.max(), abs=0.0015)
    fine.closed_loop_errors_m = loop.errors_m
    assert not gate.decide(fine).show_map


def test_laser_plane_offset_sees_a_wrong_camera_mount():
    truth = _T_wall_from_robot()
    x = np.linspace(0.3, 2.7, 200)
    laser_wall = np.column_stack([x, np.full_like(x, 0.2), np.random.default_rng(0).normal(0, 0.01, len(x))])
    laser_robot = transform_points(invert(truth), laser_wall)
    # |offset| + 1.5 m·|slope| of a line through 200 points of 1 cm noise: σ 0.7 mm and 1.5 mm, mean 1.9 mm;
    # 6 mm, the gate's LASER_PLANE_TOLERANCE_M, is its 99.9th percentile (500 seeds)
    assert registration.laser_plane_offset_m(truth, laser_robot, 1.5) < 0.006
    wrong = make_pose(None, [0.0, 0.0, 0.02]) @ truth  # the wall believed 2 cm nearer
    assert registration.laser_plane_offset_m(wrong, laser_robot, 1.5) == pytest.approx(0.02, abs=0.006)


def test_oblique_far_end_is_less_certain_and_left_out_of_the_trusted_region():
    T = look_at([0.5, 1.3, 1.0], [2.2, 1.3, 0.0], up=[0, 1, 0])  # about 60° to the wall
    grid = np.array([[x, y] for x in np.linspace(1.0, 6.0, 26) for y in np.linspace(0.9, 1.7, 5)])
    sigma = registration.local_registration_sigma_m(0.002, 0.1, T, grid, np.array([2.2, 1.3]), 0.0, 0.001, 0.0)
    near, far = sigma[grid[:, 0] < 2.5].max(), sigma[grid[:, 0] > 5.0].min()
    assert far > 3 * near
    trusted = registration.trusted_region(grid, sigma, 0.010)
    assert 0.2 < trusted.share < 1.0 and trusted.usable  # the near 30 % (x < 2.5 of 1–6 m) in, the far end out
    inside = registration.inside_polygon(grid, trusted.polygon)
    assert inside[grid[:, 0] < 2.5].all() and not inside[grid[:, 0] > 5.5].any()
    assert trusted.sigma_m == pytest.approx(sigma[inside].max(), rel=1e-6)  # the same number, up to round-off
    assert registration.trusted_region(grid, np.full(len(grid), 0.0001), 0.010).polygon is None
    assert not registration.trusted_region(grid, np.full(len(grid), 0.05), 0.010).usable


def test_pose_sigma_on_wall_is_how_far_robot_fixed_wall_points_move_and_counts_pitch_times_distance():
    from geometry.poses import pose_from_vector

    T = _T_wall_from_robot()  # robot 2 m before the wall, its origin at wall (1.5, 0)
    points = np.array([[1.5, 1.2], [4.0, 2.0], [0.2, 0.4]])
    robot_points = transform_points(invert(T), np.column_stack([points, np.zeros(len(points))]))
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6)) * np.array([1e-3, 1e-3, 1e-3, 2e-3, 2e-3, 2e-3])
    cov = A @ A.T  # correlated rotations and translations
    sigma = registration.pose_sigma_on_wall_m(points, T, cov)
    draws = rng.multivariate_normal(np.zeros(6), cov, 4000)
    moved = np.array([transform_points(T @ pose_from_vector(d), robot_points)[:, :2] - points for d in draws])
    assert sigma == pytest.approx(np.sqrt((moved ** 2).sum(axis=2).mean(axis=0)), rel=0.05)
    # a pitch of the robot alone (about its y axis, along the wall) moves the point it faces by distance × angle:
    # the roll-about-the-aim-point model (lever 0 there, no in-plane σ) said nothing at all
    pitch = np.zeros((6, 6))
    pitch[1, 1] = np.radians(0.05) ** 2
    facing = registration.pose_sigma_on_wall_m(np.array([[1.5, 0.0]]), T, pitch)
    assert facing[0] == pytest.approx(2.0 * np.radians(0.05), rel=1e-6)
    old = registration.local_registration_sigma_m(0.0, 0.0, T, np.array([[1.5, 0.0]]), np.array([1.5, 0.0]),
                                                  0.0, 0.001, 0.0, roll_sigma_rad=np.radians(0.05))
    assert old[0] == 0.0


def test_pose_sigma_with_a_dof_known_is_the_conditional_spread_and_the_terms_name_the_largest():
    from geometry.poses import pose_from_vector

    T = _T_wall_from_robot()
    points = np.array([[1.5, 1.2], [3.0, 1.8], [0.4, 0.6]])
    robot_points = transform_points(invert(T), np.column_stack([points, np.zeros(len(points))]))
    rng = np.random.default_rng(5)
    A = rng.normal(size=(6, 6)) * np.array([1e-3, 1e-3, 2e-3, 2e-3, 2e-3, 2e-3])
    cov = A @ A.T
    known = registration.pose_sigma_on_wall_m(points, T, cov, known=("rotation about the wall's normal",))
    # the spread of the draws whose rotation about the wall's normal is (nearly) nil: the conditional spread
    draws = rng.multivariate_normal(np.zeros(6), cov, 200_000)
    roll = (T[:3, :3] @ draws[:, :3].T)[2]
    keep = draws[np.abs(roll) < 0.02 * roll.std()]
    moved = np.array([transform_points(T @ pose_from_vector(d), robot_points)[:, :2] - points for d in keep])
    assert known == pytest.approx(np.sqrt((moved ** 2).sum(axis=2).mean(axis=0)), rel=0.1)
    assert np.all(known < registration.pose_sigma_on_wall_m(points, T, cov))
    # a pose whose only uncertainty is the roll about the normal: nothing left once the roll is known
    only_roll = np.zeros((6, 6))
    only_roll[:3, :3] = T[:3, :3].T @ np.diag([0.0, 0.0, np.radians(0.1) ** 2]) @ T[:3, :3]
    assert registration.pose_sigma_on_wall_m(points, T, only_roll, known=("rotation about the wall's normal",)) \
        == pytest.approx(0.0, abs=1e-9)  # nanometres: the round-off of subtracting the roll's share
    pose = registration.pose_sigma_on_wall_m(points, T, only_roll)
    terms = registration.registration_sigma_terms(0.001, 0.05, T, points, points[0], 0.0, 0.001, 0.1,
                                                  pose_sigma_m=pose)
    assert terms.total == pytest.approx(registration.local_registration_sigma_m(
        0.001, 0.05, T, points, points[0], 0.0, 0.001, 0.1, pose_sigma_m=pose))
    name, share = terms.largest()
    assert name == "pose" and 0.5 < share <= 1.0
