"""The wall plane's pitch at 4 m on the simulated site with the perfect rig (issue 20's half-pixel target). In a room
tall enough that the whole pattern lands on the wall: aimed at 1.2 m (the head almost level) the fitted normal is
right to 0.01° (seeds 1-3; seed 0: -0.033°); aimed at the scene's 1.4 m (the head tilted up 1.7-2.3°) it tilted
about the wall's horizontal axis by up to 0.055° (seeds 0-3: -0.035, -0.014, -0.055, -0.005°), a 0.01-0.02 px trend
of the corners' disparity over the image rows that the 0.2 m stereo baseline turns into the tilt; with neither lens
distorting it was right to 0.005°. The trend came from the simulated cameras, which took one bilinear sample of the
pinhole render at each pixel's centre through the lens's warp; averaged over each pixel's area
(arproj.sim.optics.CameraModel.to_sensor) the same seeds give -0.023, -0.018, -0.026, +0.004°: within the 0.03°
below, though a smaller common tilt of about -0.02° is left (not located).

These figures are for a level robot, and the tests keep it level (robot.floor_tilt_sigma_deg 0) so that only the
head's aim changes between them. On the default tilted floor (seed 2: roll -0.05°, pitch -0.04°; the head then
aims 0.04° lower) the same fits read +0.017° without lens distortion and -0.033° with it, both well inside the
fit's own 95 % bound (0.12°); with the floor tilted 0.3° / 1.0° (σ) -0.021° / -0.011° without distortion: not
growing with the tilt (no frame mix-up), the same unlocated residual at a slightly different geometry."""

import numpy as np
import pytest

from arproj.sim.wallpose_trial import calibrated_views, photograph_pair, wall_truth
from wallpose.estimate import estimate_plane
from wallpose.pattern import choose_pattern

pytestmark = pytest.mark.gl
# arproj.bench.projection.BENCH_ROOM, 3.4 m high instead of 2.6 m: no corner lands on the ceiling
TALL_ROOM = {"corners_m": [[8.0, 0.0], [0.0, 0.0], [0.0, 6.0], [8.0, 6.0]], "height_m": 3.4}
MAX_PITCH_DEG = 0.03  # ≈ 2 mm at 4 m: what half a projector pixel (1.2 mm there) can spare of it
SEED = 2


def _pitch_error_deg(gl_context: object, aim_height_m: float | None, **scene: object) -> float:
    """The fitted normal's error about the wall's horizontal axis (degrees), the perfect rig at 4 m facing the
    wall, aimed at aim_height_m (None: the scene's default); scene: more section overrides."""
    from arproj.sim import Site

    with Site.build(seed=SEED, ctx=gl_context, room=TALL_ROOM,
                    robot={"distance_m": 4.0, "incidence_deg": 0.0, "floor_tilt_sigma_deg": 0.0}, **scene) as site:
        if aim_height_m is not None:
            site.place_robot(4.0, 0.0, aim_height_m=aim_height_m)
        views = calibrated_views(site)
        pattern = choose_pattern(views, 4.0, 0.0)
        assert np.all(np.asarray(site.raycast("projector", pattern.corner_projector_px).wall_index) == 0)
        est = estimate_plane(*photograph_pair(site, pattern.image(), np.random.default_rng(SEED)), pattern, views)
        return float(np.degrees(est.normal[2] - wall_truth(site).normal[2]))  # robot z is up


def test_pitch_at_4_m_aimed_level(gl_context) -> None:
    assert abs(_pitch_error_deg(gl_context, 1.2)) < MAX_PITCH_DEG


def test_pitch_at_4_m_aimed_at_the_scene_height_without_lens_distortion(gl_context) -> None:
    no_distortion = {"dist": [0.0, 0.0, 0.0, 0.0, 0.0]}
    assert abs(_pitch_error_deg(gl_context, None, cameras=no_distortion, projector=no_distortion)) < 0.01


def test_pitch_at_4_m_aimed_at_the_scene_height(gl_context) -> None:
    assert abs(_pitch_error_deg(gl_context, None)) < MAX_PITCH_DEG
