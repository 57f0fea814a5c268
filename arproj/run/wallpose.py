"""What `arproj wallpose` runs: the wall's pose measured once from the projected pattern, drawn and returned.

On the simulated site the figures are compared with its truth; with a calibrated rig they come from the two
cameras' photos of the pattern (`pattern_out` writes the image to project).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geometry.errors import InputError
from geometry.inputs import read_image

# The simulated room lights every surface alike; in a real room the walls meeting at a corner differ in how they
# are lit. The --sim site gives wall 0's neighbours another reflectance so that its corners show (wall 0 as is).
SIM_SIDE_WALL_ALBEDO = 0.6


def parse_head_angles(text: str) -> np.ndarray:
    """--head "pan,tilt,roll" (degrees) as a (3,) array; InputError if it is not three numbers."""
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise InputError(f"--head {text!r} is not three numbers", "e.g. --head 0,5.5,0 (pan, tilt, roll °)") from None
    if values.shape != (3,):
        raise InputError(f"--head {text!r} has {values.size} angles; pan, tilt and roll are needed")
    return values


def _read_gray(path: Path, option: str) -> np.ndarray:
    return read_image(path, f"{option} image", hint="pass a PNG or JPEG photo of the pattern")


def draw_result(image: np.ndarray, corners: np.ndarray, used: np.ndarray, lines: list[str], path: Path,
                edge_points: list[np.ndarray] | None = None) -> Path:
    """The camera image with the corners found (green: used, red: left out), the wall edges' points used (blue)
    and the figures written on it."""
    import cv2

    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    for points in edge_points or []:
        for x, y in points:
            cv2.circle(canvas, (round(x), round(y)), 2, (255, 120, 0), -1, cv2.LINE_AA)
    for (x, y), ok in zip(corners, used, strict=True):
        cv2.circle(canvas, (round(x), round(y)), 3, (0, 200, 0) if ok else (0, 0, 255), 1, cv2.LINE_AA)
    for k, text in enumerate(lines):
        origin = (12, 26 + 22 * k)
        # A dark outline from the same thin text shifted by a pixel: OpenCV 5 lays out thicker text wider, so
        # a thick dark copy underneath would not line up.
        for dx, dy in ((-1, -1), (-1, 1), (1, -1), (1, 1), (0, 2)):
            cv2.putText(canvas, text, (origin[0] + dx, origin[1] + dy), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1,
                        cv2.LINE_AA)
        cv2.putText(canvas, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), canvas)
    return path


@dataclass
class WallposeSettings:
    """What `arproj wallpose` is asked to do: on the simulated site (compared with its truth), or from a rig
    and the two cameras' photos of the projected pattern."""

    sim: bool = False                # the simulated site, and its truth beside the estimate
    distance: float = 2.0            # approximate distance to the wall, m (sizes the pattern; sim: where the
    incidence: float = 0.0           #   robot stands) and incidence angle on it, °
    seed: int = 0                    # of the simulated site
    along: float | None = None       # sim: aim point along wall 0, m from its left end (None: the middle)
    rig: Path | None = None          # calibrated rig folder (rig.yaml), without sim
    head: str | None = None          # with rig: the head's current "pan,tilt,roll" in degrees
    left: Path | None = None         # with rig: the cameras' photos of the projected pattern
    right: Path | None = None
    pattern_out: Path | None = None  # write the pattern to project (PNG)
    picture: Path = Path("wallpose.png")  # where to draw the result


def run_wallpose(settings: WallposeSettings) -> dict:
    """Everything `arproj wallpose` does; returns the figures it prints."""
    s = settings
    from wallpose.detect import detect
    from wallpose.estimate import estimate_from_detections
    from wallpose.pattern import choose_pattern
    from wallpose.rig import ViewRig

    if not s.sim and s.rig is None:
        raise InputError("no rig given", "pass --sim for the simulated site, or --rig FOLDER --head PAN,TILT,ROLL")
    site = None
    if s.sim:
        from arproj.sim import Site
        from arproj.sim.wallpose_trial import LARGE_ROOM, calibrated_views, photograph_pair

        room = {**LARGE_ROOM, "walls": {1: {"albedo": SIM_SIDE_WALL_ALBEDO}, 3: {"albedo": SIM_SIDE_WALL_ALBEDO}}}
        site = Site.build(seed=s.seed, room=room)
        site.place_robot(s.distance, s.incidence, along_m=s.along, aim_height_m=1.1)
        views = calibrated_views(site)
    else:
        from geometry.rig import Rig

        if s.head is None:
            raise InputError("--head is needed with --rig", "the head's current pan,tilt,roll in degrees")
        views = ViewRig.from_rig(Rig.load(s.rig), parse_head_angles(s.head))
    pattern = choose_pattern(views, s.distance, s.incidence)
    result: dict = {"pattern": {"square_px": pattern.square_px, "squares": [pattern.cols, pattern.rows],
                                "markers": len(pattern.marker_blocks), "corners": pattern.n_corners}}
    if s.pattern_out is not None:
        import cv2

        s.pattern_out.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(s.pattern_out), pattern.image())
        result["pattern_image"] = str(s.pattern_out)
        if not s.sim and s.left is None:
            return result
    try:
        if s.sim:
            image_l, image_r = photograph_pair(site, pattern.image(), np.random.default_rng(s.seed))
        else:
            if s.left is None or s.right is None:
                raise InputError("--left and --right photos are needed with --rig",
                                 "photograph the projected pattern (see --pattern-out) with both cameras")
            image_l, image_r = _read_gray(s.left, "--left"), _read_gray(s.right, "--right")
        det_l = detect(image_l, pattern, views.camera_left, views.projector, "camera_left")
        det_r = detect(image_r, pattern, views.camera_right, views.projector, "camera_right")
        est = estimate_from_detections(det_l, det_r, pattern, views, seed=s.seed)
        result["plane"] = {
            "normal_robot": est.normal.round(6).tolist(), "distance_m": round(est.distance, 5),
            "normal_95_deg": round(est.normal_95_deg, 4),
            "centre_distance_95_mm": round(1000 * est.centre_distance_95_m, 3),
            "corners_used": est.corners, "corners_matched": est.matched, "corner_noise_px": round(est.sigma_px, 4),
            "projector_correction_deg": round(est.projector_correction_deg, 4), "warnings": est.warnings}
        lines = [f"normal ±{est.normal_95_deg:.3f} deg, distance {est.distance:.4f} m "
                 f"±{1000 * est.centre_distance_95_m:.2f} mm (95%)",
                 f"{est.corners} corners, noise {est.sigma_px:.3f} px"]
        edge_points: list[np.ndarray] = []
        if site is not None:
            from arproj.sim.wallpose_trial import room_map, true_landing, wall_truth
            from geometry.poses import invert, rotation_angle_deg
            from wallpose.edges import camera_images
            from wallpose.pose import estimate_wall_pose

            truth = wall_truth(site)
            centre = true_landing(site, pattern.centre_px[None])[0]
            result["truth"] = {"normal_error_deg": round(est.normal_error_deg(truth.normal), 5),
                               "distance_error_mm": round(1000 * abs(est.offset_at(centre)), 4)}
            T_robot_from_projector = views.T_robot_from_camera_left @ est.T_camera_left_from_projector
            pose = estimate_wall_pose(est, 0, room_map(site), site.localized_T_room_from_robot,
                                      T_robot_from_projector, site.laser_scan().points_robot(),
                                      camera_images=camera_images(views, image_l, image_r), projector=views.projector)
            T_true = invert(site.walls[0].T_room_from_wall) @ site.T_room_from_robot
            result["pose"] = {
                "T_wall_from_robot": pose.T_wall_from_robot.round(6).tolist(),
                "sigma_mm_along_height_distance": [round(1000 * v, 3) for v in
                                                   (pose.sigma_along_m, pose.sigma_height_m, pose.sigma_distance_m)],
                "error_mm_along_height_distance":
                    (1000 * (pose.T_wall_from_robot[:3, 3] - T_true[:3, 3])).round(3).tolist(),
                "rotation_error_deg": round(rotation_angle_deg(pose.T_wall_from_robot, T_true), 4),
                "sources": pose.sources,
                "edges": [{"edge": o.edge, "camera": o.camera, "points": len(o.pixels),
                           "noise_px": round(o.sigma_px, 3), "contrast_grey": round(o.contrast, 1)}
                          for o in pose.edges],
                "edges_rejected": pose.edges_rejected}
            edge_points = [o.pixels for o in pose.edges if o.camera == "camera_left"]
            lines.append(f"truth: normal off by {result['truth']['normal_error_deg']:.4f} deg, "
                         f"{result['truth']['distance_error_mm']:.3f} mm at the centre")
        used = np.isin(det_l.corner_ids, est.inlier_ids)
        result["picture"] = str(draw_result(image_l, det_l.pixels, used, lines, s.picture, edge_points))
    finally:
        if site is not None:
            site.release()
    return result
