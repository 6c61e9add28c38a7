#!/usr/bin/env python
"""Timing helpers for the coloured-ball detector (not part of the library).

    python bench/ball_tools.py     # FPS of detect_balls on a demo frame, one core

:func:`time_detector` is also used by ``tests/test_detect_balls.py``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping

import cv2
import numpy as np

from mutloc.core.camera import Camera
from mutloc.core.rig import Marker
from mutloc.detect.balls import DEFAULT_BALL_RADIUS_M, BallParams, detect_balls

__all__ = ["demo_image", "time_detector"]


def demo_image(seed: int = 0, width: int = 960, height: int = 540) -> tuple[np.ndarray, dict[str, Marker], Camera]:
    """A textured, noisy frame with four shaded balls of one robot (for timing only).

    The markers' positions are the balls' centres in this camera's frame
    (as if the robot's frame were the camera's), so the rig check applies.
    """
    rng = np.random.default_rng(seed)
    f = 800.0
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    cam = Camera(K, size=(width, height))
    bg = cv2.GaussianBlur(rng.integers(40, 160, (height // 8, width // 8, 3), dtype=np.uint8), (0, 0), 1.0)
    img = cv2.resize(bg, (width, height), interpolation=cv2.INTER_CUBIC)
    colours = {"M1": (255, 0, 0), "M2": (0, 200, 0), "M3": (0, 0, 255), "M4": (255, 255, 0)}
    markers = {}
    for i, (name, rgb) in enumerate(colours.items()):
        cx, cy = (i + 1) * width / 5 + rng.uniform(-20, 20), height / 2 + rng.uniform(-100, 100)
        r = rng.uniform(8, 24)
        for k in range(int(r), 0, -1):  # crude shading: brighter towards the centre
            shade = 0.55 + 0.45 * (1 - (k / r) ** 2) ** 0.5
            col = tuple(int(c * shade) for c in rgb[::-1])
            cv2.circle(img, (int(cx * 16), int(cy * 16)), int(k * 16), col, -1, cv2.LINE_AA, shift=4)
        z = f * DEFAULT_BALL_RADIUS_M / r
        pos = np.array([(cx - K[0, 2]) * z / f, (cy - K[1, 2]) * z / f, z])
        markers[name] = Marker(name=name, robot="q", position=pos, color=rgb)
    img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    return img, markers, cam


def time_detector(
    image: np.ndarray | None = None,
    markers: Mapping[str, Marker] | None = None,
    camera: Camera | None = None,
    *,
    repeats: int = 200,
    threads: int = 1,
    params: BallParams | None = None,
    detector=detect_balls,
) -> float:
    """Frames per second of ``detector`` (default :func:`detect_balls`) on one image (default: a demo frame).

    ``threads`` is passed to ``cv2.setNumThreads`` for the measurement (1 =
    one core) and restored afterwards.  The clock is the process's CPU time,
    so with one thread the figure is per core and does not depend on what
    else the machine is running.
    """
    if image is None or markers is None:
        image, markers, cam = demo_image()
        camera = camera or cam
    kwargs = {} if params is None else {"params": params}
    old = cv2.getNumThreads()
    cv2.setNumThreads(int(threads))
    try:
        detector(image, markers, camera=camera, **kwargs)  # warm-up (JIT, caches)
        best = math.inf
        # Best of a few batches (CPU time still feels cache and memory
        # contention from other processes).
        n = max(1, repeats // 3)
        for _ in range(3):
            t0 = time.process_time()
            for _ in range(n):
                detector(image, markers, camera=camera, **kwargs)
            best = min(best, (time.process_time() - t0) / n)
    finally:
        cv2.setNumThreads(old)
    return 1.0 / best


if __name__ == "__main__":
    img, mk, cam = demo_image()
    res = detect_balls(img, mk, camera=cam)
    print(f"found {sorted(res.detections)}, missing {res.missing}")
    print(
        f"detect_balls: {time_detector(img, mk, cam):.0f} FPS at {img.shape[1]}x{img.shape[0]}, "
        f"{len(mk)} markers, one thread"
    )
