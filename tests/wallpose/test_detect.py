import numpy as np

from geometry.poses import invert, transform_points
from wallpose import limits
from wallpose.detect import detect


def _true_pixels(case, camera, ids):
    T = case.scene.T_robot_from_projector_true
    rays = case.views.projector.rays(case.pattern.corner_projector_px[ids])
    n, d = case.plane.in_frame(invert(T))
    X = transform_points(T, rays * (-d / (rays @ n))[:, None])
    T_robot_from_cam = case.views.T_robot_from_camera_left if camera == "camera_left" \
        else case.views.T_robot_from_camera_right
    return case.views.camera(camera).project(transform_points(invert(T_robot_from_cam), X))


def test_corners_found_at_their_true_pixels(case_2m_30, photos_2m_30) -> None:
    for camera, image in zip(("camera_left", "camera_right"), photos_2m_30, strict=True):
        det = detect(image, case_2m_30.pattern, case_2m_30.views.camera(camera), case_2m_30.views.projector,
                     camera, max_corners=None)
        assert det.reason is None and det.kept_fraction == 1.0
        assert det.count > 0.9 * case_2m_30.pattern.n_corners  # the whole board is in view: at most a tenth lost
        err = det.pixels - _true_pixels(case_2m_30, camera, det.corner_ids)
        assert np.sqrt(np.mean(err ** 2)) < 0.15          # subpixel: noise 2 grey levels, blur 0.7 px
        assert np.abs(err).max() < 0.6                    # and no corner matched to the wrong id
        assert abs(err.mean()) < 2 * limits.IMAGE_OFFSET_SIGMA_PX  # no common shift beyond 2 σ of the fit's prior


def test_blank_image_gives_a_reason_not_corners(case_2m_30) -> None:
    blank = np.full((800, 1280), 30, np.uint8)
    det = detect(blank, case_2m_30.pattern, case_2m_30.views.camera_left, case_2m_30.views.projector, "camera_left")
    assert det.count == 0 and "low contrast" in det.reason


def test_corner_cap_keeps_an_even_subset_at_the_same_pixels(case_2m_30, photos_2m_30) -> None:
    pattern, views = case_2m_30.pattern, case_2m_30.views
    # A cap below this case's corner count (the default cap, limits.MAX_CORNERS, works the same way).
    cap = min(limits.MAX_CORNERS, pattern.n_corners * 2 // 3)
    full = detect(photos_2m_30[0], pattern, views.camera_left, views.projector, "camera_left", max_corners=None)
    capped = detect(photos_2m_30[0], pattern, views.camera_left, views.projector, "camera_left", max_corners=cap)
    assert full.count > cap
    assert 0.9 * cap < capped.count <= 1.05 * cap  # an even (R2) subset hits fraction·n to within a few corners
    assert capped.kept_fraction < 1.0 and set(capped.corner_ids) <= set(full.corner_ids)
    # the same corners land on the same pixels: cornerSubPix stops once a step is below SUBPIX_EPS_PX, so seeds
    # from the two homographies end within a few such steps
    same = np.searchsorted(full.corner_ids, capped.corner_ids)
    assert np.abs(full.pixels[same] - capped.pixels).max() < 5 * limits.SUBPIX_EPS_PX
    # spread evenly: every quarter of the board keeps about the kept fraction of its corners
    grid_all, grid_kept = pattern.corner_grid[full.corner_ids], pattern.corner_grid[capped.corner_ids]
    mid = np.median(grid_all, axis=0)
    for qx in (False, True):
        for qy in (False, True):
            n_all = np.sum(((grid_all[:, 0] > mid[0]) == qx) & ((grid_all[:, 1] > mid[1]) == qy))
            n_kept = np.sum(((grid_kept[:, 0] > mid[0]) == qx) & ((grid_kept[:, 1] > mid[1]) == qy))
            assert abs(n_kept / n_all - capped.kept_fraction) < 0.1  # one row (~14) of a quarter's ~150 corners
