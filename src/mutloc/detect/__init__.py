"""Marker detectors: coloured balls, blinking lights, printed tags, banded cylinders."""

from .base import Detection, DetectionResult, as_bgr

__all__ = ["Detection", "DetectionResult", "as_bgr"]
