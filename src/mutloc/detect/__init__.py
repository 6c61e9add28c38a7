"""Marker detectors: coloured balls, blinking lights, printed tags.

Each takes an OpenCV BGR image (or, for blinking lights, a stream of them)
and the rig's markers, and returns a :class:`DetectionResult`.
"""

from .base import Detection, DetectionResult, as_bgr

__all__ = ["Detection", "DetectionResult", "as_bgr", "detect_balls", "detect_tags", "BlinkTracker"]


def __getattr__(name: str):
    # Detectors load lazily: each pulls in its own OpenCV/Numba machinery.
    if name == "detect_balls":
        from .balls import detect_balls

        return detect_balls
    if name == "detect_tags":
        from .tags import detect_tags

        return detect_tags
    if name == "BlinkTracker":
        from .blink import BlinkTracker

        return BlinkTracker
    raise AttributeError(name)
