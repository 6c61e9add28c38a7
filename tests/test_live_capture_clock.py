"""Frames of an OpenCV capture stamped with the driver's capture time
(issue 38, "Say what is wrong"): OpenCV's V4L2 backend reports a buffer's
timestamp (``CAP_PROP_POS_MSEC``: ``VIDIOC_DQBUF``'s, on CLOCK_MONOTONIC
for most drivers, CLOCK_REALTIME for a few) and mutloc.live.cameras moves it
to the wall clock; with no usable stamp, the time ``read()`` returned.  No
device here: fake capture objects report the stamps."""

import math
import time

import cv2
import numpy as np
import pytest

from mutloc.live import cameras
from mutloc.live.cameras import DRIVER_STAMP_MAX_AGE, CaptureSource, DriverClock

WALL, MONO = 1_800_000_000.0, 12_345.0  # time.time() and time.monotonic() when a read returned


class Reports:
    """A capture whose ``get(CAP_PROP_POS_MSEC)`` reports ``ms`` (raises: a backend without it)."""

    def __init__(self, ms):
        self.ms = ms

    def get(self, prop):
        assert prop == cv2.CAP_PROP_POS_MSEC
        if isinstance(self.ms, Exception):
            raise self.ms
        return self.ms


@pytest.mark.parametrize("age", [0.0, 0.004, 0.033, 0.5])
def test_a_monotonic_driver_stamp_becomes_the_wall_clock_capture_time(age):
    clock = DriverClock()
    assert clock.stamp(Reports((MONO - age) * 1000), WALL, MONO) == pytest.approx(WALL - age, abs=1e-6)
    assert clock.source == "driver (monotonic)"


def test_a_realtime_driver_stamp_is_taken_as_it_is():
    clock = DriverClock()
    assert clock.stamp(Reports((WALL - 0.021) * 1000), WALL, MONO) == pytest.approx(WALL - 0.021, abs=1e-6)
    assert clock.source == "driver (realtime)"


@pytest.mark.parametrize("ms", [0.0, -1.0, math.nan, math.inf, 5_000.0, (MONO - DRIVER_STAMP_MAX_AGE - 0.1) * 1000,
                                (MONO + 0.5) * 1000, (WALL + 0.5) * 1000, RuntimeError("no such property")])
def test_no_usable_stamp_gives_the_time_read_returned(ms):
    """0 (OpenCV before the first frame), -1 (unsupported), a file's
    position, a stamp older than DRIVER_STAMP_MAX_AGE or after the read
    returned, a raising backend: the read's return time, and it says so."""
    clock = DriverClock()
    clock.source = "driver (monotonic)"  # (a previous frame's)
    assert clock.stamp(Reports(ms), WALL, MONO) == WALL
    assert clock.source == "read"


def test_a_source_that_is_no_device_never_takes_its_stamps():
    clock = DriverClock(driver=False)
    assert clock.stamp(Reports((MONO - 0.02) * 1000), WALL, MONO) == WALL and clock.source == "read"


class FakeDevice:
    """What cv2.VideoCapture gives for a V4L2 device: frames whose driver stamp is 30 ms before ``read`` returns."""

    LAG = 0.030

    def __init__(self, *args):
        self.stamps = []  # (driver stamp on the monotonic clock, wall - monotonic when it was made)
        self.n = 0

    def isOpened(self):
        return True

    def set(self, *args):
        return True

    def read(self):
        if self.n >= 5:
            return False, None
        self.n += 1
        mono = time.monotonic()
        self.stamps.append((mono - self.LAG, time.time() - mono))
        return True, np.zeros((4, 4, 3), np.uint8)

    def get(self, prop):
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.stamps[-1][0] * 1000 if self.stamps else 0.0
        return 30.0

    def release(self):
        pass


def test_a_capture_source_stamps_its_frames_with_the_driver_time(monkeypatch):
    """CaptureSource through a fake VideoCapture: each frame's t is the
    driver's stamp on the wall clock, not the later time read() returned."""
    made = []
    monkeypatch.setattr(cameras.cv2, "VideoCapture", lambda *a: made.append(FakeDevice(*a)) or made[-1])
    src = CaptureSource("0", max_failures=1).start()  # (a V4L2 device's number)
    try:
        frame = src.take(timeout=10)
        assert frame is not None, src.error
    finally:
        src.close()
    stamp, offset = made[0].stamps[frame.index]
    assert frame.t == pytest.approx(stamp + offset, abs=1e-3)  # (the offset drifts by NTP's slew at most)
    assert src.stamping == "driver (monotonic)" and not src.notes


def test_a_capture_without_stamps_says_its_frames_are_stamped_at_read(monkeypatch):
    """A stream URL (OpenCV's FFmpeg backend: CAP_PROP_POS_MSEC is the
    stream's position, no clock -- here one that happens to lie on the
    monotonic clock, as the device's): frames at the read's return time, and
    a note for the node to print."""
    made = []
    monkeypatch.setattr(cameras.cv2, "VideoCapture", lambda *a: made.append(FakeDevice(*a)) or made[-1])
    src = CaptureSource("rtsp://camera.invalid/stream", max_failures=1).start()
    try:
        frame = src.take(timeout=10)
        src._thread.join(10)  # (the fake's five frames read)
    finally:
        src.close()
    assert frame is not None, src.error
    stamp, offset = made[0].stamps[frame.index]
    assert frame.t >= stamp + FakeDevice.LAG + offset - 1e-3  # not before the read returned
    assert src.stamping == "read" and len(src.notes) == 1 and "stamped when read() returned" in src.notes[0]
