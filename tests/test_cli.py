"""Tests of the ``mutloc`` command line (in-process via ``main([...])``, plus ``python -m mutloc``).

The success-path tests build a synthetic two-robot scene with known ground truth
and project it with plain pinhole maths (no mutloc code), so they check
``mutloc localize`` end to end against the truth.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from mutloc.cli.main import main

K = np.array([[800.0, 0.0, 479.5], [0.0, 800.0, 269.5], [0.0, 0.0, 1.0]])
P_MARKERS = {"M3": [-0.15, -0.05, -0.03], "M4": [0.15, -0.05, -0.03]}  # on p, in p's camera frame
Q_MARKERS = {"M1": [-0.15, -0.05, -0.03], "M2": [0.15, -0.05, -0.03]}  # on q, in q's camera frame


def rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


# Ground truth T_qp: x_q = R x_p + t.  q is about 2 m in front of p, facing it.
R_TRUE = rot("y", 180.0 + 6.0) @ rot("x", 4.0) @ rot("z", -3.0)
T_TRUE = np.array([0.12, -0.07, 2.05])


def project(X: np.ndarray, dist=None) -> list[float]:
    """Pixel of camera-frame point X: pinhole K plus OpenCV's distortion model."""
    assert X[2] > 0
    x, y = X[0] / X[2], X[1] / X[2]
    if dist is not None:
        k1, k2, p1, p2, k3 = (list(dist) + [0.0] * 5)[:5]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        x, y = (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)
    u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
    v = K[1, 1] * y + K[1, 2]
    return [float(u), float(v)]


def scene_observations(dist_p=None, dist_q=None) -> dict:
    """p sees q's markers, q sees p's markers; raw (distorted) pixels."""
    obs_p = {m: project(R_TRUE.T @ (np.array(X) - T_TRUE), dist_p) for m, X in Q_MARKERS.items()}
    obs_q = {m: project(R_TRUE @ np.array(X) + T_TRUE, dist_q) for m, X in P_MARKERS.items()}
    for pix in list(obs_p.values()) + list(obs_q.values()):  # all inside a 960x540 image
        assert 0 <= pix[0] <= 959 and 0 <= pix[1] <= 539
    return {"p": obs_p, "q": obs_q}


def scene_rig() -> dict:
    return {
        "robots": {
            "p": {"camera": {"K": K.tolist(), "size": [960, 540]},
                  "markers": {m: {"position": X} for m, X in P_MARKERS.items()}},
            "q": {"camera": {"K": K.tolist(), "dist": [0, 0, 0, 0, 0], "size": [960, 540]},
                  "markers": {m: {"position": X, "color": [0, 0, 255]} for m, X in Q_MARKERS.items()}},
        }
    }


def write_scene(tmp_path: Path, rig=None, obs=None, rig_name="rig.yaml", obs_name="obs.json") -> tuple[str, str]:
    rig = scene_rig() if rig is None else rig
    obs = scene_observations() if obs is None else obs
    rig_path, obs_path = tmp_path / rig_name, tmp_path / obs_name
    rig_path.write_text(json.dumps(rig) if rig_name.endswith(".json") else yaml.safe_dump(rig))
    obs_path.write_text(json.dumps(obs) if obs_name.endswith(".json") else yaml.safe_dump(obs))
    return str(rig_path), str(obs_path)


def quat_to_matrix(q) -> np.ndarray:
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def run_ok(argv, capsys) -> dict:
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert err == ""
    return json.loads(out)


def run_error(argv, capsys) -> str:
    """Run a failing command: exit status 2, exactly one stderr line, no stdout."""
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == 2, (rc, out, err)
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("mutloc: error: "), err
    assert "Traceback" not in err
    return lines[0]


def check_result(res: dict, R_exp: np.ndarray, t_exp: np.ndarray, frm: str, to: str, sigma: float = 1.0) -> None:
    assert res["from"] == frm and res["to"] == to
    R = np.array(res["R"])
    t = np.array(res["t"])
    assert R.shape == (3, 3) and t.shape == (3,)
    np.testing.assert_allclose(R, R_exp, atol=1e-6)
    np.testing.assert_allclose(t, t_exp, atol=1e-6)
    np.testing.assert_allclose(quat_to_matrix(res["quaternion_xyzw"]), R_exp, atol=1e-6)
    assert len(res["quaternion_xyzw"]) == 4
    assert abs(np.linalg.norm(res["quaternion_xyzw"]) - 1) < 1e-9
    assert 0 <= res["reprojection_rms_px"] < 1e-5
    cov = np.array(res["covariance"])
    assert cov.shape == (6, 6)
    np.testing.assert_allclose(cov, cov.T, atol=1e-12 + 1e-9 * np.abs(cov).max())
    assert np.all(np.linalg.eigvalsh(0.5 * (cov + cov.T)) > -1e-12)
    assert res["pixel_sigma"] == sigma
    assert sorted(res["markers_used"]) == ["M1", "M2", "M3", "M4"]


# ---------------------------------------------------------------------------
# success paths (need mutloc.localize)
# ---------------------------------------------------------------------------


def test_localize_prints_truth(tmp_path, capsys):
    rig, obs = write_scene(tmp_path)
    res = run_ok(["localize", "--rig", rig, "--observations", obs], capsys)
    check_result(res, R_TRUE, T_TRUE, "p", "q")
    assert set(res) >= {"from", "to", "R", "t", "quaternion_xyzw", "reprojection_rms_px", "covariance",
                        "pixel_sigma", "markers_used"}


def test_localize_explicit_source_target_and_inverse(tmp_path, capsys):
    rig, obs = write_scene(tmp_path, rig_name="rig.json", obs_name="obs.yaml")
    res = run_ok(["localize", "--rig", rig, "--observations", obs, "--source", "p", "--target", "q"], capsys)
    check_result(res, R_TRUE, T_TRUE, "p", "q")
    res = run_ok(["localize", "--rig", rig, "--observations", obs, "--source", "q", "--target", "p"], capsys)
    check_result(res, R_TRUE.T, -R_TRUE.T @ T_TRUE, "q", "p")


def test_localize_pixel_sigma_scales_covariance(tmp_path, capsys):
    rig, obs = write_scene(tmp_path)
    res1 = run_ok(["localize", "--rig", rig, "--observations", obs], capsys)
    res2 = run_ok(["localize", "--rig", rig, "--observations", obs, "--pixel-sigma", "0.5"], capsys)
    check_result(res2, R_TRUE, T_TRUE, "p", "q", sigma=0.5)
    np.testing.assert_allclose(np.array(res2["covariance"]), 0.25 * np.array(res1["covariance"]),
                               rtol=1e-6, atol=1e-15)


def test_localize_output_file(tmp_path, capsys):
    rig, obs = write_scene(tmp_path)
    out = tmp_path / "results" / "pose.json"
    rc = main(["localize", "--rig", rig, "--observations", obs, "--output", str(out)])
    captured = capsys.readouterr()
    assert rc == 0 and captured.out == "" and captured.err == ""
    check_result(json.loads(out.read_text()), R_TRUE, T_TRUE, "p", "q")


def test_localize_with_calibration_files_and_distortion(tmp_path, capsys):
    """p's camera from an OpenCV FileStorage file, q's from a ROS camera_info YAML
    (relative to the rig file's folder), both with lens distortion."""
    dist_p = [-0.12, 0.03, 0.0008, -0.0004, 0.002]
    dist_q = [0.08, -0.02, -0.0006, 0.0005, 0.0]
    calib = tmp_path / "rigdir" / "calib"
    calib.mkdir(parents=True)
    fs = cv2.FileStorage(str(calib / "p_cam.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array([dist_p]))
    fs.write("image_width", 960)
    fs.write("image_height", 540)
    fs.release()
    (calib / "q_cam.yaml").write_text(yaml.safe_dump({
        "image_width": 960, "image_height": 540, "camera_name": "q",
        "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": dist_q},
    }))
    rig = scene_rig()
    rig["robots"]["p"]["camera"] = "calib/p_cam.yml"
    rig["robots"]["q"]["camera"] = "calib/q_cam.yaml"
    rig_path, obs_path = write_scene(tmp_path / "rigdir", rig=rig, obs=scene_observations(dist_p, dist_q))
    res = run_ok(["localize", "--rig", rig_path, "--observations", obs_path], capsys)
    check_result(res, R_TRUE, T_TRUE, "p", "q")


def test_localize_three_robot_rig(tmp_path, capsys):
    rig = scene_rig()
    rig["robots"]["r"] = {"camera": {"K": K.tolist()}, "markers": {"R1": {"position": [0, 0.1, 0]}}}
    rig_path, obs_path = write_scene(tmp_path, rig=rig)
    res = run_ok(["localize", "--rig", rig_path, "--observations", obs_path, "--source", "p", "--target", "q"],
                 capsys)
    check_result(res, R_TRUE, T_TRUE, "p", "q")
    # no pair named: the team (SPEC "Teams"), r seen by nobody is unlocalized
    res = run_ok(["localize", "--rig", rig_path, "--observations", obs_path, "--reference", "q"], capsys)
    assert res["reference"] == "q" and set(res["robots"]) == {"p"} and res["unlocalized"] == ["r"]
    np.testing.assert_allclose(res["robots"]["p"]["t"], T_TRUE, atol=1e-6)


# ---------------------------------------------------------------------------
# semantic errors found by mutloc.localize: still one line, exit 2
# ---------------------------------------------------------------------------


def test_localize_unknown_marker(tmp_path, capsys):
    obs = scene_observations()
    obs["p"]["M9"] = [500.0, 300.0]
    rig, obs_path = write_scene(tmp_path, obs=obs)
    assert "M9" in run_error(["localize", "--rig", rig, "--observations", obs_path], capsys)


def test_localize_too_few_observations(tmp_path, capsys):
    obs = scene_observations()
    del obs["p"]["M1"]
    del obs["q"]["M3"]
    rig, obs_path = write_scene(tmp_path, obs=obs)
    run_error(["localize", "--rig", rig, "--observations", obs_path], capsys)


def test_localize_unknown_robot(tmp_path, capsys):
    rig, obs = write_scene(tmp_path)
    line = run_error(["localize", "--rig", rig, "--observations", obs, "--source", "x", "--target", "q"], capsys)
    assert "'x'" in line


def test_localize_unwritable_output(tmp_path, capsys):
    rig, obs = write_scene(tmp_path)
    run_error(["localize", "--rig", rig, "--observations", obs, "--output", str(tmp_path)], capsys)


# ---------------------------------------------------------------------------
# bad input files: one line on stderr, exit status 2 (no solver involved)
# ---------------------------------------------------------------------------

GOOD_CAM = {"K": K.tolist()}


def _rig_with(p_markers=None, q_markers=None, p_camera=None) -> dict:
    rig = scene_rig()
    if p_markers is not None:
        rig["robots"]["p"]["markers"] = p_markers
    if q_markers is not None:
        rig["robots"]["q"]["markers"] = q_markers
    if p_camera is not None:
        rig["robots"]["p"]["camera"] = p_camera
    return rig


BAD_RIG_TEXTS = [
    ("yaml syntax", "robots:\n  p: {camera: [1, 2\n", ["rig.yaml", "line"]),
    ("no robots", "robot: {}\n", ["rig.yaml", "robots"]),
    ("missing camera", yaml.safe_dump({"robots": {"p": {"markers": {}}}}), ["'p'", "camera"]),
    ("missing markers", yaml.safe_dump({"robots": {"p": {"camera": GOOD_CAM}}}), ["'p'", "markers"]),
    ("missing position", yaml.safe_dump(_rig_with(p_markers={"M3": {"color": [1, 2, 3]}})), ["'M3'", "position"]),
    ("position wrong length", yaml.safe_dump(_rig_with(p_markers={"M3": {"position": [1, 2]}})), ["'M3'", "position"]),
    ("position nan", "robots:\n  p:\n    camera: {K: [[800, 0, 479.5], [0, 800, 269.5], [0, 0, 1]]}\n"
     "    markers: {M3: {position: [0, .nan, 1]}}\n", ["'M3'", "position"]),
    ("bad color", yaml.safe_dump(_rig_with(p_markers={"M3": {"position": [0, 0, 0], "color": [0, 300, 0]}})),
     ["'M3'", "color"]),
    ("bad blink", yaml.safe_dump(_rig_with(p_markers={"M3": {"position": [0, 0, 0], "blink_hz": 0}})),
     ["'M3'", "blink_hz"]),
    ("bad tag", yaml.safe_dump(_rig_with(p_markers={"M3": {"position": [0, 0, 0], "tag": {"family": "t", "id": 1}}})),
     ["'M3'", "tag"]),
    ("duplicate marker", yaml.safe_dump(_rig_with(p_markers={"M1": {"position": [0, 0, 0]}})), ["'M1'"]),
    ("bad K", yaml.safe_dump(_rig_with(p_camera={"K": [[1, 2, 3]]})), ["'p'", "K"]),
    ("camera file missing", yaml.safe_dump(_rig_with(p_camera="calib/none.yaml")), ["'p'", "calib/none.yaml"]),
]


@pytest.mark.parametrize("label,text,words", BAD_RIG_TEXTS, ids=[b[0] for b in BAD_RIG_TEXTS])
def test_cli_bad_rig(tmp_path, capsys, label, text, words):
    rig = tmp_path / "rig.yaml"
    rig.write_text(text)
    obs = tmp_path / "obs.json"
    obs.write_text(json.dumps(scene_observations()))
    line = run_error(["localize", "--rig", str(rig), "--observations", str(obs)], capsys)
    assert "rig.yaml" in line
    for w in words:
        assert w in line, (w, line)


def test_cli_missing_rig_file(tmp_path, capsys):
    obs = tmp_path / "obs.json"
    obs.write_text(json.dumps(scene_observations()))
    line = run_error(["localize", "--rig", str(tmp_path / "nope.yaml"), "--observations", str(obs)], capsys)
    assert "nope.yaml" in line


BAD_OBS_TEXTS = [
    ("missing file", None, ["obs.json"]),
    ("json syntax", '{"p": {"M1": [1, 2]', ["obs.json", "JSON"]),
    ("top level list", "[[1, 2]]", ["obs.json"]),
    ("pixel three numbers", '{"p": {"M1": [1, 2, 3]}}', ["'p'", "'M1'"]),
    ("pixel string", '{"q": {"M3": "1, 2"}}', ["'q'", "'M3'"]),
    ("pixel nan", '{"q": {"M4": [NaN, 2]}}', ["'q'", "'M4'"]),
    ("observer scalar", '{"p": 5}', ["'p'"]),
]


@pytest.mark.parametrize("label,text,words", BAD_OBS_TEXTS, ids=[b[0] for b in BAD_OBS_TEXTS])
def test_cli_bad_observations(tmp_path, capsys, label, text, words):
    rig, _ = write_scene(tmp_path, obs_name="good.json")
    obs = tmp_path / "obs.json"
    if text is not None:
        obs.write_text(text)
    line = run_error(["localize", "--rig", rig, "--observations", str(obs)], capsys)
    assert "obs.json" in line
    for w in words:
        assert w in line, (w, line)


# ---------------------------------------------------------------------------
# argparse usage errors: exit status 2 as usual
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["no-such-command"],
        ["localize"],
        ["localize", "--rig", "r.yaml"],
        ["localize", "--rig", "r.yaml", "--observations", "o.json", "--pixel-sigma", "-1"],
        ["localize", "--rig", "r.yaml", "--observations", "o.json", "--pixel-sigma", "nan"],
        ["localize", "--rig", "r.yaml", "--observations", "o.json", "--pixel-sigma", "abc"],
    ],
)
def test_usage_errors_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "usage: mutloc" in err and "Traceback" not in err


def test_help_lists_localize(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    assert "localize" in capsys.readouterr().out


# ---------------------------------------------------------------------------
# python -m mutloc
# ---------------------------------------------------------------------------


def test_python_dash_m(tmp_path):
    help_run = subprocess.run([sys.executable, "-m", "mutloc", "--help"], capture_output=True, text=True)
    assert help_run.returncode == 0 and "localize" in help_run.stdout
    bad = tmp_path / "rig.yaml"
    bad.write_text("robots: [1, 2]\n")
    obs = tmp_path / "obs.json"
    obs.write_text("{}")
    r = subprocess.run(
        [sys.executable, "-m", "mutloc", "localize", "--rig", str(bad), "--observations", str(obs)],
        capture_output=True, text=True,
    )
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.splitlines()) == 1 and r.stderr.startswith("mutloc: error: ")
    assert "rig.yaml" in r.stderr and "robots" in r.stderr


def test_compiling_kernels_is_announced_once_on_a_cold_cache_only(tmp_path):
    """The first use of a kernel compiles in silence for up to a minute: on a
    cold cache (and stderr a terminal) one line says so; a warm cache, or
    stderr that is not a terminal, gets nothing.  A tiny kernel of the
    test's own stands for mutloc's (the notice listens to every compilation
    in the process), in either import order."""
    import os
    import pty
    import subprocess
    import sys

    script = tmp_path / "kernel.py"
    script.write_text("import sys\nif sys.argv[1] == 'numba-first':\n    import numba\nimport mutloc\nimport numba\n\n"
                      "@numba.njit(cache=True)\ndef f(x):\n    return x + 1\n\nprint(f(1))\n")

    def run(order: str, tty: bool = True) -> str:
        env = {**os.environ, "MUTLOC_CACHE_DIR": str(tmp_path / f"cache-{order}")}
        env.pop("NUMBA_CACHE_DIR", None)
        master, slave = pty.openpty() if tty else (None, subprocess.PIPE)
        out = subprocess.run([sys.executable, str(script), order], stdout=subprocess.PIPE, stderr=slave, env=env,
                             timeout=120)
        if not tty:
            return out.stderr.decode()
        os.close(slave)
        err = b""
        try:
            while chunk := os.read(master, 4096):
                err += chunk
        except OSError:  # the terminal's other end is closed
            pass
        os.close(master)
        assert out.returncode == 0 and out.stdout.strip() == b"2", err
        return err.decode()

    for order in ("mutloc-first", "numba-first"):
        cold = run(order)
        assert cold.count("compiling numerical kernels once (cached in") == 1, cold
        assert str(tmp_path / f"cache-{order}") in cold
    assert run("mutloc-first") == ""  # warm
    (tmp_path / "cache-mutloc-first").rename(tmp_path / "kept")
    assert "compiling" not in run("mutloc-first", tty=False)  # cold, but not a terminal
