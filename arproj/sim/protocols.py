"""What the trials, the session's simulated robot and the truth checks use of a site, as protocols: the simulated
Site has all of it, and a real site (surveyed) or a recorded one can be given in its place by providing the same.

SiteTruth is what estimates are judged against (the room's walls, where the robot, its cameras and its projector
really are, where a projector pixel really lands); RobotSite adds the robot on the site as the session and the
trials drive it (its head, cameras, laser and localization).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from geometry.head import HeadModel
from geometry.intrinsics import Intrinsics

if TYPE_CHECKING:
    from arproj.sim.optics import CameraModel
    from arproj.sim.site import LaserScan, Photo, Site, Truth


class SiteWall(Protocol):
    """One wall of the room: its frame in the room (x along, y up, z out of the wall) and its size."""

    @property
    def T_room_from_wall(self) -> NDArray[np.float64]: ...

    @property
    def width_m(self) -> float: ...

    @property
    def height_m(self) -> float: ...


class SiteTruth(Protocol):
    """The truth of a site: the walls, the robot's true pose in the room, its rig as it really is, and where
    a pixel's ray really lands (Truth per pixel)."""

    @property
    def walls(self) -> Sequence[SiteWall]: ...

    @property
    def T_room_from_robot(self) -> NDArray[np.float64]: ...

    @property
    def T_robot_from_projector(self) -> NDArray[np.float64]: ...

    @property
    def T_robot_from_camera_left(self) -> NDArray[np.float64]: ...

    @property
    def T_camera_right_from_camera_left(self) -> NDArray[np.float64]: ...

    @property
    def camera_left(self) -> Intrinsics: ...

    @property
    def camera_right(self) -> Intrinsics: ...

    @property
    def projector(self) -> Intrinsics: ...

    def raycast(self, frame: str, pixels: ArrayLike) -> Truth:
        """The truth at pixels (n, 2) of frame ("projector", "camera_left", "camera_right")."""
        ...


class RobotSite(SiteTruth, Protocol):
    """A site with the projection robot on it: the head (true and nominal kinematics, its angle bias, the
    commanded angles), photographs, the laser and the robot's own localization."""

    @property
    def head(self) -> HeadModel: ...

    @property
    def head_nominal(self) -> HeadModel: ...

    @property
    def head_angle_bias_deg(self) -> NDArray[np.float64]: ...

    @property
    def head_angles_cmd_deg(self) -> NDArray[np.float64]: ...

    @property
    def localized_T_room_from_robot(self) -> NDArray[np.float64]: ...

    @property
    def scene(self) -> Mapping[str, Any]:
        """The site's description; scene["robot"] holds localization_sigma_m and localization_sigma_deg."""
        ...

    @property
    def camera_models(self) -> Mapping[str, CameraModel]: ...

    def set_head(self, cmd_deg: ArrayLike) -> NDArray[np.float64]: ...

    def photograph(self, camera: str, projector_image: NDArray | None = None,
                   exposure: float | str | None = None, *, rng: np.random.Generator | None = None) -> Photo: ...

    def render_radiance(self, camera: str, projector_image: NDArray | None = None) -> NDArray[np.float32]: ...

    def laser_scan(self) -> LaserScan: ...


if TYPE_CHECKING:
    def _the_simulated_site_is_a_robot_site(site: Site) -> RobotSite:
        return site  # the type checker compares Site with every member above
