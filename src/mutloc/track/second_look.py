"""A second look at partly hidden balls, where and as large as the pose says they appear.

The first look measures every ball on its own, its size free.  A partly
hidden ball then shows a short arc whose centre slides with the size, is
taken for the wrong blob, or is turned down by the rig check because the
size (hence the distance) read off the short arc is wrong; with two balls a
robot, the pose then rests on three observations (unverified) or none.

The mutual geometry says where each ball must appear and how large (its
radius over its distance): from a pose -- the first solve, each candidate
of an unverified one, or, when the first solve fails its consistency test,
the candidates with one observation left out -- every missing ball, and
every partly hidden one whose first-look size is off the predicted one, is
measured again with its size fixed to the prediction
(:func:`mutloc.detect.balls.refit.refit_ball`; the rim measurement's own
size bias taken off: :data:`_RIM_BIAS_PX` in an image with a whole ball),
and the pose solved again (twice).  Frames the first look leaves unsolved also start from the partly
hidden balls sized as their robot's whole ones, and from the balls looked
for again at the distance either camera's balls give.

A result is kept only if it is *verified* (passes its consistency test),
rests for at least half of its observations on pixels found before the pose
(a ball measured again counts when the look before the pose found it within
:data:`_MOVED_PX` of where it is measured now), has at
least as many observations as a verified first look, and no other verified
result disagrees with it.

Only frames with a ball partly hidden (visible fraction below
:data:`PARTLY_HIDDEN`) or missing pay for it.

Observers are cameras (``ROBOT`` or ``ROBOT/CAMERA``, as observations are
keyed): a ball's centre is predicted in the observing camera's frame through
its mount (its pose on the robot), not at the robot's origin.  Any lens: the
refit (rays cast from the predicted centre, the rim fitted as a cone of the
predicted angle) runs in a pinhole camera's own pixels, and through a
fisheye or omni lens in a rectified view centred on the predicted ball,
the first look's size compared in the view it was found in
(:mod:`.lens_refit`); balls are looked for again through the lens's views
(:func:`mutloc.detect.detect_image`).  Only the search among the blobs near
a robot's balls found (:func:`_near_mates`, pixel reaches in the image) is
for pinhole cameras alone.
"""

from __future__ import annotations

import itertools
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

from ..api import Estimate, localize
from ..core.pose import Pose
from ..core.rig import MarkerKind, Rig
from ..detect.base import DetectionResult, observations_of
from ..errors import InconsistentObservationsError, MutlocError, UnverifiedError
from .lens_refit import LensRefit, apparent_radius, context, refit
from .tag_look import first_solve, missing_tags, with_tags_looked_for

__all__ = ["MIN_REFIT_FRACTION", "PARTLY_HIDDEN", "ball_centres", "look_again", "needs_second_look", "second_look"]

#: A ball whose first look saw less of its rim than this is measured again.
PARTLY_HIDDEN = 0.9
#: Less of a rim than this (about 110 degrees) leaves a ball's centre along
#: its arc resting on the predicted size alone: the ball stays missing.
MIN_REFIT_FRACTION = 0.3
#: A partly hidden ball whose first-look size is within this (pixels) of the
#: predicted one (after the rim's own bias) keeps its first-look centre.
_SIZE_TOL = 0.05
#: The first look's rim lies about this far (pixels) inside a ball's true
#: outline in ordinary light (edge unmixing; the median, -0.06 +- 0.03 with
#: the background, over the partly hidden balls of bench/balls_occluded.py's
#: tuning scenes refitted at their rendered centres).  A fixed size carries
#: the bias into a short arc's centre (~1.2x).  The whole balls' size error
#: in the same image alone follows the hidden ball's own bias poorly
#: (correlation ~0 on those scenes), as their single free-size fits are noisier
#: than this prior.
_RIM_BIAS_PX = -0.065
#: Solves after the first: refit from the pose, solve, refit from the new pose, solve.
_ROUNDS = 2
#: Balls looked for again must be within this factor of the robots' distance.
_RANGE = 1.25
#: A ball measured again further than this (pixels) from its first look was another blob.
_MOVED_PX = 2.0
#: Verified poses closer than this are the same answer.
_SAME_M, _SAME_DEG = 0.01, 1.0


def _balls(rig: Rig, robot: str) -> dict[str, Any]:
    return {n: m for n, m in rig.robot(robot).markers.items() if m.kind == MarkerKind.BALL and m.color is not None}


def _observers(rig: Rig, keys: Iterable[str], source: str, target: str) -> dict[str, str]:
    """``{key: the other robot of the pair}`` of the observer keys (cameras) of the pair's robots: those looked
    at again (any lens, see the module's docstring)."""
    out = {}
    for key in keys:
        robot = rig.observer(key)[0]
        if robot in (source, target):
            out[key] = target if robot == source else source
    return out


def ball_centres(rig: Rig, pose: Pose, source: str, target: str, keys: Iterable[str] | None = None
                 ) -> dict[str, dict[str, np.ndarray]]:
    """``{observer: {ball: centre in the observer's camera frame}}`` for the balls of the pair under ``pose``
    (T_qp); ``keys``: the observers (camera keys, default the two robots), each camera's frame through its
    mount."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for observer in (target, source) if keys is None else keys:
        robot = rig.observer(observer)[0]
        other = target if robot == source else source
        T = pose if robot == target else pose.inverse()
        mount = rig.mount(observer)
        if not mount.is_identity:
            T = mount.pose.inverse() @ T  # the other robot -> the observing camera
        out[observer] = {n: T.apply(m.position) for n, m in _balls(rig, other).items()}
    return out


def _hidden(det: DetectionResult, name: str) -> bool:
    d = det.detections.get(name)
    return d is None or (d.visible_fraction is not None and d.visible_fraction < PARTLY_HIDDEN)


def needs_second_look(rig: Rig, detections: Mapping[str, DetectionResult], source: str, target: str) -> bool:
    """True when a ball of the pair is missing or partly hidden in the other robot's image (any camera of it)."""
    return any(_hidden(detections[obs], n) for obs, other in _observers(rig, detections, source, target).items()
               for n in _balls(rig, other))


def _size_errors(contexts: Mapping[str, Any], rig: Rig, detections: Mapping[str, DetectionResult],
                 centres: Mapping[str, Mapping[str, np.ndarray]], others: Mapping[str, str]
                 ) -> dict[tuple[str, str], float]:
    """``{(observer, ball): first-look radius - predicted radius}`` (pixels) of every ball found."""
    out = {}
    for obs, det in detections.items():
        if obs not in contexts:
            continue
        balls = _balls(rig, others[obs])
        for name, X in centres[obs].items():
            d = det.detections.get(name)
            if d is not None and "radius_px" in d.info:
                r = apparent_radius(contexts[obs], name, balls[name], X, d)
                if r is not None:
                    out[(obs, name)] = float(d.info["radius_px"]) - r
    return out


def _rim_offset(obs: str, errors: Mapping[tuple[str, str], float], detections: Mapping[str, DetectionResult]
                ) -> float:
    """The rim measurement's size bias in ``obs``'s image: :data:`_RIM_BIAS_PX` when a ball of it is whole
    (ordinary light), else the median size error of the whole balls of both images, else of every ball found
    (a hard or coloured light leaves no ball whole and moves the bias), else :data:`_RIM_BIAS_PX`."""
    whole = {k: e for k, e in errors.items() if not _hidden(detections[k[0]], k[1])}
    if any(k[0] == obs for k in whole):
        return _RIM_BIAS_PX
    for pick in (list(whole.values()), list(errors.values())):
        if pick:
            return float(np.median(pick))
    return _RIM_BIAS_PX


def _refit_all(rig: Rig, contexts: Mapping[str, Any], detections: Mapping[str, DetectionResult], pose: Pose,
               source: str, target: str, left_out: tuple[str, str] | None
               ) -> tuple[dict[str, DetectionResult], bool]:
    """The detections with every missing (or ``left_out``) ball measured again under ``pose``, and every
    partly hidden one whose first-look size is off the predicted one (its centre slid along its arc);
    and whether any ball was measured again or dropped."""
    others = _observers(rig, contexts, source, target)
    centres = ball_centres(rig, pose, source, target, others)
    errors = _size_errors(contexts, rig, detections, centres, others)
    out = {}
    touched = False
    for obs, det in detections.items():
        new = det.copy()
        if obs not in others:
            out[obs] = new  # not looked at again (see the module's docstring)
            continue
        balls = _balls(rig, others[obs])
        off = _rim_offset(obs, errors, detections)
        for name, X in centres[obs].items():
            err = errors.get((obs, name))
            if left_out != (obs, name) and name in det.detections and not (
                    _hidden(det, name) and (err is None or abs(err - off) > _SIZE_TOL
                                            or det.detections[name].info.get("guided"))):
                continue
            found = refit(contexts[obs], name, balls[name], X, radius_offset_px=off)
            new.alternatives.pop(name, None)
            if found is not None and found.visible_fraction >= MIN_REFIT_FRACTION:
                new.detections[name] = found
                touched = True
                new.missing = [m for m in new.missing if m != name]
                new.missing_reasons.pop(name, None)
            elif name in new.detections:
                # Not where the pose puts it: the first look's blob is not this ball.
                del new.detections[name]
                touched = True
                new.missing.append(name)
                new.missing_reasons[name] = "rejected: no ball of its size where the other balls put it"
        out[obs] = new
    return out, touched


def _mate_sized(rig: Rig, contexts: Mapping[str, Any], detections: Mapping[str, DetectionResult],
                source: str, target: str) -> dict[str, DetectionResult]:
    """The detections with every partly hidden ball measured again with the size of its robot's whole balls
    in the same image (before any pose: balls of one robot are at about the same distance)."""
    out = {}
    others = _observers(rig, contexts, source, target)
    for obs, det in detections.items():
        new = det.copy()
        out[obs] = new
        if obs not in others:
            continue
        balls = _balls(rig, others[obs])
        whole = [float(d.info["distance_m"]) for n, d in det.detections.items()
                 if n in balls and not _hidden(det, n) and "distance_m" in d.info]
        if whole:
            dist = float(np.median(whole))
            for name, d in det.detections.items():
                if name in balls and _hidden(det, name):
                    bearing = rig.mount(obs).camera.pixels_to_bearings(d.uv)
                    if not np.all(np.isfinite(bearing)):
                        continue
                    found = refit(contexts[obs], name, balls[name], bearing * dist)
                    if found is not None and found.visible_fraction >= MIN_REFIT_FRACTION:
                        new.detections[name] = found
                        new.alternatives.pop(name, None)
    return out


def _distances(detections: Mapping[str, DetectionResult]) -> list[float]:
    """The robots' distance as each camera's balls give it (its whole balls, if any), near ones merged."""
    out: list[float] = []
    for det in detections.values():
        seen = [(float(d.info["distance_m"]), not _hidden(det, n)) for n, d in det.detections.items()
                if "distance_m" in d.info]
        dists = [x for x, whole in seen if whole] or [x for x, _ in seen]
        if dists:
            D = float(np.median(dists))
            if all(abs(D / o - 1.0) > 0.1 for o in out):
                out.append(D)
    return out


def _redetect(rig: Rig, images: Mapping[str, np.ndarray], detections: Mapping[str, DetectionResult],
              distance: float, source: str, target: str) -> dict[str, DetectionResult]:
    """The balls looked for again with the size a robots' ``distance`` gives them.

    For frames the first look leaves unsolved: a ball of the other robot is
    seen at about the robots' distance from both sides, which rules out
    look-alikes of another size (the first look's choice of a poster's
    discs, or a whole ball the rig check turned down because its partly
    hidden mate's size misled it).  Balls the rig check still turns down
    are looked for on their own; the pose's consistency test judges what
    this finds.
    """
    from ..detect import detect_image
    from ..detect.balls import BallParams

    params = BallParams(distance_range_m=(distance / _RANGE, distance * _RANGE))
    out = {}
    others = _observers(rig, detections, source, target)
    for obs in detections:
        if obs not in others:
            out[obs] = detections[obs].copy()
            continue
        balls = _balls(rig, others[obs])
        cam = rig.mount(obs).camera
        new = detect_image(MarkerKind.BALL, images[obs], balls, cam, params=params)
        for name in list(new.missing):
            found = detect_image(MarkerKind.BALL, images[obs], {name: balls[name]}, cam, params=params)
            if name in found.detections:
                new.detections[name] = found.detections[name]
                new.missing.remove(name)
                new.missing_reasons.pop(name, None)
        # Other kinds of marker keep what the first look found.
        kept = detections[obs].copy()
        for name in balls:
            kept.detections.pop(name, None)
            kept.alternatives.pop(name, None)
        kept.missing = [m for m in kept.missing if m not in balls]
        kept.missing_reasons = {m: r for m, r in kept.missing_reasons.items() if m not in balls}
        kept.merge(new)
        out[obs] = kept
    return out


def _near_mates(rig: Rig, images: Mapping[str, np.ndarray], contexts: Mapping[str, Any],
                detections: Mapping[str, DetectionResult], source: str, target: str
                ) -> Iterator[dict[str, DetectionResult]]:
    """The detections with each missing ball taken, in turn, from the blobs of its colour within the rig's
    reach of its robot's balls found (and sized as they are).

    For frames the first look leaves with too few observations: a partly
    hidden ball scores low for being hidden (its score scales with its
    visible rim), and its free size, read off a short arc, can put it out
    of the rig's distances.  Here it needs only the score of
    :data:`MIN_REFIT_FRACTION` of a rim, is measured with its mates' size,
    and must lie where the rig can put it (its distance to a mate over the
    mates' distance, with :data:`_RANGE` to spare); the pose's consistency
    test judges what this finds.
    """
    from ..detect.balls.refit import balls_near

    options: dict[str, list[tuple[str, Any]]] = {}
    others = _observers(rig, contexts, source, target)
    for obs, det in detections.items():
        if obs not in others or isinstance(contexts[obs], LensRefit):
            continue  # pinhole cameras only: the reaches are pixels of the image
        balls = _balls(rig, others[obs])
        mates = {n: d for n, d in det.detections.items() if n in balls and "distance_m" in d.info}
        if not mates:
            continue
        D = float(np.median([float(d.info["distance_m"]) for d in mates.values()]))
        f = contexts[obs].cam.f
        for name in balls:
            if name in det.detections:
                continue
            reach = [(d.uv, float(np.linalg.norm(balls[name].position - balls[m].position)) / D * f * _RANGE)
                     for m, d in mates.items()]
            for found in balls_near(contexts[obs], name, balls[name], D, reach):
                if found.visible_fraction >= MIN_REFIT_FRACTION:
                    options.setdefault(obs, []).append((name, found))
    if not options:
        return
    per_obs = [[(obs, None)] + [(obs, o) for o in opts] for obs, opts in options.items()]
    for pick in itertools.product(*per_obs):
        if all(o is None for _, o in pick):
            continue
        out = {o: d.copy() for o, d in detections.items()}
        for obs, o in pick:
            if o is not None:
                name, d = o
                out[obs].detections[name] = d
                out[obs].missing = [m for m in out[obs].missing if m != name]
                out[obs].missing_reasons.pop(name, None)
                out[obs].alternatives.pop(name, None)
        yield out


def _hypotheses(detections: Mapping[str, DetectionResult], est: Estimate | None, error: Exception | None,
                solve: Any) -> list[tuple[Pose, tuple[str, str] | None]]:
    """Poses to predict the balls from, each with the observation it leaves out (if any)."""

    if est is None and isinstance(error, UnverifiedError):
        est = error.estimate  # type: ignore[assignment]
    if est is not None:
        if est.status == "solved":
            return [(est.pose, None)]
        return [(p, None) for p in est.candidates]
    if not isinstance(error, InconsistentObservationsError):
        return []
    out: list[tuple[Pose, tuple[str, str] | None]] = []
    for obs, det in detections.items():
        for name in det.detections:
            dets = {o: d.copy() for o, d in detections.items()}
            del dets[obs].detections[name]
            dets[obs].alternatives.pop(name, None)
            try:
                sub = solve(observations_of(dets))
            except MutlocError:
                continue
            out += [(p, (obs, name)) for p in sub.candidates]
    return out


def _anchored(est: Estimate, detections: Mapping[str, DetectionResult], base: Mapping[str, DetectionResult]
              ) -> bool:
    """At least half of the pose's observations rest on pixels found without the pose: a ball measured again
    sits where the pose puts it, so a pose resting mostly on such balls would confirm itself -- unless the
    look before the pose (``base``) found that ball within :data:`_MOVED_PX` of where it is measured now."""
    def own(obs: str, name: str, d: Any) -> bool:
        if not d.info.get("refit"):
            return True
        b = base[obs].detections.get(name)
        return b is not None and float(np.hypot(*(d.uv - b.uv))) <= _MOVED_PX

    refits = sum(not own(obs, n, d) for obs, det in detections.items() for n, d in det.detections.items()
                 if n in est.markers_used)
    return 2 * refits <= len(est.markers_used)


def second_look(rig: Rig, images: Mapping[str, np.ndarray], detections: dict[str, DetectionResult],
                est: Estimate | None, error: Exception | None, source: str, target: str, *,
                pixel_sigma: float = 1.0, **options: Any) -> tuple[Estimate, dict[str, DetectionResult]] | None:
    """A verified pose (and its detections) from the balls measured again, or None.

    ``est`` is the first look's estimate (None when it raised ``error``);
    ``images`` the BGR images per observer, ``options`` as :func:`mutloc.localize`.
    Returns a result only as the module says (verified, anchored on first-look
    pixels, not fewer observations than a verified first look, unambiguous).
    """
    if not needs_second_look(rig, detections, source, target):
        return None
    opts = dict(options, allow_unverified=True)

    def solve(obs: Any) -> Estimate:
        return localize(rig, obs, source, target, pixel_sigma=pixel_sigma, **opts)

    contexts = {obs: context(images[obs], rig.mount(obs).camera)
                for obs in _observers(rig, detections, source, target)}

    def bases() -> Iterator[tuple[dict[str, DetectionResult], Estimate | None, Exception | None]]:
        """What to start from, cheapest first: the first look; unless it is solved, the same with its
        partly hidden balls sized as their robot's whole ones; the balls looked for again at each
        distance the cameras give the robots (and those sized likewise)."""
        yield detections, est, error
        if est is not None and est.status == "solved":
            return
        redone = (_redetect(rig, images, detections, D, source, target) for D in _distances(detections))
        near = (d for d in _near_mates(rig, images, contexts, detections, source, target))
        for dets in itertools.chain([_mate_sized(rig, contexts, detections, source, target)],
                                    *(([r, _mate_sized(rig, contexts, r, source, target)] for r in redone)),
                                    near):
            try:
                yield dets, solve(observations_of(dets)), None
            except MutlocError as exc:
                yield dets, None, exc

    # Verified poses of earlier starts that disagreed among themselves.
    ambiguous: list[list[Pose]] = []
    chosen = None
    for base, first, err in bases():
        results: list[tuple[Estimate, dict[str, DetectionResult]]] = []
        # A base looked for again that verifies on its own is an answer even if nothing needs a refit.
        own = first if base is not detections and first is not None and first.status == "solved" else None
        for pose, left_out in _hypotheses(base, first, err, solve):
            res = own if left_out is None else None
            kept = (res, base) if res is not None and _anchored(res, base, base) else None
            cur = pose
            for _ in range(_ROUNDS):
                again, touched = _refit_all(rig, contexts, base, cur, source, target, left_out)
                if not touched:
                    break  # nothing measured again: the solve would repeat the last one
                try:
                    res = solve(observations_of(again))
                except MutlocError:
                    break
                cur = res.pose
                # The last verified round counts: a ball at the edge of measurable
                # (MIN_REFIT_FRACTION) may drop out of a later one.
                if res.status == "solved" and _anchored(res, again, base):
                    kept = (res, again)
            if kept is not None:
                results.append(kept)
        if not results:
            continue
        most = max(len(r.markers_used) for r, _ in results)
        top = sorted((r for r in results if len(r[0].markers_used) == most),
                     key=lambda r: r[0].reprojection_rms_px)
        # Two verified poses that disagree (a look-alike where a wrong candidate
        # put a ball): nothing tells which is right, so neither is taken from
        # this start; a later start (a look that does not rest on the same
        # blobs) may settle it, if its answer is one of them.
        if any(not _same(o.pose, top[0][0].pose) for o, _ in top[1:]):
            ambiguous.append([o.pose for o, _ in top])
            continue
        if all(any(_same(p, top[0][0].pose) for p in poses) for poses in ambiguous):
            chosen = top[0]
        break
    if chosen is None:
        return None
    res, dets = chosen
    most = len(res.markers_used)
    if est is not None and est.status == "solved" and most < len(est.markers_used):
        return None
    notes = _changes(detections, dets)
    if notes:
        res.extra["second_look"] = notes
    return res, dets


def _same(a: Pose, b: Pose) -> bool:
    return a.translation_error(b) <= _SAME_M and a.rotation_error_deg(b) <= _SAME_DEG


def _changes(before: Mapping[str, DetectionResult], after: Mapping[str, DetectionResult]) -> list[str]:
    """What the second look threw out of the first look: pixels gone, or moved further than a re-measurement."""
    notes = []
    for obs, det in before.items():
        for name, d in det.detections.items():
            new = after[obs].detections.get(name)
            if new is None:
                notes.append(f"dropped {obs} saw {name} (no ball of its size where the pose puts it)")
            elif float(np.hypot(*(new.uv - d.uv))) > _MOVED_PX:
                notes.append(f"dropped {obs} saw {name} ({float(np.hypot(*(new.uv - d.uv))):.1f} px off; "
                             "measured again where the pose puts it)")
    return notes


def look_again(rig: Rig, images: Mapping[str, np.ndarray], detections: dict[str, DetectionResult],
               source: str, target: str, *, pixel_sigma: float = 1.0, **options: Any
               ) -> tuple[dict[str, DetectionResult], list[str]]:
    """``detections`` with the tags found where the frame's pose puts them (:mod:`.tag_look`) and the balls
    the second look measured again, where each verifies a pose (else ``detections`` themselves), and notes
    on what was found again or thrown out of the first look's pixels -- for callers that solve the frame their
    own way (the tracker's filter)."""
    tags = bool(missing_tags(rig, detections, source, target))
    if not tags and not needs_second_look(rig, detections, source, target):
        return detections, []
    est, error = first_solve(rig, detections, source, target, pixel_sigma=pixel_sigma, **options)
    notes: list[str] = []
    if tags:
        detections, est, error = with_tags_looked_for(rig, images, detections, est, error, source, target,
                                                      pixel_sigma=pixel_sigma, **options)
        notes = list(est.extra.get("second_look", [])) if est is not None else []
        if not needs_second_look(rig, detections, source, target):
            return detections, notes
    out = second_look(rig, images, detections, est, error, source, target, pixel_sigma=pixel_sigma, **options)
    if out is None:
        return detections, notes
    return out[1], [*notes, *out[0].extra.get("second_look", [])]
