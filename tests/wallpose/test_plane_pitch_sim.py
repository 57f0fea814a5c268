"""The wall plane's pitch at 4 m on the simulated site (issue 20's half-pixel target): with the whole pattern
on the wall the fitted normal is right to 0.01°; with the pattern's top rows over the wall's top edge (on the
ceiling, the bench's default aim at 4 m) its tilt about the wall's horizontal axis is several times that."""

import numpy as np
import pytest

from arproj.sim.wallpose_trial import calibrated_views, photograph_pair, wall_truth
from wallpose.estimate import estimate_plane
from wallpose.pattern import choose_pattern

pytestmark = pytest.mark.gl
ROOM = {"corners_m": [[8.0, 0.0], [0.0, 0.0], [0.0, 6.0], [8.0, 6.0]]}  # arproj.bench.projection.BENCH_ROOM
MAX_PITCH_DEG = 0.03  # ≈ 2 mm at 4 m: what half a projector pixel (1.2 mm there) can spare of it


def _pitch_error_and_share_off_wall(gl_context: object, seed: int, aim_height_m: float | None) -> tuple[float, float]:
    """(the fitted normal's error about the wall's horizontal axis in degrees, share of the pattern's corners
    that land off wall 0), from the perfect rig's view at 4 m facing the wall."""
    from arproj.sim import Site

    with Site.build(seed=seed, ctx=gl_context, room=ROOM, robot={"distance_m": 4.0, "incidence_deg": 0.0}) as site:
        if aim_height_m is not None:
            site.place_robot(4.0, 0.0, aim_height_m=aim_height_m)
        views = calibrated_views(site)
        pattern = choose_pattern(views, 4.0, 0.0)
        off_wall = np.asarray(site.raycast("projector", pattern.corner_projector_px).wall_index).reshape(-1) != 0
        est = estimate_plane(*photograph_pair(site, pattern.image(), np.random.default_rng(seed)), pattern, views)
        truth = wall_truth(site)
        return float(np.degrees(est.normal[2] - truth.normal[2])), float(off_wall.mean())  # robot z is up


def test_pitch_at_4_m_with_the_pattern_on_the_wall(gl_context) -> None:
    pitch, off_wall = _pitch_error_and_share_off_wall(gl_context, 0, 1.2)
    assert off_wall == 0.0  # the case is what it claims to be
    assert abs(pitch) < MAX_PITCH_DEG


@pytest.mark.xfail(strict=True, reason="issue 20: with the pattern's top over the wall's edge the normal tilts "
                   "-0.025…-0.067° at 4 m (seeds 0-3, all corners off the wall already rejected; leaving out the "
                   "rows next to the edge does not remove it); cause not located")
def test_pitch_at_4_m_with_the_pattern_over_the_top_edge(gl_context) -> None:
    pitch, off_wall = _pitch_error_and_share_off_wall(gl_context, 0, None)
    assert off_wall > 0.1  # the bench's default aim at 4 m: the top rows land on the ceiling
    assert abs(pitch) < MAX_PITCH_DEG
