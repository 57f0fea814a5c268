"""What the session talks to: cameras, beamer, head, laser and a prior for the wall frame.

Two implementations with one interface: SimulatedRobot (the simulated site, its head reached through the
Pelco-D head simulator over socket:// — the real driver's code path) and HardwareRobot (OpenCV cameras, the
beamer window, a head at a serial URL).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from arproj.session.output import FrameOutput
from devices.pelco_d import PanTiltHead
from devices.sim import HeadFaults, HeadSimulator
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert
from geometry.rig import Rig

if TYPE_CHECKING:
    from arproj.sim.protocols import RobotSite


class RobotIO(Protocol):
    head: PanTiltHead | None

    def capture(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Show frame on the beamer and photograph it with both cameras: (left, right) images."""
        ...

    def show(self, frame: NDArray[np.uint8]) -> None: ...

    def laser_points(self) -> NDArray[np.float64] | None:
        """The current 2D laser scan, (n, 3) robot-frame points in metres, or None without a laser."""
        ...

    def wall_prior(self) -> tuple[NDArray[np.float64], float, str]:
        """(T_wall_from_robot prior, its in-plane σ in metres, where it comes from)."""
        ...

    def close(self) -> None: ...


TRUTH_PRIOR = "sim truth (in-plane)"  # SimulatedRobot.wall_prior's source with prior="truth"


class SimulatedRobot:
    """The simulated site as the session's robot. The head is commanded over Pelco-D to a HeadSimulator; the
    site's head then moves to the simulator's physical angles (its own bias, noise and backlash on top).

    prior: "measured" (default) estimates the full wall pose with the wall-pose package (plane + localization +
    floor + laser scan of the room); "truth" gives the in-plane part of the wall frame exactly (to isolate the
    projection from the wall pose); "localization" uses the robot's noisy localization alone.
    """

    def __init__(self, site: RobotSite, wall_index: int, head_sim: HeadSimulator, head: PanTiltHead,
                 output: FrameOutput | None = None, prior: str = "measured") -> None:
        self.site = site
        self.wall_index = int(wall_index)
        self.head_sim = head_sim
        self.head = head
        self.output = output
        self.prior = prior
        self._synced: tuple[float, float] | None = None
        self.wall = site.walls[self.wall_index]

    @classmethod
    def on_site(cls, site: RobotSite, wall_index: int = 0, output: FrameOutput | None = None, prior: str = "measured",
                *, seed: int = 0, head_faults: HeadFaults | None = None, head_speed_deg_s: float | None = None,
                timeout_s: float = 0.2, retries: int = 3, settle_timeout_s: float = 3.0) -> SimulatedRobot:
        """The robot on `site`, its head a HeadSimulator (seeded; `head_faults` injected; `head_speed_deg_s`,
        None: the simulator's own) started at the angles the site's head is commanded to, and reached over
        Pelco-D on socket:// with these timeouts, as a real head is."""
        speed = {} if head_speed_deg_s is None else {"speed_deg_s": head_speed_deg_s}
        head_sim = HeadSimulator(faults=head_faults, seed=seed, **speed,
                                 initial_deg=tuple(float(a) for a in site.head_angles_cmd_deg[:2]))
        head = PanTiltHead(head_sim.url, timeout_s=timeout_s, retries=retries, settle_timeout_s=settle_timeout_s)
        return cls(site, wall_index, head_sim, head, output, prior)

    def sync_head(self) -> None:
        """Move the site's head to where the simulated head physically is (slip included)."""
        true = self.head_sim.true_deg()
        if self._synced is None or not np.allclose(true, self._synced, atol=1e-9):
            self.site.set_head([true[0], true[1], 0.0])
            self._synced = true

    def capture(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        self.sync_head()
        self.show(frame)
        left = self.site.photograph("camera_left", projector_image=frame).image
        right = self.site.photograph("camera_right", projector_image=frame).image
        return left, right

    def show(self, frame: NDArray[np.uint8]) -> None:
        if self.output is not None:
            self.output.show(frame)

    def laser_points(self) -> NDArray[np.float64]:
        return self.site.laser_scan().points_robot()

    def full_pose_inputs(self) -> tuple | None:
        """(room map, wall index, localized T_room_from_robot, σ m, σ deg) for the wall-pose package's full
        estimate (plane + localization + floor + laser), or None when the in-plane part comes from truth."""
        if self.prior != "measured":
            return None
        from arproj.sim.wallpose_trial import room_map

        r = self.site.scene["robot"]
        return (room_map(self.site), self.wall_index, self.site.localized_T_room_from_robot,
                float(r["localization_sigma_m"]), float(r["localization_sigma_deg"]))

    def wall_prior(self) -> tuple[NDArray[np.float64], float, str]:
        T_wall_from_room = invert(self.wall.T_room_from_wall)
        if self.prior == "truth":
            return T_wall_from_room @ self.site.T_room_from_robot, 0.0, TRUTH_PRIOR
        sigma = float(self.site.scene["robot"]["localization_sigma_m"])
        return T_wall_from_room @ self.site.localized_T_room_from_robot, sigma, "localization"

    def close(self) -> None:
        self.head.close()
        self.head_sim.close()


def open_camera(source: str, intr: Intrinsics, name: str) -> cv2.VideoCapture:
    """A cv2.VideoCapture for an index ("0"), a file or a URL, checked against the rig's image size."""
    cap = cv2.VideoCapture(int(source) if source.isdigit() else source)
    if not cap.isOpened():
        raise InputError(f"{name}: camera {source!r} does not open",
                         "check the index/URL and that no other program uses the camera, or pass --sim")
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, intr.width)
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, intr.height)
    ok, image = cap.read()
    if not ok or image is None:
        cap.release()
        raise InputError(f"{name}: camera {source!r} opened but gives no picture")
    if image.shape[:2] != (intr.height, intr.width):
        cap.release()
        raise InputError(f"{name}: camera {source!r} delivers {image.shape[1]}x{image.shape[0]} but the rig "
                         f"file is for {intr.width}x{intr.height}", "use the rig calibrated for these cameras")
    return cap


def read_wall_prior(path: str | Path) -> NDArray[np.float64]:
    """T_wall_from_robot from a YAML file {T_wall_from_robot: [[...], ...]} (4x4, metres)."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
        T = np.asarray(doc["T_wall_from_robot"], dtype=np.float64)
    except FileNotFoundError:
        raise InputError(f"{path}: no such wall-prior file") from None
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        raise InputError(f"{path}: expected YAML with T_wall_from_robot: a 4x4 list") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"{path}: T_wall_from_robot must be a finite 4x4 matrix")
    return T


class HardwareRobot:
    """Real cameras (OpenCV), the beamer output and a Pelco-D head. The in-plane part of the wall frame comes
    from a prior file (T_wall_from_robot), e.g. from the robot's localization in the building plan."""

    def __init__(self, left: str, right: str, camera_left: Intrinsics, camera_right: Intrinsics,
                 output: FrameOutput, head: PanTiltHead | None, wall_prior_path: str | Path,
                 in_plane_sigma_m: float = 0.01, settle_s: float = 0.15) -> None:
        self._prior = read_wall_prior(wall_prior_path)
        self.in_plane_sigma_m = in_plane_sigma_m
        self._left = open_camera(left, camera_left, "camera_left")
        try:
            self._right = open_camera(right, camera_right, "camera_right")
        except InputError:
            self._left.release()
            raise
        self.output = output
        self.head = head
        self.settle_s = settle_s

    def capture(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        self.show(frame)
        time.sleep(self.settle_s)  # the beamer needs a frame or two to show the new image
        images = []
        for cap, name in ((self._left, "camera_left"), (self._right, "camera_right")):
            for _ in range(2):  # drop buffered frames taken before the new image was shown
                cap.grab()
            ok, image = cap.read()
            if not ok:
                raise InputError(f"{name}: the camera stopped delivering pictures", "check its cable")
            images.append(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
        return images[0], images[1]

    def show(self, frame: NDArray[np.uint8]) -> None:
        self.output.show(frame)

    def laser_points(self) -> None:
        return None

    def full_pose_inputs(self) -> None:
        return None  # hardware: the in-plane part comes from the wall-prior file

    def wall_prior(self) -> tuple[NDArray[np.float64], float, str]:
        return self._prior, self.in_plane_sigma_m, "wall-prior file"

    def close(self) -> None:
        self._left.release()
        self._right.release()
        if self.head is not None:
            self.head.close()
        self.output.close()


def nominal_rig(site: RobotSite) -> Rig:
    """A rig from the simulated site's DESIGN values (nominal head without its angle bias, exact cameras):
    what a robot is before calibration. Used only when no calibrated rig is available; the session's
    pattern-based estimate measures the projector's true pose on top of it."""
    return Rig(intrinsics={"camera_left": site.camera_left, "camera_right": site.camera_right,
                           "projector": site.projector},
               poses={"T_robot_from_camera_left": site.T_robot_from_camera_left,
                      "T_camera_right_from_camera_left": site.T_camera_right_from_camera_left},
               head=site.head_nominal, quality={"source": "simulated site design values (not calibrated)"})
