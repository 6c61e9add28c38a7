"""The closed set of per-frame statuses (SPEC "Filtered tracking").

A frame's status says what became of it; *why* travels apart, in the row's
``reason`` (free text for people, never parsed).
"""

from __future__ import annotations

from enum import Enum

__all__ = ["FrameStatus", "POSE_STATUSES"]


class FrameStatus(str, Enum):
    """What became of one input frame."""

    SOLVED = "solved"            # enough markers on its own, consistent with its noise
    UNVERIFIED = "unverified"    # exactly three markers: a pose, but nothing confirms it
    PARTIAL = "partial"          # fewer than three markers, updated through the filter
    PREDICTED = "predicted"      # no usable markers: motion model only
    REJECTED = "rejected"        # observations inconsistent (with their noise or the track); not used
    TOO_FEW = "too_few"          # fewer than three markers and no filter to use them
    FAILED = "failed"            # markers enough, but no pose explains them (reason says why)
    UNPAIRED = "unpaired"        # no frame of the other robot within the pairing tolerance
    CORRUPT = "corrupt"          # an image could not be decoded

    def __str__(self) -> str:
        return self.value


#: Statuses whose row carries a pose estimated from that frame's markers.
POSE_STATUSES = (FrameStatus.SOLVED, FrameStatus.UNVERIFIED)
