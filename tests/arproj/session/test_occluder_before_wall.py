"""A board some centimetres before the wall, holding a quarter of the pattern when the wall pose is estimated (the
bench's 'pattern occluded' kind, scene 10212): the map shown must not be off by more than the tolerance.

Before the fix a camera's corner finder refitted its homography to the corners of both surfaces at once (a
RANSAC gate of 1.5 px: wall and board are each only a pixel or so off a homography that splits the difference),
kept half of each and lost a quarter of the wall's corners; the plane fitted to what was left tilted beyond its
own 95 % bound, the closed loop (which shares that plane) saw nothing and the map was shown 10–15 mm off. On this
station and board that happened for 6 of 40 photo noise seeds run one after the other; run here, from the station's
first state, photo seed 21 showed the map 14.9 mm off; with seeds 2 and 18 the map happened to stay within the
tolerance (8.8 and 1.6 mm) but one camera had lost many of its wall corners (seed 18: the left kept 188). With the
fix both cameras keep about 340 and the map is within 3 mm on all 40 seeds.
"""

import numpy as np
import pytest

from arproj.session import scenarios
from arproj.session import tolerances as tol
from tests.support.stations import design_truth_station

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def station(gl_context):
    """The bench's design+truth station at 4 m and 30°."""
    with design_truth_station(gl_context, 4.0, 30.0) as st:
        yield st


@pytest.mark.parametrize("photo_seed", [2, 18, 21])
def test_a_board_before_the_wall_at_the_estimate_never_shows_a_wrong_map(station, photo_seed):
    x0, x1 = float(station.area_xy[:, 0].min()), float(station.area_xy[:, 0].max())
    fraction = 0.25
    left = float(np.linspace(x0 - 0.05, x1 + 0.05 - fraction * (x1 - x0 + 0.1), 5)[2])  # the middle of the area
    scene = scenarios.pattern_occluded(station, fraction, left, 0.09, True, np.random.default_rng(10))
    station.site._rng["photo"] = np.random.default_rng(photo_seed)  # the photographs' noise, whatever ran before
    o = scenarios.run_scene(station, scene)
    assert not o.unsafe, (o.magnitude, o.true_max_m, o.bound_m, o.reasons)
    assert o.show_map or o.reasons
    reg = station.session.registration
    if o.show_map:
        assert reg is not None and o.true_max_m <= tol.REGISTRATION_TOLERANCE_M
        # both cameras found the wall's corners, not one of them a quarter fewer (the board took its homography)
        plane = reg.plane
        assert min(plane.corners_left, plane.corners_right) > 0.9 * max(plane.corners_left, plane.corners_right)
    assert not station.site.targets  # the board was taken away again
