"""One row of a track: what became of one record (SPEC "Filtered tracking")."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..api import Estimate
from ..core.observations import ObservationSet
from ..detect.base import DetectionResult
from .status import FrameStatus

__all__ = ["TrackRow"]


@dataclass
class TrackRow:
    """One record of a track -- one camera's frame, the frames of both
    cameras within the tolerance, or an observation log's line -- with what
    became of it (``t_source``/``t_target``: each camera's frame time, None
    where the record holds no frame of it)."""

    t: float
    t_source: float | None
    t_target: float | None
    status: FrameStatus
    reason: str = ""
    estimate: Estimate | None = None
    detections: dict[str, DetectionResult] = field(default_factory=dict)
    observations: ObservationSet | None = None
