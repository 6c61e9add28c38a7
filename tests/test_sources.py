"""Image streams: folders, videos and ROS 1/2 bags written here with rosbags."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from mutloc.errors import FileFormatError, InputError
from mutloc.track.sources import bag_camera, bag_frames, folder_frames, video_frames
from mutloc.track.tracker import pair_streams
from mutloc.track.sources import Frame


def _images(n, h=48, w=64):
    rng = np.random.default_rng(0)
    return [rng.integers(0, 255, size=(h, w, 3), dtype=np.uint8) for _ in range(n)]


def write_bag(path: Path, version: int, topic: str, images, stamps, K=None, encoding="bgr8"):
    """A ROS 1 (version 1) or ROS 2 bag with sensor_msgs/Image (+ CameraInfo)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if version == 2 else Stores.ROS1_NOETIC)
    Image = store.types["sensor_msgs/msg/Image"]
    Info = store.types["sensor_msgs/msg/CameraInfo"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    RoI = store.types["sensor_msgs/msg/RegionOfInterest"]
    if version == 2:
        from rosbags.rosbag2 import Writer

        writer = Writer(path, version=8)
        ser = store.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        ser = store.serialize_ros1

    def header(t, seq):
        sec = int(t)
        kw = dict(stamp=Time(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id="cam")
        if version == 1:
            kw["seq"] = seq
        return Header(**kw)

    with writer:
        conn = writer.add_connection(topic, Image.__msgtype__, typestore=store)
        info_conn = writer.add_connection(topic.rsplit("/", 1)[0] + "/camera_info", Info.__msgtype__, typestore=store)
        for i, (img, t) in enumerate(zip(images, stamps)):
            h, w = img.shape[:2]
            data = img if encoding == "bgr8" else img[:, :, ::-1]
            msg = Image(header=header(t, i), height=h, width=w, encoding=encoding, is_bigendian=0, step=3 * w,
                        data=np.ascontiguousarray(data).reshape(-1))
            writer.write(conn, int(t * 1e9), ser(msg, Image.__msgtype__))
            if K is not None and i == 0:
                mats = dict(d=np.array([-0.1, 0.01, 0.0, 0.0, 0.0]), k=np.asarray(K, float).reshape(-1),
                            r=np.eye(3).reshape(-1), p=np.zeros(12))
                if version == 1:  # ROS 1 spells them D, K, R, P
                    mats = {k.upper(): v for k, v in mats.items()}
                info = Info(header=header(t, i), height=h, width=w, distortion_model="plumb_bob", **mats,
                            binning_x=0, binning_y=0,
                            roi=RoI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                writer.write(info_conn, int(t * 1e9), ser(info, Info.__msgtype__))


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("encoding", ["bgr8", "rgb8"])
def test_bag_images_and_camera_info_roundtrip(tmp_path, version, encoding):
    imgs = _images(4)
    stamps = [100.0 + 0.1 * i for i in range(4)]
    K = [[500.0, 0, 31.5], [0, 500.0, 23.5], [0, 0, 1]]
    path = tmp_path / ("b.bag" if version == 1 else "b2")
    write_bag(path, version, "/cam/image_raw", imgs, stamps, K=K, encoding=encoding)
    frames = list(bag_frames(path, "/cam/image_raw"))
    assert [f.status for f in frames] == ["ok"] * 4
    for f, img, t in zip(frames, imgs, stamps):
        np.testing.assert_array_equal(f.image, img)
        assert f.t == pytest.approx(t, abs=1e-9)
    cam = bag_camera(path, "/cam/camera_info")
    np.testing.assert_allclose(cam.K, K)
    assert cam.size == (64, 48) and cam.dist[0] == pytest.approx(-0.1)


def test_missing_topic_and_bad_bag_are_typed_errors(tmp_path):
    path = tmp_path / "b.bag"
    write_bag(path, 1, "/cam/image_raw", _images(1), [1.0])
    with pytest.raises(InputError, match="no topic"):
        list(bag_frames(path, "/other/image"))
    bad = tmp_path / "junk.bag"
    bad.write_bytes(b"not a bag at all")
    with pytest.raises(FileFormatError):
        list(bag_frames(bad, "/cam/image_raw"))


def test_folder_timestamps_from_names_csv_or_fps(tmp_path):
    imgs = _images(3)
    for i, img in enumerate(imgs):
        cv2.imwrite(str(tmp_path / f"{10 + i * 0.5:.3f}.png"), img)
    assert [f.t for f in folder_frames(tmp_path)] == [10.0, 10.5, 11.0]
    d2 = tmp_path / "seq"
    d2.mkdir()
    for i, img in enumerate(imgs):
        cv2.imwrite(str(d2 / f"{i:06d}.png"), img)
    with pytest.raises(InputError, match="fps"):
        list(folder_frames(d2))
    assert [f.t for f in folder_frames(d2, fps=4)] == [0.0, 0.25, 0.5]
    (d2 / "frames.csv").write_text("index,timestamp\n0,1.0\n1,1.1\n2,1.3\n")
    assert [f.t for f in folder_frames(d2)] == [1.0, 1.1, 1.3]
    (d2 / "000001.png").write_bytes(b"corrupt")
    frames = list(folder_frames(d2))
    assert frames[1].image is None and "unreadable" in frames[1].status and frames[2].image is not None


def test_video_frames_and_unreadable_video(tmp_path):
    path = tmp_path / "v.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for img in _images(5):
        vw.write(img)
    vw.release()
    frames = list(video_frames(path))
    assert len(frames) == 5 and frames[3].t == pytest.approx(0.3)
    (tmp_path / "bad.avi").write_bytes(b"junk")
    with pytest.raises(FileFormatError):
        list(video_frames(tmp_path / "bad.avi"))


def test_pairing_by_timestamp():
    a = [Frame(i, t, None) for i, t in enumerate([0.0, 0.1, 0.2, 0.3])]
    b = [Frame(i, t, None) for i, t in enumerate([0.001, 0.102, 0.25, 0.299])]
    pairs = [(x.t if x else None, y.t if y else None) for x, y in pair_streams(iter(a), iter(b), 0.005)]
    assert pairs == [(0.0, 0.001), (0.1, 0.102), (0.2, None), (None, 0.25), (0.3, 0.299)]


def test_truncated_video_keeps_earlier_frames_and_reports(tmp_path):
    path = tmp_path / "v.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for img in _images(10):
        vw.write(img)
    vw.release()
    data = path.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    frames = list(video_frames(cut))
    good = [f for f in frames if f.image is not None]
    assert 0 < len(good) < 10
    assert frames[-1].image is None and "stopped" in frames[-1].status
