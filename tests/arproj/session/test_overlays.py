"""Bands, DIN zones, drill-point check and legend, checked against exact geometry."""

import itertools

import cv2
import numpy as np
import pytest

from arproj.session import overlays
from arproj.session import tolerances as tol
from arproj.session.wallmap import WallMap, plane_mesh
from mapping.evidence import Coverage
from mapping.grid import GridInfo
from mapping.mapfile import MappedObject as MapObject


def _wall(objects, covered_x_from=0.0):
    """A 3 × 2.5 m wall whose scan covered everything right of covered_x_from (every channel, no response)."""
    coverage = Coverage.complete(GridInfo.covering(0.0, 0.0, 3.0, 2.5, 0.004))
    xs, _ = coverage.info.cell_centres()
    for layer in coverage.covered.values():
        layer[:, xs < covered_x_from] = False
    return WallMap(plane_mesh(0, 0, 3.0, 2.5), objects, coverage=coverage)


CABLE = MapObject("power_line", np.array([[1.0, 0.0], [1.0, 2.5]]), 0.008, 1.0, 0.002)
PIPE = MapObject("metal_pipe", np.array([[0.0, 1.5], [3.0, 1.5]]), 0.018, 1.0, 0.002)
CAVITY = MapObject("cavity", np.array([[2.0, 0.2], [2.5, 0.2], [2.5, 0.8], [2.0, 0.8]]), 0.0, 0.9, 0.003)


@pytest.mark.parametrize("registration_sigma_m", [0.0, 0.004])
def test_band_holds_the_whole_object_plus_margin_in_95_percent_of_placements(registration_sigma_m):
    # Where the cable really is: the mapped line, off by the map's and the registration's independent errors.
    rng = np.random.default_rng(5)
    n = 40_000
    offset = rng.normal(0, CABLE.sigma_m, n) + rng.normal(0, registration_sigma_m, n)
    far_edge = np.abs(offset) + 0.5 * CABLE.width_m  # the cable's edge farthest from the drawn centre line
    inside = far_edge + tol.BASE_SAFETY_MARGIN_M <= overlays.band_half_width_m(CABLE, registration_sigma_m)
    # 95 % coverage, neither less (unsafe) nor much more (a band wider than the evidence asks); the binomial
    # standard deviation at n = 40,000 is 0.1 %, so ±0.5 % is five of them.
    assert inside.mean() == pytest.approx(0.95, abs=0.005)


def test_drawn_band_has_the_computed_width_and_class_colour():
    wall = _wall([CABLE])
    raster = overlays.draw_map(wall, 0.003, show_zones=False)
    row = raster.image[int(raster.image.shape[0] * 0.3), :, :]  # off the middle, where its depth label is
    lit = np.flatnonzero(row[:, 3] > 0)
    width_m = (lit.max() - lit.min() + 1) / raster.px_per_m
    assert width_m == pytest.approx(2 * overlays.band_half_width_m(CABLE, 0.003), abs=2.5 / raster.px_per_m)
    centre_col = round(raster.to_px(np.array([[1.0, 1.0]]))[0, 0])
    assert tuple(row[centre_col, :3]) == overlays.CLASS_COLOR["power_line"]
    assert np.mean(lit) / raster.px_per_m == pytest.approx(1.0, abs=1.0 / raster.px_per_m)


def test_class_colours_are_distinct():
    colours = np.array([c for _, c, _ in overlays.LEGEND], dtype=float)
    d = np.linalg.norm(colours[:, None] - colours[None], axis=-1)
    assert d[~np.eye(len(colours), dtype=bool)].min() > 100


def test_drill_check_distances_and_verdicts():
    wall = _wall([CABLE, PIPE, CAVITY])
    check = overlays.check_drill_point(wall, np.array([1.1, 0.5]), 0.002)
    assert check.nearest is CABLE
    assert check.distance_m == pytest.approx(0.1 - 0.004)
    assert check.verdict == overlays.VERDICT_SAFE
    near = overlays.check_drill_point(wall, np.array([1.02, 0.5]), 0.002)
    assert near.verdict == overlays.VERDICT_KEEP_AWAY and near.distance_m == pytest.approx(0.016)
    inside = overlays.check_drill_point(wall, np.array([2.2, 0.5]), 0.002)
    assert inside.nearest is CAVITY and inside.distance_m == 0.0 and inside.verdict == overlays.VERDICT_KEEP_AWAY
    below_pipe = overlays.check_drill_point(wall, np.array([0.5, 1.45]), 0.002)
    assert below_pipe.nearest is PIPE and below_pipe.distance_m == pytest.approx(0.05 - 0.009)


def test_unscanned_point_is_unknown_and_zones_drawn_only_there():
    wall = _wall([], covered_x_from=1.5)
    assert overlays.check_drill_point(wall, np.array([0.5, 1.0]), 0.002).verdict == overlays.VERDICT_UNKNOWN
    assert overlays.check_drill_point(wall, np.array([2.0, 1.0]), 0.002).verdict == overlays.VERDICT_SAFE
    raster = overlays.draw_map(wall, 0.002)
    lit = raster.image[..., 3] > 0

    def lit_at(x, y):
        c, r = np.round(raster.to_px(np.array([[x, y]]))[0]).astype(int)
        return bool(lit[r - 6:r + 7, c - 6:c + 7].any())

    assert lit_at(0.7, 2.5 - 0.30)       # top zone (0.15–0.45 m below the ceiling), unscanned half
    assert lit_at(0.7, 0.30)             # bottom zone
    assert lit_at(0.2, 1.2)              # vertical zone beside the left corner (0.10–0.30 m)
    assert not lit_at(0.7, 1.2)          # no zone here
    assert not lit_at(2.2, 0.30)         # scanned half: the scan, not the zone, tells


def test_din_zones_follow_the_standard_distances():
    zones = overlays.din_zones(0.0, 0.0, 4.0, 2.5, openings=[(1.0, 0.0, 1.9, 2.0)])
    assert (0.0, pytest.approx(2.05), 4.0, pytest.approx(2.35)) == zones[0]
    assert zones[1] == (0.0, 0.15, 4.0, 0.45)
    assert zones[2] == (0.1, 0.0, 0.3, 2.5)
    assert zones[4] == (pytest.approx(0.7), 0.0, pytest.approx(0.9), 2.5)  # beside the door's left edge


def test_legend_and_warning_are_drawn():
    frame = np.zeros((800, 1280, 3), np.uint8)
    overlays.draw_legend(frame, ["registered ±1.2 mm"])
    for _, colour, _ in overlays.LEGEND:
        assert np.any(np.all(frame == colour, axis=-1))
    warning = overlays.warning_frame(1280, 800, ["robot moved 12 mm"])
    assert tuple(warning[5, 640]) == (255, 40, 40)
    assert warning[:, :, 0].mean() > warning[:, :, 2].mean()


@pytest.mark.parametrize("size", [(1280, 800), (640, 400), (320, 240)])
def test_warning_text_stays_inside_the_border_however_long(size):
    """Every message of the gate at once, on frames down to 320 x 240: no text on or beyond the red border."""
    from arproj.session import gate

    w, h = size
    messages = [gate.SAY_NO_WALL_POSE, gate.SAY_HEAD_SILENT, gate.SAY_ROBOT_MOVED, gate.SAY_PATTERN_HIDDEN,
                gate.SAY_RIG, gate.SAY_LASER, "The picture may be up to 12 mm off. Wait until this warning goes."]
    frame = overlays.warning_frame(w, h, messages)
    border = max(8, min(w, h) // 40)
    text = np.any(frame != (255, 40, 40), axis=-1) & np.any(frame > 0, axis=-1)  # lit, not border red
    rows, cols = np.nonzero(text)
    assert rows.size > 0
    assert cols.min() > border and cols.max() < w - border and rows.min() > border and rows.max() < h - border
    # The same frame without messages has less text: the messages were drawn, not dropped.
    assert text.sum() > 2 * (np.any(overlays.warning_frame(w, h, []) != (255, 40, 40), axis=-1)
                             & np.any(overlays.warning_frame(w, h, []) > 0, axis=-1)).sum()


@pytest.mark.parametrize("size", [(1280, 800), (640, 400)])
def test_map_frame_words_are_the_craftsmans_and_stay_inside_the_frame(size):
    """Every status line the map frame can carry, at once: plain words (no device URL, ASCII), wrapped so the
    legend box and each line's text lie inside the frame."""
    w, h = size
    check = overlays.check_drill_point(_wall([CABLE]), np.array([1.003, 1.0]), 0.001)
    lines = [overlays.say_accuracy(0.0023), overlays.say_accuracy(0.012, [0, 2]), overlays.say_clipped(0.8),
             overlays.say_zones(), overlays.say_dark_walls([1, 3]), overlays.say_drill(check)]
    assert lines[0] == "Picture accurate to 2.3 mm." and lines[1] == "Picture accurate to 12 mm on wall 0, 2."
    assert "keep away" in lines[-1]
    for line in lines:
        # OpenCV's Hershey font draws only ASCII ('±' would reach the wall as '??')
        assert "://" not in line and line.isascii() and line[0].isupper(), line
    layout = overlays.legend_layout((h, w, 3), lines, ("power_line",))
    x, y, box_w, box_h = layout.box
    assert x >= 0 and y >= 0 and x + box_w < w and y + box_h < h
    text_x = x + int(48 * layout.scale)
    for text, _, _ in layout.entries:
        (tw, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, layout.scale, layout.thickness)
        assert text_x + tw <= x + box_w, text
    status = [t for t, _, swatch in layout.entries if not swatch]
    assert " ".join(status).split() == " ".join(lines).split()  # long lines wrapped, no word dropped
    assert [t for t, _, swatch in layout.entries if swatch] == ["power line / live"]


def test_map_is_drawn_only_inside_the_trusted_polygon():
    wall = _wall([CABLE, PIPE])
    clip = np.array([[0.5, 0.5], [1.8, 0.5], [1.8, 2.0], [0.5, 2.0]])
    raster = overlays.draw_map(wall, 0.002, show_zones=False, clip=clip)

    def lit_at(x, y):
        c, r = np.round(raster.to_px(np.array([[x, y]]))[0]).astype(int)
        return bool(raster.image[r, c, 3] > 0)

    assert lit_at(1.0, 1.0) and lit_at(1.2, 1.5)   # cable and pipe inside
    assert not lit_at(1.0, 0.2) and not lit_at(2.5, 1.5)  # the same objects outside: not drawn


def test_an_object_with_a_depth_gets_a_label_beside_its_band():
    deep = MapObject("metal_pipe", np.array([[0.5, 1.2], [2.5, 1.2]]), 0.018, 1.0, 0.002, depth_m=0.032)
    flat = MapObject("metal_pipe", np.array([[0.5, 1.2], [2.5, 1.2]]), 0.018, 1.0, 0.002)
    with_label = overlays.draw_map(_wall([deep]), 0.002, show_zones=False).image
    without = overlays.draw_map(_wall([flat]), 0.002, show_zones=False).image
    changed = np.any(with_label != without, axis=2)
    rows, cols = np.nonzero(changed)
    raster = overlays.empty_raster((0.0, 0.0, 3.0, 2.5))
    ys = raster.y1 - (rows + 0.5) / raster.px_per_m
    xs = raster.x0 + (cols + 0.5) / raster.px_per_m
    band = overlays.band_half_width_m(deep, 0.002)
    # only the label differs: above the band, within a label height of it, around the pipe's middle
    assert changed.any()
    assert ys.min() > 1.2 + band and ys.max() < 1.2 + band + 2.2 * overlays.DEPTH_LABEL_HEIGHT_M
    assert abs(0.5 * (xs.min() + xs.max()) - 1.5) < 0.02


def test_din_zones_come_from_the_room_floor_ceiling_corners_openings_and_sockets():
    # The map's frame lies 0.5 m right of the room's corner and 0.3 m above the floor, the room 2.7 m high: the
    # zones lie where the room puts them, not at the map's edges.
    from types import SimpleNamespace

    from arproj.session.wallmap import wall_room_in_room
    from geometry.poses import make_pose
    from wallpose.pose import wall_frames

    wall = _wall([], covered_x_from=2.6)  # scanned only at the right end
    corners = np.array([[4.0, 0.0], [0.0, 0.0], [0.0, 3.0], [4.0, 3.0]])
    T_room_from_wall = wall_frames(corners)[0][0] @ make_pose(None, [0.5, 0.3, 0.0])
    door = SimpleNamespace(kind="door", outline_m=np.array([[1.2, -0.3], [2.0, -0.3], [2.0, 1.8], [1.2, 1.8]]))
    wall.room = wall_room_in_room(T_room_from_wall, corners, 2.7, 0, [door], np.array([[0.8, 0.0]]))
    assert wall.room.floor_y_m == pytest.approx(-0.3) and wall.room.ceiling_y_m == pytest.approx(2.4)
    assert wall.room.corner_x_m == (pytest.approx(-0.5), pytest.approx(3.5))
    raster = overlays.draw_map(wall, 0.002)
    zone = overlays.zone_mask(wall, raster)

    def at(x, y):
        c, r = np.round(raster.to_px(np.array([[x, y]]))[0]).astype(int)
        return bool(zone[r, c])

    assert at(0.1, 2.0) and not at(0.1, 2.3)   # the top zone 0.15–0.45 m below the ceiling (2.4), not the map's top
    assert at(0.1, 0.05) and not at(0.1, 0.3)  # the bottom zone 0.15–0.45 m above the floor (-0.3), not the map's foot
    assert not at(0.2, 1.2)                 # no corner zone at the map's left edge: the room's corner is at -0.5
    assert at(1.0, 1.2) and at(2.2, 1.2) and at(1.6, 1.8 + 0.2)    # beside and above the door
    assert at(0.8, 1.2) and at(0.72, 1.2) and not at(0.5, 1.2)     # the socket's vertical strip (±0.10 m)
    assert not at(2.7, 1.2) and not at(2.95, 2.4 - 0.3)            # scanned: the scan tells, not the zone
    assert raster.zone_texels == int(zone.sum()) > 0 and raster.zone_labels >= 1
    # never drawn as safe: a zone's texels are the white hatch or its words, not the safe verdict's green
    assert not np.all(raster.image[zone][:, :3] == overlays.VERDICT_COLOR[overlays.VERDICT_SAFE], axis=1).any()


@pytest.mark.parametrize("obj", [
    MapObject("power_line", np.array([[1.0, -0.3], [1.0, 1.2], [2.2, 2.8]]), 0.008, 1.0, 0.002),  # leaves the wall
    MapObject("cavity", np.array([[-0.02, 0.5], [3.02, 0.5], [3.02, 3.0], [-0.02, 3.0]]), 0.0, 0.9, 0.003),  # past 3
    MapObject("fastener", np.array([[2.99, 0.01]]), 0.01, 0.9, 0.002)])  # in a corner
def test_distance_field_window_holds_every_texel_within_reach(obj):
    # drawn over a window only (speed): the window's distances must be those over the whole raster, and every
    # texel outside it beyond reach
    raster = overlays.empty_raster((0.0, 0.0, 3.0, 2.5), px_per_m=100.0)
    reach = 0.05
    field, window = overlays._distance_field(raster, obj, reach)
    h, w = raster.image.shape[:2]
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    p = np.column_stack([raster.x0 + cols.ravel() / raster.px_per_m, raster.y1 - rows.ravel() / raster.px_per_m])
    pts = np.concatenate([obj.points_m, obj.points_m[:1]]) if obj.is_outline else obj.points_m
    pairs = list(itertools.pairwise(pts)) or [(pts[0], pts[0])]
    exact = np.min([np.linalg.norm(p - (a + np.clip((p - a) @ (b - a) / max((b - a) @ (b - a), 1e-18), 0, 1)[:, None]
                                        * (b - a)), axis=1) for a, b in pairs], axis=0).reshape(h, w)
    full = np.full((h, w), np.inf, np.float32)
    full[window] = field
    near = exact <= reach - 1e-6
    assert near.any()
    np.testing.assert_allclose(full[near], exact[near], atol=1e-6)
    outside = np.ones((h, w), bool)
    outside[window] = False
    assert not (outside & near).any()


def test_scanned_mask_is_the_coverage_cell_of_every_texel():
    # a coverage grid offset from the raster and smaller than it, covered right of x = 0.9 m
    coverage = Coverage.complete(GridInfo.covering(0.31, -0.2, 2.5, 2.2, 0.007))
    xs, _ = coverage.info.cell_centres()
    for layer in coverage.covered.values():
        layer[:, xs < 0.9] = False
    wall = WallMap(plane_mesh(0, 0, 3.0, 2.5), [], coverage=coverage)
    raster = overlays.empty_raster(wall.extent, px_per_m=100.0)
    h, w = raster.image.shape[:2]
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    r, c, inside = coverage.info.cell_of(np.column_stack([raster.x0 + cols.ravel() / raster.px_per_m,
                                                          raster.y1 - rows.ravel() / raster.px_per_m]))
    expected = np.zeros(h * w, bool)
    expected[inside] = coverage.covered_by_all()[r[inside], c[inside]]
    mask = overlays.scanned_mask(wall, raster)
    assert 0.2 < mask.mean() < 0.8
    np.testing.assert_array_equal(mask, expected.reshape(h, w))
