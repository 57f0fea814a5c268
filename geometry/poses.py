"""4x4 homogeneous poses named T_dst_from_src, rotations, and the one place OpenCV's rvec/tvec are converted.

Points are (n, 3) float64 arrays in metres; p_dst = T_dst_from_src @ p_src, so chains read right to left.
Rotation vectors (axis times angle in radians, OpenCV's rvec) go to and from matrices through scipy's Rotation,
for one vector or a batch alike.
"""

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

Pose = NDArray[np.float64]

# OpenCV camera (x right, y down, z forward) to OpenGL camera (x right, y up, z backward).
T_GL_FROM_CV: Pose = np.diag([1.0, -1.0, -1.0, 1.0])


def make_pose(R: ArrayLike | None = None, t: ArrayLike | None = None) -> Pose:
    """A 4x4 pose from a 3x3 rotation and a translation (metres)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, dtype=np.float64).reshape(3, 3)
    if t is not None:
        T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def invert(T: ArrayLike) -> Pose:
    """Inverse of a rigid pose (exact, without a general matrix inverse)."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    return make_pose(R.T, -R.T @ t)


def transform_points(T: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply pose T to points (n, 3) or (3,); returns the same shape."""
    T = np.asarray(T, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


def rotation_matrices(rvecs: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices (n, 3, 3) from rotation vectors (n, 3) (radians; zero gives the identity)."""
    return Rotation.from_rotvec(np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)).as_matrix()


def rotation_matrix(rvec: ArrayLike) -> NDArray[np.float64]:
    """The 3x3 rotation of one rotation vector (3,), as cv2.Rodrigues gives it."""
    return rotation_matrices(rvec)[0]


def rotation_vectors(Rs: ArrayLike) -> NDArray[np.float64]:
    """Rotation vectors (n, 3) of rotations (n, 3, 3) (the log map; angles in [0, π])."""
    return Rotation.from_matrix(np.asarray(Rs, dtype=np.float64).reshape(-1, 3, 3)).as_rotvec()


def rotation_vector(R: ArrayLike) -> NDArray[np.float64]:
    """The rotation vector (3,) of a 3x3 rotation (or a pose's rotation part)."""
    return rotation_vectors(np.asarray(R, dtype=np.float64)[:3, :3])[0]


def rotation_about(axis: ArrayLike, angle_rad: float) -> NDArray[np.float64]:
    """3x3 rotation by angle_rad about a (not necessarily unit) axis, right-handed."""
    a = np.asarray(axis, dtype=np.float64)
    return rotation_matrix(a / np.linalg.norm(a) * float(angle_rad))


def pose_from_rvec_tvec(rvec: ArrayLike, tvec: ArrayLike) -> Pose:
    """OpenCV's (rvec, tvec) as a pose. For solvePnP/calibrateCamera they are T_camera_from_board."""
    return make_pose(rotation_matrix(rvec), np.asarray(tvec, dtype=np.float64).reshape(3))


def pose_from_vector(x: ArrayLike) -> Pose:
    """The pose of a 6-vector (rotation vector, translation), the parametrisation the least-squares fits use."""
    x = np.asarray(x, dtype=np.float64).reshape(6)
    return pose_from_rvec_tvec(x[:3], x[3:])


def rvec_tvec_from_pose(T: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The inverse of pose_from_rvec_tvec: (rvec (3,), tvec (3,))."""
    T = np.asarray(T, dtype=np.float64)
    return rotation_vector(T[:3, :3]), T[:3, 3].copy()


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> Pose:
    """T_world_from_camera for an OpenCV camera at eye looking at target, image 'up' towards up."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    up = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image y points down
    return make_pose(np.column_stack([x, y, z]), eye)


def rotation_angle_deg(R_a: ArrayLike, R_b: ArrayLike | None = None) -> float:
    """Angle (degrees) of the rotation R_a, or of the rotation between R_a and R_b."""
    R = np.asarray(R_a, dtype=np.float64)[:3, :3]
    if R_b is not None:
        R = R.T @ np.asarray(R_b, dtype=np.float64)[:3, :3]
    # atan2 of sine and cosine parts: arccos of the trace alone cannot resolve angles below ~1e-6° (one ulp
    # of cos near 1 is already 8.5e-7°), which hid exact fits behind round-off.
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arctan2(s, c)))


def tilt_rotation(roll_rad: float, pitch_rad: float) -> NDArray[np.float64]:
    """3x3 R_level_from_body of a body rolled about its x (forward) and pitched about its y (left) axis, in the
    aerospace/ROS order R = Ry(pitch)·Rx(roll) (REP 103: positive roll lifts the left side, positive pitch
    lowers the nose). roll_pitch() inverts it."""
    return rotation_about((0.0, 1.0, 0.0), pitch_rad) @ rotation_about((1.0, 0.0, 0.0), roll_rad)


def roll_pitch(R_up_from_body: ArrayLike) -> tuple[float, float]:
    """(roll, pitch) rad of a body against gravity (z up in the frame R maps into), whatever its heading: what
    an inclinometer on the body reads. The up direction in the body frame is R's last row,
    (-sin p, cos p sin r, cos p cos r) for R = Rz(yaw)·Ry(p)·Rx(r)."""
    up = np.asarray(R_up_from_body, dtype=np.float64)[2, :3]
    return float(np.arctan2(up[1], up[2])), float(np.arcsin(np.clip(-up[0], -1.0, 1.0)))
