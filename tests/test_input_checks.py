"""Inputs that look wrong get one clear line that says what and where
(issue: never a silent wrong pose)."""

import pytest

import mutloc
from mutloc.cli.main import main
from mutloc.errors import FileFormatError, ObservationError, RigError

CAM = {"K": [[800, 0, 479.5], [0, 800, 269.5], [0, 0, 1]], "dist": [-0.3, 0.1, 0, 0, 0], "size": [960, 540]}


def _rig(markers_p=None, markers_q=None):
    return {"robots": {
        "p": {"camera": CAM, "markers": markers_p or {"M3": {"position": [-0.15, -0.05, -0.03]},
                                                      "M4": {"position": [0.15, -0.05, -0.03]}}},
        "q": {"camera": CAM, "markers": markers_q or {"M1": {"position": [-0.15, -0.05, -0.03]},
                                                      "M2": {"position": [0.15, -0.05, -0.03]}}}}}


@pytest.mark.parametrize("key,near", [("colour", "color"), ("postion", "position"), ("blink", "blink_hz")])
def test_misspelt_marker_key_names_the_key_and_the_nearest(key, near):
    m = {"position": [0.1, 0, 0], key: [255, 0, 0] if key != "postion" else [0, 0, 0]}
    if key == "postion":
        m = {"postion": [0.1, 0, 0]}
    with pytest.raises(RigError) as info:
        mutloc.load_rig(_rig(markers_p={"M3": m}))
    msg = str(info.value)
    assert f"unknown key {key!r}" in msg and repr(near) in msg and "'M3'" in msg


def test_misspelt_robot_and_tag_keys():
    rig = _rig()
    rig["robots"]["p"]["camra"] = CAM
    with pytest.raises(RigError, match="'camra'.*'camera'"):
        mutloc.load_rig(rig)
    tag = {"position": [0, 0.1, 0], "tag": {"family": "tag36h11", "id": 1, "sise": 0.1}}
    with pytest.raises(RigError, match="'sise'.*'size'"):
        mutloc.load_rig(_rig(markers_p={"T": tag}))


def test_user_keys_with_prefix_are_kept():
    rig = mutloc.load_rig(_rig(markers_p={"M3": {"position": [0.1, 0, 0], "x_serial": "A17"},
                                          "M4": {"position": [-0.1, 0, 0]}}))
    assert rig.marker("M3").extra["x_serial"] == "A17"


def test_millimetre_positions_and_tag_sizes_are_refused():
    with pytest.raises(RigError) as info:
        mutloc.load_rig(_rig(markers_q={"M1": {"position": [-150, -50, -30]}, "M2": {"position": [150, -50, -30]}}))
    assert "'M1'" in str(info.value) and "millimetres" in str(info.value)
    tag = {"position": [0, 0.1, 0], "tag": {"family": "tag36h11", "id": 1, "size": 100}}
    with pytest.raises(RigError) as info:
        mutloc.load_rig(_rig(markers_p={"T": tag}))
    assert "'T'" in str(info.value) and "millimetres" in str(info.value)


def test_endless_or_huge_input_file_is_refused_quickly(tmp_path):
    with pytest.raises(FileFormatError, match="larger than"):
        mutloc.load_observations("/dev/zero")
    with pytest.raises(FileFormatError, match="folder"):
        mutloc.load_observations(tmp_path)


def test_pixel_far_outside_the_image_says_so():
    obs = {"p": {"M1": [5000.0, 200.0], "M2": [500.0, 260.0]}, "q": {"M3": [400.0, 250.0], "M4": [470.0, 254.0]}}
    with pytest.raises(ObservationError) as info:
        mutloc.localize(_rig(), obs)
    assert "outside the 960x540 image" in str(info.value) and "'M1'" in str(info.value)


def test_one_robot_rig_message_names_no_api_words(tmp_path, capsys):
    rig = {"robots": {"p": _rig()["robots"]["p"]}}
    with pytest.raises(ObservationError) as info:
        mutloc.localize(rig, {"p": {}})
    assert "source=" not in str(info.value) and "needs two" in str(info.value)
    f = tmp_path / "rig.json"
    f.write_text(__import__("json").dumps(rig))
    o = tmp_path / "o.json"
    o.write_text('{"p": {}}')
    assert main(["localize", "--rig", str(f), "--observations", str(o)]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "needs two" in err and "source=" not in err


def test_tag_centre_and_corners_count_once():
    """An oriented tag gives its four corners as observations, not its centre
    as a fifth (the centre is computed from the corners)."""
    from mutloc.sim.render import render, two_robot_world
    from mutloc.sim.synthetic import facing_pose
    from mutloc.sim.world import standard_rig

    rig = standard_rig("tags")
    world = two_robot_world(rig, facing_pose(1.5), seed=3)
    images = {r: render(world, r, 0.0, seed=3) for r in ("p", "q")}
    res = mutloc.localize_images(rig, images)
    used = res.estimate.markers_used
    tags = [n for r in ("p", "q") for n in rig.robot(r).markers]
    assert not set(used) & set(tags), used
    assert {n.split("#")[0] for n in used} == set(tags)
    assert len(used) == 4 * len(tags)


def test_track_output_paths_are_checked_before_the_work(tmp_path, capsys):
    """``--out`` that is a file (or lies under one) and ``--annotate`` on a
    log (no images to draw on) are refused in one line, before tracking."""
    from mutloc.io import save_rig
    from mutloc.sim.world import standard_rig

    save_rig(standard_rig("balls"), tmp_path / "rig.yaml")
    log = tmp_path / "log.jsonl"
    log.write_text('{"time": 0.0, "observations": {}}\n')
    base = ["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(log), "--no-progress"]
    for out, words in ((tmp_path / "rig.yaml", "is not a folder"),
                       (tmp_path / "rig.yaml" / "sub", "is not a folder")):
        assert main(base + ["--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1, err
    assert main(base + ["--out", str(tmp_path / "o"), "--annotate", str(tmp_path / "o" / "a")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--annotate" in err and "--stream" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()
    assert main(base + ["--out", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / "trajectory.csv").exists()


def _seen(rig, distance=2.0):
    """Exact pixels of each robot's view of the other's markers, p facing q."""
    from mutloc.sim.synthetic import facing_pose

    T = facing_pose(distance)  # x_q = T x_p
    out = {}
    for robot, other, pose in (("p", "q", T.inverse()), ("q", "p", T)):
        cam = rig.robot(robot).camera
        out[robot] = {n: cam.project((pose.R @ m.position + pose.t)[None])[0].tolist()
                      for n, m in rig.robot(other).markers.items()}
    return out


@pytest.mark.parametrize("sized", [True, False])
def test_normalised_coordinates_or_image_fractions_are_not_pixels(sized, tmp_path, capsys):
    """Observations in normalised coordinates or image fractions are a unit
    mistake (as millimetres in a rig): refused in one line, not a pose
    kilometres away; real pixels of a camera of unknown image size still work."""
    import json

    import numpy as np

    spec = _rig()
    if not sized:
        for robot in spec["robots"].values():
            robot["camera"] = {k: v for k, v in CAM.items() if k != "size"}
    rig = mutloc.load_rig(spec)
    pixels = _seen(rig)
    est = mutloc.localize(rig, pixels)
    assert est.status == "solved" and abs(np.linalg.norm(est.t) - 2.0) < 1e-6
    K = np.array(CAM["K"], float)
    mistakes = {"fractions": lambda uv: (np.array(uv) / np.array(CAM["size"])).tolist(),
                "normalised": lambda uv: ((np.array(uv) - K[:2, 2]) / K[0, 0]).tolist()}
    for name, f in mistakes.items():
        wrong = {r: {n: f(uv) for n, uv in d.items()} for r, d in pixels.items()}
        with pytest.raises(ObservationError, match="not pixels") as info:
            mutloc.localize(rig, wrong)
        assert "'p'" in str(info.value), name
    (tmp_path / "rig.json").write_text(json.dumps(spec))
    (tmp_path / "obs.json").write_text(json.dumps(wrong))
    code = main(["localize", "--rig", str(tmp_path / "rig.json"), "--observations", str(tmp_path / "obs.json")])
    err = capsys.readouterr().err.strip()
    assert code != 0 and "not pixels" in err and len(err.splitlines()) == 1, err


def test_a_camera_in_normalised_units_takes_normalised_observations():
    """A camera whose principal point is at (0, 0) (K for normalised
    coordinates) is consistent with observations near zero: not refused."""
    import numpy as np

    spec = _rig()
    for robot in spec["robots"].values():
        robot["camera"] = {"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
    rig = mutloc.load_rig(spec)
    est = mutloc.localize(rig, _seen(rig))
    assert abs(np.linalg.norm(est.t) - 2.0) < 1e-6


def test_unknown_marker_suggests_the_nearest_name(tmp_path, capsys):
    import json

    obs = {"p": {"m1": [500.0, 250.0], "M2": [400.0, 250.0]}, "q": {"M3": [500.0, 250.0], "M4": [400.0, 250.0]}}
    with pytest.raises(ObservationError, match="unknown marker 'm1': did you mean 'M1'\\?"):
        mutloc.localize(_rig(), obs)
    obs["p"] = {"Z9": [500.0, 250.0], "M2": [400.0, 250.0]}
    with pytest.raises(ObservationError, match="unknown marker 'Z9' \\(the rig's markers: M1, M2, M3, M4\\)"):
        mutloc.localize(_rig(), obs)
    (tmp_path / "rig.json").write_text(json.dumps(_rig()))
    (tmp_path / "obs.json").write_text(json.dumps({**obs, "p": {"M11": [500.0, 250.0], "M2": [400.0, 250.0]}}))
    assert main(["localize", "--rig", str(tmp_path / "rig.json"), "--observations", str(tmp_path / "obs.json")]) != 0
    err = capsys.readouterr().err.strip()
    assert "did you mean 'M1'?" in err and len(err.splitlines()) == 1, err


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self"), reason="needs Linux's /proc (nothing can be "
                    "created there, even by root)")
def test_every_track_output_is_checked_before_the_work(tmp_path, capsys):
    """--out, --bag, --mcap, --rerun, --observations-out where nothing can be
    written, --bag/--mcap that exist, a file where a folder is wanted and
    one path for two outputs: one line each, exit 2, before anything is
    written (the trajectory of a run that then fails is not left behind)."""
    from mutloc.io import save_rig
    from mutloc.sim.world import standard_rig

    save_rig(standard_rig("balls"), tmp_path / "rig.yaml")
    log = tmp_path / "log.jsonl"
    log.write_text('{"time": 0.0, "observations": {}}\n')
    out = tmp_path / "o"
    base = ["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(log), "--no-progress"]
    cases = [(["--out", "/proc/mutloc-o"], "cannot be written (--out)")]
    for option, name in (("--rerun", "x.rrd"), ("--mcap", "x.mcap"), ("--observations-out", "x.jsonl"),
                         ("--bag", "bag")):
        cases.append(([option, f"/proc/mutloc-{name}"], f"cannot be written ({option})"))
    cases += [(["--mcap", str(log)], "already exists (--mcap)"), (["--bag", str(tmp_path)], "already exists (--bag)"),
              (["--rerun", str(tmp_path)], "is a folder, not a file (--rerun)"),
              (["--rerun", str(tmp_path / "a"), "--mcap", str(tmp_path / "a")], "--mcap and --rerun name the same")]
    for extra, words in cases:
        args = base + (extra if extra[0] == "--out" else ["--out", str(out)] + extra)
        assert main(args) == 2, extra
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1, err
        assert not out.exists(), extra


def test_localize_images_refuses_one_image_twice_swapped_images_and_lights(tmp_path, capsys):
    """As ``track`` refuses such streams (the same check): one camera's image
    given for both robots, or the two images swapped, would find a robot's
    own markers in its own view; lights need a sequence."""
    import cv2
    import numpy as np

    from mutloc.errors import InputError
    from mutloc.io import save_rig
    from mutloc.sim.render import render, two_robot_world
    from mutloc.sim.synthetic import facing_pose
    from mutloc.sim.world import standard_rig

    rig = standard_rig("balls")
    world = two_robot_world(rig, facing_pose(2.0), seed=1)
    img = {r: render(world, r, 0.0, seed=1) for r in ("p", "q")}
    assert mutloc.localize_images(rig, img, allow_unverified=True).estimate.status == "solved"
    with pytest.raises(InputError, match="same images"):
        mutloc.localize_images(rig, {"p": img["p"], "q": img["p"]}, allow_unverified=True)
    with pytest.raises(InputError, match="look swapped"):
        mutloc.localize_images(rig, {"p": img["q"], "q": img["p"]}, allow_unverified=True)
    save_rig(rig, tmp_path / "rig.yaml")
    cv2.imwrite(str(tmp_path / "p.png"), img["p"])
    assert main(["localize-images", "--rig", str(tmp_path / "rig.yaml"), "--image", f"p={tmp_path / 'p.png'}",
                 "--image", f"q={tmp_path / 'p.png'}", "--allow-unverified"]) == 2
    err = capsys.readouterr().err.strip()
    assert "same images" in err and "--image" in err and len(err.splitlines()) == 1, err
    lights = standard_rig("lights")
    blank = np.zeros((540, 960, 3), np.uint8)
    with pytest.raises(InputError, match="blinking lights.*sequence.*mutloc track"):
        mutloc.localize_images(lights, {"p": blank, "q": blank})


@pytest.mark.parametrize("outside", [100.0, 239.0])
def test_a_pixel_just_outside_the_image_is_named_as_the_suspect(outside):
    """Each marker in turn moved ``outside`` px past the left border (within
    the half-image margin the range check allows): the consistency error names
    that marker and its pixel -- not whichever marker the fit spread the error
    onto."""
    import numpy as np

    from mutloc.errors import InconsistentObservationsError
    from mutloc.sim.render import project_markers, relative_pose, two_robot_world
    from mutloc.sim.synthetic import facing_pose
    from mutloc.sim.world import standard_rig

    rig = standard_rig()
    world = two_robot_world(rig, facing_pose(2.0, 0.05, -0.03, 0.1), seed=1)
    exact = {r: {m: list(uv) for m, uv in project_markers(world, r).items()} for r in ("p", "q")}
    est = mutloc.localize(rig, exact)  # the true pixels give the true pose
    assert np.linalg.norm(est.t - relative_pose(world, "p", "q").t) < 1e-3
    for robot in ("p", "q"):
        for marker in exact[robot]:
            obs = {r: dict(v) for r, v in exact.items()}
            u = -0.5 - outside
            obs[robot][marker] = [u, exact[robot][marker][1]]
            with pytest.raises(InconsistentObservationsError) as info:
                mutloc.localize(rig, obs)
            msg = str(info.value)
            assert msg.startswith(f"observations[{robot!r}][{marker!r}]: pixel ({u:.2f}, "), msg
            assert f"{outside:.1f} px outside the 960x540 image" in msg, msg
