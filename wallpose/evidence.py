"""'Not enough evidence': the estimator's way to decline, with the reason, instead of a confident wrong pose."""

from __future__ import annotations

from geometry.errors import InputError


class NotEnoughEvidenceError(InputError):
    """The images do not support a trustworthy wall pose. `code` names the case for programs:

    no_pattern, too_few_corners, not_one_plane, views_disagree, too_uncertain, no_wall_frame.
    """

    def __init__(self, code: str, message: str, hint: str | None = None) -> None:
        self.code = code
        super().__init__(f"not enough evidence for the wall pose: {message}", hint)
