"""What the session talks to: cameras, beamer, head, laser, inclinometer and a prior for the wall frame.

Two implementations with one interface: SimulatedRobot (the simulated site, its head reached through the
Pelco-D head simulator over socket:// — the real driver's code path — and its inclinometer through the
inclinometer's simulator likewise) and HardwareRobot (OpenCV cameras, the beamer window, a head and an
inclinometer at serial URLs).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from arproj.session.output import FrameOutput
from arproj.session.relocalise import START_SIGMA_DEG, START_SIGMA_M, fix_in_site
from arproj.site_file import SiteWall
from calibration.capture import SETTLE_TIMEOUT_S
from devices.errors import DeviceError, DeviceResetError
from devices.pelco_d import PanTiltHead
from devices.sim import HeadFaults, HeadSimulator, InclinometerSim
from geometry.errors import InputError
from geometry.intrinsics import Intrinsics
from geometry.poses import invert, roll_pitch
from geometry.rig import Rig
from wallpose.pose import RoomMap, TiltMeasurement

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


@dataclass
class PoseInputs:
    """What the full wall-pose estimate fuses with the plane besides the laser scan: the room's walls, which of
    them holds the map, the robot's start pose in the room and its σ (wallpose.pose.estimate_wall_pose), the
    map's wall frame in the room (None: the room wall's own frame) and a σ to add in the wall's plane (how well
    that frame is known in the room); tilt: the robot's roll and pitch read from its inclinometer (None: the
    fusion's floor prior)."""

    room: RoomMap
    wall_index: int
    localized_T_room_from_robot: NDArray[np.float64]
    sigma_m: float
    sigma_deg: float
    T_room_from_map: NDArray[np.float64] | None = None
    extra_sigma_m: float = 0.0
    source: str = "localization"
    tilt: TiltMeasurement | None = None
    # the fused estimate only checks the evidence (edges, laser, the plane against the map); the pose is the
    # robot's wall_prior (the simulator's in-plane truth), so a rig the evidence contradicts is still refused
    check_only: bool = False


def site_pose_inputs(site_wall: SiteWall, scan_points: NDArray[np.float64], laser_origin: NDArray[np.float64],
                     normal_robot: NDArray[np.float64] | None, tilt: TiltMeasurement | None = None) -> PoseInputs:
    """The full estimate's inputs from a site file: its room, the start pose from the laser's fix in it (and the
    inclinometer's reading, when the robot has one)."""
    fix = fix_in_site(scan_points, laser_origin, site_wall, normal_robot)
    return PoseInputs(site_wall.room_map(), site_wall.wall_index, fix.T_room_from_robot, START_SIGMA_M,
                      START_SIGMA_DEG, site_wall.T_room_from_wall,
                      float(np.hypot(site_wall.sigma_along_m, site_wall.sigma_height_m)),
                      f"laser fix in the site's room ({' and '.join(fix.sides)} side wall)", tilt)


INCLINOMETER_HINT = "check the inclinometer's cable and power, or its URL (--inclinometer)"


class DeviceInclinometer:
    """The robot's inclinometer at a serial URL (devices/inclinometer.py): each reading as the wall-pose fusion
    takes it."""

    def __init__(self, url: str, timeout_s: float = 0.5) -> None:
        from devices.crclines import CrcLineFramer
        from devices.inclinometer import Inclinometer
        from devices.link import SerialLink

        self.link = SerialLink(url, CrcLineFramer(), "inclinometer", timeout_s=timeout_s, hint=INCLINOMETER_HINT)
        self.link.open()
        try:
            self.device = Inclinometer(self.link)
            self.model = self.device.identify()
        except BaseException:
            self.link.close()
            raise

    def reading(self) -> TiltMeasurement:
        r = self.device.tilt()
        return TiltMeasurement(r.roll_deg, r.pitch_deg, r.sigma_roll_deg, r.sigma_pitch_deg)

    def close(self) -> None:
        self.link.close()


def true_tilt_deg(site: RobotSite) -> tuple[float, float]:
    """The simulated robot's true (roll, pitch) against gravity, degrees: what its inclinometer measures."""
    roll, pitch = roll_pitch(site.T_room_from_robot)
    return float(np.degrees(roll)), float(np.degrees(pitch))


def site_wall_prior(site_wall: SiteWall, scan_points: NDArray[np.float64] | None,
                    laser_origin: NDArray[np.float64]) -> tuple[NDArray[np.float64], float, str]:
    """wall_prior() from a site file before the pattern is seen: the laser's fix alone (InputError without a
    laser scan or when it sees no side wall)."""
    if scan_points is None:
        raise InputError(f"--site: finding wall {site_wall.key!r} again needs the robot's 2-D laser",
                         "give the laser (--laser URL), or --wall-prior FILE")
    fix = fix_in_site(scan_points, laser_origin, site_wall)
    return fix.T_wall_from_robot, float(np.hypot(fix.sigma_along_m, site_wall.sigma_along_m)), \
        "laser fix in the site's room"


class SimulatedRobot:
    """The simulated site as the session's robot. The head is commanded over Pelco-D to a HeadSimulator; the
    site's head then moves to the simulator's physical angles (its own bias, noise and backlash on top).

    prior: "measured" (default) estimates the full wall pose with the wall-pose package (plane + localization +
    floor + laser scan of the room); "truth" gives the in-plane part of the wall frame exactly (to isolate the
    projection from the wall pose); "localization" uses the robot's noisy localization alone.

    T_room_from_map: the map's wall frame on the site (the truth; None: wall `wall_index`'s own frame, its
    lower-left corner). site_wall: find the wall again from a site file (arproj.site_file) instead of the
    site's truth room and the simulated localization: the laser's fix in the file's room, as on hardware.
    head_sim None: the head is another process's (`arproj devices serve`); the site's head follows the angles
    it reports. inclinometer: the robot's inclinometer (its readings replace the fusion's floor-tilt prior; None:
    the prior), inclinometer_sim the in-process simulator behind it (closed with the robot).
    """

    def __init__(self, site: RobotSite, wall_index: int, head_sim: HeadSimulator | None, head: PanTiltHead,
                 output: FrameOutput | None = None, prior: str = "measured",
                 T_room_from_map: NDArray[np.float64] | None = None, site_wall: SiteWall | None = None,
                 inclinometer: DeviceInclinometer | None = None,
                 inclinometer_sim: InclinometerSim | None = None) -> None:
        self.site = site
        self.wall_index = int(wall_index)
        self.head_sim = head_sim
        self.head = head
        self.output = output
        self.prior = prior
        self._synced: tuple[float, float] | None = None
        self.wall = site.walls[self.wall_index]
        self.T_room_from_map = np.asarray(self.wall.T_room_from_wall if T_room_from_map is None else T_room_from_map,
                                          dtype=np.float64)
        self.site_wall = site_wall
        self.inclinometer = inclinometer
        self.inclinometer_sim = inclinometer_sim

    @classmethod
    def on_site(cls, site: RobotSite, wall_index: int = 0, output: FrameOutput | None = None, prior: str = "measured",
                *, seed: int = 0, head_faults: HeadFaults | None = None, head_speed_deg_s: float | None = None,
                timeout_s: float = 0.2, retries: int = 3, settle_timeout_s: float = 3.0,
                head_url: str | None = None, T_room_from_map: NDArray[np.float64] | None = None,
                site_wall: SiteWall | None = None, inclinometer: bool = True,
                inclinometer_url: str | None = None) -> SimulatedRobot:
        """The robot on `site`, its head a HeadSimulator (seeded; `head_faults` injected; `head_speed_deg_s`,
        None: the simulator's own) started at the angles the site's head is commanded to, and reached over
        Pelco-D on socket:// with these timeouts, as a real head is; or the head at head_url (another
        process's, e.g. `arproj devices serve`), moved to those angles first. Its inclinometer: the one at
        inclinometer_url (another process's), else with `inclinometer` an InclinometerSim (seeded) reading the
        site's true tilt, reached over socket:// as a real one is; neither: none (the floor prior)."""
        incl_sim = InclinometerSim(lambda: true_tilt_deg(site), seed=seed) \
            if inclinometer and inclinometer_url is None else None
        opened: list = [] if incl_sim is None else [incl_sim]
        try:
            url = inclinometer_url if incl_sim is None else incl_sim.url
            incl = None if url is None else DeviceInclinometer(url)
            if incl is not None:
                opened.append(incl)
            if head_url is not None:
                head = PanTiltHead(head_url, timeout_s=timeout_s, retries=retries, settle_timeout_s=settle_timeout_s)
                opened.append(head)
                head.move_to(*(float(a) for a in site.head_angles_cmd_deg[:2]))
                return cls(site, wall_index, None, head, output, prior, T_room_from_map, site_wall, incl, incl_sim)
            speed = {} if head_speed_deg_s is None else {"speed_deg_s": head_speed_deg_s}
            head_sim = HeadSimulator(faults=head_faults, seed=seed, **speed,
                                     initial_deg=tuple(float(a) for a in site.head_angles_cmd_deg[:2]))
            opened.append(head_sim)
            head = PanTiltHead(head_sim.url, timeout_s=timeout_s, retries=retries, settle_timeout_s=settle_timeout_s)
            return cls(site, wall_index, head_sim, head, output, prior, T_room_from_map, site_wall, incl, incl_sim)
        except BaseException:
            for device in reversed(opened):
                device.close()
            raise

    def sync_head(self) -> None:
        """Move the site's head to where the simulated head physically is (slip included; a head of another
        process: where it reports to be)."""
        true = self.head_sim.true_deg() if self.head_sim is not None else self.head.position()
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

    def full_pose_inputs(self, normal_robot: NDArray[np.float64] | None = None) -> PoseInputs | None:
        """What the wall-pose package's full estimate fuses (plane + start pose + floor + laser), or None when the
        in-plane part comes from the localization alone. With prior="truth" the same inputs, marked check_only: the
        truth gives the pose, but what the product's own evidence contradicts is refused as on the measured path
        (a camera mount that differs from the rig file looks to the pattern like a head that turned; only the room's
        edges and the laser tell them apart). normal_robot: the measured plane's normal (orients a site's laser
        fix)."""
        if self.prior not in ("measured", "truth"):
            return None
        tilt = None if self.inclinometer is None else self.inclinometer.reading()
        if self.site_wall is not None:
            inputs = site_pose_inputs(self.site_wall, self.laser_points(), self.site.T_robot_from_laser[:3, 3],
                                      normal_robot, tilt)
            return replace(inputs, check_only=self.prior == "truth")
        from arproj.sim.wallpose_trial import room_map

        r = self.site.scene["robot"]
        return PoseInputs(room_map(self.site), self.wall_index, self.site.localized_T_room_from_robot,
                          float(r["localization_sigma_m"]), float(r["localization_sigma_deg"]), self.T_room_from_map,
                          tilt=tilt, check_only=self.prior == "truth")

    def wall_prior(self) -> tuple[NDArray[np.float64], float, str]:
        if self.site_wall is not None and self.prior == "measured":
            return site_wall_prior(self.site_wall, self.laser_points(), self.site.T_robot_from_laser[:3, 3])
        T_wall_from_room = invert(self.T_room_from_map)
        if self.prior == "truth":
            return T_wall_from_room @ self.site.T_room_from_robot, 0.0, TRUTH_PRIOR
        sigma = float(self.site.scene["robot"]["localization_sigma_m"])
        return T_wall_from_room @ self.site.localized_T_room_from_robot, sigma, "localization"

    def close(self) -> None:
        self.head.close()
        if self.head_sim is not None:
            self.head_sim.close()
        if self.inclinometer is not None:
            self.inclinometer.close()
        if self.inclinometer_sim is not None:
            self.inclinometer_sim.close()


def open_camera(source: str, intr: Intrinsics, name: str) -> cv2.VideoCapture:
    """A cv2.VideoCapture for an index ("0"), a file or a URL, checked against the rig's image size."""
    from calibration.capture import open_source

    cap = open_source(source, name)
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
    from geometry.inputs import float_array, load_document, mapping

    path = Path(path)
    hint = "give --wall-prior a YAML file {T_wall_from_robot: [[...], ...]} (4x4, metres)"
    doc = mapping(str(path), "the document", load_document(path, "wall-prior file", hint), hint=hint)
    if "T_wall_from_robot" not in doc:
        raise InputError(f"{path}: expected YAML with T_wall_from_robot: a 4x4 list", hint)
    return float_array(str(path), "T_wall_from_robot", doc["T_wall_from_robot"], (4, 4), lo=-1000.0, hi=1000.0,
                       hint=hint)


LASER_HEAD = "H"  # the projection robot's 2-D laser head that scans the horizontal plane
LASER_HINT = "check the laser's cable and power, or its URL (--laser)"


class DeviceLaser:
    """The projection robot's 2-D laser at a serial URL (devices/laser2d.py, the scan's own client): one turn
    of its horizontal head as robot-frame points, the laser's place on the robot from the rig."""

    def __init__(self, url: str, T_robot_from_laser: NDArray[np.float64], timeout_s: float = 0.5,
                 attempts: int = 4) -> None:
        from devices.crclines import CrcLineFramer
        from devices.laser2d import Laser2D
        from devices.link import SerialLink

        self.T_robot_from_laser = np.asarray(T_robot_from_laser, dtype=np.float64)
        self.attempts = attempts
        self.link = SerialLink(url, CrcLineFramer(), "laser", timeout_s=timeout_s, hint=LASER_HINT)
        self.link.open()
        try:
            self.laser = Laser2D(self.link)
            heads = self.laser.heads()
        except BaseException:
            self.link.close()
            raise
        if LASER_HEAD in heads or len(heads) == 1:
            self.head = LASER_HEAD if LASER_HEAD in heads else heads[0]
        else:
            self.link.close()
            raise DeviceError(f"the laser at {url} has heads {heads}: which one scans the horizontal plane is "
                              f"not known (the projection robot's is {LASER_HEAD})", LASER_HINT)
        self.turns = 0

    def points(self) -> NDArray[np.float64]:
        """One fresh turn, (n, 3) robot-frame returns in metres (no-return rays dropped); a device reset during
        the turn (its buffer gone) takes the turn again."""
        from arproj.sim.site import LaserScan

        for _ in range(self.attempts):
            self.turns += 1
            try:
                angles, ranges = self.laser.scan(self.head, self.turns)
            except DeviceResetError:
                continue
            return LaserScan(angles, ranges, self.T_robot_from_laser).points_robot()
        raise DeviceError(f"the laser at {self.link.url} reset {self.attempts} times in one turn", LASER_HINT)

    @property
    def origin(self) -> NDArray[np.float64]:
        return self.T_robot_from_laser[:3, 3]

    def close(self) -> None:
        self.link.close()


class HardwareRobot:
    """Real cameras (OpenCV, read continuously: each capture takes the first settled frame after the pattern
    is shown), the beamer output and a Pelco-D head. The in-plane part of the wall frame comes from a prior
    file (T_wall_from_robot, e.g. from the robot's localization in the building plan), or with a site file and
    the robot's 2-D laser from the laser's fix in the site's room (arproj.session.relocalise), as on the
    simulated site; there an inclinometer's readings replace the fusion's floor-tilt prior."""

    def __init__(self, left: str, right: str, camera_left: Intrinsics, camera_right: Intrinsics,
                 output: FrameOutput, head: PanTiltHead | None, wall_prior_path: str | Path | None = None,
                 in_plane_sigma_m: float = 0.01, settle_s: float = 0.15, laser: DeviceLaser | None = None,
                 site_wall: SiteWall | None = None, settle_timeout_s: float = SETTLE_TIMEOUT_S,
                 inclinometer: DeviceInclinometer | None = None) -> None:
        from calibration.capture import LiveCamera

        if site_wall is not None and laser is None:
            raise InputError(f"--site: finding wall {site_wall.key!r} again needs the robot's 2-D laser",
                             "give the laser (--laser URL), or --wall-prior FILE")
        if site_wall is None and wall_prior_path is None:
            raise InputError("hardware sessions need --wall-prior FILE (T_wall_from_robot), or --site FILE "
                             "--wall KEY with the robot's 2-D laser (--laser URL)")
        self._prior = None if wall_prior_path is None else read_wall_prior(wall_prior_path)
        self.in_plane_sigma_m = in_plane_sigma_m
        self.laser, self.site_wall, self.inclinometer = laser, site_wall, inclinometer
        self._left = LiveCamera(open_camera(left, camera_left, "camera_left"), "camera_left")
        try:
            self._right = LiveCamera(open_camera(right, camera_right, "camera_right"), "camera_right")
        except BaseException:
            self._left.close()
            raise
        self.output = output
        self.head = head
        self.settle_s, self.settle_timeout_s = settle_s, settle_timeout_s

    def capture(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        self.show(frame)
        after = time.monotonic() + self.settle_s  # the beamer needs a frame or two to show the new image
        return (self._left.settled_frame(after, self.settle_timeout_s),
                self._right.settled_frame(after, self.settle_timeout_s))

    def show(self, frame: NDArray[np.uint8]) -> None:
        self.output.show(frame)

    def laser_points(self) -> NDArray[np.float64] | None:
        return None if self.laser is None else self.laser.points()

    def full_pose_inputs(self, normal_robot: NDArray[np.float64] | None = None) -> PoseInputs | None:
        if self.site_wall is None or self.laser is None:
            return None  # the in-plane part comes from the wall-prior file
        tilt = None if self.inclinometer is None else self.inclinometer.reading()
        return site_pose_inputs(self.site_wall, self.laser.points(), self.laser.origin, normal_robot, tilt)

    def wall_prior(self) -> tuple[NDArray[np.float64], float, str]:
        if self.site_wall is not None and self.laser is not None:
            return site_wall_prior(self.site_wall, self.laser.points(), self.laser.origin)
        assert self._prior is not None
        return self._prior, self.in_plane_sigma_m, "wall-prior file"

    def close(self) -> None:
        self._left.close()
        self._right.close()
        if self.laser is not None:
            self.laser.close()
        if self.inclinometer is not None:
            self.inclinometer.close()
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
                      "T_camera_right_from_camera_left": site.T_camera_right_from_camera_left,
                      "T_robot_from_laser": site.T_robot_from_laser},
               head=site.head_nominal, quality={"source": "simulated site design values (not calibrated)"})
