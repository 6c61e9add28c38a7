"""``mutloc.sim.truth_log.truth_pose_at``: the simulator's truth between capture instants (what the tracking
tests and benches compare a pose stamped between frames with)."""

import numpy as np
import pytest

from mutloc.sim.truth_log import truth_pose_at


def _rz(deg):
    a = np.radians(deg)
    return [[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]


TRUTH = {"frames": [
    {"timestamp": 10.0, "robots": {"q": {"R": _rz(0), "t": [0.0, 0.0, 0.0]}}},
    {"timestamp": 11.0, "robots": {"q": {"R": _rz(90), "t": [2.0, 0.0, 4.0]}}},
    {"timestamp": 13.0, "robots": {"q": {"R": _rz(30), "t": [2.0, 6.0, 4.0]}}},
]}


def _yaw(pose):
    return np.degrees(np.arctan2(pose.R[1, 0], pose.R[0, 0]))


@pytest.mark.parametrize(("t", "yaw", "xyz"), [
    (10.0, 0.0, [0, 0, 0]),        # on a capture instant: that frame's pose
    (10.25, 22.5, [0.5, 0, 1]),    # a quarter of the way: a quarter of the turn, of the path
    (11.0, 90.0, [2, 0, 4]),
    (12.5, 45.0, [2, 4.5, 4]),     # three quarters of the way back from 90 to 30 degrees
    (9.0, 0.0, [0, 0, 0]),         # before the first frame: held there
    (14.0, 30.0, [2, 6, 4]),       # after the last: held there
])
def test_pose_between_capture_instants_is_the_geodesic_in_time(t, yaw, xyz):
    pose = truth_pose_at(TRUTH)("q", t)
    assert _yaw(pose) == pytest.approx(yaw, abs=1e-9)
    assert pose.t == pytest.approx(xyz, abs=1e-12)
    assert np.allclose(pose.R @ pose.R.T, np.eye(3), atol=1e-12)


def test_one_frame_cannot_be_interpolated():
    with pytest.raises(ValueError, match="two frames"):
        truth_pose_at({"frames": TRUTH["frames"][:1]})
