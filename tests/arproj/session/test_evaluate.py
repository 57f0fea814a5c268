"""Where the registration error is measured: points along the map's objects inside the beamer's image."""

from types import SimpleNamespace

import numpy as np

from arproj.session.evaluate import FEATURE_STEP_M, map_features
from geometry import Intrinsics, look_at
from mapping.mapfile import MappedObject


def test_map_features_run_along_the_objects_in_view_and_an_empty_map_has_none() -> None:
    intr = Intrinsics.from_fov(1280, 800, 60.0)
    T_wall_from_projector = look_at([1.0, 1.0, 2.0], [1.0, 1.0, 0.0], up=[0.0, 1.0, 0.0])  # 2 m in front
    cable = MappedObject("power_line", [[-2.0, 1.0], [4.0, 1.0]], 0.01)      # wider than the image
    screw = MappedObject("fastener", [[1.1, 0.9]], 0.004)
    far = MappedObject("metal_pipe", [[5.0, 1.0], [6.0, 1.0]], 0.02)        # wholly out of view
    features = map_features(SimpleNamespace(objects=[cable, screw, far]), T_wall_from_projector, intr)
    on_cable = features[np.isclose(features[:, 1], 1.0)]
    assert len(on_cable) + 1 == len(features) and [1.1, 0.9] in features.tolist()
    assert np.all(np.diff(np.sort(on_cable[:, 0])) <= FEATURE_STEP_M + 1e-9)
    # the inner 90 % of the image (pinhole, 2 m away): the cable's middle is in, its ends are out
    lo, hi = (1.0 + 2.0 * ((f * intr.width - 0.5) - intr.cx) / intr.fx for f in (0.05, 0.95))
    assert lo <= on_cable[:, 0].min() < lo + FEATURE_STEP_M and hi - FEATURE_STEP_M < on_cable[:, 0].max() <= hi
    assert map_features(SimpleNamespace(objects=[]), T_wall_from_projector, intr).shape == (0, 2)
