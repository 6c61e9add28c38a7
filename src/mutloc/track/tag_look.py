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
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..api import Estimate, localize
from ..core.pose import Pose
from ..core.rig import Rig
from ..detect.base import DetectionResult, observations_of
from ..detect.tags import corner_detections, corner_marker_names, find_tag_near, tag_corner_points
from ..errors import MutlocError, UnverifiedError

__all__ = ["first_solve", "look_for_tags", "missing_tags", "with_tags_looked_for"]

#: A predicted tag seen further than this off its normal (degrees) is not looked for: nothing decodes there.
_MAX_VIEW_DEG = 85.0
#: Corners predicted closer than this (pixels) to the image border leave the tag's quiet zone outside it.
_BORDER_PX = 2.0
#: Poses of a frame a missing tag is predicted from, at most.
_CANDIDATES = 4
#: The second, wider window around a prediction: this many predicted sides, at least this many pixels.
_WIDE_SIDES, _WIDE_MIN_PX = 2.0, 48.0


def first_solve(rig: Rig, detections: Mapping[str, DetectionResult], source: str, target: str, *,
                pixel_sigma: float = 1.0, **options: Any) -> tuple[Estimate | None, MutlocError | None]:
    """The first look's pose, or why there is none: what the second looks (tags here, balls in
    :mod:`.second_look`) start from."""

    try:
        return localize(rig, observations_of(detections), source, target, pixel_sigma=pixel_sigma, **options), None
    except MutlocError as exc:
        return None, exc


def missing_tags(rig: Rig, detections: Mapping[str, DetectionResult], source: str, target: str
                 ) -> dict[str, list[str]]:
    """``{observer: [tag markers of the other robot the observer's first look missed]}`` (those with a known
    ``rotation``: only they have corners to predict)."""
    out: dict[str, list[str]] = {}
    for obs, other in ((source, target), (target, source)):
        det = detections.get(obs)
        if det is None:
            continue
        names = [n for n, m in rig.robot(other).markers.items()
                 if m.tag is not None and tag_corner_points(m) is not None and n not in det.detections
                 and not any(c in det.detections for c in corner_marker_names(n))]
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


def look_for_tags(rig: Rig, images: Mapping[str, np.ndarray], detections: Mapping[str, DetectionResult],
                  est: Estimate | None, error: Exception | None, source: str, target: str
                  ) -> dict[str, DetectionResult] | None:
    """``detections`` with the missing tags found where a pose of the frame (``est``, or the candidates of
    an unverified one) puts them, or None when none was found.  ``images``: BGR images per observer."""
    wanted = missing_tags(rig, detections, source, target)
    poses = _poses(est, error)
    if not wanted or not poses:
        return None
    out = {o: d.copy() for o, d in detections.items()}
    found = False
    for obs, names in wanted.items():
        other = target if obs == source else source
        cam = rig.robot(obs).camera
        for name in names:
            marker = rig.robot(other).markers[name]
            X = tag_corner_points(marker)
            normal = X[1] - X[0]
            normal = np.cross(normal, X[3] - X[0])  # x cross y: into the tag
            for pose in poses:
                T = pose if obs == target else pose.inverse()  # the other robot's points -> the observer's
                Xc = T.apply(X)
                if np.any(Xc[:, 2] <= 0.0):
                    continue
                n_c = T.R @ normal
                centre = Xc.mean(axis=0)
                # Seen from its front: the line of sight runs along the tag's z, into the tag.
                cos_view = float((n_c @ centre) / (np.linalg.norm(n_c) * np.linalg.norm(centre)))
                if cos_view < np.cos(np.radians(_MAX_VIEW_DEG)):
                    continue
                uv = cam.project(Xc)
                w, h = cam.size if cam.size is not None else (images[obs].shape[1], images[obs].shape[0])
                if not (np.all(np.isfinite(uv)) and uv[:, 0].min() >= _BORDER_PX and uv[:, 1].min() >= _BORDER_PX
                        and uv[:, 0].max() <= w - 1 - _BORDER_PX and uv[:, 1].max() <= h - 1 - _BORDER_PX):
                    continue
                det = find_tag_near(images[obs], marker, uv, camera=cam)
                if det is None:
                    # A pose from one small tag can be off by more than the window: once more, wider.
                    side = float(np.mean(np.linalg.norm(uv - np.roll(uv, -1, axis=0), axis=1)))
                    det = find_tag_near(images[obs], marker, uv, camera=cam,
                                        margin_px=max(_WIDE_SIDES * side, _WIDE_MIN_PX))
                if det is not None:
                    # As the first look reports an oriented tag: its corners, in place of its centre.
                    corners = corner_detections(det)
                    out[obs].detections.update(corners)
                    gone = {name, *corners}
                    out[obs].missing = [m for m in out[obs].missing if m not in gone]
                    for m in gone:
                        out[obs].missing_reasons.pop(m, None)
                    found = True
                    break
    return out if found else None


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
