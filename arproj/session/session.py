"""The projection session at the drilling site.

    session = ProjectionSession(rig, wall_map, robot)
    session.aim_at([1.2, 1.1])        # turn the head so the beamer's image is centred on that wall point
    decision = session.update()       # estimate the wall pose if needed, verify, show map or warning
    session.set_drill_point([1.25, 1.0]); session.update()

Each update: (1) triggers — no registration yet, the head reports other angles than at the estimate, the
laser says the robot moved — re-estimate the wall pose from the projected pattern; (2) the closed loop
projects check marks, photographs them with both cameras, measures where they landed and corrects a small
remaining offset (a large one triggers one re-estimate); (3) the safety gate decides: the pre-warped map with
the legend, or a warning that says why.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from arproj.session import gate, overlays, registration
from arproj.session import tolerances as tol
from arproj.session.projection import MapProjector
from arproj.session.robot_io import PoseInputs, RobotIO
from arproj.session.wallmap import WallMap
from calibration.stereo import sample_stereo
from devices.errors import DeviceError
from geometry.errors import InputError
from geometry.poses import invert, make_pose, transform_points
from geometry.rig import Rig
from wallpose.edges import camera_images
from wallpose.estimate import PlaneEstimate, StereoDraw, Uncertainty, estimate_plane
from wallpose.evidence import EvidenceCode, NotEnoughEvidenceError
from wallpose.limits import MAX_NUISANCE_SIGMAS
from wallpose.pattern import choose_pattern
from wallpose.pose import estimate_wall_pose
from wallpose.rig import ViewRig

HEAD_MOVED_DEG = 0.005  # reported angles that differ by more than this since the estimate: re-estimate
CLOSED_LOOP_MARKS = 48  # check marks per closed-loop frame
HEAD_MODEL_FALLBACK_DEG = 10.0  # projector-pose prior when the head model disagrees with the pattern
HEAD_MODEL_FALLBACK_M = 0.05
STEREO_DRAWS = 48  # draws of the stereo pair from its calibration's covariance, carried into each plane estimate
STEREO_DRAW_SEED = 20  # fixed: the same rig gives the same plane covariance every time
# a pose given from outside and the measured one may differ at a drawn point by this many σ of the measured one
# (a two-dimensional 99.99 % bound, as the wall-pose package's own innovation test)
PRIOR_AGREEMENT_SIGMAS = 4.29
LOG_LINES = 1000  # the session log keeps this many last lines (a line or two a cycle: minutes of cycles)
# The craftsman's words (as gate.SAY_*) for a head found off its model while its encoder saw nothing: the map is
# measured again from the pattern and still shown, but the mount slipped and a person must look at it.
SAY_HEAD_SLIPPED = "The projector head slipped; the picture was measured again. Tell the operator."


@dataclass
class Registration:
    """The current belief of where the projector is relative to the wall."""

    head_deg: tuple[float, float]
    T_wall_from_robot: NDArray[np.float64]
    T_wall_from_projector: NDArray[np.float64]   # with the closed loop's correction applied
    plane: PlaneEstimate
    sigma_m: float
    prior_source: str
    distance_m: float
    incidence_deg: float
    footprint_m: float
    reference_scan: NDArray[np.float64] | None = None   # (n, 3) robot frame, at the estimate
    laser_plane_offset_m: float | None = None
    trusted: registration.TrustedRegion | None = None  # where the map is drawn (None: everywhere)
    loop: registration.ClosedLoopResult | None = None
    correction_xy: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    estimated_at: float = field(default_factory=time.monotonic)
    in_plane_sigma_m: float = 0.0   # the wall pose's in-plane 1σ and roll 1σ: another wall's σ is drawn from them
    roll_sigma_rad: float = 0.0
    calibration_px: float = 0.0
    # the fused pose's (6, 6) covariance in the robot frame and the map frame's σ beside it (None: no fusion):
    # another wall's σ is drawn from them as this wall's is (registration.pose_sigma_on_wall_m)
    pose_covariance: NDArray[np.float64] | None = None
    frame_sigma_m: float = 0.0
    cut_by: str = ""  # what cuts the map (registration.why_cut): the largest term where the bound is too large


@dataclass
class PoseFromPlane:
    """The wall pose made from a measured plane (ProjectionSession.pose_from_plane): T_wall_from_robot and
    T_robot_from_projector; in_plane_sigma_m / roll_sigma_rad: the pose's in-plane 1σ (with the map frame's)
    and its rotation about the normal; source (None: the robot's prior, snapped onto the plane); covariance
    (6, 6) of the fused pose (wallpose.pose.WallPose.covariance; None without fusion) and frame_sigma_m, the
    map frame's own in-plane σ in the room that adds to it."""

    T_wall_from_robot: NDArray[np.float64]
    T_robot_from_projector: NDArray[np.float64]
    in_plane_sigma_m: float
    roll_sigma_rad: float
    source: str | None
    covariance: NDArray[np.float64] | None
    frame_sigma_m: float


def _quality(rig: Rig, section: str, key: str) -> float:
    """A calibration quality figure from rig.yaml (0 when the rig does not record it)."""
    value = rig.quality.get(section, {}).get(key) if isinstance(rig.quality, dict) else None
    try:
        return float(value) if value is not None else 0.0
    except (TypeError, ValueError):
        return 0.0


def _why_declined(err: InputError) -> str:
    """Why the wall pose failed, for the log and pose_failure: the estimator's reason, or the input error."""
    return err.reason if isinstance(err, NotEnoughEvidenceError) else err.message


def check_rig(rig: Rig) -> None:
    """The rig must have what the session needs (InputError naming what is missing)."""
    for device in ("camera_left", "camera_right", "projector"):
        if device not in rig.intrinsics:
            raise InputError(f"rig has no intrinsics for {device}", "run `arproj calibrate` for this robot")
    for name in ("T_robot_from_camera_left", "T_camera_right_from_camera_left"):
        rig.pose(name)
    if rig.head is None:
        raise InputError("rig has no head model", "calibrate the pan/tilt head (`arproj calibrate`)")


class ProjectionSession:
    """Aims, registers, verifies and shows the in-wall map. Owns a MapProjector (GL); use `with`."""

    def __init__(self, rig: Rig, wall_map: WallMap, robot: RobotIO, ctx: object | None = None,
                 tolerance_m: float = tol.REGISTRATION_TOLERANCE_M, closed_loop: bool = True) -> None:
        check_rig(rig)
        self.rig = rig
        self.wall_map = wall_map
        self.robot = robot
        self.tolerance_m = tolerance_m
        self.closed_loop = closed_loop
        self.projector_intr = rig.intrinsics["projector"]
        self.map_projector = MapProjector(wall_map, self.projector_intr, ctx)
        self.registration: Registration | None = None
        self.pose_failure: str | None = None
        self.head_failure: str | None = None
        self.rig_failure: str | None = None  # the rig file cannot describe this robot (see _not_a_head_slip)
        self.refused_registration: Registration | None = None  # the last estimate, when its rig was in doubt
        self.drill_xy: NDArray[np.float64] | None = None
        self.last_decision: gate.GateDecision | None = None
        self.last_evidence: gate.RegistrationEvidence | None = None
        self.last_frame: NDArray[np.uint8] | None = None
        self.last_pattern_capture: tuple | None = None  # (pattern, left image, right image, head angles)
        self.head_slipped = False  # the current registration found the head off where its encoder says
        self.last_words: list[str] = []  # what the last frame says in words (legend lines or warning)
        self.last_legend: overlays.LegendLayout | None = None  # where the last map frame's legend went
        self.log: deque[str] = deque(maxlen=LOG_LINES)  # bounded: a session may run for days
        self._stereo_draws: tuple[StereoDraw, ...] | None = None

    def __enter__(self) -> ProjectionSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.map_projector.release()

    # -- head -----------------------------------------------------------------------------------------------
    def head_deg(self) -> tuple[float, float]:
        """The head's reported (pan, tilt); when it does not answer, the last known angles (and the gate is
        told, so the map is not shown as if the head were confirmed in place)."""
        if self.robot.head is None:
            return (0.0, 0.0) if self.registration is None else self.registration.head_deg
        try:
            angles = self.robot.head.position()
        except DeviceError as err:
            self.head_failure = str(err)
            if self.registration is not None:
                return self.registration.head_deg
            return self.robot.head.commanded or (0.0, 0.0)
        self.head_failure = None
        return angles

    def T_robot_from_projector_model(self, head_deg: tuple[float, float]) -> NDArray[np.float64]:
        assert self.rig.head is not None
        return self.rig.head.T_robot_from_projector([head_deg[0], head_deg[1], 0.0])

    def _wall_from_robot(self) -> NDArray[np.float64]:
        if self.registration is not None:
            return self.registration.T_wall_from_robot
        return self.robot.wall_prior()[0]

    def aim_at(self, wall_xy: ArrayLike) -> tuple[float, float]:
        """Turn the head so the centre of the beamer's image lands on wall point (x, y) metres; re-register."""
        if self.robot.head is None:
            raise InputError("this session has no pan/tilt head to aim with", "pass --head URL or --sim")
        xy = np.asarray(wall_xy, dtype=np.float64).reshape(2)
        target = transform_points(invert(self._wall_from_robot()), [xy[0], xy[1], 0.0])
        intr = self.projector_intr
        centre_ray = intr.rays([[(intr.width - 1) / 2, (intr.height - 1) / 2]])[0]

        def residual(pt: NDArray[np.float64]) -> NDArray[np.float64]:
            p = transform_points(invert(self.T_robot_from_projector_model((pt[0], pt[1]))), target)
            return p[:2] / max(p[2], 1e-6) - centre_ray[:2]

        start = np.asarray(self.head_deg(), dtype=np.float64)
        sol = least_squares(residual, start, x_scale=10.0)
        if np.max(np.abs(sol.fun)) > 1e-4:
            raise InputError(f"the head cannot aim at wall point ({xy[0]:.2f}, {xy[1]:.2f}) m",
                             "pick a point the beamer can reach from here, or move the robot")
        pan, tilt = (float(a) for a in sol.x)
        self.robot.head.move_to(pan, tilt)
        self.log.append(f"aimed at ({xy[0]:.3f}, {xy[1]:.3f}) m: pan {pan:.2f}°, tilt {tilt:.2f}°")
        self.registration = None  # the head moved: the old registration no longer holds
        return pan, tilt

    def set_drill_point(self, wall_xy: ArrayLike | None) -> overlays.DrillVerdict | None:
        self.drill_xy = None if wall_xy is None else np.asarray(wall_xy, dtype=np.float64).reshape(2)
        return None if self.drill_xy is None else self.drill_check(self.drill_xy)

    def drill_check(self, wall_xy: ArrayLike) -> overlays.DrillVerdict:
        sigma = self.last_decision.registration_sigma_m if self.last_decision else np.inf
        sigma = sigma if np.isfinite(sigma) else self.tolerance_m / tol.Z95
        return overlays.check_drill_point(self.wall_map, np.asarray(wall_xy, dtype=np.float64), sigma)

    # -- registration ---------------------------------------------------------------------------------------
    def _uncertainty(self) -> Uncertainty:
        """How well the head model predicts the projector's pose: the estimator's prior, never tighter than the
        head's repeatability, wider when the head calibration's residual says so (3σ of its RMS)."""
        rot = max(Uncertainty().projector_rotation_deg, 3.0 * _quality(self.rig, "head", "rotation_rms_deg"))
        trans = max(Uncertainty().projector_translation_m, 3e-3 * _quality(self.rig, "head", "position_rms_mm"))
        return Uncertainty(projector_rotation_deg=rot, projector_translation_m=trans, stereo_draws=self.stereo_draws)

    @property
    def stereo_draws(self) -> tuple[StereoDraw, ...]:
        """The stereo pair drawn from the rig's calibration covariance (none when the rig does not keep it): how
        far a calibration this good may put the wall (a depth bias of millimetres at 4 m is within it)."""
        if self._stereo_draws is None:
            stereo = self.rig.quality.get("stereo", {}) if isinstance(self.rig.quality, dict) else {}
            doc = stereo.get("parameter_covariance") if isinstance(stereo, dict) else None
            self._stereo_draws = () if not doc else tuple(sample_stereo(
                self.rig.intrinsics["camera_left"], self.rig.intrinsics["camera_right"],
                self.rig.pose("T_camera_right_from_camera_left"), doc, stereo.get("distortion_model", "k1k2p1p2k3"),
                np.random.default_rng(STEREO_DRAW_SEED), STEREO_DRAWS))
        return self._stereo_draws

    def pose_from_plane(self, plane: PlaneEstimate, views: ViewRig, scan: NDArray[np.float64] | None,
                        images: tuple[NDArray, NDArray] | None = None) -> PoseFromPlane:
        """The full wall pose from a measured plane. With the robot's localization, floor and laser
        (full_pose_inputs) the wall-pose package fuses them (and the wall's edges in images = (left, right)
        photos, where in view); otherwise the plane is snapped onto the robot's prior. Raises InputError
        (not enough evidence) when the fusion declines."""
        T_robot_from_projector = views.T_robot_from_camera_left @ plane.T_camera_left_from_projector
        prior, in_plane_sigma, prior_source = self.robot.wall_prior()
        full = getattr(self.robot, "full_pose_inputs", lambda normal: None)(plane.normal)
        if full is not None and full.check_only:
            self._check_prior_against_evidence(plane, views, scan, images, full, prior, prior_source)
        if full is None or full.check_only:
            return PoseFromPlane(registration.snap_to_plane(prior, plane.normal, plane.distance),
                                 T_robot_from_projector, in_plane_sigma, 0.0, None, None, in_plane_sigma)
        pose = estimate_wall_pose(plane, full.wall_index, full.room, full.localized_T_room_from_robot,
                                  T_robot_from_projector, scan, full.sigma_m, full.sigma_deg,
                                  camera_images=None if images is None else camera_images(views, *images),
                                  projector=views.projector, tilt=full.tilt)
        T_wall_from_robot = pose.T_wall_from_robot if full.T_room_from_map is None else \
            invert(full.T_room_from_map) @ pose.T_room_from_robot  # the map's frame, in the room wall's plane
        in_plane = float(np.sqrt(pose.sigma_along_m ** 2 + pose.sigma_height_m ** 2 + full.extra_sigma_m ** 2))
        sources = [full.source if s == "localization" else s for s in pose.sources]
        return PoseFromPlane(T_wall_from_robot, T_robot_from_projector, in_plane,
                             float(np.radians(pose.sigma_roll_deg)), "wall pose (" + ", ".join(sources) + ")",
                             pose.covariance, full.extra_sigma_m)

    def _check_prior_against_evidence(self, plane: PlaneEstimate, views: ViewRig, scan: NDArray[np.float64] | None,
                                      images: tuple[NDArray, NDArray] | None, full: PoseInputs,
                                      prior: NDArray[np.float64], prior_source: str) -> None:
        """A wall pose given from outside (full.check_only: the simulator's truth) must agree with the one the
        product measures (plane, localization, floor, laser, the room's edges): where the projector's light
        falls on the map, the two may differ by no more than the measured pose's uncertainty allows
        (PRIOR_AGREEMENT_SIGMAS). A camera mount that differs from the rig file turns the measured pose with it,
        while the given pose stays put: without this check such a rig would draw the map centimetres off and
        its closed loop, measuring in the same wrong frame, would find nothing amiss. Raises
        NotEnoughEvidenceError (also when the measured pose itself is declined)."""
        T_robot_from_projector = views.T_robot_from_camera_left @ plane.T_camera_left_from_projector
        pose = estimate_wall_pose(plane, full.wall_index, full.room, full.localized_T_room_from_robot,
                                  T_robot_from_projector, scan, full.sigma_m, full.sigma_deg,
                                  camera_images=None if images is None else camera_images(views, *images),
                                  projector=views.projector, tilt=full.tilt)
        measured = pose.T_wall_from_robot if full.T_room_from_map is None else \
            invert(full.T_room_from_map) @ pose.T_room_from_robot
        given = registration.snap_to_plane(prior, plane.normal, plane.distance)
        points = registration.choose_marks(measured @ T_robot_from_projector, self.projector_intr,
                                           self.wall_map.extent, grid=(4, 3), border=0.02)
        if not len(points) or pose.covariance is None:
            return
        on_wall = np.column_stack([points, np.zeros(len(points))])
        moved = transform_points(given @ invert(measured), on_wall)[:, :2] - points
        sigma = np.hypot(registration.pose_sigma_on_wall_m(points, measured, pose.covariance), full.extra_sigma_m)
        worst = int(np.argmax(np.linalg.norm(moved, axis=1) / sigma))
        apart, allowed = float(np.linalg.norm(moved[worst])), PRIOR_AGREEMENT_SIGMAS * float(sigma[worst])
        if apart > allowed:
            raise NotEnoughEvidenceError(
                EvidenceCode.NO_WALL_FRAME,
                f"the wall pose given ({prior_source}) puts the map {1000 * apart:.1f} mm from where "
                f"the cameras, laser and room edges put it (at most {1000 * allowed:.1f} mm): the rig file's camera "
                "mount may not fit this robot",
                "recalibrate the rig (`arproj calibrate`) or check the given wall pose")

    def estimate(self) -> Registration | None:
        """Project the pattern, estimate the wall plane and the projector's pose; None (and pose_failure set)
        when the pictures do not support a trustworthy pose."""
        head = self.head_deg()
        views = ViewRig.from_rig(self.rig, [head[0], head[1], 0.0])
        prior, in_plane_sigma, source = self.robot.wall_prior()
        T_wall_from_projector_prior = prior @ views.T_robot_from_projector
        n_p = invert(T_wall_from_projector_prior)[:3, :3] @ np.array([0.0, 0.0, 1.0])
        distance_guess = float(np.clip(T_wall_from_projector_prior[2, 3] / max(-n_p[2], 0.05), 0.3, 15.0))
        incidence_guess = float(np.degrees(np.arctan2(-n_p[0], -n_p[2])))
        self.registration = None
        self.refused_registration = None
        self.head_slipped = False
        self.rig_failure = None
        uncertainty = self._uncertainty()
        try:
            pattern = choose_pattern(views, distance_guess, incidence_guess)
            left, right = self.robot.capture(pattern.image())
            self.last_pattern_capture = (pattern, left, right, head)
            try:
                plane = estimate_plane(left, right, pattern, views, uncertainty=uncertainty)
            except NotEnoughEvidenceError as err:
                if err.code != EvidenceCode.PROJECTOR_POSE_OFF:
                    raise
                # The head model misplaces the projector (head re-mounted, head calibration off): measure the
                # projector's pose from the pattern itself; the closed loop and the gate still judge the result.
                plane = estimate_plane(left, right, pattern, views, uncertainty=Uncertainty(
                    projector_rotation_deg=HEAD_MODEL_FALLBACK_DEG, projector_translation_m=HEAD_MODEL_FALLBACK_M,
                    stereo_draws=self.stereo_draws))
                self.head_slipped = True
                self.log.append(f"head model disagrees with the pattern (projector "
                                f"{plane.projector_correction_deg:.2f}° / {plane.projector_correction_m * 1000:.1f} mm "
                                "off): its pose was measured from the pattern instead — recalibrate the head")
        except InputError as err:  # the estimator's "not enough evidence" (or pictures that do not fit the rig)
            self.pose_failure = _why_declined(err)
            self.log.append(f"wall pose: {self.pose_failure}")
            return None
        # when the pattern measured the projector freely: is what it found a slipped head?
        rig_failure = self._not_a_head_slip(head, views, plane, uncertainty) if self.head_slipped else None
        scan = self.robot.laser_points()
        try:
            fused = self.pose_from_plane(plane, views, scan, (left, right))
        except InputError as err:
            if rig_failure:  # a rig in doubt explains a wall pose that does not fit either: say that
                self._refuse_rig(rig_failure)
                return None
            self.pose_failure = _why_declined(err)
            self.log.append(f"wall pose: {self.pose_failure}")
            return None
        T_wall_from_robot, T_robot_from_projector = fused.T_wall_from_robot, fused.T_robot_from_projector
        in_plane_sigma, roll_sigma_rad = fused.in_plane_sigma_m, fused.roll_sigma_rad
        if fused.source:
            source = fused.source
        self.pose_failure = None
        T_wall_from_projector = T_wall_from_robot @ T_robot_from_projector
        aim = registration.aim_point_on_wall(T_wall_from_projector, self.projector_intr)
        distance = float(np.linalg.norm(aim - T_wall_from_projector[:3, 3]))
        inc = registration.incidence_deg(T_wall_from_projector)
        footprint = registration.pixel_footprint_m(T_wall_from_projector, self.projector_intr)
        calib_px = _quality(self.rig, "projector", "rms_px")
        # where the map is drawn (on the map and in the image) and how well each part is registered there
        drawn = registration.choose_marks(T_wall_from_projector, self.projector_intr, self.wall_map.extent,
                                          grid=(16, 10), border=0.02)
        # the fused pose's own error at each drawn point, from its full covariance (turns of the robot move the
        # far points, and a heading or pitch error moves every point by the distance to the wall)
        pose_sigma = None if fused.covariance is None else \
            registration.pose_sigma_on_wall_m(drawn, T_wall_from_robot, fused.covariance)
        terms = registration.registration_sigma_terms(
            plane.centre_distance_95_m, plane.normal_95_deg, T_wall_from_projector, drawn, aim[:2],
            in_plane_sigma if pose_sigma is None else fused.frame_sigma_m, footprint, calib_px, roll_sigma_rad,
            pose_sigma_m=pose_sigma)
        local = terms.total
        trusted = registration.trusted_region(drawn, local, self.tolerance_m)
        cut_by = registration.why_cut(terms, drawn, ~registration.within_tolerance(local, self.tolerance_m),
                                      T_wall_from_robot, fused.covariance)
        sigma = trusted.sigma_m if trusted.usable else (float(local.max()) if len(local) else float("inf"))
        # the laser against the cameras' plane alone (the fused pose already holds the laser)
        laser_offset = None if scan is None else registration.laser_plane_offset_m(
            registration.snap_to_plane(T_wall_from_robot, plane.normal, plane.distance), scan, aim[0],
            plane.covariance)
        self.registration = Registration(head, T_wall_from_robot, T_wall_from_projector, plane, sigma, source,
                                         distance, inc, footprint, scan, laser_offset, trusted,
                                         in_plane_sigma_m=in_plane_sigma, roll_sigma_rad=roll_sigma_rad,
                                         calibration_px=calib_px, pose_covariance=fused.covariance,
                                         frame_sigma_m=fused.frame_sigma_m, cut_by=cut_by)
        if rig_failure:  # kept aside, not used: what a refused rig would have shown (the bench judges it)
            self.refused_registration, self.registration = self.registration, None
            self._refuse_rig(rig_failure)
            return None
        self.log.append(f"wall pose: {plane.corners} corners, σ {sigma * 1000:.2f} mm on the wall, "
                        f"{distance:.2f} m at {inc:.0f}°, in-plane from {source}")
        if cut_by:
            self.log.append(f"map cut to {100 * trusted.share:.0f} % by {cut_by}")
        return self.registration

    def _refuse_rig(self, why: str) -> None:
        """No registration: the rig file does not describe this robot (the gate says so, "rig in doubt")."""
        self.rig_failure = why
        self.log.append(f"rig in doubt: {why}")

    def _not_a_head_slip(self, head: tuple[float, float], views: ViewRig, plane: PlaneEstimate,
                         uncertainty: Uncertainty) -> str | None:
        """Why the projector's pose measured from the pattern cannot be a slipped head (None: it can).

        A mount that slipped turns the projector about the head's joints; a camera mount, projector lens or
        head that differs from the rig file moves it otherwise. Such a rig measures the wall and the projector
        in the same wrong frame, so the closed loop finds nothing amiss while the map lands centimetres off:
        what no turn of the head explains, beyond 4 σ of the head model's prior, refuses the registration.
        Along the projector's axis the pattern cannot tell a nearer projector from a longer focal length (the map
        drawn with the measured pose stays right there): only what lies across the axis counts."""
        if self.rig.head is None:
            return None
        T_robot_from_projector = views.T_robot_from_camera_left @ plane.T_camera_left_from_projector
        slip = self.rig.head.joint_slip(head, T_robot_from_projector, uncertainty.projector_rotation_deg,
                                        uncertainty.projector_translation_m)
        axis = T_robot_from_projector[:3, 2]
        across = slip.unexplained_translation_m - float(slip.unexplained_translation_m @ axis) * axis
        across_m = float(np.linalg.norm(across))
        limit_deg = MAX_NUISANCE_SIGMAS * uncertainty.projector_rotation_deg
        limit_m = MAX_NUISANCE_SIGMAS * uncertainty.projector_translation_m
        if slip.unexplained_deg <= limit_deg and across_m <= limit_m:
            return None
        return (f"the projector sits {plane.projector_correction_deg:.2f}° / "
                f"{1000 * plane.projector_correction_m:.1f} mm from where the head model puts it, and no turn of "
                f"the head explains {slip.unexplained_deg:.2f}° / {1000 * across_m:.1f} mm across its axis (at most "
                f"{limit_deg:.2f}° / {1000 * limit_m:.0f} mm): the rig file's camera mount, projector or head does "
                "not fit this robot — recalibrate it (`arproj calibrate`)")

    def verify(self) -> registration.ClosedLoopResult | None:
        """The closed loop: project check marks, photograph them, measure where they landed, correct a small
        mean offset. Returns the measurement (errors before the correction)."""
        reg = self.registration
        if reg is None:
            return None
        cam_l, cam_r = self.rig.intrinsics["camera_left"], self.rig.intrinsics["camera_right"]
        T_robot_from_left = self.rig.pose("T_robot_from_camera_left")
        T_right_from_left = self.rig.pose("T_camera_right_from_camera_left")
        T_wall_uncorrected = make_pose(None, [-reg.correction_xy[0], -reg.correction_xy[1], 0.0]) \
            @ reg.T_wall_from_projector
        T_robot_from_right = T_robot_from_left @ invert(T_right_from_left)
        radius_m = registration.mark_radius_m(reg.distance_m, cam_l)
        r_px = radius_m * cam_l.fx / reg.distance_m

        def seen_by_both(points: NDArray[np.float64]) -> NDArray[np.float64]:
            # a mark neither camera can photograph cannot be checked: it is not projected nor counted as lost
            keep = np.ones(len(points), bool)
            on_wall = np.column_stack([points, np.zeros(len(points))])
            for T_robot_from_cam, cam in ((T_robot_from_left, cam_l), (T_robot_from_right, cam_r)):
                p_cam = transform_points(invert(reg.T_wall_from_robot @ T_robot_from_cam), on_wall)
                keep &= registration.project_in_view(cam, p_cam, 2 * r_px / min(cam.width, cam.height))[1]
            return points[keep]

        candidates = registration.choose_marks(T_wall_uncorrected, self.projector_intr, self.wall_map.extent)
        checked = None if reg.trusted is None else reg.trusted.checked_polygon
        if checked is not None:  # verify what may be shown, not the rest
            dense = registration.choose_marks(T_wall_uncorrected, self.projector_intr, self.wall_map.extent,
                                              grid=(16, 10))
            candidates = dense[registration.inside_polygon(dense, checked)]
        marks = seen_by_both(candidates)
        if checked is not None:
            step = max(1, int(np.ceil(len(marks) / CLOSED_LOOP_MARKS)))
            marks = marks[::step]  # as many marks as usual, spread over the trusted part the cameras see
        if len(marks) < tol.CLOSED_LOOP_MIN_FEATURES:
            # too few marks the cameras can photograph: the map drawn there cannot be checked, so every mark it
            # would have had counts as unseen (the gate then refuses, "pattern lost"), never as none expected
            reg.loop = registration.ClosedLoopResult(candidates, np.zeros((0, 2)), np.zeros(len(candidates), bool),
                                                     float("nan"), float("nan"))
            return reg.loop
        self.map_projector.set_check_marks(marks, radius_m)
        frame = self.map_projector.render(T_wall_uncorrected)
        left, right = self.robot.capture(frame)
        uv_l = registration.predict_camera_pixels(marks, reg.T_wall_from_robot, T_robot_from_left, cam_l)
        uv_r = registration.predict_camera_pixels(marks, reg.T_wall_from_robot, T_robot_from_right, cam_r)
        found_l = registration.find_marks(left, uv_l, r_px)
        found_r = registration.find_marks(right, uv_r, r_px)
        loop = registration.measure_marks(marks, found_l, found_r, cam_l, cam_r, T_right_from_left,
                                          reg.T_wall_from_robot @ T_robot_from_left)
        reg.loop = loop
        offset = loop.offset_xy
        if loop.seen.sum() >= tol.CLOSED_LOOP_MIN_FEATURES and np.linalg.norm(offset) <= \
                tol.CLOSED_LOOP_MAX_CORRECTION_M:
            # content drawn at c lands at c + offset: move the virtual projector by the offset (see README)
            reg.correction_xy = offset
            reg.T_wall_from_projector = make_pose(None, [offset[0], offset[1], 0.0]) @ T_wall_uncorrected
        self.log.append(loop.summary())
        return loop

    # -- evidence, gate, frame ------------------------------------------------------------------------------
    def evidence(self) -> gate.RegistrationEvidence:
        reg = self.registration
        ev = gate.RegistrationEvidence(pose_failure=self.pose_failure, rig_failure=self.rig_failure)
        now = self.head_deg()
        ev.head_failure = self.head_failure
        if reg is None:
            return ev
        ev.pose_sigma_m = reg.sigma_m
        ev.head_command_error_deg = float(max(abs(now[0] - reg.head_deg[0]), abs(now[1] - reg.head_deg[1])))
        if reg.reference_scan is not None:
            current = self.robot.laser_points()
            if current is not None:
                motion = gate.scan_motion(reg.reference_scan[:, :2], current[:, :2])
                ev.robot_motion_m = motion.displacement_at(reg.distance_m) if motion.n else np.inf
                ev.robot_motion_significant = motion.significant
        ev.laser_plane_offset_m = reg.laser_plane_offset_m
        if reg.loop is not None:
            ev.closed_loop_expected = len(reg.loop.seen)
            ev.closed_loop_errors_m = np.linalg.norm(reg.loop.errors_xy - reg.correction_xy, axis=1)
            ev.stereo_residual_px = reg.loop.residual_px if reg.loop.seen.any() else None
            ev.closed_loop_field_max_m = self._loop_field_max_m(reg)
        if reg.trusted is not None and ev.closed_loop_errors_m is not None and len(ev.closed_loop_errors_m):
            # the map only where the pose's 95 % error plus what the loop and the laser measured hold
            reg.trusted, reg.sigma_m = registration.checked_region(
                reg.trusted, ev.closed_loop_worst_m + ev.robot_motion_m, self.tolerance_m)
            ev.pose_sigma_m = reg.sigma_m
        return ev

    @staticmethod
    def _loop_field_max_m(reg: Registration) -> float:
        """The closed loop's error field (after its correction) at its worst over what is drawn: the trusted
        region's sample points inside its polygon; NaN without a loop or without samples."""
        region, loop = reg.trusted, reg.loop
        if loop is None or region is None or region.points_xy is None:
            return float("nan")
        drawn = region.points_xy if region.polygon is None else \
            region.points_xy[registration.inside_polygon(region.points_xy, region.polygon)]
        return registration.field_worst_m(loop.marks_xy[loop.seen], loop.errors_xy - reg.correction_xy, drawn)

    def decide(self) -> gate.GateDecision:
        self.last_evidence = self.evidence()
        self.last_decision = gate.decide(self.last_evidence, self.tolerance_m)
        return self.last_decision

    def render_frame(self, decision: gate.GateDecision) -> NDArray[np.uint8]:
        """The map (pre-warped, with legend and status) when the gate is open, else the warning."""
        intr = self.projector_intr
        slipped = [SAY_HEAD_SLIPPED] if self.head_slipped else []
        if not decision.show_map or self.registration is None:
            self.last_words = decision.craftsman + [w for w in slipped if w not in decision.craftsman]
            self.last_legend = None
            return overlays.warning_frame(intr.width, intr.height, self.last_words)
        trusted = self.registration.trusted
        clip = None if trusted is None else trusted.polygon
        self.map_projector.set_overlays(decision.registration_sigma_m, self.drill_xy, clip=clip)
        frame = self.map_projector.render(self.registration.T_wall_from_projector).copy()
        lines = [overlays.say_accuracy(decision.bound_m)]
        if clip is not None:
            lines.append(overlays.say_clipped(trusted.share))
        raster = self.map_projector.raster
        if raster is not None and raster.zone_texels:
            lines.append(overlays.say_zones())
        if self.drill_xy is not None:
            lines.append(overlays.say_drill(self.drill_check(self.drill_xy)))
        self.last_words = slipped + lines  # the slip first: it is what the craftsman must act on
        busy, mapped = self.map_projector.legend_layers()
        self.last_legend = overlays.legend_layout(frame.shape, self.last_words, self.legend_classes(), busy, mapped)
        overlays.draw_layout(frame, self.last_legend)
        return frame

    def legend_classes(self) -> tuple[str, ...]:
        """The classes the legend lists: those of the map's objects (the wall's, not every class there is)."""
        raster = self.map_projector.map_raster
        return raster.classes if raster is not None else tuple(sorted({o.cls for o in self.wall_map.objects}))

    def update(self, force: bool = False, show: bool = True) -> gate.GateDecision:
        """One cycle: re-estimate when needed, verify, decide, show (show=False: decide only, the frame not
        drawn — the benchmark's degraded scenes judge the decision). Returns the gate's decision."""
        needs_estimate = force or self.registration is None
        if not needs_estimate:
            ev = self.evidence()
            needs_estimate = ev.head_command_error_deg > HEAD_MOVED_DEG or gate.robot_moved(ev)
            if needs_estimate:
                self.log.append("head or robot moved: re-estimating the wall pose")
        if needs_estimate:
            self.estimate()
        if self.closed_loop and self.registration is not None:
            loop = self.verify()
            # off by more than a small shift, or by a shift that leaves the far part of the map off (the field
            # the marks measured, after the correction): measure the wall pose again
            if loop is not None and loop.seen.sum() >= tol.CLOSED_LOOP_MIN_FEATURES and not needs_estimate and \
                    (np.linalg.norm(loop.offset_xy) > tol.CLOSED_LOOP_MAX_CORRECTION_M
                     or self._loop_field_max_m(self.registration) > tol.CLOSED_LOOP_MAX_CORRECTION_M):
                self.log.append("projection landed off: re-estimating the wall pose")
                if self.estimate() is not None:
                    # the head reported no motion, yet the picture landed off: its mount slipped (or the
                    # projector moved on it); the new estimate measured it, the craftsman is told on the frame
                    self.head_slipped = True
                    self.verify()
        decision = self.decide()
        if show:
            self.last_frame = self.render_frame(decision)
            self.robot.show(self.last_frame)
        if not decision.show_map:
            self.log.append("WARNING shown: " + "; ".join(decision.reasons))
        return decision
