"""Tracking never reports a wrong frame as solved, and refuses streams that
cannot be right (issue: never a silent wrong pose)."""

import cv2
import numpy as np
import pytest

from mutloc.core.geometry import so3_log
from mutloc.errors import InputError
from mutloc.sim.render import render
from mutloc.sim.world import standard_rig
from mutloc.track.sources import Stream
from mutloc.track.tracker import track, track_log
from test_pipeline import _sequence


def test_same_video_for_both_robots_is_refused():
    rig, frames, _ = _sequence("balls", 2, 10.0, seed=1)
    with pytest.raises(InputError, match="same images"):
        track(rig, {"p": iter(frames["p"]), "q": iter(list(frames["p"]))}, fps=10.0, progress=False)


def test_swapped_streams_are_refused():
    rig, frames, _ = _sequence("balls", 2, 10.0, seed=2)
    with pytest.raises(InputError, match="swapped"):
        track(rig, {"p": iter(frames["q"]), "q": iter(frames["p"])}, fps=10.0, progress=False)


@pytest.mark.parametrize("kind,seed,n,fps,min_solved,flagged", [
    ("balls", 3, 12, 10.0, 0.8, False), ("balls", 4, 12, 10.0, 0.8, False),
    ("tags", 5, 12, 10.0, 0.8, False), ("tags", 6, 12, 10.0, 0.8, False),
    # Half the lights are off at any time: many light frames have three
    # markers or fewer, unverified until a track confirms them (seed 0: all
    # confirmed since the lights are tracked in their own colours' images).
    pytest.param("lights", 0, 45, 30.0, 0.0, False, marks=pytest.mark.slow),
    pytest.param("lights", 1, 45, 30.0, 0.0, True, marks=pytest.mark.slow),
    # Frames 27-28 of this seed have all four lights off: their positions are
    # predictions 5 px off, which four "observations" cannot expose (chi-square
    # passed, pose 6 cm off). Such a frame is unverified, never solved.
    pytest.param("lights", 3, 30, 30.0, 0.0, True, marks=pytest.mark.slow),
])
def test_no_solved_frame_is_far_off(kind, seed, n, fps, min_solved, flagged, tmp_path, tmp_path_factory):
    """Rendered rooms with posters and clutter: every frame called solved is
    within 5 cm and 2 degrees of the truth, and most frames are solved."""
    rig, frames, truth = _sequence(kind, n, fps, seed, store=tmp_path_factory)
    video = tmp_path / "sub" / "annotated.mp4"
    streams = {r: Stream(iter(f), fps, r) for r, f in frames.items()}
    traj = track(rig, streams, progress=False, annotate=video)
    solved = [(r, T) for r, T in zip(traj.rows, truth) if r.status == "solved"]
    for r, T in solved:
        assert r.estimate.pose.translation_error(T) <= 0.05 and r.estimate.pose.rotation_error_deg(T) <= 2.0, r
    assert len(solved) >= min_solved * len(traj.rows), traj.summary()
    if flagged:
        assert any(r.status in ("unverified", "rejected") for r in traj.rows)  # the doubtful ones are flagged
    cap = cv2.VideoCapture(str(video))  # written at the stream's own rate, folder created
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(fps)
    cap.release()


def test_a_poster_taken_for_a_marker_is_rejected_or_dropped(tmp_path_factory):
    """A detection moved 40 px (a blob of another object) in every third frame:
    such frames are never solved with the wrong pixel in them."""
    from mutloc.detect.base import Detection

    fps = 10.0
    rig, frames, truth = _sequence("balls", 9, fps, seed=7, store=tmp_path_factory)
    import mutloc.track.tracker as tr

    real = tr.ObserverDetector.detect
    count = {"n": 0}

    def corrupt(self, frame):
        res = real(self, frame)
        if self.observer == "p" and frame.index % 3 == 0 and res.detections:
            name = sorted(res.detections)[0]
            d = res.detections[name]
            res.detections[name] = Detection(name, d.uv + np.array([40.0, 0.0]), d.score)
            count["n"] += 1
        return res

    tr.ObserverDetector.detect = corrupt
    try:
        traj = track(rig, {r: iter(f) for r, f in frames.items()}, fps=fps, progress=False)
    finally:
        tr.ObserverDetector.detect = real
    assert count["n"] >= 3
    for i, (row, T) in enumerate(zip(traj.rows, truth)):
        if i % 3 == 0:
            assert row.status in ("rejected", "solved", "unverified"), row
            if row.status == "solved":
                assert "dropped" in row.reason and row.estimate.pose.translation_error(T) <= 0.05
        else:
            assert row.status == "solved"


def test_same_colour_prop_beside_a_ball_does_not_mislead():
    """A prop ball of M1's colour 22 cm above M1: where the detector is
    unsure it hands over both blobs and the mutual geometry picks M1."""
    import mutloc
    from mutloc.core.rig import Marker, Robot
    from mutloc.sim.render import two_robot_world
    from mutloc.sim.synthetic import facing_pose
    from mutloc.sim.world import WorldRobot
    from mutloc.track.frames import detect_markers, observations_of

    unsure = 0
    for seed in range(4):
        rig = standard_rig("balls")
        T = facing_pose(1.8, yaw_p=np.radians(4 * seed - 6))
        world = two_robot_world(rig, T, seed=seed)
        m = rig.robot("q").markers["M1"]
        props = {"X": Marker("X", "r", m.position + np.array([0.05, -0.22, 0.0]), color=m.color,
                             extra={"radius": 0.03})}
        world.robots["r"] = WorldRobot(Robot("r", rig.robot("q").camera, props), world.robots["q"].pose_at(0),
                                       body=False)
        imgs = {r: render(world, r, 0.0, seed=seed) for r in ("p", "q")}
        dets = {"p": detect_markers(rig, "p", imgs["p"], targets=["q"]),
                "q": detect_markers(rig, "q", imgs["q"], targets=["p"])}
        unsure += bool(dets["p"].alternatives)
        est = mutloc.localize(rig, observations_of(dets))
        assert est.status == "solved" and est.pose.translation_error(T) < 0.005
    assert unsure >= 1


def _lit_sequence(seed: int, first: int, n: int, fps: float = 30.0):
    """Correct detections of the standard lights (only the lights that are on,
    exact pixels + 0.05 px) from frame ``first`` on, with the truth."""
    from mutloc.sim.render import moving_world, relative_pose
    from mutloc.sim.tracking import correct_detections

    rig = standard_rig("lights")
    world = moving_world(rig, distance=2.0, seed=seed)
    rng = np.random.default_rng(seed)
    times = [i / fps for i in range(first, first + n)]
    frames = [(t, correct_detections(world, t, rng)) for t in times]
    return rig, frames, [relative_pose(world, "p", "q", t) for t in times]


@pytest.mark.parametrize("first", [2, 22, 38])
def test_three_lit_lights_start_a_tentative_track_that_a_fourth_confirms(first):
    """Four lights blinking at 2-7.5 Hz are all on in 4 frames of 60: a
    track that waited for one would lose most three-light frames.  Three
    measured lights start a tentative track; it reports nothing until a frame
    with three lights, one of them new and sharply predicted, agrees with it
    -- before the next frame with all four on -- then three-light frames are
    solved, every one within 5 cm and 2 degrees.  The tentative frames within
    the smoother's lag of the confirming one are then reported as the track
    does ("confirmed in hindsight"), the others keep their per-frame statuses."""
    from mutloc.track.filtering import DEFAULT_SMOOTH_LAG

    rig, frames, truth = _lit_sequence(0, first, 40)
    traj = track_log(rig, frames, progress=False)
    lit = [len(o) for _, o in frames]
    full = next(i for i, n in enumerate(lit) if n == 4)
    solved = [i for i, r in enumerate(traj.rows) if r.status == "solved"]
    confirmed = next(i for i, r in enumerate(traj.rows) if "track confirmed" in r.reason)
    assert solved and confirmed < full, traj.summary()
    for i in range(confirmed):
        r = traj.rows[i]
        if "confirmed in hindsight" in r.reason:
            assert confirmed - i <= DEFAULT_SMOOTH_LAG, (i, r)
        else:  # tentative: per-frame statuses only
            assert r.status in ("unverified", "too_few"), (i, r)
    for i in solved:
        est = traj.rows[i].estimate
        assert est.pose.translation_error(truth[i]) <= 0.05 and est.pose.rotation_error_deg(truth[i]) <= 2.0, (i, est)
    after = [i for i in range(confirmed, len(frames)) if lit[i] >= 3]
    assert sum(traj.rows[i].status == "solved" for i in after) >= 0.95 * len(after), traj.summary()


def test_a_wrong_three_light_start_is_never_confirmed():
    """One of the three lights that start a tentative track is 25 px off (a
    poster blob) in that frame and the next few: three markers fit any such
    error exactly, so the tentative pose is wrong; the next frames with a
    fourth light contradict it, and no wrong frame is ever called solved."""
    from mutloc.core.observations import ObservationSet

    rig, frames, truth = _lit_sequence(0, 2, 40)
    bad = []
    for k, (t, o) in enumerate(frames[:6]):
        uv = np.array(o.uv)
        i = [j for j, m in enumerate(o.marker) if m == "M1"]
        if i:
            uv[i[0]] += [25.0, -10.0]
            bad.append(k)
        frames[k] = (t, ObservationSet(o.observer, o.marker, uv, t))
    assert bad
    traj = track_log(rig, frames, progress=False)
    for r, T in zip(traj.rows, truth):
        if r.status == "solved":
            assert r.estimate.pose.translation_error(T) <= 0.05 and r.estimate.pose.rotation_error_deg(T) <= 2.0, r
    assert all(traj.rows[k].status != "solved" for k in bad)


def test_three_marker_frame_with_a_wrong_detection_is_undone(tmp_path):
    """Held-out rendered sequence (seed 7002; tests/data/seed7002): q's M3 is
    measured 18-20 px off while M4 is unseen; the frame at 0.5 s (M1, M2 and
    the wrong M3) fits a track that the partial frame before it left
    unverifiable.  No solved frame may be off by more than 5 cm or 2 deg, and
    no pose of any status by more than 5 sigma (SPEC order, per component);
    the frame solved on its own after it undoes it."""
    from pathlib import Path

    from mutloc.io.logs import iter_observation_log
    from mutloc.io.trajectory import read_tum
    from mutloc.track.tracker import track_log

    data = Path(__file__).parent / "data" / "seed7002"
    times, truth = read_tum(data / "truth.tum")
    traj = track_log(str(data / "rig.yaml"), iter_observation_log(data / "obs.jsonl"), progress=False)
    assert len(traj.rows) == len(times) == 60
    worst_z = 0.0
    for row, k in zip(traj.rows, range(len(times))):
        assert abs(row.t - times[k]) < 1e-6
        e = row.estimate
        if e is None:
            continue
        T = truth[k]
        if row.status == "solved":
            assert e.pose.translation_error(T) < 0.05 and e.pose.rotation_error_deg(T) < 2.0, row.t
        d = np.r_[so3_log(T.R @ e.R.T), T.t - e.t]
        worst_z = max(worst_z, float(np.max(np.abs(d) / np.sqrt(np.diag(e.covariance)))))
    assert worst_z < 5.0
    at = {round(r.t, 3): r for r in traj.rows}
    assert at[0.5].status == "rejected" and "not confirmed" in at[0.5].reason
    assert at[0.533].status == "solved"
