"""The core install (``pip install mutloc``) without any extra.

A fresh virtual environment per run is too slow for the suite, so the
optional packages are made unimportable instead: the subprocesses below run
with a ``sitecustomize.py`` on ``PYTHONPATH`` whose import hook refuses them
(and, to show the core commands do not touch it, pupil-apriltags too).
"""

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import mutloc
from mutloc._extras import PACKAGES
from mutloc.cli.main import NEEDS, build_parser
from mutloc.io import save_rig
from mutloc.io.logs import write_observation_log
from mutloc.io.trajectory import read_trajectory_csv
from mutloc.sim.render import default_path
from mutloc.sim.tracking import observation_sequence
from mutloc.sim.world import standard_rig

ROOT = Path(__file__).resolve().parents[1]
# The subprocesses run the mutloc under test (not whichever one is installed), so they also
# share its Numba cache: a copy elsewhere would be other code, and would compile every kernel again.
SOURCES = Path(mutloc.__file__).resolve().parents[1]
BLOCKED = sorted(PACKAGES)  # every optional package, and the core's pupil_apriltags

BLOCKER = f"""
import sys

BLOCKED = {BLOCKED!r}


class _Blocker:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}} (blocked by the test)", name=name)
        return None


sys.meta_path.insert(0, _Blocker())
"""


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A rig of two robots with balls, one frame's observations and a 1 s observation log; the true poses."""
    d = tmp_path_factory.mktemp("core")
    (d / "blocker").mkdir()
    (d / "blocker" / "sitecustomize.py").write_text(BLOCKER)
    rig = standard_rig("balls")
    save_rig(rig, d / "rig.yaml")
    seq = observation_sequence(rig, default_path(2.0, 12.0, 0.3), duration=1.0, fps=10.0, pixel_sigma=1.0,
                               seed=3, blind=(), drop=0.0, outliers=0.0)
    write_observation_log(d / "log.jsonl", seq.frames)
    (d / "obs.json").write_text(json.dumps(seq.frames[0].to_dict()))
    return d, seq.truth


def _run(d: Path, args: list[str]) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(d / "blocker"), str(SOURCES)])}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=300, cwd=d, env=env)


def test_the_blocker_blocks(scene):
    d, _ = scene
    code = ("import importlib\nfor m in " + repr(BLOCKED) + ":\n"
            "    try:\n        importlib.import_module(m)\n    except ImportError:\n        print(m)\n"
            "import mutloc\nprint(mutloc.__file__)\n")
    out = _run(d, ["-c", code])
    assert out.returncode == 0, out.stderr
    # every optional package refused, and the mutloc imported is the one under test
    assert out.stdout.splitlines() == [*BLOCKED, mutloc.__file__]


def test_localize_and_track_from_a_log_need_no_extra(scene):
    d, truth = scene
    out = _run(d, ["-m", "mutloc", "localize", "--rig", "rig.yaml", "--observations", "obs.json"])
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert (res["from"], res["to"]) == ("p", "q") and res["status"] == "solved"
    assert sum((a - b) ** 2 for a, b in zip(res["t"], truth[0].t)) ** 0.5 < 0.05

    out = _run(d, ["-m", "mutloc", "track", "--rig", "rig.yaml", "--observations", "log.jsonl", "--out", "trk",
                   "--no-progress"])
    assert out.returncode == 0, out.stderr
    rows = read_trajectory_csv(d / "trk" / "trajectory.csv")
    assert len(rows) == len(truth) == 10 and (d / "trk" / "trajectory.tum").exists()
    errs = [r["pose"].translation_error(T) for r, T in zip(rows, truth) if r["pose"] is not None]
    assert len(errs) == 10 and max(errs) < 0.1


@pytest.mark.parametrize("option, extra", [(["--bag", "bag"], "ros"), (["--mcap", "poses.mcap"], "ros"),
                                           (["--rerun", "track.rrd"], "viz"), (["--topic", "p=/image"], "ros")])
def test_track_options_of_an_extra_fail_in_one_line_before_the_work(scene, option, extra):
    d, _ = scene
    (d / "a_bag").mkdir(exist_ok=True)
    (d / "a_bag" / "metadata.yaml").touch()  # a rosbag2 folder, as far as the command line can tell
    source = ["--stream", "p=a_bag", "--stream", "q=a_bag", "--topic", "q=/image"] if option[0] == "--topic" \
        else ["--observations", "log.jsonl"]
    out = _run(d, ["-m", "mutloc", "track", "--rig", "rig.yaml", *source,
                   "--out", f"out_{extra}{option[0]}", "--no-progress", *option])
    err = out.stderr.strip()
    assert out.returncode == 2 and len(err.splitlines()) == 1, err
    assert option[0] in err and f'pip install "mutloc[{extra}]"' in err, err
    assert not (d / f"out_{extra}{option[0]}").exists() and not (d / option[1]).exists()


@pytest.mark.parametrize("argv, extra", [(["experiment", "noise", "--quick", "--out", "exp"], "experiments"),
                                         (["demo", "--out", "demo"], "viz"),
                                         (["localizer", "--rig", "rig.yaml", "--out", "live"], "live")])
def test_commands_of_an_extra_fail_in_one_line(scene, argv, extra):
    d, _ = scene
    out = _run(d, ["-m", "mutloc", *argv])
    err = out.stderr.strip()
    assert out.returncode == 2 and len(err.splitlines()) == 1, err
    assert f"mutloc {argv[0]} needs" in err and f'pip install "mutloc[{extra}]"' in err, err
    assert not (d / argv[-1]).exists()


def test_library_calls_raise_missing_extra_naming_it(scene):
    """Each library entry point of an optional package raises
    MissingExtraError (also an ImportError) naming the package and its extra."""
    d, _ = scene
    code = """
import mutloc
from mutloc.errors import MissingExtraError
calls = {
    "ros2bag": lambda: __import__("mutloc.io.ros", fromlist=["x"]).Ros2BagWriter("b", [("p", "q")]),
    "mcap": lambda: __import__("mutloc.io.ros", fromlist=["x"]).McapPoseWriter("m.mcap", [("p", "q")]),
    "bag_in": lambda: __import__("mutloc.track.sources", fromlist=["x"]).open_source("in_bag", topic="/image"),
    "rerun": lambda: __import__("mutloc.io.rrd", fromlist=["x"]).RerunWriter("r.rrd", "p", "q"),
    "video": lambda: __import__("mutloc.io.video", fromlist=["x"]).VideoWriter("v.mp4"),
    "sheet": lambda: __import__("mutloc.io.marker_sheet", fromlist=["x"]).write_marker_sheet(
        __import__("mutloc.sim.world", fromlist=["x"]).standard_rig("tags"), "sheet.pdf"),
    "sfm": lambda: __import__("mutloc.baselines.sfm", fromlist=["x"]).SfmScene({}, None),
    "apriltag": lambda: __import__("mutloc.detect.apriltag_lib", fromlist=["x"]).family_layout("tagStandard41h12"),
}
for name, call in calls.items():
    try:
        call()
        print(name, "no error")
    except MissingExtraError as exc:
        assert isinstance(exc, ImportError)
        print(name, exc)
"""
    out = _run(d, ["-c", code])
    assert out.returncode == 0, out.stderr
    lines = dict(line.split(" ", 1) for line in out.stdout.strip().splitlines())
    expect = {"ros2bag": ("rosbags", "ros"), "mcap": ("mcap", "ros"), "bag_in": ("rosbags", "ros"),
              "rerun": ("rerun-sdk", "viz"), "video": ("av", "viz"), "sheet": ("matplotlib", "viz"),
              "sfm": ("pycolmap", "experiments")}
    for name, (dist, extra) in expect.items():
        assert f'needs {dist}, part of the {extra} extra: pip install "mutloc[{extra}]"' in lines[name], lines
    assert "needs pupil-apriltags, a dependency of mutloc" in lines["apriltag"], lines
    assert not any(p.exists() for p in (d / "b", d / "m.mcap", d / "r.rrd", d / "v.mp4", d / "sheet.pdf"))


def test_pyproject_extras_match_the_package_table():
    """Every optional dependency is mapped to its extra (the one-line
    messages name it), every mapped package is where the table says, and
    [all] is every extra."""
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]

    def names(reqs):
        return {r.split(">")[0].split("=")[0].split("[")[0].strip().lower() for r in reqs}

    core = names(meta["dependencies"])
    opt = {k: names(v) for k, v in meta["optional-dependencies"].items()}
    tools = {"test", "bench", "docs", "all", "render"}  # render: bpy, a renderer for benchmarks, not in [all]
    for dist, extra in PACKAGES.values():
        assert dist in (core if extra is None else opt[extra]), dist
    mapped = {dist for dist, _ in PACKAGES.values()}
    for extra, dists in opt.items():
        if extra not in tools:
            assert dists <= mapped, (extra, dists - mapped)
    assert meta["optional-dependencies"]["all"] == [f"mutloc[{','.join(e for e in opt if e not in tools)}]"]
    assert not core & {dist for dist, extra in PACKAGES.values() if extra is not None}


def test_needs_names_real_commands_and_options():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for command, dest, modules, _extra in NEEDS:
        assert command in sub.choices, command
        if dest is not None:
            assert dest in {a.dest for a in sub.choices[command]._actions}, (command, dest)
        assert all(m in PACKAGES for m in modules), modules
