"""A second look for tags the first look missed, where the pose puts them.

The whole-image tag search (:func:`mutloc.detect.tags.detect_tags`: the
AprilTag library at quad decimation 2) loses small tags seen far off their
normal -- past about 50 degrees at 30 px (``bench/tags_steep.py``).  Searching
every frame at full resolution finds most of them but costs 2.5 times the
time.  When the frame has a pose anyway -- the other camera's tag alone gives
one, if a weak one -- the missing tag's corners are predicted in its
observer's image, and only that window is searched, at full resolution and
enlarged (:func:`mutloc.detect.tags.find_tag_near`).  A tag found there is
decoded by the library, its id read from its own pixels, its corners fitted
to its own edges: the pose chose where to look, not what is seen.  The frame
is then solved again, and the new solve kept when it is verified and rests
on more observations (or the first one failed).

Only frames with a wanted tag missing pay for it, and only for tags whose
predicted outline lies inside the image and faces the camera.

Observers are cameras (``ROBOT`` or ``ROBOT/CAMERA``, as observations are
keyed): a tag is predicted through the observing camera's mount -- its pose
on the robot and its lens's ``project`` -- not at the robot's origin.  Through
a wide-angle lens (fisheye, omni) the tag is looked for in one locally
rectified pinhole view centred on its predicted direction
(:func:`mutloc.detect.views.view_towards`): predicted, found and edge-fitted
there as in a pinhole image, its corners then taken back to the raw image
through their rays (:func:`mutloc.detect.views.detection_to_raw`).
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from ..api import Estimate, localize
from ..core.pose import Pose
from ..core.rig import Rig
from ..detect.base import DetectionResult, observations_of
from ..detect.tags import corner_detections, corner_marker_names, find_tag_near, tag_corner_points, tag_spec
from ..detect.views import detection_to_raw, needs_views, view_towards
from ..errors import MutlocError, UnverifiedError

__all__ = ["find_missing_tags", "first_solve", "look_for_tags", "look_where_tracked", "missing_tags",
           "with_tags_looked_for"]

#: A predicted tag seen further than this off its normal (degrees) is not looked for: nothing decodes there.
_MAX_VIEW_DEG = 85.0
#: Corners predicted closer than this (pixels) to the image border leave the tag's quiet zone outside it.
_BORDER_PX = 2.0
#: Poses of a frame a missing tag is predicted from, at most.
_CANDIDATES = 4
#: The second, wider window around a prediction: this many predicted sides, at least this many pixels.
_WIDE_SIDES, _WIDE_MIN_PX = 2.0, 48.0
#: A rectified view around a tag predicted through a wide-angle lens: half its field is the tag's angular
#: half-size times this, plus this many degrees (the wide window's margin fits in it), within these bounds.
_VIEW_SIDES, _VIEW_PAD_DEG, _VIEW_HALF_FOV_DEG = 3.0, 10.0, (12.0, 45.0)


def _pair_observers(rig: Rig, keys: Iterable[str], source: str, target: str) -> list[tuple[str, str, str]]:
    """``(key, its robot, the other robot of the pair)`` of every observer key of the pair's robots."""
    out = []
    for key in keys:
        robot = rig.observer(key)[0]
        if robot in (source, target):
            out.append((key, robot, target if robot == source else source))
    return out


def first_solve(rig: Rig, detections: Mapping[str, DetectionResult], source: str, target: str, *,
                pixel_sigma: float = 1.0, **options: Any) -> tuple[Estimate | None, MutlocError | None]:
    """The first look's pose, or why there is none: what the second looks (tags here, balls in
    :mod:`.second_look`) start from."""

    try:
        return localize(rig, observations_of(detections), source, target, pixel_sigma=pixel_sigma, **options), None
    except MutlocError as exc:
        return None, exc


def _missing(rig: Rig, det: DetectionResult, others: Iterable[str]) -> dict[str, list[str]]:
    """``{robot: [its oriented tags det does not hold]}`` over ``others`` (robots with none left out)."""
    out: dict[str, list[str]] = {}
    for other in others:
        names = [n for n, m in rig.robot(other).markers.items()
                 if m.tag is not None and tag_corner_points(m) is not None and n not in det.detections
                 and not any(c in det.detections for c in corner_marker_names(n))]
        if names:
            out[other] = names
    return out


def missing_tags(rig: Rig, detections: Mapping[str, DetectionResult], source: str, target: str
                 ) -> dict[str, list[str]]:
    """``{observer: [tag markers of the other robot the observer's first look missed]}`` (those with a known
    ``rotation``: only they have corners to predict); observers are the keys of ``detections`` (cameras)."""
    out: dict[str, list[str]] = {}
    for obs, _, other in _pair_observers(rig, detections, source, target):
        names = _missing(rig, detections[obs], [other]).get(other)
        if names:
            out[obs] = names
    return out


def _poses(est: Estimate | None, error: Exception | None) -> list[Pose]:
    """The poses to predict from: the estimate's, then its other candidates (at most :data:`_CANDIDATES` in
    all; one small tag seen face-on has a mirror pose as likely as the true one, which the consistency test
    cannot tell apart)."""
    if est is None and isinstance(error, UnverifiedError):
        est = error.estimate  # type: ignore[assignment]
    if est is None:
        return []
    out = [est.pose]
    for cand in est.candidates:
        if len(out) >= _CANDIDATES:
            break
        if all(cand.translation_error(p) > 0.01 or cand.rotation_error_deg(p) > 1.0 for p in out):
            out.append(cand)
    return out


def _predicted_corners(marker: Any, T: Pose, cam: Any, size: tuple[int, int]) -> np.ndarray | None:
    """The tag's corners (4, 2) in the observer's image under ``T`` (the tag's robot -> the observer's
    camera), or None when it lies behind, edge-on, or not wholly inside the image."""
    X = tag_corner_points(marker)
    Xc = T.apply(X)
    if np.any(Xc[:, 2] <= 0.0):
        return None
    n_c = T.R @ np.cross(X[1] - X[0], X[3] - X[0])  # the tag's z (x cross y): into the tag
    centre = Xc.mean(axis=0)
    # Seen from its front: the line of sight runs along the tag's z.
    if float(n_c @ centre) < np.cos(np.radians(_MAX_VIEW_DEG)) * np.linalg.norm(n_c) * np.linalg.norm(centre):
        return None
    uv = cam.project(Xc)
    w, h = size
    if not (np.all(np.isfinite(uv)) and uv[:, 0].min() >= _BORDER_PX and uv[:, 1].min() >= _BORDER_PX
            and uv[:, 0].max() <= w - 1 - _BORDER_PX and uv[:, 1].max() <= h - 1 - _BORDER_PX):
        return None
    return uv


def _through_view(image: np.ndarray, marker: Any, T: Pose, cam: Any) -> Any:
    """The tag of ``marker`` looked for in a rectified view of the wide-angle ``cam`` centred where ``T`` (the
    tag's robot -> the camera) puts it, its corners in the raw image; None if not found (or not imaged)."""
    centre = T.apply(marker.position)
    uv = cam.project(T.apply(tag_corner_points(marker)))
    w, h = cam.size
    if not (np.all(np.isfinite(uv)) and uv[:, 0].min() >= _BORDER_PX and uv[:, 1].min() >= _BORDER_PX
            and uv[:, 0].max() <= w - 1 - _BORDER_PX and uv[:, 1].max() <= h - 1 - _BORDER_PX):
        return None  # outside the lens's field or the image: no view is built for it
    _, _, size_m = tag_spec(marker)
    half = np.degrees(np.arctan(0.5 * size_m / np.linalg.norm(centre))) * _VIEW_SIDES + _VIEW_PAD_DEG
    view = view_towards(cam, centre, half_fov_deg=float(np.clip(half, *_VIEW_HALF_FOV_DEG)))
    if view is None:
        return None
    Rv = view.R.T  # camera -> view
    uv = _predicted_corners(marker, Pose(Rv @ T.R, Rv @ T.t), view.camera, view.camera.size)
    if uv is None:
        return None
    img = view.rectify(image)
    found = find_tag_near(img, marker, uv, camera=view.camera)
    if found is None:
        side = float(np.mean(np.linalg.norm(uv - np.roll(uv, -1, axis=0), axis=1)))
        found = find_tag_near(img, marker, uv, camera=view.camera, margin_px=max(_WIDE_SIDES * side, _WIDE_MIN_PX))
    return None if found is None else detection_to_raw(found, view)


def _near(image: np.ndarray, marker: Any, T: Pose, cam: Any, size: tuple[int, int]) -> Any:
    """The tag of ``marker`` looked for where ``T`` (the tag's robot -> the pinhole camera) puts it."""
    uv = _predicted_corners(marker, T, cam, size)
    if uv is None:
        return None
    found = find_tag_near(image, marker, uv, camera=cam)
    if found is None:
        # A pose from one small tag can be off by more than the window: once more, wider.
        side = float(np.mean(np.linalg.norm(uv - np.roll(uv, -1, axis=0), axis=1)))
        found = find_tag_near(image, marker, uv, camera=cam, margin_px=max(_WIDE_SIDES * side, _WIDE_MIN_PX))
    return found


def find_missing_tags(rig: Rig, observer: str, image: np.ndarray, det: DetectionResult,
                      poses: Mapping[str, Sequence[Pose]]) -> DetectionResult | None:
    """``det`` (``observer``'s detections in ``image``) with the missing tags of the robots in ``poses`` found
    where one of their poses puts them (``{robot: [T_observer_robot, ...]}``, tried in order, between robot
    frames), or None when none was found.  ``observer`` is a camera's key (``ROBOT`` or ``ROBOT/CAMERA``): the
    tags are predicted through its mount (pose on the robot, lens).  A tag found is reported as the first
    look reports an oriented tag: its corners."""
    robot = rig.observer(observer)[0]
    wanted = _missing(rig, det, [r for r in poses if r != robot])
    if not wanted:
        return None
    mount = rig.mount(observer)
    cam = mount.camera
    cam_from_robot = None if mount.is_identity else mount.pose.inverse()
    size = cam.size if cam.size is not None else (image.shape[1], image.shape[0])
    out = None
    for other, names in wanted.items():
        for name in names:
            marker = rig.robot(other).markers[name]
            for T in poses[other]:
                Tc = T if cam_from_robot is None else cam_from_robot @ T  # the tag's robot -> the camera
                found = _through_view(image, marker, Tc, cam) if needs_views(cam) else \
                    _near(image, marker, Tc, cam, size)
                if found is not None:
                    out = det.copy() if out is None else out
                    corners = corner_detections(found)
                    out.detections.update(corners)
                    gone = {name, *corners}
                    out.missing = [m for m in out.missing if m not in gone]
                    for m in gone:
                        out.missing_reasons.pop(m, None)
                    break
    return out


def look_for_tags(rig: Rig, images: Mapping[str, np.ndarray], detections: Mapping[str, DetectionResult],
                  est: Estimate | None, error: Exception | None, source: str, target: str
                  ) -> dict[str, DetectionResult] | None:
    """``detections`` with the missing tags found where a pose of the frame (``est``, or the candidates of
    an unverified one) puts them, or None when none was found.  ``images``: BGR images per observer (camera
    key, as ``detections``)."""
    if not missing_tags(rig, detections, source, target):
        return None
    poses = _poses(est, error)
    if not poses:
        return None
    out = dict(detections)
    found = False
    for obs, robot, other in _pair_observers(rig, detections, source, target):
        if obs not in images:
            continue
        T = poses if robot == target else [p.inverse() for p in poses]  # the other robot -> the observer
        more = find_missing_tags(rig, obs, images[obs], detections[obs], {other: T})
        if more is not None:
            out[obs], found = more, True
    return out if found else None


def look_where_tracked(rig: Rig, images: Mapping[str, np.ndarray], detections: Mapping[str, DetectionResult],
                       predicted: Mapping[str, Pose] | Callable[[], Mapping[str, Pose]]
                       ) -> tuple[dict[str, DetectionResult], list[tuple[str, str]]]:
    """``detections`` with the missing tags found where a tracker's prediction puts them, and a note
    ``(robot, text)`` for each, ``robot`` the tag's.  ``predicted``: each tracked robot's pose in a common frame
    (``{robot: T_ref_robot}``, the reference's too: :meth:`mutloc.track.team.TeamTracker.predicted`), or a
    callable giving it, called only when a tracked robot's tag is missing.  For records whose own pose is
    missing (a camera at its own time, a record a pose cannot be solved from alone): a tag is decoded from its
    own pixels, so a wrong prediction finds nothing rather than something wrong."""
    robot_of = {obs: rig.observer(obs)[0] for obs in detections}  # camera keys (ROBOT or ROBOT/CAMERA)
    if not any(_missing(rig, det, [r for r in rig.robots if r != robot_of[obs]]) for obs, det in detections.items()):
        return dict(detections), []
    poses_ref = predicted() if callable(predicted) else predicted
    out = dict(detections)
    notes: list[tuple[str, str]] = []
    for obs, det in detections.items():
        own = robot_of[obs]
        if own not in poses_ref or obs not in images:
            continue
        inv = poses_ref[own].inverse()  # between robot frames: find_missing_tags goes through the camera's mount
        poses = {o: [inv @ T] for o, T in poses_ref.items() if o != own}
        more = find_missing_tags(rig, obs, images[obs], det, poses)
        if more is not None:
            notes += [(robot, f"{obs} saw tag {n} where the track put it (looked for again)")
                      for robot, names in _missing(rig, det, poses).items() for n in names
                      if corner_marker_names(n)[0] in more.detections]
            out[obs] = more
    return out, notes


def with_tags_looked_for(rig: Rig, images: Mapping[str, np.ndarray], detections: dict[str, DetectionResult],
                         est: Estimate | None, error: MutlocError | None, source: str, target: str, *,
                         pixel_sigma: float = 1.0, **options: Any
                         ) -> tuple[dict[str, DetectionResult], Estimate | None, MutlocError | None]:
    """The frame's (detections, first solve, its error) after :func:`look_for_tags`: the tags found kept when
    the frame solved again with them is verified on more observations than before (or had no pose)."""
    more = look_for_tags(rig, images, detections, est, error, source, target)
    if more is None:
        return detections, est, error
    new, new_error = first_solve(rig, more, source, target, pixel_sigma=pixel_sigma, **options)
    if new is None:
        return detections, est, error
    better = (est is None or est.status != "solved" or len(new.markers_used) > len(est.markers_used)) \
        if new.status == "solved" else est is None
    if not better:
        return detections, est, error
    new.extra["second_look"] = [*new.extra.get("second_look", []),
                                *(f"{o} saw tag {n} where the pose put it (looked for again)"
                                  for o, names in missing_tags(rig, detections, source, target).items()
                                  for n in names if corner_marker_names(n)[0] in more[o].detections)]
    return more, new, new_error
