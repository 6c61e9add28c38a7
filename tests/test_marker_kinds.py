"""Marker kinds are decided in one place and each kind goes to its own detector."""

import numpy as np
import pytest

from mutloc.core.rig import DETECTED_KINDS, Marker, MarkerKind, Rig, Robot
from mutloc.sim.render import relative_pose, render, two_robot_world
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import WorldRobot, light_is_on, standard_rig
from mutloc.track.frames import detect_markers


def test_kind_precedence():
    pos = np.zeros(3)
    assert Marker("a", "p", pos, color=(255, 0, 0)).kind == MarkerKind.BALL
    # A light carries a colour too, but is found by its blink, never by colour.
    assert Marker("a", "p", pos, color=(255, 0, 0), blink_hz=5.0).kind == MarkerKind.LIGHT
    assert Marker("a", "p", pos, tag={"family": "tag36h11", "id": 1, "size": 0.1}).kind == MarkerKind.TAG
    assert Marker("a", "p", pos, extra={"cylinder": {"radius": 0.03}}).kind == MarkerKind.CYLINDER
    assert Marker("a#0", "p", pos, extra={"tag_of": "a"}).kind == MarkerKind.TAG_CORNER
    assert Marker("a#b0", "p", pos, extra={"cylinder_of": "a"}).kind == MarkerKind.CYLINDER_BAND
    assert Marker("a", "p", pos).kind == MarkerKind.POINT
    assert MarkerKind.TAG_CORNER not in DETECTED_KINDS and MarkerKind.LIGHT in DETECTED_KINDS


@pytest.mark.parametrize("seed", [0, 1])
def test_light_is_never_found_by_the_ball_detector(seed):
    """q's lights are off; beside q stands a ball of exactly the light's colour.
    From one image a light cannot be identified: it must be missing, not the ball."""
    rig = standard_rig("lights")
    T_qp = facing_pose(1.6, yaw_p=np.radians(5.0 * (seed - 0.5)))
    world = two_robot_world(rig, T_qp, seed=seed)
    lights = rig.robot("q").markers
    t_off = next(t for t in np.arange(0, 2, 1 / 60) if not any(light_is_on(m, t) for m in lights.values()))
    # A prop robot with a ball of each light's colour, 25 cm beside q's lights.
    T_wq = world.robots["q"].pose_at(t_off)
    props = {f"X{i}": Marker(f"X{i}", "r", m.position + np.array([0.0, -0.25, 0.0]), color=m.color,
                             extra={"radius": 0.03}) for i, m in enumerate(lights.values())}
    cam = rig.robot("q").camera
    world.robots["r"] = WorldRobot(Robot("r", cam, props), T_wq, body=False)
    image = render(world, "p", t_off, seed=seed)
    # The same-hue balls are in view: as balls they are found ...
    prop_rig = Rig({"p": rig.robot("p"), "r": Robot("r", cam, props)})
    found_props = detect_markers(prop_rig, "p", image, targets=["r"])
    assert set(found_props.detections) == set(props), found_props.missing
    # ... but q's lights, which carry the same colours, are not taken for them.
    res = detect_markers(rig, "p", image, targets=["q"])
    assert not res.detections, {n: d.uv for n, d in res.detections.items()}
    assert set(res.missing) == set(lights)
    assert relative_pose(world, "p", "q", t_off).translation_error(T_qp) < 1e-9
