"""From one image per robot to a pose: detect each robot's view of the other
robot's markers, then :func:`mutloc.localize`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np

from ..api import Estimate, load_rig
from ..core.rig import CAMERA_SEPARATOR, DETECTED_KINDS, Marker, MarkerKind, Rig
from ..detect import detect_image, image_detector
from ..detect.base import DetectionResult, as_bgr, observations_of
from ..errors import FileFormatError, InputError, ObservationError
from .second_look import second_look
from .tag_look import first_solve, with_tags_looked_for
from .sources import Frame

__all__ = ["FrameResult", "read_image", "detect_markers", "expanded_rig", "image_keys", "localize_images",
           "observations_of"]


@dataclass
class FrameResult:
    """Detections per observing camera (``ROBOT`` or ``ROBOT/CAMERA``) and the pose they give."""

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


def _check_size(camera: Any, image: np.ndarray, where: str, observer: str) -> None:
    size = camera.size
    if size is not None and (image.shape[1], image.shape[0]) != tuple(size):
        what = "camera" if CAMERA_SEPARATOR in observer else "robot"
        raise InputError(
            f"{where}: image is {image.shape[1]}x{image.shape[0]} but {what} {observer!r}'s calibration is "
            f"{size[0]}x{size[1]}"
        )


def detect_markers(rig: Rig, observer: str, image: np.ndarray, targets: list[str] | None = None) -> DetectionResult:
    """Every marker of the other robots (or of ``targets``) that ``observer``'s
    image shows, each found by the detector of its kind (``mutloc.detect``'s
    table).  Blinking lights need a sequence: from one image they are missing.

    ``observer`` is an observation key: ``ROBOT`` (a robot with one camera) or
    ``ROBOT/CAMERA``; the camera may have any lens (a fisheye or omni image is
    searched through rectified views, :func:`mutloc.detect.detect_image`), and
    the pixels reported are always the raw image's."""
    image = as_bgr(image, f"image of robot {observer!r}")
    if CAMERA_SEPARATOR not in observer:
        rig.robot(observer)  # an unknown robot: the rig's own error, as ever
    robot, _ = rig.observer(observer)
    camera = rig.mount(observer).camera
    _check_size(camera, image, f"image of robot {observer!r}", observer)
    others = targets if targets is not None else [r for r in rig.robots if r != robot]
    by_kind: dict[MarkerKind, dict[str, Marker]] = {}
    for r in others:
        for n, m in rig.robot(r).markers.items():
            if m.kind in DETECTED_KINDS:  # derived points come with their parent
                by_kind.setdefault(m.kind, {})[n] = m
    result = DetectionResult()
    for kind, markers in by_kind.items():
        if image_detector(kind) is None:
            result.missing.extend(n for n in markers if n not in result.missing)
            continue
        found = detect_image(kind, image, markers, camera)
        if kind == MarkerKind.TAG:
            _add_tag_corners(found, markers)
        elif kind == MarkerKind.CYLINDER:
            _bands_replace_centres(found)
        result.merge(found)
    return result


def check_streams(rig: Rig, source: str, target: str, image_s: np.ndarray, image_t: np.ndarray, *,
                  what: str = "streams", option: str = "--stream/--topic") -> dict[str, DetectionResult]:
    """InputError when the first pair of images says the inputs are wrong:
    the same images for both robots (one camera's video or image given
    twice), or each robot's images showing its own markers and not the
    other's (swapped).  ``what`` and ``option`` name the inputs in the
    message (``"images"``, ``"--image"`` for one image per robot).  Returns
    what each robot's image shows of the other's markers (its detections)."""
    if image_s.shape == image_t.shape and np.array_equal(image_s, image_t):
        raise InputError(f"the {what} of {source!r} and {target!r} show the same images: one camera's "
                         f"{'video' if what == 'streams' else 'image'} given for both robots? (check {option})")
    found = {}
    seen = {}
    for robot, image in ((source, image_s), (target, image_t)):
        other = target if robot == source else source
        own = detect_markers(rig, robot, image, targets=[robot])
        seen[robot] = detect_markers(rig, robot, image, targets=[other])
        found[robot] = (len(own.detections), len(seen[robot].detections))
    if all(own >= 2 and own > theirs for own, theirs in found.values()):
        raise InputError(f"the {what} look swapped: those of {source!r} show {source!r}'s own markers and those of "
                         f"{target!r} {target!r}'s (check {option})")
    return seen


def _add_tag_corners(found: DetectionResult, tags: Mapping[str, Marker]) -> None:
    """An oriented tag's corners are markers of their own (NAME#0..3) and
    replace its centre: the centre is computed from the corners, so keeping
    it would count the same measurement twice (an optimistic covariance)."""
    from ..detect.tags import corner_detections, tag_corner_points

    for name, det in list(found.detections.items()):
        if det.corners is not None and tag_corner_points(tags[name]) is not None:
            found.detections.update(corner_detections(det))
            del found.detections[name]


def _bands_replace_centres(found: DetectionResult) -> None:
    """A cylinder's bands (NAME#bK) replace its centre: the centre is a point
    of the same fitted axis line as the bands (with an odd count, the middle
    band's very pixel), so keeping it would count the same measurement twice."""
    for name in {d.info.get("cylinder") for d in found.detections.values() if d.info} - {None}:
        found.detections.pop(name, None)


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


def _refuse_lights(rig: Rig, source: str, target: str) -> None:
    """InputError when a robot of the pair carries only blinking lights:
    found by their blink, they need a sequence of images, not one."""
    for robot in (source, target):
        kinds = {m.kind for m in rig.robot(robot).markers.values() if m.kind in DETECTED_KINDS}
        if kinds == {MarkerKind.LIGHT}:
            raise InputError(f"robot {robot!r} carries blinking lights (blink_hz): they are found by their blink, "
                             "in a sequence of images, not in one (use mutloc track)")


def prepare_pair(rig: Any, inputs: Mapping[str, Any], source: str | None, target: str | None,
                 what: str, *, cameras: bool = False) -> tuple[Rig, str, str]:
    """The expanded rig and the (source, target) pair, checking that every
    input names a robot of the rig and both robots of the pair have one.

    With ``cameras`` the inputs are keyed by camera (``ROBOT`` or ``ROBOT/CAMERA``, :func:`image_keys`) and
    robots with several cameras or any lens are welcome; else keyed by robot, each robot's one camera."""
    rig = expanded_rig(load_rig(rig))
    source, target = rig.default_pair(source, target)
    given = set(image_keys(rig, inputs, what).values()) if cameras else set(inputs)
    for robot in inputs if not cameras else ():
        rig.robot(robot)
    for robot in (source, target):
        if robot not in given:
            raise ObservationError(f"no {what} for robot {robot!r}")
    return rig, source, target


def image_keys(rig: Rig, inputs: Mapping[str, Any], what: str = "image") -> dict[str, str]:
    """``{key: robot}`` of inputs keyed by camera, as observations are (SPEC "Robots with several cameras"):
    ``ROBOT/CAMERA``, or ``ROBOT`` for a robot with one camera.  ObservationError (one line, naming the key)
    for an unknown robot or camera, a robot with several cameras named alone, or one camera given twice."""
    out: dict[str, str] = {}
    seen: dict[tuple[str, str], str] = {}
    for key in inputs:
        if not isinstance(key, str):
            raise ObservationError(f"{what} key must be ROBOT or ROBOT{CAMERA_SEPARATOR}CAMERA, got {key!r}")
        if CAMERA_SEPARATOR not in key:
            robot = rig.robot(key)  # an unknown robot: the rig's own error, as ever
            if robot.cameras is not None and len(robot.cameras) > 1:
                first = next(iter(robot.cameras))
                raise ObservationError(f"{what} {key!r}: robot {key!r} has cameras {', '.join(robot.cameras)}: "
                                       f"give one {what} per camera ({key}{CAMERA_SEPARATOR}{first}=..., ...)")
        rname, sep, cname = key.rpartition(CAMERA_SEPARATOR)
        if sep:
            robot = rig.robot(rname) if rname in rig.robots else None
            if robot is None:
                raise ObservationError(f"{what} {key!r}: unknown robot {rname!r} (rig has {sorted(rig.robots)})")
            if robot.cameras is None or cname not in robot.cameras:
                has = (f"cameras {', '.join(robot.cameras)}" if robot.cameras is not None else
                       f"one camera: name it {rname!r} alone")
                raise ObservationError(f"{what} {key!r}: unknown camera {cname!r} (robot {rname!r} has {has})")
        resolved = rig.observer(key)
        if resolved in seen:
            raise ObservationError(f"{what}s {seen[resolved]!r} and {key!r} are of the same camera: give it once")
        seen[resolved] = key
        out[key] = resolved[0]
    return out


def _same_images(rig: Rig, loaded: Mapping[str, np.ndarray]) -> None:
    """InputError when two cameras are given the same image (one file given twice)."""
    keys = list(loaded)
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            x, y = loaded[a], loaded[b]
            if x.shape == y.shape and np.array_equal(x, y):
                raise InputError(f"the images of {a!r} and {b!r} are the same: one camera's image given for "
                                 "both? (check --image)")


def localize_images(rig: Any, images: Mapping[str, Any], source: str | None = None, target: str | None = None, *,
                    pixel_sigma: float = 1.0, **options: Any) -> FrameResult:
    """Detect the markers in one image per camera (arrays or file paths) and
    localize ``source`` in ``target``'s frame (``options`` as :func:`mutloc.localize`).

    ``images`` is keyed as observations are: ``ROBOT`` for a robot with one camera, ``ROBOT/CAMERA`` for
    each camera of a robot with several (any lens; not every camera needs an image, but each robot of the
    pair one at least).  Each image is searched for the other robot's markers through its own lens
    (:func:`detect_markers`), and the pose solved on the rays of all of them; ``detections`` are keyed
    likewise.

    After the first solve, what the first look missed is looked for where that pose puts it: an oriented
    tag, in a window around its predicted corners at full resolution (:mod:`mutloc.track.tag_look`: steep
    and small tags the whole-image search loses), and partly hidden or missing balls, measured again at
    their predicted size (:mod:`mutloc.track.second_look`).  What was found so is named in
    ``estimate.extra["second_look"]``."""
    rig, source, target = prepare_pair(rig, images, source, target, "image", cameras=True)
    _refuse_lights(rig, source, target)
    robots = image_keys(rig, images)
    keys = [k for k in images if robots[k] in (source, target)]
    loaded = {k: as_bgr(read_image(images[k]) if isinstance(images[k], (str, Path)) else images[k],
                        f"image of {'camera' if CAMERA_SEPARATOR in k else 'robot'} {k!r}") for k in keys}
    central = [k for k in keys if rig.robot(robots[k]).central_pinhole]
    if len(keys) == 2 and len(central) == 2:
        # One pinhole camera per robot: as ever (same image twice, or swapped, said in one line).
        detections = check_streams(rig, source, target, loaded[source], loaded[target], what="images",
                                   option="--image")
    else:
        # Each camera's image through its own lens (detect_markers: rectified views for a wide-angle one),
        # looked at for the other robot's markers.  (No "swapped" test: a body's camera may well see the
        # robot's own markers, a mast in a fisheye's field, without the images being swapped.)
        _same_images(rig, loaded)
        detections = {k: detect_markers(rig, k, loaded[k], targets=[target if robots[k] == source else source])
                      for k in keys}
    est, error = first_solve(rig, detections, source, target, pixel_sigma=pixel_sigma, **options)
    # Tags the first look missed, looked for where the pose puts them (see .tag_look).
    detections, est, error = with_tags_looked_for(rig, loaded, detections, est, error, source, target,
                                                  pixel_sigma=pixel_sigma, **options)
    # Partly hidden balls are measured again where the pose puts them (only
    # when a ball is partly hidden or missing; see .second_look).
    better = second_look(rig, loaded, detections, est, error, source, target, pixel_sigma=pixel_sigma, **options)
    if better is not None:
        est, detections = better
    if est is None:
        raise error  # type: ignore[misc]
    return FrameResult(est, detections)


#: Frame rate assumed when neither the caller nor the streams say.
DEFAULT_FPS = 30.0


class ObserverDetector:
    """Per-observer detection, keeping blinking-light trackers across frames.
    ``other``: the robot (or, for a team, the robots) whose markers are looked for."""

    def __init__(self, rig: Rig, observer: str, other: str | list[str], fps: float):
        self.rig, self.observer = rig, observer
        self.others = [other] if isinstance(other, str) else list(other)
        markers = {n: m for o in self.others for n, m in rig.robot(o).markers.items()}
        self.blink = None
        lights = {n: m for n, m in markers.items() if m.kind == MarkerKind.LIGHT}
        if lights:
            from ..detect.blink import BlinkTracker

            # The observer's camera: a light's sphere images off its centre's projection.
            self.blink = BlinkTracker(lights, fps, camera=rig.mount(observer).camera)
        self.last_blink: DetectionResult | None = None

    def feed(self, frame: Frame) -> None:
        """Every frame of the stream, paired or not, drives the light tracker."""
        if self.blink is not None and frame.image is not None:
            self.last_blink = self.blink.update(frame.image, frame.t)

    def detect(self, frame: Frame) -> DetectionResult:
        res = detect_markers(self.rig, self.observer, frame.image, targets=self.others)
        if self.last_blink is not None:
            res.detections.update(self.last_blink.detections)
            res.missing = [m for m in res.missing if m not in self.last_blink.detections]
        return res


def frame_rate(streams: Mapping[str, Any], fps: float | None) -> float | None:
    """The frame rate to use: the one given, else the streams' own (the
    slowest of them, since pairs come at the slower rate), else None."""
    if fps is not None:
        return float(fps)
    rates = [float(r) for r in (getattr(s, "fps", None) for s in streams.values()) if r]
    return min(rates) if rates else None
