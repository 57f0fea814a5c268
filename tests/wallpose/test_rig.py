"""ViewRig from a calibrated rig folder: the poses it derives, and a rig without a head model refused."""

import numpy as np
import pytest

from geometry.errors import InputError
from geometry.head import HeadModel
from geometry.poses import invert
from geometry.rig import Rig
from tests.support.synthetic_wallpose import default_views
from wallpose.rig import ViewRig


def test_view_rig_from_a_calibrated_rig_folder(tmp_path) -> None:
    views = default_views()
    head = HeadModel(axes=np.eye(3)[[2, 1, 0]], points=np.zeros((3, 3)),
                     T_robot_from_projector_zero=views.T_robot_from_projector)
    rig = Rig(intrinsics={"camera_left": views.camera_left, "camera_right": views.camera_right,
                          "projector": views.projector},
              poses={"T_robot_from_camera_left": views.T_robot_from_camera_left,
                     "T_camera_right_from_camera_left": views.T_camera_right_from_camera_left}, head=head)
    rig.save(tmp_path)
    loaded = ViewRig.from_rig(Rig.load(tmp_path), [0.0, 0.0, 0.0])
    assert np.allclose(loaded.T_camera_left_from_projector, views.T_camera_left_from_projector, atol=1e-9)
    assert np.allclose(loaded.T_robot_from_camera_right, views.T_robot_from_camera_left
                       @ invert(views.T_camera_right_from_camera_left), atol=1e-9)
    rig.head = None
    with pytest.raises(InputError, match="head model"):
        ViewRig.from_rig(rig, [0, 0, 0])
