"""Tags the first look missed, looked for again where the frame's pose puts them (mutloc.track.tag_look).

The scenes are tests/test_tags_real.py's pairs with p's tag on a slanted mount: q sees it 50-55 degrees off
its normal at 3 m (about 30 px), where the whole-image search (the AprilTag library at quad decimation 2)
mostly loses it while p sees q's tag nearly face-on.  Truth is the rendered geometry: the tag's corners
projected through q's camera, and the pose the scene was rendered with.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from mutloc.detect.tags import corner_marker_names, detect_tags, find_tag_near, tag_corner_points
from mutloc.errors import InputError
from mutloc.track import localize_images
from mutloc.track.frames import detect_markers, prepare_pair
from mutloc.track.second_look import look_again
from mutloc.track.tag_look import first_solve, missing_tags
from test_tags_real import pair_scene

TILT_DEG = 52.0
DISTANCE_M = 3.0


@functools.cache
def steep_scenes():
    """Eight pairs: (rig, T_qp, images, q's true pixels of p's tag corners (4, 2))."""
    out = []
    for seed in range(8):
        rig, T, images = pair_scene(200 + seed, DISTANCE_M, tilt_p_deg=TILT_DEG)
        truth = rig.robot("q").camera.project(T.apply(tag_corner_points(rig.robot("p").markers["TP"])))
        out.append((rig, T, images, truth))
    return out


def first_look(rig, images):
    ex, s, t = prepare_pair(rig, images, None, None, "image")
    dets = {o: detect_markers(ex, o, images[o], targets=[t if o == s else s]) for o in (s, t)}
    return ex, dets, first_solve(ex, dets, s, t)


def test_find_tag_near_finds_a_steep_tag_the_whole_image_search_misses():
    misses = found = 0
    for rig, _, images, truth in steep_scenes():
        marker, cam = rig.robot("p").markers["TP"], rig.robot("q").camera
        whole = detect_tags(images["q"], {"TP": marker}, camera=cam)
        if "TP" in whole.detections:
            continue
        misses += 1
        # A prediction ~10 px off, as a pose from the other camera's small tag alone gives.
        det = find_tag_near(images["q"], marker, truth + np.array([9.0, -6.0]), camera=cam)
        if det is not None:
            found += 1
            assert det.info["looked_again"] and det.info["id"] == 11
            # Fitted to its own edges, not to the prediction.
            assert np.max(np.hypot(*(det.corners - truth).T)) < 0.35
    assert misses >= 5  # the scenes are the steep case the whole-image search loses ...
    assert found >= misses - 2  # ... and the window finds most of them (one of 21 px is not decodable)


def test_find_tag_near_finds_nothing_where_no_tag_is_and_refuses_bad_input():
    rig, _, images, truth = steep_scenes()[0]
    marker, cam = rig.robot("p").markers["TP"], rig.robot("q").camera
    assert find_tag_near(images["q"], marker, truth + np.array([200.0, 120.0]), camera=cam) is None
    assert find_tag_near(images["q"], marker, truth - 5000.0, camera=cam) is None  # window off the image
    with pytest.raises(InputError):
        find_tag_near(images["q"], marker, truth[:3])
    with pytest.raises(InputError):
        find_tag_near(images["q"], marker, np.full((4, 2), np.nan))
    with pytest.raises(InputError):
        find_tag_near(images["q"], rig.robot("p").markers["TP"].__class__("B", "p", np.zeros(3)), truth)


def test_localize_images_uses_the_tag_found_again_and_the_pose_improves():
    before, after, found = [], [], 0
    for rig, T, images, truth in steep_scenes():
        ex, dets, (est, _) = first_look(rig, images)
        assert est is not None  # p's view of q's tag alone gives a pose
        before.append(100 * est.pose.translation_error(T))
        res = localize_images(rig, images)
        after.append(100 * res.estimate.pose.translation_error(T))
        got = [res.detections["q"].detections.get(c) for c in corner_marker_names("TP")]
        if "TP#0" not in dets["q"].detections and all(d is not None for d in got):
            found += 1
            assert max(np.hypot(*(d.uv - x)) for d, x in zip(got, truth)) < 0.35
            assert len(res.estimate.markers_used) == 8 and res.estimate.status == "solved"
            assert any("looked for again" in n for n in res.estimate.extra["second_look"])
    assert found >= 5  # of the 7 the first look missed
    # One small tag seen by one camera leaves the range to a few cm; both tags bring it to millimetres.
    assert np.median(before) > 1.0
    assert np.median(after) < 0.3 and np.median(after) < np.median(before) / 5


def test_the_tracker_look_again_returns_the_tag_with_a_note():
    for rig, _, images, truth in steep_scenes():
        ex, dets, (est, _) = first_look(rig, images)
        if "TP#0" in dets["q"].detections:
            continue
        assert missing_tags(ex, dets, "p", "q") == {"q": ["TP"]}
        again, notes = look_again(ex, images, dets, "p", "q")
        assert all(c in again["q"].detections for c in corner_marker_names("TP"))
        assert "TP#0" not in dets["q"].detections  # the caller's detections are left as they were
        assert notes == ["q saw tag TP where the pose put it (looked for again)"]
        return
    pytest.fail("no scene where the first look missed the steep tag")


def test_nothing_is_looked_for_when_every_tag_was_found():
    rig, _, images = pair_scene(3, 2.0)
    ex, dets, _ = first_look(rig, images)
    assert missing_tags(ex, dets, "p", "q") == {}
    again, notes = look_again(ex, images, dets, "p", "q")
    assert again is dets and notes == []


def test_look_where_tracked_finds_the_tag_where_a_prediction_puts_it_and_nothing_elsewhere():
    """A record of q's camera alone (no pose of its own): the track's prediction places p's tag."""
    from mutloc.core.pose import Pose
    from mutloc.track.tag_look import look_where_tracked

    checked = 0
    for rig, T, images, truth in steep_scenes():
        ex, dets, _ = first_look(rig, images)
        if "TP#0" in dets["q"].detections:
            continue
        q_only = {"q": dets["q"]}
        # The prediction a few centimetres and a degree off, as a filter's may be.
        off = Pose.from_rotvec([0.0, np.radians(1.0), 0.0], [0.03, -0.02, 0.04])
        found, notes = look_where_tracked(ex, images, q_only, lambda: {"q": Pose.identity(), "p": off @ T})
        got = [found["q"].detections.get(c) for c in corner_marker_names("TP")]
        if all(d is not None for d in got):
            checked += 1
            assert max(np.hypot(*(d.uv - x)) for d, x in zip(got, truth)) < 0.35
            assert notes == [("p", "q saw tag TP where the track put it (looked for again)")]
        # A prediction a metre to the side looks where the tag is not: nothing is made up.
        far = Pose.from_rotvec([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]) @ T
        none, notes = look_where_tracked(ex, images, q_only, {"q": Pose.identity(), "p": far})
        assert "TP#0" not in none["q"].detections and notes == []
    assert checked >= 5


def team_of_three(rig):
    """``rig`` (p and q) with a third robot r, the reference, carrying a tag of its own."""
    from mutloc.core.rig import Marker, Rig, Robot

    tq = rig.robot("q").markers["TQ"]
    tag = {**tq.tag, "id": 12}
    return Rig({**rig.robots, "r": Robot("r", rig.robot("q").camera, {"TR": Marker("TR", "r", tq.position, tag=tag)})})


#: Where q is in the reference r's frame (T_rq) in the team-of-three tests: beside r, turned 29 degrees.
T_RQ = ((0.05, 0.5, -0.04), (-1.5, 0.1, 0.4))


def test_look_where_tracked_from_a_robot_that_is_not_the_reference():
    """A team of three whose track is in r's frame (r the reference): q, not the reference, looks for p's
    tag where ``T_rq^-1 T_rp`` puts it, and finds it at the rendered corners.  r's own tag is predicted
    too, and is not in the image: nothing is made up for it."""
    from mutloc.core.pose import Pose
    from mutloc.track.frames import expanded_rig
    from mutloc.track.tag_look import look_where_tracked

    T_rq = Pose.from_rotvec(*T_RQ)
    checked = 0
    for rig, T_qp, images, truth in steep_scenes():
        ex, dets, _ = first_look(rig, images)
        if "TP#0" in dets["q"].detections:
            continue
        team = expanded_rig(team_of_three(rig))
        predicted = {"r": Pose.identity(), "q": T_rq, "p": T_rq @ T_qp}
        found, notes = look_where_tracked(team, images, {"q": dets["q"]}, predicted)
        got = [found["q"].detections.get(c) for c in corner_marker_names("TP")]
        if all(d is not None for d in got):
            checked += 1
            assert max(np.hypot(*(d.uv - x)) for d, x in zip(got, truth)) < 0.35
            assert notes == [("p", "q saw tag TP where the track put it (looked for again)")]
            assert not any(c in found["q"].detections for c in corner_marker_names("TR"))
    assert checked >= 5


def test_team_tracker_predicts_confirmed_robots_only_and_never_backwards():
    from mutloc.core.pose import Pose
    from mutloc.sim.render import default_path
    from mutloc.sim.tracking import observation_sequence
    from mutloc.sim.world import standard_rig
    from mutloc.track.filtering import FilterOptions
    from mutloc.track.team import TeamTracker

    rig = standard_rig()
    path = default_path(2.0, 8.0, 0.3)
    seq = observation_sequence(rig, path, duration=1.5, pixel_sigma=0.5, drop=0.0, blind=(), outliers=0.0)
    tracker = TeamTracker(rig, "q")
    assert tracker.predicted(0.0) == {}  # nothing tracked yet
    for t, obs in zip(seq.times, seq.frames):
        tracker.step(float(t), obs)
    t_next = float(seq.times[-1]) + 1 / 30
    pred = tracker.predicted(t_next)
    assert set(pred) == {"q", "p"} and pred["q"].translation_error(Pose.identity()) == 0.0
    # T_q_p predicted a frame ahead: as near the path there as the filter is now to the path now ...
    now = tracker.filter.pose("p")
    err_now = now.translation_error(path(float(seq.times[-1])))
    assert pred["p"].translation_error(path(t_next)) < err_now + 0.002
    assert pred["p"].rotation_error_deg(path(t_next)) < 0.5
    # ... moved on from the filter's pose by the velocity it has measured (p sways at up to ~0.5 m/s).
    assert 0.0005 < pred["p"].translation_error(now) < 0.03
    assert tracker.predicted(float(seq.times[-1]) - 0.5) == {}  # the filter does not run backwards
    assert tracker.filter.time == float(seq.times[-1])  # predicting did not move the filter
    unfiltered = TeamTracker(rig, "q", options=FilterOptions(kind="none"))
    unfiltered.step(0.0, seq.frames[0])
    assert unfiltered.predicted(1 / 30) == {}


@functools.cache
def steep_streams():
    """p moving 3 m in front of q with its tag turned 55 degrees, each camera at its own times (q a
    quarter frame after p, 15 fps, 0.8 px blur): no record holds both cameras' frames."""
    import dataclasses

    from mutloc.sim.render import moving_world, render
    from mutloc.track.sources import Frame
    from test_tags_real import tag_rig

    rig = tag_rig(tilt_p_deg=55.0)
    world = moving_world(rig, distance=3.0, period=8.0, seed=0)
    world = dataclasses.replace(world, sensor=dataclasses.replace(world.sensor, psf_sigma_px=0.8))
    fps, n = 15.0, 14
    frames = {r: [(k / fps + off, render(world, r, k / fps + off, seed=1 + k, noise_sigma=2.0)) for k in range(n)]
              for r, off in (("p", 0.0), ("q", 1 / 60))}
    return rig, world, frames


def _streams(frames):
    from mutloc.track.sources import Frame

    return {r: [Frame(k, t, img) for k, (t, img) in enumerate(fr)] for r, fr in frames.items()}


def test_trackers_look_for_a_missing_tag_where_the_track_puts_it():
    from mutloc.sim.render import relative_pose
    from mutloc.track.team import track_team
    from mutloc.track.tracker import track

    rig, world, frames = steep_streams()
    ex = prepare_pair(rig, {r: None for r in ("p", "q")}, None, None, "image")[0]
    X = tag_corner_points(rig.robot("p").markers["TP"])
    missed = [t for t, img in frames["q"] if "TP#0" not in detect_markers(ex, "q", img, targets=["p"]).detections]
    assert len(missed) >= 5  # q's first look loses p's steep tag in most of its frames
    for name, traj in (("track", track(rig, _streams(frames), progress=False)),
                       ("track_team", track_team(rig, _streams(frames), "q", progress=False).tracks["p"])):
        found = 0
        for row in traj.rows:
            if row.t not in missed:
                continue
            det = row.detections.get("q")
            if det is not None and "TP#0" in det.detections:
                found += 1
                truth = rig.robot("q").camera.project(relative_pose(world, "p", "q", row.t).apply(X))
                got = [det.detections[c].uv for c in corner_marker_names("TP")]
                assert max(np.hypot(*(g - x)) for g, x in zip(got, truth)) < 0.35, name
                assert "q saw tag TP where the track put it" in row.reason, name
        # Without the look none; with it most (not the first, before p's records confirm the track, nor
        # the few frames where the tag is not decodable at all: 10 of 14 here).
        assert found >= 0.6 * len(missed), (name, found, len(missed))


def test_a_tag_found_again_has_corners_its_edges_pin_down():
    """Tags 65-75 degrees off their normal (tests/test_detect_tags.py's renderer, 45 px face-on), looked for
    around their true corners moved 3 px: every tag find_tag_near returns has all four corners within
    0.7 px of the truth -- the edge fit's RMS test turns down the ones whose sides it could not follow
    (without it, some come back 1-2 px off)."""
    import test_detect_tags as T
    from mutloc.core.rig import Marker

    rng = np.random.default_rng(11)
    marker = Marker("T", "x", np.zeros(3), tag={"family": "tag36h11", "id": 3, "size": 0.12})
    found, worst = 0, 0.0
    for tilt in (65.0, 70.0, 75.0):
        for _ in range(12):
            z = float(T.K[0, 0]) * 0.12 / 45.0
            axis = rng.normal(size=3)
            axis[2] = 0.0
            axis /= np.linalg.norm(axis)
            t = np.array([rng.uniform(-0.2, 0.2) * z, rng.uniform(-0.1, 0.1) * z, z])
            img, (corners,) = T.render([("tag36h11", 3, axis * np.radians(tilt), t, 0.12)], rng)
            det = find_tag_near(img, marker, corners + rng.normal(0.0, 3.0, (1, 2)))
            if det is not None:
                found += 1
                worst = max(worst, float(np.max(np.hypot(*(det.corners - corners).T))))
    assert found >= 18  # most are still found ...
    assert worst < 0.7  # ... and none pixels off


def test_a_first_look_tag_whose_edge_fit_fails_is_fitted_again_enlarged():
    """p's tag 65 degrees off its normal at 3 m (tests/test_tags_real.py's pair 30457): the whole-image
    search decodes it, but its quad is 3.3 px off and the edge fit cannot follow the sides from there; fitted
    again in an enlarged window around it, its corners come within a few tenths of a pixel of the truth."""
    rig, T, images = pair_scene(30457, 3.0, tilt_p_deg=65.0)
    marker, cam = rig.robot("p").markers["TP"], rig.robot("q").camera
    truth = cam.project(T.apply(tag_corner_points(marker)))
    library = detect_tags(images["q"], {"TP": marker}, camera=cam, refine="none").detections["TP"]
    assert np.max(np.hypot(*(library.corners - truth).T)) > 2.0  # the case is real
    det = detect_tags(images["q"], {"TP": marker}, camera=cam).detections["TP"]
    assert det.info["refine"] == "edges_enlarged" and "looked_again" not in det.info
    assert np.max(np.hypot(*(det.corners - truth).T)) < 0.3
