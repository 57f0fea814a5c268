"""Wall pose from a projected checker pattern seen by the stereo cameras, with the projector as third view.

    pattern = choose_pattern(views, distance_m=2.0)            # what to project (pattern.image())
    plane = estimate_plane(left_image, right_image, pattern, views)   # or NotEnoughEvidenceError(reason)
    pose = estimate_wall_pose(plane, wall, room, localized_T_room_from_robot, T_robot_from_projector, laser)
    pose = estimate_wall_pose(..., tilt=TiltMeasurement(roll, pitch, σ_roll, σ_pitch))  # an inclinometer's, deg

views is a ViewRig (ViewRig.from_rig(geometry.Rig, head_angles) or arproj.sim.wallpose_trial.calibrated_views).
The paper's single-square method is wallpose.baseline; numeric tolerances live in limits.py.
"""

from wallpose.estimate import PlaneEstimate, Uncertainty, estimate_from_detections, estimate_plane
from wallpose.evidence import NotEnoughEvidenceError
from wallpose.pattern import CheckerPattern, choose_pattern
from wallpose.pose import RoomMap, TiltMeasurement, WallPose, estimate_wall_pose
from wallpose.rig import ViewRig

__all__ = [
    "CheckerPattern",
    "NotEnoughEvidenceError",
    "PlaneEstimate",
    "RoomMap",
    "TiltMeasurement",
    "Uncertainty",
    "ViewRig",
    "WallPose",
    "choose_pattern",
    "estimate_from_detections",
    "estimate_plane",
    "estimate_wall_pose",
]
