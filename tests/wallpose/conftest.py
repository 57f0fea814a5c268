"""Fixtures for the wall-pose tests: an exact synthetic planar scene and a simulated site."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest

from geometry.poses import invert, transform_points
from tests.support.synthetic_wallpose import PlanarScene, Plane, default_views, perturbed, wall_plane
from wallpose.pattern import CheckerPattern, choose_pattern
from wallpose.rig import ViewRig


@dataclass
class SyntheticCase:
    views: ViewRig
    pattern: CheckerPattern
    plane: Plane
    scene: PlanarScene

    def photos(self, **kw: object) -> tuple[np.ndarray, np.ndarray]:
        img = self.pattern.image()
        return self.scene.photograph("camera_left", img, **kw), self.scene.photograph("camera_right", img, **kw)

    def true_centre(self) -> np.ndarray:
        """Robot-frame point where the pattern's centre really lands on the (first) plane."""
        T = self.scene.T_robot_from_projector_true
        ray = self.views.projector.rays(self.pattern.centre_px[None])[0]
        n, d = self.plane.in_frame(invert(T))
        return transform_points(T, ray * (-d / (ray @ n)))


def make_case(distance: float, incidence: float, seed: int = 0, head_error_deg: float = 0.05,
              **scene_kw: object) -> SyntheticCase:
    views = default_views()
    rng = np.random.default_rng(seed)
    plane = wall_plane(distance, incidence, views)
    T_true = perturbed(views.T_robot_from_projector, head_error_deg, 0.0005, rng)
    scene = PlanarScene(views, [plane], T_true, rng=rng, supersample=2, **scene_kw)  # type: ignore[arg-type]
    return SyntheticCase(views, choose_pattern(views, distance, incidence), plane, scene)


@pytest.fixture(scope="module")
def case_2m_30() -> SyntheticCase:
    return make_case(2.0, 30.0, seed=1)


@pytest.fixture(scope="module")
def photos_2m_30(case_2m_30: SyntheticCase) -> tuple[np.ndarray, np.ndarray]:
    return case_2m_30.photos()


@pytest.fixture(scope="module")
def sim_site(gl_context: object) -> Iterator[object]:
    """The simulated site in a room large enough for 4 m at 60°; robot 2.5 m from wall 0 at 20°."""
    from arproj.sim import Site
    from arproj.sim.wallpose_trial import LARGE_ROOM

    site = Site.build(seed=3, ctx=gl_context, room=LARGE_ROOM)
    site.place_robot(2.5, 20.0)
    yield site
    site.release()
