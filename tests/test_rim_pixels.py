"""A pixel a little past a fisheye lens's rim (where Kannala-Brandt stops being one-to-one) is set aside and
named in ``rejected``, not a refusal of the whole pair, team or tracked record; one far past stays an error.

Scenes are the simulator's bodies (mutloc.sim.bodies) with exact pixels; one fisheye observation is moved
just past the rim along its own azimuth.  The rim is computed here in closed form (theta_d at the lens's
largest one-to-one angle, the derivative's first root of theta (1 + k1 theta^2 + ... + k4 theta^8)), not
through the library's projection; the poses are checked against the simulator's truth.
"""

from __future__ import annotations

import numpy as np
import pytest

import mutloc
from mutloc.core.geometry import so3_log
from mutloc.core.observations import ObservationSet
from mutloc.sim.bodies import body_observations, random_pair, random_team
from mutloc.track.team import TeamTracker


def _theta_d_max(k) -> float:
    """theta_d at the first root in (0, pi] of its derivative (pi if none): the lens circle's radius / f."""
    # d/dtheta theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8) = 1 + 3 k1 t^2 + 5 k2 t^4 + 7 k3 t^6 + 9 k4 t^8
    roots = np.roots([9 * k[3], 0, 7 * k[2], 0, 5 * k[1], 0, 3 * k[0], 0, 1.0])
    real = sorted(r.real for r in roots if abs(r.imag) < 1e-12 and 0 < r.real <= np.pi)
    t = real[0] if real else np.pi
    return t * (1 + k[0] * t**2 + k[1] * t**4 + k[2] * t**6 + k[3] * t**8)


def _past_rim(rig, key: str, uv, past_px: float):
    """The pixel ``past_px`` pixels past camera ``key``'s rim, on the line from the principal point through ``uv``."""
    cam = rig.mount(key).camera
    K = np.asarray(cam.K, float)
    assert K[0, 0] == K[1, 1] and K[0, 1] == 0  # the simulator's lenses: the rim is a circle of f theta_d_max
    c = K[:2, 2]
    d = np.asarray(uv, float) - c
    return (c + d / np.linalg.norm(d) * (K[0, 0] * _theta_d_max(np.asarray(cam.dist, float)[:4]) + past_px)).tolist()


def _fisheye_rows(rig, obs):
    """Fisheye observations whose lens circle, 20 px past it along their azimuth, is still in the image."""
    def inside(k, uv):
        w, h = rig.mount(k).camera.size
        u, v = _past_rim(rig, k, uv, 20.0)
        return 0 <= u <= w - 1 and 0 <= v <= h - 1
    return [(k, m) for k, v in obs.items() for m in v
            if rig.mount(k).camera.model == "fisheye" and inside(k, v[m])]


def _pair_scene():
    rng = np.random.default_rng(7)
    while True:
        rig, poses, T = random_pair(rng)
        obs = body_observations(rig, poses)
        if sum(len(v) for v in obs.values()) >= 7 and _fisheye_rows(rig, obs):
            return rig, obs, T


def _team_scene():
    rng = np.random.default_rng(11)
    while True:
        rig, poses = random_team(rng, 3)
        obs = body_observations(rig, poses)
        if sum(len(v) for v in obs.values()) >= 30 and _fisheye_rows(rig, obs):
            return rig, obs, {r: poses["r0"].inverse() @ poses[r] for r in poses}


def _moved(rig, obs, past_px):
    key, m = _fisheye_rows(rig, obs)[0]
    out = {k: dict(v) for k, v in obs.items()}
    out[key][m] = _past_rim(rig, key, obs[key][m], past_px)
    return out, key, m


def _exact(pose, truth) -> bool:
    return bool(np.linalg.norm(so3_log(pose.R @ truth.R.T)) < 1e-7 and np.linalg.norm(pose.t - truth.t) < 1e-6)


def test_rim_is_where_the_lens_stops_imaging():
    rig, obs, _ = _pair_scene()
    key, m = _fisheye_rows(rig, obs)[0]
    cam = rig.mount(key).camera
    inside = np.asarray(_past_rim(rig, key, obs[key][m], -0.5))
    outside = np.asarray(_past_rim(rig, key, obs[key][m], 0.5))
    assert np.all(np.isfinite(cam.pixels_to_bearings(inside)))
    assert not np.all(np.isfinite(cam.pixels_to_bearings(outside)))
    assert mutloc.core.rays.past_rim_px(cam, _past_rim(rig, key, obs[key][m], 2.5)) == pytest.approx(2.5, abs=1e-3)


def test_pair_sets_aside_a_pixel_just_past_the_rim():
    rig, obs, T = _pair_scene()
    moved, key, m = _moved(rig, obs, 2.0)
    est = mutloc.localize(rig, moved, "p", "q")
    assert est.rejected[0] == {"observer": key, "marker": m, "residual_px": None, "at": "lens",
                               "past_rim_px": pytest.approx(2.0, abs=1e-3)}
    assert len(est.markers_used) == sum(len(v) for v in obs.values()) - 1  # the others all used
    assert est.to_dict()["rejected"][0]["at"] == "lens"
    assert _exact(est.pose, T)  # the rest are exact: so is the pose
    # 4 sigma of a noisier detector: 6 px past is set aside at 2 px noise, refused at 1 px
    assert mutloc.localize(rig, _moved(rig, obs, 6.0)[0], "p", "q", pixel_sigma=2.0).rejected[0]["at"] == "lens"
    with pytest.raises(mutloc.errors.ObservationError, match="outside what the fisheye lens images"):
        mutloc.localize(rig, _moved(rig, obs, 6.0)[0], "p", "q")


def test_far_past_the_rim_is_still_refused():
    rig, obs, _ = _pair_scene()
    moved, key, m = _moved(rig, obs, 20.0)
    with pytest.raises(mutloc.errors.ObservationError, match=f"observations\\['{key}'\\]\\['{m}'\\].*outside what"):
        mutloc.localize(rig, moved, "p", "q")
    rig, obs, _ = _team_scene()
    with pytest.raises(mutloc.errors.ObservationError, match="outside what the fisheye lens images"):
        mutloc.localize_team(rig, _moved(rig, obs, 20.0)[0], "r0")


def test_team_sets_aside_a_pixel_just_past_the_rim():
    rig, obs, truth = _team_scene()
    moved, key, m = _moved(rig, obs, 3.0)
    team = mutloc.localize_team(rig, moved, "r0")
    assert team.rejected == [{"observer": key, "marker": m, "residual_px": None, "at": "lens",
                              "past_rim_px": pytest.approx(3.0, abs=1e-3)}]
    assert team.observations_used == sum(len(v) for v in obs.values()) - 1
    assert set(team.robots) == {"r1", "r2"}
    for r in team.robots:
        assert _exact(team.poses[r], truth[r])


def test_team_tracker_sets_aside_a_pixel_just_past_the_rim():
    rig, obs, truth = _team_scene()
    moved, key, m = _moved(rig, obs, 3.0)
    tracker = TeamTracker(rig, "r0")
    for k in range(3):
        rows = tracker.step(0.1 * k, ObservationSet.from_dict(moved, time=0.1 * k))
    for r, row in rows.items():
        assert row.status.value in ("solved", "unverified"), (r, row.status, row.reason)
        assert np.linalg.norm(row.estimate.pose.t - truth[r].t) < 1e-4
    robot, owner = rig.observer(key)[0], rig.owner(m)
    for r in {robot, owner} - {"r0"}:
        assert "past the lens's rim" in rows[r].reason and m in rows[r].reason
