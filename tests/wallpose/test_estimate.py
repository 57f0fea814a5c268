import numpy as np
import pytest

from geometry.poses import invert, rotation_angle_deg
from wallpose import limits
from wallpose.detect import detect
from wallpose.estimate import Uncertainty, estimate_plane
from wallpose.evidence import EvidenceCode, NotEnoughEvidenceError

from .conftest import make_case

# The targets (arproj.bench.wallpose.TARGETS): normal error (°) and distance error (m) at 2 m and 4 m.
NORMAL_2M_DEG, DISTANCE_2M_M = 0.05, 0.001
NORMAL_4M_DEG, DISTANCE_4M_M = 0.15, 0.003


def _assert_right(est, case) -> None:
    """The estimate is within its own 95 % bounds of the truth (and the bounds are tight)."""
    n_err = est.normal_error_deg(case.plane.normal)
    d_err = abs(est.offset_at(case.true_centre()))
    assert n_err <= est.normal_95_deg, (n_err, est.normal_95_deg)
    assert d_err <= est.centre_distance_95_m, (d_err, est.centre_distance_95_m)


def test_plane_at_2m_30deg_is_exact_to_hundredths_of_a_degree(case_2m_30, photos_2m_30) -> None:
    est = estimate_plane(*photos_2m_30, case_2m_30.pattern, case_2m_30.views)
    assert est.normal_error_deg(case_2m_30.plane.normal) < NORMAL_2M_DEG
    assert abs(est.offset_at(case_2m_30.true_centre())) < DISTANCE_2M_M
    _assert_right(est, case_2m_30)
    # tight: 95 % bounds within twice the targets, so they can vouch for them
    assert est.normal_95_deg < 2 * NORMAL_2M_DEG and est.centre_distance_95_m < 2 * DISTANCE_2M_M
    # all but a tenth of the corners are inliers; their noise within the detector's subpixel bound (test_detect)
    assert est.corners > 0.9 * min(case_2m_30.pattern.n_corners, limits.MAX_CORNERS) and est.sigma_px < 0.15
    # the projector's pose as measured is nearer the truth than the head model's
    T_true = invert(case_2m_30.views.T_robot_from_camera_left) @ case_2m_30.scene.T_robot_from_projector_true
    assert rotation_angle_deg(est.T_camera_left_from_projector, T_true) < \
        rotation_angle_deg(case_2m_30.views.T_camera_left_from_projector, T_true)


def test_plane_at_4m_60deg() -> None:
    case = make_case(4.0, 60.0, seed=2)
    est = estimate_plane(*case.photos(), case.pattern, case.views)
    assert est.normal_error_deg(case.plane.normal) < NORMAL_4M_DEG
    assert abs(est.offset_at(case.true_centre())) < DISTANCE_4M_M
    _assert_right(est, case)


def test_occluded_pattern_still_right(case_2m_30) -> None:
    img = case_2m_30.pattern.image()
    band_left = np.array([[300, 0], [520, 0], [520, 800], [300, 800]], float)   # a person in front
    band_right = np.array([[200, 0], [420, 0], [420, 800], [200, 800]], float)
    left = case_2m_30.scene.photograph("camera_left", img, occluder=band_left)
    right = case_2m_30.scene.photograph("camera_right", img, occluder=band_right)
    est = estimate_plane(left, right, case_2m_30.pattern, case_2m_30.views)
    _assert_right(est, case_2m_30)
    # the corners behind the person are left out (all corners refined here, so none hides in the subsampling)
    det = detect(left, case_2m_30.pattern, case_2m_30.views.camera_left, case_2m_30.views.projector,
                 "camera_left", max_corners=None)
    assert det.count < 0.9 * case_2m_30.pattern.n_corners  # the bands hide well over a tenth of the board
    assert not np.any((det.pixels[:, 0] > 300) & (det.pixels[:, 0] < 520))


def test_too_few_corners_is_declined(case_2m_30) -> None:
    img = case_2m_30.pattern.image()
    everything_but_a_corner = np.array([[0, 0], [1280, 0], [1280, 800], [0, 800], [0, 0]], float)
    left = case_2m_30.scene.photograph("camera_left", img, occluder=everything_but_a_corner)
    right = case_2m_30.scene.photograph("camera_right", img)
    with pytest.raises(NotEnoughEvidenceError) as err:
        estimate_plane(left, right, case_2m_30.pattern, case_2m_30.views)
    assert err.value.code in ("too_few_corners", "no_pattern")
    assert "camera_left" in str(err.value)


def test_low_contrast_is_declined_with_the_reason() -> None:
    case = make_case(2.0, 30.0, seed=5, gain=0.02, ambient=120.0, noise_sigma=2.5)
    with pytest.raises(NotEnoughEvidenceError) as err:
        estimate_plane(*case.photos(), case.pattern, case.views)
    assert "low contrast" in str(err.value)


def test_over_exposed_is_still_right_or_declined(case_2m_30) -> None:
    # white clips but black does not: X-corners keep their place, the estimate holds (with a warning)
    left, right = case_2m_30.photos(exposure=4.0)
    est = estimate_plane(left, right, case_2m_30.pattern, case_2m_30.views)
    _assert_right(est, case_2m_30)
    assert any("over-exposed" in w for w in est.warnings)
    # everything clips: nothing to see, and it says so
    left, right = case_2m_30.photos(exposure=40.0)
    with pytest.raises(NotEnoughEvidenceError, match="over-exposed"):
        estimate_plane(left, right, case_2m_30.pattern, case_2m_30.views)


def test_robot_moved_between_the_images_is_declined(case_2m_30) -> None:
    from geometry.poses import make_pose, rotation_about
    from tests.support.synthetic_wallpose import PlanarScene, Plane

    # the robot turned by 1° and moved 2 cm towards the wall before the right image was taken
    T_new_from_old = make_pose(rotation_about([0, 0, 1], np.radians(1.0)), [-0.02, 0.0, 0.0])
    n, d = case_2m_30.plane.in_frame(T_new_from_old)
    moved = PlanarScene(case_2m_30.views, [Plane(n, d)], case_2m_30.scene.T_robot_from_projector_true,
                        rng=np.random.default_rng(9), supersample=2)
    img = case_2m_30.pattern.image()
    left = case_2m_30.scene.photograph("camera_left", img)
    right = moved.photograph("camera_right", img)
    with pytest.raises(NotEnoughEvidenceError) as err:
        estimate_plane(left, right, case_2m_30.pattern, case_2m_30.views)
    # The pattern is still one plane with every corner found: only the views' disagreement can tell.
    assert err.value.code == EvidenceCode.VIEWS_DISAGREE and "move" in str(err.value)


def test_projector_off_its_prior_is_its_own_case_and_measurable() -> None:
    # the projector 2° from where the rig puts it (a head re-mounted): beyond its prior, the cameras agree
    case = make_case(2.0, 30.0, seed=1, head_error_deg=2.0)
    photos = case.photos()
    with pytest.raises(NotEnoughEvidenceError) as err:
        estimate_plane(*photos, case.pattern, case.views)
    assert err.value.code == EvidenceCode.PROJECTOR_POSE_OFF
    assert err.value.code == "projector_pose_off"  # the value programs and tables see
    # with a prior that admits it, the pattern measures the projector's pose, and the plane is right
    est = estimate_plane(*photos, case.pattern, case.views,
                         uncertainty=Uncertainty(projector_rotation_deg=10.0, projector_translation_m=0.05))
    _assert_right(est, case)
    T_true = invert(case.views.T_robot_from_camera_left) @ case.scene.T_robot_from_projector_true
    assert rotation_angle_deg(est.T_camera_left_from_projector, T_true) < 0.05
    assert abs(est.projector_correction_deg - 2.0) < 0.05


def test_the_stereo_calibrations_uncertainty_widens_the_plane_to_cover_a_vergence_error() -> None:
    """A right camera turned by a vergence error the calibration cannot rule out moves the whole plane at 4 m by
    millimetres (depth error ∝ distance²/baseline): the corners' noise alone does not cover it, the calibration's
    draws (here ±that error) do."""
    from dataclasses import replace

    from geometry.poses import make_pose, rotation_about

    case = make_case(4.0, 0.0, seed=3)
    photos = case.photos()
    views = case.views
    vergence = np.radians(0.003)

    def turned(angle: float) -> np.ndarray:
        return make_pose(rotation_about([0.0, 1.0, 0.0], angle)) @ views.T_camera_right_from_camera_left

    wrong = replace(views, T_camera_right_from_camera_left=turned(vergence))
    draws = tuple((views.camera_left, views.camera_right, turned(s * vergence)) for s in (-1.0, 1.0))
    alone = estimate_plane(*photos, case.pattern, wrong)
    offset = abs(alone.offset_at(case.true_centre()))
    assert offset > alone.centre_distance_95_m  # the corners' noise does not cover the calibration's error
    covered = estimate_plane(*photos, case.pattern, wrong, uncertainty=Uncertainty(stereo_draws=draws))
    assert offset <= covered.centre_distance_95_m
    assert covered.normal_95_deg >= alone.normal_95_deg
