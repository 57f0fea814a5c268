"""Head, robot, exposure, colour, non-convex rooms, and the pictures/CLI of the simulated site."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from arproj.session.overlays import LEGEND
from arproj.sim import Site, optics
from arproj.sim.pictures import write_site_pictures
from geometry.errors import InputError
from geometry.poses import look_at, transform_points

L_ROOM = [[0.0, 0.0], [6.0, 0.0], [6.0, 3.0], [3.0, 3.0], [3.0, 5.0], [0.0, 5.0]]


def test_head_errors_bias_noise_and_backlash() -> None:
    site = Site.build(seed=5, head={"angle_noise_deg": 0.0, "backlash_deg": 0.2})
    bias = site.head_angle_bias_deg
    site.set_head([10.0, 5.0, 0.0])
    up = site.head_angles_true_deg - site.head_angles_cmd_deg
    site.set_head([0.0, 0.0, -2.0])
    down = site.head_angles_true_deg - site.head_angles_cmd_deg
    # Moving up the joints stop 0.1° short (below), moving down 0.1° above; roll has not moved yet.
    assert np.allclose(up, bias + np.array([-0.1, -0.1, 0.0]), atol=1e-12)
    assert np.allclose(down, bias + np.array([0.1, 0.1, 0.1]), atol=1e-12)
    # The projector pose follows the true angles through the true (imperfect) head.
    expected = site.T_room_from_robot @ site.head.T_robot_from_projector(site.head_angles_true_deg)
    assert np.allclose(site.T_room_from("projector"), expected)
    nominal = site.T_room_from_robot @ site.head_nominal.T_robot_from_projector(site.head_angles_true_deg)
    assert 1e-4 < np.linalg.norm(nominal[:3, 3] - expected[:3, 3]) < 0.02
    with pytest.raises(InputError, match=r"tilt = 80\.000° is outside its limits"):
        site.set_head([0.0, 80.0, 0.0])


def test_move_robot_refuses_walls_and_outside() -> None:
    site = Site.build(seed=0)
    T = site.T_room_from_robot
    T[:2, 3] = [0.1, 2.0]
    with pytest.raises(InputError, match="closer than its footprint radius"):
        site.move_robot(T)
    T[:2, 3] = [-1.0, 2.0]
    with pytest.raises(InputError, match="outside the room"):
        site.move_robot(T)


@pytest.mark.gl
def test_exposure_is_linear_before_gamma_and_clips(gl_context: object) -> None:
    with Site.build(seed=0, ctx=gl_context, cameras={"gamma": 1.0, "vignetting": False}) as site:
        a = site.photograph("camera_left", noise=False, exposure=0.02).image.astype(float)
        b = site.photograph("camera_left", noise=False, exposure=0.04).image.astype(float)
        c = site.photograph("camera_left", noise=False, exposure=10.0).image
    valid = (a > 20) & (b < 250)
    # 8-bit rounding of values above 20: at most ±2.5 % per pixel, the median far less
    assert np.median(b[valid] / a[valid]) == pytest.approx(2.0, rel=0.02)
    assert (c == 255).mean() > 0.99


@pytest.mark.gl
def test_colour_camera_sees_a_red_pattern_red(gl_context: object) -> None:
    with Site.build(seed=0, ctx=gl_context, cameras={"color": True}) as site:
        red = np.zeros((site.projector.height, site.projector.width, 3), np.uint8)
        red[..., 0] = 255
        photo = site.photograph("camera_left", red, noise=False)
        dark = site.photograph("camera_left", noise=False)
        landing = site.projector_landing()
    assert photo.image.shape == (800, 1280, 3)
    lit = (photo.image.astype(int) - dark.image).sum(axis=2) > 60
    assert lit.mean() > 0.1
    r, g, b = (photo.image[lit].astype(int) - dark.image[lit]).T
    assert np.median(r) > 5 * max(np.median(g), 1) and np.median(b) <= 2
    assert (landing.wall_index >= 0).mean() > 0.99


def test_l_shaped_room_truth_and_laser() -> None:
    site = Site.build({"room": {"corners_m": L_ROOM}, "robot": {"wall": 0, "distance_m": 2.0}}, seed=2)
    assert len(site.walls) == 6
    # Every wall frame: origin on the floor, z into the room (a point 1 cm in front is inside the polygon).
    for wall in site.walls:
        front = wall.to_room([[wall.width_m / 2, 1.0]])[0] + 0.01 * wall.normal
        assert site.room.contains(front[:2])[0]
    scan = site.laser_scan()
    points = transform_points(site.T_room_from_robot, scan.points_robot())
    distance = site.room.distance_to_walls(points[:, :2])
    assert np.mean(distance < 0.04) > 0.98  # 4 σ of the 1 cm range noise; all but the 0.5 % outliers, with margin
    landing = site.projector_landing()
    assert np.all(landing.wall_index[400:, 640] == 0)


@pytest.mark.gl
def test_pictures_and_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                          monkeypatch: pytest.MonkeyPatch) -> None:
    small = {"cameras": {"width": 640, "height": 400}, "projector": {"width": 640, "height": 400}}
    import cv2

    from arproj.sim.patterns import expected_camera_pixels

    with Site.build(small, seed=0) as site:
        paths = write_site_pictures(site, tmp_path / "pics")
        # The test pattern's centre cross is lit; 40 px off it along the diagonal the pattern is black.
        centre = np.array([[site.projector.width // 2, site.projector.height // 2]], dtype=np.float64)
        spots = {camera: expected_camera_pixels(site, camera, np.vstack([centre, centre + 40])).round().astype(int)
                 for camera in ("camera_left", "camera_right")}
    assert [p.name for p in paths] == ["camera_left.png", "camera_right.png", "ground_truth.png", "site_plan.png"]
    for camera, ((c_lit, r_lit), (c_dark, r_dark)) in spots.items():
        photo = cv2.imread(str(tmp_path / "pics" / f"{camera}.png"), cv2.IMREAD_GRAYSCALE)
        assert photo.shape == (400, 640)
        # the saved photo shows the pattern where the projector put it (3x3 max: the cross is 3 px wide)
        lit = int(photo[r_lit - 1:r_lit + 2, c_lit - 1:c_lit + 2].max())
        assert lit > int(photo[r_dark, c_dark]) + 40
    for name in ("ground_truth.png", "site_plan.png"):
        figure = cv2.imread(str(tmp_path / "pics" / name))
        assert figure is not None and figure.shape[1] > figure.shape[0] and figure.std() > 10  # a drawing
    # A bad scene file: one line naming the key and value, exit status 2, no traceback.
    from arproj.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("robot:\n  distance_m: -1\n")
    monkeypatch.setattr(sys, "argv", ["arproj", "site", "--scene", str(bad), "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit) as done:
        main()
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert "robot.distance_m = -1.0" in err and "Traceback" not in err


@pytest.mark.gl
def test_auto_exposure_puts_the_pattern_below_clipping(gl_context: object) -> None:
    with Site.build(seed=0, ctx=gl_context) as site:
        white = np.full((site.projector.height, site.projector.width), 255, np.uint8)
        fixed = site.photograph("camera_left", white, exposure=0.2, noise=False)
        auto = site.photograph("camera_left", white, exposure="auto", noise=False)
        rng_a = site.photograph("camera_left", white, rng=np.random.default_rng(7)).image
        rng_b = site.photograph("camera_left", white, rng=np.random.default_rng(7)).image
    assert (fixed.image == 255).mean() > 0.2
    assert (auto.image == 255).mean() < 0.005 and np.percentile(auto.image, 99) > 200
    assert auto.exposure_s < 0.2
    assert np.array_equal(rng_a, rng_b)


@pytest.mark.gl
def test_interreflection_brightens_the_unlit_room_as_the_split_flux_law_says(gl_context: object) -> None:
    linear = {"gamma": 1.0, "vignetting": False, "prnu": 0.0, "exposure_s": 0.04}
    with Site.build(seed=0, ctx=gl_context, cameras=linear) as site:
        white = np.full((site.projector.height, site.projector.width), 255, np.uint8)
        dark = site.photograph("camera_left", noise=False).image[680:, :].astype(float)
        lit = site.photograph("camera_left", white, noise=False).image[680:, :].astype(float)
        area, rho = site.room.area_and_mean_albedo()
        ambient = site.room.ambient_lux
    indirect = rho * site.scene["projector"]["lumens"] / (area * (1 - rho))
    assert np.median(lit / dark) == pytest.approx((ambient + indirect) / ambient, rel=0.03)


def test_range_image_drops_depth_edges_and_grazing_surfaces() -> None:
    site = Site.build(seed=1, rangecam={"dropout_fraction": 0.0, "sigma_at_1m_m": 0.0, "step_at_1m_m": 0.0})
    T = look_at([2.5, 2.5, 1.3], [2.5, 0.0, 1.3])
    board_T = look_at([2.3, 1.5, 1.5], [2.3, 0.0, 1.5], up=(0.0, 0.0, -1.0))   # 1 m in front of the wall
    site.add_target(np.full((10, 10), 255, np.uint8), (0.4, 0.4), board_T)
    depth, intr = site.range_image(T)
    truth = site.raycast_depth(T, intr)
    edge_px = site.scene["rangecam"]["edge_dropout_px"]
    jump = np.abs(np.diff(truth, axis=1)) > 0.3                 # board silhouette, left and right sides
    rows, cols = np.nonzero(jump)
    assert len(rows) > 50
    for r, c in zip(rows, cols, strict=True):
        assert np.all(np.isnan(depth[r, max(c - edge_px + 1, 0):c + edge_px + 1]))
    valid = np.isfinite(depth)
    # no noise configured: exact where present, up to float32 at metres (~1e-7 m) and the ray cast's round-off
    assert np.allclose(depth[valid], truth[valid], atol=1e-5)
    assert valid.mean() > 0.8


@pytest.mark.gl
def test_sites_dropped_without_release_free_their_gpu_objects() -> None:
    """Sites built on the shared context queue their objects when garbage collected; drawing frees them."""
    import gc

    from arproj.sim.site import shared_context

    small = {"cameras": {"width": 320, "height": 200}, "projector": {"width": 320, "height": 200}}
    for seed in range(3):
        site = Site.build(small, seed=seed)
        site.photograph("camera_left", np.zeros((200, 320), np.uint8))
        site.place_robot(2.0, 10.0)                      # new view: re-renders, releasing replaced objects
        site.photograph("camera_left", np.full((200, 320), 255, np.uint8))
        del site
        gc.collect()
        assert len(shared_context().objects) > 20         # this site's textures, buffers, framebuffers …
        other = Site.build(small, seed=9)
        other.photograph("camera_left")                   # … are freed by the next site's drawing
        assert len(shared_context().objects) < 10         # (a few may be queued by a late cycle collection)
        other.release()


# A projected class colour, photographed by the colour camera, keeps its hue within this (HSV hue, degrees):
# the wall's albedo tint, the two gammas and the Bayer interpolation move it by about 10°.
CLASS_HUE_TOLERANCE_DEG = 15.0


def _hue_deg(rgb: np.ndarray) -> float:
    pixel = np.clip(np.rint(rgb), 0, 255).astype(np.uint8).reshape(1, 1, 3)
    return float(cv2.cvtColor(pixel, cv2.COLOR_RGB2HSV_FULL)[0, 0, 0]) * 360.0 / 256.0


def _hue_gap_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_bayer_mosaic_keeps_each_pixels_own_channel_and_demosaicing_restores_a_flat_colour() -> None:
    rgb = np.zeros((6, 8, 3), np.float32)
    rgb[...] = (1.0, 2.0, 3.0)
    mosaic = optics.bayer_mosaic(rgb)
    assert mosaic[0, 0] == 1.0 and mosaic[0, 1] == 2.0 and mosaic[1, 0] == 2.0 and mosaic[1, 1] == 3.0  # RGGB
    flat = np.full((16, 16, 3), (3000, 1200, 300), np.float32)
    restored = optics.demosaic(optics.bayer_mosaic(flat).astype(np.uint16))
    assert restored.shape == (16, 16, 3)
    assert np.array_equal(restored[2:-2, 2:-2], np.broadcast_to(np.uint16([3000, 1200, 300]), (12, 12, 3)))


@pytest.mark.gl
def test_colour_camera_keeps_the_maps_colour_code(gl_context: object) -> None:
    """Each legend colour projected as a patch is photographed (Bayer sensor with noise, demosaiced) with its
    hue, and the nearest legend hue in the photo is its own: the photo shows the colour code."""
    with Site.build(seed=0, ctx=gl_context, cameras={"color": True}) as site:
        h, w = site.projector.height, site.projector.width
        frame = np.zeros((h, w, 3), np.uint8)
        edges = np.linspace(0, w, len(LEGEND) + 1).astype(int)
        for k, (_, colour, _) in enumerate(LEGEND):
            frame[h // 4:3 * h // 4, edges[k] + 20:edges[k + 1] - 20] = colour
        lit = site.photograph("camera_left", frame).image.astype(float)
        dark = site.photograph("camera_left").image
        u, v = np.moveaxis(site.projector_pixels_seen("camera_left"), -1, 0)
    legend_hues = [_hue_deg(np.array(colour, float)) for _, colour, _ in LEGEND]
    for k, (name, _, _) in enumerate(LEGEND):
        patch = (u > edges[k] + 40) & (u < edges[k + 1] - 40) & (v > h // 4 + 20) & (v < 3 * h // 4 - 20)
        assert patch.sum() > 5000, name
        hue = _hue_deg(np.median(lit[patch] - dark[patch], axis=0))
        gaps = [_hue_gap_deg(hue, other) for other in legend_hues]
        assert gaps[k] < CLASS_HUE_TOLERANCE_DEG, (name, hue, legend_hues[k])
        assert int(np.argmin(gaps)) == k, (name, hue)
