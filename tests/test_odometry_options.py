"""The command line's odometry options (cli/_common.py ODOMETRY, odometry_options):
each robot's odometry loaded from its source, one line for what cannot be."""

import argparse

import numpy as np
import pytest

from mutloc.cli._common import ODOMETRY, odometry_options, robot_value
from mutloc.core.odometry import OdometryNoise
from mutloc.errors import OdometryError
from mutloc.io.trajectory import write_tum
from mutloc.sim.world import standard_rig

from test_odometry_io import _truth, write_odometry_bag


def _args(*argv):
    p = argparse.ArgumentParser(parents=[ODOMETRY])
    p.add_argument("--stream", action="append", type=robot_value, default=[])
    p.add_argument("--topic", action="append", type=robot_value, default=[])
    return p.parse_args(list(argv))


@pytest.fixture
def files(tmp_path):
    times, poses = _truth()
    write_tum(tmp_path / "p.tum", times, poses)
    write_odometry_bag(tmp_path / "q2", 2, "/q/odom", times, poses, child="q")
    return tmp_path, times, poses


def test_each_robots_odometry_from_a_tum_file_and_its_bag(files):
    d, times, poses = files
    rig = standard_rig("balls")
    got = odometry_options(_args("--odometry", f"p={d / 'p.tum'}", "--odometry", "q=bag:/q/odom",
                                 "--stream", f"q={d / 'q2'}", "--topic", "q=/q/image",
                                 "--odometry-noise", "distance=0.05,floor-deg=0.2"), rig)
    assert set(got) == {"p", "q"}
    for odo in got.values():
        np.testing.assert_allclose(odo.times, times, atol=1e-9)
        assert odo.noise == OdometryNoise(distance=0.05, floor_deg=0.2)
    want = poses[2].inverse() @ poses[9]
    assert got["q"].increment(times[2], times[9]).pose.translation_error(want) < 1e-9
    assert odometry_options(_args(), rig) == {}


def test_live_takes_ros_topics_and_refuses_bags(files):
    rig = standard_rig("balls")
    assert odometry_options(_args("--odometry", "p=ros:/p/odom"), rig, live=True) == {"p": "/p/odom"}
    with pytest.raises(OdometryError, match=r"^--odometry p=ros:/p/odom: a live topic \(ros:/TOPIC\) is for the "):
        odometry_options(_args("--odometry", "p=ros:/p/odom"), rig)
    with pytest.raises(OdometryError, match="live, there is no bag"):
        odometry_options(_args("--odometry", "p=bag:/p/odom"), rig, live=True)


@pytest.mark.parametrize("argv, message", [
    (["--odometry", "z=p.tum"], r"^--odometry z=p\.tum: no robot 'z' in the rig \(robots: p, q\)$"),
    (["--odometry", "p=missing.tum"], r"^--odometry p: \S*missing\.tum: cannot read"),
    (["--odometry", "q=bag:/q/odom"], (r"^--odometry q: odometry of 'q': 'bag:/q/odom' names a topic of the "
                                       r"robot's bag, and 'q' has none")),
    (["--odometry", "p=p.tum", "--odometry", "p=p.tum"], r"--odometry given twice for robot 'p'"),
    (["--odometry", "p=p.tum", "--odometry-noise", "speed=1"], r"^--odometry-noise 'speed=1': expected KEY=VALUE"),
    (["--odometry", "p=p.tum", "--odometry-noise", "turn=x"], r"^--odometry-noise turn=x: not a number$"),
    (["--odometry", "p=p.tum", "--odometry-noise", "turn=-1"], r"noise turn must be a finite number >= 0"),
])
def test_refusals_in_one_line(files, monkeypatch, argv, message):
    d, _, _ = files
    monkeypatch.chdir(d)
    with pytest.raises(ValueError, match=message) as exc:
        odometry_options(_args(*argv), standard_rig("balls"))
    assert "\n" not in str(exc.value)
