"""``--rerun FILE.rrd``: the track as a Rerun recording, read back with the
Rerun SDK (rerun.chunk.RrdReader) and compared with trajectory.csv."""

import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.io import save_rig
from mutloc.io.logs import write_observation_log
from mutloc.io.trajectory import read_trajectory_csv
from mutloc.sim.render import default_path
from mutloc.sim.tracking import observation_sequence
from mutloc.sim.world import standard_rig


def _read(path):
    """{entity path: [record batch rows as dicts]} of a .rrd file."""
    from rerun.chunk import RrdReader

    import pyarrow as pa

    out = {}
    for chunk in RrdReader(path).stream().to_chunks():
        rb = chunk.to_record_batch()
        cols = {n: rb.column(n) for n in rb.schema.names if n != "log_time"}  # wall clock of logging: not ours
        if "time" in cols:
            cols["time"] = cols["time"].cast(pa.int64())  # nanoseconds of the track's time line
        out.setdefault(chunk.entity_path, []).extend(pa.table(cols).to_pylist())
    for rows in out.values():
        rows.sort(key=lambda r: r.get("time") or 0)
    return out


def _seconds(ns):
    return ns * 1e-9


def test_rerun_from_a_log(tmp_path):
    rig = standard_rig("balls")
    seq = observation_sequence(rig, default_path(2.0, 12.0, 0.3), duration=1.5, fps=30.0, pixel_sigma=1.0, seed=4,
                               blind=((0.5, 0.8, "q"),))
    save_rig(rig, tmp_path / "rig.yaml")
    write_observation_log(tmp_path / "log.jsonl", seq.frames)
    rrd = tmp_path / "viz" / "track.rrd"
    assert main(["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(tmp_path / "log.jsonl"),
                 "--out", str(tmp_path / "out"), "--rerun", str(rrd), "--no-progress"]) == 0
    rows = read_trajectory_csv(tmp_path / "out" / "trajectory.csv")
    with_pose = [r for r in rows if r["pose"] is not None]
    data = _read(rrd)
    assert {"/world", "/world/q", "/world/p", "/world/p_uncertainty", "/world/trajectory", "/status"} <= set(data)
    status = data["/status"]
    assert len(status) == len(rows)
    for s, r in zip(status, rows):
        assert _seconds(s["time"]) == pytest.approx(r["t"], abs=1e-6)
        assert s["TextLog:text"][0].startswith(r["status"])
    tf = data["/world/p"]
    assert len(tf) == len(with_pose)
    for m, r in zip(tf, with_pose):
        np.testing.assert_allclose(m["Transform3D:translation"][0], r["pose"].t, atol=1e-6)
        R = np.array(m["Transform3D:mat3x3"][0]).reshape(3, 3).T  # stored column-major
        np.testing.assert_allclose(R, r["pose"].R, atol=1e-6)
    ell = data["/world/p_uncertainty"]
    assert len(ell) == len(with_pose)
    for m, r in zip(ell, with_pose):
        np.testing.assert_allclose(m["Ellipsoids3D:centers"][0], r["pose"].t, atol=1e-6)
        # The ellipsoid's axes are 3 sigma along the covariance's eigenvectors: same total variance as the CSV's.
        half = np.array(m["Ellipsoids3D:half_sizes"][0])
        assert np.sum((half / 3) ** 2) == pytest.approx(np.sum(r["sigma"][3:] ** 2), rel=1e-4)
    strip = np.array(data["/world/trajectory"][0]["LineStrips3D:strips"][0])
    np.testing.assert_allclose(strip, [r["pose"].t for r in with_pose], atol=1e-6)


def test_rerun_from_images_has_the_images_and_labelled_detections(tmp_path, tmp_path_factory):
    """... the images as JPEG: the file is a fraction of the raw frames'
    size, and each image decodes to the frame that was tracked."""
    import cv2

    from mutloc.track.tracker import track
    from test_pipeline import _sequence

    rig, frames, truth = _sequence("balls", 2, 10.0, seed=3, store=tmp_path_factory)
    rrd = tmp_path / "img.rrd"
    traj = track(rig, {r: iter(f) for r, f in frames.items()}, fps=10.0, progress=False, rerun=rrd)
    raw = sum(f.image.nbytes for fs in frames.values() for f in fs)
    assert rrd.stat().st_size < raw / 4, (rrd.stat().st_size, raw)
    data = _read(rrd)
    for robot, seen in (("p", {"M1", "M2"}), ("q", {"M3", "M4"})):
        imgs = data[f"/images/{robot}"]
        assert len(imgs) == 2
        for rec, frame in zip(imgs, frames[robot]):
            assert rec["EncodedImage:media_type"] == ["image/jpeg"]
            back = cv2.imdecode(np.frombuffer(bytes(rec["EncodedImage:blob"][0]), np.uint8), cv2.IMREAD_COLOR)
            assert back.shape == frame.image.shape
            assert np.abs(back.astype(int) - frame.image).mean() < 3.0
        dets = data[f"/images/{robot}/detections"]
        assert len(dets) == 2
        for d, row in zip(dets, traj.rows):
            assert set(d["Points2D:labels"]) == seen
            det = row.detections[robot].detections
            for name, uv in zip(d["Points2D:labels"], d["Points2D:positions"]):
                np.testing.assert_allclose(uv, det[name].uv, atol=1e-3)
    assert len(data["/world/p"]) == 2

