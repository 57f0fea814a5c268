"""A small, exact stand-in scene: the projector's image on one or more planes, photographed by a camera.

Independent of arproj.sim on purpose: the warp is the exact plane homography (distortion-free views only), so
tests of the estimator check it against geometry that shares no code with it. The projector's pixels are
interpolated bilinearly (as a slightly soft lens would show them; hard pixel edges sampled on a grid alias into
corner biases of a tenth of a pixel). Camera effects: supersampling (area integration of each pixel), Gaussian
blur, ambient light, gain, sensor noise and clipping.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, look_at, make_pose, rotation_about
from wallpose.rig import ViewRig


@dataclass
class Plane:
    """A plane in the robot frame: unit normal into the room (towards the robot) and offset, n·X = -distance."""

    normal: NDArray[np.float64]
    distance: float

    def in_frame(self, T_frame_from_robot: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        """(normal, distance) of the same plane in another frame."""
        n = T_frame_from_robot[:3, :3] @ self.normal
        return n, float(self.distance - n @ T_frame_from_robot[:3, 3])


@dataclass
class PlanarScene:
    """views: the nominal rig; T_robot_from_projector_true: where the projector really is (head error)."""

    views: ViewRig
    planes: list[Plane]
    T_robot_from_projector_true: NDArray[np.float64]
    blur_sigma_px: float = 0.7
    noise_sigma: float = 2.0
    ambient: float = 20.0
    gain: float = 0.8
    supersample: int = 3
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))

    def _homography(self, cam: Intrinsics, T_cam_from_robot: NDArray, plane: Plane,
                    proj: Intrinsics) -> NDArray[np.float64]:
        """Camera pixel -> projector pixel for one plane (3x3)."""
        T_proj_from_cam = invert(self.T_robot_from_projector_true) @ invert(T_cam_from_robot)
        n_c, d_c = plane.in_frame(T_cam_from_robot)
        R, t = T_proj_from_cam[:3, :3], T_proj_from_cam[:3, 3]
        # a camera point X on n·X = -d: X_proj = R X + t = (R - t n^T / d) X
        return proj.K @ (R - np.outer(t, n_c) / d_c) @ np.linalg.inv(cam.K)

    def photograph(self, camera: str, projector_image: NDArray[np.uint8],
                   occluder: NDArray[np.float64] | None = None, exposure: float = 1.0) -> NDArray[np.uint8]:
        """The camera's 8-bit grey image of the lit planes; occluder: (k, 2) polygon in camera pixels."""
        cam = self.views.camera(camera)
        proj = self.views.projector
        if cam.has_distortion or proj.has_distortion:
            raise InputError("the synthetic planar scene renders distortion-free views only")
        T_robot_from_cam = self.views.T_robot_from_camera_left if camera == "camera_left" \
            else self.views.T_robot_from_camera_right
        T_cam_from_robot = invert(T_robot_from_cam)
        s = self.supersample
        big = cam.scaled(s)
        light = projector_image.astype(np.float32)
        rays = _pixel_rays(big)
        image = np.zeros((big.height, big.width), np.float32)
        nearest = np.full((big.height, big.width), np.inf, np.float32)
        for plane in self.planes:
            n_c, d_c = plane.in_frame(T_cam_from_robot)
            lam = (-d_c / (rays @ n_c)).astype(np.float32)
            lam[lam <= 0] = np.inf
            H = self._homography(big, T_cam_from_robot, plane, proj)
            lit = cv2.warpPerspective(light, H, (big.width, big.height),
                                      flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0.0)
            closer = lam < nearest
            image[closer] = lit[closer]
            nearest[closer] = lam[closer]
        image[~np.isfinite(nearest)] = 0.0
        image = cv2.resize(image, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        if self.blur_sigma_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.blur_sigma_px)
        image = exposure * (self.ambient + self.gain * image)
        if occluder is not None:
            mask = np.zeros(image.shape, np.uint8)
            cv2.fillPoly(mask, [np.round(occluder).astype(np.int32)], 1)
            image[mask > 0] = 60.0 * exposure
        image = image + self.rng.normal(0.0, self.noise_sigma, image.shape)
        return np.clip(np.round(image), 0, 255).astype(np.uint8)


def _pixel_rays(intr: Intrinsics) -> NDArray[np.float32]:
    """(h, w, 3) unit-z rays of every pixel of a distortion-free camera."""
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float32), np.arange(intr.height, dtype=np.float32))
    return np.dstack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)])


def default_views() -> ViewRig:
    """A rig like the simulated site's defaults: 1280x800 projector above two 1280x800 cameras 0.2 m apart.

    Robot frame: x forward, y left, z up (REP 103). Cameras and projector look along +x at zero head angles.
    """
    camera = Intrinsics.from_fov(1280, 800, 62.0)
    projector = Intrinsics.from_fov(1280, 800, 42.0, cy=760.0)  # lens shift: image above the axis
    T_robot_from_left = look_at([0.0, 0.1, 1.0], [5.0, 0.1, 1.0])
    T_robot_from_right = look_at([0.0, -0.1, 1.0], [5.0, -0.1, 1.0])
    T_robot_from_projector = look_at([0.02, 0.0, 1.18], [5.0, 0.0, 1.18])
    return ViewRig(camera_left=camera, camera_right=camera, projector=projector,
                   T_robot_from_camera_left=T_robot_from_left,
                   T_camera_right_from_camera_left=invert(T_robot_from_right) @ T_robot_from_left,
                   T_robot_from_projector=T_robot_from_projector)


def wall_plane(distance_m: float, incidence_deg: float, views: ViewRig) -> Plane:
    """The wall distance_m ahead of the projector along its axis, turned by incidence_deg about vertical."""
    T = views.T_robot_from_projector
    axis = T[:3, 2] * np.array([1.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    centre = T[:3, 3] + distance_m * axis
    normal = rotation_about([0.0, 0.0, 1.0], np.radians(incidence_deg)) @ (-axis)
    return Plane(normal=normal, distance=float(-normal @ centre))


def perturbed(T: NDArray[np.float64], rotation_deg: float, translation_m: float,
              rng: np.random.Generator) -> NDArray[np.float64]:
    """T composed with a random rotation of rotation_deg (about a random axis) and translation of translation_m."""
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    dT = make_pose(rotation_about(axis, np.radians(rotation_deg)),
                   translation_m * direction / np.linalg.norm(direction))
    return T @ dT
