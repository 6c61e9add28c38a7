"""Marker detectors: coloured balls, blinking lights, printed tags, banded cylinders.

Each image detector takes an OpenCV BGR image and the rig's markers of its
kind and returns a :class:`DetectionResult`; blinking lights need a stream
and are found by :class:`BlinkTracker`.  Which detector finds which marker
is this module's one table, keyed by :class:`mutloc.MarkerKind`.
"""

from __future__ import annotations

import importlib
from typing import Any, Callable

from ..core.rig import MarkerKind
from .base import Detection, DetectionResult, as_bgr

__all__ = ["Detection", "DetectionResult", "as_bgr", "detect_balls", "detect_tags", "detect_cylinders",
           "BlinkTracker", "IMAGE_DETECTORS", "SEQUENCE_DETECTORS", "image_detector", "detect_image"]

#: kind -> (module, function) of the detector that finds it in one image.
IMAGE_DETECTORS: dict[MarkerKind, tuple[str, str]] = {
    MarkerKind.BALL: ("balls", "detect_balls"),
    MarkerKind.TAG: ("tags", "detect_tags"),
    MarkerKind.CYLINDER: ("cylinders", "detect_cylinders"),
}
#: kind -> (module, class) of the detector that needs a stream of images.
SEQUENCE_DETECTORS: dict[MarkerKind, tuple[str, str]] = {
    MarkerKind.LIGHT: ("blink", "BlinkTracker"),
}

_LAZY = {fn: mod for mod, fn in [*IMAGE_DETECTORS.values(), *SEQUENCE_DETECTORS.values()]}


def image_detector(kind: MarkerKind) -> Callable[..., DetectionResult] | None:
    """The single-image detector of ``kind`` (None: needs a stream, or none exists)."""
    entry = IMAGE_DETECTORS.get(kind)
    if entry is None:
        return None
    return getattr(importlib.import_module(f".{entry[0]}", __name__), entry[1])


def detect_image(kind: MarkerKind, image: Any, markers: Any, camera: Any = None,
                 **options: Any) -> DetectionResult:
    """Find the markers of ``kind`` in one image taken through any lens (the raw image's pixels).

    ``camera``: the lens that took the image (:class:`~mutloc.core.camera.Camera`, ``FisheyeCamera``,
    ``OmniCamera``) or None.  A pinhole camera (or none) calls the kind's detector exactly as before; a
    wide-angle lens runs it on the lens's rectified views (:func:`.views.detect_in_views`).  ``options``
    go to the detector.  ValueError for a kind that has no single-image detector (blinking lights)."""
    detector = image_detector(kind)
    if detector is None:
        raise ValueError(f"markers of kind {kind.value!r} are not found in single images")
    from .views import detect_in_views, needs_views

    if needs_views(camera):
        return detect_in_views(detector, image, markers, camera, **options)
    return detector(image, markers, camera=camera, **options)


def __getattr__(name: str) -> Any:
    # Detectors load lazily: each pulls in its own OpenCV/Numba machinery.
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(name)
    return getattr(importlib.import_module(f".{mod}", __name__), name)
