"""The driver: run the stages of the ball detector over one image."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ...core.camera import Camera
from ...core.rig import Marker
from ...errors import InputError
from ..base import Detection, DetectionResult, as_bgr
from .choose import (SHADED, Candidate, assign, choose_consistent, rig_mates, same_blob, score_candidate, scored,
                     worst_pair_error)
from .fit import CameraModel, Fit, ellipse_info, fit_rim
from .guided import guided_blobs, per_rim
from .cues import encoded_hue_chroma
from .light import light_gains, lut_gains
from .occlusion import recentre, smooth_rim
from .params import BallParams, value_lut
from .rim import sample_rim
from .search import WHOLE, BallSearch, Blob, find_blobs, pick_downscale, value_floor
from .sweep import OK, measure, sweep

__all__ = ["detect_balls", "refine_blob"]



def detect_balls(
    image: Any,
    markers: Mapping[str, Marker],
    *,
    camera: Camera | None = None,
    params: BallParams | None = None,
) -> DetectionResult:
    """Find the coloured balls of ``markers`` in a BGR image.

    Parameters
    ----------
    image:
        ``uint8`` BGR ``(H, W, 3)`` (grayscale and float images are converted
        by :func:`~mutloc.detect.base.as_bgr`).
    markers:
        ``{name: Marker}``; markers without a ``color`` are ignored.  A colour
        without a usable hue (white, grey, black) raises :class:`InputError`.
        ``Marker.extra["radius"]`` (metres, default 0.03) is used with
        ``camera`` to reject blobs of implausible size and to report distance.
    camera:
        The camera that took the image.  With it the reported pixel is the
        projection of the sphere centre (perspective-corrected, distortion
        aware); without it, the centre of the fitted ellipse.
    params:
        Tuning (:class:`BallParams`; its defaults when None).

    Returns
    -------
    DetectionResult
        ``detections[name]`` has ``uv``, ``score`` in (0, 1] and ``info``
        (``radius_px``, ``rim_fraction`` (share of the rim that fits; lower
        when occluded), ``rms_px``, ``hue_deg``, ``chroma``, ``shading``,
        ``ellipse`` (the fitted outline) and, with a camera, ``distance_m``
        to the ball's centre), ``visible_fraction`` (share of the rim seen
        unhidden) and ``residual_px`` (the rim fit's RMS); every marker with
        a colour that was not found is listed in ``missing``, with why in
        ``missing_reasons`` (e.g. too hidden to measure without bias).  Never raises
        for "not found".
    """
    img = as_bgr(image)
    if not isinstance(markers, Mapping):
        raise InputError(f"markers must be a mapping name -> Marker, got {type(markers).__name__}")
    if params is None:
        params = BallParams()
    elif not isinstance(params, BallParams):
        raise InputError(f"params must be a BallParams, got {type(params).__name__}")
    if camera is not None and not isinstance(camera, Camera):
        raise InputError(f"camera must be a mutloc Camera, got {type(camera).__name__}")
    searches = [
        BallSearch.from_marker(str(name), m, params)
        for name, m in markers.items()
        if getattr(m, "color", None) is not None
    ]
    result = DetectionResult()
    if not searches:
        return result

    Himg, Wimg = img.shape[:2]
    rmax = float(params.max_radius_px) if params.max_radius_px is not None else min(Himg, Wimg) / 3.0
    k = pick_downscale(params.downscale, params.min_radius_px, Wimg, Himg)
    # Hybrid search (the default when min_radius_px needs full resolution):
    # the coarse search runs at half resolution, which finds every ball of
    # more than ~1.5 coarse pixels, and only markers it leaves without a
    # candidate are searched again at full resolution, for small blobs.
    fallback = params.downscale is None and k == 1 and min(Wimg, Himg) // 2 >= 120
    if fallback:
        k = 2
    lut = value_lut(bool(params.srgb), float(params.mix_gamma))
    # Exposure from the full image: the same floor whatever the search
    # resolution.
    v_floor = value_floor(img)
    cam = CameraModel(camera) if camera is not None else None
    # The light's colour, divided out before hues are compared (None: white).
    gains = light_gains(img, params)
    # Why each marker's candidates were turned down, the most telling first.
    why: dict[str, tuple[int, str]] = {}

    def reject(name: str, rank: int, reason: str) -> None:
        if rank > why.get(name, (-1, ""))[0]:
            why[name] = (rank, reason)

    # Blobs whose rim, on the first look, was much off their coarse circle
    # (an occluder cut into them): the ones worth a second look.
    cut: list[Blob] = []

    def refine(s: BallSearch, blob: Blob, rescue: bool = False) -> Candidate | None:
        looked.setdefault(s.name, []).append(blob)
        c = refine_blob(img, lut, s, blob, cam, rmax, params, v_floor=v_floor, gains=gains,
                        recentre_it=rescue, cut=None if rescue else cut)
        if c is None:
            reject(s.name, 0, "rejected: no blob of its colour has the outline of a ball")
            return None
        vis = float(c.info["rim_fraction"])
        if vis < params.min_visible_fraction:
            reject(s.name, 3, f"occluded: only {100 * vis:.0f}% of its rim is visible "
                              f"(min_visible_fraction {100 * params.min_visible_fraction:.0f}%)")
            return None
        if c.score < params.min_score:
            # Kept aside: a ball hidden by more than half scores low for the rim it does not show
            # (the rig's guided look below judges it by the rim it shows).
            weak.setdefault(s.name, []).append(c)
            reject(s.name, 1, f"rejected: its best blob scores {c.score:.2f}, below min_score {params.min_score}")
            return None
        source[id(c)] = blob
        return c

    source: dict[int, Blob] = {}  # id of a candidate -> the blob it was refined from
    weak: dict[str, list[Candidate]] = {}  # candidates scoring below min_score, per marker
    looked: dict[str, list[Blob]] = {}  # blobs refined, per marker
    masks: dict[str, list[tuple[np.ndarray, float, float]]] = {}  # the searches' hue masks, per marker

    per_marker: dict[str, list[Candidate]] = {}
    skipped: dict[str, list[Blob]] = {}
    later: dict[str, list[Blob]] = {}

    def search(level: list[BallSearch], k: int, blob_rmax: float) -> None:
        for s, blobs in zip(level, find_blobs(img, level, k, blob_rmax, v_floor, params, gains=gains, masks=masks)):
            good_r = math.inf
            found: list[Candidate] = []
            # Blobs ranked below max_candidates are looked at only when none
            # of the best-ranked ones is a ball (a partly hidden ball ranks
            # low among look-alikes).  Not for the rig check's second look:
            # at a distance the rig cannot tell a printed disc from a ball,
            # and more blobs looked at would find more of those.
            later[s.name] = list(blobs[: 2 * int(params.max_candidates)])
            skipped[s.name] = []
            for blob in [b for b in blobs if b.quality >= WHOLE][: int(params.max_candidates)]:
                # Once a blob fits well, a lower-ranked blob can only win by
                # being bigger (more rim evidence): smaller ones are not
                # refined (unless the rig check below asks for them), which
                # saves time in cluttered scenes.
                if good_r == math.inf or blob.radius > good_r:
                    c = refine(s, blob)
                    if c is not None:
                        found.append(c)
                        if c.score >= params.good_enough:
                            good_r = min(good_r, c.radius_px)
                else:
                    skipped[s.name].append(blob)
            per_marker[s.name] = found

    def rescue(s: BallSearch, mates: list[Candidate], whole: bool = True) -> list[Candidate]:
        """Candidates of ``s`` that the first look missed: a partly hidden
        ball ranks low among look-alikes (its coarse blob is a piece, off
        the ball's circle), so more blobs are looked at, and those whose rim
        looked cut have their circle found again from the visible outline.
        Only when needed: that search is slower, and where the first fit
        holds it is the more accurate.  ``whole``: also whole-looking blobs
        ranked below the first look's."""
        # Where the robot's other balls were found, a blob far from their
        # size is not this ball (the rig is small against the distance: a
        # factor 1.6 either way leaves room for 1.2 m).
        sizes = [c.radius_px for c in mates]
        lo, hi = (min(sizes) / 1.6, max(sizes) * 1.6) if sizes else (0.0, math.inf)
        blobs = [b for b in later[s.name] if lo <= b.radius <= hi]
        done = [b for b in later[s.name] if b.quality >= WHOLE][: int(params.max_candidates)]
        found = [c for b in blobs if (whole or b.quality < WHOLE) and not any(b is x for x in done)
                 and (c := refine(s, b)) is not None]
        found += [c for b in blobs if any(b is x for x in cut) and (c := refine(s, b, True)) is not None]
        later[s.name] = []
        return found

    def best_of_mates(s: BallSearch) -> list[Candidate]:
        return [max(per_marker[g.name], key=lambda c: c.score) for g in searches
                if g is not s and g.robot is not None and g.robot == s.robot and per_marker[g.name]]

    def look_where_the_rig_says(group: list[BallSearch], picked: list[Candidate]) -> list[Candidate]:
        """``picked`` with the robot's missing balls looked for again where the rig puts them, around a
        ball of the robot found whole (:mod:`.guided`)."""
        whole = [c for c in picked if float(c.info["rim_fraction"]) >= 0.9 and c.xyz is not None]
        if not whole or cam is None:
            return picked
        mate = max(whole, key=lambda c: c.score)
        for g in group:
            if any(c.search.name == g.name for c in picked):
                continue
            L = float(np.linalg.norm(g.position - mate.search.position))  # type: ignore[operator]
            if L < 1e-6:
                continue
            # Looked for among blobs of its hue (posters), where printed discs are what passes for a
            # ball: a candidate must be shaded like a lit sphere.
            def fits(c: Candidate | None) -> bool:
                return (c is not None and float(c.info["rim_fraction"]) >= params.min_visible_fraction
                        and per_rim(c, params) >= params.min_score and float(c.info["shading"]) >= SHADED)

            cands = [c for c in weak.get(g.name, []) if fits(c)]
            # Blobs judged already are not refined again (those that scored low were kept aside).
            for b in guided_blobs(img, g, mate, L, cam.f, v_floor, gains, params, looked.get(g.name),
                                  masks.get(g.name, [])):
                if fits(c := refine_blob(img, lut, g, b, cam, rmax, params, v_floor=v_floor, gains=gains)):
                    cands.append(c)  # type: ignore[arg-type]
            if not cands:
                continue
            # The found balls stay as they are; the rig check decides between the candidates and none.
            options = {c.search.name: [c] for c in picked}
            options[g.name] = cands
            new, _ = choose_consistent([x for x in group if x.name in options], options, params,
                                       key=lambda c: per_rim(c, params))
            if len(new) == len(picked) + 1:
                for c in new:
                    if c.search.name == g.name:
                        c.info["guided"] = True
                picked = new
                per_marker[g.name] = per_marker.get(g.name, []) + [c for c in new if c.search.name == g.name]
        return picked

    search(searches, k, rmax)
    for s in searches:
        if not per_marker[s.name] and later[s.name]:
            per_marker[s.name] = rescue(s, best_of_mates(s))
    if fallback:
        lost = [s for s in searches if not per_marker[s.name]]
        if lost:
            # Balls big enough for the half-resolution search were found
            # there: full resolution only looks for the small ones.
            search(lost, 1, min(rmax, params.fallback_max_radius_px))

    # Balls that share a robot with another searched ball at a different
    # place are checked against each other (needs a camera for their 3-D
    # positions).
    mates = rig_mates(searches) if camera is not None else {}
    chosen: list[Candidate] = []
    for group in mates.values():
        # Per robot, the combination of blobs (or none) that best agrees
        # with the rig: balls of one robot keep their mutual distances.
        picked, consistent = choose_consistent(group, per_marker, params)
        if not consistent or (any(skipped[g.name] for g in group)
                              and worst_pair_error(picked) > params.recheck_pair_error):
            # Something does not fit: the blobs passed over may hold the
            # right ball, and a ball left out may be partly hidden.
            kept = {c.search.name: c for c in picked}
            for g in group:
                per_marker[g.name] += [c for b in skipped[g.name] if (c := refine(g, b)) is not None]
                if g.name not in kept and later[g.name]:
                    per_marker[g.name] += rescue(g, list(kept.values()), whole=False)
            picked, _ = choose_consistent(group, per_marker, params)
        # A chosen ball whose rim was cut (an occluder) and whose size is off its whole mate's: the
        # first fit may have taken the occluder's edge for rim; its circle found again from the
        # visible outline competes with it.
        whole = [c.radius_px for c in picked if float(c.info["rim_fraction"]) >= 0.9]
        if whole:
            extra = False
            for c in picked:
                b = source.get(id(c))
                if (b is not None and any(b is x for x in cut) and abs(c.radius_px / np.median(whole) - 1.0) > params.cut_size_tolerance
                        and (c2 := refine(c.search, b, True)) is not None):
                    per_marker[c.search.name].append(c2)
                    extra = True
            if extra:
                picked, _ = choose_consistent(group, per_marker, params)
        chosen.extend(look_where_the_rig_says(group, picked))
    rest = [c for s in searches if s.robot not in mates for c in per_marker[s.name]]

    for s in searches:
        if per_marker.get(s.name) and not any(c.search.name == s.name for c in chosen) and s.robot in mates:
            reject(s.name, 2, "rejected: its blobs do not fit the rig's distances to the robot's other balls")
    taken = assign(chosen, rest)
    for c in taken:
        c.info["ellipse"] = ellipse_info(c.outline)
        result.detections[c.search.name] = Detection(
            marker=c.search.name, uv=c.uv, score=c.score, info=c.info,
            visible_fraction=float(c.info["rim_fraction"]), residual_px=float(c.info["rms_px"]),
            sigma_scale=float(c.info["sigma_scale"]))
    # Where another blob of a marker scored nearly as well, the detector is
    # unsure: hand it over too, and let the mutual geometry decide.  Scores
    # are compared per share of visible rim: a partly hidden ball scores
    # low for being hidden, not for looking less like a ball.
    for c in taken:
        alts = [a for a in per_marker.get(c.search.name, [])
                if a is not c and per_rim(a, params) >= params.alternative_ratio * per_rim(c, params)
                and not any(same_blob(a, t) for t in taken)]
        if alts:
            result.alternatives[c.search.name] = [
                Detection(marker=a.search.name, uv=a.uv, score=a.score, info=a.info,
                          sigma_scale=float(a.info["sigma_scale"]))
                for a in sorted(alts, key=lambda a: -a.score)[: params.max_alternatives]]
    result.missing = [s.name for s in searches if s.name not in result.detections]
    for name in result.missing:
        if per_marker.get(name) and name not in why:
            reject(name, 2, "ambiguous: its blob went to another marker of a similar colour")
        result.missing_reasons[name] = why.get(name, (0, "not_found: no blob of its colour"))[1]
    return result


def refine_blob(
    img: np.ndarray,
    lut: np.ndarray,
    s: BallSearch,
    blob: Blob,
    cam: CameraModel | None,
    max_r: float,
    params: BallParams,
    *,
    v_floor: int = 12,
    gains: np.ndarray | None = None,
    recentre_it: bool = False,
    cut: list[Blob] | None = None,
) -> Candidate | None:
    """Sub-pixel fit and score of one coarse blob; None if it is not a plausible ball.

    Two rounds of rim sampling and fitting: the second casts its rays from
    the fitted centre, with its windows centred on the fitted outline (an
    ellipse off-axis).  With ``recentre_it``, when much of the first
    round's rim is off the coarse circle (an occluder cut or split the
    blob), the circle is found again from the visible outline
    (:func:`~.occlusion.recentre`); without, such a blob is appended to
    ``cut``.  Rim points on an occluder's edge are left out
    (:func:`~.occlusion.smooth_rim`).
    ``v_floor`` and ``gains`` (the light's colour) are as in the coarse search.
    """
    cx, cy, r = float(blob.u), float(blob.v), float(blob.radius)
    # Rims are measured in colours as under white light.
    lg = lut_gains(gains, params) if gains is not None else None
    if cam is not None and cam.pinhole and not recentre_it:
        return _refine_pinhole(img, lut, s, blob, cam, max_r, params, lg, cut)
    recentred = moved = False
    it = 0
    hw = params.local_half_window_px
    while it < 2:
        if it == 0:
            n_rays = min(max(round(2 * math.pi * r), 24), 96)
            ang = np.arange(n_rays) * (2.0 * math.pi / n_rays)
            rexp = np.full(n_rays, r)
        rim = sample_rim(img, lut, cx, cy, ang, rexp, hw, params.step_px, lg)
        # Rays far off the expected rim are occluders, clutter or a bad
        # coarse circle: the ones close to it are the initial inlier set.
        tol0 = max(1.5, 0.15 * r) if it == 0 else max(0.75, 0.05 * r)
        near = rim.valid & (np.abs(np.where(rim.valid, rim.radius, 1e9) - rexp) <= tol0)
        if it == 0 and not recentred and near.sum() < params.recentre_below * n_rays:
            recentred = True
            if not recentre_it:
                if cut is not None:
                    cut.append(blob)
            else:
                c = recentre(img, s, blob, v_floor, gains, params)
                if c is not None and math.hypot(c[0] - cx, c[1] - cy) + abs(c[2] - r) > 0.25 + 0.05 * r:
                    cx, cy, r = c
                    moved = True
                    continue
        rim.valid = smooth_rim(rim.radius, rim.valid, rim.ang, params.max_rim_slope_deg)
        init = near & rim.valid
        if init.sum() < 6:
            return None
        fit = fit_rim(rim, init, cam, params.max_axis_ratio)
        if fit is None:
            return None
        cx, cy = float(fit.centre_px[0]), float(fit.centre_px[1])
        rexp = fit.radii
        r = fit.radius_px
        if not (0.7 * params.min_radius_px <= r <= 1.5 * max_r) or not np.all(np.isfinite(rexp)):
            return None
        if it == 0:
            hw = _second_round_window(params, int(near.sum()), np.count_nonzero(fit.weights > 0.5), n_rays)
        it += 1
    # The coarse blob of a split ball is one piece of it, filling little of
    # its circle: the visible rim (in the score) is the better judge then.
    fill = max(blob.fill, 0.6) if moved else blob.fill
    return score_candidate(img, lut, s, fill, rim, fit, cam, params, rim_gains=lg)


def _second_round_window(params: BallParams, n_near: int, n_kept: int, n_rays: int) -> float:
    """The local window of the second round of rays: :attr:`~.params.BallParams.whole_rim_half_window_px` when
    the first round found the rim nearly whole (``whole_rim_share`` of the rays near the circle and kept by
    its fit), else :attr:`~.params.BallParams.local_half_window_px`."""
    whole = min(n_near, n_kept) >= params.whole_rim_share * n_rays
    return params.whole_rim_half_window_px if whole else params.local_half_window_px


def _refine_pinhole(
    img: np.ndarray,
    lut: np.ndarray,
    s: BallSearch,
    blob: Blob,
    cam: CameraModel,
    max_r: float,
    params: BallParams,
    lg: np.ndarray | None,
    cut: list[Blob] | None,
) -> Candidate | None:
    """:func:`refine_blob` with a pinhole camera and no recentring: each round of rays one compiled
    :func:`~.sweep.sweep`, the score's measurements one :func:`~.sweep.measure` (the same figures)."""
    cx, cy, r = float(blob.u), float(blob.v), float(blob.radius)
    gain = np.ones(3) if lg is None else np.ascontiguousarray(lg, dtype=np.float64)
    n_rays = min(max(round(2 * math.pi * r), 24), 96)
    ang = np.arange(n_rays) * (2.0 * math.pi / n_rays)
    rexp = np.full(n_rays, r)
    slope_lim = math.tan(math.radians(params.max_rim_slope_deg)) * 2.0 * math.pi / max(n_rays, 1)
    K, dist = cam.camera.K, cam.camera.dist
    hw = params.local_half_window_px
    for it in range(2):
        tol0 = max(1.5, 0.15 * r) if it == 0 else max(0.75, 0.05 * r)
        status, n_near, inner, d, w, cos_t, rms, outline, cu, cv_, radii, r_fit, finite = sweep(
            img, lut, gain, cx, cy, ang, rexp, hw, params.step_px, tol0, slope_lim,
            cam.Kinv, K, dist, cam.f)
        if it == 0 and n_near < params.recentre_below * n_rays and cut is not None:
            cut.append(blob)
        if status != OK:
            return None
        cx, cy, rexp, r = cu, cv_, radii, r_fit
        if not (0.7 * params.min_radius_px <= r <= 1.5 * max_r) or not finite:
            return None
        if it == 0:
            hw = _second_round_window(params, n_near, np.count_nonzero(w > 0.5), n_rays)
    fit = Fit(outline, np.array([cx, cy]), radii, r, w, rms, d, cos_t, None)
    n_in, eb, eg, er, shading, uv = measure(img, lut, gain, w, inner, cx, cy, ang, radii, 2.0 * params.hue_tol_deg, K,
                                            dist, d)
    hue, chroma = encoded_hue_chroma(eb, eg, er)
    return scored(s, blob.fill, fit, True, params, float(n_in) / len(w), hue, chroma, shading, uv, ang)
