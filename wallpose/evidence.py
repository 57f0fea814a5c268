"""'Not enough evidence': the estimator's way to decline, with the reason, instead of a confident wrong pose."""

from __future__ import annotations

from enum import StrEnum

from geometry.errors import InputError


class EvidenceCode(StrEnum):
    """Why a wall pose was declined, for programs to act on (never the message's words). The values are what
    `--json` output and benchmark tables show."""

    NO_PATTERN = "no_pattern"  # the pattern (or the baseline's square) is not in the images
    TOO_FEW_CORNERS = "too_few_corners"  # fewer corners seen by both cameras than a trustworthy plane needs
    NOT_ONE_PLANE = "not_one_plane"  # the corners lie on several surfaces
    VIEWS_DISAGREE = "views_disagree"  # the images disagree with the calibrated rig or with each other
    # the projector is not where the rig puts it (beyond its prior) while the cameras agree with the rig: its
    # pose may be measured from the pattern instead (a head re-mounted, a head calibration off)
    PROJECTOR_POSE_OFF = "projector_pose_off"
    TOO_UNCERTAIN = "too_uncertain"  # the corners found constrain the wall too loosely
    NO_WALL_FRAME = "no_wall_frame"  # the measured plane is not where the map's wall is


class NotEnoughEvidenceError(InputError):
    """The images do not support a trustworthy wall pose. `code` names the case for programs, `reason` says it
    for people (the message without its 'not enough evidence' prefix)."""

    def __init__(self, code: EvidenceCode, reason: str, hint: str | None = None) -> None:
        self.code = code
        self.reason = reason
        super().__init__(f"not enough evidence for the wall pose: {reason}", hint)
