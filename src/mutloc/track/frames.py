"""From one image per robot to a pose: detect each robot's view of the other
robot's markers, then :func:`mutloc.localize`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np

from ..api import Estimate, load_rig, localize
from ..core.rig import Marker, Rig
from ..detect.base import Detection, DetectionResult, as_bgr
from ..errors import FileFormatError, InputError, ObservationError

__all__ = ["FrameResult", "read_image", "detect_markers", "expanded_rig", "localize_images"]


@dataclass
class FrameResult:
    """Detections per observing robot and the pose they give."""

    estimate: Estimate
    detections: dict[str, DetectionResult]

    def detections_dict(self) -> dict[str, Any]:
        return {robot: det.to_dict() for robot, det in self.detections.items()}


def read_image(path: str | Path) -> np.ndarray:
    """A BGR image from a file; FileFormatError if it cannot be read."""
    p = Path(path)
    if not p.is_file():
        raise FileFormatError(f"{p}: no such image file")
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise FileFormatError(f"{p}: not a readable image")
    return img


def _check_size(rig: Rig, robot: str, image: np.ndarray, where: str) -> None:
    size = rig.robot(robot).camera.size
    if size is not None and (image.shape[1], image.shape[0]) != tuple(size):
        raise InputError(
            f"{where}: image is {image.shape[1]}x{image.shape[0]} but robot {robot!r}'s calibration is "
            f"{size[0]}x{size[1]}"
        )


def detect_markers(rig: Rig, observer: str, image: np.ndarray, targets: list[str] | None = None) -> DetectionResult:
    """Every marker of the other robots (or of ``targets``) that ``observer``'s
    image shows, by the detector each marker's rig keys call for."""
    image = as_bgr(image, f"image of robot {observer!r}")
    _check_size(rig, observer, image, f"image of robot {observer!r}")
    camera = rig.robot(observer).camera
    others = targets if targets is not None else [r for r in rig.robots if r != observer]
    markers: dict[str, Marker] = {}
    for r in others:
        markers.update(rig.robot(r).markers)
    # Derived point markers (tag corners, cylinder bands) are found through
    # their parent marker, not on their own.
    markers = {n: m for n, m in markers.items() if "tag_of" not in m.extra and "cylinder_of" not in m.extra}
    balls = {n: m for n, m in markers.items() if m.color is not None and m.tag is None}
    tags = {n: m for n, m in markers.items() if m.tag is not None}
    cylinders = {n: m for n, m in markers.items() if "cylinder" in m.extra}
    result = DetectionResult()
    if balls:
        from ..detect.balls import detect_balls

        _merge(result, detect_balls(image, balls, camera=camera))
    if tags:
        from ..detect.tags import corner_marker_names, detect_tags, tag_corner_points

        found = detect_tags(image, tags, camera=camera)
        # An oriented tag's corners are markers of their own (NAME#0..3).
        for name, det in list(found.detections.items()):
            if det.corners is not None and tag_corner_points(tags[name]) is not None:
                for cname, uv in zip(corner_marker_names(name), det.corners):
                    found.detections[cname] = Detection(cname, np.asarray(uv, float), det.score)
        _merge(result, found)
    if cylinders:
        from ..detect.cylinders import detect_cylinders

        _merge(result, detect_cylinders(image, cylinders, camera=camera))
    handled = set(balls) | set(tags) | set(cylinders)
    # Blinking lights need a sequence: a single image cannot show them.
    result.missing.extend(n for n in markers if n not in handled and n not in result.missing)
    return result


def expanded_rig(rig: Rig) -> Rig:
    """The rig with oriented tags' corners and cylinders' bands as markers,
    so every point a detector reports has a known position."""
    markers = [m for r in rig.robots.values() for m in r.markers.values()]
    if any(m.tag is not None and isinstance(m.tag, Mapping) and "rotation" in m.tag for m in markers):
        from ..detect.tags import expand_tag_corners

        rig = expand_tag_corners(rig)
    if any("cylinder" in m.extra for m in markers):
        from ..detect.cylinders import expand_cylinder_bands

        rig = expand_cylinder_bands(rig)
    return rig


def prepare_pair(rig: Any, inputs: Mapping[str, Any], source: str | None, target: str | None,
                 what: str) -> tuple[Rig, str, str]:
    """The expanded rig and the (source, target) pair, checking that every
    input names a robot of the rig and both robots of the pair have one."""
    rig = expanded_rig(load_rig(rig))
    source, target = rig.default_pair(source, target)
    for robot in inputs:
        rig.robot(robot)
    for robot in (source, target):
        if robot not in inputs:
            raise ObservationError(f"no {what} for robot {robot!r}")
    return rig, source, target


def _merge(into: DetectionResult, other: DetectionResult) -> None:
    into.detections.update(other.detections)
    into.missing.extend(m for m in other.missing if m not in into.missing)


def localize_images(rig: Any, images: Mapping[str, Any], source: str | None = None, target: str | None = None, *,
                    pixel_sigma: float = 1.0) -> FrameResult:
    """Detect the markers in one image per robot (arrays or file paths) and
    localize ``source`` in ``target``'s frame."""
    rig, source, target = prepare_pair(rig, images, source, target, "image")
    detections: dict[str, DetectionResult] = {}
    observations: dict[str, dict[str, tuple[float, float]]] = {}
    for observer, other in ((source, target), (target, source)):
        img = images[observer]
        if isinstance(img, (str, Path)):
            img = read_image(img)
        det = detect_markers(rig, observer, img, targets=[other])
        detections[observer] = det
        observations[observer] = det.pixels()
    n = sum(len(v) for v in observations.values())
    if n < 3:
        found = ", ".join(f"{r}: {sorted(v)}" for r, v in observations.items())
        raise ObservationError(f"only {n} markers detected ({found}); at least three are needed")
    est = localize(rig, observations, source, target, pixel_sigma=pixel_sigma)
    return FrameResult(est, detections)
