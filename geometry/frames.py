"""The fixed frame names (REP 105 style: each frame has one parent).

    room ─┬─ wall            one per wall plane; origin at the wall's lower-left corner seen from the room,
          │                  x right along the wall, y up, z out of the wall into the room (metres)
          └─ robot ─┬─ head ── projector      head: the moving plate of the 3-DOF pan/tilt head
                    ├─ camera_left ── camera_right
                    ├─ laser                 the 2-D laser, fixed to the body (its scan plane z = 0)
                    └─ scanner               the wall scanner on the xy linear drives

Camera-like frames (projector, camera_left, camera_right) use OpenCV's convention: x right, y down,
z forward along the optical axis. OpenGL's convention appears only inside the renderer.
Poses are 4x4 float64 arrays named T_<dst>_from_<src>: p_dst = T_dst_from_src @ p_src.
"""

from geometry.errors import InputError

FRAMES: tuple[str, ...] = (
    "room",
    "wall",
    "robot",
    "head",
    "projector",
    "camera_left",
    "camera_right",
    "scanner",
    "laser",
)


def parse_pose_name(name: str) -> tuple[str, str]:
    """Split 'T_dst_from_src' into (dst, src), checking both are known frames."""
    if not name.startswith("T_") or "_from_" not in name:
        raise InputError(f"pose name {name!r} is not of the form T_<dst>_from_<src>",
                         f"use frame names from {', '.join(FRAMES)}")
    dst, src = name[2:].split("_from_", 1)
    for frame in (dst, src):
        if frame not in FRAMES:
            raise InputError(f"pose name {name!r} uses unknown frame {frame!r}",
                             f"known frames: {', '.join(FRAMES)}")
    return dst, src
